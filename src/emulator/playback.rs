//! When each recorded scan is due. Scan `k` of an endless sequence is recorded scan `k % n`,
//! due at its recorded offset plus `k / n` whole recordings (when looping), divided by speed.

use crate::scan::Scan;

/// Timing of a recording's scans, ms from the first scan.
#[derive(Debug, Clone, PartialEq)]
pub struct Playback {
    offsets_ms: Vec<f64>,
    /// Length of one pass: last offset plus one mean period.
    pass_ms: f64,
    speed: f64,
    looping: bool,
}

impl Playback {
    /// Timing from the scans' host stamps; `fallback_period_ms` when a recording has one scan.
    pub fn new(scans: &[Scan], fallback_period_ms: f64, speed: f64, looping: bool) -> Self {
        let first = scans.first().map_or(0, |s| s.stamp_ns);
        let offsets_ms: Vec<f64> = scans
            .iter()
            .map(|s| s.stamp_ns.saturating_sub(first) as f64 / 1e6)
            .collect();
        let last = offsets_ms.last().copied().unwrap_or(0.0);
        let period = if offsets_ms.len() > 1 {
            last / (offsets_ms.len() - 1) as f64
        } else {
            fallback_period_ms
        };
        let speed = if speed.is_finite() && speed > 0.0 {
            speed
        } else {
            1.0
        };
        Playback {
            offsets_ms,
            pass_ms: last + period.max(1e-3),
            speed,
            looping,
        }
    }

    /// Loops every `pass_ms` instead (several recordings of one site loop together), when that
    /// is longer than this recording.
    pub fn with_pass_ms(mut self, pass_ms: f64) -> Self {
        let last = self.offsets_ms.last().copied().unwrap_or(0.0);
        if pass_ms.is_finite() && pass_ms > last {
            self.pass_ms = pass_ms;
        }
        self
    }

    pub fn len(&self) -> usize {
        self.offsets_ms.len()
    }

    pub fn is_empty(&self) -> bool {
        self.offsets_ms.is_empty()
    }

    /// Mean time between scans at this speed, ms.
    pub fn period_ms(&self) -> f64 {
        self.pass_ms / self.offsets_ms.len().max(1) as f64 / self.speed
    }

    /// Recorded scan index of sequence number `k`, `None` past the end when not looping.
    pub fn index(&self, k: u64) -> Option<usize> {
        let n = self.offsets_ms.len() as u64;
        if n == 0 || (!self.looping && k >= n) {
            return None;
        }
        Some((k % n) as usize)
    }

    /// When sequence number `k` is due, ms after playback started.
    pub fn due_ms(&self, k: u64) -> Option<f64> {
        let index = self.index(k)?;
        let n = self.offsets_ms.len() as u64;
        let pass = (k / n) as f64;
        Some((pass * self.pass_ms + self.offsets_ms.get(index).copied()?) / self.speed)
    }

    /// The latest sequence number due at `elapsed_ms` (clamped to the last scan when not looping).
    pub fn current(&self, elapsed_ms: f64) -> Option<u64> {
        let n = self.offsets_ms.len();
        if n == 0 {
            return None;
        }
        let t = (elapsed_ms * self.speed).max(0.0);
        let pass = (t / self.pass_ms).floor();
        if !self.looping && pass >= 1.0 {
            return Some(n as u64 - 1);
        }
        let within = t - pass * self.pass_ms;
        let index = self
            .offsets_ms
            .partition_point(|&o| o <= within)
            .saturating_sub(1);
        Some(pass as u64 * n as u64 + index as u64)
    }
}

/// The slowest period a unit is taken to have when its recording does not say (s): 40 Hz.
pub const DEFAULT_PERIOD_S: f64 = 0.025;

/// Where a replay of several units' recordings starts (the earliest first scan, ns) and how
/// long one pass of it is (to the latest last scan, plus the slowest unit's period): the
/// span every recording loops over, so that they loop in step. `units`: each one's first
/// and last scan stamps and its period (s). `None` without a scan.
pub fn replay_span(units: impl IntoIterator<Item = (u64, u64, f64)>) -> Option<(u64, u64)> {
    let (mut origin_ns, mut last_ns, mut period_s) = (u64::MAX, 0, DEFAULT_PERIOD_S);
    for (first, last, period) in units {
        origin_ns = origin_ns.min(first);
        last_ns = last_ns.max(last);
        period_s = period_s.max(period);
    }
    (origin_ns != u64::MAX).then(|| {
        (
            origin_ns,
            last_ns.saturating_sub(origin_ns) + (period_s * 1e9) as u64,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scans(stamps_ms: &[u64]) -> Vec<Scan> {
        stamps_ms
            .iter()
            .map(|&ms| Scan {
                stamp_ns: 1_000_000_000 + ms * 1_000_000,
                sensor_stamp_ms: None,
                start_angle_rad: 0.0,
                end_angle_rad: 0.0,
                ranges_m: vec![],
                intensities: vec![],
            })
            .collect()
    }

    #[test]
    fn loops_continue_at_the_recorded_rate_and_speed_scales_time() {
        let p = Playback::new(&scans(&[0, 25, 50, 75]), 25.0, 2.0, true);
        assert_eq!(p.due_ms(0), Some(0.0));
        assert_eq!(p.due_ms(3), Some(37.5));
        assert_eq!(p.due_ms(4), Some(50.0));
        assert_eq!(p.index(5), Some(1));
        assert_eq!(p.current(51.0), Some(4));
        assert!((p.period_ms() - 12.5).abs() < 1e-9);
        let once = Playback::new(&scans(&[0, 25]), 25.0, 1.0, false);
        assert_eq!(once.due_ms(2), None);
        assert_eq!(once.current(1000.0), Some(1));
    }

    #[test]
    fn a_replay_spans_every_unit_plus_the_slowest_period() {
        assert_eq!(replay_span([]), None);
        let units = [(1_000, 2_000_000_000, 0.025), (500, 1_000_000_000, 0.05)];
        assert_eq!(
            replay_span(units),
            Some((500, 2_000_000_000 - 500 + 50_000_000))
        );
    }

    #[test]
    fn recordings_of_one_site_loop_together() {
        // 40 Hz and 20 Hz units of one 2 s recording: on their own they loop every 2.000 s
        // and 2.025 s; given the site's pass, both every 2.05 s.
        let fast = Playback::new(
            &scans(&(0..80).map(|k| k * 25).collect::<Vec<_>>()),
            25.0,
            1.0,
            true,
        );
        let slow = Playback::new(
            &scans(&(0..40).map(|k| 25 + k * 50).collect::<Vec<_>>()),
            50.0,
            1.0,
            true,
        );
        assert_ne!(fast.due_ms(80), slow.due_ms(40).map(|d| d - 25.0));
        let (fast, slow) = (fast.with_pass_ms(2050.0), slow.with_pass_ms(2050.0));
        assert_eq!(fast.due_ms(80), Some(2050.0));
        assert_eq!(
            slow.due_ms(40),
            Some(2050.0),
            "offsets are its own: the site adds its shift"
        );
        assert_eq!(fast.current(2060.0), Some(80));
        // Shorter than the recording: ignored.
        assert_eq!(slow.with_pass_ms(10.0).due_ms(40), Some(2050.0));
    }
}
