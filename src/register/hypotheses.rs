//! Pose hypotheses (METHOD §3, 3.4.1–3.4.2), pruned by the dominant wall directions: the
//! headings come from segment pairs (both orientations), and for each heading the translation
//! is voted by segment pairs slid along their line and by corner pairs of the same kind. The
//! peaks of the vote are the hypotheses; everything else is never scored.

use super::{RegisterParams, ScanModel};
use crate::features::EdgeKind;
use crate::geometry::{Pose2, pose2, wrap_angle_rad};
use nalgebra::{Point2, Rotation2, Vector2};
use rayon::prelude::*;
use std::f64::consts::{PI, TAU};

/// Translation peaks weaker than this share of a vote's strongest are not hypotheses.
const PEAK_FLOOR: f32 = 0.25;

/// Segments used per scan for hypotheses (the longest).
const MAX_SEGMENTS: usize = 40;

/// How far beyond A's outline (and A itself) the translation vote reaches (m). B may stand
/// well outside what A sees (behind A's back, or in a doorway A's walls hide); with 2 m the
/// true pose was never hypothesised for 8 of 360 simulated and 6 of 600 real pairs at ≥ 30 %
/// overlap (eval seeds 1–3 / 1–5). 15 m found no more and cost time.
const VOTE_MARGIN_M: f64 = 8.0;

/// Headings θ (B's heading in A's frame) worth trying, strongest first.
pub fn rotation_candidates(a: &ScanModel, b: &ScanModel, p: &RegisterParams) -> Vec<f64> {
    let sa = &a.features.segments[..a.features.segments.len().min(MAX_SEGMENTS)];
    let sb = &b.features.segments[..b.features.segments.len().min(MAX_SEGMENTS)];
    if sa.len() < 2 || sb.len() < 2 {
        // Too few walls to prune by: sweep like the paper's edge-point rotation search.
        return (0..180)
            .map(|k| wrap_angle_rad(k as f64 * 2f64.to_radians()))
            .collect();
    }
    const BINS: usize = 720;
    let bin = TAU / BINS as f64;
    let mut hist = vec![0.0f64; BINS];
    let mut sum_sin = vec![0.0f64; BINS];
    let mut sum_cos = vec![0.0f64; BINS];
    for s in sa {
        for t in sb {
            let da = s.direction();
            let db = t.direction();
            let base = da.y.atan2(da.x) - db.y.atan2(db.x);
            let w = s.length_m().min(t.length_m()).min(5.0);
            for theta in [base, base + PI] {
                let k = ((theta.rem_euclid(TAU)) / bin) as usize % BINS;
                hist[k] += w;
                sum_sin[k] += w * theta.sin();
                sum_cos[k] += w * theta.cos();
            }
        }
    }
    // Smooth over ±2 bins (±1°) and take local maxima.
    let smooth: Vec<f64> = (0..BINS)
        .map(|k| (0..5).map(|d| hist[(k + BINS + d - 2) % BINS]).sum())
        .collect();
    let mut peaks: Vec<(f64, usize)> = (0..BINS)
        .filter(|&k| {
            let v = smooth[k];
            v > 0.0
                && (1..=4).all(|d| v >= smooth[(k + d) % BINS] && v > smooth[(k + BINS - d) % BINS])
        })
        .map(|k| (smooth[k], k))
        .collect();
    peaks.sort_by(|x, y| y.0.total_cmp(&x.0));
    let top = peaks.first().map_or(0.0, |x| x.0);
    peaks
        .into_iter()
        .filter(|(v, _)| *v >= 0.1 * top)
        .take(p.max_rotations)
        .map(|(_, k)| {
            let (s, c) = (-2..=2).fold((0.0, 0.0), |(s, c), d| {
                let j = (k as i64 + d).rem_euclid(BINS as i64) as usize;
                (s + sum_sin[j], c + sum_cos[j])
            });
            s.atan2(c)
        })
        .collect()
}

/// A translation vote over B's possible positions in A's frame.
struct Accumulator {
    min: Point2<f64>,
    res: f64,
    width: usize,
    height: usize,
    votes: Vec<f32>,
    /// Cells ever voted for span columns `touched.0..=touched.1`, rows `touched.2..=touched.3`.
    touched: (usize, usize, usize, usize),
}

impl Accumulator {
    fn new(a: &ScanModel, res: f64) -> Self {
        let (mut lo, mut hi) = (Point2::new(0.0, 0.0), Point2::new(0.0, 0.0));
        for q in a.points() {
            lo = lo.inf(q);
            hi = hi.sup(q);
        }
        let min = lo - Vector2::repeat(VOTE_MARGIN_M);
        let width = ((hi.x - min.x + VOTE_MARGIN_M) / res).ceil() as usize + 1;
        let height = ((hi.y - min.y + VOTE_MARGIN_M) / res).ceil() as usize + 1;
        Accumulator {
            min,
            res,
            width,
            height,
            votes: vec![0.0; width * height],
            touched: (usize::MAX, 0, usize::MAX, 0),
        }
    }

    fn add(&mut self, k: usize, w: f32) {
        if let Some(v) = self.votes.get_mut(k) {
            *v += w;
            let (x, y) = (k % self.width, k / self.width);
            let t = &mut self.touched;
            *t = (t.0.min(x), t.1.max(x), t.2.min(y), t.3.max(y));
        }
    }

    fn cell(&self, t: &Point2<f64>) -> Option<usize> {
        let x = (t.x - self.min.x) / self.res;
        let y = (t.y - self.min.y) / self.res;
        (x >= 0.0 && y >= 0.0 && (x as usize) < self.width && (y as usize) < self.height)
            .then(|| y as usize * self.width + x as usize)
    }

    fn point(&mut self, t: &Point2<f64>, w: f32) {
        if let Some(k) = self.cell(t) {
            self.add(k, w);
        }
    }

    /// Votes once per cell along the segment from `from` to `to`.
    fn line(&mut self, from: &Point2<f64>, to: &Point2<f64>, w: f32) {
        let len = (to - from).norm();
        let steps = (len / (0.5 * self.res)).ceil().max(1.0) as usize;
        let mut last = usize::MAX;
        for s in 0..=steps {
            let t = from + (to - from) * (s as f64 / steps as f64);
            if let Some(k) = self.cell(&t)
                && k != last
            {
                self.add(k, w);
                last = k;
            }
        }
    }

    fn centre(&self, k: usize) -> Point2<f64> {
        let (x, y) = (k % self.width, k / self.width);
        Point2::new(
            self.min.x + (x as f64 + 0.5) * self.res,
            self.min.y + (y as f64 + 0.5) * self.res,
        )
    }

    /// The strongest local maxima of the 3×3-summed vote, at least `min_gap` cells apart.
    fn peaks(&self, count: usize, min_gap: usize) -> Vec<(f32, Point2<f64>)> {
        let (w, h) = (self.width, self.height);
        if w < 3 || h < 3 {
            return Vec::new();
        }
        // 3×3 box sum over the voted window (one cell of margin), separably: rows of three,
        // then three rows.
        let (x0, x1, y0, y1) = self.touched;
        if x0 > x1 || y0 > y1 {
            return Vec::new();
        }
        let (x0, x1) = (x0.max(1), x1.min(w - 2));
        let (y0, y1) = (y0.max(1), y1.min(h - 2));
        // Votes only in the border cells leave no window inside it (and would underflow).
        if x0 > x1 || y0 > y1 {
            return Vec::new();
        }
        // Over the window only, by row slices so the sums vectorise; each cell adds in the
        // same order as cell by cell. `summed` has a border of one zero cell all round (cells
        // outside the window sum to nothing).
        let ww = x1 - x0 + 1;
        let sw = ww + 2;
        let mut rows = vec![0.0f32; (y1 - y0 + 3) * ww];
        for (y, r) in (y0 - 1..=y1 + 1).zip(rows.chunks_exact_mut(ww)) {
            let v = &self.votes[y * w..(y + 1) * w];
            let (left, mid, right) = (&v[x0 - 1..x1], &v[x0..=x1], &v[x0 + 1..=x1 + 1]);
            for (((out, l), m), rr) in r.iter_mut().zip(left).zip(mid).zip(right) {
                *out = l + m + rr;
            }
        }
        let mut summed = vec![0.0f32; (y1 - y0 + 3) * sw];
        // Each row's largest sum: rows wholly below the floor hold no peak and are not scanned.
        let mut row_top = vec![0.0f32; y1 - y0 + 1];
        for ((r, out), row_top) in summed
            .chunks_exact_mut(sw)
            .skip(1)
            .take(y1 - y0 + 1)
            .enumerate()
            .zip(row_top.iter_mut())
        {
            let (above, here, below) = (
                &rows[r * ww..(r + 1) * ww],
                &rows[(r + 1) * ww..(r + 2) * ww],
                &rows[(r + 2) * ww..(r + 3) * ww],
            );
            let out = &mut out[1..=ww];
            for (((o, a), m), b) in out.iter_mut().zip(above).zip(here).zip(below) {
                *o = a + m + b;
            }
            *row_top = out.iter().copied().fold(0.0, f32::max);
        }
        let top = row_top.iter().copied().fold(0.0, f32::max);
        // Only local maxima well above nothing can be peaks: sorting just those keeps this
        // cheap on big sites.
        let floor = (PEAK_FLOOR * top).max(f32::MIN_POSITIVE);
        let mut order: Vec<usize> = Vec::new();
        for sy in 1..=y1 - y0 + 1 {
            if row_top[sy - 1] < floor {
                continue;
            }
            for sx in 1..=ww {
                let k = sy * sw + sx;
                let v = summed[k];
                if v >= floor
                    && [
                        k - sw - 1,
                        k - sw,
                        k - sw + 1,
                        k - 1,
                        k + 1,
                        k + sw - 1,
                        k + sw,
                        k + sw + 1,
                    ]
                    .iter()
                    .all(|&j| summed[j] <= v)
                {
                    order.push((y0 + sy - 1) * w + x0 + sx - 1);
                }
            }
        }
        // Cells (not votes with them) sorted unstably by vote: ties fall as they always did.
        let vote = |k: usize| summed[(k / w + 1 - y0) * sw + k % w + 1 - x0];
        order.sort_unstable_by(|&i, &j| vote(j).total_cmp(&vote(i)));
        let mut out: Vec<(f32, usize)> = Vec::with_capacity(count);
        for k in order {
            if out.len() >= count {
                break;
            }
            let (x, y) = ((k % w) as i64, (k / w) as i64);
            let far = out.iter().all(|&(_, j)| {
                let (jx, jy) = ((j % w) as i64, (j / w) as i64);
                (jx - x).abs().max((jy - y).abs()) >= min_gap as i64
            });
            if far {
                out.push((vote(k), k));
            }
        }
        // Sub-cell position: vote-weighted centre of the 3×3 block.
        out.into_iter()
            .map(|(v, k)| {
                let (x, y) = (k % w, k / w);
                let mut c = Vector2::zeros();
                let mut total = 0.0;
                for yy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                    for xx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                        let kk = yy * w + xx;
                        let vv = self.votes[kk] as f64;
                        c += self.centre(kk).coords * vv;
                        total += vv;
                    }
                }
                let centre = if total > 0.0 {
                    Point2::from(c / total)
                } else {
                    self.centre(k)
                };
                (v, centre)
            })
            .collect()
    }
}

/// Hypotheses for one heading: translation peaks voted by segment and corner pairs.
fn hypotheses_for(
    a: &ScanModel,
    b: &ScanModel,
    theta: f64,
    p: &RegisterParams,
) -> Vec<(f32, Pose2)> {
    let rot = Rotation2::new(theta);
    let mut acc = Accumulator::new(a, p.vote_res_m);
    let parallel = 2f64.to_radians().sin();
    let sa = &a.features.segments[..a.features.segments.len().min(MAX_SEGMENTS)];
    let sb = &b.features.segments[..b.features.segments.len().min(MAX_SEGMENTS)];
    for s in sa {
        let da = s.direction();
        for t in sb {
            let db = rot * t.direction();
            // Parallel, and seen from the same side (the other side would contradict free space).
            if da.perp(&db).abs() > parallel || s.normal.dot(&(rot * t.normal)) < 0.9 {
                continue;
            }
            let (la, lb) = (s.length_m(), t.length_m());
            let centre = s.midpoint() - rot * t.midpoint().coords;
            let slide = 0.5 * (la + lb) - 0.25 * la.min(lb);
            let w = la.min(lb).min(4.0) as f32;
            acc.line(&(centre - da * slide), &(centre + da * slide), w);
        }
    }
    for ea in &a.features.edges {
        if ea.kind == EdgeKind::End {
            continue;
        }
        for eb in &b.features.edges {
            if eb.kind == ea.kind {
                acc.point(&(ea.p - rot * eb.p.coords), 1.0);
            }
        }
    }
    let gap = (p.same_pose_m / p.vote_res_m).round().max(1.0) as usize;
    let mut out: Vec<(f32, Pose2)> = acc
        .peaks(p.peaks_per_rotation, gap)
        .into_iter()
        .map(|(v, t)| (v, pose2(t.x, t.y, theta)))
        .collect();
    out.extend(
        point_votes(a, b, &rot, p)
            .peaks(p.peaks_per_rotation, gap.div_ceil(2))
            .into_iter()
            .map(|(v, t)| (v, pose2(t.x, t.y, theta))),
    );
    out
}

/// Translation vote of every point pair whose normals agree under `rot`: the translation that
/// puts the most of B's outline onto A's gets the most votes. Sparse or cluttered scans, whose
/// few segments may not share a wall, still vote through their points.
fn point_votes(
    a: &ScanModel,
    b: &ScanModel,
    rot: &Rotation2<f64>,
    p: &RegisterParams,
) -> Accumulator {
    // Twice as coarse as the segment vote: point pairs scatter more, and the coarse scoring's
    // slack absorbs the difference.
    let mut acc = Accumulator::new(a, 2.0 * p.vote_res_m);
    let (pa, pb) = (a.points(), b.points());
    let a_side: Vec<(Point2<f64>, Vector2<f64>)> = a
        .score_sample
        .iter()
        .map(|&i| (pa[i], a.normals[i]))
        .collect();
    for &j in &b.score_sample {
        let q = rot * pb[j].coords;
        let n = rot * b.normals[j];
        for (pa_i, na_i) in &a_side {
            if na_i.dot(&n) >= p.min_normal_agreement {
                acc.point(&(pa_i - q), 1.0);
            }
        }
    }
    acc
}

/// All hypotheses `a_from_b` with their vote strength.
pub fn hypotheses(a: &ScanModel, b: &ScanModel, p: &RegisterParams) -> Vec<(f32, Pose2)> {
    let thetas = rotation_candidates(a, b, p);
    thetas
        .par_iter()
        .flat_map_iter(|&theta| hypotheses_for(a, b, theta, p))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn votes_only_in_a_border_column_give_no_peak_rather_than_a_panic() {
        let mut acc = Accumulator {
            min: Point2::origin(),
            res: 0.1,
            width: 10,
            height: 10,
            votes: vec![0.0; 100],
            touched: (usize::MAX, 0, usize::MAX, 0),
        };
        acc.add(5 * 10, 1.0);
        assert!(acc.peaks(4, 1).is_empty());
        // A vote inside the border makes peaks (its 3×3 sums are a plateau).
        acc.add(5 * 10 + 4, 2.0);
        assert!(!acc.peaks(4, 1).is_empty());
    }
}
