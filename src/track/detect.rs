//! The one walker detector, shared by registration (`register::motion`) and tracking: returns
//! short of a sensor's background, grouped into person-sized blobs, and a blob's centre (a
//! scanner sees a body's near side, so the returns' centroid is pushed back along the beam).
//! Pure: points and ranges in, blobs and centres out, all in the sensor's own frame.

use nalgebra::{Point2, Vector2};

use crate::geometry::ScanPoint;

/// What makes returns a walker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobParams {
    /// A return this much (plus `margin_frac` of its range) short of the background is
    /// something that walked in (m).
    pub moved_m: f64,
    pub margin_frac: f64,
    /// A blob: neighbouring moved returns (at most one beam skipped) no further apart than
    /// `gap_m`, at least `min_points` of them, no wider than `max_width_m` (m).
    pub gap_m: f64,
    pub min_points: usize,
    pub max_width_m: f64,
    /// Far off, a body spans few beams and some of its returns drop out: a blob there needs
    /// no more returns than beams fall across this much of a body at its range, and at
    /// least 2 (0: always `min_points`) (m).
    pub far_body_m: f64,
}

impl BlobParams {
    /// How many returns a blob `range_m` away needs, beams `beam_rad` apart.
    pub fn min_points_at(&self, range_m: f64, beam_rad: f64) -> usize {
        if self.far_body_m <= 0.0 || range_m <= 0.0 || beam_rad <= 0.0 {
            return self.min_points;
        }
        let across = (self.far_body_m / (range_m * beam_rad)).floor() as usize;
        across.max(2).min(self.min_points)
    }
}

/// Whether a return at `r` (m, horizontal) is short of the background `s` (NaN: nothing
/// there, so anything that returns walked in).
pub fn is_moved(r: f32, s: f32, p: &BlobParams) -> bool {
    let r = r as f64;
    r.is_finite() && (s.is_nan() || r < s as f64 - p.moved_m - p.margin_frac * r)
}

/// Runs of moved returns among a scan's `points` (its horizontal `ranges_m` per beam, against
/// the background's `background_m` per beam), each one blob, in beam order.
pub fn blobs(
    points: &[ScanPoint],
    ranges_m: &[f32],
    background_m: &[f32],
    p: &BlobParams,
) -> Vec<Vec<Point2<f64>>> {
    let moved = |beam: usize| {
        let (Some(&r), Some(&s)) = (ranges_m.get(beam), background_m.get(beam)) else {
            return false;
        };
        is_moved(r, s, p)
    };
    let beam_rad = if p.far_body_m > 0.0 {
        beam_spacing_rad(points)
    } else {
        0.0
    };
    let mut out: Vec<Vec<Point2<f64>>> = Vec::new();
    let mut run: Vec<(usize, Point2<f64>)> = Vec::new();
    let mut close = |run: &mut Vec<(usize, Point2<f64>)>| {
        let (width, range_m) = match (run.first(), run.last()) {
            (Some(a), Some(b)) => (
                (a.1 - b.1).norm(),
                0.5 * (a.1.coords.norm() + b.1.coords.norm()),
            ),
            _ => (0.0, 0.0),
        };
        if run.len() >= p.min_points_at(range_m, beam_rad) && width <= p.max_width_m {
            out.push(run.iter().map(|(_, q)| *q).collect());
        }
        run.clear();
    };
    for sp in points {
        if !moved(sp.beam) {
            continue;
        }
        let joins = run
            .last()
            .is_some_and(|(b, q)| sp.beam <= b + 2 && (sp.p - q).norm() <= p.gap_m);
        if !joins {
            close(&mut run);
        }
        run.push((sp.beam, sp.p));
    }
    close(&mut run);
    out
}

/// The angle between neighbouring beams (rad): the median over the scan's first neighbouring
/// returns; 0 when it cannot be told.
fn beam_spacing_rad(points: &[ScanPoint]) -> f64 {
    let bearing = |q: &ScanPoint| q.p.y.atan2(q.p.x);
    let mut steps: Vec<f64> = points
        .windows(2)
        .filter(|w| w[1].beam == w[0].beam + 1)
        .map(|w| crate::geometry::wrap_angle_rad(bearing(&w[1]) - bearing(&w[0])).abs())
        .take(65)
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    let mid = steps.len() / 2;
    *steps.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The width of a blob: its first to its last return (m).
pub fn width_m(blob: &[Point2<f64>]) -> f64 {
    match (blob.first(), blob.last()) {
        (Some(a), Some(b)) => (a - b).norm(),
        _ => 0.0,
    }
}

/// What a blob is taken to be the near side of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Body {
    /// A round body: its returns' centroid lies π/8 of the width they span in front of its
    /// centre, along the beam (evenly spaced beams sample the near side evenly across).
    Round,
    /// A centrally symmetric body of this area (m²) at the scan's height, such as a torso,
    /// wider across the shoulders than deep. The chord between the two points where beams
    /// graze it passes through its centre and cuts off half its area, so the returns'
    /// centroid lies area/(2·width) in front of the centre: a 0.45 × 0.28 m torso shows 0.45 m
    /// from in front, its centre 11 cm behind the centroid, and 0.28 m from the side, 18 cm
    /// behind, where a round body's rule says 18 and 11.
    Area(f64),
}

/// The width a blob shows (m): its extreme returns' distance plus a beam spacing (the
/// silhouette reaches about half a spacing past each).
pub fn shown_width_m(blob: &[Point2<f64>]) -> f64 {
    let extremes_m = width_m(blob);
    extremes_m + extremes_m / blob.len().saturating_sub(1).max(1) as f64
}

/// How wide one walker looked at one moment: half the width it showed across the beam (m),
/// and cos² of the angle between the beam and the way it walked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Silhouette {
    pub half_width_m: f64,
    pub cos2: f64,
}

/// Heights (m) at which a level scanner cuts people across the hips, waist or chest.
const TORSO_HEIGHT_M: [f64; 2] = [0.7, 1.5];
/// A plane pitched more than this cuts people at heights that vary with range (at 2°, 35 cm
/// over 10 m): legs far off, a torso near.
const LEVEL_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;

/// Whether a scanner this high (m) and pitched this much (rad) cuts people at one height, and
/// that height a torso's: only then can a walker's blob be the near side of something other
/// than a round body ([`Body::Area`], [`torso_area`]).
pub fn cuts_torsos(height_m: f64, pitch_rad: f64) -> bool {
    pitch_rad.abs() <= LEVEL_RAD && (TORSO_HEIGHT_M[0]..=TORSO_HEIGHT_M[1]).contains(&height_m)
}

/// A walker moving at least this fast (m/s) has a heading its silhouette is measured against.
pub const WALKING_M_S: f64 = 0.4;

/// How `blob` (sensor frame, its centre `centre`) looks against `walked`, the way its person
/// walks (any length, sensor frame): half the width it shows, and cos² of the angle between
/// the beam and that way. `None` at the origin or without a heading.
pub fn silhouette(
    blob: &[Point2<f64>],
    centre: &Point2<f64>,
    walked: &Vector2<f64>,
) -> Option<Silhouette> {
    let (beam, way) = (
        centre.coords.try_normalize(1e-9)?,
        walked.try_normalize(1e-9)?,
    );
    let cos = beam.dot(&way);
    Some(Silhouette {
        half_width_m: 0.5 * shown_width_m(blob),
        cos2: cos * cos,
    })
}

/// The area (m²) of the torsos people show, from how wide they look against the way they
/// walk. A torso `a` across the walking direction and `b` along it (semi-axes) shows a half
/// width h with h² = a² cos²θ + b² sin²θ, θ between the beam and the walking direction: from
/// in front or behind its full width, from the side its depth. The medians of h² in four bins
/// of cos²θ (a body partly hidden looks narrower; the median does not follow it) are fitted
/// by a line: b² at cos²θ = 0, a² at 1, the area π a b. `None` unless both end bins hold
/// `min_per_bin` sightings (walkers seen from in front and from the side), or where the fit
/// is not a torso's (a deeper than wide, or either under 5 cm).
pub fn torso_area(sightings: &[Silhouette], min_per_bin: usize) -> Option<f64> {
    const BINS: usize = 4;
    let mut bins: [Vec<f64>; BINS] = Default::default();
    for s in sightings {
        let k = ((s.cos2.clamp(0.0, 1.0) * BINS as f64) as usize).min(BINS - 1);
        bins[k].push(s.half_width_m * s.half_width_m);
    }
    if bins[0].len() < min_per_bin || bins[BINS - 1].len() < min_per_bin {
        return None;
    }
    // (bin centre, median h², weight √n)
    let points: Vec<(f64, f64, f64)> = bins
        .iter_mut()
        .enumerate()
        .filter(|(_, b)| b.len() >= min_per_bin.max(1))
        .map(|(k, b)| {
            b.sort_by(f64::total_cmp);
            let median = b[b.len() / 2];
            (
                (k as f64 + 0.5) / BINS as f64,
                median,
                (b.len() as f64).sqrt(),
            )
        })
        .collect();
    let w: f64 = points.iter().map(|p| p.2).sum();
    let mx = points.iter().map(|p| p.2 * p.0).sum::<f64>() / w;
    let my = points.iter().map(|p| p.2 * p.1).sum::<f64>() / w;
    let sxx: f64 = points.iter().map(|p| p.2 * (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| p.2 * (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    let (b2, a2) = (my - slope * mx, my + slope * (1.0 - mx));
    let (a, b) = (a2.max(0.0).sqrt(), b2.max(0.0).sqrt());
    (a >= b && b >= 0.05).then_some(std::f64::consts::PI * a * b)
}

/// The centre of the body a blob is the near side of, sensor frame: the returns' centroid
/// pushed away from the sensor along its beam, by how much `body` says. For [`Body::Area`]
/// the width shown is the extreme returns' distance plus a beam spacing (the silhouette
/// reaches about half a spacing past each), and no less than 0.9 √area (less is a body
/// partly hidden, which says nothing of where its centre is). `None` for an empty blob or
/// one at the origin.
pub fn centre(blob: &[Point2<f64>], body: Body) -> Option<Point2<f64>> {
    if blob.is_empty() {
        return None;
    }
    let c = blob.iter().map(|q| q.coords).sum::<Vector2<f64>>() / blob.len() as f64;
    let push_m = match body {
        Body::Round => std::f64::consts::FRAC_PI_8 * width_m(blob),
        Body::Area(area) => area / (2.0 * shown_width_m(blob).max(0.9 * area.sqrt())),
    };
    let d = c.norm();
    (d > 1e-6).then(|| Point2::from(c * ((d + push_m) / d)))
}

/// Splits a blob where people already followed stand in it: `centres` (sensor frame) whose
/// bearing lies within the blob's and whose range is from `behind_m` short of its nearest
/// return to `behind_m` past it (a body's centre lies behind its near side) each take the
/// returns nearest their bearing, cut midway between neighbours. Two people walking close
/// together, one partly behind the other, show one run of returns no wider than one person.
/// Stays whole unless two or more centres lie in it and every part keeps `min_points`.
pub fn split_by_centres(
    blob: Vec<Point2<f64>>,
    centres: &[Point2<f64>],
    behind_m: f64,
    min_points: usize,
) -> Vec<Vec<Point2<f64>>> {
    let Some(first) = blob.first() else {
        return vec![blob];
    };
    let b0 = first.y.atan2(first.x);
    let rel = |q: &Point2<f64>| crate::geometry::wrap_angle_rad(q.y.atan2(q.x) - b0);
    let bearings: Vec<f64> = blob.iter().map(rel).collect();
    let (lo, hi) = bearings
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), b| {
            (l.min(*b), h.max(*b))
        });
    let near_m = blob
        .iter()
        .map(|q| q.coords.norm())
        .fold(f64::INFINITY, f64::min);
    let mut inside: Vec<f64> = centres
        .iter()
        .filter(|c| (c.coords.norm() - near_m).abs() <= behind_m)
        .map(rel)
        .filter(|b| (lo..=hi).contains(b))
        .collect();
    if inside.len() < 2 {
        return vec![blob];
    }
    inside.sort_by(f64::total_cmp);
    let cuts: Vec<f64> = inside.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    let mut parts: Vec<Vec<Point2<f64>>> = vec![Vec::new(); inside.len()];
    for (q, b) in blob.iter().zip(&bearings) {
        parts[cuts.iter().filter(|c| *b > **c).count()].push(*q);
    }
    if parts.iter().any(|part| part.len() < min_points) {
        return vec![blob];
    }
    parts
}

/// Splits a blob wider than `max_person_m` into as many equal runs (by count of returns) as
/// people of `person_m` across would fill it: two people side by side touching are one run
/// of returns. Blobs no wider stay whole.
pub fn split_wide(
    blob: Vec<Point2<f64>>,
    max_person_m: f64,
    person_m: f64,
    min_points: usize,
) -> Vec<Vec<Point2<f64>>> {
    let w = width_m(&blob);
    if w <= max_person_m || person_m <= 0.0 {
        return vec![blob];
    }
    let parts = ((w / person_m).round() as usize)
        .max(2)
        .min(blob.len() / min_points.max(1));
    if parts < 2 {
        return vec![blob];
    }
    let n = blob.len();
    (0..parts)
        .map(|k| blob[k * n / parts..(k + 1) * n / parts].to_vec())
        .collect()
}

/// Pairs legs: the centres of leg-sized blobs one low sensor sees, merged two by two, closest
/// pairs first, when no further apart than `pair_m`; a leg with no partner (the other hidden
/// behind it) stays alone. Returns one centre per person.
pub fn pair_legs(legs: &[Point2<f64>], pair_m: f64) -> Vec<Point2<f64>> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for i in 0..legs.len() {
        for j in i + 1..legs.len() {
            let d = (legs[i] - legs[j]).norm();
            if d <= pair_m {
                pairs.push((d, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut used = vec![false; legs.len()];
    let mut out = Vec::with_capacity(legs.len());
    for (_, i, j) in pairs {
        if used[i] || used[j] {
            continue;
        }
        used[i] = true;
        used[j] = true;
        out.push(nalgebra::center(&legs[i], &legs[j]));
    }
    out.extend(
        legs.iter()
            .zip(&used)
            .filter(|(_, u)| !**u)
            .map(|(q, _)| *q),
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_torso_s_area_is_read_from_how_wide_it_looks_against_the_way_it_walks() {
        // A 0.45 × 0.28 m torso (0.099 m²), seen at headings spread evenly over the turn.
        let (a, b) = (0.225f64, 0.14f64);
        let seen = |k: usize| {
            let theta = k as f64 * 0.37;
            let cos2 = theta.cos().powi(2);
            Silhouette {
                half_width_m: (a * a * cos2 + b * b * (1.0 - cos2)).sqrt(),
                cos2,
            }
        };
        let all: Vec<Silhouette> = (0..400).map(seen).collect();
        let truth = std::f64::consts::PI * a * b;
        let area = torso_area(&all, 20).expect("seen from every side");
        assert!(
            (area - truth).abs() < 0.05 * truth,
            "{area} against {truth}"
        );
        // A third of them partly hidden, looking half as wide: the medians do not follow.
        let hidden: Vec<Silhouette> = (0..400)
            .map(|k| match k % 3 {
                0 => Silhouette {
                    half_width_m: 0.5 * seen(k).half_width_m,
                    ..seen(k)
                },
                _ => seen(k),
            })
            .collect();
        let area = torso_area(&hidden, 20).expect("seen from every side");
        assert!(
            (area - truth).abs() < 0.15 * truth,
            "{area} against {truth}"
        );
        // Only ever seen from in front: the depth is unknown.
        let front: Vec<Silhouette> = all.iter().copied().filter(|s| s.cos2 > 0.5).collect();
        assert_eq!(torso_area(&front, 20), None);
        // Bodies 8 cm across from every side (legs, say) are no torso: nothing is measured.
        let round: Vec<Silhouette> = all
            .iter()
            .map(|s| Silhouette {
                half_width_m: 0.04,
                ..*s
            })
            .collect();
        assert_eq!(torso_area(&round, 20), None);
    }

    fn sp(beam: usize, x: f64, y: f64) -> ScanPoint {
        ScanPoint {
            p: Point2::new(x, y),
            beam,
            z_m: None,
        }
    }

    fn params() -> BlobParams {
        BlobParams {
            moved_m: 0.3,
            margin_frac: 0.03,
            gap_m: 0.3,
            min_points: 3,
            max_width_m: 1.2,
            far_body_m: 0.0,
        }
    }

    #[test]
    fn returns_short_of_the_background_make_a_blob_and_the_rest_do_not() {
        // Beams 0..10 along x = 5; beams 3..6 hit something at x = 3.
        let mut points = Vec::new();
        let mut ranges = Vec::new();
        for b in 0..10 {
            let y = -0.5 + 0.1 * b as f64;
            let x = if (3..=6).contains(&b) { 3.0 } else { 5.0 };
            points.push(sp(b, x, y));
            ranges.push((x * x + y * y).sqrt() as f32);
        }
        let background: Vec<f32> = (0..10)
            .map(|b| {
                let y = -0.5 + 0.1 * b as f64;
                (25.0 + y * y).sqrt() as f32
            })
            .collect();
        let found = blobs(&points, &ranges, &background, &params());
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].len(), 4);
        // Nothing short of the background: no blob.
        assert!(blobs(&points, &background, &background, &params()).is_empty());
    }

    #[test]
    fn far_off_two_returns_make_a_blob_and_near_by_they_do_not() {
        // A wall across beams 0.25° apart; beams 10 and 11 hit something 0.5 m in front of it.
        let step = 0.25f64.to_radians();
        let scan = |range_m: f64| {
            let mut points = Vec::new();
            let (mut ranges, mut background) = (Vec::new(), Vec::new());
            for b in 0..20 {
                let r = if (10..=11).contains(&b) {
                    range_m - 0.5
                } else {
                    range_m
                };
                let a = (b as f64 - 10.0) * step;
                points.push(sp(b, r * a.cos(), r * a.sin()));
                ranges.push(r as f32);
                background.push(range_m as f32);
            }
            (points, ranges, background)
        };
        let p = BlobParams {
            moved_m: 0.2,
            margin_frac: 0.0,
            far_body_m: 0.3,
            ..params()
        };
        // At 24 m a 0.3 m body spans under 3 beams (10.5 cm apart): two returns are a walker.
        let (points, ranges, background) = scan(24.0);
        assert_eq!(blobs(&points, &ranges, &background, &p).len(), 1);
        assert_eq!(p.min_points_at(24.0, step), 2);
        // Without the rule, or at 8 m where such a body spans 8 beams, they are not.
        let strict = BlobParams {
            far_body_m: 0.0,
            ..p
        };
        assert!(blobs(&points, &ranges, &background, &strict).is_empty());
        let (points, ranges, background) = scan(8.0);
        assert!(blobs(&points, &ranges, &background, &p).is_empty());
        assert_eq!(p.min_points_at(8.0, step), 3);
    }

    #[test]
    fn a_run_with_two_followed_people_in_it_is_cut_between_them() {
        // One run of returns 4 m off, 0.5 m across: two people, one partly behind the other.
        let blob: Vec<Point2<f64>> = (0..10)
            .map(|k| Point2::new(4.0 + 0.01 * k as f64, -0.25 + 0.05 * k as f64))
            .collect();
        let left = Point2::new(4.2, -0.15);
        let right = Point2::new(4.3, 0.15);
        let parts = split_by_centres(blob.clone(), &[right, left], 0.5, 2);
        assert_eq!(parts.len(), 2, "{parts:?}");
        assert_eq!(parts[0].len() + parts[1].len(), blob.len());
        assert!(parts[0].iter().all(|q| q.y < 0.0) && parts[1].iter().all(|q| q.y >= 0.0));
        // One person in it, one far behind it, one beside it, or parts too small: whole.
        let behind = Point2::new(6.0, 0.15);
        let beside = Point2::new(4.2, 0.6);
        for centres in [vec![left], vec![left, behind], vec![left, beside]] {
            assert_eq!(split_by_centres(blob.clone(), &centres, 0.5, 2).len(), 1);
        }
        let edge = Point2::new(4.2, 0.2);
        assert_eq!(
            split_by_centres(blob.clone(), &[left, edge], 0.5, 4).len(),
            2
        );
        assert_eq!(split_by_centres(blob, &[left, edge], 0.5, 5).len(), 1);
    }

    #[test]
    fn the_centre_is_pushed_away_from_the_sensor() {
        let blob = vec![
            Point2::new(2.0, -0.2),
            Point2::new(1.9, 0.0),
            Point2::new(2.0, 0.2),
        ];
        let c = centre(&blob, Body::Round).expect("a centre");
        assert!(c.x > 1.96 + 0.1, "{c}");
        assert!(c.y.abs() < 1e-9);
    }

    #[test]
    fn two_people_in_one_run_are_split_and_legs_pair_up() {
        let blob: Vec<Point2<f64>> = (0..20).map(|k| Point2::new(3.0, k as f64 * 0.05)).collect();
        let parts = split_wide(blob, 0.7, 0.45, 3);
        assert_eq!(parts.len(), 2);
        let legs = [
            Point2::new(0.0, 0.0),
            Point2::new(0.25, 0.0),
            Point2::new(2.0, 0.0),
            Point2::new(2.2, 0.1),
            Point2::new(5.0, 0.0),
        ];
        let people = pair_legs(&legs, 0.6);
        assert_eq!(people.len(), 3, "{people:?}");
        assert!(
            people
                .iter()
                .any(|p| (p - Point2::new(0.125, 0.0)).norm() < 1e-9)
        );
    }
}
