//! Where a sensor added to a placed site stands, and how surely: each of its pairs that agrees
//! with where it joined carries its partner's pose to it, and these estimates are weighed by
//! information (the pair's covariance, floored as the solve floors it, plus what the partner's
//! own σ does at that distance). It is the joint solve with the placed sensors held where they
//! stand. The partners' errors share the anchor and are treated as independent: slightly
//! optimistic where several rest on one chain.

use super::SiteParams;
use super::solve::{agreeing_candidate, floored};
use crate::geometry::{Pose2, pose_delta, pose_step, pose2};
use crate::register::{PairResult, RegisterParams};
use nalgebra::{Matrix3, Vector3};

pub(super) struct Settled {
    pub pose: Pose2,
    /// σ of x, y (anchor frame) and yaw.
    pub sigma: [f64; 3],
    /// Indices into the pairs of those it rests on.
    pub used: Vec<usize>,
}

/// Settles sensor `new`, joined at `at`, from `pairs` (each (a, b) with its result); `placed`
/// holds each placed sensor's index, anchor-frame pose and σ (x, y, yaw); `proposed` the join's
/// (pair, candidate) proposals, which count even with little shared view. None when no pair
/// agrees with `at` (the join's own proposals do, so only a malformed input gets there).
pub(super) fn settle(
    new: usize,
    at: &Pose2,
    placed: &[(usize, Pose2, [f64; 3])],
    pairs: &[((usize, usize), PairResult)],
    proposed: &[(usize, usize)],
    p: &RegisterParams,
    sp: &SiteParams,
) -> Option<Settled> {
    let (mut info, mut pull) = (Matrix3::zeros(), Vector3::zeros());
    let mut used = Vec::new();
    for (k, &((a, b), ref r)) in pairs.iter().enumerate() {
        let partner = match (a == new, b == new) {
            (true, false) => b,
            (false, true) => a,
            _ => continue,
        };
        let Some(&(_, at_partner, sigma)) = placed.iter().find(|(i, _, _)| *i == partner) else {
            continue;
        };
        // Where the added sensor stands given the pair's pose of b in a's frame.
        let through = |a_from_b: &Pose2| {
            if a == new {
                at_partner * a_from_b.inverse()
            } else {
                at_partner * a_from_b
            }
        };
        let predicted = if a == new {
            at.inverse() * at_partner
        } else {
            at_partner.inverse() * at
        };
        let Some(c) = agreeing_candidate(r, &predicted, |ci| proposed.contains(&(k, ci)), p, sp)
            .and_then(|ci| r.candidates.get(ci))
        else {
            continue;
        };
        let estimate = through(&c.a_from_b);
        // The pair's covariance is of a left perturbation of a_from_b (a's frame): carried
        // through to the added sensor's own position and heading, numerically as the solve.
        let eps = 1e-6;
        let j = Matrix3::from_fn(|m, k| {
            let mut d = [0.0; 3];
            d[k] = eps;
            pose_delta(&estimate, &through(&(pose2(d[0], d[1], d[2]) * c.a_from_b)))[m] / eps
        });
        // The partner's own error moves it as a rigid lever: its heading swings the added
        // sensor about it.
        let lever = estimate.translation.vector - at_partner.translation.vector;
        let swing = Matrix3::new(1.0, 0.0, -lever.y, 0.0, 1.0, lever.x, 0.0, 0.0, 1.0);
        let own = Matrix3::from_diagonal(&Vector3::new(
            sigma[0] * sigma[0],
            sigma[1] * sigma[1],
            sigma[2] * sigma[2],
        ));
        let cov = j * floored(&c.covariance, sp) * j.transpose() + swing * own * swing.transpose();
        let Some(w) = cov.try_inverse() else {
            continue;
        };
        info += w;
        pull += w * pose_delta(at, &estimate);
        used.push(k);
    }
    let cov = info.try_inverse().filter(|_| !used.is_empty())?;
    let step = cov * pull;
    Some(Settled {
        pose: pose_step(at, &step),
        sigma: [0, 1, 2].map(|m| cov[(m, m)].max(0.0).sqrt()),
        used,
    })
}
