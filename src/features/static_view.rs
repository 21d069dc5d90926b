//! A sensor's static view: what stays put. Over a second, the per-beam median removes people
//! walking through (they occupy a beam for a fraction of the window) and halves the noise.
//! Through a crowd the median sees people, not walls: over a longer window
//! [`persistent_view`] takes per beam the farthest range that keeps coming back, so a wall
//! seen between passers-by, or behind a queue that moves up now and then, is the view.

use crate::scan::Scan;

/// Median ranges per beam over the scans within `window_s` of the first one. A beam is a
/// return only when more than half of the scans saw one there. `None` when there are no scans;
/// scans with a different beam count than the first are skipped.
pub fn static_view(scans: &[Scan], window_s: f64) -> Option<Scan> {
    per_beam(scans, window_s, |returns, used| {
        if returns.len() * 2 <= used {
            return 0.0;
        }
        returns.get(returns.len() / 2).copied().unwrap_or(0.0)
    })
}

/// A view of the scans within `window_s` of the first (of its beam count), one range per beam
/// from `reduce(returns, scans)`: that beam's returns (finite, above zero) sorted, and how many
/// scans there were.
fn per_beam(
    scans: &[Scan],
    window_s: f64,
    mut reduce: impl FnMut(&[f32], usize) -> f32,
) -> Option<Scan> {
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
            column.sort_by(f32::total_cmp);
            reduce(&column, used.len())
        })
        .collect();
    Some(Scan {
        ranges_m,
        intensities: Vec::new(),
        ..first.clone()
    })
}

/// A crowd-proof static view over `window_s` when there are enough scans for "keeps coming
/// back" to mean something ([`PERSIST_MIN_SCANS`], at least [`PERSIST_SHARE`] of them), the
/// median over `median_s` otherwise.
pub fn crowd_proof_view(scans: &[Scan], window_s: f64, median_s: f64) -> Option<Scan> {
    let first = scans.first()?;
    let within = scans
        .iter()
        .filter(|s| s.stamp_ns.saturating_sub(first.stamp_ns) as f64 <= window_s * 1e9)
        .count();
    if within >= PERSIST_MIN_SCANS {
        persistent_view(scans, window_s, PERSIST_SHARE, PERSIST_TOL_M)
    } else {
        static_view(scans, median_s)
    }
}

/// Scans a persistent view needs; the share of them a range must come back in; its tolerance.
pub const PERSIST_MIN_SCANS: usize = 40;
pub const PERSIST_SHARE: f64 = 0.15;
pub const PERSIST_TOL_M: f32 = 0.05;

/// Per beam, the farthest range that comes back in at least `min_share` of the scans within
/// `window_s` of the first (returns within `tol_m` + 1 % of each other count as one range), its
/// median taken; no return where nothing persists. People hide a wall for a while; the wall
/// is still the farthest thing that keeps coming back. `None` without scans.
pub fn persistent_view(scans: &[Scan], window_s: f64, min_share: f64, tol_m: f32) -> Option<Scan> {
    per_beam(scans, window_s, |column, used| {
        let need = ((min_share * used as f64).ceil() as usize).max(2);
        // From the far end: the first run of `need` returns within tolerance of each other.
        let mut hi = column.len();
        while hi >= need {
            let (Some(&top), Some(&low)) = (column.get(hi - 1), column.get(hi - need)) else {
                break;
            };
            if top - low <= tol_m + 0.01 * top {
                // The whole cluster around it, and its median.
                let start = column[..hi]
                    .iter()
                    .rposition(|r| top - *r > tol_m + 0.01 * top)
                    .map_or(0, |k| k + 1);
                return column.get((start + hi) / 2).copied().unwrap_or(top);
            }
            hi -= 1;
        }
        0.0
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

    #[test]
    fn the_farthest_range_that_keeps_coming_back_is_the_wall_behind_a_crowd() {
        // Beam 0: a wall at 8 m, hidden by people 70 % of the time at ever other ranges.
        // Beam 1: a queue standing at 2 m for 85 % of the window, the wall at 6 m otherwise.
        // Beam 2: nothing but a stray return now and then.
        let scans: Vec<Scan> = (0..100)
            .map(|i| {
                let person = 1.0 + (i % 7) as f32 * 0.9;
                let b0 = if i % 10 < 7 {
                    person
                } else {
                    8.0 + (i % 3) as f32 * 0.01
                };
                let b1 = if i < 85 { 2.0 } else { 6.0 };
                let b2 = if i % 50 == 0 { 3.0 } else { 0.0 };
                scan(i * 100, vec![b0, b1, b2])
            })
            .collect();
        let view = persistent_view(&scans, 30.0, 0.1, 0.05).unwrap_or_else(|| scan(0, vec![]));
        assert!(
            (view.ranges_m[0] - 8.01).abs() < 0.011,
            "{:?}",
            view.ranges_m
        );
        assert_eq!(view.ranges_m[1], 6.0);
        assert_eq!(view.ranges_m[2], 0.0);
        // The median over the same scans sees the crowd.
        let median = static_view(&scans, 30.0).unwrap_or_else(|| scan(0, vec![]));
        assert!(median.ranges_m[0] < 8.0 && median.ranges_m[1] == 2.0);
    }
}
