//! A minimal 2D ray caster against wall segments: synthetic scans for tests and evaluation of
//! the features and registration stages without the full simulator.

use super::Pose2;
use nalgebra::{Point2, Vector2};

/// A wall from `a` to `b`, site frame, m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wall {
    pub a: Point2<f64>,
    pub b: Point2<f64>,
}

impl Wall {
    pub fn new(ax: f64, ay: f64, bx: f64, by: f64) -> Self {
        Wall {
            a: Point2::new(ax, ay),
            b: Point2::new(bx, by),
        }
    }
}

/// The closed outline through `corners` as walls.
pub fn polygon(corners: &[(f64, f64)]) -> Vec<Wall> {
    (0..corners.len())
        .map(|i| {
            let (ax, ay) = corners[i];
            let (bx, by) = corners[(i + 1) % corners.len()];
            Wall::new(ax, ay, bx, by)
        })
        .collect()
}

/// Distance along the ray from `origin` in direction `dir` (unit) to the nearest wall.
pub fn cast(walls: &[Wall], origin: Point2<f64>, dir: Vector2<f64>) -> Option<f64> {
    let mut best: Option<f64> = None;
    for w in walls {
        let e = w.b - w.a;
        let denom = dir.perp(&e);
        if denom.abs() < 1e-12 {
            continue;
        }
        let d = w.a - origin;
        let t = d.perp(&e) / denom;
        let u = d.perp(&dir) / denom;
        if t > 1e-9 && (-1e-9..=1.0 + 1e-9).contains(&u) && best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    }
    best
}

/// Ranges seen by a sensor at `site_from_sensor` along `angles_rad` (sensor frame); 0 = no
/// return within `max_range_m`.
pub fn scan_ranges(
    walls: &[Wall],
    site_from_sensor: &Pose2,
    angles_rad: &[f64],
    max_range_m: f64,
) -> Vec<f32> {
    let origin = Point2::from(site_from_sensor.translation.vector);
    angles_rad
        .iter()
        .map(|&a| {
            let dir = site_from_sensor.rotation * Vector2::new(a.cos(), a.sin());
            match cast(walls, origin, dir) {
                Some(t) if t < max_range_m => t as f32,
                _ => 0.0,
            }
        })
        .collect()
}

/// A 270° scan of `walls` from `site_from_sensor` at `step_deg` steps, stamped `t_ns`, every
/// range returned: what the unit tests of motion, walkers and tracking look at.
#[cfg(test)]
pub(crate) fn scan_270(
    walls: &[Wall],
    site_from_sensor: &Pose2,
    step_deg: f64,
    t_ns: u64,
) -> crate::scan::Scan {
    let (start, step) = (-135f64.to_radians(), step_deg.to_radians());
    let n = (270.0 / step_deg).round() as usize + 1;
    let angles: Vec<f64> = (0..n).map(|k| start + step * k as f64).collect();
    crate::scan::Scan {
        stamp_ns: t_ns,
        sensor_stamp_ms: None,
        start_angle_rad: start,
        end_angle_rad: start + step * (n - 1) as f64,
        ranges_m: scan_ranges(walls, site_from_sensor, &angles, f64::INFINITY),
        intensities: vec![],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;

    #[test]
    fn square_room_ranges_from_centre() {
        let walls = polygon(&[(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)]);
        let angles = [0.0, std::f64::consts::FRAC_PI_4, std::f64::consts::PI];
        let r = scan_ranges(&walls, &pose2(0.0, 0.0, 0.0), &angles, 30.0);
        assert!((r[0] - 2.0).abs() < 1e-6);
        assert!((r[1] as f64 - 8f64.sqrt()).abs() < 1e-5);
        assert!((r[2] - 2.0).abs() < 1e-6);
        let r = scan_ranges(
            &walls,
            &pose2(1.0, 0.0, std::f64::consts::PI),
            &angles,
            30.0,
        );
        assert!(
            (r[0] - 3.0).abs() < 1e-6,
            "facing -x from x=1 sees the wall at 3 m"
        );
    }
}
