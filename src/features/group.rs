//! Grouping (METHOD §2, 3.3.1): consecutive points close enough to belong to one surface.

use super::FeatureParams;
use crate::geometry::ScanPoint;
use std::ops::Range;

/// Splits points (in scan order) into groups of consecutive points; the gap threshold grows
/// with range so far walls stay whole. Groups smaller than `min_group_points` are dropped.
/// `step_rad` is the angle between adjacent beams.
pub fn group_points(
    points: &[ScanPoint],
    step_rad: f64,
    params: &FeatureParams,
) -> Vec<Range<usize>> {
    let mut groups = Vec::new();
    let mut start = 0;
    for i in 1..=points.len() {
        let split = match (points.get(i - 1), points.get(i)) {
            (Some(prev), Some(next)) => {
                let beams = next.beam.saturating_sub(prev.beam).max(1) as f64;
                let range_m = prev.p.coords.norm().max(next.p.coords.norm());
                let gap_m =
                    params.group_gap_m + params.group_gap_beams * range_m * step_rad * beams;
                (next.p - prev.p).norm() > gap_m
            }
            _ => true,
        };
        if split {
            if i - start >= params.min_group_points {
                groups.push(start..i);
            }
            start = i;
        }
    }
    groups
}
