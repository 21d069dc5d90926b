//! Summary figures of one sensor's scans, for `scanfuse info`: counts, rate, gaps.

use crate::scan::{Scan, SensorInfo};

/// A pause in a sensor's stream longer than [`GAP_FACTOR`] scan periods.
#[derive(Debug, Clone, PartialEq)]
pub struct Gap {
    /// Stamp of the last scan before the gap, ns.
    pub after_ns: u64,
    pub length_s: f64,
}

/// An interval this many times the expected period is a gap (one lost scan doubles it).
pub const GAP_FACTOR: f64 = 1.5;

#[derive(Debug, Clone, PartialEq)]
pub struct SensorStats {
    pub scans: usize,
    pub first_ns: Option<u64>,
    pub last_ns: Option<u64>,
    /// Scans per second over the stream.
    pub rate_hz: Option<f64>,
    /// Rate the sensor's PP `SCAN` promises.
    pub nominal_hz: Option<f64>,
    pub gaps: Vec<Gap>,
    /// Scans stamped earlier than the scan before them.
    pub backwards: usize,
    /// Fewest and most ranges in one scan.
    pub ranges_per_scan: Option<(usize, usize)>,
    /// Share of all ranges that are real returns.
    pub return_fraction: f64,
    pub with_intensities: usize,
}

impl SensorStats {
    pub fn duration_s(&self) -> f64 {
        match (self.first_ns, self.last_ns) {
            (Some(a), Some(b)) if b > a => (b - a) as f64 * 1e-9,
            _ => 0.0,
        }
    }
}

pub fn sensor_stats(sensor: &SensorInfo, scans: &[Scan]) -> SensorStats {
    let nominal_hz = sensor.geometry.map(|g| 1.0 / g.period_s());
    let first_ns = scans.iter().map(|s| s.stamp_ns).min();
    let last_ns = scans.iter().map(|s| s.stamp_ns).max();
    let intervals: Vec<(u64, f64)> = scans
        .windows(2)
        .map(|w| {
            (
                w[0].stamp_ns,
                w[1].stamp_ns as f64 * 1e-9 - w[0].stamp_ns as f64 * 1e-9,
            )
        })
        .collect();
    let backwards = intervals.iter().filter(|(_, dt)| *dt < 0.0).count();
    // Without PP the expected period is the median interval.
    let period_s = nominal_hz.map(|hz| 1.0 / hz).or_else(|| {
        let mut dts: Vec<f64> = intervals
            .iter()
            .map(|(_, dt)| *dt)
            .filter(|dt| *dt > 0.0)
            .collect();
        dts.sort_by(f64::total_cmp);
        dts.get(dts.len() / 2).copied()
    });
    let gaps = match period_s {
        Some(period) => intervals
            .iter()
            .filter(|(_, dt)| *dt > GAP_FACTOR * period)
            .map(|(after_ns, dt)| Gap {
                after_ns: *after_ns,
                length_s: *dt,
            })
            .collect(),
        None => Vec::new(),
    };
    let rate_hz = match (first_ns, last_ns) {
        (Some(a), Some(b)) if b > a && scans.len() > 1 => {
            Some((scans.len() - 1) as f64 / ((b - a) as f64 * 1e-9))
        }
        _ => None,
    };
    let lens = scans.iter().map(|s| s.ranges_m.len());
    let ranges_per_scan = lens.clone().min().zip(lens.clone().max());
    let total: usize = lens.sum();
    let returns: usize = scans
        .iter()
        .map(|s| (0..s.ranges_m.len()).filter(|i| s.is_return(*i)).count())
        .sum();
    SensorStats {
        scans: scans.len(),
        first_ns,
        last_ns,
        rate_hz,
        nominal_hz,
        gaps,
        backwards,
        ranges_per_scan,
        return_fraction: if total > 0 {
            returns as f64 / total as f64
        } else {
            0.0
        },
        with_intensities: scans.iter().filter(|s| !s.intensities.is_empty()).count(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::ScanGeometry;

    fn scan(stamp_ms: u64) -> Scan {
        Scan {
            stamp_ns: stamp_ms * 1_000_000,
            sensor_stamp_ms: None,
            start_angle_rad: -1.0,
            end_angle_rad: 1.0,
            ranges_m: vec![1.0, 0.0, f32::NAN, 2.0],
            intensities: vec![],
        }
    }

    #[test]
    fn finds_gaps_rate_and_backward_stamps() {
        let mut sensor = SensorInfo::new("a", "UTM-30LX-EW");
        sensor.geometry = Some(ScanGeometry::UTM_30LX_EW);
        let stamps = [0, 25, 50, 125, 150, 140, 175];
        let scans: Vec<Scan> = stamps.iter().map(|ms| scan(*ms)).collect();
        let st = sensor_stats(&sensor, &scans);
        assert_eq!(st.scans, 7);
        assert_eq!(st.gaps.len(), 1);
        assert_eq!(st.gaps[0].after_ns, 50_000_000);
        assert!((st.gaps[0].length_s - 0.075).abs() < 1e-9);
        assert_eq!(st.backwards, 1);
        assert!((st.duration_s() - 0.175).abs() < 1e-9);
        assert!((st.rate_hz.unwrap() - 6.0 / 0.175).abs() < 1e-6);
        assert_eq!(st.nominal_hz, Some(40.0));
        assert_eq!(st.return_fraction, 0.5);
    }

    #[test]
    fn empty_streams_have_no_rate() {
        let st = sensor_stats(&SensorInfo::new("a", ""), &[]);
        assert_eq!((st.scans, st.rate_hz, st.ranges_per_scan), (0, None, None));
    }
}
