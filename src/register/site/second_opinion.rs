//! The second opinion: every placed sensor weighed alone against all the others after the
//! joins, moved where the rest of the site clearly and jointly puts it.

use super::SensorInput;
use super::SiteParams;
use super::join::{JoinContext, Refusal};
use super::memo::ScoreMemo;
use crate::geometry::{Pose2, pose_error};
use crate::register::{PairResult, RegisterParams};

/// A second opinion on every placement: each placed sensor weighed alone against all the
/// others, as a group joining them would be. Two wrong edges that agree with each other (a
/// mirror image of the sensor's view, seen the same way by two neighbours) close a cycle and
/// bind it into a group; its pairs with the rest of the site may still say, jointly and
/// clearly, that it stands elsewhere. Then it moves there; when it is the anchor, everyone
/// else moves instead, so the anchor keeps the frame.
///
/// A move changes the evidence for the others (a block of sensors bound to a look-alike place
/// moves back one by one, and the first weighed still saw the rest of the block there), so the
/// passes repeat while anything moves. A sensor whose pairs outvote its place but whose rival
/// place is refused too stands nowhere the site can say: it is withdrawn (returned, with why).
#[allow(clippy::too_many_arguments)] // the stage inputs, as `join_groups` and `site_result`
pub(super) fn second_opinion(
    placed: &mut [Option<Pose2>],
    anchor: usize,
    sensors: &[SensorInput],
    pairs: &[(usize, usize)],
    results: &[PairResult],
    p: &RegisterParams,
    sp: &SiteParams,
    memo: &ScoreMemo,
) -> Vec<(usize, Refusal)> {
    let reach_m = super::reach_m(sensors);
    // What every opinion is weighed against but the placed sensors (filled in per sensor).
    let base = JoinContext {
        sensors,
        placed: Vec::new(),
        pairs,
        results,
        p,
        sp,
        reach_m: &reach_m,
        memo: Some(memo),
    };
    let mut withdrawn = Vec::new();
    for _ in 0..MAX_PASSES {
        if !one_pass(placed, anchor, &base, &mut withdrawn) {
            break;
        }
    }
    withdrawn
}

/// Passes of the second opinion at most (each after one that moved or withdrew a sensor).
const MAX_PASSES: usize = 4;

/// One pass over every placed sensor; whether any moved or was withdrawn.
fn one_pass(
    placed: &mut [Option<Pose2>],
    anchor: usize,
    base: &JoinContext<'_>,
    withdrawn: &mut Vec<(usize, Refusal)>,
) -> bool {
    let (sensors, p, sp) = (base.sensors, base.p, base.sp);
    let mut changed = false;
    // The anchor first: were it wrong, every other opinion would be taken in its wrong frame.
    let order = std::iter::once(anchor).chain((0..placed.len()).filter(|&k| k != anchor));
    for k in order {
        let Some(current) = placed.get(k).copied().flatten() else {
            continue;
        };
        let ctx = JoinContext {
            placed: placed
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != k)
                .filter_map(|(i, pose)| pose.map(|pose| (i, pose)))
                .collect(),
            ..*base
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
        let join = match ctx.weigh(&alone) {
            Ok(join) => join,
            Err(then) => {
                // Outvoted, and the rival place does not stand either: withdraw it (never
                // the anchor, which keeps the frame).
                let against = ctx
                    .opinions_on(k, current)
                    .filter(|(_, _, _, agrees)| !agrees)
                    .map(|(_, _, place, _)| ctx.support(k, place))
                    .max()
                    .unwrap_or(0);
                if k != anchor && against > current_support {
                    tracing::trace!("second opinion withdraws {}", sensors[k].id);
                    placed[k] = None;
                    withdrawn.push((
                        k,
                        Refusal::Outvoted {
                            support: current_support,
                            against,
                            then: Box::new(then),
                        },
                    ));
                    changed = true;
                }
                continue;
            }
        };
        let (dt, dyaw) = pose_error(&join.anchor_from_root, &current);
        if (dt <= sp.confirm_m && dyaw <= sp.confirm_rad) || ctx.slides(&alone, &join).is_some() {
            continue;
        }
        if !contradicted && !outvoted(&join.anchor_from_root) {
            continue;
        }
        tracing::trace!(
            "second opinion moves {} by {dt:.2} m (contradicted: {contradicted})",
            sensors[k].id
        );
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
        changed = true;
    }
    changed
}
