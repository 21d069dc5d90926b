//! The solve: which edges enter it (checked edges that agree with where the site put their
//! sensors, and every other placed pair's agreeing candidate), and the joint weighted least
//! squares over them (anchor fixed, surveys as priors) with each pose's σ.

use super::groups::Checked;
use super::{Edge, Prior, SiteParams, candidate_edge};
use crate::geometry::{Pose2, pose_delta, pose_error, pose2, wrap_angle_rad, yaw_rad};
use crate::register::{PairResult, RegisterParams};
use nalgebra::{DMatrix, DVector, Matrix3};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

/// The solve's edges and, per edge, its (pair, candidate).
#[allow(clippy::type_complexity)]
pub(super) fn solve_edges(
    placed: &[Option<Pose2>],
    checked: &Checked,
    pairs: &[(usize, usize)],
    results: &[PairResult],
    join_sources: &[(usize, usize)],
    p: &RegisterParams,
    sp: &SiteParams,
) -> (Vec<Edge>, Vec<(usize, usize)>) {
    // The solve's edges: checked edges that agree with where the site put their sensors, then
    // for every other pair of placed sensors the candidate that agrees (the join's own
    // proposals always; others only with enough shared view to carry information).
    let (mut edges, mut origin) = (Vec::new(), Vec::new());
    for (e, o) in checked.edges.iter().zip(&checked.origin) {
        let (Some(pa), Some(pb)) = (placed[e.a], placed[e.b]) else {
            continue;
        };
        let (dt, dyaw) = pose_error(&e.a_from_b, &(pa.inverse() * pb));
        if dt <= sp.cycle_m && dyaw <= sp.cycle_rad {
            edges.push(e.clone());
            origin.push(*o);
        }
    }
    for (k, (&(a, b), r)) in pairs.iter().zip(results).enumerate() {
        let (Some(pa), Some(pb)) = (placed[a], placed[b]) else {
            continue;
        };
        if origin.iter().any(|o| o.0 == k) {
            continue;
        }
        let agreeing = agreeing_candidate(
            r,
            &(pa.inverse() * pb),
            |ci| join_sources.contains(&(k, ci)),
            p,
            sp,
        );
        if let Some(ci) = agreeing
            && let Some(edge) = candidate_edge((a, b), r, ci)
        {
            edges.push(edge);
            origin.push((k, ci));
        }
    }
    (edges, origin)
}

/// The first of `r`'s candidates that agrees with where the site puts B in A's frame
/// (`predicted`), fits without contradiction and shares enough view to carry information (or
/// is one of the join's own proposals, `proposed`).
pub(super) fn agreeing_candidate(
    r: &PairResult,
    predicted: &Pose2,
    proposed: impl Fn(usize) -> bool,
    p: &RegisterParams,
    sp: &SiteParams,
) -> Option<usize> {
    r.candidates.iter().enumerate().position(|(ci, c)| {
        let (dt, dyaw) = pose_error(&c.a_from_b, predicted);
        dt <= sp.confirm_m
            && dyaw <= sp.confirm_rad
            && c.score.violation() <= p.max_violation
            && (c.score.overlap() >= p.min_overlap || proposed(ci))
    })
}

/// Residual of an edge: the measured pose's error, expressed like the pair covariance
/// (a left perturbation in A's frame).
fn edge_residual(pa: &Pose2, pb: &Pose2, z: &Pose2) -> [f64; 3] {
    let d = (pa.inverse() * pb) * z.inverse();
    [d.translation.x, d.translation.y, yaw_rad(&d)]
}

fn information(cov: &Matrix3<f64>, sp: &SiteParams) -> Matrix3<f64> {
    floored(cov, sp)
        .try_inverse()
        .unwrap_or_else(Matrix3::zeros)
}

/// An edge's covariance with the σ floor added (`SiteParams::min_sigma_m`).
pub(super) fn floored(cov: &Matrix3<f64>, sp: &SiteParams) -> Matrix3<f64> {
    let mut c = *cov;
    for k in 0..2 {
        c[(k, k)] += sp.min_sigma_m * sp.min_sigma_m;
    }
    c[(2, 2)] += sp.min_sigma_rad * sp.min_sigma_rad;
    c
}

/// Joint weighted least squares (Gauss–Newton, numeric Jacobians) over all sensors reachable
/// from the anchor; returns pose and σ (x, y, yaw) per sensor.
#[allow(clippy::type_complexity)]
pub fn solve(
    n: usize,
    anchor: usize,
    edges: &[Edge],
    priors: &[(usize, Prior)],
    sp: &SiteParams,
) -> Vec<Option<(Pose2, [f64; 3])>> {
    let mut poses = super::spanning_poses(n, anchor, edges);
    // Surveyed nodes the anchor's edges do not reach start at their survey (the surest
    // first), and the nodes their edges reach start from there.
    let mut surveyed: Vec<(usize, Prior)> = priors.to_vec();
    surveyed.sort_by(|x, y| x.1.sigma_xy_m.total_cmp(&y.1.sigma_xy_m));
    for (i, prior) in surveyed {
        if poses.get(i).is_some_and(|p| p.is_none()) {
            poses[i] = Some(prior.anchor_from_node());
            super::groups::grow_poses(&mut poses, edges);
        }
    }
    let free: Vec<usize> = (0..n)
        .filter(|&i| i != anchor && poses[i].is_some())
        .collect();
    let mut slots = vec![None; n];
    for (s, &i) in free.iter().enumerate() {
        slots[i] = Some(s);
    }
    let slot = |i: usize| slots.get(i).copied().flatten();
    let dim = 3 * free.len();
    let mut normal = Normal::new(dim);
    for _ in 0..10 {
        normal = Normal::new(dim);
        let Normal { h, g, .. } = &mut normal;
        let current = |i: usize, poses: &[Option<Pose2>]| poses[i].unwrap_or_else(Pose2::identity);
        // Each factor: residual r(x), information W, and the variables it touches.
        let mut add = |vars: &[usize],
                       r: &dyn Fn(&[Pose2]) -> [f64; 3],
                       w: &Matrix3<f64>,
                       poses: &[Option<Pose2>]| {
            let base: Vec<Pose2> = vars.iter().map(|&v| current(v, poses)).collect();
            let r0 = r(&base);
            let mut jac: Vec<(usize, [[f64; 3]; 3])> = Vec::new();
            for (vi, &v) in vars.iter().enumerate() {
                let Some(s) = slot(v) else { continue };
                let mut cols = [[0.0; 3]; 3];
                for (k, col) in cols.iter_mut().enumerate() {
                    let eps = 1e-6;
                    let mut moved = base.clone();
                    let mut delta = [0.0; 3];
                    delta[k] = eps;
                    moved[vi] = pose2(delta[0], delta[1], delta[2]) * moved[vi];
                    let r1 = r(&moved);
                    for m in 0..3 {
                        let diff = if m == 2 {
                            wrap_angle_rad(r1[m] - r0[m])
                        } else {
                            r1[m] - r0[m]
                        };
                        col[m] = diff / eps;
                    }
                }
                jac.push((s, cols));
            }
            let rv = nalgebra::Vector3::from(r0);
            for (s1, c1) in &jac {
                let j1 = Matrix3::from_fn(|m, k| c1[k][m]);
                let gi = j1.transpose() * w * rv;
                for m in 0..3 {
                    g[3 * s1 + m] += gi[m];
                }
                for (s2, c2) in &jac {
                    let j2 = Matrix3::from_fn(|m, k| c2[k][m]);
                    h.push((*s1, *s2, j1.transpose() * w * j2));
                }
            }
        };
        for e in edges {
            if poses[e.a].is_none() || poses[e.b].is_none() {
                continue;
            }
            let w = information(&e.covariance, sp);
            let z = e.a_from_b;
            add(
                &[e.a, e.b],
                &|x: &[Pose2]| edge_residual(&x[0], &x[1], &z),
                &w,
                &poses,
            );
        }
        for &(i, prior) in priors {
            if i == anchor || poses.get(i).is_none_or(|p| p.is_none()) {
                continue;
            }
            let w = Matrix3::from_diagonal(&nalgebra::Vector3::new(
                prior.sigma_xy_m.powi(-2),
                prior.sigma_xy_m.powi(-2),
                prior.sigma_yaw_rad.powi(-2),
            ));
            let (z, node_from_sensor) = (prior.anchor_from_sensor, prior.node_from_sensor);
            // A survey's σ is about the sensor's own position and heading, so its residual is
            // too (an edge's left perturbation would rotate about the anchor instead); on a
            // zone, the surveyed unit's, where the zone puts it.
            let survey_residual = |x: &[Pose2]| {
                let d = pose_delta(&z, &(x[0] * node_from_sensor));
                [d.x, d.y, d.z]
            };
            add(&[i], &survey_residual, &w, &poses);
        }
        if dim == 0 {
            break;
        }
        let Some(step) = normal.step() else {
            break;
        };
        for (s, &i) in free.iter().enumerate() {
            if let Some(pose) = poses[i] {
                poses[i] = Some(pose2(step[3 * s], step[3 * s + 1], step[3 * s + 2]) * pose);
            }
        }
        if step.norm() < 1e-9 {
            break;
        }
    }
    let cov = normal.covariance_blocks();
    (0..n)
        .map(|i| {
            let pose = poses[i]?;
            let sigma = match (slot(i), &cov) {
                (Some(s), Some(c)) => {
                    // The perturbation rotates about the anchor's origin, so the position moves by
                    // δt + δθ·perp(t): propagate through that Jacobian.
                    let block = c[s];
                    let t = pose.translation.vector;
                    let j = nalgebra::Matrix2x3::new(1.0, 0.0, -t.y, 0.0, 1.0, t.x);
                    let pos = j * block * j.transpose();
                    [
                        pos[(0, 0)].max(0.0).sqrt(),
                        pos[(1, 1)].max(0.0).sqrt(),
                        block[(2, 2)].max(0.0).sqrt(),
                    ]
                }
                _ => [0.0; 3],
            };
            Some((pose, sigma))
        })
        .collect()
}

/// The normal equations H δ = −g of one Gauss–Newton step, H in 3 × 3 blocks per pair of
/// sensors a factor links (an edge, or a survey on the diagonal): sparse, as a site's sensors
/// each see a few neighbours.
pub(super) struct Normal {
    dim: usize,
    /// (slot, slot, block) terms of H; repeated blocks add up.
    h: Vec<(usize, usize, Matrix3<f64>)>,
    g: DVector<f64>,
}

impl Normal {
    fn new(dim: usize) -> Self {
        Normal {
            dim,
            h: Vec::new(),
            g: DVector::zeros(dim),
        }
    }

    /// H + damping·I, factored (None when it is not positive definite).
    fn factor(&self, damping: f64) -> Option<CscCholesky<f64>> {
        let mut coo = CooMatrix::new(self.dim, self.dim);
        for (s1, s2, block) in &self.h {
            for m in 0..3 {
                for k in 0..3 {
                    coo.push(3 * s1 + m, 3 * s2 + k, block[(m, k)]);
                }
            }
        }
        for d in 0..self.dim {
            coo.push(d, d, damping);
        }
        CscCholesky::factor(&CscMatrix::from(&coo)).ok()
    }

    /// The step δ (the damping keeps a flat direction from blowing it up).
    fn step(&self) -> Option<DVector<f64>> {
        let x =
            self.factor(1e-9)?
                .solve(&DMatrix::from_column_slice(self.dim, 1, self.g.as_slice()));
        Some(-x.column(0).into_owned())
    }

    /// The 3 × 3 diagonal blocks of H⁻¹, each sensor's covariance, one sparse solve per sensor.
    fn covariance_blocks(&self) -> Option<Vec<Matrix3<f64>>> {
        let chol = self.factor(1e-12)?;
        Some(
            (0..self.dim / 3)
                .map(|s| {
                    let mut rhs = DMatrix::zeros(self.dim, 3);
                    for k in 0..3 {
                        rhs[(3 * s + k, k)] = 1.0;
                    }
                    let x = chol.solve(&rhs);
                    Matrix3::from_fn(|m, k| x[(3 * s + m, k)])
                })
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chain of 40 sensors with chords, blocks from random SPD 3 × 3 informations: the
    /// sparse step and covariances equal the dense solve of the same system.
    #[test]
    fn the_sparse_normal_equations_solve_as_the_dense_ones() {
        let n = 40;
        let mut normal = Normal::new(3 * n);
        let mut seed = 7u64;
        let mut rand = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut links: Vec<(usize, usize)> = (0..n - 1).map(|i| (i, i + 1)).collect();
        links.extend((0..n - 7).step_by(5).map(|i| (i, i + 7)));
        for (a, b) in links {
            let j = Matrix3::from_fn(|_, _| rand());
            let w = j * j.transpose() + Matrix3::identity();
            // An edge a–b adds W to both diagonal blocks and −W off the diagonal.
            normal
                .h
                .extend([(a, a, w), (b, b, w), (a, b, -w), (b, a, -w)]);
        }
        // The first sensor is tied down (as the anchor's edges tie its neighbours).
        normal.h.push((0, 0, Matrix3::identity() * 10.0));
        normal.g = DVector::from_fn(3 * n, |_, _| rand());
        let mut dense = DMatrix::<f64>::zeros(3 * n, 3 * n);
        for (s1, s2, block) in &normal.h {
            let mut view = dense.fixed_view_mut::<3, 3>(3 * s1, 3 * s2);
            view += block;
        }
        let damped = |d: f64| &dense + DMatrix::<f64>::identity(3 * n, 3 * n) * d;
        let want = damped(1e-9).lu().solve(&(-&normal.g)).expect("dense solve");
        let got = normal.step().expect("sparse solve");
        assert!(
            (&got - &want).amax() < 1e-9 * want.amax().max(1.0),
            "step differs"
        );
        let inverse = damped(1e-12).try_inverse().expect("dense inverse");
        let blocks = normal.covariance_blocks().expect("sparse covariance");
        for (s, block) in blocks.iter().enumerate() {
            let want = inverse.fixed_view::<3, 3>(3 * s, 3 * s).into_owned();
            assert!((block - want).amax() < 1e-9 * want.amax(), "sensor {s}");
        }
    }
}
