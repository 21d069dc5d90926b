//! The sensor's ms clock against the host's: 24-bit unwrap, TM1 time sync, drift tracking.
//! Pure: the driver passes host times in, nothing here reads a clock.

/// The sensor clock has 24 bits and wraps every 2^24 ms ≈ 4 h 40 min.
pub const WRAP_MS: u64 = 1 << 24;

/// Turns 24-bit stamps into a monotonic ms count. A step back of less than half the range is
/// jitter (kept as is), a bigger one is a wrap.
#[derive(Debug, Clone, Default)]
pub struct Unwrapper {
    last: Option<u32>,
    wraps: u64,
}

impl Unwrapper {
    pub fn unwrap(&mut self, raw_ms: u32) -> u64 {
        let raw_ms = raw_ms & 0xFF_FFFF;
        if let Some(last) = self.last
            && raw_ms < last
            && last - raw_ms > (WRAP_MS / 2) as u32
        {
            self.wraps += 1;
        }
        self.last = Some(raw_ms);
        self.wraps * WRAP_MS + raw_ms as u64
    }
}

/// One TM1 exchange: host time when sent and when the reply arrived, and the sensor's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeSample {
    pub sent_ns: u64,
    pub received_ns: u64,
    pub sensor_ms: u32,
}

impl TimeSample {
    pub fn round_trip_ns(&self) -> u64 {
        self.received_ns.saturating_sub(self.sent_ns)
    }
    /// Host time minus sensor time, taking the sensor's reading at the round trip's midpoint.
    fn offset_ns(&self) -> i128 {
        let mid = self.sent_ns as i128 + self.round_trip_ns() as i128 / 2;
        mid - self.sensor_ms as i128 * 1_000_000
    }
}

/// Result of a time sync.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyncResult {
    /// Host ns = sensor ms × 10^6 + offset (at the sync).
    pub offset_ns: i128,
    /// Samples kept after dropping slow round trips.
    pub used: usize,
    /// Median round trip of the kept samples.
    pub round_trip_ns: u64,
}

/// Median offset of the samples whose round trip is at most twice the fastest one (plus 1 ms,
/// for links that are all fast): a slow round trip says little about when the sensor read its
/// clock. `None` without samples.
pub fn sync(samples: &[TimeSample]) -> Option<SyncResult> {
    let fastest = samples.iter().map(TimeSample::round_trip_ns).min()?;
    let limit = fastest.saturating_mul(2).saturating_add(1_000_000);
    let mut kept: Vec<&TimeSample> = samples
        .iter()
        .filter(|s| s.round_trip_ns() <= limit)
        .collect();
    kept.sort_by_key(|s| s.offset_ns());
    let mid = kept.get(kept.len() / 2)?;
    let mut trips: Vec<u64> = kept.iter().map(|s| s.round_trip_ns()).collect();
    trips.sort_unstable();
    Some(SyncResult {
        offset_ns: mid.offset_ns(),
        used: kept.len(),
        round_trip_ns: trips.get(trips.len() / 2).copied().unwrap_or(0),
    })
}

/// Maps unwrapped sensor ms to host ns: starts from a TM1 sync and follows the sensor's drift
/// from the scans' arrival times. Transmission delay only ever makes a scan arrive later, so the
/// lower envelope of `arrival − sensor time` tracks the clock offset; its slope is the drift.
#[derive(Debug, Clone)]
pub struct ClockModel {
    /// Offset at `reference_ms`.
    offset_ns: i128,
    reference_ms: u64,
    /// Host ns per sensor ms, minus 10^6 (so 0 = no drift).
    drift_ns_per_ms: f64,
    /// Minimum `arrival − sensor` per window, for the slope.
    window_ms: u64,
    windows: Vec<(u64, i128)>,
}

/// Windows kept for the drift fit.
const DRIFT_WINDOWS: usize = 16;

impl ClockModel {
    pub fn new(sync: SyncResult, reference_ms: u64) -> Self {
        ClockModel {
            offset_ns: sync.offset_ns,
            reference_ms,
            drift_ns_per_ms: 0.0,
            window_ms: 10_000,
            windows: Vec::new(),
        }
    }

    /// Host time of a sensor time.
    pub fn host_ns(&self, sensor_ms: u64) -> i128 {
        let dt_ms = sensor_ms as f64 - self.reference_ms as f64;
        sensor_ms as i128 * 1_000_000 + self.offset_ns + (self.drift_ns_per_ms * dt_ms) as i128
    }

    /// Drift in parts per million (positive: the sensor clock runs slow); 1 ppm = 1 ns per ms.
    pub fn drift_ppm(&self) -> f64 {
        self.drift_ns_per_ms
    }

    /// Feeds a scan's sensor time and host arrival time.
    pub fn observe(&mut self, sensor_ms: u64, arrival_ns: u64) {
        let lag = arrival_ns as i128 - sensor_ms as i128 * 1_000_000;
        let window = sensor_ms / self.window_ms;
        match self.windows.last_mut() {
            Some((w, min)) if *w == window => *min = (*min).min(lag),
            _ => {
                self.windows.push((window, lag));
                if self.windows.len() > DRIFT_WINDOWS {
                    self.windows.remove(0);
                }
                self.refit();
            }
        }
    }

    /// Least-squares slope over the completed windows (all but the newest).
    fn refit(&mut self) {
        let done = self.windows.len().saturating_sub(1);
        let Some(points) = self.windows.get(..done) else {
            return;
        };
        if points.len() < 3 {
            return;
        }
        let n = points.len() as f64;
        let xs: Vec<f64> = points
            .iter()
            .map(|(w, _)| (*w * self.window_ms) as f64)
            .collect();
        let base = points.first().map_or(0, |p| p.1);
        let ys: Vec<f64> = points.iter().map(|(_, lag)| (*lag - base) as f64).collect();
        let mx = xs.iter().sum::<f64>() / n;
        let my = ys.iter().sum::<f64>() / n;
        let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
        if sxx <= 0.0 {
            return;
        }
        let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
        // Re-anchor so the mapping stays continuous at the current reference.
        let now_ms = xs.last().copied().unwrap_or(0.0) as u64;
        let before = self.host_ns(now_ms);
        self.drift_ns_per_ms = sxy / sxx;
        self.reference_ms = now_ms;
        self.offset_ns = before - now_ms as i128 * 1_000_000;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_are_unwrapped_and_jitter_is_not_a_wrap() {
        let mut u = Unwrapper::default();
        assert_eq!(u.unwrap(0xFF_FFF0), 0xFF_FFF0);
        assert_eq!(u.unwrap(0x00_0010), WRAP_MS + 0x10);
        assert_eq!(u.unwrap(0x00_0008), WRAP_MS + 0x08);
        assert_eq!(u.unwrap(0x00_0030), WRAP_MS + 0x30);
    }

    #[test]
    fn sync_takes_the_median_of_fast_round_trips() {
        // Sensor clock = host ms - 5000. Fast exchanges are symmetric; one is slow and skewed.
        let sample = |sent_ms: u64, trip_ms: u64, skew_ms: u64| TimeSample {
            sent_ns: sent_ms * 1_000_000,
            received_ns: (sent_ms + trip_ms) * 1_000_000,
            sensor_ms: (sent_ms + trip_ms / 2 + skew_ms - 5000) as u32,
        };
        let samples = [
            sample(10_000, 2, 0),
            sample(10_010, 2, 0),
            sample(10_020, 3, 1),
            sample(10_030, 400, 390),
        ];
        let result = sync(&samples).unwrap();
        assert_eq!(result.used, 3);
        assert!(
            (result.offset_ns - 5_000_000_000).abs() <= 1_000_000,
            "{result:?}"
        );
        assert_eq!(sync(&[]), None);
    }

    #[test]
    fn drift_is_followed_from_arrival_times() {
        // The sensor clock loses 100 ppm; arrivals lag by 1–4 ms of transmission jitter.
        let offset_ns: i128 = 1_700_000_000_000_000_000;
        let mut model = ClockModel::new(
            SyncResult {
                offset_ns,
                used: 10,
                round_trip_ns: 0,
            },
            0,
        );
        let mut last = 0;
        for i in 0..(200_000 / 25) {
            let host_ms = i * 25;
            let sensor_ms = host_ms - host_ms / 10_000; // 100 ppm slow
            let arrival =
                (offset_ns + host_ms as i128 * 1_000_000) as u64 + 1_000_000 + (i % 4) * 1_000_000;
            model.observe(sensor_ms, arrival);
            last = sensor_ms;
        }
        assert!(
            (model.drift_ppm() - 100.0).abs() < 5.0,
            "drift {}",
            model.drift_ppm()
        );
        let truth = offset_ns + (last + last / 9_999) as i128 * 1_000_000;
        let err_ms = (model.host_ns(last) - truth) as f64 / 1e6;
        assert!(err_ms.abs() < 3.0, "error {err_ms} ms");
    }
}
