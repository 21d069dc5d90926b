//! The report: each sensor's placement (pose with σ and caveat: on too few pairs, or walls
//! alone) or why it has none, and what happened to every pair.

use super::check::Solved;
use super::join::Refusal;
use super::{PairReport, PlacedPose, Placement, SensorInput, SiteParams, SiteResult, UNCONFIRMED};
use crate::geometry::Pose3;
use crate::register::PairResult;

#[allow(clippy::too_many_arguments)]
pub(super) fn site_result(
    sensors: &[SensorInput],
    anchor: usize,
    pairs: Vec<(usize, usize)>,
    results: Vec<PairResult>,
    groups: &[Vec<(usize, crate::geometry::Pose2)>],
    refusals: &[Option<Refusal>],
    solved: &Solved,
    sp: &SiteParams,
) -> SiteResult {
    let Solved {
        solution,
        contradicted,
        loose,
        origin,
        survey_conflicts,
    } = solved;
    let anchor_pitch = sensors.get(anchor).map_or(0.0, |s| s.mount.pitch_rad);
    let id = |k: usize| sensors.get(k).map_or("another sensor", |s| s.id.as_str());
    let caveat_of = |i: usize| {
        let used: Vec<((usize, usize), &PairResult)> = origin
            .iter()
            .filter_map(|&(k, _)| Some((*pairs.get(k)?, results.get(k)?)))
            .filter(|&((a, b), _)| a == i || b == i)
            .collect();
        let surveyed = sensors.get(i).is_some_and(|s| s.prior.is_some());
        caveat(sensors, i, i == anchor || surveyed, &used, sp)
    };
    let placements = sensors
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let survey_off = survey_conflicts.get(i).copied().flatten();
            Placement {
            id: s.id.clone(),
            survey_off,
            caveat: match survey_off {
                Some((dt, dyaw)) => Some(format!(
                    "stands where surveyed, {dt:.2} m / {:.1}° from where its scans put it against the others: its scans were left out of their placement; if the scans are right, clear its survey",
                    dyaw.to_degrees()
                )),
                None => solution.get(i).copied().flatten().and_then(|_| caveat_of(i)),
            },
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
                None => Err(match (contradicted[i], &loose[i]) {
                    (_, Some(why)) => why.describe(&id),
                    (Some(j), None) => format!(
                        "its only registrations put its scan in space {} saw empty",
                        id(j)
                    ),
                    (None, None) => {
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
                            Some(pair) if matches!(refusal_of(g, refusals), Some(Refusal::NoProposal)) => {
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
            }
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
        skipped: Vec::new(),
        rounds: 0,
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

impl SiteResult {
    /// What placed sensor `i`, in the pairs' vocabulary ([`evidence`]): `"walls"`,
    /// `"walkers"` (people alone) or `"walls+walkers"`, from the pairs that entered the solve
    /// at it. A sensor the join placed on no pair of its own was placed by the walls (joins
    /// score static views). None for the anchor and for a sensor not placed.
    ///
    /// [`evidence`]: crate::register::walkers::evidence
    pub fn evidence(&self, i: usize) -> Option<&'static str> {
        let placed = self.sensors.get(i).is_some_and(|s| s.pose.is_ok());
        if !placed || i == self.anchor {
            return None;
        }
        Some(evidence(
            self.pairs
                .iter()
                .filter(|p| p.used && (p.a == i || p.b == i))
                .map(|p| &p.result),
        ))
    }
}

/// What placed a sensor, from the pairs that placed it ([`SiteResult::evidence`]).
pub(super) fn evidence<'a>(used: impl IntoIterator<Item = &'a PairResult>) -> &'static str {
    let mut kinds = used
        .into_iter()
        .map(|r| crate::register::walkers::evidence(r.walkers.as_ref()));
    let first = kinds.next().unwrap_or("walls");
    if kinds.all(|k| k == first) {
        first
    } else {
        "walls+walkers"
    }
}

/// What to check of sensor `i`, placed on the `used` pairs (each with its result): that it
/// rests on too few pairs, and that nobody walked in any view it rests on (the walls alone
/// decided). None for an `exempt` sensor (the anchor, a surveyed one: only the latter part
/// could apply, and a survey confirms it).
pub(super) fn caveat(
    sensors: &[SensorInput],
    i: usize,
    exempt: bool,
    used: &[((usize, usize), &PairResult)],
    sp: &SiteParams,
) -> Option<String> {
    if exempt {
        return None;
    }
    let id = |k: usize| sensors.get(k).map_or("another sensor", |s| s.id.as_str());
    let mut partners: Vec<usize> = used
        .iter()
        .filter_map(|&((a, b), _)| match (a == i, b == i) {
            (true, _) => Some(b),
            (_, true) => Some(a),
            _ => None,
        })
        .collect();
    partners.sort_unstable();
    partners.dedup();
    // Where no one walked in any view it rests on, the walls alone decided.
    let nobody_walked = used
        .iter()
        .filter(|&&((a, b), _)| a == i || b == i)
        .map(|(_, r)| r.nobody_walked_s)
        .collect::<Option<Vec<f64>>>()
        .and_then(|w| w.into_iter().reduce(f64::min));
    let unconfirmed = nobody_walked.map(|watched_s| {
        format!(
            "{UNCONFIRMED}: no one walked in {watched_s:.0} s, so the walls alone placed \
             it; walk through its shared views while recording to confirm it"
        )
    });
    let thin = (partners.len() < sp.confirming_pairs).then(|| {
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
}
