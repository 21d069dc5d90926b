//! Whether what two views share tells where one stands from the other. Two views that share
//! only one corner (two walls meeting) or one wall match exactly there, yet any corner of any
//! building matches them as well: the fit is sharp and unique within the pair, and says nothing
//! of which corner it is. Found in a concourse where a unit facing a corner was placed 56 m off
//! on another unit's corner. A match is telling when what it rests on holds more: a third wall,
//! or enough points off the walls (columns, furniture, door jambs) — or, where two views hold
//! more than they share, a pose at which the rest of each faces the other's free space.

use super::score::PoseScore;
use super::{RegisterParams, ScanModel};
use crate::geometry::Pose2;

/// Walls closer than this in direction (rad) and offset (m) are one wall seen in pieces (behind
/// a column, across a door).
const SAME_WALL_RAD: f64 = 0.09;
const SAME_WALL_M: f64 = 0.2;

/// Walls within 10° of each other's direction are parallel.
const PARALLEL_COS: f64 = 0.985;

/// A matched point farther than this from every wall's line is structure of its own (a door
/// recess lies a few centimetres behind its wall).
const OFF_WALL_M: f64 = 0.06;

/// A wall, or the points off the walls, counts when this many matched points lie on it, for a
/// 0.25° unit (fewer for coarser beams, at least `MIN_POINTS_ANY`): a few stray hits are not
/// structure.
const MIN_POINTS_QUARTER_DEG: f64 = 12.0;
const MIN_POINTS_ANY: usize = 4;

/// Structures a telling match rests on: more than one corner.
const TELLING: usize = 3;

/// A view this much of which lands on the other's is all at stake in the match.
const MOSTLY_SHARED: f64 = 0.75;

/// The structures a match at `a_from_b` rests on, when it is generic: fewer than `TELLING`,
/// and one of the two views is almost all of it (`MOSTLY_SHARED` of its points land on the
/// other's). Where both views hold much more than they share, a wrong pose would have put the
/// rest in the other's free space; a view that is one corner puts nothing at risk.
pub fn generic_match(
    a: &ScanModel,
    b: &ScanModel,
    a_from_b: &Pose2,
    score: &PoseScore,
    p: &RegisterParams,
) -> Option<usize> {
    if score.a_in_b.overlap.max(score.b_in_a.overlap) < MOSTLY_SHARED {
        return None;
    }
    let shared =
        structures_hit(a, b, a_from_b, p).min(structures_hit(b, a, &a_from_b.inverse(), p));
    (shared < TELLING).then_some(shared)
}

/// The structures of `into` that `from`'s points hit.
fn structures_hit(
    into: &ScanModel,
    from: &ScanModel,
    into_from_from: &Pose2,
    p: &RegisterParams,
) -> usize {
    let beams_per_quarter_deg = 0.25f64.to_radians() / from.polar.bin_rad();
    let min_points =
        ((MIN_POINTS_QUARTER_DEG * beams_per_quarter_deg).round() as usize).max(MIN_POINTS_ANY);
    let segments = &into.features.segments;
    let mut segment_of = vec![None; into.points().len()];
    for (k, s) in segments.iter().enumerate() {
        for &i in &s.points {
            if let Some(slot) = segment_of.get_mut(i) {
                *slot = Some(k);
            }
        }
    }
    let mut on_segment = vec![0usize; segments.len()];
    let mut matched = Vec::new();
    let into_points = into.points();
    for q in from.points() {
        let q = into_from_from * q;
        let Some(j) = into.grid.nearest(&q) else {
            continue;
        };
        if (q - into_points[j]).norm() >= p.hit_m {
            continue;
        }
        if let Some(k) = segment_of[j] {
            on_segment[k] += 1;
        }
        matched.push(into_points[j]);
    }
    // Walls, counted once however many pieces they were seen in; the best-hit pieces first.
    let mut order: Vec<usize> = (0..segments.len()).filter(|&k| on_segment[k] > 0).collect();
    order.sort_by_key(|&k| std::cmp::Reverse(on_segment[k]));
    let mut walls: Vec<(usize, usize)> = Vec::new(); // (first piece, points)
    for k in order {
        let s = &segments[k];
        match walls.iter_mut().find(|(w, _)| same_wall(&segments[*w], s)) {
            Some((_, n)) => *n += on_segment[k],
            None => walls.push((k, on_segment[k])),
        }
    }
    walls.retain(|&(_, n)| n >= min_points);
    // Off the walls' lines: columns, furniture, door jambs and recesses. A corner's own points
    // lie on its two walls' lines and add nothing.
    let off_walls = matched
        .iter()
        .filter(|q| {
            walls
                .iter()
                .all(|&(w, _)| (*q - segments[w].a).dot(&segments[w].normal).abs() > OFF_WALL_M)
        })
        .count();
    // Two parallel walls are a corridor: what fixes the slide along it (the `Degenerate`
    // check demands something) is structure of its own, however small.
    let corridor = matches!(walls.as_slice(), [(w, _), (v, _)]
        if segments[*w].normal.dot(&segments[*v].normal).abs() > PARALLEL_COS);
    walls.len() + usize::from(off_walls >= min_points || corridor)
}

fn same_wall(w: &crate::features::Segment, s: &crate::features::Segment) -> bool {
    let turn = w.normal.dot(&s.normal).abs().clamp(0.0, 1.0).acos();
    let mid = nalgebra::center(&s.a, &s.b);
    turn < SAME_WALL_RAD && (mid - w.a).dot(&w.normal).abs() < SAME_WALL_M
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raycast::{Wall, polygon, scan_ranges};
    use crate::geometry::{Mount, pose_error, pose2};
    use crate::register::{Abstain, register_pair};

    /// A unit with 8 m of range at `site_from_sensor`, 0.25° beams over 270°.
    fn unit(walls: &[Wall], site_from_sensor: Pose2) -> ScanModel {
        let (start, step) = (-135f64.to_radians(), 0.25f64.to_radians());
        let angles: Vec<f64> = (0..=1080).map(|k| start + step * f64::from(k)).collect();
        let scan = crate::scan::Scan {
            stamp_ns: 0,
            sensor_stamp_ms: None,
            start_angle_rad: start,
            end_angle_rad: start + step * 1080.0,
            ranges_m: scan_ranges(walls, &site_from_sensor, &angles, 8.0),
            intensities: vec![],
        };
        ScanModel::from_scan(&scan, None, &Mount::default(), &RegisterParams::default())
    }

    /// A 40 × 20 m hall; each unit 1.5 m out from a corner, facing it.
    fn hall() -> Vec<Wall> {
        polygon(&[(0.0, 0.0), (40.0, 0.0), (40.0, 20.0), (0.0, 20.0)])
    }

    #[test]
    fn units_facing_different_corners_are_not_placed_on_each_other() {
        let p = RegisterParams::default();
        let north_east = pose2(38.5, 18.5, 45f64.to_radians());
        let south_west = pose2(1.5, 1.5, -135f64.to_radians());
        let r = register_pair(&unit(&hall(), north_east), &unit(&hall(), south_west), &p);
        // They share nothing; the corners match each other exactly, and any corner would.
        assert!(
            matches!(r.verdict, Err(Abstain::Generic { structures: 2 })),
            "{:?}",
            r.verdict
        );
    }

    #[test]
    fn a_room_both_see_places_the_unit() {
        let p = RegisterParams::default();
        let mut walls = polygon(&[
            (0.0, 0.0),
            (9.0, 0.0),
            (9.0, 4.0),
            (6.5, 4.0),
            (6.5, 6.0),
            (0.0, 6.0),
        ]);
        walls.extend(polygon(&[(6.0, 1.0), (7.2, 1.0), (7.2, 1.6), (6.0, 1.6)]));
        let a = pose2(2.0, 3.0, 0.0);
        let b = pose2(7.5, 3.0, 170f64.to_radians());
        let r = register_pair(&unit(&walls, a), &unit(&walls, b), &p);
        assert!(r.verdict.is_ok(), "{:?}", r.verdict);
        let (dt, dyaw) = pose_error(&r.a_from_b, &(a.inverse() * b));
        assert!(dt < 0.05 && dyaw < 0.01, "{dt} m {dyaw} rad");
    }
}
