//! A cheap rotation- and translation-invariant summary of one sensor's static view, to rank
//! which other sensors it likely shares view with before any pair is registered: the
//! distribution of distances between its points (a room's size and shape, whatever the
//! heading), of its wall segments' lengths, and of the angles between its walls. Two sensors
//! that see the same room see much of the same distances and walls.

use crate::register::ScanModel;

/// Histograms, each normalised to sum 1 (or all zero when the view has nothing to count).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewDescriptor {
    /// Distances between points, 0–32 m in 0.5 m bins (the far bin takes the rest).
    distances: Vec<f64>,
    /// Wall segment lengths (log scale, 0.25–32 m), weighted by length.
    walls: Vec<f64>,
    /// Angles between two walls, folded into 0–90° (15° bins), weighted by both lengths.
    angles: Vec<f64>,
}

/// Points sampled for the distance histogram: all pairs of them are counted.
const SAMPLE: usize = 160;

impl ViewDescriptor {
    pub fn of(model: &ScanModel) -> Self {
        let points = model.points();
        let sample: Vec<_> = if model.score_sample.is_empty() {
            points.to_vec()
        } else {
            model
                .score_sample
                .iter()
                .filter_map(|&i| points.get(i).copied())
                .collect()
        };
        let stride = sample.len().div_ceil(SAMPLE).max(1);
        let sample: Vec<_> = sample.into_iter().step_by(stride).collect();
        let mut distances = vec![0.0; 64];
        for (i, p) in sample.iter().enumerate() {
            for q in &sample[i + 1..] {
                let bin = ((p - q).norm() / 0.5) as usize;
                distances[bin.min(63)] += 1.0;
            }
        }
        let segments = &model.features.segments;
        let mut walls = vec![0.0; 8];
        for s in segments {
            let len = s.length_m();
            let bin = (len / 0.25).max(1.0).log2() as usize;
            walls[bin.min(7)] += len;
        }
        let mut angles = vec![0.0; 6];
        for (i, s) in segments.iter().enumerate() {
            for t in &segments[i + 1..] {
                let d = (s.direction().dot(&t.direction())).abs().min(1.0).acos();
                let bin = (d.to_degrees() / 15.0) as usize;
                angles[bin.min(5)] += s.length_m() * t.length_m();
            }
        }
        ViewDescriptor {
            distances: normalised(distances),
            walls: normalised(walls),
            angles: normalised(angles),
        }
    }

    /// How unlike two views are: 0 the same, up to 1 (half the summed L1 distances of the
    /// histograms, the point distances weighing as much as the walls and angles together).
    pub fn distance(&self, other: &Self) -> f64 {
        let l1 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>();
        0.25 * l1(&self.distances, &other.distances)
            + 0.125 * l1(&self.walls, &other.walls)
            + 0.125 * l1(&self.angles, &other.angles)
    }
}

fn normalised(mut h: Vec<f64>) -> Vec<f64> {
    let sum: f64 = h.iter().sum();
    if sum > 0.0 {
        h.iter_mut().for_each(|x| *x /= sum);
    }
    h
}

/// Every sensor's other sensors, most alike first (ties by index, so the order is stable).
pub fn rank_partners(descriptors: &[ViewDescriptor]) -> Vec<Vec<usize>> {
    (0..descriptors.len())
        .map(|i| {
            let mut others: Vec<(f64, usize)> = (0..descriptors.len())
                .filter(|&j| j != i)
                .map(|j| (descriptors[i].distance(&descriptors[j]), j))
                .collect();
            others.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            others.into_iter().map(|(_, j)| j).collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;
    use crate::geometry::raycast::{Wall, polygon};
    use crate::register::site::tests::sensor_at;

    #[test]
    fn a_view_turned_and_moved_is_described_alike_and_another_room_is_not() {
        // Two rooms of different size and shape: two sensors in the first, one in the second.
        let mut walls: Vec<Wall> = polygon(&[(0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)]);
        walls.extend(polygon(&[
            (30.0, 0.0),
            (34.0, 0.0),
            (34.0, 14.0),
            (31.0, 14.0),
            (31.0, 3.0),
            (30.0, 3.0),
        ]));
        let fov = 270f64.to_radians();
        let a = sensor_at(&walls, pose2(2.0, 2.0, 0.3), fov, "a");
        let b = sensor_at(&walls, pose2(7.5, 4.0, 2.9), fov, "b");
        let c = sensor_at(&walls, pose2(32.5, 6.0, 1.2), fov, "c");
        let d: Vec<ViewDescriptor> = [&a, &b, &c]
            .iter()
            .map(|s| ViewDescriptor::of(&s.model))
            .collect();
        assert!(d[0].distance(&d[0]) < 1e-12);
        let (same_room, other_room) = (d[0].distance(&d[1]), d[0].distance(&d[2]));
        assert!(
            same_room < other_room,
            "same room {same_room:.3}, other room {other_room:.3}"
        );
        assert_eq!(rank_partners(&d)[0], vec![1, 2]);
    }
}
