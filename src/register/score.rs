//! Scoring a candidate pose against the lookup tables, in both directions: hits (points that
//! land near the other scan's points) minus weighted free-space violations (points that land
//! where the other sensor saw empty space). Violations are counted, not fatal: at the true
//! pose a few per cent of real points violate (clutter, people, grazing walls).

use super::{RegisterParams, ScanModel};
use crate::geometry::Pose2;

/// Hit and violation fractions of one direction.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DirScore {
    /// Soft hit count / points: 1 − (d/hit)² per hit.
    pub hit: f64,
    /// Points within the hit distance / points.
    pub overlap: f64,
    /// Points in the other sensor's free space / points.
    pub violation: f64,
}

/// The score of a pose: both directions and the combined value.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PoseScore {
    pub a_in_b: DirScore,
    pub b_in_a: DirScore,
    pub value: f64,
}

impl PoseScore {
    /// Estimated shared view: the smaller of the two hit shares.
    pub fn overlap(&self) -> f64 {
        self.a_in_b.overlap.min(self.b_in_a.overlap)
    }
    /// The worse direction's violation share: one sensor contradicting the other suffices.
    pub fn violation(&self) -> f64 {
        self.a_in_b.violation.max(self.b_in_a.violation)
    }
}

/// Scores `from`'s sample moved by `into_from_from` against `into`'s tables.
fn score_dir(
    from: &ScanModel,
    into: &ScanModel,
    into_from_from: &Pose2,
    p: &Tolerance,
) -> DirScore {
    let (mut hit, mut overlap, mut violation) = (0.0, 0usize, 0usize);
    let pts = from.points();
    let into_pts = into.points();
    for &i in &from.score_sample {
        let q = into_from_from * pts[i];
        if let Some(j) = into.grid.nearest(&q) {
            let d = (q - into_pts[j]).norm();
            if d < p.hit_m {
                let x = d / p.hit_m;
                hit += 1.0 - x * x;
                overlap += 1;
            }
        }
        if into.polar.violates(&q, p.free_margin_m, p.free_margin_frac) {
            violation += 1;
        }
    }
    let n = from.score_sample.len().max(1) as f64;
    DirScore {
        hit: hit / n,
        overlap: overlap as f64 / n,
        violation: violation as f64 / n,
    }
}

/// Hit distance and free-space margins of one scoring pass.
#[derive(Debug, Clone, Copy)]
struct Tolerance {
    hit_m: f64,
    free_margin_m: f64,
    free_margin_frac: f64,
    violation_weight: f64,
}

/// Scores the pose `a_from_b` of B in A's frame.
pub fn score(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2, p: &RegisterParams) -> PoseScore {
    let t = Tolerance {
        hit_m: p.hit_m,
        free_margin_m: p.free_margin_m,
        free_margin_frac: p.free_margin_frac,
        violation_weight: p.violation_weight,
    };
    score_with(a, b, a_from_b, &t)
}

/// Scores an unrefined hypothesis: its heading may be a degree off, so hits and free-space
/// margins are widened by `coarse_slack_m`.
pub fn score_coarse(
    a: &ScanModel,
    b: &ScanModel,
    a_from_b: &Pose2,
    p: &RegisterParams,
) -> PoseScore {
    let t = Tolerance {
        hit_m: p.hit_m + p.coarse_slack_m,
        free_margin_m: p.free_margin_m + p.coarse_slack_m,
        free_margin_frac: p.free_margin_frac,
        violation_weight: p.violation_weight,
    };
    score_with(a, b, a_from_b, &t)
}

fn score_with(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2, p: &Tolerance) -> PoseScore {
    let b_in_a = score_dir(b, a, a_from_b, p);
    let a_in_b = score_dir(a, b, &a_from_b.inverse(), p);
    let value = 0.5 * (a_in_b.hit + b_in_a.hit)
        - p.violation_weight * (a_in_b.violation + b_in_a.violation);
    PoseScore {
        a_in_b,
        b_in_a,
        value,
    }
}
