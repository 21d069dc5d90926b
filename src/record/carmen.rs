//! CARMEN text logs (gzip), as the Radish "corrected" datasets ship them: one
//! `FLASER n r_1 … r_n x y theta …` line per 180° front-laser scan, with the SLAM-corrected
//! robot pose. scanfuse reads them for evaluation against real laser data: each scan with the
//! laser's pose in the log's frame as the truth.

use super::RecordError;
use crate::geometry::{Pose2, pose2};
use crate::scan::Scan;
use std::io::{BufRead, BufReader};
use std::path::Path;

/// One front-laser scan and where the laser stood (site frame of the log).
#[derive(Debug, Clone)]
pub struct LogScan {
    pub scan: Scan,
    pub site_from_laser: Pose2,
}

/// Reads every `FLASER` line of a gzipped CARMEN log. `PARAM robot_frontlaser_offset` (the
/// laser's distance ahead of the robot's centre) is applied where the log gives it.
pub fn load(path: &Path) -> Result<Vec<LogScan>, RecordError> {
    let invalid = |line: usize, what: &str| RecordError::Invalid {
        path: path.to_path_buf(),
        what: format!("line {line}: {what}"),
    };
    let file = std::fs::File::open(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let reader = BufReader::new(flate2::read::GzDecoder::new(file));
    let mut offset_m = 0.0;
    let mut out = Vec::new();
    for (n, line) in reader.lines().enumerate() {
        let line = line.map_err(|source| RecordError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut words = line.split_whitespace();
        match words.next() {
            Some("PARAM") if words.next() == Some("robot_frontlaser_offset") => {
                offset_m = words
                    .next()
                    .and_then(|w| w.parse::<f64>().ok())
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| invalid(n + 1, "robot_frontlaser_offset is not a number"))?;
            }
            Some("FLASER") => {
                let bad = || invalid(n + 1, "malformed FLASER (count, ranges, x y theta)");
                let count: usize = words.next().and_then(|w| w.parse().ok()).ok_or_else(bad)?;
                if count < 2 {
                    return Err(bad());
                }
                // Ranges and the corrected pose; the host name and stamps after them are not
                // needed.
                let values: Vec<f64> = words
                    .take(count + 3)
                    .map(|w| w.parse::<f64>().ok().filter(|v| v.is_finite()))
                    .collect::<Option<_>>()
                    .ok_or_else(bad)?;
                let (Some(ranges), Some(&[x, y, theta])) =
                    (values.get(..count), values.get(count..count + 3))
                else {
                    return Err(bad());
                };
                out.push(LogScan {
                    scan: flaser_scan(ranges),
                    site_from_laser: pose2(x, y, theta) * pose2(offset_m, 0.0, 0.0),
                });
            }
            _ => {}
        }
    }
    Ok(out)
}

/// A FLASER line's ranges as a scan. Beam angles: the first beam at −90°, 180°/n apart for 180
/// or 360 beams and 180°/(n − 1) for 181 or 361. The corrected poses support this over the
/// alternatives: refining 150 high-overlap pairs per log from the truth with both-way ICP, a
/// start angle off by δ turns the found translation by ≈ δ about A (the residual itself does
/// not tell them apart). With this rule the turn is −0.02° (intel), +0.08° (aces), −0.04°
/// (fr079), −0.11° (csail); CARMEN's own centred guess (−89.5° … +89.5°) gives +0.47°, +0.58°,
/// +0.21°, and 180°/(n − 1) for 180 beams +0.41°, +0.59°, +0.20°. Heading bias and residual
/// are the same under all three (±0.05°, ±0.01 cm).
fn flaser_scan(ranges: &[f64]) -> Scan {
    let count = ranges.len();
    let half = std::f64::consts::FRAC_PI_2;
    let step = if count % 2 == 1 {
        2.0 * half / (count - 1) as f64
    } else {
        2.0 * half / count as f64
    };
    Scan {
        stamp_ns: 0,
        sensor_stamp_ms: None,
        start_angle_rad: -half,
        end_angle_rad: -half + step * (count - 1) as f64,
        ranges_m: ranges.iter().map(|&r| r as f32).collect(),
        intensities: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn gz(text: &str) -> tempfile::NamedTempFile {
        let f = tempfile::NamedTempFile::new().unwrap();
        let mut enc = flate2::write::GzEncoder::new(f.reopen().unwrap(), Default::default());
        enc.write_all(text.as_bytes()).unwrap();
        enc.finish().unwrap();
        f
    }

    #[test]
    fn reads_flaser_lines_and_applies_the_laser_offset() {
        let f = gz("PARAM robot_frontlaser_offset 0.5\n\
                    ODOM 1 2 3 0 0 0 1.0 host 1.0\n\
                    FLASER 3 1.0 2.0 3.0 10.0 20.0 1.5707963267948966 0 0 0 0 0 0 1.0 host 1.0\n");
        let scans = load(f.path()).unwrap();
        assert_eq!(scans.len(), 1);
        let s = &scans[0];
        assert_eq!(s.scan.ranges_m, vec![1.0, 2.0, 3.0]);
        // 3 beams: odd count, 90° apart, from −90° to +90°.
        assert!((s.scan.start_angle_rad + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((s.scan.end_angle_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // The robot faces +y, so the laser 0.5 m ahead of it stands at (10, 20.5).
        let t = s.site_from_laser.translation.vector;
        assert!(
            (t.x - 10.0).abs() < 1e-9 && (t.y - 20.5).abs() < 1e-9,
            "{t:?}"
        );
    }

    #[test]
    fn a_truncated_flaser_line_is_an_error_naming_file_and_line() {
        let f = gz("FLASER 180 1.0 2.0\n");
        let e = load(f.path()).unwrap_err().to_string();
        assert!(e.contains(&f.path().display().to_string()), "{e}");
        assert!(e.contains("line 1") && e.contains("FLASER"), "{e}");
    }

    #[test]
    fn a_non_numeric_range_is_an_error() {
        let f = gz("\nFLASER 2 1.0 abc 0 0 0\n");
        let e = load(f.path()).unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }
}
