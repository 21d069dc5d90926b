//! Zones joined into one site frame (issue 21). Each zone places its own sensors in its own
//! frame and stays authoritative for them; this finds where each zone stands in the anchor
//! zone's frame (`site_from_zone`) from pairs of sensors of different zones, registered on
//! their static views by the same `register_pair` as inside a zone.
//!
//! Every registered cross pair (s of zone A, t of zone B) says where B stands in A:
//! `a_from_b = a_from_s · s_from_t · (b_from_t)⁻¹`. The pairs between two zones must agree:
//! the largest set that agrees (the site's cycle tolerance) is the link, and a rival set half
//! its size or more leaves the two unlinked (a look-alike across zones). A set stands only
//! where the two zones' whole views bear its pose out (every sensor of one against every
//! sensor of the other, not just the pairs that registered). Links that disagree
//! around triangles of zones are dropped as inside a site (`consistent_edges`), and the weighted
//! least squares of the site (`solve`) places every zone the links reach, with σ.

use nalgebra::Matrix3;
use rayon::prelude::*;

use super::score::{WholeView, score};
use super::site::{Edge, Prior, SiteParams, consistent_edges, solve};
use super::{PairResult, RegisterParams, ScanModel, register_pair};
use crate::geometry::{Pose2, pose_error, pose2, wrap_angle_rad};

/// One placed sensor of a zone.
#[derive(Debug, Clone)]
pub struct ZoneSensor {
    pub id: String,
    pub model: ScanModel,
    /// Its pose in its zone's frame, and σ (x m, y m, yaw rad) there.
    pub zone_from_sensor: Pose2,
    pub sigma: [f64; 3],
    /// Its pose surveyed in the site frame (the anchor zone's), if an installer measured it:
    /// a second anchor, that holds its zone where the survey puts the unit (with the
    /// survey's σ and the unit's in its zone). The anchor zone's surveys are not used.
    pub surveyed: Option<Prior>,
}

/// One zone: its id and its placed sensors.
#[derive(Debug, Clone)]
pub struct ZoneInput {
    pub id: String,
    pub sensors: Vec<ZoneSensor>,
}

/// How the zones are joined.
#[derive(Debug, Clone)]
pub struct ZoneParams {
    pub register: RegisterParams,
    pub site: SiteParams,
    /// Every cross pair is registered while there are at most this many; beyond, only the
    /// pairs among each zone's `outward` sensors that see most past their zone ([`outward`]).
    pub all_pairs_up_to: usize,
    pub outward: usize,
}

impl Default for ZoneParams {
    fn default() -> Self {
        ZoneParams {
            register: RegisterParams::default(),
            site: SiteParams::default(),
            all_pairs_up_to: 400,
            outward: 6,
        }
    }
}

/// Where one zone stands, or why it does not.
#[derive(Debug, Clone, PartialEq)]
pub struct ZonePlacement {
    pub id: String,
    /// `site_from_zone` and its σ (x m, y m, yaw rad).
    pub site_from_zone: Result<(Pose2, [f64; 3]), String>,
    /// Cross pairs the link to it rests on (0 for the anchor).
    pub pairs: usize,
}

/// One cross pair registered: sensor `s` of zone `za` against `t` of zone `zb`.
#[derive(Debug, Clone)]
pub struct CrossPair {
    pub za: usize,
    pub s: usize,
    pub zb: usize,
    pub t: usize,
    pub result: PairResult,
    /// It is part of the link between its two zones.
    pub used: bool,
}

#[derive(Debug, Clone)]
pub struct ZonesResult {
    pub anchor: usize,
    pub zones: Vec<ZonePlacement>,
    pub pairs: Vec<CrossPair>,
}

/// A sensor by its zone and index in it.
type At = (usize, usize);

/// Places every zone it can in the frame of zone `anchor`.
pub fn join_zones(zones: &[ZoneInput], anchor: usize, p: &ZoneParams) -> ZonesResult {
    join_zones_with(zones, anchor, p, Vec::new(), false)
}

/// As [`join_zones`], with the cross pairs `earlier` joins registered on the same sensors
/// (static views of other moments, through other people) beside this join's: each link
/// averages them. A sensor pair measured k times counts as one measurement (each of its
/// edges' covariance × k): the moments share most of the walls, so they are not independent.
/// Pairs naming a zone or sensor `zones` lacks are dropped. With `again`, only the sensor
/// pairs `earlier` holds are registered anew: a join that refines the links it has, not one
/// that looks for others (at hundreds of units, most cross pairs tried register nothing).
pub fn join_zones_with(
    zones: &[ZoneInput],
    anchor: usize,
    p: &ZoneParams,
    earlier: Vec<CrossPair>,
    again: bool,
) -> ZonesResult {
    let exists = |z: usize, s: usize| zones.get(z).is_some_and(|z| s < z.sensors.len());
    let earlier: Vec<CrossPair> = earlier
        .into_iter()
        .filter(|c| exists(c.za, c.s) && exists(c.zb, c.t) && c.za != c.zb)
        .map(|c| CrossPair { used: false, ..c })
        .collect();
    let tried = if again {
        let mut those: Vec<(At, At)> = earlier.iter().map(|c| ((c.za, c.s), (c.zb, c.t))).collect();
        those.sort_unstable();
        those.dedup();
        those
    } else {
        cross_pairs(zones, p)
    };
    let mut pairs: Vec<CrossPair> = tried
        .par_iter()
        .map(|&((za, s), (zb, t))| CrossPair {
            za,
            s,
            zb,
            t,
            result: register_pair(
                &zones[za].sensors[s].model,
                &zones[zb].sensors[t].model,
                &p.register,
            ),
            used: false,
        })
        .collect();
    pairs.extend(earlier);
    link(zones, anchor, pairs, p)
}

/// The cross pairs worth registering, each once, the lower zone first.
fn cross_pairs(zones: &[ZoneInput], p: &ZoneParams) -> Vec<(At, At)> {
    let all: Vec<At> = zones
        .iter()
        .enumerate()
        .flat_map(|(z, zone)| (0..zone.sensors.len()).map(move |s| (z, s)))
        .collect();
    let mut pairs: Vec<(At, At)> = Vec::new();
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            if a.0 != b.0 {
                pairs.push((*a, *b));
            }
        }
    }
    if pairs.len() <= p.all_pairs_up_to {
        return pairs;
    }
    // A zone meets its neighbours where its sensors see past it: pairs between the sensors
    // that look outward most. (Views alike in kind rank poorly where bays repeat.)
    let chosen: Vec<At> = zones
        .iter()
        .enumerate()
        .flat_map(|(z, zone)| {
            let share = outward(zone);
            let mut order: Vec<usize> = (0..zone.sensors.len()).collect();
            order.sort_by(|&a, &b| share[b].total_cmp(&share[a]).then(a.cmp(&b)));
            order.truncate(p.outward);
            order.into_iter().map(move |s| (z, s))
        })
        .collect();
    pairs.retain(|(a, b)| chosen.contains(a) && chosen.contains(b));
    pairs
}

/// Each sensor's share of its view that no other sensor of its zone sees (0.5 m cells in the
/// zone's frame): high for a sensor that looks past its zone, towards the zones beside it.
pub fn outward(zone: &ZoneInput) -> Vec<f64> {
    const CELL_M: f64 = 0.5;
    let cells: Vec<std::collections::HashSet<(i64, i64)>> = zone
        .sensors
        .iter()
        .map(|s| {
            s.model
                .points()
                .iter()
                .map(|p| {
                    let q = s.zone_from_sensor * p;
                    ((q.x / CELL_M).floor() as i64, (q.y / CELL_M).floor() as i64)
                })
                .collect()
        })
        .collect();
    let mut seen_by: std::collections::HashMap<(i64, i64), usize> =
        std::collections::HashMap::new();
    for c in cells.iter().flatten() {
        *seen_by.entry(*c).or_insert(0) += 1;
    }
    cells
        .iter()
        .map(|mine| {
            let alone = mine.iter().filter(|c| seen_by.get(c) == Some(&1)).count();
            alone as f64 / mine.len().max(1) as f64
        })
        .collect()
}

/// The (x, y, yaw) of a pose.
fn params(p: &Pose2) -> [f64; 3] {
    [p.translation.x, p.translation.y, p.rotation.angle()]
}

/// Covariance of `f(x)` for `x` with covariance `cov`, by a numeric Jacobian.
fn propagate(x: &Pose2, cov: &Matrix3<f64>, f: impl Fn(&Pose2) -> Pose2) -> Matrix3<f64> {
    let base = params(&f(x));
    let xp = params(x);
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let eps = 1e-6;
        let mut moved = xp;
        moved[k] += eps;
        let out = params(&f(&pose2(moved[0], moved[1], moved[2])));
        for m in 0..3 {
            let d = if m == 2 {
                wrap_angle_rad(out[m] - base[m])
            } else {
                out[m] - base[m]
            };
            j[(m, k)] = d / eps;
        }
    }
    j * cov * j.transpose()
}

fn diag(sigma: &[f64; 3]) -> Matrix3<f64> {
    Matrix3::from_diagonal(&nalgebra::Vector3::new(
        sigma[0] * sigma[0],
        sigma[1] * sigma[1],
        sigma[2] * sigma[2],
    ))
}

/// What one registered cross pair says of zone `zb` in zone `za`'s frame.
fn zone_edge(zones: &[ZoneInput], c: &CrossPair) -> Edge {
    let s = &zones[c.za].sensors[c.s];
    let t = &zones[c.zb].sensors[c.t];
    let (za_s, s_t, zb_t) = (s.zone_from_sensor, c.result.a_from_b, t.zone_from_sensor);
    let a_from_b = za_s * s_t * zb_t.inverse();
    let covariance = propagate(&s_t, &c.result.covariance, |x| za_s * x * zb_t.inverse())
        + propagate(&za_s, &diag(&s.sigma), |x| x * s_t * zb_t.inverse())
        + propagate(&zb_t, &diag(&t.sigma), |x| za_s * s_t * x.inverse());
    Edge {
        a: c.za,
        b: c.zb,
        a_from_b,
        covariance,
        strength: c.result.overlap * c.result.match_score,
    }
}

/// [`WholeView`] of zones `za` and `zb` with `zb` at `a_from_b`. Sensor pairs farther apart
/// than both their farthest returns cannot meet and are skipped.
fn whole_view(
    zones: &[ZoneInput],
    za: usize,
    zb: usize,
    a_from_b: &Pose2,
    p: &RegisterParams,
) -> WholeView {
    let (a, b) = (&zones[za].sensors, &zones[zb].sensors);
    let reach_b: Vec<f64> = b.iter().map(|t| t.model.reach_m()).collect();
    a.par_iter()
        .map(|s| {
            let reach_s = s.model.reach_m();
            let mut sum = WholeView::default();
            for (t, reach_t) in b.iter().zip(&reach_b) {
                let s_from_t = s.zone_from_sensor.inverse() * a_from_b * t.zone_from_sensor;
                if s_from_t.translation.vector.norm() > reach_s + reach_t {
                    continue;
                }
                sum.add(&score(&s.model, &t.model, &s_from_t, p), &s.model, &t.model);
            }
            sum
        })
        .reduce(WholeView::default, WholeView::merged)
}

/// The link between two zones from their registered cross pairs (`edges[k]` from `pairs[k]`):
/// the indices of the largest agreeing set whose pose `bears_out` (the zones' whole views at
/// it), or why there is none. Sets are tried largest first until two bear out: a rival half
/// as large as the best leaves the zones unlinked. (On a concourse whose bays look alike, lone
/// pairs between zones 200 m apart registered, each a set of its own without a rival, and
/// turned half the site round; at their poses 31–87 % of the points where the two zones' views
/// meet contradicted the other's view, at the true links 3–6 %.)
fn agreeing(
    edges: &[&Edge],
    sp: &SiteParams,
    bears_out: impl Fn(&Edge) -> Result<(), String>,
) -> Result<Vec<usize>, String> {
    let agrees = |x: &Edge, y: &Edge| {
        let (dt, dyaw) = pose_error(&x.a_from_b, &y.a_from_b);
        dt <= sp.cycle_m && dyaw <= sp.cycle_rad
    };
    let strength = |c: &[usize]| c.iter().map(|&m| edges[m].strength).sum::<f64>();
    let largest = |among: &[usize]| -> Vec<usize> {
        among
            .iter()
            .map(|&k| {
                among
                    .iter()
                    .copied()
                    .filter(|&m| agrees(edges[k], edges[m]))
                    .collect::<Vec<usize>>()
            })
            .max_by(|x, y| {
                x.len()
                    .cmp(&y.len())
                    .then(strength(x).total_cmp(&strength(y)))
            })
            .unwrap_or_default()
    };
    let at = |c: &[usize]| {
        let e = edges[c[0]];
        format!(
            "{} at ({:.2}, {:.2}) m, {:.1}°",
            c.len(),
            e.a_from_b.translation.x,
            e.a_from_b.translation.y,
            e.a_from_b.rotation.angle().to_degrees()
        )
    };
    let mut left: Vec<usize> = (0..edges.len()).collect();
    let mut borne: Vec<Vec<usize>> = Vec::new();
    let mut refuted: Vec<String> = Vec::new();
    while borne.len() < 2 && !left.is_empty() {
        let mut set = largest(&left);
        left.retain(|k| !set.contains(k));
        // The strongest first: its pose stands for the set's.
        set.sort_by(|&x, &y| edges[y].strength.total_cmp(&edges[x].strength));
        match bears_out(edges[set[0]]) {
            Ok(()) => borne.push(set),
            Err(why) => refuted.push(format!("{} ({why})", at(&set))),
        }
    }
    match borne.as_slice() {
        [] => Err(format!(
            "their sensor pairs place it only where the two zones' whole views contradict each other: {}",
            refuted.join(", ")
        )),
        [best] => Ok(best.clone()),
        [best, rival] if 2 * rival.len() >= best.len() => Err(format!(
            "their sensor pairs disagree: {} against {}",
            at(best),
            at(rival)
        )),
        [best, ..] => Ok(best.clone()),
    }
}

/// Each surveyed unit's survey as a prior on its zone: the unit where the zone puts it, with
/// the survey's σ and the unit's own in its zone added (the larger of its x and y).
fn zone_priors(zones: &[ZoneInput]) -> Vec<(usize, Prior)> {
    let mut priors = Vec::new();
    for (z, zone) in zones.iter().enumerate() {
        for s in &zone.sensors {
            let Some(survey) = s.surveyed else { continue };
            let within = s.sigma[0].max(s.sigma[1]);
            priors.push((
                z,
                Prior {
                    sigma_xy_m: survey.sigma_xy_m.hypot(within),
                    sigma_yaw_rad: survey.sigma_yaw_rad.hypot(s.sigma[2]),
                    node_from_sensor: s.zone_from_sensor,
                    ..survey
                },
            ));
        }
    }
    priors
}

/// Links the zones from their registered cross pairs and solves where each stands.
fn link(
    zones: &[ZoneInput],
    anchor: usize,
    mut pairs: Vec<CrossPair>,
    p: &ZoneParams,
) -> ZonesResult {
    let sp = &p.site;
    let n = zones.len();
    let mut edges: Vec<Edge> = Vec::new();
    let mut from_pair: Vec<usize> = Vec::new();
    let mut why_not: Vec<Vec<String>> = vec![Vec::new(); n];
    for za in 0..n {
        for zb in za + 1..n {
            let between: Vec<usize> = (0..pairs.len())
                .filter(|&k| {
                    let c = &pairs[k];
                    c.za == za && c.zb == zb && c.result.registered()
                })
                .collect();
            if between.is_empty() {
                continue;
            }
            let sensors = |k: usize| (pairs[k].s, pairs[k].t);
            let found: Vec<Edge> = between
                .iter()
                .map(|&k| {
                    let mut e = zone_edge(zones, &pairs[k]);
                    let times = between
                        .iter()
                        .filter(|&&m| sensors(m) == sensors(k))
                        .count();
                    e.covariance *= times as f64;
                    e
                })
                .collect();
            let bears_out = |e: &Edge| {
                let whole = whole_view(zones, za, zb, &e.a_from_b, &p.register);
                if whole.violation() <= sp.whole_view_violation {
                    Ok(())
                } else {
                    Err(format!(
                        "{:.0} % of the points where their views meet land in the other's free space",
                        100.0 * whole.violation()
                    ))
                }
            };
            match agreeing(&found.iter().collect::<Vec<_>>(), sp, bears_out) {
                Ok(kept) => {
                    // Strongest first (as `agreeing` gives them): the cycle check takes the
                    // first edge of each pair.
                    for k in kept {
                        edges.push(found[k].clone());
                        from_pair.push(between[k]);
                    }
                }
                Err(why) => {
                    let line = |other: usize| format!("with zone {}, {why}", zones[other].id);
                    why_not[za].push(line(zb));
                    why_not[zb].push(line(za));
                }
            }
        }
    }
    let kept = consistent_edges(n, anchor, &edges, sp);
    let used: Vec<Edge> = kept.iter().map(|&k| edges[k].clone()).collect();
    for &k in &kept {
        pairs[from_pair[k]].used = true;
    }
    let priors = zone_priors(zones);
    let solved = solve(n, anchor, &used, &priors, sp);
    let tried = |z: usize| pairs.iter().filter(|c| c.za == z || c.zb == z).count();
    let zones_out = (0..n)
        .map(|z| {
            let rests_on = used.iter().filter(|e| e.a == z || e.b == z).count();
            let site_from_zone = match solved.get(z).copied().flatten() {
                Some(found) => Ok(found),
                None if !why_not[z].is_empty() => Err(why_not[z].join("; ")),
                None if rests_on > 0 => Err(format!(
                    "it is linked to other zones, but no chain of them reaches zone {}",
                    zones[anchor].id
                )),
                None => Err(format!(
                    "none of its {} sensor(s) registered with a sensor of another zone ({} pairs tried); its sensors must share a view with another zone's",
                    zones[z].sensors.len(),
                    tried(z)
                )),
            };
            ZonePlacement {
                id: zones[z].id.clone(),
                site_from_zone,
                pairs: if z == anchor { 0 } else { rests_on },
            }
        })
        .collect();
    ZonesResult {
        anchor,
        zones: zones_out,
        pairs,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::raycast::{Wall, polygon};
    use crate::register::site::tests::sensor_at;

    /// An L-shaped hall with a pillar, scanned by six sensors in three zones of two. Each zone's
    /// frame is its first sensor's; the anchor zone's is the site's.
    fn hall() -> (Vec<Wall>, Vec<(usize, Pose2)>) {
        let mut walls = polygon(&[
            (0.0, 0.0),
            (24.0, 0.0),
            (24.0, 8.0),
            (14.0, 8.0),
            (14.0, 18.0),
            (0.0, 18.0),
        ]);
        walls.extend(polygon(&[(5.0, 5.0), (6.0, 5.0), (6.0, 6.5), (5.0, 6.5)]));
        walls.extend(polygon(&[
            (18.0, 3.0),
            (19.5, 3.0),
            (19.5, 4.0),
            (18.0, 4.0),
        ]));
        walls.extend(polygon(&[
            (7.0, 12.0),
            (9.0, 12.0),
            (9.0, 12.6),
            (7.0, 12.6),
        ]));
        let sensors = vec![
            (0, pose2(2.0, 2.0, 0.4)),
            (0, pose2(10.0, 3.0, 1.9)),
            (1, pose2(20.0, 6.5, -2.6)),
            (1, pose2(15.0, 1.5, 2.2)),
            (2, pose2(3.0, 15.0, -0.8)),
            (2, pose2(11.0, 10.0, 2.6)),
        ];
        (walls, sensors)
    }

    fn zones_of(walls: &[Wall], sensors: &[(usize, Pose2)]) -> Vec<ZoneInput> {
        let fov = 270f64.to_radians();
        let mut zones: Vec<ZoneInput> = (0..3)
            .map(|z| ZoneInput {
                id: ["west", "east", "north"][z].to_string(),
                sensors: Vec::new(),
            })
            .collect();
        for (k, &(z, site_from_sensor)) in sensors.iter().enumerate() {
            let first = sensors.iter().find(|(zz, _)| *zz == z).map(|(_, p)| *p);
            let zone_from_sensor = first.unwrap_or(site_from_sensor).inverse() * site_from_sensor;
            let id = format!("s{k}");
            zones[z].sensors.push(ZoneSensor {
                model: sensor_at(walls, site_from_sensor, fov, &id).model,
                id,
                zone_from_sensor,
                sigma: [0.01, 0.01, 0.002],
                surveyed: None,
            });
        }
        zones
    }

    /// A unit surveyed in the site frame holds its zone: tight, it pulls the zone most of the
    /// way to where the survey puts the unit (here 10 cm from where the pairs put it); loose,
    /// it hardly moves it; and a zone no pair links is placed by its survey alone, with its σ.
    #[test]
    fn a_surveyed_unit_holds_its_zone_by_its_sigma() {
        let (walls, sensors) = hall();
        let p = ZoneParams::default();
        let site_from_west = sensors[0].1;
        // North's second unit (s5), surveyed 10 cm off its truth along the site's y.
        let truth_s5 = site_from_west.inverse() * sensors[5].1;
        let off = pose2(0.0, 0.10, 0.0) * truth_s5;
        let north_with = |sigma_m: f64| {
            let mut zones = zones_of(&walls, &sensors);
            zones[2].sensors[1].surveyed = Some(Prior::new(off, sigma_m, 0.2f64.to_radians()));
            let got = join_zones(&zones, 0, &p);
            let (pose, sigma) = got.zones[2].site_from_zone.clone().expect("north placed");
            ((pose * zones[2].sensors[1].zone_from_sensor), sigma)
        };
        let moved = |at: &Pose2| pose_error(at, &truth_s5).0;
        // 1 mm, plus the unit's own 1 cm in its zone, against the links' few cm: most of
        // the way to the survey.
        let (tight, _) = north_with(0.001);
        assert!(
            moved(&tight) > 0.05 && moved(&tight) < 0.101,
            "a tight survey: s5 {:.3} m from its truth",
            moved(&tight)
        );
        let (loose, _) = north_with(10.0);
        assert!(moved(&loose) < 0.03, "{:.3} m", moved(&loose));
        // North's units see nothing of another zone's: only their survey places them.
        let mut zones = zones_of(&walls, &sensors);
        for s in &mut zones[2].sensors {
            s.model = crate::register::site::tests::sensor_at(
                &[],
                Pose2::identity(),
                270f64.to_radians(),
                &s.id,
            )
            .model;
        }
        zones[2].sensors[1].surveyed = Some(Prior::new(truth_s5, 0.02, 0.005));
        let got = join_zones(&zones, 0, &p);
        let (pose, sigma) = got.zones[2]
            .site_from_zone
            .clone()
            .unwrap_or_else(|why| panic!("north unplaced: {why}"));
        let at = pose * zones[2].sensors[1].zone_from_sensor;
        assert!(moved(&at) < 1e-6, "{:.3} m", moved(&at));
        assert_eq!(got.zones[2].pairs, 0);
        assert!(sigma[0] > 0.01 && sigma[0] < 0.2, "{sigma:?}");
    }

    #[test]
    fn zones_that_share_views_are_placed_where_their_first_sensors_stand() {
        let (walls, sensors) = hall();
        let zones = zones_of(&walls, &sensors);
        let got = join_zones(&zones, 0, &ZoneParams::default());
        let site_from_west = sensors[0].1;
        for (z, first) in [(1, 2), (2, 4)] {
            let truth = site_from_west.inverse() * sensors[first].1;
            let placement = &got.zones[z];
            let (pose, sigma) = placement
                .site_from_zone
                .as_ref()
                .unwrap_or_else(|why| panic!("zone {} unplaced: {why}", placement.id));
            let (dt, dyaw) = pose_error(pose, &truth);
            assert!(
                dt < 0.05 && dyaw < 0.5f64.to_radians(),
                "zone {}: {dt:.3} m, {:.2}° off",
                placement.id,
                dyaw.to_degrees()
            );
            assert!(sigma.iter().all(|s| *s > 0.0 && *s < 0.1), "{sigma:?}");
            assert!(placement.pairs >= 1);
        }
        assert_eq!(
            got.zones[0].site_from_zone.as_ref().ok().map(|p| p.0),
            Some(Pose2::identity())
        );
    }

    /// Earlier joins' pairs (other moments' views) are averaged with this join's: pairs that
    /// put east 3 cm to one side, beside this join's, move the link half way, and σ does not
    /// shrink as for independent measurements (by √2) from counting each sensor pair twice.
    #[test]
    fn earlier_joins_pairs_are_averaged_in_and_a_pair_counted_twice_is_one_measurement() {
        let (walls, sensors) = hall();
        let zones = zones_of(&walls, &sensors);
        let p = ZoneParams::default();
        let now = join_zones(&zones, 0, &p);
        let east = |r: &ZonesResult| r.zones[1].site_from_zone.clone().expect("east placed");
        let (at_now, sigma_now) = east(&now);
        // The same registrations, each pair's pose 3 cm off along its A's x.
        let shifted: Vec<CrossPair> = now
            .pairs
            .iter()
            .filter(|c| c.result.registered())
            .map(|c| {
                let mut c = c.clone();
                c.result.a_from_b = pose2(0.03, 0.0, 0.0) * c.result.a_from_b;
                c
            })
            .collect();
        let alone = link(&zones, 0, shifted.clone(), &p);
        let (at_shifted, _) = east(&alone);
        let both = join_zones_with(&zones, 0, &p, shifted.clone(), false);
        let again = join_zones_with(&zones, 0, &p, shifted.clone(), true);
        assert_eq!(
            again.pairs.len(),
            2 * shifted.len(),
            "a join again registers only the pairs it had"
        );
        let (at_both, sigma_both) = east(&both);
        let (dt, dyaw) = pose_error(&east(&again).0, &at_both);
        assert!(dt < 1e-6 && dyaw < 1e-9, "{dt} m, {dyaw} rad");
        let (apart, _) = pose_error(&at_now, &at_shifted);
        assert!(apart > 0.02, "the shift moved east {apart:.3} m");
        let (to_now, _) = pose_error(&at_both, &at_now);
        let (to_shifted, _) = pose_error(&at_both, &at_shifted);
        assert!(
            (to_now - apart / 2.0).abs() < 0.005 && (to_shifted - apart / 2.0).abs() < 0.005,
            "averaged: {to_now:.4} m from this join's, {to_shifted:.4} m from the earlier ({apart:.4} apart)"
        );
        for k in 0..3 {
            assert!(
                sigma_both[k] > 0.85 * sigma_now[k],
                "σ {sigma_both:?} against {sigma_now:?}"
            );
        }
        assert!(
            both.pairs.iter().filter(|c| c.used).count()
                > now.pairs.iter().filter(|c| c.used).count()
        );
    }

    #[test]
    fn beyond_the_limit_only_the_sensors_that_look_past_their_zone_are_paired() {
        let (walls, sensors) = hall();
        let zones = zones_of(&walls, &sensors);
        for zone in &zones {
            let share = outward(zone);
            assert!(share.iter().all(|s| (0.0..=1.0).contains(s)), "{share:?}");
        }
        let all = cross_pairs(&zones, &ZoneParams::default());
        assert_eq!(all.len(), 12, "3 zones of 2: every cross pair");
        let one_each = ZoneParams {
            all_pairs_up_to: 0,
            outward: 1,
            ..ZoneParams::default()
        };
        let few = cross_pairs(&zones, &one_each);
        assert_eq!(
            few.len(),
            3,
            "one sensor of each zone, paired across: {few:?}"
        );
        for (z, zone) in zones.iter().enumerate() {
            let share = outward(zone);
            let most = if share[0] >= share[1] { 0 } else { 1 };
            assert!(
                few.iter()
                    .all(|(a, b)| (a.0 != z || a.1 == most) && (b.0 != z || b.1 == most)),
                "zone {z}: {share:?} {few:?}"
            );
        }
    }

    /// The hall, with north's sensors moved into a room of their own, far off and closed.
    fn north_apart() -> Vec<ZoneInput> {
        let (walls, sensors) = two_rooms();
        zones_of(&walls, &sensors)
    }

    /// The hall and a closed room far off, sharing no view; the last two sensors in the room.
    pub(crate) fn two_rooms() -> (Vec<Wall>, Vec<(usize, Pose2)>) {
        let (mut walls, mut sensors) = hall();
        walls.extend(polygon(&[
            (100.0, 0.0),
            (107.0, 0.0),
            (107.0, 5.0),
            (100.0, 5.0),
        ]));
        sensors[4].1 = pose2(101.0, 1.0, 0.3);
        sensors[5].1 = pose2(106.0, 4.0, -2.5);
        (walls, sensors)
    }

    #[test]
    fn a_zone_that_shares_no_view_stays_unplaced_and_says_why() {
        let zones = north_apart();
        let got = join_zones(&zones, 0, &ZoneParams::default());
        assert!(got.zones[1].site_from_zone.is_ok());
        let why = got.zones[2].site_from_zone.as_ref().unwrap_err();
        assert!(why.contains("share a view"), "{why}");
    }

    #[test]
    fn cross_pairs_that_disagree_link_nothing() {
        let (walls, sensors) = hall();
        let zones = zones_of(&walls, &sensors);
        let good = join_zones(&zones, 0, &ZoneParams::default());
        // The same pairs, with every second registered pair between west and east turned by
        // 90°: two sets of equal standing.
        let mut pairs = good.pairs.clone();
        let mut flip = false;
        for c in pairs
            .iter_mut()
            .filter(|c| c.za == 0 && c.zb == 1 && c.result.registered())
        {
            if flip {
                c.result.a_from_b = pose2(3.0, -4.0, 1.57) * c.result.a_from_b;
            }
            flip = !flip;
        }
        let between = pairs
            .iter()
            .filter(|c| c.za == 0 && c.zb == 1 && c.result.registered())
            .count();
        assert!(
            between >= 2,
            "west and east share {between} registered pairs"
        );
        let got = link(&zones, 0, pairs, &ZoneParams::default());
        let east = &got.zones[1].site_from_zone;
        // East may still be placed through north (a chain that does agree), but never at
        // the rival's pose.
        if let Ok((pose, _)) = east {
            let truth = sensors[0].1.inverse() * sensors[2].1;
            assert!(pose_error(pose, &truth).0 < 0.05);
        } else {
            assert!(east.as_ref().unwrap_err().contains("disagree"), "{east:?}");
        }
    }

    /// A lone cross pair registered at a look-alike pose (zones that share no view: on a
    /// concourse whose bays repeat, such pairs turned half the site round) has no rival, but
    /// the two zones' whole views at its pose contradict each other: it links nothing. Before
    /// the check, north was placed where the pair put it.
    #[test]
    fn a_lone_look_alike_pair_the_whole_views_contradict_links_nothing() {
        let zones = north_apart();
        let p = ZoneParams::default();
        let good = join_zones(&zones, 0, &p);
        let mut look_alike = good
            .pairs
            .iter()
            .find(|c| c.za == 0 && c.zb == 1 && c.used)
            .expect("west and east linked")
            .clone();
        // West's s1 against north's s4, turned half round in the middle of the hall.
        (look_alike.s, look_alike.zb, look_alike.t) = (1, 2, 0);
        look_alike.result.a_from_b = pose2(1.0, -2.0, 3.1);
        let mut pairs = good.pairs.clone();
        pairs.push(look_alike);
        let got = link(&zones, 0, pairs.clone(), &p);
        let why = got.zones[2].site_from_zone.as_ref().unwrap_err();
        assert!(why.contains("whole views contradict"), "{why}");
        assert!(got.zones[1].site_from_zone.is_ok(), "{:?}", got.zones[1]);
        // Without the whole views, the pair alone would have placed it: what the check is for.
        let off = ZoneParams {
            site: SiteParams {
                whole_view_violation: 1.0,
                ..SiteParams::default()
            },
            ..ZoneParams::default()
        };
        let unchecked = link(&zones, 0, pairs, &off);
        assert!(unchecked.zones[2].site_from_zone.is_ok());
    }
}
