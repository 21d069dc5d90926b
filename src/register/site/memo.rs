//! Pair scores already computed while placing a site, by the two sensors and the pose of one in
//! the other's frame. A join weighs every open group again after each join near it, mostly at
//! the same placements against the same placed sensors (which do not move while joining), and
//! the second opinion weighs those placements again: scoring (`score::score`, a pure function
//! of the two scans, the pose and the parameters) is the dear part, so each is done once.

use crate::geometry::Pose2;
use crate::register::score::PoseScore;
use rustc_hash::FxHashMap;
use std::sync::Mutex;

/// (sensor in whose frame, other sensor, the other's pose there, bit for bit).
type Key = (usize, usize, [u64; 4]);

/// Scores kept at most: past it the rest are scored afresh each time they are asked for. A
/// 100-scanner concourse keeps 0.45 M; the 200-scanner one, whose two halves weighed 33 594
/// placements of a 161-sensor group, kept 102 M and peaked at 21.6 GB RSS, 2.2 GB capped.
const MAX_KEPT: usize = 4_000_000;

/// Scores by pair and relative pose, for one set of sensors and one `RegisterParams`.
pub(super) struct ScoreMemo {
    scores: Mutex<FxHashMap<Key, PoseScore>>,
    max_kept: usize,
}

impl Default for ScoreMemo {
    fn default() -> Self {
        ScoreMemo {
            scores: Mutex::default(),
            max_kept: MAX_KEPT,
        }
    }
}

fn key(i: usize, j: usize, i_from_j: &Pose2) -> Key {
    let (t, r) = (i_from_j.translation.vector, i_from_j.rotation);
    (i, j, [t.x, t.y, r.re, r.im].map(f64::to_bits))
}

impl ScoreMemo {
    /// The score of every (i, j, i_from_j) in `terms`, computing with `score` only those not
    /// seen before. The lock is held for lookups and inserts, never while scoring, so callers
    /// may score placements in parallel.
    pub fn scores(
        &self,
        terms: &[(usize, usize, Pose2)],
        score: impl Fn(usize, usize, &Pose2) -> PoseScore,
    ) -> Vec<PoseScore> {
        let known: Vec<Option<PoseScore>> = {
            let map = self.scores.lock().unwrap_or_else(|e| e.into_inner());
            terms
                .iter()
                .map(|(i, j, pose)| map.get(&key(*i, *j, pose)).copied())
                .collect()
        };
        let mut fresh = Vec::new();
        let scores = terms
            .iter()
            .zip(known)
            .map(|(&(i, j, pose), known)| {
                known.unwrap_or_else(|| {
                    let s = score(i, j, &pose);
                    fresh.push((key(i, j, &pose), s));
                    s
                })
            })
            .collect();
        if !fresh.is_empty() {
            let mut map = self.scores.lock().unwrap_or_else(|e| e.into_inner());
            let room = self.max_kept.saturating_sub(map.len());
            map.extend(fresh.into_iter().take(room));
        }
        scores
    }

    /// How many scores are kept.
    pub fn len(&self) -> usize {
        self.scores.lock().map_or(0, |m| m.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;
    use std::cell::Cell;

    #[test]
    fn a_score_is_computed_once_per_pair_and_pose() {
        let memo = ScoreMemo::default();
        let calls = Cell::new(0);
        let score = |i: usize, j: usize, pose: &Pose2| {
            calls.set(calls.get() + 1);
            PoseScore {
                value: i as f64 * 10.0 + j as f64 + pose.translation.x,
                ..PoseScore::default()
            }
        };
        let (a, b) = (pose2(1.0, 2.0, 0.3), pose2(1.0, 2.0, 0.3 + 1e-12));
        let first = memo.scores(&[(0, 1, a), (0, 2, a)], score);
        assert_eq!(calls.get(), 2);
        // The same pair and pose again is looked up; another pair, or a pose a hair apart, not.
        let again = memo.scores(&[(0, 1, a), (1, 0, a), (0, 1, b)], score);
        assert_eq!(calls.get(), 4);
        assert_eq!(again[0], first[0]);
        assert_eq!(again[1].value, 11.0);
        assert_eq!(memo.len(), 4);
    }

    #[test]
    fn a_full_memo_keeps_no_more_but_still_answers() {
        let memo = ScoreMemo {
            max_kept: 2,
            ..ScoreMemo::default()
        };
        let calls = Cell::new(0);
        let score = |i: usize, _: usize, _: &Pose2| {
            calls.set(calls.get() + 1);
            PoseScore {
                value: i as f64,
                ..PoseScore::default()
            }
        };
        let terms: Vec<(usize, usize, Pose2)> =
            (0..4).map(|i| (i, 9, pose2(0.0, 0.0, 0.0))).collect();
        let first = memo.scores(&terms, score);
        assert_eq!(memo.len(), 2);
        let again = memo.scores(&terms, score);
        assert_eq!(first, again);
        // The two kept are looked up; the two past the limit are scored again.
        assert_eq!(calls.get(), 6);
    }
}
