//! Joins: each group not yet placed is weighed against every placed sensor jointly (the
//! placements its pairs' candidates propose, scored against all placed scans; refused when
//! ambiguous, weak, contradicted or free to slide), and the best-supported acceptable group
//! joins first, one at a time, since each join is evidence for the rest. People walking weigh
//! in three times: a placement a pair's walkers decided stands on their walks where walls
//! share too little or let it slide, candidates they refuted propose nothing, and a best
//! placement that puts a member's walkers where a placed sensor saw straight through (or the
//! reverse) is refused, whichever pair proposed it. Owns `Refusal`, the reasons a group stays
//! unplaced.

use super::memo::ScoreMemo;
use super::{SensorInput, SiteParams};
use crate::geometry::{Pose2, pose_error, pose2};
use crate::register::motion::co_motion;
use crate::register::{Abstain, Candidate, PairResult, RegisterParams};
use rayon::prelude::*;

/// What the joins leave: why each group is unplaced (None if joined or not weighed) and the
/// (pair, candidate) proposals of every join.
pub(super) struct Joined {
    pub refusals: Vec<Option<Refusal>>,
    pub sources: Vec<(usize, usize)>,
    /// (joins, groups weighed, placements scored): what the stage's time went on.
    pub tally: (usize, usize, usize),
}

/// Places surveyed groups at their surveys, then joins the other groups one at a time, the
/// best-supported first; splits off a member that contradicts where the rest of its group fits.
#[allow(clippy::too_many_arguments)] // the stage inputs, as `second_opinion` and `site_result`
pub(super) fn join_groups(
    placed: &mut [Option<Pose2>],
    groups: &mut Vec<Vec<(usize, Pose2)>>,
    sensors: &[SensorInput],
    pairs: &[(usize, usize)],
    results: &[PairResult],
    p: &RegisterParams,
    sp: &SiteParams,
    memo: &ScoreMemo,
) -> Joined {
    // Join the groups one at a time, the best-supported first: each join adds evidence
    // (placed sensors to check against) for the rest.
    let mut refusals: Vec<Option<Refusal>> = vec![None; groups.len()];
    // A group with a surveyed member stands where its best survey puts it (the solve weighs
    // the survey against the edges later); from there it is evidence for the groups that join.
    let mut open: Vec<usize> = Vec::new();
    for (g, members) in groups.iter().enumerate() {
        let surveyed = members
            .iter()
            .filter_map(|&(m, root_from_m)| Some((sensors.get(m)?.prior?, root_from_m)))
            .min_by(|x, y| x.0.sigma_xy_m.total_cmp(&y.0.sigma_xy_m));
        let Some((prior, root_from_m)) = surveyed else {
            open.push(g);
            continue;
        };
        let anchor_from_root = prior.anchor_from_sensor * root_from_m.inverse();
        for &(m, root_from_member) in members {
            placed[m] = Some(anchor_from_root * root_from_member);
        }
    }
    let mut join_sources: Vec<(usize, usize)> = Vec::new();
    let reach_m = super::reach_m(sensors);
    // Each sensor's partners in some pair: a join gives a group new proposals only through them.
    let mut partners: Vec<Vec<usize>> = vec![Vec::new(); sensors.len()];
    for &(a, b) in pairs {
        if a < partners.len() && b < partners.len() {
            partners[a].push(b);
            partners[b].push(a);
        }
    }
    // A group's last verdict (with its slide test, once run) and the placements it scored:
    // kept until a join could change it (`changes`), since weighing is the dear part.
    let mut cache: Vec<Option<Weighed>> = vec![None; groups.len()];
    let (mut weighs, mut weighed_places, mut joins) = (0usize, 0usize, 0usize);
    loop {
        let ctx = JoinContext {
            sensors,
            placed: placed
                .iter()
                .enumerate()
                .filter_map(|(i, pose)| pose.map(|pose| (i, pose)))
                .collect(),
            pairs,
            results,
            p,
            sp,
            reach_m: &reach_m,
            memo: Some(memo),
        };
        let mut acceptable = Vec::new();
        let mut split = Vec::new();
        cache.resize(groups.len(), None);
        for &g in &open {
            let weighed = cache[g].get_or_insert_with(|| {
                let (outcome, places) = ctx.weigh_at(&groups[g]);
                weighs += 1;
                weighed_places += places.len();
                Weighed {
                    outcome,
                    places,
                    slid: None,
                }
            });
            match weighed.outcome.clone() {
                Ok(join) => acceptable.push((g, join)),
                Err(Refusal::MemberContradicts { member }) => split.push((g, member)),
                Err(why) => refusals[g] = Some(why),
            }
        }
        // A group whose best placement a minority of its members contradict: their checked
        // edges were wrong after all (or they see what the others do not); weigh them apart.
        if !split.is_empty() {
            for (g, member) in split {
                cache[g] = None;
                groups[g].retain(|(m, _)| *m != member);
                groups.push(vec![(member, Pose2::identity())]);
                refusals.push(None);
                open.push(groups.len() - 1);
            }
            continue;
        }
        acceptable.sort_by(|x, y| y.1.priority().total_cmp(&x.1.priority()));
        // The slide test is the dearest: run it on the front-runners only, in order.
        let mut joined = None;
        for (g, join) in acceptable {
            let slid = match cache[g].as_ref().and_then(|w| w.slid.clone()) {
                Some(slid) => slid,
                None => ctx.slides(&groups[g], &join),
            };
            if let Some(w) = cache[g].as_mut() {
                w.slid = Some(slid.clone());
            }
            match slid {
                Some(why) => refusals[g] = Some(why),
                None => {
                    joined = Some((g, join));
                    break;
                }
            }
        }
        let Some((g, join)) = joined else { break };
        joins += 1;
        tracing::trace!(
            "join {joins}: [{}] at ({:.2}, {:.2}) value {:.2} overlap {:.2} ambiguity {:.2}, from pairs {}",
            groups[g]
                .iter()
                .map(|&(m, _)| sensors[m].id.as_str())
                .collect::<Vec<_>>()
                .join(" "),
            join.anchor_from_root.translation.x,
            join.anchor_from_root.translation.y,
            join.score.value,
            join.score.overlap,
            join.ambiguity,
            join.sources
                .iter()
                .map(|&(k, ci)| format!(
                    "{}–{} #{ci}",
                    sensors[pairs[k].0].id, sensors[pairs[k].1].id
                ))
                .collect::<Vec<_>>()
                .join(", ")
        );
        for &(m, root_from_member) in &groups[g] {
            placed[m] = Some(join.anchor_from_root * root_from_member);
        }
        join_sources.extend(join.sources);
        refusals[g] = None;
        open.retain(|&o| o != g);
        let joined: Vec<(usize, Pose2)> = groups[g]
            .iter()
            .filter_map(|&(m, _)| Some((m, placed[m]?)))
            .collect();
        for &o in &open {
            let stale = cache[o]
                .as_ref()
                .is_some_and(|w| w.changes(&groups[o], &joined, &partners, &reach_m));
            if stale {
                cache[o] = None;
            }
        }
    }
    tracing::debug!("joins: {joins} joins, {weighs} groups weighed at {weighed_places} placements");
    Joined {
        refusals,
        sources: join_sources,
        tally: (joins, weighs, weighed_places),
    }
}

/// Joins that took longer than this (s) are said at a terminal, not only in the debug log:
/// a 200-unit concourse spends 11 minutes a pass in them, and a person waiting at a silent
/// `register` cannot tell it from a hang.
const SLOW_JOINS_S: f64 = 60.0;

/// What to say of joins that took `took_s`: (joins, groups weighed, placements scored), and
/// how many of `sensors` are placed after them. None when they were quick.
pub(super) fn slow_joins(
    took_s: f64,
    (joins, weighs, places): (usize, usize, usize),
    placed: usize,
    sensors: usize,
) -> Option<String> {
    (took_s > SLOW_JOINS_S).then(|| {
        format!(
            "site registration: placing groups of units against each other took {took_s:.0} s ({weighs} groups weighed at {places} placements, {joins} joined; {placed} of {sensors} units placed so far) and may take as long again: on a long floor whose parts look alike, surveyed poses for a few units far apart (`survey` in the config, or dragged on the page) settle it sooner"
        )
    })
}

/// A group's verdict against the sensors placed so far.
#[derive(Clone)]
struct Weighed {
    outcome: Result<Join, Refusal>,
    /// Anchor-frame placements of the group's root that were scored.
    places: Vec<Pose2>,
    /// The slide test's verdict, once run on an acceptable outcome.
    slid: Option<Option<Refusal>>,
}

impl Weighed {
    /// Whether sensors just placed (`joined`, anchor-frame poses) could change the verdict: one
    /// is in a pair with a member (a new proposal), or within reach of a member at some scored
    /// placement (a new term of its joint score). Otherwise weighing again gives the same.
    fn changes(
        &self,
        group: &[(usize, Pose2)],
        joined: &[(usize, Pose2)],
        partners: &[Vec<usize>],
        reach_m: &[f64],
    ) -> bool {
        let reach = |k: usize| reach_m.get(k).copied().unwrap_or(f64::INFINITY);
        joined.iter().any(|&(m, at_m)| {
            group.iter().any(|&(j, root_from_j)| {
                partners.get(m).is_some_and(|p| p.contains(&j))
                    || self.places.iter().any(|place| {
                        let at_j = place * root_from_j;
                        (at_j.translation.vector - at_m.translation.vector).norm()
                            <= reach(j) + reach(m)
                    })
            })
        })
    }
}

/// Why a group was not joined to the placed sensors.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Refusal {
    /// No pair between it and a placed sensor has a candidate that respects free space.
    NoProposal,
    /// Every proposed placement puts a scan in space a placed sensor saw empty (or the
    /// reverse); the best-scoring one contradicts `with` on this share of points.
    Contradicts { with: usize, violation: f64 },
    /// The best-scoring placement fits every placed sensor but for a few members' scans, which
    /// contradict one's free space: the group is weighed again without this one.
    MemberContradicts { member: usize },
    /// The best placement the walls allow puts people a member saw walking where placed
    /// sensor `with` saw straight through at that moment (or the reverse): a look-alike place.
    PeopleSawThrough { with: usize },
    /// The best placement is proposed only by pairs that share too little view or fit poorly.
    NoPairStands,
    /// The best placement shares too little view with the placed sensors.
    TooLittle { overlap: f64 },
    /// It shares view, but free-space violations outweigh the hits.
    Outweighed { value: f64 },
    /// Shared view and the rival's score together leave too thin a margin.
    Weak { overlap: f64, ambiguity: f64 },
    /// A clearly different placement fits the placed sensors nearly as well.
    Ambiguous {
        ratio: f64,
        apart_m: f64,
        apart_deg: f64,
    },
    /// Sliding the best placement along this direction costs almost nothing.
    Slides { axis_deg: f64 },
    /// Only placed sensor `with` shares its view, and that pair alone does not register.
    LonePair { with: usize, why: String },
    /// Placed with its group, but more of its pairs with the rest of the site put it
    /// elsewhere (`against` pairs to `support`), and that place is refused in turn (`then`):
    /// withdrawn by the second opinion rather than left where the site outvotes it.
    Outvoted {
        support: usize,
        against: usize,
        then: Box<Refusal>,
    },
    /// Placed, but the pairs it rests on leave its pose looser than a placed sensor's may be
    /// (`SiteParams::placed_max_sigma_m`, `placed_max_sigma_rad`): σ of position (m) and
    /// heading (rad).
    Loose { sigma_m: f64, sigma_yaw_rad: f64 },
}

impl Refusal {
    /// `Loose` where σ (x, y, yaw) is wider than a placed sensor's may be.
    pub(super) fn loose(sigma: &[f64; 3], sp: &SiteParams) -> Option<Refusal> {
        let sigma_m = sigma[0].hypot(sigma[1]);
        let sigma_yaw_rad = sigma[2];
        // NaN is loose too: a solve that could not say how sure it is.
        let within = sigma_m <= sp.placed_max_sigma_m && sigma_yaw_rad <= sp.placed_max_sigma_rad;
        (!within).then_some(Refusal::Loose {
            sigma_m,
            sigma_yaw_rad,
        })
    }

    pub(super) fn describe<'a>(&self, id: &impl Fn(usize) -> &'a str) -> String {
        const HELP: &str = "survey it, or add a sensor that sees both it and a placed one";
        match self {
            Refusal::MemberContradicts { member } => format!(
                "its placement is contradicted where {} stands; {HELP}",
                id(*member)
            ),
            Refusal::NoProposal => {
                format!("it shares no usable view with any placed sensor; {HELP}")
            }
            Refusal::Contradicts { with, violation } => format!(
                "every placement its pairs propose puts a scan in space {} saw empty ({:.0} % of points); {HELP}",
                id(*with),
                violation * 100.0
            ),
            Refusal::PeopleSawThrough { with } => format!(
                "where the walls fit it best, people it saw walking stand where {} saw straight through at that moment (a look-alike place); {HELP}",
                id(*with)
            ),
            Refusal::NoPairStands => format!(
                "its best placement rests only on pairs with too little shared view or a poor fit; {HELP}"
            ),
            Refusal::TooLittle { overlap } => format!(
                "its best placement shares only {:.0} % of its view with the placed sensors, too little to place it; {HELP}",
                overlap * 100.0
            ),
            Refusal::Outweighed { value } => format!(
                "at its best placement, points in the placed sensors' free space outweigh the shared view (score {value:.2}); {HELP}"
            ),
            // Without a rival the margin is the shared view alone: say so, not "0 % as well".
            Refusal::Weak { overlap, ambiguity } if *ambiguity < 0.005 => format!(
                "its best placement shares only {:.0} % of its view with the placed sensors, too little to rest a placement on; {HELP}",
                overlap * 100.0
            ),
            Refusal::Weak { overlap, ambiguity } => format!(
                "its best placement shares {:.0} % of its view with the placed sensors and another scores {:.0} % as well, too thin a margin to place it; {HELP}",
                overlap * 100.0,
                ambiguity * 100.0
            ),
            Refusal::Ambiguous {
                ratio,
                apart_m,
                apart_deg,
            } => format!(
                "two placements fit the placed sensors about equally (the other, {apart_m:.2} m / {apart_deg:.0}° away, scores {:.0} % as well: a mirror image or repeated structure); {HELP}",
                ratio * 100.0
            ),
            Refusal::LonePair { with, why } => format!(
                "only {} of the placed sensors shares its view, and that pair alone is not registered ({why}); {HELP}",
                id(*with)
            ),
            Refusal::Outvoted {
                support,
                against,
                then,
            } => format!(
                "its group put it where {support} of its pairs agree, but {against} put it elsewhere (a look-alike place?), and there: {}",
                then.describe(id)
            ),
            Refusal::Loose {
                sigma_m,
                sigma_yaw_rad,
            } => format!(
                "its scans fit the placed sensors', but the pairs that place it fix it only loosely (σ {sigma_m:.2} m / {:.1}°: what they share holds too little across some direction); survey it, add a sensor that sees both it and a placed one, or let people walk where it and a placed sensor both look",
                sigma_yaw_rad.to_degrees()
            ),
            Refusal::Slides { axis_deg } => format!(
                "its position along {axis_deg:.0}° is not fixed by what the placed sensors see (a corridor seen lengthwise); survey it, or add a sensor that sees across"
            ),
        }
    }
}

/// Where a group stands, chosen jointly against every placed sensor.
#[derive(Debug, Clone)]
pub(super) struct Join {
    pub(super) anchor_from_root: Pose2,
    /// (pair, candidate) of every proposal of this placement.
    pub(super) sources: Vec<(usize, usize)>,
    pub(super) score: Joint,
    /// The best rival placement's joint score over this one's (0 = none).
    pub(super) ambiguity: f64,
    /// A pair people placed proposes it: their walks fix it where walls let it slide.
    pub(super) walked: bool,
}

/// Whether people walking refuted every candidate of the pair (`Abstain::PeopleDisagree`):
/// then none proposes a placement or speaks for or against one. Weighed by walls alone
/// against the placed sensors, a look-alike the walkers had refuted joined six correctly
/// bound units 12 m and 90° off the anchor (held-out shop, `eval --only drawing`).
fn refuted_by_people(r: &PairResult) -> bool {
    matches!(r.verdict, Err(Abstain::PeopleDisagree { .. }))
}

impl Join {
    pub(super) fn priority(&self) -> f64 {
        self.score.value * (1.0 - self.ambiguity)
    }
}

/// A placement's scores against every placed sensor, summed over those pairs.
#[derive(Debug, Clone)]
pub(super) struct Joint {
    pub(super) value: f64,
    pub(super) overlap: f64,
    /// The worst pair's violation share, and the placed sensor of that pair.
    pub(super) violation: f64,
    pub(super) worst: usize,
    /// Members in some pair over the violation limit.
    pub(super) violating: Vec<usize>,
    /// (placed, member) pairs that share at least `min_overlap` of their view here.
    pub(super) witnesses: Vec<(usize, usize)>,
}

/// One placement the proposals agree on, with its joint score.
#[derive(Debug, Clone)]
pub(super) struct Proposal {
    pub(super) anchor_from_root: Pose2,
    /// (pair, candidate) of every proposal of this placement.
    pub(super) sources: Vec<(usize, usize)>,
    pub(super) joint: Joint,
}

/// What a join is weighed against.
pub(super) struct JoinContext<'a> {
    pub(super) sensors: &'a [SensorInput],
    /// Placed sensors and their poses in the anchor's frame.
    pub(super) placed: Vec<(usize, Pose2)>,
    pub(super) pairs: &'a [(usize, usize)],
    pub(super) results: &'a [PairResult],
    pub(super) p: &'a RegisterParams,
    pub(super) sp: &'a SiteParams,
    /// Each sensor's reach (`reach_m`): the joint score skips placed sensors out of it.
    pub(super) reach_m: &'a [f64],
    /// Pair scores computed before (None: score every term afresh).
    pub(super) memo: Option<&'a ScoreMemo>,
}

impl JoinContext<'_> {
    /// Scores a group (members with `root_from_member`) placed at `anchor_from_root` against
    /// every placed sensor.
    pub(super) fn joint(&self, group: &[(usize, Pose2)], anchor_from_root: &Pose2) -> Joint {
        let terms = self.terms(group, anchor_from_root);
        let score = |i: usize, j: usize, i_from_j: &Pose2| {
            crate::register::score::score(
                &self.sensors[i].model,
                &self.sensors[j].model,
                i_from_j,
                self.p,
            )
        };
        let scores = match self.memo {
            Some(memo) => memo.scores(&terms, score),
            None => terms
                .iter()
                .map(|(i, j, pose)| score(*i, *j, pose))
                .collect(),
        };
        let mut joint = Joint {
            value: 0.0,
            overlap: 0.0,
            violation: 0.0,
            worst: 0,
            violating: Vec::new(),
            witnesses: Vec::new(),
        };
        for (&(i, j, _), s) in terms.iter().zip(scores) {
            joint.value += s.value;
            joint.overlap += s.overlap();
            if s.violation() > joint.violation {
                joint.violation = s.violation();
                joint.worst = i;
            }
            if s.violation() > self.p.max_violation && !joint.violating.contains(&j) {
                joint.violating.push(j);
            }
            if s.overlap() >= self.p.min_overlap {
                joint.witnesses.push((i, j));
            }
        }
        joint
    }

    /// Every (placed, member) pair within reach of each other with the group at
    /// `anchor_from_root`, and the member's pose in the placed sensor's frame, in this order
    /// (the worst and the witnesses of `joint` are the first found): out of each other's
    /// reach, no hit, no contradiction, nothing.
    fn terms(
        &self,
        group: &[(usize, Pose2)],
        anchor_from_root: &Pose2,
    ) -> Vec<(usize, usize, Pose2)> {
        let reach = |k: usize| self.reach_m.get(k).copied().unwrap_or(f64::INFINITY);
        let mut terms = Vec::new();
        for &(i, anchor_from_i) in &self.placed {
            for &(j, root_from_j) in group {
                if i >= self.sensors.len() || j >= self.sensors.len() {
                    continue;
                }
                let i_from_j = anchor_from_i.inverse() * anchor_from_root * root_from_j;
                if i_from_j.translation.vector.norm() <= reach(i) + reach(j) {
                    terms.push((i, j, i_from_j));
                }
            }
        }
        terms
    }

    /// The placed sensor whose walkers a member, with the group at `anchor_from_root`, saw
    /// straight through at that moment, or the reverse, as often as refutes a pair's candidate
    /// (`MotionEvidence::refutes`). The walls' joint score cannot tell a look-alike room from
    /// the right one; people walking can, as they do for a pair.
    fn refuted_by_walkers(
        &self,
        group: &[(usize, Pose2)],
        anchor_from_root: &Pose2,
    ) -> Option<usize> {
        self.terms(group, anchor_from_root)
            .into_iter()
            .find(|(i, j, i_from_j)| {
                let (Some(mi), Some(mj)) = (
                    self.sensors[*i].model.motion.as_ref(),
                    self.sensors[*j].model.motion.as_ref(),
                ) else {
                    return false;
                };
                // Only level planes at torso height: a pitched beam crosses people at their
                // legs somewhere along its way, and passes between them.
                if !(mi.sees_torsos() && mj.sees_torsos()) {
                    return false;
                }
                co_motion(mi, mj, i_from_j, &self.p.motion).refutes(&self.p.motion)
            })
            .map(|(i, _, _)| i)
    }

    /// The candidates of every pair between sensor `k` and a placed sensor, each with its pair
    /// index, where it puts `k` (anchor's frame) and whether that is `anchor_from_k` (within
    /// `confirm_m` / `confirm_rad`); candidates that contradict free space are left out.
    pub(super) fn opinions_on(
        &self,
        k: usize,
        anchor_from_k: Pose2,
    ) -> impl Iterator<Item = (usize, &Candidate, Pose2, bool)> + '_ {
        self.pairs
            .iter()
            .zip(self.results)
            .enumerate()
            .filter_map(move |(pair, (&(a, b), r))| {
                let (other, k_is_b) = match (a == k, b == k) {
                    (true, false) => (b, false),
                    (false, true) => (a, true),
                    _ => return None,
                };
                if refuted_by_people(r) {
                    return None;
                }
                let (_, anchor_from_other) = self.placed.iter().find(|(i, _)| *i == other)?;
                let other_from_k = anchor_from_other.inverse() * anchor_from_k;
                Some(r.candidates.iter().filter_map(move |c| {
                    let said = if k_is_b {
                        c.a_from_b
                    } else {
                        c.a_from_b.inverse()
                    };
                    let (dt, dyaw) = pose_error(&said, &other_from_k);
                    let agrees = dt <= self.sp.confirm_m && dyaw <= self.sp.confirm_rad;
                    let proposed = anchor_from_other * said;
                    (c.score.violation() <= self.p.max_violation)
                        .then_some((pair, c, proposed, agrees))
                }))
            })
            .flatten()
    }

    /// Whether a candidate with enough shared view and fit to stand alone puts `k` elsewhere
    /// than `anchor_from_k`.
    pub(super) fn standing_dissent(&self, k: usize, anchor_from_k: Pose2) -> bool {
        self.opinions_on(k, anchor_from_k).any(|(_, c, _, agrees)| {
            !agrees && c.score.overlap() >= self.p.min_overlap && c.score.value >= self.p.min_score
        })
    }

    /// How many pairs have a candidate that puts `k` at `anchor_from_k`.
    pub(super) fn support(&self, k: usize, anchor_from_k: Pose2) -> usize {
        let mut pairs: Vec<usize> = self
            .opinions_on(k, anchor_from_k)
            .filter_map(|(pair, _, _, agrees)| agrees.then_some(pair))
            .collect();
        pairs.dedup();
        pairs.len()
    }

    /// Every distinct placement the candidates of pairs between the group and a placed
    /// sensor propose, scored jointly; the best is accepted when it contradicts no placed
    /// sensor, shares enough view, and no clearly different placement scores nearly as well.
    pub(super) fn weigh(&self, group: &[(usize, Pose2)]) -> Result<Join, Refusal> {
        self.weigh_at(group).0
    }

    /// `weigh`, and every placement (of the group's root) it scored.
    fn weigh_at(&self, group: &[(usize, Pose2)]) -> (Result<Join, Refusal>, Vec<Pose2>) {
        let scored = self.proposals(group);
        let places = scored.iter().map(|c| c.anchor_from_root).collect();
        (self.judge(group, &scored), places)
    }

    /// Every distinct placement the group's pairs with placed sensors propose, scored jointly.
    fn proposals(&self, group: &[(usize, Pose2)]) -> Vec<Proposal> {
        // Lookups by sensor, not searches: every group is weighed again after each join.
        let by_sensor = |list: &[(usize, Pose2)]| {
            let mut at = vec![None; self.sensors.len()];
            for &(i, pose) in list {
                if let Some(slot) = at.get_mut(i) {
                    *slot = Some(pose);
                }
            }
            at
        };
        let (placed_at, member_at) = (by_sensor(&self.placed), by_sensor(group));
        let pose_of = |s: usize| placed_at.get(s).copied().flatten();
        let member = |s: usize| member_at.get(s).copied().flatten();
        let mut proposals: Vec<(f64, Pose2, (usize, usize))> = Vec::new();
        for (k, (&(a, b), r)) in self.pairs.iter().zip(self.results).enumerate() {
            if refuted_by_people(r) {
                continue;
            }
            let (anchor_from_placed, root_from_member, member_is_b) =
                match (pose_of(a), member(b), pose_of(b), member(a)) {
                    (Some(pa), Some(rb), _, _) => (pa, rb, true),
                    (_, _, Some(pb), Some(ra)) => (pb, ra, false),
                    _ => continue,
                };
            for (ci, c) in r.candidates.iter().enumerate() {
                if c.score.violation() > self.p.max_violation {
                    continue;
                }
                let placed_from_member = if member_is_b {
                    c.a_from_b
                } else {
                    c.a_from_b.inverse()
                };
                let anchor_from_root =
                    anchor_from_placed * placed_from_member * root_from_member.inverse();
                proposals.push((c.score.value, anchor_from_root, (k, ci)));
            }
        }
        proposals.sort_by(|x, y| y.0.total_cmp(&x.0));
        // One placement per cluster of proposals that agree (the best-scoring one stands for it).
        let mut placements: Vec<(Pose2, Vec<(usize, usize)>)> = Vec::new();
        for (_, pose, source) in proposals {
            // Position first: the heading costs two arctangents, and most proposals lie apart.
            let same = placements.iter_mut().find(|(q, _)| {
                (q.translation.vector - pose.translation.vector).norm() <= self.sp.confirm_m
                    && pose_error(q, &pose).1 <= self.sp.confirm_rad
            });
            match same {
                Some((_, sources)) => sources.push(source),
                None => placements.push((pose, vec![source])),
            }
        }
        let scored: Vec<Proposal> = placements
            .into_par_iter()
            .map(|(anchor_from_root, sources)| Proposal {
                joint: self.joint(group, &anchor_from_root),
                anchor_from_root,
                sources,
            })
            .collect();
        scored
    }

    /// The verdict on a group's scored placements (`weigh`).
    fn judge(&self, group: &[(usize, Pose2)], scored: &[Proposal]) -> Result<Join, Refusal> {
        let by_value = |x: &&Proposal, y: &&Proposal| x.joint.value.total_cmp(&y.joint.value);
        // A minority of members contradicting the placed sensors where the rest fit best is
        // split off (one at a time); a majority contradicting means the placement is wrong.
        if let Some(top) = scored.iter().max_by(by_value)
            && let Some(&member) = top.joint.violating.first()
            && top.joint.violating.len() * 2 < group.len()
        {
            return Err(Refusal::MemberContradicts { member });
        }
        let viable: Vec<&Proposal> = scored
            .iter()
            .filter(|c| c.joint.violation <= self.p.max_violation)
            .collect();
        let Some(best) = viable.iter().copied().max_by(by_value) else {
            return Err(match scored.iter().max_by(by_value) {
                Some(c) => Refusal::Contradicts {
                    with: c.joint.worst,
                    violation: c.joint.violation,
                },
                None => Refusal::NoProposal,
            });
        };
        // People walking veto the walls' best where they saw through it; the next best is
        // not taken instead (the walls' look-alikes come in families, and what the walkers
        // left unchecked is no better than what they refuted).
        if let Some(with) = self.refuted_by_walkers(group, &best.anchor_from_root) {
            return Err(Refusal::PeopleSawThrough { with });
        }
        let joint = &best.joint;
        // Third sensors settle which of a pair's answers is right; they do not make a placement
        // out of scraps: one proposal must stand on its own pair's shared view and fit.
        let stands_alone = best.sources.iter().any(|&(k, ci)| {
            self.results
                .get(k)
                .and_then(|r| r.candidates.get(ci))
                .is_some_and(|c| {
                    c.score.overlap() >= self.p.min_overlap && c.score.value >= self.p.min_score
                })
        });
        // A pair people placed (alone or choosing among the walls' answers) stands on their
        // walks, not on how much wall the two share: the walls' share thresholds do not apply.
        let walked = self.walkers_placed(&best.sources);
        if !stands_alone && !walked {
            return Err(Refusal::NoPairStands);
        }
        if let Some(refusal) = self.lone_witness_abstains(group, &best.joint, &best.sources) {
            return Err(refusal);
        }
        if joint.overlap < self.p.min_overlap && !walked {
            return Err(Refusal::TooLittle {
                overlap: joint.overlap,
            });
        }
        if joint.value < self.p.min_score && !walked {
            return Err(Refusal::Outweighed { value: joint.value });
        }
        // The strongest rival: any placement that is not the same answer. One that contradicts
        // a placed sensor yet fits the rest so well that it nearly matches the best (its
        // violations are already charged in its score) means the evidence conflicts.
        let rival = scored
            .iter()
            .filter(|c| {
                let (dt, dyaw) = pose_error(&c.anchor_from_root, &best.anchor_from_root);
                dt >= self.p.same_pose_m || dyaw >= self.p.same_pose_rad
            })
            .max_by(by_value);
        let ambiguity = rival.map_or(0.0, |r| (r.joint.value / joint.value).max(0.0));
        if let Some(r) = rival
            && ambiguity >= self.sp.join_max_ambiguity
        {
            let (apart_m, apart_rad) = pose_error(&r.anchor_from_root, &best.anchor_from_root);
            return Err(Refusal::Ambiguous {
                ratio: ambiguity,
                apart_m,
                apart_deg: apart_rad.to_degrees(),
            });
        }
        if joint.overlap * (1.0 - ambiguity) < self.sp.join_min_strength && !walked {
            return Err(Refusal::Weak {
                overlap: joint.overlap,
                ambiguity,
            });
        }
        Ok(Join {
            anchor_from_root: best.anchor_from_root,
            sources: best.sources.clone(),
            score: best.joint.clone(),
            ambiguity,
            walked,
        })
    }

    /// Whether one of `sources` is the answer of a pair that registered with people deciding
    /// (`PairResult::walkers`): their walks passed the walker fit's own limits (sightings, time,
    /// floor, residual, rival).
    fn walkers_placed(&self, sources: &[(usize, usize)]) -> bool {
        sources.iter().any(|&(k, ci)| {
            self.results.get(k).is_some_and(|r| {
                r.registered()
                    && r.walkers.is_some()
                    && r.candidates.get(ci).is_some_and(|c| {
                        let (dt, dyaw) = pose_error(&c.a_from_b, &r.a_from_b);
                        dt < self.p.same_pose_m && dyaw < self.p.same_pose_rad
                    })
            })
        })
    }

    /// A lone sensor that only one placed sensor shares view with is that pair's answer and
    /// nothing more: no third sensor checks it. Then it stands only where the pair, registered
    /// alone, would put it; otherwise the pair's own reason for abstaining is the refusal.
    /// (Placing through such a pair's other candidates, or past its σ and corridor checks, made
    /// a site of two sensors confidently wrong more often than the pair alone.) A group joining
    /// is checked by its other members' views of the placed sensors' walls and free space as
    /// well, so the walls' reasons are weighed afresh for it; but not whether people confirmed
    /// it: a pair people walked by without confirming is walls alone, and a group of office
    /// cells matches a row of look-alike cells as well as one cell does (a held-out site had
    /// three units joined 8 m off that way).
    pub(super) fn lone_witness_abstains(
        &self,
        group: &[(usize, Pose2)],
        joint: &Joint,
        sources: &[(usize, usize)],
    ) -> Option<Refusal> {
        let [(i, j)] = joint.witnesses.as_slice() else {
            return None;
        };
        let k = self
            .pairs
            .iter()
            .position(|&(a, b)| (a, b) == (*i, *j) || (a, b) == (*j, *i))?;
        let r = self.results.get(k)?;
        if group.len() > 1 && !matches!(r.verdict, Err(Abstain::Unconfirmed { .. })) {
            return None;
        }
        let why = match &r.verdict {
            Err(why) => why.to_string(),
            Ok(()) if !sources.contains(&(k, 0)) => {
                "its best answer is another placement".to_string()
            }
            Ok(()) => return None,
        };
        Some(Refusal::LonePair { with: *i, why })
    }

    /// A slide of the placement (every 15°, by each of `join_slide_m` both ways) that keeps
    /// the pair check's `slide_ratio` of the joint score: the position is not fixed along it.
    /// None for a placement people walked: the walls' slide is what their walks fix.
    pub(super) fn slides(&self, group: &[(usize, Pose2)], join: &Join) -> Option<Refusal> {
        if join.walked {
            return None;
        }
        let shifts: Vec<(f64, f64)> = (0..12)
            .flat_map(|k| {
                let deg = 15.0 * k as f64;
                self.sp
                    .join_slide_m
                    .iter()
                    .flat_map(move |&d| [(deg, d), (deg, -d)])
            })
            .collect();
        shifts
            .par_iter()
            .find_first(|&&(deg, d)| {
                let rad = f64::to_radians(deg);
                let moved = pose2(d * rad.cos(), d * rad.sin(), 0.0) * join.anchor_from_root;
                self.joint(group, &moved).value > self.p.slide_ratio * join.score.value
            })
            .map(|&(deg, _)| Refusal::Slides { axis_deg: deg })
    }
}
