//! Poses, scan-to-point projection and a minimal ray caster: the small shared math of
//! registration. Pure: values in, values out.

pub mod pose;
pub mod project;
pub mod raycast;
pub mod tables;

pub use pose::{
    Pose2, Pose3, pose_delta, pose_error, pose_step, pose2, within_sigma, wrap_angle_rad, yaw_rad,
};
pub use project::{Mount, ProjectParams, ScanPoint, beam_angles_rad, project_scan};
