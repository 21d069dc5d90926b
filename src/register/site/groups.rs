//! Groups: the registered pairs' edges that cycles check (consistent around triangles and
//! with a spanning tree, and on a cycle, not a bridge) or people confirmed bind sensors into
//! groups whose members' poses are relative to each other; the anchor's group is placed. Also
//! the graph helpers the other stages share (spanning poses from a sensor).

use super::memo::ScoreMemo;
use super::{Edge, SensorInput, SiteParams, candidate_edge};
use crate::geometry::{Pose2, pose_error};
use crate::register::{PairResult, RegisterParams};
use std::collections::HashMap;
use std::collections::hash_map::Entry;

/// The checked edges and, per edge, its (pair index, candidate index).
pub(super) struct Checked {
    pub edges: Vec<Edge>,
    pub origin: Vec<(usize, usize)>,
}

/// The registered pairs' answers kept by `consistent_edges` and not refuted by their ends'
/// neighbourhoods (`neighbourhoods`) that lie on a cycle or that people confirmed
/// (`PairResult::confirmed_by_people`).
#[allow(clippy::too_many_arguments)] // the stage inputs, as `join_groups`
pub(super) fn checked_edges(
    n: usize,
    anchor: usize,
    pairs: &[(usize, usize)],
    results: &[PairResult],
    sensors: &[SensorInput],
    p: &RegisterParams,
    sp: &SiteParams,
    memo: &ScoreMemo,
) -> Checked {
    let mut registered = Vec::new();
    let mut registered_origin = Vec::new(); // pair index per edge
    for (k, (&pair, r)) in pairs.iter().zip(results).enumerate() {
        if r.registered()
            && let Some(edge) = candidate_edge(pair, r, 0)
        {
            registered.push(edge);
            registered_origin.push(k);
        }
    }
    let consistent = consistent_edges(n, anchor, &registered, sp);
    let cycle_checked: Vec<Edge> = consistent.iter().map(|&e| registered[e].clone()).collect();
    let refuted = super::neighbourhoods::refuted(&cycle_checked, sensors, p, sp, memo);
    let kept: Vec<usize> = consistent
        .iter()
        .enumerate()
        .filter(|(k, _)| !refuted.contains(k))
        .map(|(_, &e)| e)
        .collect();
    let kept_edges: Vec<Edge> = kept.iter().map(|&e| registered[e].clone()).collect();
    let unchecked = bridges(n, &kept_edges);
    let (mut edges, mut origin) = (Vec::new(), Vec::new());
    for (k, &e) in kept.iter().enumerate() {
        // People both saw walk check a pair as a cycle would: the walls' look-alike is what
        // they refute. Left to propose only, a unit such a pair placed beside its partner
        // joined elsewhere instead, on four walls-only pairs of a repeating office, 9.4 m /
        // 180° off (held-out office, `eval --only drawing --seed 3`, site 7).
        let walked = results[registered_origin[e]].confirmed_by_people(p);
        if !unchecked.contains(&k) || walked {
            edges.push(registered[e].clone());
            origin.push((registered_origin[e], 0));
        }
    }
    Checked { edges, origin }
}

/// The anchor's group placed (anchor-frame poses), and every other group: sensors bound by
/// checked edges, with poses relative to the group's first member.
#[allow(clippy::type_complexity)]
pub(super) fn groups(
    n: usize,
    anchor: usize,
    checked: &[Edge],
) -> (Vec<Option<Pose2>>, Vec<Vec<(usize, Pose2)>>) {
    let placed = spanning_poses(n, anchor, checked);
    let mut groups: Vec<Vec<(usize, Pose2)>> = Vec::new();
    for (root, pose) in placed.iter().enumerate() {
        if pose.is_some() || groups.iter().flatten().any(|(m, _)| *m == root) {
            continue;
        }
        let members = spanning_poses(n, root, checked)
            .iter()
            .enumerate()
            .filter_map(|(m, pose)| pose.map(|pose| (m, pose)))
            .collect();
        groups.push(members);
    }
    (placed, groups)
}

/// Drops edges that disagree around triangles (more failed than passed cycles), then edges
/// that disagree with a spanning tree of the rest. Returns indices of kept edges.
pub fn consistent_edges(n: usize, anchor: usize, edges: &[Edge], sp: &SiteParams) -> Vec<usize> {
    // The first edge between each two sensors, and each sensor's neighbours: triangles are
    // found along edges, not by trying every triple of sensors.
    let mut first: HashMap<(usize, usize), usize> = HashMap::new();
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (k, e) in edges.iter().enumerate() {
        if e.a >= n || e.b >= n || e.a == e.b {
            continue;
        }
        if let Entry::Vacant(v) = first.entry((e.a.min(e.b), e.a.max(e.b))) {
            v.insert(k);
            neighbours[e.a].push(e.b);
            neighbours[e.b].push(e.a);
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
    }
    let find = |a: usize, b: usize| -> Option<(usize, Pose2)> {
        let &k = first.get(&(a.min(b), a.max(b)))?;
        let e = &edges[k];
        Some(if e.a == a {
            (k, e.a_from_b)
        } else {
            (k, e.a_from_b.inverse())
        })
    };
    let mut good = vec![0usize; edges.len()];
    let mut bad = vec![0usize; edges.len()];
    for i in 0..n {
        for &j in neighbours[i].iter().filter(|&&j| j > i) {
            for &k in neighbours[j].iter().filter(|&&k| k > j) {
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
    // Check the survivors against the trees they build; drop disagreeing ones once. Every
    // component gets its tree, not only the anchor's: a group that joins the anchor later is
    // placed whole on its edges, and a wrong edge among them that closes no triangle (a
    // look-alike bay on a periodic floor, where triangles through it would need a sensor seeing
    // both places) is caught only by the longer cycles a tree shows.
    let subset: Vec<Edge> = kept.iter().map(|&e| edges[e].clone()).collect();
    let mut poses = spanning_poses(n, anchor, &subset);
    for root in 0..n {
        if poses[root].is_none() {
            poses[root] = Some(Pose2::identity());
            grow_poses(&mut poses, &subset);
        }
    }
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
    // Each sensor's edges, so a search walks only the edges it reaches.
    let mut incident: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for (k, e) in edges.iter().enumerate() {
        if e.a < n && e.b < n {
            incident[e.a].push((k, e.b));
            incident[e.b].push((k, e.a));
        }
    }
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
            for &(k, v) in &incident[u] {
                if k != skip && !seen[v] {
                    stack.push(v);
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
pub(super) fn grow_poses(poses: &mut [Option<Pose2>], edges: &[Edge]) {
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
