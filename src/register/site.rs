//! The site solve (METHOD §4, seed 004): register every pair, drop edges that disagree around
//! cycles, let third sensors decide pairs that are ambiguous alone, and solve all kept edges
//! jointly by weighted least squares with the anchor fixed (and surveyed priors, if any).

use super::{Candidate, PairResult, RegisterParams, ScanModel, register_pair};
use crate::geometry::{Mount, Pose2, Pose3, pose_error, pose2, wrap_angle_rad, yaw_rad};
use nalgebra::{DMatrix, DVector, Matrix3};
use rayon::prelude::*;

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
        }
    }
}

/// A sensor's place in the anchor's frame, or why it has none.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub id: String,
    pub pose: Result<PlacedPose, String>,
    /// For a placed sensor that rests on too few pairs (`SiteParams::confirming_pairs`) and
    /// no survey: what to check. None otherwise.
    pub caveat: Option<String>,
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
}

/// Registers every pair of `sensors` and places all of them in the frame of `anchor`.
///
/// Edges that lie on a cycle of consistent registered pairs are trusted: they bind sensors into
/// groups. Everything else — a registered pair no cycle checks (a bridge), an ambiguous pair's
/// candidates — only proposes where a group stands, and a group joins the placed sensors only
/// where its scans fit every placed sensor's scan jointly, clearly better than anywhere else
/// proposed, and contradict none of them (`weigh_join`).
pub fn register_site(
    sensors: &[SensorInput],
    anchor: usize,
    p: &RegisterParams,
    sp: &SiteParams,
) -> SiteResult {
    let n = sensors.len();
    let pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
        .collect();
    let results: Vec<PairResult> = pairs
        .par_iter()
        .map(|&(a, b)| register_pair(&sensors[a].model, &sensors[b].model, p))
        .collect();

    let mut registered = Vec::new();
    let mut registered_origin = Vec::new(); // pair index per edge
    for (k, (&pair, r)) in pairs.iter().zip(&results).enumerate() {
        if r.registered()
            && let Some(edge) = candidate_edge(pair, r, 0)
        {
            registered.push(edge);
            registered_origin.push(k);
        }
    }
    let kept = consistent_edges(n, anchor, &registered, sp);
    let kept_edges: Vec<Edge> = kept.iter().map(|&e| registered[e].clone()).collect();
    let unchecked = bridges(n, &kept_edges);
    let (mut inner, mut inner_origin) = (Vec::new(), Vec::new());
    for (k, &e) in kept.iter().enumerate() {
        if !unchecked.contains(&k) {
            inner.push(registered[e].clone());
            inner_origin.push((registered_origin[e], 0));
        }
    }

    // Groups: sensors bound by checked edges, poses relative to the group's first member.
    let mut placed = spanning_poses(n, anchor, &inner);
    let mut groups: Vec<Vec<(usize, Pose2)>> = Vec::new();
    for (root, pose) in placed.iter().enumerate() {
        if pose.is_some() || groups.iter().flatten().any(|(m, _)| *m == root) {
            continue;
        }
        let members = spanning_poses(n, root, &inner)
            .iter()
            .enumerate()
            .filter_map(|(m, pose)| pose.map(|pose| (m, pose)))
            .collect();
        groups.push(members);
    }

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
    loop {
        let ctx = JoinContext {
            sensors,
            placed: placed
                .iter()
                .enumerate()
                .filter_map(|(i, pose)| pose.map(|pose| (i, pose)))
                .collect(),
            pairs: &pairs,
            results: &results,
            p,
            sp,
        };
        let mut acceptable = Vec::new();
        let mut split = Vec::new();
        for &g in &open {
            match ctx.weigh(&groups[g]) {
                Ok(join) => acceptable.push((g, join)),
                Err(Refusal::MemberContradicts { member }) => split.push((g, member)),
                Err(why) => refusals[g] = Some(why),
            }
        }
        // A group whose best placement a minority of its members contradict: their checked
        // edges were wrong after all (or they see what the others do not); weigh them apart.
        if !split.is_empty() {
            for (g, member) in split {
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
            match ctx.slides(&groups[g], &join) {
                Some(why) => refusals[g] = Some(why),
                None => {
                    joined = Some((g, join));
                    break;
                }
            }
        }
        let Some((g, join)) = joined else { break };
        for &(m, root_from_member) in &groups[g] {
            placed[m] = Some(join.anchor_from_root * root_from_member);
        }
        join_sources.extend(join.sources);
        refusals[g] = None;
        open.retain(|&o| o != g);
    }

    second_opinion(&mut placed, anchor, sensors, &pairs, &results, p, sp);

    // The solve's edges: checked edges that agree with where the site put their sensors, then
    // for every other pair of placed sensors the candidate that agrees (the join's own
    // proposals always; others only with enough shared view to carry information).
    let (mut edges, mut origin) = (Vec::new(), Vec::new());
    for (e, o) in inner.iter().zip(&inner_origin) {
        let (Some(pa), Some(pb)) = (placed[e.a], placed[e.b]) else {
            continue;
        };
        let (dt, dyaw) = pose_error(&e.a_from_b, &(pa.inverse() * pb));
        if dt <= sp.cycle_m && dyaw <= sp.cycle_rad {
            edges.push(e.clone());
            origin.push(*o);
        }
    }
    for (k, (&(a, b), r)) in pairs.iter().zip(&results).enumerate() {
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

    // Every placed sensor must agree with every other placed sensor about free space, not
    // only with the ones it was registered to: a sensor hanging on one wrong edge has no cycle
    // to expose it, but its scan lands where a third sensor saw nothing. Drop the weaker side's
    // edges and solve again until no placement contradicts another (`contradicts`: certain
    // contradictions only).
    let mut solution = solve(n, anchor, &edges, sensors, sp);
    let mut contradicted = vec![None::<usize>; n];
    let certain = certain_only(p, sp);
    loop {
        let placed: Vec<(usize, Pose2)> = solution
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|(p, _)| (i, p)))
            .collect();
        let conflict = placed
            .par_iter()
            .flat_map_iter(|&(i, pi)| {
                placed
                    .iter()
                    .filter(move |(j, _)| *j > i)
                    .map(move |&(j, pj)| (i, pi, j, pj))
            })
            .find_first(|&(i, pi, j, pj)| {
                contradicts(
                    &sensors[i].model,
                    &sensors[j].model,
                    &(pi.inverse() * pj),
                    &certain,
                )
            })
            .map(|(i, _, j, _)| (i, j));
        let Some((i, j)) = conflict else { break };
        let support = |k: usize| edges.iter().filter(|e| e.a == k || e.b == k).count();
        // Never drop the anchor; otherwise the sensor with fewer edges loses them all.
        let loser = if i == anchor {
            j
        } else if j == anchor || support(i) < support(j) {
            i
        } else if support(j) < support(i) {
            j
        } else {
            i.max(j)
        };
        contradicted[loser] = Some(if loser == i { j } else { i });
        let keep: Vec<bool> = edges.iter().map(|e| e.a != loser && e.b != loser).collect();
        let mut k = 0;
        edges.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        let mut k = 0;
        origin.retain(|_| {
            k += 1;
            keep[k - 1]
        });
        solution = solve(n, anchor, &edges, sensors, sp);
    }
    let anchor_pitch = sensors.get(anchor).map_or(0.0, |s| s.mount.pitch_rad);
    let id = |k: usize| sensors.get(k).map_or("another sensor", |s| s.id.as_str());
    let caveat = |i: usize| {
        let mut partners: Vec<usize> = origin
            .iter()
            .filter_map(|&(k, _)| match pairs.get(k) {
                Some(&(a, b)) if a == i => Some(b),
                Some(&(a, b)) if b == i => Some(a),
                _ => None,
            })
            .collect();
        partners.sort_unstable();
        partners.dedup();
        let surveyed = sensors.get(i).is_some_and(|s| s.prior.is_some());
        // Where no one walked in any view it rests on, the walls alone decided.
        let nobody_walked = origin
            .iter()
            .filter(|&&(k, _)| pairs.get(k).is_some_and(|&(a, b)| a == i || b == i))
            .map(|&(k, _)| results.get(k).and_then(|r| r.nobody_walked_s))
            .collect::<Option<Vec<f64>>>()
            .and_then(|w| w.into_iter().reduce(f64::min));
        let unconfirmed = (i != anchor && !surveyed)
            .then_some(nobody_walked)
            .flatten()
            .map(|watched_s| {
                format!(
                    "{UNCONFIRMED}: no one walked in {watched_s:.0} s, so the walls alone placed \
                     it; walk through its shared views while recording to confirm it"
                )
            });
        let thin = (i != anchor && !surveyed && partners.len() < sp.confirming_pairs).then(|| {
            let with: Vec<&str> = partners.iter().map(|&k| id(k)).collect();
            format!(
                "rests on {} only ({}): where rooms or bays repeat that can be a look-alike \
                 spot; check it on the map, or survey it",
                match partners.len() {
                    1 => "one pair".to_string(),
                    n => format!("{n} pairs"),
                },
                match with.as_slice() {
                    [] => "no pair".to_string(),
                    _ => format!("with {}", with.join(", ")),
                }
            )
        });
        match (thin, unconfirmed) {
            (Some(t), Some(u)) => Some(format!("{t}; it {u}")),
            (t, u) => t.or(u),
        }
    };
    let placements = sensors
        .iter()
        .enumerate()
        .map(|(i, s)| Placement {
            id: s.id.clone(),
            caveat: solution.get(i).copied().flatten().and_then(|_| caveat(i)),
            pose: match solution.get(i).copied().flatten() {
                Some((pose, sigma)) => Ok(PlacedPose {
                    pose: Pose3::from_planar(
                        &pose,
                        s.mount.height_m.unwrap_or(0.0),
                        s.mount.pitch_rad - anchor_pitch,
                    ),
                    sigma_x_m: sigma[0],
                    sigma_y_m: sigma[1],
                    sigma_yaw_rad: sigma[2],
                }),
                None => Err(match contradicted[i] {
                    Some(j) => format!(
                        "its only registrations put its scan in space {} saw empty",
                        id(j)
                    ),
                    None => {
                        let g = groups.iter().position(|g| g.iter().any(|(m, _)| *m == i));
                        let others: Vec<&str> = g
                            .and_then(|g| groups.get(g))
                            .map(|g| g.iter().filter(|(m, _)| *m != i).map(|(m, _)| id(*m)))
                            .into_iter()
                            .flatten()
                            .collect();
                        let why = match g.and_then(|g| refusals.get(g).cloned().flatten()) {
                            Some(why) => why.describe(&id),
                            None => "no other sensor to register against".to_string(),
                        };
                        let why = match why_best_pair(i, &pairs, &results) {
                            Some(pair) if matches!(refusal_of(g, &refusals), Some(Refusal::NoProposal)) => {
                                format!("{why} (its best pair: {pair})")
                            }
                            _ => why,
                        };
                        if others.is_empty() {
                            why
                        } else {
                            format!(
                                "registered with {} (a group), but the group cannot be placed: {why}",
                                others.join(", ")
                            )
                        }
                    }
                }),
            },
        })
        .collect();
    let reports = pairs
        .iter()
        .zip(results)
        .enumerate()
        .map(|(k, (&(a, b), result))| PairReport {
            a,
            b,
            result,
            used: origin.iter().any(|o| o.0 == k),
        })
        .collect();
    SiteResult {
        anchor,
        sensors: placements,
        pairs: reports,
    }
}

fn refusal_of(group: Option<usize>, refusals: &[Option<Refusal>]) -> Option<&Refusal> {
    refusals.get(group?)?.as_ref()
}

/// The verdict of a sensor's best-scoring pair, when no pair was registered.
fn why_best_pair(i: usize, pairs: &[(usize, usize)], results: &[PairResult]) -> Option<String> {
    let (_, r) = pairs
        .iter()
        .zip(results)
        .filter(|((a, b), _)| *a == i || *b == i)
        .max_by(|x, y| x.1.score.value.total_cmp(&y.1.score.value))?;
    r.verdict.as_ref().err().map(|why| why.to_string())
}

/// The edge a pair's candidate `ci` makes (candidate 0 is the pair's own answer), with the
/// covariance linearised at that candidate.
fn candidate_edge(pair: (usize, usize), r: &PairResult, ci: usize) -> Option<Edge> {
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

/// Why a group was not joined to the placed sensors.
#[derive(Debug, Clone, PartialEq)]
enum Refusal {
    /// No pair between it and a placed sensor has a candidate that respects free space.
    NoProposal,
    /// Every proposed placement puts a scan in space a placed sensor saw empty (or the
    /// reverse); the best-scoring one contradicts `with` on this share of points.
    Contradicts { with: usize, violation: f64 },
    /// The best-scoring placement fits every placed sensor but for a few members' scans, which
    /// contradict one's free space: the group is weighed again without this one.
    MemberContradicts { member: usize },
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
}

impl Refusal {
    fn describe<'a>(&self, id: &impl Fn(usize) -> &'a str) -> String {
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
            Refusal::Slides { axis_deg } => format!(
                "its position along {axis_deg:.0}° is not fixed by what the placed sensors see (a corridor seen lengthwise); survey it, or add a sensor that sees across"
            ),
        }
    }
}

/// Where a group stands, chosen jointly against every placed sensor.
#[derive(Debug, Clone)]
struct Join {
    anchor_from_root: Pose2,
    /// (pair, candidate) of every proposal of this placement.
    sources: Vec<(usize, usize)>,
    score: Joint,
    /// The best rival placement's joint score over this one's (0 = none).
    ambiguity: f64,
}

impl Join {
    fn priority(&self) -> f64 {
        self.score.value * (1.0 - self.ambiguity)
    }
}

/// A placement's scores against every placed sensor, summed over those pairs.
#[derive(Debug, Clone)]
struct Joint {
    value: f64,
    overlap: f64,
    /// The worst pair's violation share, and the placed sensor of that pair.
    violation: f64,
    worst: usize,
    /// Members in some pair over the violation limit.
    violating: Vec<usize>,
    /// (placed, member) pairs that share at least `min_overlap` of their view here.
    witnesses: Vec<(usize, usize)>,
}

/// One placement the proposals agree on, with its joint score.
#[derive(Debug, Clone)]
struct Proposal {
    anchor_from_root: Pose2,
    /// (pair, candidate) of every proposal of this placement.
    sources: Vec<(usize, usize)>,
    joint: Joint,
}

/// What a join is weighed against.
struct JoinContext<'a> {
    sensors: &'a [SensorInput],
    /// Placed sensors and their poses in the anchor's frame.
    placed: Vec<(usize, Pose2)>,
    pairs: &'a [(usize, usize)],
    results: &'a [PairResult],
    p: &'a RegisterParams,
    sp: &'a SiteParams,
}

impl JoinContext<'_> {
    /// Scores a group (members with `root_from_member`) placed at `anchor_from_root` against
    /// every placed sensor.
    fn joint(&self, group: &[(usize, Pose2)], anchor_from_root: &Pose2) -> Joint {
        let mut joint = Joint {
            value: 0.0,
            overlap: 0.0,
            violation: 0.0,
            worst: 0,
            violating: Vec::new(),
            witnesses: Vec::new(),
        };
        for &(i, anchor_from_i) in &self.placed {
            for &(j, root_from_j) in group {
                let (Some(si), Some(sj)) = (self.sensors.get(i), self.sensors.get(j)) else {
                    continue;
                };
                let i_from_j = anchor_from_i.inverse() * anchor_from_root * root_from_j;
                let s = super::score::score(&si.model, &sj.model, &i_from_j, self.p);
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
        }
        joint
    }

    /// The candidates of every pair between sensor `k` and a placed sensor, each with its pair
    /// index, where it puts `k` (anchor's frame) and whether that is `anchor_from_k` (within
    /// `confirm_m` / `confirm_rad`); candidates that contradict free space are left out.
    fn opinions_on(
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
    fn standing_dissent(&self, k: usize, anchor_from_k: Pose2) -> bool {
        self.opinions_on(k, anchor_from_k).any(|(_, c, _, agrees)| {
            !agrees && c.score.overlap() >= self.p.min_overlap && c.score.value >= self.p.min_score
        })
    }

    /// How many pairs have a candidate that puts `k` at `anchor_from_k`.
    fn support(&self, k: usize, anchor_from_k: Pose2) -> usize {
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
    fn weigh(&self, group: &[(usize, Pose2)]) -> Result<Join, Refusal> {
        let pose_of = |s: usize| self.placed.iter().find(|(i, _)| *i == s).map(|(_, p)| *p);
        let member = |s: usize| group.iter().find(|(m, _)| *m == s).map(|(_, p)| *p);
        let mut proposals: Vec<(f64, Pose2, (usize, usize))> = Vec::new();
        for (k, (&(a, b), r)) in self.pairs.iter().zip(self.results).enumerate() {
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
            let same = placements.iter_mut().find(|(q, _)| {
                let (dt, dyaw) = pose_error(q, &pose);
                dt <= self.sp.confirm_m && dyaw <= self.sp.confirm_rad
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
        if !stands_alone {
            return Err(Refusal::NoPairStands);
        }
        if let [_] = group
            && let Some(refusal) = self.lone_witness_abstains(&best.joint, &best.sources)
        {
            return Err(refusal);
        }
        if joint.overlap < self.p.min_overlap {
            return Err(Refusal::TooLittle {
                overlap: joint.overlap,
            });
        }
        if joint.value < self.p.min_score {
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
        if joint.overlap * (1.0 - ambiguity) < self.sp.join_min_strength {
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
        })
    }

    /// A lone sensor that only one placed sensor shares view with is that pair's answer and
    /// nothing more: no third sensor checks it. Then it stands only where the pair, registered
    /// alone, would put it; otherwise the pair's own reason for abstaining is the refusal.
    /// (Placing through such a pair's other candidates, or past its σ and corridor checks, made
    /// a site of two sensors confidently wrong more often than the pair alone.) A group joining
    /// is checked by its other members' views of the placed sensors' free space as well.
    fn lone_witness_abstains(&self, joint: &Joint, sources: &[(usize, usize)]) -> Option<Refusal> {
        let [(i, j)] = joint.witnesses.as_slice() else {
            return None;
        };
        let k = self
            .pairs
            .iter()
            .position(|&(a, b)| (a, b) == (*i, *j) || (a, b) == (*j, *i))?;
        let r = self.results.get(k)?;
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
    fn slides(&self, group: &[(usize, Pose2)], join: &Join) -> Option<Refusal> {
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

/// A second opinion on every placement: each placed sensor weighed alone against all the
/// others, as a group joining them would be. Two wrong edges that agree with each other (a
/// mirror image of the sensor's view, seen the same way by two neighbours) close a cycle and
/// bind it into a group; its pairs with the rest of the site may still say, jointly and
/// clearly, that it stands elsewhere. Then it moves there; when it is the anchor, everyone
/// else moves instead, so the anchor keeps the frame.
fn second_opinion(
    placed: &mut [Option<Pose2>],
    anchor: usize,
    sensors: &[SensorInput],
    pairs: &[(usize, usize)],
    results: &[PairResult],
    p: &RegisterParams,
    sp: &SiteParams,
) {
    // The anchor first: were it wrong, every other opinion would be taken in its wrong frame.
    let order = std::iter::once(anchor).chain((0..placed.len()).filter(|&k| k != anchor));
    for k in order {
        let Some(current) = placed.get(k).copied().flatten() else {
            continue;
        };
        let ctx = JoinContext {
            sensors,
            placed: placed
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != k)
                .filter_map(|(i, pose)| pose.map(|pose| (i, pose)))
                .collect(),
            pairs,
            results,
            p,
            sp,
        };
        // Only a pair that could carry a placement alone may overrule (as in `weigh`): where
        // every such pair agrees with the current place, there is nothing to weigh.
        if !ctx.standing_dissent(k, current) {
            continue;
        }
        // Overrule the group only on more evidence: the current place contradicts a placed
        // sensor, or more pairs propose the new one than the current one. (In a symmetric
        // scene a correctly placed sensor that shares little view with the rest would
        // otherwise be pulled onto a mirror image that overlaps them more.) `weigh` picks one
        // of the places the pairs propose, so when none has more support than the current
        // one, weighing them (the dear part) could not move `k`: count first.
        let alone = [(k, Pose2::identity())];
        let contradicted = ctx.joint(&alone, &current).violation > p.max_violation;
        let current_support = ctx.support(k, current);
        let outvoted = |place: &Pose2| ctx.support(k, *place) > current_support;
        if !contradicted
            && !ctx
                .opinions_on(k, current)
                .any(|(_, _, place, agrees)| !agrees && outvoted(&place))
        {
            continue;
        }
        let Ok(join) = ctx.weigh(&alone) else {
            continue;
        };
        let (dt, dyaw) = pose_error(&join.anchor_from_root, &current);
        if (dt <= sp.confirm_m && dyaw <= sp.confirm_rad) || ctx.slides(&alone, &join).is_some() {
            continue;
        }
        if !contradicted && !outvoted(&join.anchor_from_root) {
            continue;
        }
        if k == anchor {
            let anchor_from_new = join.anchor_from_root.inverse() * current;
            for (i, pose) in placed.iter_mut().enumerate() {
                if let Some(pose) = pose.as_mut()
                    && i != k
                {
                    *pose = anchor_from_new * *pose;
                }
            }
        } else {
            placed[k] = Some(join.anchor_from_root);
        }
    }
}

/// The registration parameters with only the contradictions the last check is sure of
/// counted (`SiteParams::conflict_dz_m`).
fn certain_only(p: &RegisterParams, sp: &SiteParams) -> RegisterParams {
    RegisterParams {
        free_space_dz_m: sp.conflict_dz_m,
        ..p.clone()
    }
}

/// Whether `j`'s scan placed at `i_from_j` in `i`'s frame puts enough points in space one of
/// them saw empty, under `certain` (`certain_only`): the last check's veto on a placed sensor.
fn contradicts(i: &ScanModel, j: &ScanModel, i_from_j: &Pose2, certain: &RegisterParams) -> bool {
    super::score::score(i, j, i_from_j, certain).violation() > certain.max_violation
}

/// Drops edges that disagree around triangles (more failed than passed cycles), then edges
/// that disagree with a spanning tree of the rest. Returns indices of kept edges.
pub fn consistent_edges(n: usize, anchor: usize, edges: &[Edge], sp: &SiteParams) -> Vec<usize> {
    let find = |a: usize, b: usize| -> Option<(usize, Pose2)> {
        edges.iter().enumerate().find_map(|(k, e)| {
            if e.a == a && e.b == b {
                Some((k, e.a_from_b))
            } else if e.a == b && e.b == a {
                Some((k, e.a_from_b.inverse()))
            } else {
                None
            }
        })
    };
    let mut good = vec![0usize; edges.len()];
    let mut bad = vec![0usize; edges.len()];
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let (Some((e1, ij)), Some((e2, jk)), Some((e3, ik))) =
                    (find(i, j), find(j, k), find(i, k))
                else {
                    continue;
                };
                let (dt, dyaw) = pose_error(&(ij * jk), &ik);
                let counts = if dt <= sp.cycle_m && dyaw <= sp.cycle_rad {
                    &mut good
                } else {
                    &mut bad
                };
                for e in [e1, e2, e3] {
                    counts[e] += 1;
                }
            }
        }
    }
    let mut kept: Vec<usize> = (0..edges.len()).filter(|&e| bad[e] <= good[e]).collect();
    // Check the survivors against the tree they build; drop disagreeing ones once.
    let subset: Vec<Edge> = kept.iter().map(|&e| edges[e].clone()).collect();
    let poses = spanning_poses(n, anchor, &subset);
    kept.retain(|&e| {
        let edge = &edges[e];
        match (poses[edge.a], poses[edge.b]) {
            (Some(pa), Some(pb)) => {
                let (dt, dyaw) = pose_error(&(pa.inverse() * pb), &edge.a_from_b);
                dt <= sp.cycle_m * 2.0 && dyaw <= sp.cycle_rad * 2.0
            }
            _ => true,
        }
    });
    kept
}

/// Indices of the edges that lie on no cycle: removing one disconnects its two sensors.
pub fn bridges(n: usize, edges: &[Edge]) -> Vec<usize> {
    let connected_without = |skip: usize, from: usize, to: usize| {
        let mut seen = vec![false; n];
        let mut stack = vec![from];
        while let Some(u) = stack.pop() {
            if u == to {
                return true;
            }
            if std::mem::replace(&mut seen[u], true) {
                continue;
            }
            for (k, e) in edges.iter().enumerate() {
                if k == skip {
                    continue;
                }
                if e.a == u && !seen[e.b] {
                    stack.push(e.b);
                } else if e.b == u && !seen[e.a] {
                    stack.push(e.a);
                }
            }
        }
        false
    };
    (0..edges.len())
        .filter(|&k| {
            let e = &edges[k];
            e.a < n && e.b < n && !connected_without(k, e.a, e.b)
        })
        .collect()
}

/// Anchor-frame poses by a maximum-strength spanning tree from the anchor (Prim).
pub fn spanning_poses(n: usize, anchor: usize, edges: &[Edge]) -> Vec<Option<Pose2>> {
    let mut poses: Vec<Option<Pose2>> = vec![None; n];
    if anchor >= n {
        return poses;
    }
    poses[anchor] = Some(Pose2::identity());
    grow_poses(&mut poses, edges);
    poses
}

/// Extends `poses` along `edges` from the sensors already posed, strongest edge first.
fn grow_poses(poses: &mut [Option<Pose2>], edges: &[Edge]) {
    loop {
        let next = edges
            .iter()
            .filter_map(|e| match (poses[e.a], poses[e.b]) {
                (Some(pa), None) => Some((e.strength, e.b, pa * e.a_from_b)),
                (None, Some(pb)) => Some((e.strength, e.a, pb * e.a_from_b.inverse())),
                _ => None,
            })
            .max_by(|x, y| x.0.total_cmp(&y.0));
        match next {
            Some((_, i, pose)) => poses[i] = Some(pose),
            None => return,
        }
    }
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
    let mut poses = spanning_poses(n, anchor, edges);
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
            grow_poses(&mut poses, edges);
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

#[cfg(test)]
mod tests {
    use super::*;

    fn edge(a: usize, b: usize, truth: &[Pose2], bias: Pose2) -> Edge {
        Edge {
            a,
            b,
            a_from_b: bias * truth[a].inverse() * truth[b],
            covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-5)),
            strength: 1.0,
        }
    }

    #[test]
    fn one_wrong_edge_is_dropped_and_the_rest_solve_to_truth() {
        let truth = [
            pose2(0.0, 0.0, 0.0),
            pose2(5.0, 1.0, 0.5),
            pose2(3.0, 6.0, -1.0),
            pose2(-4.0, 2.0, 2.0),
            pose2(1.0, -5.0, 3.0),
        ];
        let mut edges = Vec::new();
        for a in 0..5 {
            for b in a + 1..5 {
                // Small, different errors on every good edge; one edge is a metre and 20° off.
                let bias = if (a, b) == (1, 3) {
                    pose2(1.0, -0.5, 0.35)
                } else {
                    pose2(
                        0.004 * (a as f64 - b as f64),
                        0.003 * a as f64,
                        0.001 * b as f64,
                    )
                };
                edges.push(edge(a, b, &truth, bias));
            }
        }
        let sp = SiteParams::default();
        let kept = consistent_edges(5, 0, &edges, &sp);
        assert_eq!(kept.len(), 9);
        assert!(kept.iter().all(|&k| (edges[k].a, edges[k].b) != (1, 3)));
        let kept_edges: Vec<Edge> = kept.iter().map(|&k| edges[k].clone()).collect();
        let sensors: Vec<SensorInput> = Vec::new();
        let solution = solve(5, 0, &kept_edges, &sensors, &sp);
        for (i, t) in truth.iter().enumerate() {
            let Some((pose, sigma)) = solution[i] else {
                panic!("sensor {i} unplaced")
            };
            let (dt, dyaw) = pose_error(&pose, t);
            assert!(dt < 0.03 && dyaw < 0.005, "sensor {i}: {dt} m {dyaw} rad");
            if i != 0 {
                assert!(
                    sigma[0] > 0.0 && sigma[0] < 0.05 && sigma[2] > 0.0,
                    "sigma {sigma:?}"
                );
            }
        }
    }

    #[test]
    fn surveyed_priors_place_an_unreached_sensor_and_weigh_against_edges() {
        let truth = [
            pose2(0.0, 0.0, 0.0),
            pose2(5.0, 1.0, 0.5),
            pose2(3.0, 6.0, -1.0),
        ];
        let model = ScanModel::new(&[], 0.25f64.to_radians(), &RegisterParams::default());
        let input = |i: usize, prior: Option<Prior>| SensorInput {
            id: format!("s{i}"),
            mount: crate::geometry::Mount::default(),
            model: model.clone(),
            prior,
        };
        // Sensor 1: its edge (σ² 1e-4 plus the 1 cm floor: 2e-4) and a survey 20 cm off along
        // x (σ² 1e-4) meet at the weighted mean, 2/3 of the way to the survey. Sensor 2: no
        // edge, only a survey; it stands where surveyed, with the survey's σ.
        let sensors = [
            input(0, None),
            input(
                1,
                Some(Prior {
                    anchor_from_sensor: pose2(0.2, 0.0, 0.0) * truth[1],
                    sigma_xy_m: 0.01,
                    sigma_yaw_rad: 0.01,
                }),
            ),
            input(
                2,
                Some(Prior {
                    anchor_from_sensor: truth[2],
                    sigma_xy_m: 0.05,
                    sigma_yaw_rad: 0.02,
                }),
            ),
        ];
        let edges = vec![edge(0, 1, &truth, Pose2::identity())];
        let solution = solve(3, 0, &edges, &sensors, &SiteParams::default());
        let (one, _) = solution[1].expect("sensor 1 placed");
        let (dx, dy) = (
            one.translation.x - truth[1].translation.x,
            one.translation.y - truth[1].translation.y,
        );
        assert!(
            (dx - 0.2 * 2.0 / 3.0).abs() < 0.01 && dy.abs() < 0.01,
            "weighted mean expected: {dx} {dy}"
        );
        let (two, sigma) = solution[2].expect("sensor 2 placed by its survey");
        let (dt, dyaw) = pose_error(&two, &truth[2]);
        assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
        assert!((sigma[0] - 0.05).abs() < 0.01, "σx {}", sigma[0]);
    }

    use crate::geometry::raycast::{Wall, cast, polygon};
    use crate::geometry::{ScanPoint, pose_error};
    use crate::register::Candidate;

    /// A 12 × 6 m hall, symmetric under a half turn about its centre but for one 1.5 × 1.5 m
    /// block in its north-west; the block's mirror image would stand in empty floor.
    fn hall() -> Vec<Wall> {
        let mut walls = polygon(&[(-6.0, -3.0), (6.0, -3.0), (6.0, 3.0), (-6.0, 3.0)]);
        walls.extend(polygon(&[
            (-5.5, 1.0),
            (-4.0, 1.0),
            (-4.0, 2.5),
            (-5.5, 2.5),
        ]));
        walls
    }

    /// The scan of a sensor at `site_from_sensor` over `fov_rad` centred ahead, 0.5° steps.
    fn sensor_at(walls: &[Wall], site_from_sensor: Pose2, fov_rad: f64, id: &str) -> SensorInput {
        let step = 0.5f64.to_radians();
        let beams = (fov_rad / step) as usize;
        let points: Vec<ScanPoint> = (0..beams)
            .filter_map(|k| {
                let angle = -fov_rad / 2.0 + step * k as f64;
                let dir_site =
                    site_from_sensor.rotation * nalgebra::Vector2::new(angle.cos(), angle.sin());
                let origin = nalgebra::Point2::from(site_from_sensor.translation.vector);
                let range = cast(walls, origin, dir_site)?;
                Some(ScanPoint {
                    p: nalgebra::Point2::new(range * angle.cos(), range * angle.sin()),
                    beam: k,
                    z_m: None,
                })
            })
            .collect();
        SensorInput {
            id: id.to_string(),
            model: ScanModel::new(&points, step, &RegisterParams::default()),
            mount: crate::geometry::Mount::default(),
            prior: None,
        }
    }

    #[test]
    fn a_surveyed_sensor_out_of_reach_places_the_sensors_registered_to_it() {
        // Two rooms 40 m apart that share no view: s0 and s1 in the hall, s2 and s3 in an
        // L-shaped room with a pillar. Only s2 is surveyed; s3 registers with s2 alone.
        let mut room = polygon(&[
            (40.0, 0.0),
            (52.0, 0.0),
            (52.0, 5.0),
            (46.0, 5.0),
            (46.0, 10.0),
            (40.0, 10.0),
        ]);
        room.extend(polygon(&[
            (43.0, 3.0),
            (43.6, 3.0),
            (43.6, 3.6),
            (43.0, 3.6),
        ]));
        let walls: Vec<Wall> = hall().into_iter().chain(room).collect();
        let truth = [
            pose2(-3.0, -1.0, 0.3),
            pose2(1.0, -2.0, 2.6),
            pose2(41.0, 1.5, 0.6),
            pose2(50.0, 3.5, 2.9),
        ];
        let fov = 270f64.to_radians();
        let mut sensors: Vec<SensorInput> = truth
            .iter()
            .enumerate()
            .map(|(i, t)| sensor_at(&walls, *t, fov, &format!("s{i}")))
            .collect();
        sensors[2].prior = Some(Prior {
            anchor_from_sensor: truth[0].inverse() * truth[2],
            sigma_xy_m: 0.02,
            sigma_yaw_rad: 0.01,
        });
        let site = register_site(
            &sensors,
            0,
            &RegisterParams::default(),
            &SiteParams::default(),
        );
        for k in 1..4 {
            let placed = site.sensors[k].pose.as_ref();
            let pose = placed.unwrap_or_else(|why| panic!("s{k} not placed: {why}"));
            let (dt, dyaw) = pose_error(&pose.pose.planar(), &(truth[0].inverse() * truth[k]));
            assert!(
                dt < 0.05 && dyaw < 0.5f64.to_radians(),
                "s{k} off by {dt} m {} deg",
                dyaw.to_degrees()
            );
        }
        // s1 and s3 each rest on one pair: the caveat says so and names the other end. The
        // anchor and the surveyed s2 have none.
        let caveat = |k: usize| site.sensors[k].caveat.clone();
        for (k, with) in [(1, "s0"), (3, "s2")] {
            let c = caveat(k).unwrap_or_else(|| panic!("s{k} rests on one pair, no caveat"));
            assert!(c.contains("one pair") && c.contains(with), "s{k}: {c}");
        }
        assert_eq!((caveat(0), caveat(2)), (None, None));
    }

    /// A pair that could not decide between `poses` (best first): each is a candidate, scored
    /// honestly against the two scans.
    fn undecided_pair(a: &SensorInput, b: &SensorInput, poses: &[Pose2]) -> PairResult {
        let p = RegisterParams::default();
        let candidates: Vec<Candidate> = poses
            .iter()
            .map(|pose| Candidate {
                a_from_b: *pose,
                score: crate::register::score::score(&a.model, &b.model, pose, &p),
                covariance: Matrix3::identity() * 1e-4,
            })
            .collect();
        let best = candidates.first().cloned().unwrap_or(Candidate {
            a_from_b: Pose2::identity(),
            score: Default::default(),
            covariance: Matrix3::identity() * 1e-4,
        });
        PairResult {
            verdict: Err(crate::register::Abstain::Ambiguous {
                ratio: 0.9,
                other: Pose2::identity(),
            }),
            a_from_b: best.a_from_b,
            covariance: Matrix3::identity() * 1e-4,
            match_score: 0.5,
            ambiguity: 0.9,
            overlap: best.score.overlap(),
            score: best.score,
            candidates,
            hypotheses: poses.len(),
            icp_iterations: 0,
            motion: None,
            walkers: None,
            nobody_walked_s: None,
        }
    }

    /// s0 and s1 look only at symmetric corners of the hall, so each of their pairs with s3
    /// fits s3's true pose and its half-turn mirror image equally well, and both pairs put the
    /// mirror first: two neighbours agreeing on the wrong pose. The group to join is s3 alone.
    struct MirrorScene {
        sensors: Vec<SensorInput>,
        pairs: Vec<(usize, usize)>,
        results: Vec<PairResult>,
        truth: Vec<Pose2>,
        mirror_of_s3: Pose2,
    }

    /// A join context in which the scene's first `count` sensors stand at their true poses.
    fn truth_placed<'a>(
        scene: &'a MirrorScene,
        count: usize,
        p: &'a RegisterParams,
        sp: &'a SiteParams,
    ) -> JoinContext<'a> {
        JoinContext {
            sensors: &scene.sensors,
            placed: (0..count)
                .map(|i| (i, scene.truth[0].inverse() * scene.truth[i]))
                .collect(),
            pairs: &scene.pairs,
            results: &scene.results,
            p,
            sp,
        }
    }

    fn mirror_scene() -> MirrorScene {
        let walls = hall();
        let half_turn = pose2(0.0, 0.0, std::f64::consts::PI);
        // s0 sees only the hall's north-east, s1 (its half-turn image) only its south-west;
        // s3 sees all of the hall but the block's shadow; s2 looks at the block.
        let truth = vec![
            pose2(0.0, 2.0, 45f64.to_radians()),
            half_turn * pose2(0.0, 2.0, 45f64.to_radians()),
            pose2(-2.0, 2.5, 195f64.to_radians()),
            pose2(-2.0, -0.5, 0.3),
        ];
        let fov_deg = [120.0, 120.0, 60.0, 360.0];
        let sensors: Vec<SensorInput> = truth
            .iter()
            .zip(fov_deg)
            .enumerate()
            .map(|(i, (pose, fov))| {
                sensor_at(&walls, *pose, f64::to_radians(fov), &format!("s{i}"))
            })
            .collect();
        let mirror_of_s3 = half_turn * truth[3];
        let pairs = vec![(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
        let results = pairs
            .iter()
            .map(|&(a, b)| {
                let poses = if b == 3 && a != 2 {
                    let site_from_a = truth[a];
                    vec![
                        site_from_a.inverse() * mirror_of_s3,
                        site_from_a.inverse() * truth[3],
                    ]
                } else {
                    Vec::new()
                };
                undecided_pair(&sensors[a], &sensors[b], &poses)
            })
            .collect();
        MirrorScene {
            sensors,
            pairs,
            results,
            truth,
            mirror_of_s3,
        }
    }

    #[test]
    fn a_mirror_image_two_neighbours_agree_on_is_refused_by_a_third_sensors_free_space() {
        let scene = mirror_scene();
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        // The premise: on their own, s0 and s1 cannot tell the mirror image from the truth.
        for pair in [2, 4] {
            let c = &scene.results[pair].candidates;
            let (mirror, truth) = (&c[0].score, &c[1].score);
            assert!(
                mirror.violation() <= p.max_violation && truth.violation() <= p.max_violation,
                "pair {pair}: both fit"
            );
            assert!(
                mirror.value >= 0.9 * truth.value,
                "pair {pair}: mirror {} vs truth {}",
                mirror.value,
                truth.value
            );
        }
        let ctx = truth_placed(&scene, 3, &p, &sp);
        let s3 = [(3, Pose2::identity())];
        // The mirror image puts s3's view of the pillar in the floor s2 sees empty.
        let at_mirror = ctx.joint(&s3, &(scene.truth[0].inverse() * scene.mirror_of_s3));
        assert!(
            at_mirror.violation > p.max_violation && at_mirror.worst == 2,
            "mirror violation {} against s{}",
            at_mirror.violation,
            at_mirror.worst
        );
        let join = ctx
            .weigh(&s3)
            .expect("the true pose is the one placement left");
        assert!(ctx.slides(&s3, &join).is_none());
        let (dt, dyaw) = pose_error(
            &join.anchor_from_root,
            &(scene.truth[0].inverse() * scene.truth[3]),
        );
        assert!(
            dt < 0.01 && dyaw < 0.001,
            "placed {dt} m {dyaw} rad from the truth"
        );
    }

    #[test]
    fn a_second_opinion_moves_a_sensor_placed_at_a_mirror_image_to_where_the_rest_fit() {
        let scene = mirror_scene();
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        let rel = |i: usize| scene.truth[0].inverse() * scene.truth[i];
        let near = |x: &Option<Pose2>, y: &Pose2| {
            let (dt, dyaw) = pose_error(&x.expect("placed"), y);
            dt < 0.01 && dyaw < 0.001
        };
        let opinion = |placed: &mut [Option<Pose2>], anchor: usize| {
            let (sensors, pairs, results) = (&scene.sensors, &scene.pairs, &scene.results);
            second_opinion(placed, anchor, sensors, pairs, results, &p, &sp);
        };
        // s3 placed at its mirror image (as two agreeing wrong edges would put it): s2's free
        // space rules that out, and s0's and s1's pairs also propose the truth.
        let mut placed = vec![
            Some(rel(0)),
            Some(rel(1)),
            Some(rel(2)),
            Some(scene.truth[0].inverse() * scene.mirror_of_s3),
        ];
        opinion(&mut placed, 0);
        for (i, pose) in placed.iter().enumerate() {
            assert!(near(pose, &rel(i)), "s{i} at {pose:?}");
        }
        // The same with s3 as the anchor: the others were placed in its mirrored frame, and
        // they move instead.
        let m = scene.mirror_of_s3;
        let mut placed: Vec<Option<Pose2>> = (0..3)
            .map(|i| Some(m.inverse() * scene.truth[i]))
            .chain([Some(Pose2::identity())])
            .collect();
        opinion(&mut placed, 3);
        for (i, pose) in placed.iter().enumerate() {
            let truth = scene.truth[3].inverse() * scene.truth[i];
            assert!(near(pose, &truth), "s{i} at {pose:?}");
        }
    }

    #[test]
    fn without_the_third_sensor_the_mirror_image_is_reported_not_placed() {
        let scene = mirror_scene();
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        let ctx = truth_placed(&scene, 2, &p, &sp);
        let refusal = ctx.weigh(&[(3, Pose2::identity())]).err();
        let Some(Refusal::Ambiguous {
            ratio, apart_deg, ..
        }) = refusal
        else {
            panic!("expected two placements fitting equally, got {refusal:?}");
        };
        assert!(
            ratio > 0.9 && (apart_deg - 180.0).abs() < 1.0,
            "{ratio} {apart_deg}"
        );
        let why = Refusal::Ambiguous {
            ratio,
            apart_m: 9.0,
            apart_deg,
        }
        .describe(&|i| ["s0", "s1", "s2", "s3"][i]);
        assert!(
            why.contains("mirror image") && why.contains("survey it"),
            "{why}"
        );
    }

    /// Two 270° sensors in `walls` at `truth` (site frame) and their pair, whose only
    /// candidate is the true pose (verdict: undecided).
    struct TwoSensors {
        sensors: Vec<SensorInput>,
        pair: PairResult,
    }

    fn two_in(walls: &[Wall], truth: [Pose2; 2]) -> TwoSensors {
        let sensors: Vec<SensorInput> = truth
            .iter()
            .enumerate()
            .map(|(i, pose)| sensor_at(walls, *pose, 270f64.to_radians(), &format!("s{i}")))
            .collect();
        let pair = undecided_pair(&sensors[0], &sensors[1], &[truth[0].inverse() * truth[1]]);
        TwoSensors { sensors, pair }
    }

    impl TwoSensors {
        /// `f` on a join context in which s0 is placed at the origin.
        fn context<T>(
            &self,
            p: &RegisterParams,
            sp: &SiteParams,
            f: impl FnOnce(&JoinContext<'_>) -> T,
        ) -> T {
            let (pairs, results) = ([(0, 1)], [self.pair.clone()]);
            f(&JoinContext {
                sensors: &self.sensors,
                placed: vec![(0, Pose2::identity())],
                pairs: &pairs,
                results: &results,
                p,
                sp,
            })
        }
    }

    #[test]
    fn a_sensor_one_placed_sensor_sees_stands_only_where_that_pair_alone_would_put_it() {
        let two = two_in(&hall(), [pose2(-1.0, 0.0, 0.0), pose2(1.5, 0.5, 0.3)]);
        let truth = two.pair.a_from_b;
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        let weigh = |verdict: Result<(), crate::register::Abstain>| {
            let with = TwoSensors {
                pair: PairResult {
                    verdict,
                    ..two.pair.clone()
                },
                sensors: two.sensors.clone(),
            };
            with.context(&p, &sp, |ctx| ctx.weigh(&[(1, Pose2::identity())]))
        };
        // Registered alone: placed where the pair puts it.
        let join = weigh(Ok(())).expect("a registered pair places its sensor");
        let (dt, dyaw) = pose_error(&join.anchor_from_root, &truth);
        assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
        // Not registered alone (its σ too wide): nothing else checks it, so the pair's own
        // reason is the refusal, naming the one placed sensor that sees it.
        let uncertain = crate::register::Abstain::Uncertain {
            sigma_m: 0.2,
            sigma_yaw_deg: 0.1,
        };
        let refusal = weigh(Err(uncertain)).err();
        let Some(Refusal::LonePair { with: 0, why }) = &refusal else {
            panic!("expected the lone pair's refusal, got {refusal:?}");
        };
        assert!(why.contains("too uncertain"), "{why}");
        let said = refusal.map(|r| r.describe(&|k| ["s0", "s1"][k]));
        assert!(said.is_some_and(|s| s.contains("only s0")));
    }

    #[test]
    fn a_weak_join_names_the_rival_only_when_there_is_one() {
        let id = |i: usize| ["s0", "s1"][i];
        let alone = Refusal::Weak {
            overlap: 0.22,
            ambiguity: 0.0,
        }
        .describe(&id);
        assert!(
            alone.contains("only 22 %") && !alone.contains("as well"),
            "{alone}"
        );
        let rivalled = Refusal::Weak {
            overlap: 0.45,
            ambiguity: 0.4,
        }
        .describe(&id);
        assert!(rivalled.contains("40 % as well"), "{rivalled}");
    }

    #[test]
    fn a_sensor_seen_only_along_a_corridor_is_not_placed() {
        // Two 60 m walls 3 m apart and no end in sight: sliding along them changes nothing.
        let walls = vec![
            Wall::new(-30.0, -1.5, 30.0, -1.5),
            Wall::new(-30.0, 1.5, 30.0, 1.5),
        ];
        let mut two = two_in(&walls, [pose2(0.0, 0.0, 0.0), pose2(3.0, 0.2, 0.4)]);
        // Registered alone (the pair's own slide check is not what this tests).
        two.pair.verdict = Ok(());
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        let s1 = [(1, Pose2::identity())];
        // One proposal, no rival: only the slide test can refuse it.
        let slid = two.context(&p, &sp, |ctx| {
            let join = ctx.weigh(&s1).expect("a lone proposal that fits");
            ctx.slides(&s1, &join)
        });
        let Some(Refusal::Slides { axis_deg }) = slid else {
            panic!("a placement free to slide along the corridor was accepted");
        };
        assert!(
            !(20.0..=160.0).contains(&axis_deg),
            "slides along {axis_deg}°, not along the corridor"
        );
    }

    #[test]
    fn a_sensor_reached_by_no_edge_stays_unplaced() {
        let truth = [
            pose2(0.0, 0.0, 0.0),
            pose2(5.0, 1.0, 0.5),
            pose2(3.0, 6.0, -1.0),
        ];
        let edges = vec![edge(0, 1, &truth, Pose2::identity())];
        let solution = solve(3, 0, &edges, &[], &SiteParams::default());
        assert!(solution[1].is_some());
        assert!(solution[2].is_none());
    }

    #[test]
    fn the_last_check_drops_a_sensor_only_for_contradictions_it_is_sure_of() {
        use crate::register::score::tests::facing;
        let (p, sp) = (RegisterParams::default(), SiteParams::default());
        let same = Pose2::identity();
        // Side by side, the low unit (0.8 m) hits a counter 3 m out; the high one (1.1 m) sees
        // over it to the wall at 6 m. Pair scoring counts that against the pose (0.3 m above is
        // within its 0.5 m), the last check does not: the counter may stand under 1.1 m.
        let (low, high) = (facing(3.0, Some(0.8)), facing(6.0, Some(1.1)));
        assert!(crate::register::score::score(&high, &low, &same, &p).violation() > 0.9);
        let certain = certain_only(&p, &sp);
        assert!(!contradicts(&high, &low, &same, &certain));
        // A low beam that passed where the high unit saw something would have hit it.
        let (low_far, high_near) = (facing(6.0, Some(0.8)), facing(3.0, Some(1.1)));
        assert!(contradicts(&low_far, &high_near, &same, &certain));
        // Mounts unknown: one plane, and the counter contradicts.
        let (far, near) = (facing(6.0, None), facing(3.0, None));
        assert!(contradicts(&far, &near, &same, &certain));
    }
}
