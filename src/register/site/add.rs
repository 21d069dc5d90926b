//! Adding one sensor to a placed site, with work proportional to its neighbours rather than to
//! the site: it is registered against the placed sensors whose views look most like its own
//! first (`descriptor`), a few at a time, and weighed alone against every placed sensor as a
//! joining group is (`join`: ambiguity, shared view, free space, slide). An accepted place is
//! then checked by every placed sensor it predicts shares enough of the new view to register
//! with it (`min_overlap`), registered too, and weighed again with them (their candidates are
//! the rivals a look-alike place would meet): it stands once there is none left to register.
//! Every placed scan within reach weighs in each joint score either way. Refused, the next
//! partners in the ranking are tried (twice as many each time), down to every placed sensor.
//! Where it stands then, and how surely, comes from the pairs that agree with it (`settle`).

use super::descriptor::ViewDescriptor;
use super::join::{JoinContext, Refusal};
use super::memo::ScoreMemo;
use super::report::{caveat, evidence};
use super::settle::settle;
use super::{SensorInput, SiteParams};
use crate::geometry::Pose2;
use crate::register::model::shared_view;
use crate::register::{PairResult, RegisterParams, register_pair};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Partners tried first: `SiteParams::partners`, at most this many.
const FIRST_PARTNERS: usize = 8;

/// Where a sensor added to a placed site stands, and the pairs it took.
#[derive(Debug, Clone)]
pub struct AddedSensor {
    /// Its pose in the anchor's frame, or why it cannot be placed.
    pub pose: Result<Pose2, String>,
    /// σ of its x, y (anchor frame) and yaw: from the pairs it rests on and their partners' σ.
    /// Zero when refused.
    pub sigma: [f64; 3],
    /// What to check of it, as the site registration says it (`Placement::caveat`).
    pub caveat: Option<String>,
    /// What placed it, in the pairs' vocabulary (`SiteResult::evidence`); None when refused.
    pub evidence: Option<&'static str>,
    /// The pairs registered (a < b), with their results.
    pub pairs: Vec<((usize, usize), PairResult)>,
    /// Placed sensors it could have been registered against.
    pub placed: usize,
}

/// Places `sensors[new]` against the others at `placed` (anchor-frame poses; `None` for one
/// not placed, which is left out), whose σ (x, y, yaw) are `sigma` (missing: exact).
/// `placed[new]` is ignored.
pub fn add_sensor(
    sensors: &[SensorInput],
    placed: &[Option<Pose2>],
    sigma: &[[f64; 3]],
    new: usize,
    p: &RegisterParams,
    sp: &SiteParams,
) -> AddedSensor {
    let others: Vec<(usize, Pose2)> = placed
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != new && i < sensors.len())
        .filter_map(|(i, pose)| pose.map(|pose| (i, pose)))
        .collect();
    let Some(newcomer) = sensors.get(new) else {
        return AddedSensor::refused(
            format!("no sensor {new} among {}", sensors.len()),
            Vec::new(),
            others.len(),
        );
    };
    let mine = ViewDescriptor::of(&newcomer.model);
    let mut ranked: Vec<(f64, usize)> = others
        .par_iter()
        .map(|&(i, _)| (mine.distance(&ViewDescriptor::of(&sensors[i].model)), i))
        .collect();
    ranked.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    let reach_m = super::reach_m(sensors);
    let memo = ScoreMemo::default();
    let mut results: BTreeMap<(usize, usize), PairResult> = BTreeMap::new();
    let key = |i: usize| (i.min(new), i.max(new));
    let register = |todo: &[usize], results: &mut BTreeMap<(usize, usize), PairResult>| {
        let done: Vec<((usize, usize), PairResult)> = todo
            .par_iter()
            .map(|&i| {
                let (a, b) = key(i);
                (
                    (a, b),
                    register_pair(&sensors[a].model, &sensors[b].model, p),
                )
            })
            .collect();
        results.extend(done);
    };
    let (mut tried, mut count) = (0, sp.partners.clamp(1, FIRST_PARTNERS));
    let mut why = "no placed sensor to register it against".to_string();
    while tried < ranked.len() {
        let todo: Vec<usize> = ranked[tried..(tried + count).min(ranked.len())]
            .iter()
            .map(|&(_, i)| i)
            .filter(|&i| !results.contains_key(&key(i)))
            .collect();
        tried += count;
        count = count.saturating_mul(2);
        register(&todo, &mut results);
        // Weigh; where it lands, register every placed sensor predicted to share its view and
        // weigh again, until the place holds with all of them (each pass registers more).
        loop {
            let (pairs, rs): (Vec<(usize, usize)>, Vec<PairResult>) =
                results.iter().map(|(&k, r)| (k, r.clone())).unzip();
            let ctx = JoinContext {
                sensors,
                placed: others.clone(),
                pairs: &pairs,
                results: &rs,
                p,
                sp,
                reach_m: &reach_m,
                memo: Some(&memo),
            };
            let alone = [(new, Pose2::identity())];
            let verdict = ctx
                .weigh(&alone)
                .and_then(|join| match ctx.slides(&alone, &join) {
                    Some(refusal) => Err(refusal),
                    None => Ok(join),
                });
            let join = match verdict {
                Ok(join) => join,
                Err(refusal) => {
                    why = refusal.describe(&|i| sensors.get(i).map_or("?", |s| s.id.as_str()));
                    break;
                }
            };
            let at = join.anchor_from_root;
            let unchecked: Vec<usize> = others
                .par_iter()
                .filter(|&&(i, _)| !results.contains_key(&key(i)))
                .filter(|&&(i, anchor_from_i)| {
                    let i_from_new = anchor_from_i.inverse() * at;
                    i_from_new.translation.vector.norm() <= reach_m[i] + reach_m[new]
                        && shared_view(&sensors[i].model, &newcomer.model, &i_from_new)
                            >= p.min_overlap
                })
                .map(|&(i, _)| i)
                .collect();
            if unchecked.is_empty() {
                let pairs: Vec<((usize, usize), PairResult)> = results.into_iter().collect();
                return settled(
                    sensors,
                    &others,
                    sigma,
                    new,
                    &at,
                    pairs,
                    &join.sources,
                    p,
                    sp,
                );
            }
            register(&unchecked, &mut results);
        }
    }
    AddedSensor::refused(why, results.into_iter().collect(), others.len())
}

impl AddedSensor {
    fn refused(why: String, pairs: Vec<((usize, usize), PairResult)>, placed: usize) -> Self {
        AddedSensor {
            pose: Err(why),
            sigma: [0.0; 3],
            caveat: None,
            evidence: None,
            pairs,
            placed,
        }
    }
}

/// The added sensor joined at `at` by the join's `proposed` (pair, candidate)s, settled on its
/// agreeing pairs, with its caveat and evidence from them.
#[allow(clippy::too_many_arguments)] // add_sensor's inputs and the join's outcome
fn settled(
    sensors: &[SensorInput],
    others: &[(usize, Pose2)],
    sigma: &[[f64; 3]],
    new: usize,
    at: &Pose2,
    pairs: Vec<((usize, usize), PairResult)>,
    proposed: &[(usize, usize)],
    p: &RegisterParams,
    sp: &SiteParams,
) -> AddedSensor {
    let placed: Vec<(usize, Pose2, [f64; 3])> = others
        .iter()
        .map(|&(i, pose)| (i, pose, sigma.get(i).copied().unwrap_or([0.0; 3])))
        .collect();
    let Some(s) = settle(new, at, &placed, &pairs, proposed, p, sp) else {
        let why = "no pair agrees with where its view fits the placed sensors".to_string();
        return AddedSensor::refused(why, pairs, others.len());
    };
    if let Some(loose) = Refusal::loose(&s.sigma, sp) {
        let why = loose.describe(&|i| sensors.get(i).map_or("?", |s| s.id.as_str()));
        return AddedSensor::refused(why, pairs, others.len());
    }
    let used: Vec<((usize, usize), &PairResult)> = s
        .used
        .iter()
        .filter_map(|&k| pairs.get(k).map(|(key, r)| (*key, r)))
        .collect();
    AddedSensor {
        pose: Ok(s.pose),
        sigma: s.sigma,
        caveat: caveat(sensors, new, false, &used, sp),
        evidence: Some(evidence(used.iter().map(|&(_, r)| r))),
        placed: others.len(),
        pairs,
    }
}
