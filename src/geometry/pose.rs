//! 2D and 3D sensor poses on nalgebra. A pose is named for what it maps: `a_from_b` takes
//! points in B's frame to A's frame, so `site_from_b = site_from_a * a_from_b` checks itself.

use nalgebra::{Isometry2, Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use std::f64::consts::{PI, TAU};

/// A planar rigid transform (x, y, yaw).
pub type Pose2 = Isometry2<f64>;

/// The pose with translation (`x_m`, `y_m`) and heading `yaw_rad`.
pub fn pose2(x_m: f64, y_m: f64, yaw_rad: f64) -> Pose2 {
    Isometry2::new(Vector2::new(x_m, y_m), yaw_rad)
}

/// The heading of a pose in (−π, π].
pub fn yaw_rad(pose: &Pose2) -> f64 {
    pose.rotation.angle()
}

/// An angle folded into (−π, π].
pub fn wrap_angle_rad(angle_rad: f64) -> f64 {
    let mut a = angle_rad.rem_euclid(TAU);
    if a > PI {
        a -= TAU;
    }
    a
}

/// Translation and heading difference between two poses of the same thing, (m, rad ≥ 0).
pub fn pose_error(estimate: &Pose2, truth: &Pose2) -> (f64, f64) {
    let dt = (estimate.translation.vector - truth.translation.vector).norm();
    let dyaw = wrap_angle_rad(yaw_rad(estimate) - yaw_rad(truth)).abs();
    (dt, dyaw)
}

/// `to`'s (x, y, yaw) minus `from`'s, the heading folded into (−π, π]: a step in the
/// parameters a pose's (x, y, yaw) covariance is of.
pub fn pose_delta(from: &Pose2, to: &Pose2) -> Vector3<f64> {
    let d = to.translation.vector - from.translation.vector;
    Vector3::new(d.x, d.y, wrap_angle_rad(yaw_rad(to) - yaw_rad(from)))
}

/// `from` moved by `step` in its (x, y, yaw): what [`pose_delta`] measures, applied.
pub fn pose_step(from: &Pose2, step: &Vector3<f64>) -> Pose2 {
    let t = from.translation.vector;
    pose2(t.x + step.x, t.y + step.y, yaw_rad(from) + step.z)
}

/// Whether a pose error (m, rad, as [`pose_error`] gives it) lies within `k` σ of what was
/// claimed for the pose: σ of x and y (m) and of the heading (rad). Beyond, the claim was
/// wrong, not just imprecise (what the zones' eval and bench count).
pub fn within_sigma(error: (f64, f64), sigma_xy_m: [f64; 2], sigma_yaw_rad: f64, k: f64) -> bool {
    error.0 <= k * sigma_xy_m[0].hypot(sigma_xy_m[1]) && error.1 <= k * sigma_yaw_rad
}

/// A sensor pose in 3D as the site reports it: position, height, heading and pitch
/// (pitch about the sensor's own y axis, positive up; no roll).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose3 {
    pub x_m: f64,
    pub y_m: f64,
    pub z_m: f64,
    pub yaw_rad: f64,
    pub pitch_rad: f64,
}

impl Pose3 {
    /// Lifts a planar pose with a height and a pitch.
    pub fn from_planar(pose: &Pose2, z_m: f64, pitch_rad: f64) -> Self {
        Pose3 {
            x_m: pose.translation.x,
            y_m: pose.translation.y,
            z_m,
            yaw_rad: yaw_rad(pose),
            pitch_rad,
        }
    }

    /// The planar part.
    pub fn planar(&self) -> Pose2 {
        pose2(self.x_m, self.y_m, self.yaw_rad)
    }

    /// The rigid transform: yaw about z, then pitch about the rotated y axis. The sensor
    /// convention is pitch positive *up*, which is a negative rotation about +y.
    pub fn isometry(&self) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw_rad)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -self.pitch_rad);
        Isometry3::from_parts(Translation3::new(self.x_m, self.y_m, self.z_m), rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point2;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn wrap_stays_in_half_open_interval_and_keeps_direction(a in -50.0f64..50.0) {
            let w = wrap_angle_rad(a);
            prop_assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
            prop_assert!((w.cos() - a.cos()).abs() < 1e-9 && (w.sin() - a.sin()).abs() < 1e-9);
        }

        #[test]
        fn composition_reads_right_to_left(
            x1 in -20.0f64..20.0, y1 in -20.0f64..20.0, t1 in -3.1f64..3.1,
            x2 in -20.0f64..20.0, y2 in -20.0f64..20.0, t2 in -3.1f64..3.1,
            px in -10.0f64..10.0, py in -10.0f64..10.0,
        ) {
            let site_from_a = pose2(x1, y1, t1);
            let a_from_b = pose2(x2, y2, t2);
            let p_b = Point2::new(px, py);
            let direct = site_from_a * (a_from_b * p_b);
            let composed = (site_from_a * a_from_b) * p_b;
            prop_assert!((direct - composed).norm() < 1e-9);
            let back = a_from_b.inverse() * (a_from_b * p_b);
            prop_assert!((back - p_b).norm() < 1e-9);
            let (dt, dyaw) = pose_error(&(site_from_a * a_from_b), &(site_from_a * a_from_b));
            prop_assert!(dt < 1e-9 && dyaw < 1e-9);
        }

        #[test]
        fn pose3_keeps_planar_part_and_pitches_forward_axis_up(
            x in -5.0f64..5.0, y in -5.0f64..5.0, z in 0.0f64..3.0,
            yaw in -3.1f64..3.1, pitch in -1.2f64..1.2,
        ) {
            let pose = Pose3 { x_m: x, y_m: y, z_m: z, yaw_rad: yaw, pitch_rad: pitch };
            let planar = pose.planar();
            prop_assert!(pose_error(&planar, &pose2(x, y, yaw)).0 < 1e-12);
            let forward = pose.isometry() * nalgebra::Point3::new(1.0, 0.0, 0.0);
            prop_assert!((forward.z - z - pitch.sin()).abs() < 1e-9);
        }
    }

    #[test]
    fn an_error_within_3_sigma_of_both_position_and_heading_is_within() {
        // σ 3 cm × 4 cm (5 cm together) and 0.1°.
        let (sigma, yaw) = ([0.03, 0.04], 0.1f64.to_radians());
        assert!(within_sigma((0.14, 0.25f64.to_radians()), sigma, yaw, 3.0));
        assert!(!within_sigma((0.16, 0.25f64.to_radians()), sigma, yaw, 3.0));
        assert!(!within_sigma((0.14, 0.35f64.to_radians()), sigma, yaw, 3.0));
    }
}
