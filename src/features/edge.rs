//! Edge points (METHOD §2, 3.3.3): corners where the outline turns, and the ends of groups.

use super::FeatureParams;
use nalgebra::Point2;
use std::ops::Range;

/// What kind of edge point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EdgeKind {
    /// The outline turns towards the sensor (the corner of a pillar).
    Convex,
    /// The outline turns away from the sensor (the inside corner of a room).
    Concave,
    /// First or last point of a group: an object's end or an occlusion boundary.
    End,
}

/// An edge point: index into the scan's points and its kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgePoint {
    pub index: usize,
    pub p: Point2<f64>,
    pub kind: EdgeKind,
}

/// Edge points of one group. φ_i is measured to the nearest neighbours at least
/// `edge_neighbour_m` away; of a run of consecutive candidates only the sharpest is kept.
pub fn edges_of_group(
    points: &[Point2<f64>],
    group: Range<usize>,
    params: &FeatureParams,
) -> Vec<EdgePoint> {
    let mut out = Vec::new();
    let (first, last) = (group.start, group.end - 1);
    out.push(EdgePoint {
        index: first,
        p: points[first],
        kind: EdgeKind::End,
    });
    // The sharpest candidate of the current run of consecutive candidates.
    let mut best: Option<(usize, f64, EdgeKind)> = None;
    let mut previous_candidate = usize::MAX;
    for i in group.start + 1..group.end - 1 {
        let pi = points[i];
        let far = |j: &usize| (points[*j] - pi).norm() >= params.edge_neighbour_m;
        let before = (group.start..i).rev().find(far);
        let after = (i + 1..group.end).find(far);
        let candidate = match (before, after) {
            (Some(j), Some(k)) => {
                let (u, v) = (points[j] - pi, points[k] - pi);
                let phi = u.perp(&v).atan2(u.dot(&v)).abs();
                // Concave when the vertex lies beyond the chord of its neighbours, seen from
                // the sensor at the origin.
                let chord = nalgebra::center(&points[j], &points[k]);
                let kind = if pi.coords.norm() > chord.coords.norm() {
                    EdgeKind::Concave
                } else {
                    EdgeKind::Convex
                };
                (phi <= params.edge_angle_rad).then_some((i, phi, kind))
            }
            _ => None,
        };
        let Some(c) = candidate else { continue };
        best = match best {
            Some(b) if previous_candidate + 1 == i => Some(if c.1 < b.1 { c } else { b }),
            Some(b) => {
                out.push(EdgePoint {
                    index: b.0,
                    p: points[b.0],
                    kind: b.2,
                });
                Some(c)
            }
            None => Some(c),
        };
        previous_candidate = i;
    }
    if let Some(b) = best {
        out.push(EdgePoint {
            index: b.0,
            p: points[b.0],
            kind: b.2,
        });
    }
    if last != first {
        out.push(EdgePoint {
            index: last,
            p: points[last],
            kind: EdgeKind::End,
        });
    }
    out
}
