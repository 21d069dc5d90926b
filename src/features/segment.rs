//! Line segments (METHOD §2, 3.3.2): the paper's Hough/RANSAC hybrid seeds and grows each line,
//! total least squares refits it, and collinear neighbours merge.

use super::FeatureParams;
use nalgebra::{Point2, Vector2};
use std::ops::Range;

/// A wall segment in the sensor frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// End points: feet of the perpendiculars from the extreme points onto the fitted line.
    pub a: Point2<f64>,
    pub b: Point2<f64>,
    /// Unit normal of the fitted line, pointing towards the sensor.
    pub normal: Vector2<f64>,
    /// Indices of the points the segment was fitted to.
    pub points: Vec<usize>,
}

impl Segment {
    pub fn length_m(&self) -> f64 {
        (self.b - self.a).norm()
    }
    pub fn midpoint(&self) -> Point2<f64> {
        nalgebra::center(&self.a, &self.b)
    }
    /// Unit direction from `a` to `b`.
    pub fn direction(&self) -> Vector2<f64> {
        (self.b - self.a).normalize()
    }
    /// Direction angle of the undirected line in [0, π).
    pub fn angle_rad(&self) -> f64 {
        let d = self.b - self.a;
        d.y.atan2(d.x).rem_euclid(std::f64::consts::PI)
    }
    /// Signed distance of `p` from the segment's line, positive on the sensor's side.
    pub fn line_distance_m(&self, p: &Point2<f64>) -> f64 {
        self.normal.dot(&(p - self.a))
    }
}

/// Total-least-squares line through `points[idx]`: (centroid, unit direction).
fn tls_line(points: &[Point2<f64>], idx: &[usize]) -> Option<(Point2<f64>, Vector2<f64>)> {
    if idx.len() < 2 {
        return None;
    }
    let n = idx.len() as f64;
    let c = idx
        .iter()
        .fold(Vector2::zeros(), |s, &i| s + points[i].coords)
        / n;
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for &i in idx {
        let d = points[i].coords - c;
        sxx += d.x * d.x;
        sxy += d.x * d.y;
        syy += d.y * d.y;
    }
    // Direction of largest spread: angle of the principal axis of the 2×2 scatter matrix.
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    Some((Point2::from(c), Vector2::new(angle.cos(), angle.sin())))
}

/// Builds a segment from its points by TLS; `None` when degenerate.
fn fit_segment(points: &[Point2<f64>], idx: Vec<usize>) -> Option<Segment> {
    let (c, dir) = tls_line(points, &idx)?;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &i in &idx {
        let s = dir.dot(&(points[i] - c));
        lo = lo.min(s);
        hi = hi.max(s);
    }
    let mut normal = Vector2::new(-dir.y, dir.x);
    if normal.dot(&(Point2::origin() - c)) < 0.0 {
        normal = -normal;
    }
    Some(Segment {
        a: c + dir * lo,
        b: c + dir * hi,
        normal,
        points: idx,
    })
}

/// Grows a run from `seed` in both directions while points stay within `tol` of the line
/// through `origin` with unit normal `n`. Returns the covered index range.
fn extend(
    points: &[Point2<f64>],
    run: &Range<usize>,
    seed: usize,
    origin: Point2<f64>,
    n: Vector2<f64>,
    tol: f64,
) -> Range<usize> {
    let near = |i: usize| n.dot(&(points[i] - origin)).abs() <= tol;
    let mut lo = seed;
    while lo > run.start && near(lo - 1) {
        lo -= 1;
    }
    let mut hi = seed + 1;
    while hi < run.end && near(hi) {
        hi += 1;
    }
    lo..hi
}

/// Segments of one group by the Hough/RANSAC hybrid: seed at the middle of the longest
/// uncovered run (deterministic, where the paper draws at random), sweep the normal angle
/// θ ∈ [0, π), grow along the scan while points stay within T_lp, keep the θ covering most,
/// refit by TLS and grow once more along the refitted line.
pub fn segments_of_group(
    points: &[Point2<f64>],
    group: Range<usize>,
    params: &FeatureParams,
) -> Vec<Segment> {
    let mut segments = Vec::new();
    let mut runs = vec![group];
    let steps = (std::f64::consts::PI / params.hough_step_rad)
        .ceil()
        .max(1.0) as usize;
    let normals: Vec<Vector2<f64>> = (0..steps)
        .map(|k| {
            let t = k as f64 * params.hough_step_rad;
            Vector2::new(t.cos(), t.sin())
        })
        .collect();
    while let Some(pos) = runs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.len() >= params.min_segment_points)
        .max_by_key(|(_, r)| r.len())
        .map(|(i, _)| i)
    {
        let run = runs.swap_remove(pos);
        let seed = run.start + run.len() / 2;
        let origin = points[seed];
        let best = normals
            .iter()
            .map(|n| extend(points, &run, seed, origin, *n, params.line_tolerance_m))
            .max_by_key(|r| r.len())
            .unwrap_or(seed..seed + 1);
        let mut covered = best;
        if covered.len() >= params.min_segment_points {
            let idx: Vec<usize> = covered.clone().collect();
            if let Some((c, dir)) = tls_line(points, &idx) {
                let n = Vector2::new(-dir.y, dir.x);
                let regrown = extend(points, &run, seed, c, n, params.line_tolerance_m);
                if regrown.len() >= covered.len() {
                    covered = regrown;
                }
            }
        }
        if covered.len() >= params.min_segment_points {
            if let Some(s) = fit_segment(points, covered.clone().collect()) {
                segments.push(s);
            }
        } else {
            // The seed lies on no line: give up on it alone so the rest can still be tried.
            covered = seed..seed + 1;
        }
        if covered.start > run.start {
            runs.push(run.start..covered.start);
        }
        if covered.end < run.end {
            runs.push(covered.end..run.end);
        }
    }
    segments
}

fn angle_gap_rad(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::PI);
    d.min(std::f64::consts::PI - d)
}

fn mergeable(s: &Segment, t: &Segment, params: &FeatureParams) -> bool {
    if angle_gap_rad(s.angle_rad(), t.angle_rad()) > params.merge_angle_rad {
        return false;
    }
    let ends_close = [(s.a, t.a), (s.a, t.b), (s.b, t.a), (s.b, t.b)]
        .iter()
        .any(|(p, q)| (p - q).norm() <= params.merge_endpoint_gap_m);
    ends_close
        && s.line_distance_m(&t.midpoint()).abs() <= params.merge_line_dist_m
        && t.line_distance_m(&s.midpoint()).abs() <= params.merge_line_dist_m
}

/// Merges collinear neighbouring segments until none apply, refitting each merge by TLS.
pub fn merge_segments(
    points: &[Point2<f64>],
    mut segments: Vec<Segment>,
    params: &FeatureParams,
) -> Vec<Segment> {
    'again: loop {
        for i in 0..segments.len() {
            for j in i + 1..segments.len() {
                if mergeable(&segments[i], &segments[j], params) {
                    let t = segments.swap_remove(j);
                    let s = segments.swap_remove(i);
                    let mut idx = s.points;
                    idx.extend(t.points);
                    idx.sort_unstable();
                    if let Some(m) = fit_segment(points, idx) {
                        segments.push(m);
                    }
                    continue 'again;
                }
            }
        }
        return segments;
    }
}
