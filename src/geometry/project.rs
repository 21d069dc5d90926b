//! Scan → points (METHOD §1): exact SCIP step angles when the sensor's PP layout is known,
//! otherwise the scan's own start/end angles; tilted-mount projection and floor-hit removal.

use std::cell::RefCell;
use std::sync::Arc;

use super::tables::Tables;
use crate::scan::{Scan, ScanGeometry};
use nalgebra::Point2;

/// How a sensor is mounted: height of its optical centre above the floor and pitch of its scan
/// plane (positive up). Unknown height means floor hits cannot be told apart and are kept.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Mount {
    pub height_m: Option<f64>,
    pub pitch_rad: f64,
}

/// Limits for turning ranges into points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectParams {
    /// Returns farther than this are dropped: sparse, noisy and rarely shared (m).
    pub max_range_m: f64,
    /// A hit this close to the floor (z below it) on a tilted mount is floor, not wall (m).
    pub floor_margin_m: f64,
}

impl Default for ProjectParams {
    fn default() -> Self {
        ProjectParams {
            max_range_m: 30.0,
            floor_margin_m: 0.10,
        }
    }
}

/// One return, projected into the horizontal plane of the sensor frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPoint {
    /// Horizontal position in the sensor frame, m.
    pub p: Point2<f64>,
    /// Index of the beam in the scan (scan order).
    pub beam: usize,
    /// Height above the floor when the mount height is known, m.
    pub z_m: Option<f64>,
}

/// Direction of every range of `scan` in the sensor frame, rad.
///
/// With the PP layout, the beams are the SCIP steps starting at the one nearest the scan's
/// start angle, `(s − AFRT)·2π/ARES` exactly; the layout is used only when the scan's end angle
/// agrees with it to within half a step (otherwise the scan is not from that layout).
pub fn beam_angles_rad(scan: &Scan, geometry: Option<&ScanGeometry>) -> Vec<f64> {
    let n = scan.ranges_m.len();
    if let Some(g) = geometry.filter(|g| g.ares > 0) {
        let first = g.step_of_angle(scan.start_angle_rad);
        let step = g.step_rad();
        let last_angle = (first + n as i64 - 1 - g.afrt as i64) as f64 * step;
        let first_angle = (first - g.afrt as i64) as f64 * step;
        if n >= 2
            && (last_angle - scan.end_angle_rad).abs() < 0.5 * step
            && (first_angle - scan.start_angle_rad).abs() < 0.5 * step
        {
            return (0..n)
                .map(|i| (first + i as i64 - g.afrt as i64) as f64 * step)
                .collect();
        }
    }
    (0..n).map(|i| scan.angle_of_index_rad(i)).collect()
}

/// `sin_cos` of every beam's direction ([`beam_angles_rad`]). A site's scans share a few
/// layouts, and the sines were a quarter of the daemon's CPU at 100 sensors, so each thread
/// keeps the tables of the last [`LAYOUTS`] layouts it met: the same numbers, computed once.
pub fn beam_directions(scan: &Scan, geometry: Option<&ScanGeometry>) -> Directions {
    type Key = (usize, u64, u64, Option<(u32, u32)>);
    thread_local! {
        static TABLES: RefCell<Tables<Key, Directions>> = const { RefCell::new(Tables::new(LAYOUTS)) };
    }
    let key: Key = (
        scan.ranges_m.len(),
        scan.start_angle_rad.to_bits(),
        scan.end_angle_rad.to_bits(),
        geometry.map(|g| (g.ares, g.afrt)),
    );
    TABLES.with_borrow_mut(|tables| {
        tables.get(key, || {
            beam_angles_rad(scan, geometry)
                .into_iter()
                .map(f64::sin_cos)
                .collect()
        })
    })
}

/// `(sin, cos)` of each beam's direction, in scan order.
pub type Directions = Arc<[(f64, f64)]>;

/// Beam layouts whose direction tables a thread keeps.
const LAYOUTS: usize = 8;

/// Projects a scan's returns into the sensor's horizontal plane (eq. 16): x = d cosθ cosφ,
/// y = d sinθ, z = h + d cosθ sinφ. Ranges outside the layout's DMIN..DMAX (or past
/// `max_range_m`) are "no return"; on a known-height tilted mount, hits with z below
/// `floor_margin_m` are floor and dropped.
pub fn project_scan(
    scan: &Scan,
    geometry: Option<&ScanGeometry>,
    mount: &Mount,
    params: &ProjectParams,
) -> Vec<ScanPoint> {
    let directions = beam_directions(scan, geometry);
    let (dmin_m, mut dmax_m) = match geometry {
        Some(g) => (g.dmin_mm as f64 / 1000.0, g.dmax_mm as f64 / 1000.0),
        None => (0.0, f64::INFINITY),
    };
    dmax_m = dmax_m.min(params.max_range_m);
    let (sin_pitch, cos_pitch) = mount.pitch_rad.sin_cos();
    scan.ranges_m
        .iter()
        .zip(directions.iter())
        .enumerate()
        .filter_map(|(beam, (&range, &(s, c)))| {
            let d = range as f64;
            if !d.is_finite() || d <= 0.0 || d < dmin_m || d >= dmax_m {
                return None;
            }
            let z_m = mount.height_m.map(|h| h + d * c * sin_pitch);
            if mount.pitch_rad != 0.0 && z_m.is_some_and(|z| z < params.floor_margin_m) {
                return None;
            }
            Some(ScanPoint {
                p: Point2::new(d * c * cos_pitch, d * s),
                beam,
                z_m,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn scan_with(ranges_m: Vec<f32>, start: f64, end: f64) -> Scan {
        Scan {
            stamp_ns: 0,
            sensor_stamp_ms: None,
            start_angle_rad: start,
            end_angle_rad: end,
            ranges_m,
            intensities: vec![],
        }
    }

    #[test]
    fn utm_layout_gives_exact_step_angles() {
        let g = ScanGeometry::UTM_30LX_EW;
        let n = g.step_count();
        // A start/end pair rounded the way a float32 LaserScan would carry them.
        let start = g.angle_of_step_rad(g.amin) as f32 as f64;
        let end = g.angle_of_step_rad(g.amax) as f32 as f64;
        let scan = scan_with(vec![1.0; n], start, end);
        let angles = beam_angles_rad(&scan, Some(&g));
        assert_eq!(angles.len(), n);
        for (i, a) in angles.iter().enumerate() {
            assert_eq!(*a, g.angle_of_step_rad(g.amin + i as u32));
        }
    }

    #[test]
    fn each_layout_gets_its_own_direction_table_however_many_pass_through() {
        let g = ScanGeometry::UTM_30LX_EW;
        let utm = scan_with(
            vec![1.0; g.step_count()],
            g.angle_of_step_rad(g.amin),
            g.angle_of_step_rad(g.amax),
        );
        // More layouts than a thread keeps, interleaved with the UTM's: every answer is still
        // its own layout's.
        for k in 0..3 * LAYOUTS {
            let other = scan_with(vec![1.0; 91 + k], -1.0 - 0.01 * k as f64, 1.0);
            for (scan, geometry) in [(&utm, Some(&g)), (&other, None), (&other, Some(&g))] {
                let want: Vec<(f64, f64)> = beam_angles_rad(scan, geometry)
                    .into_iter()
                    .map(f64::sin_cos)
                    .collect();
                assert_eq!(*beam_directions(scan, geometry), *want);
            }
        }
    }

    #[test]
    fn scan_that_does_not_fit_layout_uses_its_own_angles() {
        let g = ScanGeometry::UTM_30LX_EW;
        let scan = scan_with(
            vec![1.0; 181],
            -std::f64::consts::FRAC_PI_2,
            std::f64::consts::FRAC_PI_2,
        );
        let angles = beam_angles_rad(&scan, Some(&g));
        assert!((angles[90]).abs() < 1e-12);
        assert!((angles[180] - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn invalid_and_out_of_range_returns_are_not_points() {
        let g = ScanGeometry::UXM_30LX_E;
        let mut ranges = vec![2.0f32; g.step_count()];
        ranges[0] = 0.0;
        ranges[1] = f32::NAN;
        ranges[2] = 0.05; // below DMIN 100 mm
        ranges[3] = 45.0; // past max_range_m
        let scan = scan_with(
            ranges,
            g.angle_of_step_rad(g.amin),
            g.angle_of_step_rad(g.amax),
        );
        let points = project_scan(
            &scan,
            Some(&g),
            &Mount::default(),
            &ProjectParams::default(),
        );
        assert_eq!(points.len(), g.step_count() - 4);
        assert_eq!(points[0].beam, 4);
    }

    #[test]
    fn tilted_down_mount_drops_floor_hits() {
        // 0.5 m high, pitched 30° down: a beam straight ahead meets the floor at d = 1 m.
        let mount = Mount {
            height_m: Some(0.5),
            pitch_rad: -30f64.to_radians(),
        };
        let scan = scan_with(vec![1.0, 0.6], 0.0, 0.0);
        let points = project_scan(&scan, None, &mount, &ProjectParams::default());
        assert_eq!(
            points.len(),
            1,
            "the floor hit at 1 m must go, the wall hit at 0.6 m stays"
        );
        assert!((points[0].p.x - 0.6f32 as f64 * 30f64.to_radians().cos()).abs() < 1e-9);
    }

    proptest! {
        #[test]
        fn level_projection_keeps_range_and_bearing(
            d in 0.2f64..29.0, i in 0usize..1081,
        ) {
            let g = ScanGeometry::UTM_30LX_EW;
            let mut ranges = vec![0.0f32; g.step_count()];
            ranges[i] = d as f32;
            let scan = scan_with(ranges, g.angle_of_step_rad(g.amin), g.angle_of_step_rad(g.amax));
            let points = project_scan(&scan, Some(&g), &Mount::default(), &ProjectParams::default());
            prop_assert_eq!(points.len(), 1);
            let p = points[0].p;
            prop_assert!((p.coords.norm() - d as f32 as f64).abs() < 1e-9);
            let bearing = p.y.atan2(p.x);
            prop_assert!((crate::geometry::wrap_angle_rad(bearing - g.angle_of_step_rad(i as u32))).abs() < 1e-9);
        }

        #[test]
        fn tilted_projection_shrinks_only_forward_component(
            d in 0.5f64..20.0, angle in -2.3f64..2.3, pitch in 0.0f64..1.0,
        ) {
            let mount = Mount { height_m: Some(1.0), pitch_rad: pitch };
            // Backward beams on an upward tilt go down to the floor; those are dropped above.
            prop_assume!(1.0 + d * angle.cos() * pitch.sin() > 0.2);
            let scan = scan_with(vec![d as f32], angle, angle);
            let points = project_scan(&scan, None, &mount, &ProjectParams::default());
            prop_assert_eq!(points.len(), 1);
            let d = d as f32 as f64;
            prop_assert!((points[0].p.x - d * angle.cos() * pitch.cos()).abs() < 1e-9);
            prop_assert!((points[0].p.y - d * angle.sin()).abs() < 1e-9);
            let z = points[0].z_m.unwrap_or(f64::NAN);
            prop_assert!((z - 1.0 - d * angle.cos() * pitch.sin()).abs() < 1e-9);
        }
    }
}
