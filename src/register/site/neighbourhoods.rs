//! Whether an edge's two ends agree beyond themselves: the views around one end (its
//! neighbours through the other checked edges) and those around the other, placed by the
//! edge, must not contradict each other. Cycles cannot tell a look-alike that repeats: on a
//! 120-unit concourse whose bays look alike turned end to end, units far apart matched each
//! other turned 180° (each pair's best answer, no rival), their edges closed consistent
//! triangles, and two stretches of the concourse (14 units) joined the anchor's group 44–120 m
//! off (`eval --only site --floor concourse --site-sensors 120 --motion-seconds 0 --seed 12`).
//! At such an edge the neighbours on either side land across each other's walls.

use super::memo::ScoreMemo;
use super::{Edge, SensorInput, SiteParams};
use crate::geometry::Pose2;
use crate::register::RegisterParams;
use crate::register::score::{WholeView, score};
use rayon::prelude::*;

/// Each end's neighbours counted, the strongest edges first: enough views to see past a
/// look-alike, few enough that a dense site's check costs little beside registering.
const NEIGHBOURS: usize = 8;

/// Below this many points where the two sides meet, the edge has no neighbourhood to test.
const MIN_POINTS: f64 = 200.0;

/// The indices of `edges` whose ends' neighbourhoods contradict each other (more than
/// `SiteParams::whole_view_violation` of the points where they meet), dropped one at a time,
/// the one most points contradict first, and the rest judged again without it: a wrong edge
/// inside one end's neighbourhood charges its right edges too.
pub(super) fn refuted(
    edges: &[Edge],
    sensors: &[SensorInput],
    p: &RegisterParams,
    sp: &SiteParams,
    memo: &ScoreMemo,
) -> Vec<usize> {
    let started = std::time::Instant::now();
    let reach = super::reach_m(sensors);
    let mut incident: Vec<Vec<usize>> = vec![Vec::new(); sensors.len()];
    for (k, e) in edges.iter().enumerate() {
        for s in [e.a, e.b] {
            if let Some(list) = incident.get_mut(s) {
                list.push(k);
            }
        }
    }
    let ctx = Ctx {
        edges,
        incident: &incident,
        sensors,
        reach: &reach,
        p,
        memo,
    };
    let mut alive = vec![true; edges.len()];
    let mut verdict: Vec<Option<WholeView>> = vec![None; edges.len()];
    let mut dropped = Vec::new();
    let refutes = |v: &WholeView| {
        v.hits + v.violations >= MIN_POINTS && v.violation() > sp.whole_view_violation
    };
    loop {
        let stale: Vec<usize> = (0..edges.len())
            .filter(|&e| alive[e] && verdict[e].is_none())
            .collect();
        let judged: Vec<WholeView> = stale.par_iter().map(|&e| ctx.meeting(e, &alive)).collect();
        for (&e, v) in stale.iter().zip(judged) {
            verdict[e] = Some(v);
        }
        let live = || {
            (0..edges.len())
                .filter(|&e| alive[e])
                .filter_map(|e| Some((e, verdict[e]?)))
        };
        // Of the refuted, the one most points contradict: a right edge beside a wrong one is
        // charged only through the few views the wrong one misplaces, the wrong one through
        // all the views on either side.
        let worst = live()
            .filter(|(_, v)| refutes(v))
            .max_by(|x, y| x.1.violations.total_cmp(&y.1.violations));
        let Some((e, v)) = worst else {
            let standing = live()
                .filter(|(_, v)| v.hits + v.violations >= MIN_POINTS)
                .map(|(_, v)| v.violation())
                .fold(0.0, f64::max);
            tracing::debug!(
                "neighbourhoods: {} edges, {} refuted, the worst standing at {:.0} %, {:.2} s",
                edges.len(),
                dropped.len(),
                100.0 * standing,
                started.elapsed().as_secs_f64()
            );
            break;
        };
        tracing::trace!(
            "neighbourhoods refute {}–{}: {:.0} % of the points where they meet contradict",
            sensors[edges[e].a].id,
            sensors[edges[e].b].id,
            100.0 * v.violation()
        );
        alive[e] = false;
        dropped.push(e);
        // The edges at either end had this one in their neighbourhoods.
        let (a, b) = (edges[e].a, edges[e].b);
        for &k in incident[a].iter().chain(&incident[b]) {
            verdict[k] = None;
        }
    }
    dropped
}

/// What every edge is judged against.
struct Ctx<'a> {
    edges: &'a [Edge],
    /// Each sensor's edges.
    incident: &'a [Vec<usize>],
    sensors: &'a [SensorInput],
    reach: &'a [f64],
    p: &'a RegisterParams,
    memo: &'a ScoreMemo,
}

impl Ctx<'_> {
    /// The views around edge `e`'s two ends, the second end's placed by the edge in the
    /// first's frame, scored against each other.
    fn meeting(&self, e: usize, alive: &[bool]) -> WholeView {
        let edge = &self.edges[e];
        let (side_a, side_b) = (
            self.neighbourhood(edge.a, edge.b, alive),
            self.neighbourhood(edge.b, edge.a, alive),
        );
        let reach = |s: usize| self.reach.get(s).copied().unwrap_or(f64::INFINITY);
        let mut terms: Vec<(usize, usize, Pose2)> = Vec::new();
        for &(u, a_from_u) in &side_a {
            for &(v, b_from_v) in &side_b {
                if u == v || (u, v) == (edge.a, edge.b) {
                    continue;
                }
                let u_from_v = a_from_u.inverse() * edge.a_from_b * b_from_v;
                if u_from_v.translation.vector.norm() <= reach(u) + reach(v) {
                    terms.push((u, v, u_from_v));
                }
            }
        }
        let model = |s: usize| &self.sensors[s].model;
        let scores = self
            .memo
            .scores(&terms, |u, v, pose| score(model(u), model(v), pose, self.p));
        let mut view = WholeView::default();
        for ((u, v, _), s) in terms.iter().zip(&scores) {
            view.add(s, model(*u), model(*v));
        }
        view
    }

    /// Sensor `s` and its `NEIGHBOURS` strongest neighbours through live edges other than to
    /// `not`, each with its pose in `s`'s frame.
    fn neighbourhood(&self, s: usize, not: usize, alive: &[bool]) -> Vec<(usize, Pose2)> {
        let mut near: Vec<(f64, usize, Pose2)> = self.incident[s]
            .iter()
            .filter(|&&k| alive[k])
            .filter_map(|&k| {
                let e = &self.edges[k];
                match (e.a == s, e.b == s) {
                    (true, false) if e.b != not => Some((e.strength, e.b, e.a_from_b)),
                    (false, true) if e.a != not => Some((e.strength, e.a, e.a_from_b.inverse())),
                    _ => None,
                }
            })
            .collect();
        near.sort_by(|x, y| y.0.total_cmp(&x.0));
        let mut out = vec![(s, Pose2::identity())];
        for (_, k, pose) in near {
            if out.len() > NEIGHBOURS {
                break;
            }
            if out.iter().all(|(m, _)| *m != k) {
                out.push((k, pose));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;
    use crate::register::site::tests::sensor_at;

    /// Four sensors in an L-shaped hall with pillars, two more in a closed room far off: the
    /// two rooms share no view.
    fn two_rooms() -> (Vec<SensorInput>, Vec<Pose2>) {
        let (walls, sensors) = crate::register::zones::tests::two_rooms();
        let truth: Vec<Pose2> = sensors.iter().map(|(_, pose)| *pose).collect();
        let fov = 270f64.to_radians();
        let sensors = truth
            .iter()
            .enumerate()
            .map(|(k, pose)| sensor_at(&walls, *pose, fov, &format!("s{k}")))
            .collect();
        (sensors, truth)
    }

    fn edge(a: usize, b: usize, a_from_b: Pose2) -> Edge {
        Edge {
            a,
            b,
            a_from_b,
            covariance: nalgebra::Matrix3::identity() * 1e-4,
            strength: 0.5,
        }
    }

    /// Two wrong edges that agree with each other (a triangle with the far room's own edge
    /// closes, as look-alikes on a periodic floor do) put the far room in the hall: the hall's
    /// other sensors see its walls cross their free space, and both are refuted; the true
    /// edges stand.
    #[test]
    fn wrong_edges_a_triangle_checks_are_refuted_where_the_neighbours_meet() {
        let (sensors, truth) = two_rooms();
        let rel = |a: usize, b: usize| truth[a].inverse() * truth[b];
        let mut edges: Vec<Edge> = Vec::new();
        for (a, b) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (4, 5)] {
            edges.push(edge(a, b, rel(a, b)));
        }
        let (p, sp, memo) = (
            RegisterParams::default(),
            SiteParams::default(),
            ScoreMemo::default(),
        );
        assert_eq!(
            refuted(&edges, &sensors, &p, &sp, &memo),
            Vec::<usize>::new()
        );
        // s4 stood half turned in the middle of the hall, and s5 beside it where s4 sees it.
        let s1_from_s4 = pose2(1.0, -2.0, 3.1);
        edges.push(edge(1, 4, s1_from_s4));
        edges.push(edge(1, 5, s1_from_s4 * rel(4, 5)));
        let mut got = refuted(&edges, &sensors, &p, &sp, &memo);
        got.sort_unstable();
        assert_eq!(got, vec![7, 8]);
    }
}
