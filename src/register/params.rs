//! Every registration threshold in one place, with the reasoning behind each default.

use super::motion::MotionParams;
use super::walkers::WalkerParams;
use crate::features::FeatureParams;
use crate::geometry::ProjectParams;

/// Parameters of pairwise registration.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterParams {
    pub project: ProjectParams,
    pub features: FeatureParams,
    /// Cell size of the nearest-point lookup grid (m).
    pub grid_res_m: f64,
    /// How far from a point the lookup grid still knows it (m); bounds ICP's capture range.
    pub grid_radius_m: f64,
    /// Normals of points off segments are fitted over scan neighbours this close (m); sparse
    /// 1° scans need a wide window for a stable direction.
    pub normal_radius_m: f64,
    /// Points used for scoring, spread evenly along the outline (at most).
    pub score_points: usize,
    /// Points used by ICP (at most).
    pub icp_points: usize,
    /// A transformed point within this of the other scan is a hit (m).
    pub hit_m: f64,
    /// A point counts as violating the other sensor's free space when it lies at least this
    /// much (plus `free_margin_frac` of its range) short of what that sensor saw (m).
    pub free_margin_m: f64,
    pub free_margin_frac: f64,
    /// ... and only where that sensor's scan plane passes no more than this above the point
    /// (m): a unit mounted higher, or tilted down, sees over boxes and partitions the other one
    /// hits, while a beam below the point would have hit it (objects stand on the floor).
    /// 0.5 m: over seeds 1–3 of eval's simulated pairs and seeds 1–16 of its sites, 0.3 m lost
    /// sim success, 0.8 m was no better overall (7 more installed sensors, 4 fewer right and 1
    /// more wrong in random sites).
    pub free_space_dz_m: f64,
    /// ... and no more than this below it (m). Unbounded for the walls' own score: it may not
    /// assume that what a unit saw ends where its beam does, and most things stand on the
    /// floor. Where walkers chose the pose it is `WalkerParams::chosen_free_space_dz_m` too.
    pub free_space_dz_below_m: f64,
    /// ... and only where that sensor's beam meets the surface the point lies on (where the
    /// point's own sensor fitted one) at less than this incidence (°): a beam running along a
    /// wall, its footprint partly beside it, reaches past points on it without contradicting
    /// them (a unit 0.2 m from a corridor wall, looking down it, "sees through" the wall that
    /// the unit at the corridor's far end sees face on). Only where that sensor saw the
    /// surface nearer itself: the two site tests of a hall and a far room placed a wrong
    /// 46.5 m / 90° rival without that condition.
    pub free_space_grazing_deg: f64,
    /// Weight of the violation fraction against the hit fraction in the score: free space
    /// decides, since hits alone favour the pose with the most overlap.
    pub violation_weight: f64,
    /// Extra hit distance and free-space margin when scoring unrefined hypotheses (m).
    pub coarse_slack_m: f64,
    /// Hypotheses closer than this are one seed for refinement (m, rad).
    pub seed_gap_m: f64,
    pub seed_gap_rad: f64,
    /// Rotation candidates kept from the segment-direction histogram.
    pub max_rotations: usize,
    /// Translation peaks kept per rotation.
    pub peaks_per_rotation: usize,
    /// Cell size of the translation vote (m).
    pub vote_res_m: f64,
    /// Candidates refined by ICP after coarse scoring.
    pub refine_best: usize,
    /// Two poses closer than this are the same answer (m, rad).
    pub same_pose_m: f64,
    pub same_pose_rad: f64,
    /// Class-aware correspondences (seed 002) in ICP.
    pub class_aware: bool,
    /// Cost of a class mismatch, in units of (`class_scale_m`)² squared distance.
    pub class_weight: f64,
    pub class_scale_m: f64,
    pub icp_max_iterations: usize,
    /// Cauchy kernel width on point-to-line residuals (m).
    pub huber_m: f64,
    /// Correspondences farther than this are ignored (m); the gate shrinks each iteration
    /// from the first value to the second.
    pub max_correspondence_m: f64,
    pub min_correspondence_m: f64,
    /// Matched points' normals must agree at least this much (cosine).
    pub min_normal_agreement: f64,
    /// Residual errors of neighbouring points are correlated; the ICP covariance is
    /// multiplied by this to stay honest.
    pub covariance_inflation: f64,
    /// The winner is polished by plain ICP when that lowers its score by at most this.
    pub polish_tolerance: f64,
    /// β of MATCH = β·SIM + (1−β)·CON (eq. 14).
    pub match_beta: f64,
    /// Abstain below this overlap estimate.
    pub min_overlap: f64,
    /// Abstain above this violation fraction at the best pose.
    pub max_violation: f64,
    /// Abstain when the pose's own standard deviation (covariance above, worst translation
    /// direction; heading) exceeds these: "registered" promises ~10 cm / 1°, and on sparse real
    /// scans the covariance reads the true error about 3× low. From eval `--csv` on 600 real
    /// pairs: 95 % of correct poses have σ under 4–7 cm / 0.7°; 18 of 31 wrong ones exceeded
    /// 10 cm / 1°. The heading limit is 0.45°, not 0.75°: over eval's real pairs, seeds 1–5,
    /// σ 0.45–0.75° held 15 of 43 confident-wrong poses (1.5–2.6° off) against 50 of 527
    /// right ones (12 at ≥ 30 % overlap); no simulated pair, seeds 1–3, has σ above 0.4°.
    pub max_sigma_m: f64,
    pub max_sigma_rad: f64,
    /// Abstain when the runner-up (a different pose) scores at least this fraction of the best.
    pub max_ambiguity: f64,
    /// Abstain when the best score (hit share minus weighted violations) is below this.
    pub min_score: f64,
    /// A pose slid ±0.25/0.5 m along an axis ICP cannot see that keeps this share of the best
    /// score means the scans do not fix the position along it.
    pub slide_ratio: f64,
    /// Abstain when the weakest translation direction carries less than this share of the
    /// constraint (a corridor seen lengthwise).
    pub min_constraint_share: f64,
    /// The check against people both sensors saw walk (when the scans carry them).
    pub motion: MotionParams,
    /// Poses proposed by people both sensors saw walk.
    pub walkers: WalkerParams,
}

impl Default for RegisterParams {
    fn default() -> Self {
        RegisterParams {
            project: ProjectParams::default(),
            features: FeatureParams::default(),
            grid_res_m: 0.05,
            grid_radius_m: 0.4,
            normal_radius_m: 0.3,
            score_points: 300,
            icp_points: 600,
            hit_m: 0.12,
            free_margin_m: 0.15,
            free_margin_frac: 0.02,
            free_space_dz_m: 0.5,
            free_space_dz_below_m: f64::INFINITY,
            free_space_grazing_deg: 88.0,
            violation_weight: 3.0,
            coarse_slack_m: 0.12,
            seed_gap_m: 0.25,
            seed_gap_rad: 2f64.to_radians(),
            max_rotations: 24,
            peaks_per_rotation: 6,
            vote_res_m: 0.1,
            refine_best: 16,
            same_pose_m: 0.5,
            same_pose_rad: 5f64.to_radians(),
            class_aware: true,
            class_weight: 1.0,
            class_scale_m: 0.1,
            icp_max_iterations: 40,
            huber_m: 0.05,
            max_correspondence_m: 0.4,
            min_correspondence_m: 0.12,
            min_normal_agreement: 0.8,
            covariance_inflation: 4.0,
            polish_tolerance: 0.02,
            match_beta: 0.5,
            min_overlap: 0.2,
            max_violation: 0.15,
            max_ambiguity: 0.5,
            max_sigma_m: 0.06,
            max_sigma_rad: 0.45f64.to_radians(),
            min_score: 0.12,
            slide_ratio: 0.95,
            min_constraint_share: 0.005,
            motion: MotionParams::default(),
            walkers: WalkerParams::default(),
        }
    }
}
