//! Features of one scan (METHOD §2): groups, wall segments, edge points and a class for every
//! point. Pure: projected points in, features out.

pub mod edge;
pub mod group;
pub mod params;
pub mod segment;
pub mod static_view;

pub use edge::{EdgeKind, EdgePoint};
pub use params::FeatureParams;
pub use segment::Segment;
pub use static_view::{crowd_proof_view, persistent_view, static_view};

use crate::geometry::ScanPoint;
use nalgebra::Point2;
use std::ops::Range;

/// The class of a point for class-aware refinement (seed 002 in 2D).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PointClass {
    Wall,
    ConvexCorner,
    ConcaveCorner,
    Other,
}

/// Everything extracted from one scan, in the sensor frame.
#[derive(Debug, Clone)]
pub struct Features {
    /// The points, in scan order.
    pub points: Vec<Point2<f64>>,
    /// Groups as index ranges into `points`; points outside every group are clutter.
    pub groups: Vec<Range<usize>>,
    pub segments: Vec<Segment>,
    pub edges: Vec<EdgePoint>,
    /// One class per point.
    pub classes: Vec<PointClass>,
}

/// Extracts features from projected points (scan order); `step_rad` is the beam spacing.
pub fn extract(scan_points: &[ScanPoint], step_rad: f64, params: &FeatureParams) -> Features {
    let points: Vec<Point2<f64>> = scan_points.iter().map(|s| s.p).collect();
    let groups = group::group_points(scan_points, step_rad, params);
    let mut segments = Vec::new();
    let mut edges = Vec::new();
    for g in &groups {
        let in_group = segment::segments_of_group(&points, g.clone(), params);
        segments.extend(segment::merge_segments(&points, in_group, params));
        edges.extend(edge::edges_of_group(&points, g.clone(), params));
    }
    let mut segments = segment::merge_segments(&points, segments, params);
    segments.retain(|s| s.length_m() >= params.min_segment_len_m);
    segments.sort_by(|a, b| b.length_m().total_cmp(&a.length_m()));

    let mut classes = vec![PointClass::Other; points.len()];
    for s in &segments {
        for &i in &s.points {
            classes[i] = PointClass::Wall;
        }
    }
    for e in &edges {
        let class = match e.kind {
            EdgeKind::Convex => PointClass::ConvexCorner,
            EdgeKind::Concave => PointClass::ConcaveCorner,
            EdgeKind::End => continue,
        };
        // Neighbours in scan order within the corner radius share the corner's class.
        let near = |i: &usize| (points[*i] - e.p).norm() <= params.corner_radius_m;
        for i in (0..e.index)
            .rev()
            .take_while(near)
            .chain((e.index..points.len()).take_while(near))
        {
            classes[i] = class;
        }
    }
    Features {
        points,
        groups,
        segments,
        edges,
        classes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raycast::{Wall, polygon, scan_ranges};
    use crate::geometry::{Mount, ProjectParams, pose2, project_scan};
    use crate::scan::Scan;

    fn synthetic(
        walls: &[Wall],
        x: f64,
        y: f64,
        yaw: f64,
        start: f64,
        end: f64,
        n: usize,
    ) -> (Vec<ScanPoint>, f64) {
        let step = (end - start) / (n - 1) as f64;
        let angles: Vec<f64> = (0..n).map(|i| start + step * i as f64).collect();
        let scan = Scan {
            stamp_ns: 0,
            sensor_stamp_ms: None,
            start_angle_rad: start,
            end_angle_rad: end,
            ranges_m: scan_ranges(walls, &pose2(x, y, yaw), &angles, 30.0),
            intensities: vec![],
        };
        (
            project_scan(&scan, None, &Mount::default(), &ProjectParams::default()),
            step,
        )
    }

    #[test]
    fn square_room_gives_four_segments_and_four_concave_corners() {
        let room = polygon(&[(-3.0, -3.0), (3.0, -3.0), (3.0, 3.0), (-3.0, 3.0)]);
        // A full turn starting mid-wall: the first wall is split by the scan seam and must merge.
        let n = 1440;
        let end = std::f64::consts::TAU * (n - 1) as f64 / n as f64;
        let (points, step) = synthetic(&room, 0.4, -0.7, 0.3, 0.0, end, n);
        let f = extract(&points, step, &FeatureParams::default());
        assert_eq!(
            f.segments.len(),
            4,
            "{:?}",
            f.segments.iter().map(|s| (s.a, s.b)).collect::<Vec<_>>()
        );
        for s in &f.segments {
            assert!(
                (s.length_m() - 6.0).abs() < 0.2,
                "wall length {}",
                s.length_m()
            );
        }
        let concave: Vec<_> = f
            .edges
            .iter()
            .filter(|e| e.kind == EdgeKind::Concave)
            .collect();
        assert_eq!(concave.len(), 4, "{:?}", f.edges);
        assert!(f.edges.iter().all(|e| e.kind != EdgeKind::Convex));
        for e in concave {
            let corner = pose2(0.4, -0.7, 0.3) * e.p;
            assert!((corner.x.abs() - 3.0).abs() < 0.05 && (corner.y.abs() - 3.0).abs() < 0.05);
            assert_eq!(f.classes[e.index], PointClass::ConcaveCorner);
        }
        let walls = f.classes.iter().filter(|c| **c == PointClass::Wall).count();
        assert!(walls > f.points.len() * 8 / 10);
    }

    #[test]
    fn pillar_corners_are_convex_and_its_sides_are_segments() {
        let mut walls = polygon(&[(-8.0, -8.0), (8.0, -8.0), (8.0, 8.0), (-8.0, 8.0)]);
        walls.extend(polygon(&[(2.0, -0.5), (3.0, -0.5), (3.0, 0.5), (2.0, 0.5)]));
        // A 180° SICK-like scan at 0.5° steps looking at the pillar's corner.
        let (points, step) = synthetic(
            &walls,
            0.0,
            -2.0,
            0.6,
            -std::f64::consts::FRAC_PI_2,
            std::f64::consts::FRAC_PI_2,
            361,
        );
        let f = extract(&points, step, &FeatureParams::default());
        let convex: Vec<_> = f
            .edges
            .iter()
            .filter(|e| e.kind == EdgeKind::Convex)
            .collect();
        assert_eq!(convex.len(), 1, "{:?}", f.edges);
        let c = pose2(0.0, -2.0, 0.6) * convex[0].p;
        assert!(
            (c.x - 2.0).abs() < 0.05 && (c.y + 0.5).abs() < 0.05,
            "pillar corner at {c}"
        );
        // Two pillar sides (1 m each) are among the segments.
        let short = f
            .segments
            .iter()
            .filter(|s| (s.length_m() - 1.0).abs() < 0.2)
            .count();
        assert_eq!(
            short,
            2,
            "{:?}",
            f.segments.iter().map(|s| s.length_m()).collect::<Vec<_>>()
        );
    }
}
