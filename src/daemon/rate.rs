//! Scan rates for `status`: scans per second over a sliding window of host receive times.
//! Pure: the caller passes the times, so tests need no clock.

use std::collections::VecDeque;

/// Counts events in a sliding time window.
#[derive(Debug, Clone)]
pub struct RateMeter {
    window_ns: u64,
    stamps_ns: VecDeque<u64>,
}

impl RateMeter {
    /// A meter averaging over the last `window_s` seconds.
    pub fn new(window_s: f64) -> RateMeter {
        RateMeter {
            window_ns: (window_s.max(1e-3) * 1e9) as u64,
            stamps_ns: VecDeque::new(),
        }
    }

    /// Records one event at `stamp_ns` (non-decreasing).
    pub fn record(&mut self, stamp_ns: u64) {
        self.stamps_ns.push_back(stamp_ns);
        self.expire(stamp_ns);
    }

    /// Events per second at `now_ns`: `None` when none arrived in the window (before the
    /// first event, or once they stopped: a stale or zero rate would read as a live source),
    /// else the rate between the window's first and last event.
    pub fn rate_hz(&mut self, now_ns: u64) -> Option<f64> {
        self.expire(now_ns);
        let (Some(&first), Some(&last)) = (self.stamps_ns.front(), self.stamps_ns.back()) else {
            return None;
        };
        if last <= first {
            // One event in the window: it says the source is alive, not how fast.
            return Some(1e9 / self.window_ns as f64);
        }
        Some((self.stamps_ns.len() - 1) as f64 * 1e9 / (last - first) as f64)
    }

    fn expire(&mut self, now_ns: u64) {
        let oldest = now_ns.saturating_sub(self.window_ns);
        while self.stamps_ns.front().is_some_and(|&t| t < oldest) {
            self.stamps_ns.pop_front();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measures_a_steady_rate_and_notices_silence() {
        let mut meter = RateMeter::new(2.0);
        assert_eq!(meter.rate_hz(0), None);
        // 40 Hz for 3 s.
        for i in 0..120u64 {
            meter.record(i * 25_000_000);
        }
        let rate = meter.rate_hz(119 * 25_000_000).unwrap();
        assert!((rate - 40.0).abs() < 1e-9, "{rate}");
        // Memory stays bounded by the window.
        assert!(meter.stamps_ns.len() <= 81);
        // Silence longer than the window: no rate, neither the stale one nor 0.
        assert_eq!(meter.rate_hz(10_000_000_000), None);
    }

    #[test]
    fn a_lone_event_reads_as_a_low_rate() {
        let mut meter = RateMeter::new(2.0);
        meter.record(5_000_000_000);
        assert_eq!(meter.rate_hz(5_500_000_000), Some(0.5));
    }
}
