//! Refinement (METHOD §5): point-to-line ICP with a Huber kernel. With classes on (seed 002),
//! a correspondence is the candidate minimising d²/s² + λ·[class differs] among the nearest
//! point and its scan neighbours; with classes off, the same candidates by distance alone.

use super::{RegisterParams, ScanModel};
use crate::geometry::{Pose2, pose2};
use nalgebra::{Matrix3, Vector3};

/// Scan neighbours of the grid's nearest point considered as correspondences.
const NEIGHBOURS: usize = 6;

/// The refined pose and what the last linearisation says about it.
#[derive(Debug, Clone, PartialEq)]
pub struct IcpResult {
    pub a_from_b: Pose2,
    pub iterations: usize,
    /// Weighted normal matrix JᵀWJ over (x, y, yaw) at the result.
    pub hessian: Matrix3<f64>,
    /// Weighted RMS of the point-to-line residuals (m).
    pub rms_m: f64,
    pub correspondences: usize,
}

/// Refines `a_from_b` from `init` by aligning B's ICP sample onto A's lines.
pub fn refine(
    a: &ScanModel,
    b: &ScanModel,
    init: &Pose2,
    p: &RegisterParams,
    class_aware: bool,
) -> IcpResult {
    let mut pose = *init;
    let a_pts = a.points();
    let b_pts = b.points();
    let scale2 = p.class_scale_m * p.class_scale_m;
    let mut result = IcpResult {
        a_from_b: pose,
        iterations: 0,
        hessian: Matrix3::zeros(),
        rms_m: f64::INFINITY,
        correspondences: 0,
    };
    for iteration in 1..=p.icp_max_iterations {
        let mut h = Matrix3::zeros();
        let mut g = Vector3::zeros();
        let (mut sum_wr2, mut sum_w, mut used) = (0.0, 0.0, 0usize);
        for &i in &b.icp_sample {
            let q = pose * b_pts[i];
            let Some(j0) = a.grid.nearest(&q) else {
                continue;
            };
            let class_b = b.class(i);
            let cost = |j: usize| {
                let d2 = (q - a_pts[j]).norm_squared() / scale2;
                if class_aware && a.class(j) != class_b {
                    d2 + p.class_weight
                } else {
                    d2
                }
            };
            let lo = j0.saturating_sub(NEIGHBOURS);
            let hi = (j0 + NEIGHBOURS).min(a_pts.len() - 1);
            let j = (lo..=hi)
                .min_by(|&x, &y| cost(x).total_cmp(&cost(y)))
                .unwrap_or(j0);
            let d = q - a_pts[j];
            if d.norm() > p.max_correspondence_m {
                continue;
            }
            let n = a.normals[j];
            let r = n.dot(&d);
            let w = if r.abs() <= p.huber_m {
                1.0
            } else {
                p.huber_m / r.abs()
            };
            let jac = Vector3::new(n.x, n.y, n.x * -q.y + n.y * q.x);
            h += w * jac * jac.transpose();
            g += w * jac * r;
            sum_wr2 += w * r * r;
            sum_w += w;
            used += 1;
        }
        result = IcpResult {
            a_from_b: pose,
            iterations: iteration,
            hessian: h,
            rms_m: if sum_w > 0.0 {
                (sum_wr2 / sum_w).sqrt()
            } else {
                f64::INFINITY
            },
            correspondences: used,
        };
        if used < 10 {
            break;
        }
        let Some(step) = (h + Matrix3::identity() * 1e-9).lu().solve(&(-g)) else {
            break;
        };
        // The increment acts in A's frame: q' = R(δθ)·q + δt.
        pose = pose2(step.x, step.y, step.z) * pose;
        result.a_from_b = pose;
        if step.x.hypot(step.y) < 1e-4 && step.z.abs() < 1e-5 {
            break;
        }
    }
    result
}
