//! The tracker on a simulated scene, scored against the simulator's truth (`/truth/people`)
//! with CLEAR-MOT: what `scanfuse eval --only tracking` tabulates and the end-to-end tests
//! assert on. Everything in memory; same plan and seed, same figures.

use std::collections::BTreeMap;

use super::mot::ClearMot;
use super::{SensorScan, TrackParams, Tracker};
use crate::daemon::protocol::Tracks;
use crate::features::persistent_view;
use crate::geometry::{Mount, Pose2, pose2};
use crate::scan::Scan;
use crate::sim::{Plan, PlanError, SimEvent, Simulation};

/// How a scene is run and scored.
#[derive(Debug, Clone)]
pub struct ScoreOptions {
    pub seed: u64,
    /// Simulated span (s).
    pub seconds: f64,
    /// The first seconds' scans seed each sensor's background (as `scanfuse track` seeds it
    /// from a recording's persistent view); 0 starts from the first scan.
    pub seed_s: f64,
    /// Seed from the plan without its people (a site whose background was learnt while
    /// empty) rather than from the scene's own first `seed_s`.
    pub seed_empty: bool,
    /// Truth frames before this time (s) are not scored.
    pub warmup_s: f64,
    /// CLEAR-MOT's match radius (m).
    pub radius_m: f64,
    /// Sensor poses to track with (site frame, by id); absent ones use the truth.
    pub poses: BTreeMap<String, Pose2>,
    /// This sensor stops sending at this time (s): a unit unplugged mid-run.
    pub drop_sensor: Option<(String, f64)>,
}

impl Default for ScoreOptions {
    fn default() -> Self {
        ScoreOptions {
            seed: 1,
            seconds: 30.0,
            seed_s: 1.0,
            seed_empty: true,
            warmup_s: 1.0,
            radius_m: 0.5,
            poses: BTreeMap::new(),
            drop_sensor: None,
        }
    }
}

/// The figures of one run.
#[derive(Debug, Clone, Default)]
pub struct SceneScore {
    pub mot: ClearMot,
    /// Σ people × time scored (min).
    pub person_minutes: f64,
    /// Fused steps the tracker made, and the most confirmed tracks at once.
    pub steps: usize,
    pub most_tracks: usize,
    /// Distinct track ids output.
    pub ids: usize,
}

/// The floor the truth is scored on: inside the plan's closed walls (its bounding box when it
/// has none), at least `inset_m` from them, not within `sensor_clear_m` of a sensor used (below
/// its minimum range, or behind it against the wall), and within `range_m` of one. People
/// outside the hall (arriving 1 m outside a door, or in a recess behind the scanners) and
/// tracks there are not counted.
#[derive(Debug, Clone)]
struct Floor {
    outlines: Vec<Vec<[f64; 2]>>,
    min: [f64; 2],
    max: [f64; 2],
    inset_m: f64,
    sensors: Vec<[f64; 2]>,
    sensor_clear_m: f64,
    range_m: f64,
}

fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

impl Floor {
    fn of(plan: &Plan, inset_m: f64, range_m: f64) -> Floor {
        let mut min = [f64::INFINITY; 2];
        let mut max = [f64::NEG_INFINITY; 2];
        for w in &plan.walls {
            for (a, b) in w.segments() {
                for p in [a, b] {
                    for k in 0..2 {
                        min[k] = min[k].min(p[k]);
                        max[k] = max[k].max(p[k]);
                    }
                }
            }
        }
        Floor {
            outlines: plan
                .walls
                .iter()
                .filter(|w| w.closed && w.points.len() >= 3)
                .map(|w| w.points.clone())
                .collect(),
            min,
            max,
            inset_m,
            sensors: plan.sensors.iter().map(|s| [s.x, s.y]).collect(),
            sensor_clear_m: 0.5,
            range_m,
        }
    }

    fn contains(&self, x: f64, y: f64) -> bool {
        let p = [x, y];
        let inside = if self.outlines.is_empty() {
            (self.min[0] + self.inset_m..=self.max[0] - self.inset_m).contains(&x)
                && (self.min[1] + self.inset_m..=self.max[1] - self.inset_m).contains(&y)
        } else {
            self.outlines.iter().any(|o| {
                let n = o.len();
                let mut inside = false;
                for i in 0..n {
                    let (a, b) = (o[i], o[(i + 1) % n]);
                    if (a[1] > y) != (b[1] > y)
                        && x < a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
                    {
                        inside = !inside;
                    }
                }
                inside && (0..n).all(|i| segment_distance(p, o[i], o[(i + 1) % n]) >= self.inset_m)
            })
        };
        let dist = |s: &[f64; 2]| (s[0] - x).hypot(s[1] - y);
        inside
            && self.sensors.iter().all(|s| dist(s) >= self.sensor_clear_m)
            && self.sensors.iter().any(|s| dist(s) <= self.range_m)
    }
}

/// Runs `plan` (its sensors as given: drop some beforehand to use fewer) through a tracker
/// and scores it against the truth.
pub fn score_plan(
    plan: &Plan,
    params: &TrackParams,
    o: &ScoreOptions,
) -> Result<SceneScore, PlanError> {
    let floor = Floor::of(plan, 0.25, params.max_range_m);
    let mut sim = Simulation::new(plan, o.seed)?;
    let infos = sim.sensors().to_vec();
    let start_ns = sim.start_ns();
    let mounts: Vec<Mount> = infos
        .iter()
        .map(|i| Mount {
            height_m: i.height_m,
            pitch_rad: i.pitch_deg.unwrap_or(0.0).to_radians(),
        })
        .collect();
    let poses: Vec<Option<Pose2>> = infos
        .iter()
        .map(|i| {
            o.poses
                .get(&i.id)
                .copied()
                .or_else(|| i.truth.map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())))
        })
        .collect();
    let mut tracker = Tracker::new(params.clone());
    if o.seed_s > 0.0 {
        // The background as learnt before the people came in: the plan without its people
        // (a site set up while empty), or the scene's own first seconds.
        let mut empty = plan.clone();
        if o.seed_empty {
            empty.people.clear();
            empty.crowds.clear();
            empty.queues.clear();
            empty.truth_people = Some(false);
        }
        let mut seeder = Simulation::new(&empty, o.seed)?;
        let mut scans: Vec<Vec<Scan>> = vec![Vec::new(); infos.len()];
        let _ = seeder.run(o.seed_s.min(o.seconds), |i, scan| {
            if let Some(v) = scans.get_mut(i) {
                v.push(scan);
            }
            Ok::<(), ()>(())
        });
        for (i, info) in infos.iter().enumerate() {
            if let Some(view) = persistent_view(&scans[i], o.seed_s, 0.15, 0.05) {
                let ranges =
                    Tracker::horizontal_ranges(&view, info.geometry.as_ref(), &mounts[i], params);
                tracker.seed_background(&info.id, ranges);
            }
        }
    }
    let mut score = SceneScore {
        mot: ClearMot::new(o.radius_m),
        ..SceneScore::default()
    };
    let mut latest: Option<Tracks> = None;
    let mut ids = std::collections::BTreeSet::new();
    let drop = o
        .drop_sensor
        .as_ref()
        .map(|(id, at_s)| (id.clone(), start_ns + (at_s * 1e9) as u64));
    let warmup_ns = start_ns + (o.warmup_s * 1e9) as u64;
    let _ = sim.run_with_truth(o.seconds, |event| {
        match event {
            SimEvent::Scan(i, scan) => {
                let (Some(info), Some(mount)) = (infos.get(i), mounts.get(i)) else {
                    return Ok(());
                };
                if let Some((id, at_ns)) = &drop
                    && *id == info.id
                    && scan.stamp_ns >= *at_ns
                {
                    return Ok(());
                }
                let out = tracker.push(SensorScan {
                    id: &info.id,
                    scan: &scan,
                    geometry: info.geometry.as_ref(),
                    mount: *mount,
                    site_from_sensor: poses.get(i).copied().flatten(),
                });
                if let Some(out) = out {
                    score.steps += 1;
                    score.most_tracks = score.most_tracks.max(out.tracks.len());
                    ids.extend(out.tracks.iter().map(|t| t.id));
                    latest = Some(out);
                }
            }
            SimEvent::People(truth) => {
                if truth.t_ns < warmup_ns {
                    return Ok(());
                }
                let people: Vec<(String, f64, f64)> = truth
                    .people
                    .iter()
                    .filter(|p| floor.contains(p.x_m, p.y_m))
                    .map(|p| (p.id.clone(), p.x_m, p.y_m))
                    .collect();
                // The tracks as of the truth's instant, carried to it along their velocity.
                let tracks: Vec<(u64, f64, f64)> = latest
                    .as_ref()
                    .map(|l| {
                        let dt = truth.t_ns as f64 * 1e-9 - l.t_ns as f64 * 1e-9;
                        l.tracks
                            .iter()
                            .map(|t| (t.id, t.x_m + t.vx_m_s * dt, t.y_m + t.vy_m_s * dt))
                            .filter(|(_, x, y)| floor.contains(*x, *y))
                            // A track of someone off the scored floor (in a doorway, behind a
                            // sensor at the wall) is neither right nor false: not scored.
                            .filter(|(_, x, y)| {
                                let nearest = truth.people.iter().min_by(|a, b| {
                                    (a.x_m - x)
                                        .hypot(a.y_m - y)
                                        .total_cmp(&(b.x_m - x).hypot(b.y_m - y))
                                });
                                nearest.is_none_or(|p| {
                                    floor.contains(p.x_m, p.y_m)
                                        || (p.x_m - x).hypot(p.y_m - y) > o.radius_m
                                })
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                score.person_minutes +=
                    people.len() as f64 * crate::sim::PEOPLE_TRUTH_PERIOD_NS as f64 * 1e-9 / 60.0;
                let before = (score.mot.misses, score.mot.false_tracks);
                score.mot.frame(&people, &tracks);
                if tracing::enabled!(tracing::Level::TRACE) {
                    tracing::trace!(
                        "t {:.1} truth {} tracks {} miss +{} false +{} live {}",
                        (truth.t_ns - start_ns) as f64 * 1e-9,
                        people.len(),
                        tracks.len(),
                        score.mot.misses - before.0,
                        score.mot.false_tracks - before.1,
                        tracker.live_tracks()
                    );
                    for (id, x, y) in &people {
                        let d = tracks
                            .iter()
                            .map(|(_, tx, ty)| (tx - x).hypot(ty - y))
                            .fold(f64::INFINITY, f64::min);
                        if d > 0.5 {
                            tracing::trace!("   miss {id} at {x:.2},{y:.2} nearest {d:.2}");
                        }
                    }
                    for (id, x, y) in &tracks {
                        let (d, who) = truth
                            .people
                            .iter()
                            .map(|p| ((p.x_m - x).hypot(p.y_m - y), p.id.clone()))
                            .fold((f64::INFINITY, String::new()), |a, b| {
                                if b.0 < a.0 { b } else { a }
                            });
                        if d > 0.5 {
                            tracing::trace!("   false {id} at {x:.2},{y:.2} nearest {who} {d:.2}");
                        }
                    }
                }
            }
        }
        Ok::<(), ()>(())
    });
    score.ids = ids.len();
    Ok(score)
}

/// `plan` with only its first `n` sensors, and its crowds' sizes set to `people` (cap and
/// people inside at the start), when given.
pub fn variant(plan: &Plan, n_sensors: Option<usize>, people: Option<u32>) -> Plan {
    let mut p = plan.clone();
    if let Some(n) = n_sensors {
        p.sensors.truncate(n.max(1));
    }
    if let Some(people) = people {
        for c in &mut p.crowds {
            c.people = people;
            c.max_people = Some(people);
        }
    }
    p
}
