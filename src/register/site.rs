//! The site solve (METHOD §4, seed 004): register every pair, drop edges that disagree around
//! cycles, let third sensors decide pairs that are ambiguous alone, and solve all kept edges
//! jointly by weighted least squares with the anchor fixed (and surveyed priors, if any).

use super::{PairResult, RegisterParams, ScanModel, register_pair};
use crate::geometry::{Mount, Pose2, Pose3, pose_error, pose2, wrap_angle_rad, yaw_rad};
use nalgebra::{DMatrix, DVector, Matrix3};
use rayon::prelude::*;

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
    /// Two candidate poses from different neighbours agreeing this well confirm each other.
    pub confirm_m: f64,
    pub confirm_rad: f64,
    /// Floor on edge σ, so no single edge is trusted absolutely.
    pub min_sigma_m: f64,
    pub min_sigma_rad: f64,
    /// An edge on no cycle (a bridge) has nothing to check it: it is kept only with at least
    /// this strength (overlap × (1 − ambiguity)); a weaker one leaves the far side to be
    /// placed by two agreeing candidates instead.
    pub bridge_min_strength: f64,
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
            bridge_min_strength: 0.2,
        }
    }
}

/// A sensor's place in the anchor's frame, or why it has none.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    pub id: String,
    pub pose: Result<PlacedPose, String>,
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

    let mut edges = Vec::new();
    let mut origin = Vec::new(); // (pair index, candidate index) per edge
    for (k, (&pair, r)) in pairs.iter().zip(&results).enumerate() {
        if r.registered()
            && let Some(edge) = candidate_edge(pair, r, 0)
        {
            edges.push(edge);
            origin.push((k, 0));
        }
    }
    let mut kept = consistent_edges(n, anchor, &edges, sp);
    let kept_edges: Vec<Edge> = kept.iter().map(|&e| edges[e].clone()).collect();
    let weak_bridges: Vec<usize> = bridges(n, &kept_edges)
        .into_iter()
        .filter(|&k| kept_edges[k].strength < sp.bridge_min_strength)
        .map(|k| kept[k])
        .collect();
    let weak_links: Vec<Edge> = weak_bridges.iter().map(|&e| edges[e].clone()).collect();
    kept.retain(|e| !weak_bridges.contains(e));
    let mut edges: Vec<Edge> = kept.iter().map(|&e| edges[e].clone()).collect();
    let mut origin: Vec<(usize, usize)> = kept.iter().map(|&e| origin[e]).collect();

    // Pairs that were not registered alone: a candidate confirmed by a second path wins.
    loop {
        let poses = spanning_poses(n, anchor, &edges);
        let mut added = false;
        for (k, (&(a, b), r)) in pairs.iter().zip(&results).enumerate() {
            if r.registered() || origin.iter().any(|o| o.0 == k) {
                continue;
            }
            let (Some(pa), Some(pb)) = (poses[a], poses[b]) else {
                continue;
            };
            let predicted = pa.inverse() * pb;
            let confirmed = r.candidates.iter().enumerate().find(|(_, c)| {
                let (dt, dyaw) = pose_error(&c.a_from_b, &predicted);
                c.score.overlap() >= p.min_overlap
                    && c.score.violation() <= p.max_violation
                    && dt <= sp.confirm_m
                    && dyaw <= sp.confirm_rad
            });
            if let Some((ci, _)) = confirmed
                && let Some(edge) = candidate_edge((a, b), r, ci)
            {
                edges.push(edge);
                origin.push((k, ci));
                added = true;
            }
        }
        // A sensor, or a group of sensors registered among themselves, hanging on no trusted
        // edge to the anchor's side: two candidates of different pairs, from different placed
        // sensors, that agree about where the group stands place it.
        if let Some(found) = confirm_group(n, anchor, &edges, &pairs, &results, &poses, p, sp) {
            for (k, ci) in found {
                if let Some(edge) = candidate_edge(pairs[k], &results[k], ci) {
                    edges.push(edge);
                    origin.push((k, ci));
                }
            }
            added = true;
        }
        if !added {
            break;
        }
    }

    // Every placed sensor must agree with every other placed sensor about free space, not
    // only with the ones it was registered to: a sensor hanging on one wrong edge has no cycle
    // to expose it, but its scan lands where a third sensor saw nothing. Drop the weaker side's
    // edges and solve again until no placement contradicts another.
    let mut solution = solve(n, anchor, &edges, sensors, sp);
    let mut contradicted = vec![None::<usize>; n];
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
                let v = super::score::score(
                    &sensors[i].model,
                    &sensors[j].model,
                    &(pi.inverse() * pj),
                    p,
                );
                v.violation() > p.max_violation
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
    let placements = sensors
        .iter()
        .enumerate()
        .map(|(i, s)| Placement {
            id: s.id.clone(),
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
                        sensors.get(j).map_or("another sensor", |s| s.id.as_str())
                    ),
                    None => unplaced_reason(i, sensors, &edges, &weak_links, &pairs, &results),
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

/// The edge a pair's candidate `ci` makes (candidate 0 is the pair's own answer).
fn candidate_edge(pair: (usize, usize), r: &PairResult, ci: usize) -> Option<Edge> {
    Some(Edge {
        a: pair.0,
        b: pair.1,
        a_from_b: r.candidates.get(ci)?.a_from_b,
        covariance: r.covariance,
        strength: strength(r),
    })
}

fn strength(r: &PairResult) -> f64 {
    r.overlap * (1.0 - r.ambiguity).max(0.05)
}

/// Finds two candidates, of pairs joining the anchor's side to one unplaced group (sensors
/// linked among themselves by kept edges, or a lone sensor), from two different placed
/// sensors, that agree about where the group stands. Returns (pair, candidate) of both.
#[allow(clippy::too_many_arguments)]
fn confirm_group(
    n: usize,
    anchor: usize,
    edges: &[Edge],
    pairs: &[(usize, usize)],
    results: &[PairResult],
    poses: &[Option<Pose2>],
    p: &RegisterParams,
    sp: &SiteParams,
) -> Option<[(usize, usize); 2]> {
    let mut grouped = vec![false; n];
    for root in 0..n {
        if poses[root].is_some() || grouped[root] || root == anchor {
            continue;
        }
        // The group's own frame: poses relative to `root` through its kept edges.
        let group = spanning_poses(n, root, edges);
        for (g, pose) in group.iter().enumerate() {
            grouped[g] |= pose.is_some();
        }
        // (pair, candidate, placed sensor, group member, anchor_from_root)
        let mut options = Vec::new();
        for (k, (&(a, b), r)) in pairs.iter().zip(results).enumerate() {
            let (placed, member, member_is_b) = match (poses[a], group[b], poses[b], group[a]) {
                (Some(_), Some(_), _, _) => (a, b, true),
                (_, _, Some(_), Some(_)) => (b, a, false),
                _ => continue,
            };
            let (Some(anchor_from_placed), Some(root_from_member)) = (poses[placed], group[member])
            else {
                continue;
            };
            for (ci, c) in r.candidates.iter().enumerate() {
                if c.score.overlap() < p.min_overlap || c.score.violation() > p.max_violation {
                    continue;
                }
                let placed_from_member = if member_is_b {
                    c.a_from_b
                } else {
                    c.a_from_b.inverse()
                };
                let anchor_from_root =
                    anchor_from_placed * placed_from_member * root_from_member.inverse();
                options.push((k, ci, placed, member, anchor_from_root));
            }
        }
        // Every placement two placed sensors agree on; a symmetric view can be confirmed
        // twice over, both the true pose and its mirror image, and then nothing is placed.
        let mut confirmed: Vec<([(usize, usize); 2], Pose2)> = Vec::new();
        for (i, x) in options.iter().enumerate() {
            for y in &options[i + 1..] {
                // From two placed sensors: one placed sensor's symmetric view can match a
                // whole group wrongly, consistently, through several of its members.
                if x.2 == y.2 {
                    continue;
                }
                let (dt, dyaw) = pose_error(&x.4, &y.4);
                if dt <= sp.confirm_m && dyaw <= sp.confirm_rad {
                    confirmed.push(([(x.0, x.1), (y.0, y.1)], x.4));
                }
            }
        }
        let Some((first, pose)) = confirmed.first() else {
            continue;
        };
        let unique = confirmed.iter().all(|(_, other)| {
            let (dt, dyaw) = pose_error(pose, other);
            dt <= 2.0 * sp.confirm_m && dyaw <= 2.0 * sp.confirm_rad
        });
        if unique {
            return Some(*first);
        }
    }
    None
}

fn unplaced_reason(
    i: usize,
    sensors: &[SensorInput],
    edges: &[Edge],
    weak_links: &[Edge],
    pairs: &[(usize, usize)],
    results: &[PairResult],
) -> String {
    let id = |k: usize| sensors.get(k).map_or("?", |s| s.id.as_str());
    // Its group: the sensors its kept edges reach.
    let group: Vec<usize> = spanning_poses(sensors.len(), i, edges)
        .iter()
        .enumerate()
        .filter_map(|(k, p)| p.map(|_| k))
        .collect();
    if group.len() > 1 {
        let names: Vec<&str> = group.iter().filter(|&&k| k != i).map(|&k| id(k)).collect();
        let links: Vec<String> = weak_links
            .iter()
            .filter(|e| group.contains(&e.a) != group.contains(&e.b))
            .map(|e| format!("{}–{} strength {:.2}", id(e.a), id(e.b), e.strength))
            .collect();
        return if links.is_empty() {
            format!(
                "registered with {}, but none of that group registers to the anchor's side",
                names.join(", ")
            )
        } else {
            format!(
                "registered with {}, but that group's links to the others ({}) are single edges no cycle checks, too weak to trust",
                names.join(", "),
                links.join(", ")
            )
        };
    }
    if let Some(e) = weak_links.iter().find(|e| e.a == i || e.b == i) {
        return format!(
            "its only registration ({}–{}) is too weak to trust unchecked (strength {:.2})",
            id(e.a),
            id(e.b),
            e.strength
        );
    }
    let best = pairs
        .iter()
        .zip(results)
        .filter(|((a, b), _)| *a == i || *b == i)
        .max_by(|x, y| x.1.score.value.total_cmp(&y.1.score.value));
    match best {
        None => "no other sensor to register against".to_string(),
        Some((_, r)) => match &r.verdict {
            Err(why) => format!("no consistent pair; best pair: {why}"),
            Ok(()) => "its registered pairs disagree with the rest of the site".to_string(),
        },
    }
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
            None => return poses,
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
    // Surveyed sensors not reached by any edge are placed by their prior.
    for (i, s) in sensors.iter().enumerate() {
        if poses[i].is_none()
            && let Some(prior) = s.prior
        {
            poses[i] = Some(prior.anchor_from_sensor);
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
}
