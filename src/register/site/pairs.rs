//! Pair selection: which pairs of sensors are registered. Most pairs of a large site share no
//! view, and registering one is the dearest step, so a site starts from each sensor's most
//! likely partners (`descriptor`'s ranking) and widens in rounds. Two pairs registered
//! through one sensor propose the pair that closes their triangle; then the groups alone, and
//! once nothing more comes of them the stages (joins), say where every sensor stands: a
//! sensor still unplaced tries the sensors posed beside those it already shares view with,
//! where a candidate of that pair would put them in its view, and when there are none, the
//! next partners in its ranking (twice as many each round, down to every other sensor); two
//! sensors placed (or in one group) are registered when their scans overlap where the site
//! puts them, which adds the cycles and pairs that check them. It stops when a round
//! proposes nothing new. Every other pair is skipped, and why.

use super::SensorInput;
use super::descriptor::{ViewDescriptor, rank_partners};
use crate::geometry::Pose2;
use crate::register::model::shared_view;
use crate::register::{PairResult, RegisterParams, register_pair};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Why a pair was not registered.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Skip {
    /// Both ends were placed (or bound in one group) and at those poses their scans share
    /// this share of view, too little to register.
    NoSharedView { predicted: f64 },
    /// Both ends were placed before either's ranking reached the other.
    NotNeeded,
}

impl Skip {
    /// A short name of the reason, for counting and for JSON.
    pub fn kind(&self) -> &'static str {
        match self {
            Skip::NoSharedView { .. } => "no_shared_view",
            Skip::NotNeeded => "not_needed",
        }
    }

    pub fn describe(&self) -> String {
        match self {
            Skip::NoSharedView { predicted } => format!(
                "where the site places them they share {:.0} % of their view",
                predicted * 100.0
            ),
            Skip::NotNeeded => {
                "both were placed before their views ranked each other as likely partners"
                    .to_string()
            }
        }
    }
}

/// A pair that was not registered.
#[derive(Debug, Clone, PartialEq)]
pub struct SkippedPair {
    pub a: usize,
    pub b: usize,
    pub why: Skip,
}

/// Two sensors placed in one frame are registered when they are predicted to share at least
/// this share of view: less cannot register (`min_overlap` 0.2) but a pair near it may still
/// carry a candidate the joins, the second opinion and the solve weigh. The prediction counts
/// every point within 10 cm, the registration its sample within the hit distance: on a
/// 100-scanner concourse a pair predicted at 4.6 % found 15 % and entered the solve.
const PREDICTED_SHARE: f64 = 0.03;

/// The pairs registered so far, and the ranking that proposes more.
pub(super) struct PairSelection<'a> {
    sensors: &'a [SensorInput],
    p: &'a RegisterParams,
    /// Each sensor's other sensors, most alike first.
    ranking: Vec<Vec<usize>>,
    /// How far down its ranking each sensor has been tried.
    tried: Vec<usize>,
    results: BTreeMap<(usize, usize), PairResult>,
    /// How far each sensor's points reach from it (m): two sensors farther apart than the sum
    /// share no view.
    reach_m: Vec<f64>,
    /// `partners` is the first round's count per sensor.
    partners: usize,
}

impl<'a> PairSelection<'a> {
    pub fn new(sensors: &'a [SensorInput], p: &'a RegisterParams, partners: usize) -> Self {
        let descriptors: Vec<ViewDescriptor> = sensors
            .par_iter()
            .map(|s| ViewDescriptor::of(&s.model))
            .collect();
        PairSelection {
            sensors,
            p,
            ranking: rank_partners(&descriptors),
            tried: vec![0; sensors.len()],
            results: BTreeMap::new(),
            reach_m: super::reach_m(sensors),
            partners: partners.max(1),
        }
    }

    /// The first round: every sensor's `partners` most alike.
    pub fn first_round(&mut self) -> Vec<(usize, usize)> {
        let all: Vec<usize> = (0..self.sensors.len()).collect();
        self.next_partners(&all, self.partners)
    }

    /// The next `count` partners in each of `sensors`' rankings, as new pairs (a < b).
    fn next_partners(&mut self, sensors: &[usize], count: usize) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for &i in sensors {
            let from = self.tried[i];
            let to = from.saturating_add(count).min(self.ranking[i].len());
            for &j in &self.ranking[i][from..to] {
                pairs.push((i.min(j), i.max(j)));
            }
            self.tried[i] = to;
        }
        self.fresh(pairs)
    }

    /// `pairs` without duplicates and those already registered.
    fn fresh(&self, mut pairs: Vec<(usize, usize)>) -> Vec<(usize, usize)> {
        pairs.sort_unstable();
        pairs.dedup();
        pairs.retain(|k| k.0 != k.1 && !self.results.contains_key(k));
        pairs
    }

    /// Registers `pairs` (in parallel).
    pub fn register(&mut self, pairs: &[(usize, usize)]) {
        let (sensors, p) = (self.sensors, self.p);
        let done: Vec<PairResult> = pairs
            .par_iter()
            .map(|&(a, b)| register_pair(&sensors[a].model, &sensors[b].model, p))
            .collect();
        self.results.extend(pairs.iter().copied().zip(done));
    }

    /// The pairs registered so far, in (a, b) order, and their results.
    #[allow(clippy::type_complexity)]
    pub fn registered(&self) -> (Vec<(usize, usize)>, Vec<PairResult>) {
        self.results.iter().map(|(&k, r)| (k, r.clone())).unzip()
    }

    /// Predicted shared view of `a` and `b` at `a_from_b` (0 when out of each other's reach).
    fn predicted(&self, a: usize, b: usize, a_from_b: &Pose2) -> f64 {
        if a_from_b.translation.vector.norm() > self.reach_m[a] + self.reach_m[b] {
            return 0.0;
        }
        shared_view(&self.sensors[a].model, &self.sensors[b].model, a_from_b)
    }

    /// The next round, given where the stages put every sensor: `frame[i]` is the frame a
    /// sensor was posed in (0 = the anchor's, g + 1 = group g's) and its pose there.
    pub fn widen(
        &mut self,
        frame: &[Option<(usize, Pose2)>],
        placed: &[bool],
    ) -> Vec<(usize, usize)> {
        let n = self.sensors.len();
        let mut pairs = Vec::new();
        // Posed in one frame: register where the scans overlap.
        let posed: Vec<(usize, usize, Pose2)> = frame
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f.map(|(g, pose)| (i, g, pose)))
            .collect();
        let candidates: Vec<(usize, usize, Pose2)> = posed
            .iter()
            .flat_map(|&(i, gi, pi)| {
                posed
                    .iter()
                    .filter(move |&&(j, gj, _)| j > i && gj == gi)
                    .map(move |&(j, _, pj)| (i, j, pi.inverse() * pj))
            })
            .filter(|(i, j, _)| !self.results.contains_key(&(*i, *j)))
            .collect();
        pairs.extend(
            candidates
                .par_iter()
                .filter(|(i, j, rel)| self.predicted(*i, *j, rel) >= PREDICTED_SHARE)
                .map(|&(i, j, _)| (i, j))
                .collect::<Vec<_>>(),
        );
        // Unplaced: the sensors posed beside those each already shares view with, where one
        // of those pairs' candidates would put them in its view; else further down the
        // ranking (twice as far as before).
        let unplaced: Vec<usize> = (0..n).filter(|&i| !placed[i]).collect();
        let near: Vec<Vec<(usize, usize)>> = unplaced
            .par_iter()
            .map(|&u| self.fresh(self.beside_neighbours(u, frame, &posed)))
            .collect();
        for (&u, near) in unplaced.iter().zip(near) {
            if near.is_empty() {
                let count = self.tried[u].max(self.partners);
                pairs.extend(self.next_partners(&[u], count));
            } else {
                pairs.extend(near);
            }
        }
        self.fresh(pairs)
    }

    /// Pairs of `u` with sensors posed in the frame of one of its neighbours `v` (a pair that
    /// found shared view, placed or not), where some candidate of `u`–`v` puts them in `u`'s
    /// view: a candidate of a look-alike pair proposes only the few sensors it would make
    /// `u` overlap, not every partner of `v`'s.
    fn beside_neighbours(
        &self,
        u: usize,
        frame: &[Option<(usize, Pose2)>],
        posed: &[(usize, usize, Pose2)],
    ) -> Vec<(usize, usize)> {
        let own = frame[u].map(|(g, _)| g);
        let mut near = Vec::new();
        for (v, r) in self.neighbour_results(u) {
            let Some((g, pv)) = frame[v] else { continue };
            if Some(g) == own {
                continue;
            }
            let beside: Vec<(usize, Pose2)> = posed
                .iter()
                .filter(|&&(w, gw, _)| gw == g && w != u)
                .map(|&(w, _, pw)| (w, pw))
                .collect();
            for c in &r.candidates {
                let u_from_v = if u < v {
                    c.a_from_b
                } else {
                    c.a_from_b.inverse()
                };
                let u_from_frame = u_from_v * pv.inverse();
                for &(w, pw) in &beside {
                    let key = (u.min(w), u.max(w));
                    if !self.results.contains_key(&key)
                        && !near.contains(&key)
                        && self.predicted(u, w, &(u_from_frame * pw)) >= PREDICTED_SHARE
                    {
                        near.push(key);
                    }
                }
            }
        }
        near
    }

    /// Pairs that close a triangle: `a` and `c`, each registered with some `b`, that share at
    /// least `PREDICTED_SHARE` of their view where those two registrations put them. It needs
    /// no joins, so a chain of pairs becomes cycles (and groups) before the site stages weigh
    /// it: most of a large site's true pairs are found this way, in few rounds.
    pub fn close_triangles(&self) -> Vec<(usize, usize)> {
        let n = self.sensors.len();
        let mut linked: Vec<Vec<(usize, Pose2)>> = vec![Vec::new(); n];
        for (&(a, b), r) in &self.results {
            if r.registered() {
                linked[a].push((b, r.a_from_b));
                linked[b].push((a, r.a_from_b.inverse()));
            }
        }
        let candidates: Vec<(usize, usize, Pose2)> = (0..n)
            .flat_map(|b| {
                let linked = &linked;
                linked[b].iter().flat_map(move |&(a, b_from_a)| {
                    linked[b]
                        .iter()
                        .filter(move |&&(c, _)| c > a)
                        .map(move |&(c, b_from_c)| (a, c, b_from_a.inverse() * b_from_c))
                })
            })
            .filter(|(a, c, _)| !self.results.contains_key(&(*a, *c)))
            .collect();
        let mut pairs: Vec<(usize, usize)> = candidates
            .par_iter()
            .filter(|(a, c, a_from_c)| self.predicted(*a, *c, a_from_c) >= PREDICTED_SHARE)
            .map(|&(a, c, _)| (a, c))
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    }

    /// Sensors whose pair with `i` found at least `min_overlap` of shared view, and that pair.
    fn neighbour_results(&self, i: usize) -> impl Iterator<Item = (usize, &PairResult)> {
        self.results
            .iter()
            .filter(|(_, r)| r.overlap >= self.p.min_overlap)
            .filter_map(move |(&(a, b), r)| match (a == i, b == i) {
                (true, _) => Some((b, r)),
                (_, true) => Some((a, r)),
                _ => None,
            })
    }

    /// Every pair not registered, and why.
    pub fn skipped(&self, frame: &[Option<(usize, Pose2)>]) -> Vec<SkippedPair> {
        let n = self.sensors.len();
        (0..n)
            .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
            .filter(|k| !self.results.contains_key(k))
            .map(|(a, b)| {
                let why = match (frame[a], frame[b]) {
                    (Some((ga, pa)), Some((gb, pb))) if ga == gb => Skip::NoSharedView {
                        predicted: self.predicted(a, b, &(pa.inverse() * pb)),
                    },
                    _ => Skip::NotNeeded,
                };
                SkippedPair { a, b, why }
            })
            .collect()
    }
}
