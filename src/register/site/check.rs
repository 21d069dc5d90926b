//! The last check: every two placed sensors must agree about free space, not only the pairs
//! that registered; the weaker side of a certain contradiction loses its edges and the site is
//! solved again until none is left.

use super::{Edge, SensorInput, SiteParams};
use crate::geometry::Pose2;
use crate::register::{RegisterParams, ScanModel};
use rayon::prelude::*;

/// The solution after the last check: pose and σ per sensor, the sensor whose free space each
/// dropped one contradicted, and the (pair, candidate) of every edge it rests on.
pub(super) struct Solved {
    pub solution: Vec<Option<(Pose2, [f64; 3])>>,
    pub contradicted: Vec<Option<usize>>,
    pub origin: Vec<(usize, usize)>,
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
    let mut solution = super::solve(n, anchor, &edges, &priors, sp);
    let mut contradicted = vec![None::<usize>; n];
    let certain = certain_only(p, sp);
    let reach = super::reach_m(sensors);
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
                    // Out of each other's reach they cannot contradict each other.
                    .filter(|&(i, pi, j, pj)| {
                        (pi.translation.vector - pj.translation.vector).norm()
                            <= reach[i] + reach[j]
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
        tracing::trace!(
            "free-space check drops {} (contradicts {})",
            sensors[loser].id,
            sensors[if loser == i { j } else { i }].id
        );
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
        solution = super::solve(n, anchor, &edges, &priors, sp);
    }
    Solved {
        solution,
        contradicted,
        origin,
    }
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
