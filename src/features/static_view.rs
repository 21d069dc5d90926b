//! A sensor's static view: the per-beam median over its first scans removes people walking
//! through (they occupy a beam for a fraction of the window) and halves the noise.

use crate::scan::Scan;

/// Median ranges per beam over the scans within `window_s` of the first one. A beam is a
/// return only when more than half of the scans saw one there. `None` when there are no scans;
/// scans with a different beam count than the first are skipped.
pub fn static_view(scans: &[Scan], window_s: f64) -> Option<Scan> {
    let first = scans.first()?;
    let n = first.ranges_m.len();
    let window_ns = (window_s * 1e9) as u64;
    let used: Vec<&Scan> = scans
        .iter()
        .filter(|s| s.ranges_m.len() == n && s.stamp_ns.saturating_sub(first.stamp_ns) <= window_ns)
        .collect();
    let mut column = Vec::with_capacity(used.len());
    let ranges_m = (0..n)
        .map(|i| {
            column.clear();
            column.extend(
                used.iter()
                    .filter_map(|s| s.ranges_m.get(i).copied())
                    .filter(|r| r.is_finite() && *r > 0.0),
            );
            if column.len() * 2 <= used.len() {
                return 0.0;
            }
            column.sort_by(f32::total_cmp);
            column[column.len() / 2]
        })
        .collect();
    Some(Scan {
        ranges_m,
        intensities: Vec::new(),
        ..first.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(stamp_ms: u64, ranges_m: Vec<f32>) -> Scan {
        Scan {
            stamp_ns: stamp_ms * 1_000_000,
            sensor_stamp_ms: None,
            start_angle_rad: 0.0,
            end_angle_rad: 1.0,
            ranges_m,
            intensities: vec![],
        }
    }

    #[test]
    fn median_removes_a_passing_person_and_late_scans_are_ignored() {
        let mut scans: Vec<Scan> = (0..10)
            .map(|i| scan(i * 100, vec![5.0, 3.0, 0.0]))
            .collect();
        scans[3].ranges_m[0] = 1.2; // a person in front of the wall
        scans[4].ranges_m[0] = 1.1;
        scans[5].ranges_m[2] = 4.0; // a single spurious return on an empty beam
        scans.push(scan(5000, vec![0.5, 0.5, 0.5])); // outside the 1 s window
        let view = static_view(&scans, 1.0).unwrap_or_else(|| scan(0, vec![]));
        assert_eq!(view.ranges_m, vec![5.0, 3.0, 0.0]);
        assert!(static_view(&[], 1.0).is_none());
    }
}
