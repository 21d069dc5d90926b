//! The solve: which edges enter it (checked edges that agree with where the site put their
//! sensors, and every other placed pair's agreeing candidate), and the joint weighted least
//! squares over them (anchor fixed, surveys as priors) with each pose's σ.

use super::groups::Checked;
use super::{Edge, Prior, SensorInput, SiteParams, candidate_edge};
use crate::geometry::{Pose2, pose_error, pose2, wrap_angle_rad, yaw_rad};
use crate::register::{PairResult, RegisterParams};
use nalgebra::{DMatrix, DVector, Matrix3};

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
        let predicted = pa.inverse() * pb;
        let agreeing = r.candidates.iter().enumerate().find(|(ci, c)| {
            let (dt, dyaw) = pose_error(&c.a_from_b, &predicted);
            dt <= sp.confirm_m
                && dyaw <= sp.confirm_rad
                && c.score.violation() <= p.max_violation
                && (c.score.overlap() >= p.min_overlap || join_sources.contains(&(k, *ci)))
        });
        if let Some((ci, _)) = agreeing
            && let Some(edge) = candidate_edge((a, b), r, ci)
        {
            edges.push(edge);
            origin.push((k, ci));
        }
    }
    (edges, origin)
}

/// Residual of an edge: the measured pose's error, expressed like the pair covariance
/// (a left perturbation in A's frame).
fn edge_residual(pa: &Pose2, pb: &Pose2, z: &Pose2) -> [f64; 3] {
    let d = (pa.inverse() * pb) * z.inverse();
    [d.translation.x, d.translation.y, yaw_rad(&d)]
}

fn information(cov: &Matrix3<f64>, sp: &SiteParams) -> Matrix3<f64> {
    let mut c = *cov;
    for k in 0..2 {
        c[(k, k)] += sp.min_sigma_m * sp.min_sigma_m;
    }
    c[(2, 2)] += sp.min_sigma_rad * sp.min_sigma_rad;
    c.try_inverse().unwrap_or_else(Matrix3::zeros)
}

/// Joint weighted least squares (Gauss–Newton, numeric Jacobians) over all sensors reachable
/// from the anchor; returns pose and σ (x, y, yaw) per sensor.
#[allow(clippy::type_complexity)]
pub fn solve(
    n: usize,
    anchor: usize,
    edges: &[Edge],
    sensors: &[SensorInput],
    sp: &SiteParams,
) -> Vec<Option<(Pose2, [f64; 3])>> {
    let mut poses = super::spanning_poses(n, anchor, edges);
    // Surveyed sensors the anchor's edges do not reach start at their survey (the surest
    // first), and the sensors their edges reach start from there.
    let mut surveyed: Vec<(usize, Prior)> = sensors
        .iter()
        .enumerate()
        .filter_map(|(i, s)| Some((i, s.prior?)))
        .collect();
    surveyed.sort_by(|x, y| x.1.sigma_xy_m.total_cmp(&y.1.sigma_xy_m));
    for (i, prior) in surveyed {
        if poses.get(i).is_some_and(|p| p.is_none()) {
            poses[i] = Some(prior.anchor_from_sensor);
            super::groups::grow_poses(&mut poses, edges);
        }
    }
    let free: Vec<usize> = (0..n)
        .filter(|&i| i != anchor && poses[i].is_some())
        .collect();
    let slot = |i: usize| free.iter().position(|&f| f == i);
    let dim = 3 * free.len();
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    for _ in 0..10 {
        h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
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
                    let block = j1.transpose() * w * j2;
                    for m in 0..3 {
                        for k in 0..3 {
                            h[(3 * s1 + m, 3 * s2 + k)] += block[(m, k)];
                        }
                    }
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
        for (i, s) in sensors.iter().enumerate() {
            let Some(prior) = s.prior else { continue };
            if i == anchor || poses[i].is_none() {
                continue;
            }
            let w = Matrix3::from_diagonal(&nalgebra::Vector3::new(
                prior.sigma_xy_m.powi(-2),
                prior.sigma_xy_m.powi(-2),
                prior.sigma_yaw_rad.powi(-2),
            ));
            let z = prior.anchor_from_sensor;
            // A survey's σ is about the sensor's own position and heading, so its residual is
            // too (an edge's left perturbation would rotate about the anchor instead).
            let survey_residual = |x: &[Pose2]| {
                let d = x[0].translation.vector - z.translation.vector;
                [
                    d.x,
                    d.y,
                    wrap_angle_rad(x[0].rotation.angle() - z.rotation.angle()),
                ]
            };
            add(&[i], &survey_residual, &w, &poses);
        }
        if dim == 0 {
            break;
        }
        let Some(step) = (&h + DMatrix::<f64>::identity(dim, dim) * 1e-9)
            .lu()
            .solve(&(-&g))
        else {
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
    let cov = (&h + DMatrix::<f64>::identity(dim, dim) * 1e-12).try_inverse();
    (0..n)
        .map(|i| {
            let pose = poses[i]?;
            let sigma = match (slot(i), &cov) {
                (Some(s), Some(c)) => {
                    // The perturbation rotates about the anchor's origin, so the position moves by
                    // δt + δθ·perp(t): propagate through that Jacobian.
                    let block = c.fixed_view::<3, 3>(3 * s, 3 * s).into_owned();
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
