//! Pairwise global registration (METHOD §3): hypotheses from segment and corner pairs, scored
//! against lookup grids with free-space violations in both directions, the best few refined by
//! ICP, then a verdict: registered with a covariance, or not registered with the reason.

use super::hypotheses::hypotheses;
use super::icp::{IcpResult, refine_scored};
use super::matching::match_score;
use super::motion::{MotionEvidence, co_motion};
use super::score::{PoseScore, score, score_coarse};
use super::telling::generic_match;
use super::walkers::{WalkerFit, fit_walkers, walkers_keep};
use super::{RegisterParams, ScanModel};
use crate::geometry::{Pose2, pose_delta, pose_error, pose_step, pose2};
use nalgebra::Matrix3;
use rayon::prelude::*;
use std::fmt;

/// Why a pair was not registered.
#[derive(Debug, Clone, PartialEq)]
pub enum Abstain {
    /// One scan has too few features to form a hypothesis.
    NoHypotheses,
    /// The best pose shares too little of the view.
    TooLittleOverlap { overlap: f64 },
    /// The best pose's hits barely outweigh its free-space violations.
    WeakMatch { score: f64 },
    /// The best pose puts too many points in space the other sensor saw empty.
    ContradictsFreeSpace { violation: f64 },
    /// The scans pin the pose only loosely: its own standard deviation exceeds the limits.
    Uncertain { sigma_m: f64, sigma_yaw_deg: f64 },
    /// A clearly different pose scores nearly as well (a symmetric corridor, a repeated room).
    Ambiguous { ratio: f64, other: Pose2 },
    /// The geometry does not fix the position along one direction (a corridor seen lengthwise).
    Degenerate { weak_axis_deg: f64 },
    /// People one sensor saw walking stand where the other saw straight through at that
    /// moment, at the walls' best pose (its counts); `left`: why the best pose people left
    /// standing is not reported either, if any was.
    PeopleDisagree {
        seen_through: usize,
        seen: usize,
        left: Option<Box<Abstain>>,
    },
    /// The walls' best pose and the pose people walking agree on differ (`other`: the walkers'
    /// pose in the frame of the walls' best), and neither rules the other out.
    WalkersDisagree { other: Pose2 },
    /// The sensors watched together this long (s), people walked, but none where both look:
    /// the walls alone cannot rule out a look-alike place.
    Unconfirmed { watched_s: f64 },
    /// The match rests on fewer than `telling::TELLING` structures (one corner, one wall):
    /// any other place with as much matches as well.
    Generic { structures: usize },
}

impl fmt::Display for Abstain {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Abstain::NoHypotheses => write!(f, "too few walls or corners to form a hypothesis"),
            Abstain::WeakMatch { score } => write!(f, "weak match (score {score:.2})"),
            Abstain::TooLittleOverlap { overlap } => {
                write!(f, "too little shared view ({:.0} %)", overlap * 100.0)
            }
            Abstain::ContradictsFreeSpace { violation } => {
                write!(
                    f,
                    "best pose contradicts free space ({:.0} % of points)",
                    violation * 100.0
                )
            }
            Abstain::Ambiguous { ratio, other } => write!(
                f,
                "ambiguous: a pose {:.2} m / {:.1}° away scores {:.0} % as well",
                other.translation.vector.norm(),
                other.rotation.angle().to_degrees(),
                ratio * 100.0
            ),
            Abstain::Uncertain {
                sigma_m,
                sigma_yaw_deg,
            } => write!(
                f,
                "too uncertain (σ {sigma_m:.2} m / {sigma_yaw_deg:.1}°): too few points fix it"
            ),
            Abstain::PeopleDisagree {
                seen_through,
                seen,
                left,
            } => {
                write!(
                    f,
                    "people disagree: at the best pose {seen_through} walkers one sensor saw stand where the other saw through at that moment ({seen} seen by both); a look-alike place"
                )?;
                match left {
                    Some(why) => write!(f, "; the best pose they leave: {why}"),
                    None => Ok(()),
                }
            }
            Abstain::WalkersDisagree { other } => write!(
                f,
                "walls and walkers disagree: the people both sensors saw walking put it {:.2} m / {:.1}° from where the walls do; walk through their shared view again, or survey it",
                other.translation.vector.norm(),
                other.rotation.angle().to_degrees()
            ),
            Abstain::Unconfirmed { watched_s } => write!(
                f,
                "not confirmed: in {watched_s:.0} s people walked, but none where both sensors look, and walls alone can match a look-alike place; walk through their shared view while recording"
            ),
            Abstain::Generic { structures } => write!(
                f,
                "what both see is {}: any other place with as much matches as well; needs a third wall or a column both see, or people walking through both views",
                match structures {
                    0 => "no wall and nothing else",
                    1 => "only one wall",
                    _ => "only two walls (a corner), or one wall and one thing by it",
                }
            ),
            Abstain::Degenerate { weak_axis_deg } => {
                write!(
                    f,
                    "position unconstrained along {weak_axis_deg:.0}° (corridor-like view)"
                )
            }
        }
    }
}

/// A refined candidate pose with its score and covariance (x, y, yaw; m², rad²).
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub a_from_b: Pose2,
    pub score: PoseScore,
    pub covariance: Matrix3<f64>,
}

/// The outcome for one pair. The best candidate is always reported (for diagnosis and for the
/// site solve, which may resolve an ambiguous pair through third sensors); `verdict` says
/// whether it may be used alone.
#[derive(Debug, Clone, PartialEq)]
pub struct PairResult {
    pub verdict: Result<(), Abstain>,
    /// Best pose of B in A's frame.
    pub a_from_b: Pose2,
    /// Covariance of (x, y, yaw) of `a_from_b`, A's frame (m², rad²).
    pub covariance: Matrix3<f64>,
    /// The paper's MATCH in [0, 1].
    pub match_score: f64,
    /// Runner-up score / best score, runner-up being a clearly different pose (0 = none).
    pub ambiguity: f64,
    /// Estimated share of the view seen by both.
    pub overlap: f64,
    pub score: PoseScore,
    /// Distinct refined candidates, best first.
    pub candidates: Vec<Candidate>,
    pub hypotheses: usize,
    pub icp_iterations: usize,
    /// Walkers at the best pose, when both scans carry people seen over time.
    pub motion: Option<MotionEvidence>,
    /// The pose people both sensors saw walk agree on, when it chose the best pose among the
    /// walls' candidates (the pose itself is the walls').
    pub walkers: Option<WalkerFit>,
    /// The two watched together this long (s) and no one walked in either view: the walls
    /// alone decided, and the pose is not confirmed by people.
    pub nobody_walked_s: Option<f64>,
}

impl PairResult {
    pub fn registered(&self) -> bool {
        self.verdict.is_ok()
    }

    /// Registered, and people both sensors saw walk confirm the pose
    /// (`MotionParams::settle_min_seen` of them there, few seen through): not the walls alone.
    pub fn confirmed_by_people(&self, p: &RegisterParams) -> bool {
        self.registered() && self.motion.is_some_and(|e| e.confirms(p))
    }
}

fn same_pose(x: &Pose2, y: &Pose2, p: &RegisterParams) -> bool {
    let (dt, dyaw) = pose_error(x, y);
    dt < p.same_pose_m && dyaw < p.same_pose_rad
}

/// Registers B against A: the pose `a_from_b` of B's scan in A's frame.
pub fn register_pair(a: &ScanModel, b: &ScanModel, p: &RegisterParams) -> PairResult {
    let mut coarse: Vec<(PoseScore, Pose2)> = hypotheses(a, b, p)
        .into_par_iter()
        .map(|(_, pose)| (score_coarse(a, b, &pose, p), pose))
        .collect();
    coarse.sort_by(|x, y| y.0.value.total_cmp(&x.0.value));
    let hypotheses_count = coarse.len();
    // Keep the best few distinct hypotheses for refinement.
    let mut seeds: Vec<Pose2> = Vec::new();
    for (_, pose) in &coarse {
        if seeds.len() >= p.refine_best {
            break;
        }
        let apart = |s: &Pose2| {
            let (dt, dyaw) = pose_error(s, pose);
            dt >= p.seed_gap_m || dyaw >= p.seed_gap_rad
        };
        if seeds.iter().all(apart) {
            seeds.push(*pose);
        }
    }
    let mut refined: Vec<(Candidate, IcpResult)> = seeds
        .par_iter()
        .map(|seed| {
            let (icp, score) = refine_scored(a, b, seed, p, p.class_aware);
            (
                Candidate {
                    a_from_b: icp.a_from_b,
                    score,
                    // Linearised at the end, for the distinct candidates only.
                    covariance: Matrix3::zeros(),
                },
                icp,
            )
        })
        .collect();
    refined.sort_by(|x, y| y.0.score.value.total_cmp(&x.0.score.value));
    let mut distinct: Vec<(Candidate, IcpResult)> = Vec::new();
    for r in refined {
        if distinct
            .iter()
            .all(|d| !same_pose(&d.0.a_from_b, &r.0.a_from_b, p))
        {
            distinct.push(r);
        }
    }
    let (mut distinct, mut evidence, refuted) = sift_by_people(a, b, distinct, p);
    let mut disputed: Option<WalkerFit> = None;
    // People both saw walk propose a pose of their own; where it is decisive, the walls'
    // candidate in its basin leads.
    let walkers = decisive_walkers(a, b, p);
    if let Some(fit) = &walkers {
        propose_from_walkers(a, b, fit, &mut distinct, &mut evidence, p);
    }
    let walkers = match walkers {
        Some(fit) if lead_with_walkers(&fit, &mut distinct, &mut evidence, p) => Some(fit),
        // No wall candidate there, or it failed the walkers' own check: they lead nothing,
        // but a walls' best they contradict is refused below.
        Some(fit) => {
            disputed = Some(fit);
            None
        }
        None => None,
    };
    // The guarded ICP keeps the iterate the score likes best, and the score is flat within a
    // degree or two of the optimum: polish the winner with plain narrow-gate ICP, both ways,
    // which settles the heading, unless that costs score (it slid off along a weak direction).
    if let Some((first, _)) = distinct.first_mut() {
        let polished = polish(a, b, &first.a_from_b, p);
        let polished_score = score(a, b, &polished, p);
        let still_theirs = walkers
            .as_ref()
            .is_none_or(|f| f.near(&polished, &p.walkers));
        if polished_score.value >= first.score.value - p.polish_tolerance && still_theirs {
            first.a_from_b = polished;
            first.score = polished_score;
        }
    }
    // The people's fit, decisive or disputed: what may place the pair alone.
    let any_fit = walkers.as_ref().or(disputed.as_ref());
    let Some((mut best, icp)) = distinct.first().cloned() else {
        if let Some(placed) = any_fit.and_then(|f| placed_by_walkers(a, b, f, hypotheses_count, p))
        {
            return placed;
        }
        let (verdict, a_from_b, score, motion) = match refuted {
            Some((c, e)) => (
                Err(Abstain::PeopleDisagree {
                    seen_through: e.seen_through,
                    seen: e.seen,
                    left: None,
                }),
                c.a_from_b,
                c.score,
                Some(e),
            ),
            None => (
                Err(Abstain::NoHypotheses),
                Pose2::identity(),
                PoseScore::default(),
                None,
            ),
        };
        return PairResult {
            verdict,
            a_from_b,
            covariance: Matrix3::identity() * 1e6,
            match_score: 0.0,
            ambiguity: 0.0,
            overlap: score.overlap(),
            score,
            candidates: Vec::new(),
            hypotheses: hypotheses_count,
            icp_iterations: 0,
            motion,
            walkers: None,
            nobody_walked_s: None,
        };
    };
    let (covariance, weak) = covariance_at(a, b, &best.a_from_b, p);
    // The walkers chose this pose among the walls' candidates: what the walls cannot tell
    // apart (a look-alike, the runner-up) they settled; the rest the walls must still show.
    let by_walkers = walkers
        .as_ref()
        .filter(|f| f.near(&best.a_from_b, &p.walkers));
    // What the walls leave loose (along a corridor seen lengthwise) the walkers may fix: the
    // two joined, the walls' pose moves only where they could not hold it. Along that
    // direction the walkers place the pair alone, so only a fit that could place it alone may
    // (its errors run to 2-3 of its σ: `eval --diagnose`). Where the walls hold it all, their
    // pose stands.
    let loose = weak.is_some() || too_uncertain(&covariance, p).is_some();
    let fixing = by_walkers.filter(|fit| loose && fit.places_alone_but_for_its_rival(&p.walkers));
    let (covariance, weak) = match fixing {
        Some(fit) => {
            let (pose, joined) = joined_with_walkers(&best.a_from_b, &covariance, fit, p);
            best.a_from_b = pose;
            best.score = score(a, b, &pose, p);
            if let Some((first, _)) = distinct.first_mut() {
                first.a_from_b = pose;
                first.score = best.score;
            }
            (joined, None)
        }
        None => (covariance, weak),
    };
    let overlap = best.score.overlap();
    // The runner-up is one the walkers left standing: in their basin when they chose, and not
    // a pose people watched long enough to confirm and never did while they confirm the best.
    let expected = unconfirmed(a, b, None, p).is_some();
    let runner_up = distinct
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, (c, _))| by_walkers.is_none_or(|f| f.near(&c.a_from_b, &p.walkers)))
        .find(|(k, _)| !outwatched(evidence.first(), evidence.get(*k), expected, p))
        .map(|(_, (c, _))| c.clone());
    let ambiguity = match &runner_up {
        Some(r) if best.score.value > 0.0 => (r.score.value / best.score.value).max(0.0),
        _ => 0.0,
    };
    // The walls' checks, on what they can still say where people chose the pose.
    let walls = match by_walkers {
        Some(_) => walls_under_walkers(a, b, &best, p),
        None => best.score,
    };
    // Where people both saw walk chose the pose and confirm it, a look-alike is what they
    // ruled out: the walls need share only enough to refine it (their σ still gates it), but
    // must fit what they share as well as ever (the score floor scales with the share).
    let confirmed = by_walkers.is_some() && evidence.first().is_some_and(|e| e.confirms(p));
    let (min_overlap, min_score) = if confirmed {
        let share = (walls.overlap() / p.min_overlap).min(1.0);
        (p.walkers.chosen_min_overlap, p.min_score * share)
    } else {
        (p.min_overlap, p.min_score)
    };
    let verdict = if walls.overlap() < min_overlap {
        Err(Abstain::TooLittleOverlap {
            overlap: walls.overlap(),
        })
    } else if walls.value < min_score {
        Err(Abstain::WeakMatch { score: walls.value })
    } else if walls.violation() > p.max_violation {
        Err(Abstain::ContradictsFreeSpace {
            violation: walls.violation(),
        })
    } else if let Some(weak_axis_deg) = weak.filter(|deg| slides_freely(a, b, &best, *deg, p)) {
        Err(Abstain::Degenerate { weak_axis_deg })
    } else if let Some((sigma_m, sigma_rad)) = too_uncertain(&covariance, p) {
        Err(Abstain::Uncertain {
            sigma_m,
            sigma_yaw_deg: sigma_rad.to_degrees(),
        })
    } else if by_walkers.is_some() {
        Ok(())
    } else if let Some(structures) = generic_match(a, b, &best.a_from_b, &best.score, p) {
        Err(Abstain::Generic { structures })
    } else if ambiguity > p.max_ambiguity {
        let other = runner_up.map_or(Pose2::identity(), |r| best.a_from_b.inverse() * r.a_from_b);
        Err(Abstain::Ambiguous {
            ratio: ambiguity,
            other,
        })
    } else if let Some(fit) = disputed
        .as_ref()
        .filter(|f| !f.agrees(&best.a_from_b, &p.walkers))
    {
        Err(Abstain::WalkersDisagree {
            other: best.a_from_b.inverse() * fit.a_from_b,
        })
    } else if let Some(watched_s) = unconfirmed(a, b, evidence.first().copied(), p) {
        Err(Abstain::Unconfirmed { watched_s })
    } else {
        Ok(())
    };
    // When people ruled out a pose that fitted the walls better than anything left, that is
    // the reason worth reporting first, and the leftover's own second (what would settle it).
    let verdict = match (verdict, refuted) {
        (Err(left), Some((c, e))) if c.score.value > best.score.value => {
            Err(Abstain::PeopleDisagree {
                seen_through: e.seen_through,
                seen: e.seen,
                left: Some(Box::new(left)),
            })
        }
        (verdict, _) => verdict,
    };
    // The walls gave no answer of their own (not one the walkers contradict): people both
    // sensors saw walk may place the pair alone.
    if verdict
        .as_ref()
        .is_err_and(|why| !matches!(why, Abstain::WalkersDisagree { .. }))
        && let Some(placed) = any_fit.and_then(|f| placed_by_walkers(a, b, f, hypotheses_count, p))
    {
        return placed;
    }
    PairResult {
        verdict,
        a_from_b: best.a_from_b,
        covariance,
        match_score: match_score(a, b, &best.a_from_b, p),
        ambiguity,
        overlap,
        score: best.score,
        candidates: walkers_keep(distinct, by_walkers, |(c, _)| &c.a_from_b, &p.walkers)
            .into_iter()
            .enumerate()
            .map(|(k, (c, _))| {
                let walls = if k == 0 {
                    covariance
                } else {
                    covariance_at(a, b, &c.a_from_b, p).0
                };
                // Once: the pose joined with the walkers has their evidence already.
                let fit = by_walkers.filter(|_| !(fixing.is_some() && k == 0));
                Candidate {
                    covariance: weighed_with_walkers(&walls, &c.a_from_b, fit, p),
                    ..c
                }
            })
            .collect(),
        hypotheses: hypotheses_count,
        icp_iterations: icp.iterations,
        motion: evidence.first().copied(),
        walkers: by_walkers.cloned(),
        nobody_walked_s: nobody_walked(a, b, p),
    }
}

/// How long the two watched together with no walker in either view, once that is long
/// enough to have expected one (`MotionParams::confirm_after_s`).
fn nobody_walked(a: &ScanModel, b: &ScanModel, p: &RegisterParams) -> Option<f64> {
    let (ma, mb) = (a.motion.as_ref()?, b.motion.as_ref()?);
    let watched_s = ma.watched_with(mb);
    (watched_s >= p.motion.confirm_after_s && ma.walkers() + mb.walkers() == 0).then_some(watched_s)
}

/// The pair placed by people alone (`"evidence":"walkers"`): where the fit passes the
/// stricter `alone_*` thresholds, the walls see no free space violated at its pose, and no
/// more than `max_through_share` of the walkers both saw are seen through there; a rival
/// with too many walks of its own stops it only where the rival passes those two too. Where the
/// walls share a view at the walkers' pose (`min_overlap`), they polish it (a walker pose is
/// biased 10–20 cm by bodies' shapes) and must keep it in the walkers' basin; if they pull it
/// away, walls and walkers disagree and nothing is placed.
pub(crate) fn placed_by_walkers(
    a: &ScanModel,
    b: &ScanModel,
    fit: &WalkerFit,
    hypotheses: usize,
    p: &RegisterParams,
) -> Option<PairResult> {
    let (ma, mb) = (a.motion.as_ref()?, b.motion.as_ref()?);
    if !fit.places_alone_but_for_its_rival(&p.walkers) {
        return None;
    }
    if fit.has_rival(&p.walkers) && !fit.rival.is_some_and(|r| people_fail_at(a, b, &r, p)) {
        return None;
    }
    let mut pose = fit.a_from_b;
    let mut at = score(a, b, &pose, p);
    if at.overlap() >= p.min_overlap {
        pose = polish(a, b, &pose, p);
        if !fit.near(&pose, &p.walkers) {
            return None;
        }
        at = score(a, b, &pose, p);
    }
    let e = co_motion(ma, mb, &pose, &p.motion);
    if people_fail(&at, &e, p) {
        return None;
    }
    let covariance = fit.biased_covariance(&p.walkers);
    Some(PairResult {
        verdict: Ok(()),
        a_from_b: pose,
        covariance,
        match_score: match_score(a, b, &pose, p),
        ambiguity: fit.rival_share(),
        overlap: at.overlap(),
        score: at,
        candidates: vec![Candidate {
            a_from_b: pose,
            score: at,
            covariance,
        }],
        hypotheses,
        icp_iterations: 0,
        motion: Some(e),
        walkers: Some(WalkerFit {
            alone: true,
            ..fit.clone()
        }),
        nobody_walked_s: None,
    })
}

/// The walls' score of a pose the walkers chose, where a beam passing above or below what the
/// other unit saw (by more than `WalkerParams::chosen_free_space_dz_m`) does not contradict
/// it. Between two units at different heights the walls disagree where it matters least: a
/// privacy screen, a counter or a shelf top between the two beams, which the higher one
/// passes over, or a monitor on a desk the lower one passes under, are contradictions by the
/// walls' own score (which may not assume what a unit saw ends where its beam does), and at
/// 0.2–0.4 m apart they cost a right pose a third of its points. A unit tilted down meets the
/// ceiling with its rear beams, a line of returns 2.5 m up that a level unit's beams pass
/// under: at the true pose that cost 14–17 % of the points (held-out office, `eval --only
/// sim --motion-seconds 30 --seed 7`). The walkers have checked free space with people
/// themselves (`lead_with_walkers`), so the walls need not count either. (The walls' own
/// score keeps counting what a beam passes under: from walls alone, a tilted unit's ceiling
/// line, right over the wall it is mounted on, refutes look-alikes; not counting it cost 4–5
/// right pairs at ≥ 30 % and made 1–2 wrong ones of 300, held-out seeds 1–2.)
fn walls_under_walkers(
    a: &ScanModel,
    b: &ScanModel,
    best: &Candidate,
    p: &RegisterParams,
) -> PoseScore {
    let lenient = RegisterParams {
        free_space_dz_m: p.free_space_dz_m.min(p.walkers.chosen_free_space_dz_m),
        free_space_dz_below_m: p
            .free_space_dz_below_m
            .min(p.walkers.chosen_free_space_dz_m),
        ..p.clone()
    };
    score(a, b, &best.a_from_b, &lenient)
}

/// What a pose people propose must pass, and a rival of theirs fail: free space no more
/// violated than a wall match may, and few of the walkers both saw seen through.
fn people_fail(at: &PoseScore, e: &MotionEvidence, p: &RegisterParams) -> bool {
    at.violation() > p.max_violation
        || e.refutes(&p.motion)
        || e.seen_through as f64 > p.walkers.max_through_share * e.seen as f64
}

/// [`people_fail`] at `at` (B's pose in A's frame); true without walkers in both scans.
fn people_fail_at(a: &ScanModel, b: &ScanModel, at: &Pose2, p: &RegisterParams) -> bool {
    let (Some(ma), Some(mb)) = (&a.motion, &b.motion) else {
        return true;
    };
    people_fail(&score(a, b, at, p), &co_motion(ma, mb, at, &p.motion), p)
}

/// The walker fit, when it decides the pose (what registration acts on; eval's calibration
/// of walker fits measures these).
pub fn decisive_walkers(a: &ScanModel, b: &ScanModel, p: &RegisterParams) -> Option<WalkerFit> {
    let (ma, mb) = (a.motion.as_ref()?, b.motion.as_ref()?);
    deciding(a, b, fit_walkers(ma, mb, &p.walkers, &p.motion)?, p)
}

/// `fit`, if it decides the pose: decisive as fitted, or once a runner-up that fails
/// [`people_fail`] no longer counts. Walkers all along one corridor agree nearly as often
/// with a pose turned a few degrees or slid a metre or two, which lays the corridor's walls
/// across the other's view.
pub fn deciding(
    a: &ScanModel,
    b: &ScanModel,
    fit: WalkerFit,
    p: &RegisterParams,
) -> Option<WalkerFit> {
    if fit.decisive(&p.walkers) {
        return Some(fit);
    }
    let fit = fit.without(|q| people_fail_at(a, b, q, p));
    fit.decisive(&p.walkers).then_some(fit)
}

/// The walls refined from the walkers' pose: where no wall candidate lies in the walkers'
/// basin (the walls' hypotheses missed it: a shop's shelving hides the corners both see) it
/// joins the others, with what the walkers say of it, to face the same checks; where one
/// does but this one scores better, it takes that one's place (a refinement that started
/// elsewhere can stop short along a weak direction, 15–20 cm off, where the walkers' start
/// does not). It counts only if the walls keep it in the basin: the walkers choose the place,
/// the walls still give the pose.
pub(super) fn propose_from_walkers(
    a: &ScanModel,
    b: &ScanModel,
    fit: &WalkerFit,
    distinct: &mut Vec<(Candidate, IcpResult)>,
    evidence: &mut Vec<MotionEvidence>,
    p: &RegisterParams,
) {
    let (Some(ma), Some(mb)) = (&a.motion, &b.motion) else {
        return;
    };
    if distinct.len() != evidence.len() {
        return;
    }
    let (icp, score) = refine_scored(a, b, &fit.a_from_b, p, p.class_aware);
    if !fit.near(&icp.a_from_b, &p.walkers) {
        return;
    }
    let candidate = Candidate {
        a_from_b: icp.a_from_b,
        score,
        covariance: Matrix3::zeros(),
    };
    // Best first: the first in the basin is the best the walls found there.
    let in_basin = distinct
        .iter()
        .position(|(c, _)| fit.near(&c.a_from_b, &p.walkers));
    if in_basin.is_some_and(|k| distinct[k].0.score.value >= candidate.score.value) {
        return;
    }
    let e = co_motion(ma, mb, &candidate.a_from_b, &p.motion);
    if e.refutes(&p.motion) {
        return;
    }
    match in_basin {
        Some(k) => {
            distinct[k] = (candidate, icp);
            evidence[k] = e;
        }
        None => {
            distinct.push((candidate, icp));
            evidence.push(e);
        }
    }
}

/// Puts the wall candidate in the walkers' basin first (with its walker evidence): the
/// walkers pick among the poses the walls allow, the walls give the pose. `false` when no wall
/// candidate lies there, or when it fails the walkers' own check (it puts too many of them
/// where the other sensor saw through): then nothing moves. Walkers alone are not precise
/// enough to place a sensor (a body's shape and the time between two scans bias them by
/// 10–20 cm), only to choose.
fn lead_with_walkers(
    fit: &WalkerFit,
    distinct: &mut Vec<(Candidate, IcpResult)>,
    evidence: &mut Vec<MotionEvidence>,
    p: &RegisterParams,
) -> bool {
    let Some(k) = distinct
        .iter()
        .position(|(c, _)| fit.near(&c.a_from_b, &p.walkers))
    else {
        return false;
    };
    let e = evidence.get(k).copied().unwrap_or_default();
    if e.refutes(&p.motion) || e.seen_through as f64 > p.walkers.max_through_share * e.seen as f64 {
        return false;
    }
    let lead = distinct.remove(k);
    if k < evidence.len() {
        evidence.remove(k);
    }
    distinct.insert(0, lead);
    evidence.insert(0, e);
    true
}

/// Refined candidates with what the walkers say of each.
type Sifted = (
    Vec<(Candidate, IcpResult)>,
    Vec<MotionEvidence>,
    Option<(Candidate, MotionEvidence)>,
);

/// People both sensors saw walk rule out candidates the walls cannot: the look-alike room,
/// the corridor turned end for end. Returns the candidates left (in order) with their
/// evidence, and the best one ruled out. Without people in both scans, all are left.
fn sift_by_people(
    a: &ScanModel,
    b: &ScanModel,
    candidates: Vec<(Candidate, IcpResult)>,
    p: &RegisterParams,
) -> Sifted {
    let (Some(ma), Some(mb)) = (&a.motion, &b.motion) else {
        return (candidates, Vec::new(), None);
    };
    let evidence: Vec<MotionEvidence> = candidates
        .par_iter()
        .map(|(c, _)| co_motion(ma, mb, &c.a_from_b, &p.motion))
        .collect();
    let (mut left, mut left_evidence, mut refuted) = (Vec::new(), Vec::new(), None);
    for (candidate, e) in candidates.into_iter().zip(evidence) {
        if e.refutes(&p.motion) {
            refuted = refuted.or(Some((candidate.0, e)));
        } else {
            left.push(candidate);
            left_evidence.push(e);
        }
    }
    (left, left_evidence, refuted)
}

/// Whether people rule `rival` out as a rival of the best pose: they confirm the best
/// (`MotionParams::settle_min_seen` walkers both saw there, at most `max_through_share` of
/// them seen through) and saw none at `rival` over a stretch long enough to expect one, so
/// that `rival`, were it the best, would be refused as not confirmed. Without walkers in both
/// scans, nothing is ruled out.
/// `expected`: the two watched long enough, with people walking, to expect a walker both saw
/// at a right pose (`unconfirmed`'s test).
fn outwatched(
    best: Option<&MotionEvidence>,
    rival: Option<&MotionEvidence>,
    expected: bool,
    p: &RegisterParams,
) -> bool {
    let (Some(best), Some(rival)) = (best, rival) else {
        return false;
    };
    expected && best.confirms(p) && rival.seen == 0
}

/// How long the two sensors watched together, when that is long enough to expect a walker
/// both saw at the best pose and none was (`MotionParams::confirm_after_s`).
fn unconfirmed(
    a: &ScanModel,
    b: &ScanModel,
    best: Option<MotionEvidence>,
    p: &RegisterParams,
) -> Option<f64> {
    let (ma, mb) = (a.motion.as_ref()?, b.motion.as_ref()?);
    let watched_s = ma.watched_with(mb);
    let seen = best.is_some_and(|e| e.seen > 0);
    // Where no one walked at all (an empty hall), the walls decide: the pose is reported as
    // not confirmed by people (`PairResult::nobody_walked_s`), not refused.
    let anyone = ma.walkers() + mb.walkers() > 0;
    (watched_s >= p.motion.confirm_after_s && !seen && anyone).then_some(watched_s)
}

/// Where the scans settle from `init`: narrow-gate point-to-line ICP, both ways (the last step
/// of `register_pair`). Eval also starts it at a reference pose, to tell a wrong answer from a
/// reference the scans themselves dispute.
pub fn polish(a: &ScanModel, b: &ScanModel, init: &Pose2, p: &RegisterParams) -> Pose2 {
    let narrow = RegisterParams {
        max_correspondence_m: p.min_correspondence_m * 1.5,
        ..p.clone()
    };
    symmetric_refine(a, b, init, &narrow)
}

/// Point-to-line ICP aligns B's points onto A's lines; with sparse scans each direction alone
/// leans its heading towards the denser side. The mean of both directions is fairer.
fn symmetric_refine(a: &ScanModel, b: &ScanModel, init: &Pose2, p: &RegisterParams) -> Pose2 {
    let forward = super::icp::refine(a, b, init, p, p.class_aware).a_from_b;
    let backward = super::icp::refine(b, a, &init.inverse(), p, p.class_aware)
        .a_from_b
        .inverse();
    let yaw = forward.rotation.angle()
        + 0.5
            * crate::geometry::wrap_angle_rad(backward.rotation.angle() - forward.rotation.angle());
    let t = 0.5 * (forward.translation.vector + backward.translation.vector);
    pose2(t.x, t.y, yaw)
}

/// ICP cannot see along `axis_deg` (every matched surface is parallel to it); the free-space
/// score may still pin the pose there (a door recess, a corridor's end). True when poses slid
/// ±0.25 m and ±0.5 m along the axis score nearly as well as the best.
fn slides_freely(
    a: &ScanModel,
    b: &ScanModel,
    best: &Candidate,
    axis_deg: f64,
    p: &RegisterParams,
) -> bool {
    let axis = nalgebra::Vector2::new(axis_deg.to_radians().cos(), axis_deg.to_radians().sin());
    let best_value = best.score.value;
    let ratios: Vec<f64> = [-0.5, -0.25, 0.25, 0.5]
        .iter()
        .map(|&d| {
            let shift = axis * d;
            let moved = crate::geometry::pose2(shift.x, shift.y, 0.0) * best.a_from_b;
            score(a, b, &moved, p).value / best_value
        })
        .collect();
    ratios.iter().any(|r| *r > p.slide_ratio)
}

/// Linearises once more at `a_from_b` with a narrow gate: that is the information the scans
/// carry about the pose (the guarded ICP may have stopped at an early, wide-gate iterate).
/// Returns its covariance and the direction of a translation the scans do not constrain.
fn covariance_at(
    a: &ScanModel,
    b: &ScanModel,
    a_from_b: &Pose2,
    p: &RegisterParams,
) -> (Matrix3<f64>, Option<f64>) {
    let narrow = RegisterParams {
        icp_max_iterations: 1,
        max_correspondence_m: 0.2,
        ..p.clone()
    };
    let at = super::icp::refine(a, b, a_from_b, &narrow, p.class_aware);
    covariance_of(&at, p)
}

/// The position σ (along the worst direction, m) and heading σ (rad) when either exceeds its
/// limit: a pose whose own uncertainty is wider than the accuracy promised is not reported.
fn too_uncertain(covariance: &Matrix3<f64>, p: &RegisterParams) -> Option<(f64, f64)> {
    let (sigma_m, sigma_rad) = pose_sigmas(covariance);
    let within = sigma_m <= p.max_sigma_m && sigma_rad <= p.max_sigma_rad;
    (!within).then_some((sigma_m, sigma_rad))
}

/// The walls' pose and covariance joined with the walkers' fit (information-weighted, the
/// fit's covariance widened by its bias, [`WalkerFit::biased_covariance`]): where the walls
/// fix a direction they keep it, where they cannot the walkers' pose holds it.
fn joined_with_walkers(
    walls: &Pose2,
    covariance: &Matrix3<f64>,
    fit: &WalkerFit,
    p: &RegisterParams,
) -> (Pose2, Matrix3<f64>) {
    let people = information(&fit.biased_covariance(&p.walkers));
    let Some(joined) = joined_information(covariance, &people) else {
        return (*walls, *covariance);
    };
    let step = joined * people * pose_delta(walls, &fit.a_from_b);
    (pose_step(walls, &step), joined)
}

/// The covariance of the walls' evidence and the walkers' (`people`, as information) together.
fn joined_information(walls: &Matrix3<f64>, people: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    (information(walls) + people).try_inverse()
}

/// What the site weighs a candidate at `at` by: the walls' covariance and, where people both
/// saw walking agree with it (`fit` near it), theirs, information-weighted, the fit's widened
/// by its bias. The pose stays the walls'; what the walls leave loose (a glass front's walls
/// fix nothing across it), the walkers' σ bounds.
fn weighed_with_walkers(
    walls: &Matrix3<f64>,
    at: &Pose2,
    fit: Option<&WalkerFit>,
    p: &RegisterParams,
) -> Matrix3<f64> {
    let Some(fit) = fit.filter(|f| f.near(at, &p.walkers)) else {
        return *walls;
    };
    joined_information(walls, &information(&fit.biased_covariance(&p.walkers))).unwrap_or(*walls)
}

fn information(c: &Matrix3<f64>) -> Matrix3<f64> {
    floored_inverse(c, 0.0, 1e-12)
}

/// `m` (symmetric) inverted through its eigenvalues, each taken as at least `relative` of the
/// largest and at least `absolute`: a nearly singular matrix gives a huge value along its weak
/// direction rather than a negative or NaN one.
fn floored_inverse(m: &Matrix3<f64>, relative: f64, absolute: f64) -> Matrix3<f64> {
    let e = m.symmetric_eigen();
    let floor = (relative * e.eigenvalues.max()).max(absolute);
    let inv = e.eigenvalues.map(|l| 1.0 / l.max(floor));
    e.eigenvectors * Matrix3::from_diagonal(&inv) * e.eigenvectors.transpose()
}

/// A pose's position σ along its worst direction (m: the largest eigenvalue of the xy block)
/// and heading σ (rad), from its (x, y, yaw) covariance: the one reading of a covariance
/// every σ gate uses (the walls' `too_uncertain`, the walkers' `places_alone`).
pub fn pose_sigmas(covariance: &Matrix3<f64>) -> (f64, f64) {
    let xy = covariance.fixed_view::<2, 2>(0, 0).into_owned();
    let sigma_m = xy.symmetric_eigen().eigenvalues.max().max(0.0).sqrt();
    (sigma_m, covariance[(2, 2)].max(0.0).sqrt())
}

/// Covariance σ²·(JᵀWJ)⁻¹, inflated for correlated residuals, and the direction (deg) of a
/// translation the scans do not constrain, if any.
fn covariance_of(icp: &IcpResult, p: &RegisterParams) -> (Matrix3<f64>, Option<f64>) {
    let h = icp.hessian;
    let sigma = if icp.rms_m.is_finite() {
        icp.rms_m.clamp(0.01, 1.0)
    } else {
        1.0
    };
    // Floored at 1e-9 of its largest eigenvalue: a huge variance along a weak direction.
    let covariance = floored_inverse(&h, 1e-9, 1e-21) * (sigma * sigma * p.covariance_inflation);
    let tt = h.fixed_view::<2, 2>(0, 0).into_owned();
    let eig = tt.symmetric_eigen();
    let (k_min, k_max) = if eig.eigenvalues[0] <= eig.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let share =
        eig.eigenvalues[k_min] / (eig.eigenvalues[k_min] + eig.eigenvalues[k_max]).max(1e-12);
    let weak = (share < p.min_constraint_share).then(|| {
        let v = eig.eigenvectors.column(k_min);
        v[1].atan2(v[0]).to_degrees().rem_euclid(180.0)
    });
    (covariance, weak)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn icp_with(hessian: Matrix3<f64>, rms_m: f64) -> IcpResult {
        IcpResult {
            a_from_b: Pose2::identity(),
            iterations: 1,
            hessian,
            rms_m,
            correspondences: 100,
        }
    }

    /// Walls that fix nothing across a glass front (σ of kilometres) and walkers that agree
    /// with their candidate: the candidate carries the walkers' σ, so the site can vouch for
    /// it; a candidate the walkers do not agree with keeps the walls' own.
    #[test]
    fn a_candidate_the_walls_leave_loose_is_weighed_by_the_walkers_who_agree() {
        let p = RegisterParams::default();
        let at = pose2(3.0, 1.0, 0.4);
        let fit = WalkerFit {
            a_from_b: at,
            inliers: 200,
            span_s: 20.0,
            spread_m: 6.0,
            rms_m: 0.06,
            others: vec![(10, pose2(-2.0, 5.0, 1.5))],
            walks: 8,
            runner_up_walks: 0,
            rival: None,
            covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(4e-4, 4e-4, 1e-5)),
            alone: false,
            torso_area_m2: None,
        };
        let walls = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e6, 1e6, 1e-2));
        let (with_m, with_rad) = pose_sigmas(&weighed_with_walkers(&walls, &at, Some(&fit), &p));
        // The walkers' σ (2 cm, 0.18°) widened by a chosen body's bias (5 cm).
        assert!(
            with_m < 0.06 && with_rad < 0.2f64.to_radians(),
            "{with_m} {with_rad}"
        );
        let elsewhere = pose2(7.0, 1.0, 0.4);
        let apart = weighed_with_walkers(&walls, &elsewhere, Some(&fit), &p);
        assert_eq!(apart, walls);
        assert_eq!(weighed_with_walkers(&walls, &at, None, &p), walls);
    }

    #[test]
    fn a_rival_people_never_saw_at_does_not_make_a_confirmed_pose_ambiguous() {
        let p = RegisterParams::default();
        let e = |seen, seen_through| MotionEvidence { seen, seen_through };
        let many = p.motion.settle_min_seen;
        // Confirmed best, a rival no one was seen at, over a stretch that expected someone.
        assert!(outwatched(Some(&e(many, 0)), Some(&e(0, 0)), true, &p));
        assert!(outwatched(Some(&e(many, 0)), Some(&e(0, 3)), true, &p));
        // A rival with a walker both saw stays a rival.
        assert!(!outwatched(Some(&e(many, 0)), Some(&e(1, 0)), true, &p));
        // A best too few people confirm, or that many see through, rules nothing out.
        assert!(!outwatched(Some(&e(many - 1, 0)), Some(&e(0, 0)), true, &p));
        assert!(!outwatched(Some(&e(many, many)), Some(&e(0, 0)), true, &p));
        // Too short a watch (or no one walking) to expect a walker: no evidence either way.
        assert!(!outwatched(Some(&e(many, 0)), Some(&e(0, 0)), false, &p));
        // Without walkers in both scans.
        assert!(!outwatched(None, None, true, &p));
    }

    #[test]
    fn under_walkers_beams_above_or_below_what_the_other_saw_do_not_contradict_it() {
        use crate::register::score::tests::facing;
        let p = RegisterParams::default();
        // Both at one spot: the unit at 1.0 m hits a counter 3 m out, the one at 1.3 m sees
        // over it to the wall at 6 m; 0.3 m apart, within the walls' `free_space_dz_m`.
        let (low, high) = (facing(3.0, Some(1.0)), facing(6.0, Some(1.3)));
        let best = Candidate {
            a_from_b: Pose2::identity(),
            score: score(&high, &low, &Pose2::identity(), &p),
            covariance: Matrix3::zeros(),
        };
        assert!(best.score.violation() > 0.9, "{:?}", best.score);
        let chosen = walls_under_walkers(&high, &low, &best, &p);
        assert!(chosen.violation() < 0.01, "{chosen:?}");
        // Nor does one passing under what the other saw (a monitor on a desk, a tilted unit's
        // line of ceiling returns), which the walls' own score counts: things stand on the floor.
        let (low_far, high_near) = (facing(6.0, Some(1.0)), facing(3.0, Some(1.3)));
        let best = Candidate {
            score: score(&low_far, &high_near, &Pose2::identity(), &p),
            ..best
        };
        assert!(best.score.violation() > 0.9, "{:?}", best.score);
        let chosen = walls_under_walkers(&low_far, &high_near, &best, &p);
        assert!(chosen.violation() < 0.01, "{chosen:?}");
        // A beam within `chosen_free_space_dz_m` of the point still contradicts it.
        let level_far = facing(6.0, Some(1.28));
        let chosen = walls_under_walkers(&level_far, &high_near, &best, &p);
        assert!(chosen.violation() > 0.9, "{chosen:?}");
    }

    #[test]
    fn people_disagreeing_also_say_why_the_pose_they_leave_is_not_reported() {
        let left = Abstain::WeakMatch { score: 0.08 };
        let why = Abstain::PeopleDisagree {
            seen_through: 12,
            seen: 3,
            left: Some(Box::new(left)),
        }
        .to_string();
        assert!(
            why.starts_with("people disagree: at the best pose 12 walkers"),
            "{why}"
        );
        assert!(
            why.ends_with("; the best pose they leave: weak match (score 0.08)"),
            "{why}"
        );
        let alone = Abstain::PeopleDisagree {
            seen_through: 12,
            seen: 3,
            left: None,
        };
        assert!(alone.to_string().ends_with("a look-alike place"), "{alone}");
    }

    #[test]
    fn one_reading_of_a_covariance_its_worst_direction() {
        // σ 2.5 cm along x and y, correlated 0.9: 3.4 cm along the diagonal.
        let s2 = 0.025f64.powi(2);
        let cov = Matrix3::new(s2, 0.9 * s2, 0.0, 0.9 * s2, s2, 0.0, 0.0, 0.0, 1e-6);
        let (sigma_m, sigma_rad) = pose_sigmas(&cov);
        assert!((sigma_m - 0.025 * 1.9f64.sqrt()).abs() < 1e-6, "{sigma_m}");
        assert!((sigma_rad - 1e-3).abs() < 1e-9);
    }

    #[test]
    fn a_singular_system_gives_a_huge_finite_variance_and_is_too_uncertain() {
        let p = RegisterParams::default();
        // Only x and yaw constrained (a corridor along y); inverting directly gives garbage.
        let h = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e4, 0.0, 1e4));
        let (cov, _) = covariance_of(&icp_with(h, 0.02), &p);
        assert!(cov.iter().all(|v| v.is_finite()));
        assert!((0..3).all(|k| cov[(k, k)] >= 0.0));
        assert!(cov[(1, 1)] > 1.0 && cov[(0, 0)] < 1e-4);
        let (sigma_m, _) = too_uncertain(&cov, &p).expect("a free direction is too uncertain");
        assert!(sigma_m > p.max_sigma_m);
    }

    #[test]
    fn a_well_constrained_pose_passes_and_a_loose_heading_does_not() {
        let p = RegisterParams::default();
        let tight = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e4, 1e4, 1e4));
        let (cov, _) = covariance_of(&icp_with(tight, 0.02), &p);
        assert_eq!(too_uncertain(&cov, &p), None);
        // Heading barely constrained: σ_yaw = 0.02·2/√0.5 rad ≈ 3°.
        let loose = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e4, 1e4, 0.5));
        let (cov, _) = covariance_of(&icp_with(loose, 0.02), &p);
        let (_, sigma_rad) = too_uncertain(&cov, &p).expect("loose heading");
        assert!(sigma_rad > p.max_sigma_rad);
        // A NaN residual (no correspondences) must not make a NaN covariance.
        let (cov, _) = covariance_of(&icp_with(tight, f64::NAN), &p);
        assert!(cov.iter().all(|v| v.is_finite()));
    }
}
