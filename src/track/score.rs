//! The tracker on a simulated scene, scored against the simulator's truth (`/truth/people`)
//! with CLEAR-MOT: what `scanfuse eval --only tracking` tabulates and the end-to-end tests
//! assert on. Everything in memory; same plan and seed, same figures.
//!
//! With counting lines and zones in the options (see [`counting_layout`]), the same run also
//! counts line crossings and zone occupancy from the tracks with [`zones`](super::zones) and
//! from the truth, and scores the difference.

use std::collections::BTreeMap;

use super::mot::ClearMot;
use super::zones::{CountLine, Counter, DEFAULT_HYSTERESIS_M, Xy, Zone, inside};
use super::{SensorScan, TrackParams, Tracker};
use crate::daemon::protocol::{Message, Side, Track, Tracks};
use crate::features::persistent_view;
use crate::geometry::{Mount, Pose2, pose2};
use crate::scan::Scan;
use crate::sim::{Plan, PlanError, Sightlines, SimEvent, Simulation};

/// How far short of a person a sight line may end and still see them: a body's half-width.
const BODY_M: f64 = 0.3;

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
    /// Sensors not placed (registration left them out): they feed the tracker nothing, and
    /// the people only they see are missed.
    pub unplaced: std::collections::BTreeSet<String>,
    /// This sensor stops sending at this time (s): a unit unplugged mid-run.
    pub drop_sensor: Option<(String, f64)>,
    /// Counting lines: crossings (after `warmup_s`) counted from the tracks and from the truth.
    pub lines: Vec<CountLine>,
    /// Zones: occupancy from the tracks against the truth at each scored truth frame (the
    /// people and tracks CLEAR-MOT scores).
    pub zones: Vec<Zone>,
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
            unplaced: std::collections::BTreeSet::new(),
            drop_sensor: None,
            lines: Vec::new(),
            zones: Vec::new(),
        }
    }
}

/// The figures of one run.
#[derive(Debug, Clone, Default)]
pub struct SceneScore {
    pub mot: ClearMot,
    /// Σ people × time scored (min).
    pub person_minutes: f64,
    /// Σ people × time within the sensors' reach but out of their sight behind the plan's
    /// walls, shelves or pillars: not scored (min).
    pub hidden_person_minutes: f64,
    /// Fused steps the tracker made, and the most confirmed tracks at once.
    pub steps: usize,
    pub most_tracks: usize,
    /// Distinct track ids output.
    pub ids: usize,
    /// Per counting line of the options, in their order.
    pub lines: Vec<LineScore>,
    /// Per zone of the options, in their order.
    pub zones: Vec<ZoneScore>,
}

impl SceneScore {
    /// True crossings over all lines, both ways.
    pub fn line_truth(&self) -> u32 {
        self.lines.iter().map(LineScore::truth_total).sum()
    }

    /// Crossings counted from the tracks over all lines, both ways.
    pub fn line_counted(&self) -> u32 {
        self.lines.iter().map(LineScore::counted_total).sum()
    }

    /// Line-count error over all lines, % of the true crossings: each line's miscount each
    /// way, summed (a missed crossing one way does not cancel a false one the other way).
    /// NaN when nobody crossed.
    pub fn line_error_pct(&self) -> f64 {
        let wrong: u32 = self.lines.iter().map(LineScore::wrong).sum();
        let truth = self.line_truth();
        if truth == 0 {
            f64::NAN
        } else {
            100.0 * f64::from(wrong) / f64::from(truth)
        }
    }

    /// Mean absolute zone-occupancy error (people), over the zones and the scored frames;
    /// NaN without zones.
    pub fn zone_mae(&self) -> f64 {
        let frames: usize = self.zones.iter().map(|z| z.frames).sum();
        if frames == 0 {
            return f64::NAN;
        }
        self.zones.iter().map(|z| z.abs_error_sum).sum::<f64>() / frames as f64
    }

    /// Mean true occupancy of the zones (people), for scale; NaN without zones.
    pub fn zone_mean_truth(&self) -> f64 {
        let frames: usize = self.zones.iter().map(|z| z.frames).sum();
        if frames == 0 {
            return f64::NAN;
        }
        self.zones.iter().map(|z| z.truth_sum).sum::<f64>() / frames as f64
    }
}

/// One counting line's crossings, from the truth and from the tracks, `[to the left, to the
/// right]` of the line's direction.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LineScore {
    pub id: String,
    pub truth: [u32; 2],
    pub counted: [u32; 2],
}

impl LineScore {
    pub fn truth_total(&self) -> u32 {
        self.truth[0] + self.truth[1]
    }

    pub fn counted_total(&self) -> u32 {
        self.counted[0] + self.counted[1]
    }

    /// Miscounted crossings: |counted − true| each way, summed.
    pub fn wrong(&self) -> u32 {
        self.truth[0].abs_diff(self.counted[0]) + self.truth[1].abs_diff(self.counted[1])
    }
}

/// One zone's occupancy error, summed over the scored truth frames.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ZoneScore {
    pub id: String,
    pub frames: usize,
    /// Σ |people inside by the tracks − people inside by the truth|.
    pub abs_error_sum: f64,
    /// Σ people inside by the truth.
    pub truth_sum: f64,
}

/// The counting lines and zones a scene is scored on, from its plan:
/// - lines: across the entrances the crowd uses, 2 m inside each of the two widest doors,
///   parallel to the door's wall and 1 m longer than the door at each end (everyone who comes
///   in or goes out through it crosses it; left is into the hall). A plan whose crowds enter at
///   set points (`entrances`), or that has no doors, gets two lines across the middle of the
///   floor its sensors surround instead (through the centre of their bounding box, one along
///   each axis).
/// - zones: the floor just inside the widest door (0.5 to 3.5 m in, 1 m either side of it),
///   where people arrive and leave, and a 6 × 6 m square at the centre of the sensors'
///   bounding box.
pub fn counting_layout(plan: &Plan) -> (Vec<CountLine>, Vec<Zone>) {
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for s in &plan.sensors {
        lo = [lo[0].min(s.x), lo[1].min(s.y)];
        hi = [hi[0].max(s.x), hi[1].max(s.y)];
    }
    if !lo.iter().chain(&hi).all(|v| v.is_finite()) {
        return (Vec::new(), Vec::new());
    }
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    // The doors the crowd walks through, widest first, each with its wall's direction (unit)
    // and the normal into the floor (towards the centre).
    let crowd_uses_doors = !plan.crowds.is_empty()
        && plan
            .crowds
            .iter()
            .all(|c| c.entrances.is_empty() && c.exits.is_empty());
    let mut doors: Vec<(Xy, f64, Xy, Xy)> = Vec::new();
    if crowd_uses_doors {
        for d in &plan.doors {
            let nearest = plan
                .walls
                .iter()
                .flat_map(|w| w.segments())
                .filter(|(a, b)| a != b)
                .min_by(|x, y| {
                    segment_distance(d.at, x.0, x.1).total_cmp(&segment_distance(d.at, y.0, y.1))
                });
            let Some((a, b)) = nearest else { continue };
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            let u = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            let mut n = [-u[1], u[0]];
            if n[0] * (centre[0] - d.at[0]) + n[1] * (centre[1] - d.at[1]) < 0.0 {
                n = [-n[0], -n[1]];
            }
            doors.push((d.at, d.width_m, u, n));
        }
        doors.sort_by(|x, y| y.1.total_cmp(&x.1));
    }
    let mut lines = Vec::new();
    for &(at, width_m, u, n) in doors.iter().take(2) {
        let c = [at[0] + 2.0 * n[0], at[1] + 2.0 * n[1]];
        let half = width_m / 2.0 + 1.0;
        // Directed so that into the hall (along n) is to the line's left.
        let (mut from, mut to) = (
            [c[0] - half * u[0], c[1] - half * u[1]],
            [c[0] + half * u[0], c[1] + half * u[1]],
        );
        if u[0] * n[1] - u[1] * n[0] < 0.0 {
            std::mem::swap(&mut from, &mut to);
        }
        lines.push(CountLine {
            id: format!("door {},{}", at[0], at[1]),
            from,
            to,
            hysteresis_m: DEFAULT_HYSTERESIS_M,
        });
    }
    if lines.is_empty() {
        lines.push(CountLine {
            id: format!("x = {}", centre[0]),
            from: [centre[0], lo[1]],
            to: [centre[0], hi[1]],
            hysteresis_m: DEFAULT_HYSTERESIS_M,
        });
        lines.push(CountLine {
            id: format!("y = {}", centre[1]),
            from: [lo[0], centre[1]],
            to: [hi[0], centre[1]],
            hysteresis_m: DEFAULT_HYSTERESIS_M,
        });
    }
    let mut zones = Vec::new();
    if let Some(&(at, width_m, u, n)) = doors.first() {
        let half = width_m / 2.0 + 1.0;
        let p = |along: f64, inward: f64| {
            [
                at[0] + along * u[0] + inward * n[0],
                at[1] + along * u[1] + inward * n[1],
            ]
        };
        zones.push(Zone {
            id: format!("inside door {},{}", at[0], at[1]),
            polygon: vec![p(-half, 0.5), p(half, 0.5), p(half, 3.5), p(-half, 3.5)],
        });
    }
    zones.push(Zone {
        id: "middle".into(),
        polygon: vec![
            [centre[0] - 3.0, centre[1] - 3.0],
            [centre[0] + 3.0, centre[1] - 3.0],
            [centre[0] + 3.0, centre[1] + 3.0],
            [centre[0] - 3.0, centre[1] + 3.0],
        ],
    });
    (lines, zones)
}

/// Adds the crossings among `messages` (at or after `from_ns`) to the line scores: to `truth`
/// or to `counted`.
fn tally(lines: &mut [LineScore], messages: &[Message], from_ns: u64, counted: bool) {
    for m in messages {
        let Message::Crossing(c) = m else { continue };
        if c.t_ns < from_ns {
            continue;
        }
        let Some(line) = lines.iter_mut().find(|l| l.id == c.line) else {
            continue;
        };
        let k = match c.to {
            Side::Left => 0,
            Side::Right => 1,
        };
        if counted {
            line.counted[k] += 1;
        } else {
            line.truth[k] += 1;
        }
    }
}

/// The floor the truth is scored on: inside the plan's closed walls (its bounding box when it
/// has none), at least `inset_m` from them, not within `sensor_clear_m` of a sensor used (below
/// its minimum range, or behind it against the wall), and within `range_m` and in the sight of
/// one (past the plan's walls, shelves and pillars, though not past other people: hiding behind
/// each other is the tracker's problem, hiding behind a shelf is the site's). People outside
/// that floor (arriving 1 m outside a door, in a recess behind the scanners, in an aisle no
/// scanner looks down) and tracks there are not counted.
#[derive(Debug, Clone)]
struct Floor {
    outlines: Vec<Vec<[f64; 2]>>,
    min: [f64; 2],
    max: [f64; 2],
    inset_m: f64,
    sensors: Vec<[f64; 2]>,
    sensor_clear_m: f64,
    range_m: f64,
    sight: Sightlines,
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
    fn of(plan: &Plan, inset_m: f64, range_m: f64) -> Result<Floor, PlanError> {
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
        Ok(Floor {
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
            sight: Sightlines::new(plan)?,
        })
    }

    /// On the floor and in a sensor's sight.
    fn contains(&self, x: f64, y: f64) -> bool {
        self.within_reach(x, y) && self.sight.seen([x, y], self.range_m, BODY_M)
    }

    /// On the floor, whether or not a sensor has it in sight.
    fn within_reach(&self, x: f64, y: f64) -> bool {
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
    let floor = Floor::of(plan, 0.25, params.max_range_m)?;
    let mut sim = Simulation::new(plan, o.seed)?;
    let infos = sim.sensors().to_vec();
    let start_ns = sim.start_ns();
    let mounts: Vec<Mount> = infos.iter().map(|i| i.mount()).collect();
    let poses: Vec<Option<Pose2>> = infos
        .iter()
        .map(|i| {
            if o.unplaced.contains(&i.id) {
                return None;
            }
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
    score.lines = o
        .lines
        .iter()
        .map(|l| LineScore {
            id: l.id.clone(),
            ..LineScore::default()
        })
        .collect();
    score.zones = o
        .zones
        .iter()
        .map(|z| ZoneScore {
            id: z.id.clone(),
            ..ZoneScore::default()
        })
        .collect();
    // The same counter the daemon runs, once on the tracks and once on the truth.
    let mut track_counter = Counter::new(Vec::new(), o.lines.clone());
    let mut truth_counter = Counter::new(Vec::new(), o.lines.clone());
    let mut truth_ids: BTreeMap<String, u64> = BTreeMap::new();
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
                    if !o.lines.is_empty() {
                        let m = track_counter.update(&out);
                        tally(&mut score.lines, &m, warmup_ns, true);
                    }
                    latest = Some(out);
                }
            }
            SimEvent::People(truth) => {
                if !o.lines.is_empty() {
                    let as_tracks = Tracks {
                        t_ns: truth.t_ns,
                        tracks: truth
                            .people
                            .iter()
                            .map(|p| {
                                let n = truth_ids.len() as u64;
                                let id = *truth_ids.entry(p.id.clone()).or_insert(n);
                                Track {
                                    id,
                                    x_m: p.x_m,
                                    y_m: p.y_m,
                                    vx_m_s: 0.0,
                                    vy_m_s: 0.0,
                                    sigma_m: 0.0,
                                    age_s: 0.0,
                                    sensors: Vec::new(),
                                }
                            })
                            .collect(),
                    };
                    let m = truth_counter.update(&as_tracks);
                    tally(&mut score.lines, &m, warmup_ns, false);
                }
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
                let minutes = |n: usize| {
                    n as f64 * crate::sim::PEOPLE_TRUTH_PERIOD_NS as f64 * 1e-9 / 60.0
                };
                let reached = truth
                    .people
                    .iter()
                    .filter(|p| floor.within_reach(p.x_m, p.y_m))
                    .count();
                score.person_minutes += minutes(people.len());
                score.hidden_person_minutes += minutes(reached - people.len());
                for (zone, z) in o.zones.iter().zip(score.zones.iter_mut()) {
                    let truth_in = people
                        .iter()
                        .filter(|(_, x, y)| inside(&zone.polygon, [*x, *y]))
                        .count();
                    let tracks_in = tracks
                        .iter()
                        .filter(|(_, x, y)| inside(&zone.polygon, [*x, *y]))
                        .count();
                    z.frames += 1;
                    z.abs_error_sum += truth_in.abs_diff(tracks_in) as f64;
                    z.truth_sum += truth_in as f64;
                }
                let before = (score.mot.misses, score.mot.false_tracks);
                let switches = score.mot.frame(&people, &tracks);
                for (i, from, to) in &switches {
                    let (id, x, y) = &people[*i];
                    let near = people
                        .iter()
                        .filter(|(o, _, _)| o != id)
                        .map(|(_, ox, oy)| (ox - x).hypot(oy - y))
                        .fold(f64::INFINITY, f64::min);
                    let alive = tracks.iter().any(|(t, _, _)| t == from);
                    tracing::debug!(
                        "switch t {:.1} {id} at {x:.2},{y:.2}: {from} -> {to} (old track {}; nearest other person {near:.2} m)",
                        (truth.t_ns - start_ns) as f64 * 1e-9,
                        if alive { "alive" } else { "gone" }
                    );
                }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::Crossing;

    fn hall(crowd: &str) -> Plan {
        let text = format!(
            r#"
name = "hall"
[[wall]]
points = [[0, 0], [32, 0], [32, 20], [0, 20]]
closed = true
[[door]]
at = [8, 0]
width_m = 2.0
[[door]]
at = [14.5, 20]
width_m = 4.0
[[door]]
at = [0, 6]
width_m = 1.2
[[sensor]]
id = "s"
model = "UTM-30LX-EW"
x = 16.0
y = 0.4
yaw_deg = 90
[[sensor]]
id = "n"
model = "UTM-30LX-EW"
x = 20.0
y = 19.6
yaw_deg = -90
{crowd}
"#
        );
        Plan::from_toml(&text, "hall").expect("the plan parses")
    }

    fn left_of(l: &CountLine, p: Xy) -> bool {
        let d = [l.to[0] - l.from[0], l.to[1] - l.from[1]];
        d[0] * (p[1] - l.from[1]) - d[1] * (p[0] - l.from[0]) > 0.0
    }

    #[test]
    fn lines_cross_the_two_widest_doors_inside_with_in_to_the_left() {
        let (lines, zones) = counting_layout(&hall("[[crowd]]\npeople = 5"));
        assert_eq!(lines.len(), 2, "{lines:?}");
        // Widest first: the 4 m north door; 2 m inside (y = 18), 6 m long, centred on it.
        let north = &lines[0];
        assert_eq!(north.id, "door 14.5,20");
        for end in [north.from, north.to] {
            assert!((end[1] - 18.0).abs() < 1e-9, "{north:?}");
        }
        let xs = [
            north.from[0].min(north.to[0]),
            north.from[0].max(north.to[0]),
        ];
        assert!(
            (xs[0] - 11.5).abs() < 1e-9 && (xs[1] - 17.5).abs() < 1e-9,
            "{north:?}"
        );
        assert!(
            left_of(north, [14.5, 10.0]),
            "into the hall is left: {north:?}"
        );
        let south = &lines[1];
        assert_eq!(south.id, "door 8,0");
        assert!((south.from[1] - 2.0).abs() < 1e-9 && (south.to[1] - 2.0).abs() < 1e-9);
        assert!(left_of(south, [8.0, 10.0]), "{south:?}");
        assert!(!left_of(south, [8.0, -1.0]), "{south:?}");
        // Zones: inside the widest door, and the middle of the sensors' box (18, 10).
        assert_eq!(zones.len(), 2);
        assert!(inside(&zones[0].polygon, [14.5, 18.0]));
        assert!(
            !inside(&zones[0].polygon, [14.5, 19.7]),
            "not in the doorway"
        );
        assert!(!inside(&zones[0].polygon, [14.5, 15.0]));
        assert!(inside(&zones[1].polygon, [18.0, 10.0]));
        assert!(!inside(&zones[1].polygon, [14.0, 10.0]));
    }

    #[test]
    fn a_crowd_with_set_entrances_is_counted_across_the_middle() {
        let plan = hall("[[crowd]]\npeople = 5\nentrances = [[10, 10], [20, 10]]");
        let (lines, zones) = counting_layout(&plan);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert_eq!((lines[0].from, lines[0].to), ([18.0, 0.4], [18.0, 19.6]));
        assert_eq!((lines[1].from, lines[1].to), ([16.0, 10.0], [20.0, 10.0]));
        assert_eq!(zones.len(), 1, "no door zone: {zones:?}");
    }

    #[test]
    fn a_miscount_one_way_does_not_cancel_one_the_other_way() {
        let mut lines = vec![LineScore {
            id: "door".into(),
            ..LineScore::default()
        }];
        let crossing = |t_ns, to| {
            Message::Crossing(Crossing {
                t_ns,
                line: "door".into(),
                track: 1,
                to,
                left_total: 0,
                right_total: 0,
            })
        };
        let truth = [
            crossing(5, Side::Left),
            crossing(20, Side::Left),
            crossing(30, Side::Right),
        ];
        tally(&mut lines, &truth, 10, false);
        tally(
            &mut lines,
            &[crossing(20, Side::Right), crossing(30, Side::Right)],
            10,
            true,
        );
        assert_eq!(
            lines[0].truth,
            [1, 1],
            "the one before warm-up is not scored"
        );
        assert_eq!(lines[0].counted, [0, 2]);
        let score = SceneScore {
            lines,
            ..SceneScore::default()
        };
        assert_eq!((score.line_truth(), score.line_counted()), (2, 2));
        assert!((score.line_error_pct() - 100.0).abs() < 1e-9);
        assert!(SceneScore::default().line_error_pct().is_nan());
        assert!(SceneScore::default().zone_mae().is_nan());
    }
}
