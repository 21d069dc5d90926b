//! The paper's MATCH score (eq. 8–14) of a pose: segment similarity SIM and edge-point
//! consistency CON. Reported with every pair; ranking itself is done by the free-space score.

use super::{RegisterParams, ScanModel};
use crate::features::{EdgeKind, Segment};
use crate::geometry::Pose2;
use nalgebra::Point2;

/// Line distance limit T_ldist (m) and minimum overlap T_overlap (m) of eq. 9.
const T_LDIST_M: f64 = 0.2;
const T_OVERLAP_M: f64 = 0.2;
/// T_epd: edge points this close are consistent (eq. 12).
const T_EPD_M: f64 = 0.2;

/// Length of `a` projected onto the line through `b`, clipped to `b` (Mapping, eq. 10).
fn mapping(a: (Point2<f64>, Point2<f64>), b: (Point2<f64>, Point2<f64>)) -> f64 {
    let d = b.1 - b.0;
    let len = d.norm();
    if len < 1e-9 {
        return 0.0;
    }
    let u = d / len;
    let (s0, s1) = (u.dot(&(a.0 - b.0)), u.dot(&(a.1 - b.0)));
    let (lo, hi) = (s0.min(s1).max(0.0), s0.max(s1).min(len));
    (hi - lo).max(0.0)
}

/// Distance from `a`'s midpoint to the line through `b` (Distance, eq. 11).
fn distance(a: (Point2<f64>, Point2<f64>), b: (Point2<f64>, Point2<f64>)) -> f64 {
    let d = b.1 - b.0;
    let len = d.norm();
    if len < 1e-9 {
        return f64::INFINITY;
    }
    let m = nalgebra::center(&a.0, &a.1);
    (d.perp(&(m - b.0)) / len).abs()
}

fn sim(a: (Point2<f64>, Point2<f64>), b: (Point2<f64>, Point2<f64>)) -> f64 {
    let overlap = mapping(a, b).min(mapping(b, a));
    let line_distance = distance(a, b).max(distance(b, a));
    if overlap < T_OVERLAP_M || line_distance > T_LDIST_M {
        return 0.0;
    }
    let shorter = (a.1 - a.0).norm().min((b.1 - b.0).norm());
    overlap / shorter + (T_LDIST_M - line_distance) / T_LDIST_M
}

/// MATCH = β·SIM + (1−β)·CON with SIM divided by its maximum 2·min(|LS_A|, |LS_B|) so that
/// MATCH lies in [0, 1].
pub fn match_score(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2, p: &RegisterParams) -> f64 {
    let moved: Vec<(Point2<f64>, Point2<f64>)> = b
        .features
        .segments
        .iter()
        .map(|s: &Segment| (a_from_b * s.a, a_from_b * s.b))
        .collect();
    let segs_a = &a.features.segments;
    let sim_sum: f64 = segs_a
        .iter()
        .map(|s| {
            moved
                .iter()
                .map(|&m| sim((s.a, s.b), m))
                .fold(0.0, f64::max)
        })
        .sum();
    let sim_max = 2.0 * segs_a.len().min(moved.len()) as f64;
    let sim_norm = if sim_max > 0.0 {
        (sim_sum / sim_max).min(1.0)
    } else {
        0.0
    };

    let ea: Vec<Point2<f64>> = a
        .features
        .edges
        .iter()
        .filter(|e| e.kind != EdgeKind::End)
        .map(|e| e.p)
        .collect();
    let eb: Vec<Point2<f64>> = b
        .features
        .edges
        .iter()
        .filter(|e| e.kind != EdgeKind::End)
        .map(|e| a_from_b * e.p)
        .collect();
    // One-to-one nearest pairs: a pair counts when each is the other's nearest (eq. 12–13).
    let nearest = |p: &Point2<f64>, set: &[Point2<f64>]| {
        set.iter()
            .enumerate()
            .map(|(i, q)| (i, (q - p).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1))
    };
    let consistent = ea
        .iter()
        .enumerate()
        .filter(|(i, pa)| match nearest(pa, &eb) {
            Some((j, d)) if d <= T_EPD_M => nearest(&eb[j], &ea).is_some_and(|(k, _)| k == *i),
            _ => false,
        })
        .count();
    let con = if ea.is_empty() || eb.is_empty() {
        0.0
    } else {
        consistent as f64 / ea.len().min(eb.len()) as f64
    };
    p.match_beta * sim_norm + (1.0 - p.match_beta) * con
}
