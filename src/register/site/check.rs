//! The last check: every two placed sensors must agree about free space, not only the pairs
//! that registered; the weaker side of a certain contradiction loses its edges and the site is
//! solved again until none is left.

use super::join::Refusal;
use super::{Edge, SensorInput, SiteParams};
use crate::geometry::Pose2;
use crate::register::{RegisterParams, ScanModel};
use rayon::prelude::*;

/// The solution after the last check: pose and σ per sensor, the sensor whose free space each
/// dropped one contradicted, those left unplaced as too loose (`Refusal::Loose`), the (pair,
/// candidate) of every edge it rests on, and for each surveyed sensor the scans contradict,
/// how far apart the two put it.
pub(super) struct Solved {
    pub solution: Vec<Option<(Pose2, [f64; 3])>>,
    pub contradicted: Vec<Option<usize>>,
    pub loose: Vec<Option<Refusal>>,
    pub origin: Vec<(usize, usize)>,
    pub survey_conflicts: Vec<Option<(f64, f64)>>,
}

/// A survey and the scans disagree beyond both their 3σ by more than this (m, rad) before the
/// survey is called a mistake rather than weighed against the scans.
const SURVEY_SLACK_M: f64 = 0.3;
const SURVEY_SLACK_RAD: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// The surveyed sensors whose survey the scans alone (the edges, without any survey) put far
/// off: (sensor, metres, radians apart).
fn surveys_the_scans_contradict(
    n: usize,
    anchor: usize,
    edges: &[Edge],
    priors: &[(usize, super::Prior)],
    sp: &SiteParams,
) -> Vec<(usize, f64, f64)> {
    if priors.is_empty() {
        return Vec::new();
    }
    let scans = super::solve(n, anchor, edges, &[], sp);
    priors
        .iter()
        .filter_map(|&(i, prior)| {
            let (pose, sigma) = scans.get(i).copied().flatten()?;
            let (dt, dyaw) = crate::geometry::pose_error(&pose, &prior.anchor_from_node());
            let sigma_m = sigma[0].hypot(sigma[1]).hypot(prior.sigma_xy_m);
            let sigma_rad = sigma[2].hypot(prior.sigma_yaw_rad);
            (dt > 3.0 * sigma_m + SURVEY_SLACK_M || dyaw > 3.0 * sigma_rad + SURVEY_SLACK_RAD)
                .then_some((i, dt, dyaw))
        })
        .collect()
}

pub(super) fn solve_without_conflicts(
    n: usize,
    anchor: usize,
    mut edges: Vec<Edge>,
    mut origin: Vec<(usize, usize)>,
    sensors: &[SensorInput],
    p: &RegisterParams,
    sp: &SiteParams,
) -> Solved {
    // Every placed sensor must agree with every other placed sensor about free space, not
    // only with the ones it was registered to: a sensor hanging on one wrong edge has no cycle
    // to expose it, but its scan lands where a third sensor saw nothing. Drop the weaker side's
    // edges and solve again until no placement contradicts another (`contradicts`: certain
    // contradictions only).
    let priors = super::priors_of(sensors);
    // A survey metres off what the scans say (a drag to the wrong place, a typo) is a
    // mistake, not a measurement to average: weighed in, it would carry every unit that
    // shares a view with its sensor. The sensor stands where surveyed, as asked, and its
    // edges are left out.
    let mut survey_conflicts = vec![None; n];
    for (i, dt, dyaw) in surveys_the_scans_contradict(n, anchor, &edges, &priors, sp) {
        tracing::debug!(
            "{}'s survey is {dt:.2} m / {:.1}° from where the scans put it: its edges are left out",
            sensors[i].id,
            dyaw.to_degrees()
        );
        survey_conflicts[i] = Some((dt, dyaw));
        drop_edges_of(i, &mut edges, &mut origin);
    }
    let mut solution = super::solve(n, anchor, &edges, &priors, sp);
    let mut contradicted = vec![None::<usize>; n];
    let certain = certain_only(p, sp);
    let reach = super::reach_m(sensors);
    let mut unsettled: Vec<(usize, usize)> = Vec::new();
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
                    // Out of each other's reach they cannot contradict each other; a survey
                    // the scans contradict vetoes no one (it is named already); and what
                    // dropping edges cannot settle is left as it is.
                    .filter(|&(i, pi, j, pj)| {
                        (pi.translation.vector - pj.translation.vector).norm()
                            <= reach[i] + reach[j]
                            && survey_conflicts[i].is_none()
                            && survey_conflicts[j].is_none()
                            && !unsettled.contains(&(i, j))
                    })
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
        // Never drop the anchor, nor a sensor without edges (placed by its survey alone:
        // dropping nothing would find the same conflict again); otherwise the sensor with
        // fewer edges loses them all.
        let droppable = |k: usize| k != anchor && support(k) > 0;
        let loser = match (droppable(i), droppable(j)) {
            (false, false) => {
                unsettled.push((i, j));
                continue;
            }
            (true, false) => i,
            (false, true) => j,
            _ if support(i) < support(j) => i,
            _ if support(j) < support(i) => j,
            _ => i.max(j),
        };
        contradicted[loser] = Some(if loser == i { j } else { i });
        tracing::trace!(
            "free-space check drops {} (contradicts {})",
            sensors[loser].id,
            sensors[if loser == i { j } else { i }].id
        );
        drop_edges_of(loser, &mut edges, &mut origin);
        solution = super::solve(n, anchor, &edges, &priors, sp);
    }
    // A pose the solve cannot say it is sure of is not given: its edges are left out (they
    // told the rest next to nothing) and the site solved again without it. A surveyed
    // sensor stands as surveyed, with the σ it was given: that is a person's word, not the
    // scans'. Each round refuses at least one sensor more, so the loop ends.
    let mut loose = vec![None; n];
    loop {
        let found: Vec<(usize, Refusal)> = solution
            .iter()
            .enumerate()
            .filter(|&(i, _)| {
                loose[i].is_none() && sensors.get(i).is_some_and(|s| s.prior.is_none())
            })
            .filter_map(|(i, s)| Some((i, Refusal::loose(&s.as_ref()?.1, sp)?)))
            .collect();
        if found.is_empty() {
            break;
        }
        for (i, why) in found {
            tracing::debug!("{} is placed too loosely: {why:?}", sensors[i].id);
            drop_edges_of(i, &mut edges, &mut origin);
            loose[i] = Some(why);
        }
        solution = super::solve(n, anchor, &edges, &priors, sp);
    }
    Solved {
        solution,
        contradicted,
        loose,
        origin,
        survey_conflicts,
    }
}

/// Removes every edge of sensor `k`, and its origin beside it.
fn drop_edges_of(k: usize, edges: &mut Vec<Edge>, origin: &mut Vec<(usize, usize)>) {
    let keep: Vec<bool> = edges.iter().map(|e| e.a != k && e.b != k).collect();
    let mut kept = keep.iter();
    edges.retain(|_| kept.next().copied().unwrap_or(true));
    let mut kept = keep.iter();
    origin.retain(|_| kept.next().copied().unwrap_or(true));
}

/// The registration parameters with only the contradictions the last check is sure of
/// counted (`SiteParams::conflict_dz_m`).
pub(super) fn certain_only(p: &RegisterParams, sp: &SiteParams) -> RegisterParams {
    RegisterParams {
        free_space_dz_m: sp.conflict_dz_m,
        ..p.clone()
    }
}

/// Whether `j`'s scan placed at `i_from_j` in `i`'s frame puts enough points in space one of
/// them saw empty, under `certain` (`certain_only`): the last check's veto on a placed sensor.
pub(super) fn contradicts(
    i: &ScanModel,
    j: &ScanModel,
    i_from_j: &Pose2,
    certain: &RegisterParams,
) -> bool {
    crate::register::score::score(i, j, i_from_j, certain).violation() > certain.max_violation
}
