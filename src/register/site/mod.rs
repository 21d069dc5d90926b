//! The site solve (METHOD §4, seed 004): place every sensor in the anchor's frame from its pairs.
//! The pipeline, one stage per file: `pairs` registers the pairs; `groups` keeps the edges
//! cycles check and the views around their ends bear out (`neighbourhoods`) and binds sensors
//! into groups; `join` places the groups one at a time against everything placed;
//! `second_opinion` re-weighs every placement alone; `solve` is the joint weighted least
//! squares; `check` drops placements that contradict another's free space; `report` says where
//! each sensor stands or why it does not. This file owns the types and the order of the
//! stages. `add` places one sensor added to a placed site, and `settle` says where it stands
//! and how surely.

mod add;
mod check;
mod descriptor;
mod groups;
mod join;
mod memo;
mod neighbourhoods;
mod pairs;
mod report;
mod second_opinion;
mod settle;
mod solve;
#[cfg(test)]
pub(crate) mod tests;

pub use add::{AddedSensor, add_sensor};
pub use descriptor::{ViewDescriptor, rank_partners};
pub use groups::{bridges, consistent_edges, spanning_poses};
pub use pairs::{Skip, SkippedPair};
pub use solve::solve;

use super::{PairResult, RegisterParams, ScanModel};
use crate::geometry::{Mount, Pose2, Pose3};
use nalgebra::Matrix3;
use std::time::Instant;

/// How a caveat begins when walls alone placed a sensor and nobody walked to confirm it (the
/// daemon clears it once people do).
pub const UNCONFIRMED: &str = "is not confirmed by people";

/// `caveat` once people confirmed the pose: without its [`UNCONFIRMED`] part (what else it
/// says, such as resting on one pair, stays).
pub fn confirmed_caveat(caveat: &str) -> Option<String> {
    let rest = match caveat.find(UNCONFIRMED) {
        Some(k) => caveat
            .get(..k)
            .unwrap_or_default()
            .trim_end_matches("; it "),
        None => caveat,
    };
    let rest = rest.trim();
    (!rest.is_empty()).then(|| rest.to_string())
}

/// One sensor to place.
#[derive(Debug, Clone)]
pub struct SensorInput {
    pub id: String,
    pub model: ScanModel,
    pub mount: Mount,
    /// A surveyed pose in the anchor's frame, with its σ, if the installer has one.
    pub prior: Option<Prior>,
}

/// A surveyed pose and its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prior {
    pub anchor_from_sensor: Pose2,
    pub sigma_xy_m: f64,
    pub sigma_yaw_rad: f64,
    /// Where the surveyed sensor stands in the frame of the node the prior holds: identity
    /// when the node is the sensor itself; its pose in its zone when the node is a zone
    /// (`register::zones`: a unit of a zone surveyed in the site frame).
    pub node_from_sensor: Pose2,
}

impl Prior {
    /// A sensor surveyed at `anchor_from_sensor`, σ `sigma_xy_m` and `sigma_yaw_rad`.
    pub fn new(anchor_from_sensor: Pose2, sigma_xy_m: f64, sigma_yaw_rad: f64) -> Prior {
        Prior {
            anchor_from_sensor,
            sigma_xy_m,
            sigma_yaw_rad,
            node_from_sensor: Pose2::identity(),
        }
    }

    /// Where the node stands if the survey holds.
    pub fn anchor_from_node(&self) -> Pose2 {
        self.anchor_from_sensor * self.node_from_sensor.inverse()
    }
}

/// The surveyed sensors' priors, each on its own node.
pub fn priors_of(sensors: &[SensorInput]) -> Vec<(usize, Prior)> {
    sensors
        .iter()
        .enumerate()
        .filter_map(|(i, s)| Some((i, s.prior?)))
        .collect()
}

/// A measured relative pose between two sensors.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    pub a: usize,
    pub b: usize,
    pub a_from_b: Pose2,
    /// Covariance of (x, y, yaw) of `a_from_b`.
    pub covariance: Matrix3<f64>,
    /// Preference when building the first spanning tree (higher is stronger).
    pub strength: f64,
}

/// Thresholds of the graph stage.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteParams {
    /// An edge disagreeing with a cycle or with the tree by more than this is inconsistent.
    pub cycle_m: f64,
    pub cycle_rad: f64,
    /// Two candidate poses agreeing this well are one placement (and an unregistered pair's
    /// candidate this close to where the site puts the pair becomes an edge of the solve).
    pub confirm_m: f64,
    pub confirm_rad: f64,
    /// Floor on edge σ, so no single edge is trusted absolutely.
    pub min_sigma_m: f64,
    pub min_sigma_rad: f64,
    /// A group (sensors linked by edges that cycles check) joins the placed sensors only when
    /// no other placement its pairs propose scores at least this share of the best one, scored
    /// jointly against every placed sensor. As strict as a pair's own ambiguity limit: a joint
    /// score sums more evidence, but a mirror-symmetric room stays symmetric in all of it.
    pub join_max_ambiguity: f64,
    /// The best placement slid this far (m) in any direction must lose more than the pair's
    /// `slide_ratio` of its joint score, or the position is not fixed (a corridor seen
    /// lengthwise by every sensor that sees the group); ±0.25 and ±0.5 m as the pair check does.
    pub join_slide_m: [f64; 2],
    /// A join's strength, joint shared view × (1 − ambiguity), must reach this: the pair
    /// thresholds (`min_overlap` 0.2) are where a pair abstains, and a placement that a whole
    /// group rests on needs a margin above that. Over 30 simulated sites (eval seeds 1–3) the
    /// two wrong joins had 0.17 and 0.22, the 25 right ones 0.33 and more.
    pub join_min_strength: f64,
    /// The last check between every two placed sensors drops one whose scan lands in space the
    /// other saw empty, but counts only contradictions it is sure of: where the other's beam
    /// ran no more than this above the point (m). A beam passing below what a sensor saw would
    /// have hit it (objects stand on the floor); one passing above may have cleared a desk
    /// screen or a counter. Pair scoring weighs probable contradictions too
    /// (`free_space_dz_m`, 0.5 m), which ranks candidates well; this veto removes an already
    /// registered sensor, so it waits for certain ones. Over eval's sites (seeds 1–4, 40 of
    /// each kind per plan set) 0.5 m dropped 18 correctly placed sensors in the held-out plans
    /// (desks, screens and counters at 0.75–1.2 m) and 1 in the fixture plans; 0.2 / 0.1 / 0
    /// placed 14 / 17 / 18 of them back and no wrong one.
    pub conflict_dz_m: f64,
    /// A placed sensor whose pose the solve draws from fewer pairs than this (and no survey)
    /// gets a caveat: check it. Over eval's sites (seeds 1–3, 10 of each kind, both plan
    /// sets) placements on 1–2 pairs were wrong 5 times in 27, on 3 or more once in 536; all
    /// six wrong ones were in the held-out plans, where identical rooms repeat.
    pub confirming_pairs: usize,
    /// Pair selection (`pairs`): register first only each sensor's this many most alike
    /// views, the rest only where sensors stay unplaced or the site puts two sensors' views
    /// over each other. Sites of up to this many + 1 sensors register every pair either way.
    /// On generated concourses (`eval --only site --floor concourse --site-compare`, this
    /// 2-core machine) it placed exactly what every pair placed, to 0.00 mm: installed at 25
    /// (seeds 1–3, 75/75), 50 (seeds 1–2, 100/100) and 100 (seed 1, 100/100), dropped at
    /// random at 25 (39/75, none wrong); at 100 it registers 3444 of 4950 pairs, 8.8–8.9 s
    /// against 12.1 s. Its ranking is the weak part: of the pairs sharing ≥ 30 % of their
    /// view, the first 8 partners hold 25 % at 100 scanners (a concourse's bays look alike).
    /// Of the 3011 pairs before the generator kept dividers clear of scanners, 544 were first
    /// partners, about 350 closed triangles, 1070 tried sensors posed beside a neighbour and
    /// 970 went further down a ranking. `usize::MAX` registers every pair.
    pub partners: usize,
    /// An edge stands only where the views around its two ends bear it out: at most this
    /// share of the points where they meet may land in the other side's free space
    /// (`neighbourhoods`); zone links stand on the same share of their zones' whole views.
    pub whole_view_violation: f64,
    /// A sensor is placed only with σ within these (position, m; heading, rad): the site's
    /// own cycle tolerance (`cycle_m`, `cycle_rad`). A wider σ says the pairs that place it
    /// leave it loose, however well the joint score took it (a group joined through one pair
    /// that sees one wall or a glass front was placed right to 3 cm with σ 482 m / 8°:
    /// glass-shop, seed 1). Over eval's sites (seed 1: 10 per kind in both plan sets, two
    /// 50-unit concourses) placed sensors had σ up to 6.7 cm and 0.18°.
    pub placed_max_sigma_m: f64,
    pub placed_max_sigma_rad: f64,
}

impl Default for SiteParams {
    fn default() -> Self {
        SiteParams {
            cycle_m: 0.25,
            cycle_rad: 2.5f64.to_radians(),
            confirm_m: 0.15,
            confirm_rad: 1.5f64.to_radians(),
            min_sigma_m: 0.01,
            min_sigma_rad: 0.1f64.to_radians(),
            join_max_ambiguity: 0.5,
            join_slide_m: [0.25, 0.5],
            join_min_strength: 0.3,
            conflict_dz_m: 0.0,
            confirming_pairs: 3,
            partners: 8,
            whole_view_violation: 0.15,
            placed_max_sigma_m: 0.25,
            placed_max_sigma_rad: 2.5f64.to_radians(),
        }
    }
}

/// A sensor's place in the anchor's frame, or why it has none.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub id: String,
    pub pose: Result<PlacedPose, String>,
    /// For a placed sensor that rests on too few pairs (`SiteParams::confirming_pairs`) and
    /// no survey, what to check; for a surveyed one the scans contradict, that. None
    /// otherwise.
    pub caveat: Option<String>,
    /// A survey the scans put this far off (m, rad): the sensor stands where surveyed, and
    /// its scans were left out of the others' placement.
    pub survey_off: Option<(f64, f64)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlacedPose {
    /// x, y, yaw in the anchor's frame; z = mount height above the floor; pitch relative to
    /// the anchor's (METHOD §1).
    pub pose: Pose3,
    pub sigma_x_m: f64,
    pub sigma_y_m: f64,
    pub sigma_yaw_rad: f64,
}

/// What happened to one pair.
#[derive(Debug, Clone)]
pub struct PairReport {
    pub a: usize,
    pub b: usize,
    pub result: PairResult,
    /// The pair's pose entered the joint solve.
    pub used: bool,
}

#[derive(Debug, Clone)]
pub struct SiteResult {
    pub anchor: usize,
    pub sensors: Vec<Placement>,
    pub pairs: Vec<PairReport>,
    /// Pairs not registered (pair selection), and why.
    pub skipped: Vec<SkippedPair>,
    /// Rounds of pair selection it took.
    pub rounds: usize,
}

/// Registers the pairs of `sensors` that matter (`pairs`) and places all of them in the frame of `anchor`.
///
/// Edges that lie on a cycle of consistent registered pairs, or that people both sensors saw
/// walk confirmed, are trusted: they bind sensors into groups. Everything else — a registered
/// pair that the walls alone and no cycle check (a bridge), an ambiguous pair's candidates —
/// only proposes where a group stands, and a group joins the placed sensors only where its
/// scans fit every placed sensor's scan jointly, clearly better than anywhere else
/// proposed, and contradict none of them (`join`).
pub fn register_site(
    sensors: &[SensorInput],
    anchor: usize,
    p: &RegisterParams,
    sp: &SiteParams,
) -> SiteResult {
    let n = sensors.len();
    let mut selection = pairs::PairSelection::new(sensors, p, sp.partners);
    let mut round = selection.first_round();
    let mut rounds = 0;
    let mut cheap_done = false;
    // Scores of placements stay valid from round to round: pairs added propose new ones.
    let memo = memo::ScoreMemo::default();
    // Register a round of pairs, place what they place, widen where that leaves gaps.
    let placing = loop {
        rounds += 1;
        let started = Instant::now();
        selection.register(&round);
        tracing::debug!(
            "site round {rounds}: {} pairs registered in {:.2} s",
            round.len(),
            started.elapsed().as_secs_f64()
        );
        // Close the triangles the pairs make before weighing anything: cheap, and it binds
        // chains into groups, which the joins then need not weigh one by one.
        round = selection.close_triangles();
        if !round.is_empty() {
            continue;
        }
        // Widen from the groups alone (the anchor's group as placed) while that proposes
        // pairs: the joins are the dear stage, and more pairs make bigger groups.
        if !cheap_done {
            let (pairs, results) = selection.registered();
            let checked = groups::checked_edges(n, anchor, &pairs, &results, sensors, p, sp, &memo);
            let (placed, groups) = groups::groups(n, anchor, &checked.edges);
            let is_placed: Vec<bool> = placed.iter().map(Option::is_some).collect();
            round = selection.widen(&frames(&placed, &groups), &is_placed);
            if !round.is_empty() {
                continue;
            }
            cheap_done = true;
        }
        let placing = place(n, anchor, sensors, selection.registered(), p, sp, &memo);
        round = selection.widen(&placing.frame(), &placing.is_placed());
        if round.is_empty() {
            break placing;
        }
    };
    let Placing {
        pairs,
        results,
        checked,
        placed,
        groups,
        joined,
    } = placing;
    let skipped = selection.skipped(&frames(&placed, &groups));
    let started = Instant::now();
    let (edges, origin) =
        solve::solve_edges(&placed, &checked, &pairs, &results, &joined.sources, p, sp);
    let solved = check::solve_without_conflicts(n, anchor, edges, origin, sensors, p, sp);
    tracing::debug!(
        "site solve and free-space check: {:.2} s",
        started.elapsed().as_secs_f64()
    );
    let mut site = report::site_result(
        sensors,
        anchor,
        pairs,
        results,
        &groups,
        &joined.refusals,
        &solved,
        sp,
    );
    site.skipped = skipped;
    site.rounds = rounds;
    site
}

/// Where the stages before the solve put every sensor, from the pairs registered so far.
struct Placing {
    pairs: Vec<(usize, usize)>,
    results: Vec<PairResult>,
    checked: groups::Checked,
    /// Anchor-frame pose of every placed sensor.
    placed: Vec<Option<Pose2>>,
    groups: Vec<Vec<(usize, Pose2)>>,
    joined: join::Joined,
}

impl Placing {
    fn frame(&self) -> Vec<Option<(usize, Pose2)>> {
        frames(&self.placed, &self.groups)
    }

    fn is_placed(&self) -> Vec<bool> {
        self.placed.iter().map(Option::is_some).collect()
    }
}

/// Each sensor's frame and pose there: 0 the anchor's for a placed one, g + 1 for a member of
/// unplaced group g (relative to its root).
fn frames(placed: &[Option<Pose2>], groups: &[Vec<(usize, Pose2)>]) -> Vec<Option<(usize, Pose2)>> {
    let mut frame: Vec<Option<(usize, Pose2)>> =
        placed.iter().map(|p| p.map(|pose| (0, pose))).collect();
    for (g, members) in groups.iter().enumerate() {
        for &(m, pose) in members {
            if let Some(f) = frame.get_mut(m)
                && f.is_none()
            {
                *f = Some((g + 1, pose));
            }
        }
    }
    frame
}

/// The stages up to the second opinion, on `registered` pairs.
fn place(
    n: usize,
    anchor: usize,
    sensors: &[SensorInput],
    registered: (Vec<(usize, usize)>, Vec<PairResult>),
    p: &RegisterParams,
    sp: &SiteParams,
    memo: &memo::ScoreMemo,
) -> Placing {
    let (pairs, results) = registered;
    let started = Instant::now();
    let checked = groups::checked_edges(n, anchor, &pairs, &results, sensors, p, sp, memo);
    let (mut placed, mut groups) = groups::groups(n, anchor, &checked.edges);
    let grouped = started.elapsed().as_secs_f64();
    for members in groups.iter().filter(|g| g.len() > 1) {
        tracing::trace!(
            "group [{}]",
            members
                .iter()
                .map(|&(m, _)| sensors[m].id.as_str())
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    let joined = join::join_groups(
        &mut placed,
        &mut groups,
        sensors,
        &pairs,
        &results,
        p,
        sp,
        memo,
    );
    let joins = started.elapsed().as_secs_f64() - grouped;
    let placed_now = placed.iter().filter(|p| p.is_some()).count();
    if let Some(slow) = join::slow_joins(joins, joined.tally, placed_now, n) {
        tracing::warn!("{slow}");
    }
    let mut joined = joined;
    let withdrawn =
        second_opinion::second_opinion(&mut placed, anchor, sensors, &pairs, &results, p, sp, memo);
    // A withdrawn sensor stands alone, with why, as a group that could not join.
    for (k, why) in withdrawn {
        for g in groups.iter_mut() {
            g.retain(|&(m, _)| m != k);
        }
        groups.push(vec![(k, Pose2::identity())]);
        joined.refusals.push(Some(why));
    }
    tracing::debug!(
        "site stages: groups {grouped:.2} s ({} groups), joins {joins:.2} s, second opinion {:.2} s; {} pair scores kept",
        groups.len(),
        started.elapsed().as_secs_f64() - grouped - joins,
        memo.len()
    );
    Placing {
        pairs,
        results,
        checked,
        placed,
        groups,
        joined,
    }
}

/// How far each sensor's points reach from it (m): two sensors farther apart than the sum of
/// theirs plus `REACH_MARGIN_M` cannot hit or contradict each other's scans.
pub(super) fn reach_m(sensors: &[SensorInput]) -> Vec<f64> {
    sensors
        .iter()
        .map(|s| s.model.reach_m() + REACH_MARGIN_M)
        .collect()
}

/// Beyond the hit radius and free-space margins of scoring.
const REACH_MARGIN_M: f64 = 1.0;

/// The edge a pair's candidate `ci` makes (candidate 0 is the pair's own answer), with the
/// covariance linearised at that candidate.
pub(super) fn candidate_edge(pair: (usize, usize), r: &PairResult, ci: usize) -> Option<Edge> {
    let c = r.candidates.get(ci)?;
    Some(Edge {
        a: pair.0,
        b: pair.1,
        a_from_b: c.a_from_b,
        covariance: c.covariance,
        strength: strength(r),
    })
}

fn strength(r: &PairResult) -> f64 {
    r.overlap * (1.0 - r.ambiguity).max(0.05)
}
