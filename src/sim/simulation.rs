//! Turning a plan into a stream of scans: sensor timing and clocks, moves, people, and the
//! per-beam sensor model.
//!
//! The static scene is ray-cast once per sensor pose (three sub-rays per beam across the
//! beam's footprint) and cached; each scan only intersects the people, who move during the
//! scan (every step is taken at its own time), and draws the sensor model's randomness. Each
//! sensor draws from its own ChaCha stream, so a sensor's scans do not depend on the others or on
//! how long the run is: a shorter run is a prefix of a longer one.

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::PlanError;
use super::crowd::{BodyNow, CrowdPlan, CrowdRun};
use super::people::{BODY_REACH_M, Body, Walker};
use super::plan::{Model, Plan, SensorPlan};
use super::scene::{Cylinder, Extent, Hit, Ray, Scene, Surface, hit_cylinder};
use super::sensor_model::{BeamModel, read_beam};
use crate::scan::{MoveTruth, PeopleTruth, PersonTruth, Scan, ScanGeometry, SensorInfo, TruthPose};

/// The random stream of the crowds, well apart from the setup (0) and the sensors (1 + i).
const CROWD_STREAM: u64 = 1 << 40;
/// Time between two `/truth/people` messages, ns.
pub const PEOPLE_TRUTH_PERIOD_NS: u64 = 100_000_000;

/// What [`Simulation::run_with_truth`] hands out, in time order.
#[derive(Debug, Clone, PartialEq)]
pub enum SimEvent {
    /// A scan of the sensor with this index.
    Scan(usize, Scan),
    /// Where everyone is (only when the plan asks for the people's truth).
    People(PeopleTruth),
}

/// Where the outer sub-rays of a beam sit, in steps either side of its centre.
const FOOTPRINT_HALF_STEPS: f64 = 0.4;
/// Largest drift of a sensor's clock (and mirror) from the host's.
const MAX_DRIFT: f64 = 50e-6;
/// Sensor ms clocks start anywhere in their 24-bit range.
const CLOCK_RANGE_MS: u64 = 1 << 24;

/// A sensor as simulated: its plan entry, layout, clock and pose over time.
#[derive(Debug, Clone)]
struct Unit {
    plan: SensorPlan,
    geometry: ScanGeometry,
    beam: BeamModel,
    /// Scan period on the host clock, s.
    period_s: f64,
    /// Start of the first scan after the recording start, s.
    phase_s: f64,
    clock_offset_ms: u64,
    drift: f64,
    /// Fixed part of the receive latency, s.
    latency_s: f64,
    /// (from time s, [x, y, yaw_rad]) in time order, the first from 0.
    poses: Vec<(f64, [f64; 3])>,
}

/// A running sensor: its random stream and the cached static view for its current pose.
struct UnitRun {
    rng: ChaCha8Rng,
    next_scan: u64,
    pose_index: Option<usize>,
    /// Per beam, three sub-rays across the footprint (centre in the middle).
    rays: Vec<[Ray; 3]>,
    statics: Vec<[Option<Hit>; 3]>,
    /// Horizontal unit direction of each beam's centre ray, to cull people quickly.
    headings: Vec<[f64; 2]>,
}

/// A plan ready to produce scans. Same plan and seed give bit-identical scans.
pub struct Simulation {
    scene: Scene,
    seed: u64,
    start_ns: u64,
    infos: Vec<SensorInfo>,
    units: Vec<Unit>,
    walkers: Vec<Walker>,
    person_reflectivity: Vec<f64>,
    moves: Vec<MoveTruth>,
    crowd: Option<CrowdPlan>,
    people_truth: bool,
}

/// The PP and VV fields a unit of this model reports.
fn fields_of(model: Model, geometry: &ScanGeometry, serial: u32) -> BTreeMap<String, String> {
    let mut fields = geometry.to_fields();
    let (prod, firm, seri) = match model {
        Model::Utm30lxEw => (
            "SOKUIKI Sensor TOP-URG UTM-30LX-EW",
            "1.1.6(28/Jun./2013)",
            format!("H13{serial:05}"),
        ),
        Model::Uxm30lxE => (
            "SOKUIKI Sensor Tough-URG UXM-30LX-E",
            "0.3.01(11/Mar./2010)",
            format!("H09{serial:05}"),
        ),
        // As the unit in fixtures/scip/example_urg_04lx.logr answers VV.
        Model::Urg04lx => (
            "SOKUIKI Sensor URG-04LX",
            "3.1.04(02/Aug./2007)",
            format!("H07{serial:05}"),
        ),
    };
    for (key, value) in [
        (
            "MODL",
            format!("{}(Hokuyo Automatic Co.,Ltd.)", model.name()),
        ),
        ("VEND", "Hokuyo Automatic Co.,Ltd.".to_string()),
        ("PROD", prod.to_string()),
        ("FIRM", firm.to_string()),
        ("PROT", "SCIP 2.0".to_string()),
        ("SERI", seri),
    ] {
        fields.insert(key.to_string(), value);
    }
    fields
}

/// The random stream for a purpose: 0 sets the units up, 1 + i is sensor i's scans.
fn stream(seed: u64, index: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index);
    rng
}

/// Site-frame pose of the beam origin, [x, y, yaw_rad].
fn pose_of(sensor: &SensorPlan) -> [f64; 3] {
    [sensor.x, sensor.y, sensor.yaw_deg.to_radians()]
}

fn truth_of(pose: [f64; 3]) -> TruthPose {
    TruthPose {
        x_m: pose[0],
        y_m: pose[1],
        yaw_deg: pose[2].to_degrees(),
    }
}

fn ns_of_s(seconds: f64) -> u64 {
    (seconds * 1e9).round().max(0.0) as u64
}

/// The beams of a sensor at `pose`: three sub-rays per step across its footprint.
pub(crate) fn beam_rays(
    sensor: &SensorPlan,
    geometry: &ScanGeometry,
    pose: [f64; 3],
) -> Vec<[Ray; 3]> {
    let pitch_rad = sensor.pitch_deg.to_radians();
    let half = FOOTPRINT_HALF_STEPS * geometry.step_rad();
    (geometry.amin..=geometry.amax)
        .map(|step| {
            let theta = geometry.angle_of_step_rad(step);
            [theta - half, theta, theta + half]
                .map(|t| Ray::from_sensor(pose, sensor.height_m, pitch_rad, t))
        })
        .collect()
}

impl Simulation {
    /// Prepares a simulation of `plan`; `seed` fixes every random draw.
    pub fn new(plan: &Plan, seed: u64) -> Result<Simulation, PlanError> {
        plan.validate()?;
        let scene = Scene::build(plan)?;
        let start_ns = plan.start_unix_s.saturating_mul(1_000_000_000);
        let mut setup = stream(seed, 0);
        let mut units = Vec::new();
        let mut infos = Vec::new();
        let mut moves = Vec::new();
        for sensor in &plan.sensors {
            let geometry = sensor.model.geometry();
            let drift = (setup.random::<f64>() * 2.0 - 1.0) * MAX_DRIFT;
            let period_s = geometry.period_s() / (1.0 + drift);
            let phase_s = setup.random::<f64>() * period_s;
            let clock_offset_ms = setup.random_range(0..CLOCK_RANGE_MS);
            let latency_s = 1.0e-3 + setup.random::<f64>() * 2.0e-3;
            let serial = setup.random_range(0..100_000u32);

            let mut pose = pose_of(sensor);
            let mut poses = vec![(0.0, pose)];
            let mut own: Vec<_> = plan
                .moves
                .iter()
                .filter(|m| m.sensor == sensor.id)
                .collect();
            own.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
            for m in own {
                pose = [
                    pose[0] + m.dx,
                    pose[1] + m.dy,
                    pose[2] + m.dyaw_deg.to_radians(),
                ];
                poses.push((m.at_s, pose));
                moves.push(MoveTruth {
                    sensor_id: sensor.id.clone(),
                    at_ns: start_ns.saturating_add(ns_of_s(m.at_s)),
                    pose: truth_of(pose),
                });
            }
            infos.push(SensorInfo {
                id: sensor.id.clone(),
                model: sensor.model.name().to_string(),
                connect: format!("sim:{}", plan.name),
                geometry: Some(geometry),
                fields: fields_of(sensor.model, &geometry, serial),
                height_m: Some(sensor.height_m),
                pitch_deg: Some(sensor.pitch_deg),
                truth: Some(truth_of(pose_of(sensor))),
            });
            units.push(Unit {
                plan: sensor.clone(),
                geometry,
                beam: BeamModel::of(
                    sensor.model,
                    geometry.dmin_mm as f64 / 1000.0,
                    geometry.dmax_mm as f64 / 1000.0,
                ),
                period_s,
                phase_s,
                clock_offset_ms,
                drift,
                latency_s,
                poses,
            });
        }
        moves.sort_by_key(|m| m.at_ns);
        // Clothes from dark to light.
        let person_reflectivity = plan
            .people
            .iter()
            .map(|_| 0.15 + 0.6 * setup.random::<f64>())
            .collect();
        Ok(Simulation {
            seed,
            start_ns,
            infos,
            units,
            walkers: plan.people.iter().map(Walker::new).collect(),
            person_reflectivity,
            moves,
            crowd: CrowdPlan::build(plan, &scene)?,
            people_truth: plan.writes_people_truth(),
            scene,
        })
    }

    /// Whether [`run_with_truth`](Self::run_with_truth) hands out the people's truth.
    pub fn has_people_truth(&self) -> bool {
        self.people_truth
    }

    /// The sensors, in plan order (the index `run` passes to its sink).
    pub fn sensors(&self) -> &[SensorInfo] {
        &self.infos
    }

    /// Every move, in time order, with the pose after it.
    pub fn moves(&self) -> &[MoveTruth] {
        &self.moves
    }

    /// Recording start, ns since the Unix epoch.
    pub fn start_ns(&self) -> u64 {
        self.start_ns
    }

    /// Every scan of every sensor with `stamp_ns` less than `seconds` after the start, in stamp
    /// order across sensors, handed to `sink` one at a time. Each call starts again from the
    /// beginning; `seconds = inf` runs until the sink returns an error.
    pub fn run<E>(
        &mut self,
        seconds: f64,
        mut sink: impl FnMut(usize, Scan) -> Result<(), E>,
    ) -> Result<(), E> {
        self.run_events(seconds, false, |event| match event {
            SimEvent::Scan(i, scan) => sink(i, scan),
            SimEvent::People(_) => Ok(()),
        })
    }

    /// As [`run`](Self::run), with the people's truth interleaved in time order when the plan
    /// asks for it: every 0.1 s from the start, every body's centre (`/truth/people`). The scans
    /// are the same as `run` gives.
    pub fn run_with_truth<E>(
        &mut self,
        seconds: f64,
        sink: impl FnMut(SimEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        let truth = self.people_truth;
        self.run_events(seconds, truth, sink)
    }

    /// Everyone's truth at `t_ns`.
    fn people_at(&self, crowd: Option<&mut CrowdRun<'_>>, t_ns: u64) -> PeopleTruth {
        let t_s = t_ns.saturating_sub(self.start_ns) as f64 * 1e-9;
        let round = |v: f64| (v * 1e4).round() / 1e4;
        let mut people: Vec<PersonTruth> = self
            .walkers
            .iter()
            .enumerate()
            .map(|(i, w)| {
                let (p, _) = w.state_at(t_s);
                PersonTruth {
                    id: format!("w{}", i + 1),
                    x_m: round(p[0]),
                    y_m: round(p[1]),
                }
            })
            .collect();
        if let Some(crowd) = crowd {
            people.extend(crowd.bodies_at(t_s).iter().map(|b| PersonTruth {
                id: format!("p{}", b.state.id),
                x_m: round(b.state.pos[0]),
                y_m: round(b.state.pos[1]),
            }));
        }
        PeopleTruth { t_ns, people }
    }

    fn run_events<E>(
        &mut self,
        seconds: f64,
        with_truth: bool,
        mut sink: impl FnMut(SimEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        let this = &*self;
        let mut crowd = this
            .crowd
            .as_ref()
            .map(|c| c.start(stream(this.seed, CROWD_STREAM)));
        let mut next_truth_ns = this.start_ns;
        if seconds.is_nan() || seconds <= 0.0 {
            return Ok(());
        }
        let limit_ns = if seconds.is_finite() {
            self.start_ns.saturating_add(ns_of_s(seconds))
        } else {
            u64::MAX
        };
        let mut runs: Vec<UnitRun> = (0..this.units.len())
            .map(|i| UnitRun {
                rng: stream(this.seed, 1 + i as u64),
                next_scan: 0,
                pose_index: None,
                rays: Vec::new(),
                statics: Vec::new(),
                headings: Vec::new(),
            })
            .collect();
        let mut pending: Vec<Option<Scan>> = Vec::with_capacity(runs.len());
        for (unit, run) in this.units.iter().zip(runs.iter_mut()) {
            pending.push(this.next_scan(unit, run, limit_ns, crowd.as_mut()));
        }
        loop {
            let earliest = pending
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.as_ref().map(|s| (s.stamp_ns, i)))
                .min();
            // The truth up to the next scan (or to the end) goes first.
            let until_ns = earliest.map_or(limit_ns, |(stamp_ns, _)| stamp_ns.saturating_add(1));
            while with_truth && next_truth_ns < until_ns && next_truth_ns < limit_ns {
                sink(SimEvent::People(
                    this.people_at(crowd.as_mut(), next_truth_ns),
                ))?;
                next_truth_ns = next_truth_ns.saturating_add(PEOPLE_TRUTH_PERIOD_NS);
            }
            let Some((_, i)) = earliest else {
                return Ok(());
            };
            let (Some(slot), Some(unit), Some(run)) =
                (pending.get_mut(i), this.units.get(i), runs.get_mut(i))
            else {
                return Ok(());
            };
            let next = this.next_scan(unit, run, limit_ns, crowd.as_mut());
            if let Some(scan) = std::mem::replace(slot, next) {
                sink(SimEvent::Scan(i, scan))?;
            }
        }
    }

    /// The unit's next scan, or `None` once its stamp reaches `limit_ns`.
    fn next_scan(
        &self,
        unit: &Unit,
        run: &mut UnitRun,
        limit_ns: u64,
        crowd: Option<&mut CrowdRun<'_>>,
    ) -> Option<Scan> {
        let k = run.next_scan;
        run.next_scan += 1;
        let t_start = unit.phase_s + k as f64 * unit.period_s;
        // Stamp first: it decides whether the scan exists, and must not depend on the scan.
        let jitter_s = (-0.4e-3 * (1.0 - run.rng.random::<f64>()).ln()).min(5e-3);
        let stamp_ns = self
            .start_ns
            .saturating_add(ns_of_s(t_start + unit.period_s + unit.latency_s + jitter_s));
        if stamp_ns >= limit_ns {
            return None;
        }
        // Moves take effect for scans that start at or after them.
        let pose_index = unit
            .poses
            .partition_point(|(at_s, _)| *at_s <= t_start)
            .saturating_sub(1);
        if run.pose_index != Some(pose_index) {
            let pose = unit
                .poses
                .get(pose_index)
                .map_or_else(|| pose_of(&unit.plan), |p| p.1);
            run.rays = beam_rays(&unit.plan, &unit.geometry, pose);
            run.statics = run
                .rays
                .iter()
                .map(|rays| rays.each_ref().map(|r| self.scene.cast(r)))
                .collect();
            run.headings = run
                .rays
                .iter()
                .map(|[_, centre, _]| {
                    let [x, y, _] = centre.dir;
                    let norm = x.hypot(y).max(1e-12);
                    [x / norm, y / norm]
                })
                .collect();
            run.pose_index = Some(pose_index);
        }
        let people: Vec<([f64; 2], [f64; 2])> =
            self.walkers.iter().map(|w| w.state_at(t_start)).collect();
        // Each person can only be hit by beams within a cone around their direction: its
        // half-angle covers their radius, their walk during the scan and the beam footprint.
        let origin = run.rays.first().map_or([0.0; 3], |r| r[1].origin);
        let cones: Vec<([f64; 2], f64)> = people
            .iter()
            .zip(&self.walkers)
            .map(|((pos, vel), walker)| {
                let (dx, dy) = (pos[0] - origin[0], pos[1] - origin[1]);
                let dist = dx.hypot(dy);
                let reach = walker.radius_m + vel[0].hypot(vel[1]) * unit.period_s + 0.05;
                if dist <= reach * 1.5 {
                    return ([1.0, 0.0], -2.0);
                }
                let half = (reach / dist).asin() + 3.0 * unit.geometry.step_rad();
                ([dx / dist, dy / dist], half.cos())
            })
            .collect();
        // The crowd's bodies, culled the same way.
        let bodies: Vec<BodyNow> = crowd.map(|c| c.bodies_at(t_start)).unwrap_or_default();
        let body_cones: Vec<([f64; 2], f64)> = bodies
            .iter()
            .map(|b| {
                let (dx, dy) = (b.state.pos[0] - origin[0], b.state.pos[1] - origin[1]);
                let dist = dx.hypot(dy);
                let reach = BODY_REACH_M + b.vel[0].hypot(b.vel[1]) * unit.period_s + 0.05;
                if dist <= reach * 1.5 {
                    return ([1.0, 0.0], -2.0);
                }
                let half = (reach / dist).asin() + 3.0 * unit.geometry.step_rad();
                ([dx / dist, dy / dist], half.cos())
            })
            .collect();
        let first_body_surface = self.walkers.len() as u32;
        let step_s = unit.period_s / unit.geometry.ares as f64;
        let with_intensities = unit.plan.has_intensities();
        let n = run.rays.len();
        let mut ranges_m = Vec::with_capacity(n);
        let mut intensities = Vec::with_capacity(if with_intensities { n } else { 0 });
        let beams = run.rays.iter().zip(&run.statics).zip(&run.headings);
        for (i, ((rays, statics), heading)) in beams.enumerate() {
            let mut subs = *statics;
            let dt = i as f64 * step_s;
            let crowd = people.iter().zip(&self.walkers).zip(&cones);
            for (p, (((pos, vel), walker), (towards, cos_limit))) in crowd.enumerate() {
                if heading[0] * towards[0] + heading[1] * towards[1] < *cos_limit {
                    continue;
                }
                let body = Cylinder {
                    center: [pos[0] + vel[0] * dt, pos[1] + vel[1] * dt],
                    radius_m: walker.radius_m,
                    extent: Extent {
                        z_min_m: 0.0,
                        z_max_m: walker.height_m,
                    },
                    reflectivity: self.person_reflectivity.get(p).copied().unwrap_or(0.4),
                };
                for (sub, ray) in subs.iter_mut().zip(rays) {
                    if let Some(h) = hit_cylinder(ray, &body, Surface::Person(p as u32))
                        && sub.is_none_or(|s| h.range_m < s.range_m)
                    {
                        *sub = Some(h);
                    }
                }
            }
            for (b, (towards, cos_limit)) in bodies.iter().zip(&body_cones) {
                if heading[0] * towards[0] + heading[1] * towards[1] < *cos_limit {
                    continue;
                }
                let body = Body::at(b, dt);
                let surface = Surface::Person(first_body_surface.saturating_add(b.state.id));
                for (sub, ray) in subs.iter_mut().zip(rays) {
                    if let Some(h) = body.hit(ray, surface)
                        && sub.is_none_or(|s| h.range_m < s.range_m)
                    {
                        *sub = Some(h);
                    }
                }
            }
            let reading = read_beam(&unit.beam, &subs, with_intensities, &mut run.rng);
            ranges_m.push(reading.range_m);
            if with_intensities {
                intensities.push(reading.intensity);
            }
        }
        // The sensor's own clock runs at its drifted rate from its random offset.
        let sensor_ms = (t_start * (1.0 + unit.drift) * 1000.0).floor() as u64;
        Some(Scan {
            stamp_ns,
            sensor_stamp_ms: Some(unit.clock_offset_ms.saturating_add(sensor_ms)),
            start_angle_rad: unit.geometry.angle_of_step_rad(unit.geometry.amin),
            end_angle_rad: unit.geometry.angle_of_step_rad(unit.geometry.amax),
            ranges_m,
            intensities,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10 × 10 m room; sensor `a` 3.000 m from the wall x = 5, facing it.
    const ROOM: &str = r#"
name = "room"
[[wall]]
points = [[-5, -5], [5, -5], [5, 5], [-5, 5]]
closed = true

[[sensor]]
id = "a"
model = "UTM-30LX-EW"
x = 2.0
y = 0.0
"#;

    fn sim(text: &str, seed: u64) -> Simulation {
        let plan = Plan::from_toml(text, "test.toml").unwrap();
        Simulation::new(&plan, seed).unwrap()
    }

    /// All scans of sensor `index` for `seconds`.
    fn scans_of(sim: &mut Simulation, seconds: f64, index: usize) -> Vec<Scan> {
        let mut out = Vec::new();
        sim.run(seconds, |i, scan| {
            if i == index {
                out.push(scan);
            }
            Ok::<(), ()>(())
        })
        .unwrap();
        out
    }

    fn front(scan: &Scan, geometry: &ScanGeometry) -> f32 {
        scan.ranges_m[(geometry.afrt - geometry.amin) as usize]
    }

    /// Median of the returns within `half` steps of the front.
    fn front_median(scan: &Scan, geometry: &ScanGeometry, half: usize) -> f64 {
        let c = (geometry.afrt - geometry.amin) as usize;
        let mut v: Vec<f64> = scan.ranges_m[c - half..=c + half]
            .iter()
            .filter(|r| **r > 0.0)
            .map(|r| *r as f64)
            .collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    }

    #[test]
    fn wall_three_metres_ahead_reads_three_metres_on_the_square_beam() {
        let mut sim = sim(ROOM, 1);
        let g = ScanGeometry::UTM_30LX_EW;
        let scans = scans_of(&mut sim, 10.0, 0);
        assert!(
            (395..=401).contains(&scans.len()),
            "{} scans in 10 s",
            scans.len()
        );
        let returns: Vec<f64> = scans
            .iter()
            .map(|s| front(s, &g) as f64)
            .filter(|r| *r > 0.0)
            .collect();
        // Rare spurious returns (dust) are outliers, not noise.
        let ranges: Vec<f64> = returns
            .iter()
            .copied()
            .filter(|r| (r - 3.0).abs() < 0.2)
            .collect();
        assert!(returns.len() - ranges.len() <= 2);
        assert!(ranges.len() > 380);
        let mean = ranges.iter().sum::<f64>() / ranges.len() as f64;
        assert!((mean - 3.0).abs() < 0.003, "mean {mean}");
        let sd =
            (ranges.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / ranges.len() as f64).sqrt();
        assert!((0.005..0.02).contains(&sd), "sd {sd}");
        let scan = &scans[0];
        assert_eq!(scan.ranges_m.len(), 1081);
        assert_eq!(scan.intensities.len(), 1081);
        assert!((scan.start_angle_rad + 135f64.to_radians()).abs() < 1e-12);
        assert!((scan.end_angle_rad - 135f64.to_radians()).abs() < 1e-12);
    }

    #[test]
    fn tilted_unit_sees_the_floor_at_height_over_sine_of_pitch() {
        let text = ROOM
            .replace(
                "y = 0.0",
                "y = 0.0\nheight_m = 2.5\npitch_deg = -20\nx = -4.5",
            )
            .replace("x = 2.0\n", "");
        let mut sim = sim(&text, 3);
        let g = ScanGeometry::UTM_30LX_EW;
        let scans = scans_of(&mut sim, 5.0, 0);
        let ranges: Vec<f64> = scans
            .iter()
            .map(|s| front(s, &g) as f64)
            .filter(|r| *r > 0.0)
            .collect();
        assert!(ranges.len() > 150, "{} floor returns", ranges.len());
        let mean = ranges.iter().sum::<f64>() / ranges.len() as f64;
        let expected = 2.5 / 20f64.to_radians().sin();
        assert!((expected - 7.3095).abs() < 1e-3);
        assert!(
            (mean - expected).abs() < 0.005,
            "mean {mean}, expected {expected}"
        );
        let info = &sim.sensors()[0];
        assert_eq!(info.pitch_deg, Some(-20.0));
        assert_eq!(info.height_m, Some(2.5));
    }

    #[test]
    fn same_seed_gives_identical_scans_and_another_seed_does_not() {
        let collect = |seed| {
            let mut all = Vec::new();
            sim(ROOM, seed)
                .run(0.5, |i, s| {
                    all.push((i, s));
                    Ok::<(), ()>(())
                })
                .unwrap();
            all
        };
        let a = collect(7);
        assert!(!a.is_empty());
        assert_eq!(a, collect(7));
        let c = collect(8);
        assert_ne!(
            a.iter().map(|(_, s)| &s.ranges_m).collect::<Vec<_>>(),
            c.iter().map(|(_, s)| &s.ranges_m).collect::<Vec<_>>()
        );
    }

    #[test]
    fn shorter_run_is_a_prefix_of_a_longer_one_and_stamps_are_ordered() {
        let text = format!(
            "{ROOM}\n[[sensor]]\nid = \"b\"\nmodel = \"UXM-30LX-E\"\nx = -2.0\ny = 1.0\nyaw_deg = 170\n"
        );
        let mut s = sim(&text, 11);
        let mut long = Vec::new();
        s.run(2.0, |i, scan| {
            long.push((i, scan));
            Ok::<(), ()>(())
        })
        .unwrap();
        let mut short = Vec::new();
        s.run(1.0, |i, scan| {
            short.push((i, scan));
            Ok::<(), ()>(())
        })
        .unwrap();
        assert_eq!(&long[..short.len()], &short[..]);
        assert!(long.windows(2).all(|w| w[0].1.stamp_ns <= w[1].1.stamp_ns));
        let start = s.start_ns();
        assert!(
            long.iter()
                .all(|(_, scan)| scan.stamp_ns - start < 2_000_000_000)
        );
        for (index, period_ms) in [(0usize, 25.0), (1, 50.0)] {
            let own: Vec<&Scan> = long
                .iter()
                .filter(|(i, _)| *i == index)
                .map(|(_, s)| s)
                .collect();
            let expected = (2000.0 / period_ms) as usize;
            assert!(
                own.len() + 1 >= expected && own.len() <= expected,
                "sensor {index}: {} scans",
                own.len()
            );
            for w in own.windows(2) {
                let dt_ms = (w[1].stamp_ns - w[0].stamp_ns) as f64 / 1e6;
                assert!((dt_ms - period_ms).abs() < 6.0, "host period {dt_ms} ms");
                let clock_ms = w[1].sensor_stamp_ms.unwrap() - w[0].sensor_stamp_ms.unwrap();
                assert!(
                    (clock_ms as f64 - period_ms).abs() <= 1.0,
                    "sensor period {clock_ms} ms"
                );
            }
        }
        // The UXM has 761 steps and no intensities by default.
        let uxm = long.iter().find(|(i, _)| *i == 1).unwrap();
        assert_eq!(uxm.1.ranges_m.len(), 761);
        assert!(uxm.1.intensities.is_empty());
    }

    #[test]
    fn move_shows_between_the_last_scan_before_and_the_first_after() {
        let text =
            format!("{ROOM}\n[[move]]\nsensor = \"a\"\nat_s = 1.0\ndx = 0.5\ndyaw_deg = 10\n");
        let mut s = sim(&text, 5);
        let g = ScanGeometry::UTM_30LX_EW;
        let moves = s.moves().to_vec();
        assert_eq!(moves.len(), 1);
        assert_eq!(moves[0].at_ns, s.start_ns() + 1_000_000_000);
        assert!(
            (moves[0].pose.x_m - 2.5).abs() < 1e-12 && (moves[0].pose.yaw_deg - 10.0).abs() < 1e-12
        );
        let start = s.start_ns();
        let scans = scans_of(&mut s, 2.0, 0);
        // A scan's stamp is its start + 25 ms + 1..8 ms latency.
        let started_s = |scan: &Scan| (scan.stamp_ns - start) as f64 / 1e9 - 0.025;
        let before: Vec<&Scan> = scans.iter().filter(|s| started_s(s) < 1.0).collect();
        let after: Vec<&Scan> = scans
            .iter()
            .filter(|s| started_s(s) > 1.0 + 0.009)
            .collect();
        assert!(before.len() > 30 && after.len() > 30);
        // Before: wall 3 m ahead. After: 2.5 m along x, 10° turned: 2.5 / cos 10°.
        let after_m = 2.5 / 10f64.to_radians().cos();
        for scan in &before {
            assert!((front_median(scan, &g, 2) - 3.0).abs() < 0.05);
        }
        for scan in &after {
            assert!((front_median(scan, &g, 2) - after_m).abs() < 0.05);
        }
        let last_before = before.last().unwrap();
        let first_after = scans.iter().find(|s| started_s(s) >= 1.0).unwrap();
        assert!((front_median(last_before, &g, 2) - front_median(first_after, &g, 2)).abs() > 0.4);
    }

    #[test]
    fn people_occlude_the_wall_behind_them() {
        let person = "\n[[person]]\nwaypoints = [[4, -4], [4, 4]]\nspeed_m_s = 1.5\n";
        let g = ScanGeometry::UTM_30LX_EW;
        let nearest = |text: &str| {
            let mut s = sim(text, 9);
            scans_of(&mut s, 12.0, 0)
                .iter()
                .map(|scan| front_median(scan, &g, 2))
                .fold(f64::INFINITY, f64::min)
        };
        // Walking across x = 4, 2 m ahead: the front beams read about 2 - 0.25 m.
        let with = nearest(&format!("{ROOM}{person}"));
        assert!((with - 1.75).abs() < 0.05, "nearest front return {with}");
        let without = nearest(ROOM);
        assert!(
            (without - 3.0).abs() < 0.05,
            "nearest front return {without}"
        );
    }

    #[test]
    fn pillar_edges_give_mixed_pixels_and_far_walls_drop_out_plausibly() {
        // A pillar 3 m ahead in front of a wall 8 m ahead: two silhouette edges.
        let text = r#"
name = "edges"
[[wall]]
points = [[-10, -30], [10, -30], [10, 30], [-10, 30]]
closed = true
[[circle]]
center = [5, 0]
radius_m = 0.3
[[sensor]]
id = "a"
model = "UTM-30LX-EW"
x = 2.0
y = 0.0
"#;
        let mut s = sim(text, 4);
        let scans = scans_of(&mut s, 10.0, 0);
        let g = ScanGeometry::UTM_30LX_EW;
        let c = (g.afrt - g.amin) as usize;
        let mut in_between = 0;
        let mut dropped = 0;
        let mut beams = 0;
        for scan in &scans {
            // Beams around the pillar: returns between the pillar's silhouette (2.985 m at the
            // tangent) and the wall are mixed pixels.
            in_between += scan.ranges_m[c - 30..=c + 30]
                .iter()
                .filter(|r| **r as f64 > 3.1 && (**r as f64) < 7.8)
                .count();
            for r in &scan.ranges_m {
                beams += 1;
                dropped += usize::from(*r == 0.0);
            }
        }
        let mixed_per_scan = in_between as f64 / scans.len() as f64;
        // Two edges, each straddled by about one beam, mixed 60 % of the time.
        assert!(
            (0.5..3.0).contains(&mixed_per_scan),
            "{mixed_per_scan} mixed pixels per scan"
        );
        // Walls 8–30 m away at all angles: a few percent drop out, not none, not most.
        let drop_rate = dropped as f64 / beams as f64;
        assert!(
            (0.005..0.15).contains(&drop_rate),
            "dropout rate {drop_rate}"
        );
    }

    #[test]
    fn crowd_truth_comes_every_tenth_of_a_second_between_unchanged_scans() {
        let text = format!(
            "{ROOM}\n[[door]]\nat = [0, -5]\nwidth_m = 1.2\n[[crowd]]\npeople = 5\n\
             [[person]]\nwaypoints = [[-3, -3], [-3, 3]]\n"
        );
        let mut s = sim(&text, 3);
        assert!(s.has_people_truth());
        let mut scans = Vec::new();
        let mut truths = Vec::new();
        let mut order = Vec::new();
        s.run_with_truth(2.0, |event| {
            match event {
                SimEvent::Scan(i, scan) => {
                    order.push(scan.stamp_ns);
                    scans.push((i, scan));
                }
                SimEvent::People(p) => {
                    order.push(p.t_ns);
                    truths.push(p);
                }
            }
            Ok::<(), ()>(())
        })
        .unwrap();
        assert!(order.windows(2).all(|w| w[0] <= w[1]), "not in time order");
        assert_eq!(truths.len(), 20);
        for (k, t) in truths.iter().enumerate() {
            assert_eq!(t.t_ns, s.start_ns() + k as u64 * PEOPLE_TRUTH_PERIOD_NS);
            assert_eq!(t.people[0].id, "w1");
            assert!(t.people.len() >= 6, "{t:?}");
            assert!(t.people[1..].iter().all(|p| p.id.starts_with('p')));
            assert!(
                t.people
                    .iter()
                    .all(|p| p.x_m.abs() < 6.5 && p.y_m.abs() < 6.5)
            );
        }
        // The walker's truth is its loop position.
        let w = Walker::new(&Plan::from_toml(&text, "t").unwrap().people[0]);
        let (p, _) = w.state_at(1.0);
        assert!((truths[10].people[0].y_m - p[1]).abs() < 1e-3);
        // The scans are those `run` gives, and the crowd shows in them.
        let mut plain = Vec::new();
        s.run(2.0, |i, scan| {
            plain.push((i, scan));
            Ok::<(), ()>(())
        })
        .unwrap();
        assert_eq!(plain, scans);
        let mut empty = Vec::new();
        sim(
            &text.replace("people = 5", "people = 0\nrate_per_min = 0"),
            3,
        )
        .run(2.0, |i, scan| {
            empty.push((i, scan));
            Ok::<(), ()>(())
        })
        .unwrap();
        assert_ne!(empty, scans, "the crowd is seen");
    }

    #[test]
    fn plans_without_crowds_carry_no_truth_unless_asked() {
        assert!(!sim(ROOM, 1).has_people_truth());
        let asked = format!("truth_people = true\n{ROOM}");
        assert!(sim(&asked, 1).has_people_truth());
    }

    #[test]
    fn sensor_info_carries_pp_vv_fields_and_truth() {
        let s = sim(ROOM, 1);
        let info = &s.sensors()[0];
        assert_eq!(info.connect, "sim:room");
        assert_eq!(info.geometry, Some(ScanGeometry::UTM_30LX_EW));
        for key in [
            "MODL", "DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN", "VEND", "PROD", "FIRM",
            "PROT", "SERI",
        ] {
            assert!(info.fields.contains_key(key), "missing {key}");
        }
        assert_eq!(
            ScanGeometry::from_fields(&info.fields),
            Ok(ScanGeometry::UTM_30LX_EW)
        );
        assert_eq!(
            info.truth,
            Some(TruthPose {
                x_m: 2.0,
                y_m: 0.0,
                yaw_deg: 0.0
            })
        );
    }

    /// A URG-04LX 2 m from the wall x = 5, facing it: 682 beams (AMIN..=AMAX, as many as the
    /// capture in fixtures/scip/example_urg_04lx.logr holds) over 240°, nothing past
    /// 5.6 m (the back corners lie further), no intensities, and the spec's noise at 2 m:
    /// σ = 1 % / 3 of the range ≈ 6.7 mm, not the floor of 3.3 mm nor the UTM's 10 mm.
    #[test]
    fn urg_sees_682_beams_to_5_6_m_with_one_percent_noise() {
        let text = ROOM
            .replace("UTM-30LX-EW", "URG-04LX")
            .replace("x = 2.0", "x = 3.0");
        let mut sim = sim(&text, 5);
        let g = ScanGeometry::URG_04LX;
        let info = &sim.sensors()[0];
        assert_eq!(info.model, "URG-04LX");
        assert_eq!(info.geometry, Some(g));
        assert_eq!(ScanGeometry::from_fields(&info.fields), Ok(g));
        assert_eq!(
            info.fields.get("MODL").map(String::as_str),
            Some("URG-04LX(Hokuyo Automatic Co.,Ltd.)")
        );
        assert_eq!(
            info.fields.get("PROD").map(String::as_str),
            Some("SOKUIKI Sensor URG-04LX")
        );
        let scans = scans_of(&mut sim, 20.0, 0);
        assert!(
            (198..=201).contains(&scans.len()),
            "{} scans in 20 s at 10 Hz",
            scans.len()
        );
        let c = (g.afrt - g.amin) as usize;
        let mut errors = Vec::new();
        for scan in &scans {
            assert_eq!(scan.ranges_m.len(), 682);
            assert!(scan.intensities.is_empty());
            assert!(
                scan.ranges_m.iter().all(|r| *r <= 5.6),
                "a return past DMAX"
            );
            // The beams aimed at the far back corners find nothing within reach.
            assert!(scan.ranges_m[..5].iter().all(|r| *r == 0.0));
            for i in c - 5..=c + 5 {
                let truth = 2.0 / scan.angle_of_index_rad(i).cos();
                let r = scan.ranges_m[i] as f64;
                if r > 0.0 && (r - truth).abs() < 0.1 {
                    errors.push(r - truth);
                }
            }
        }
        assert!((scans[0].start_angle_rad.to_degrees() + 119.53125).abs() < 1e-9);
        assert!((scans[0].end_angle_rad.to_degrees() - 119.8828125).abs() < 1e-9);
        assert!(errors.len() > 2000, "{} returns", errors.len());
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let sd =
            (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        assert!(mean.abs() < 0.001, "mean {mean}");
        assert!((0.0058..0.0076).contains(&sd), "sd {sd}, expected ≈ 0.0067");
    }

    /// The plans `eval --plans fixtures/plans-heldout` measures generalisation on stay valid
    /// scenes: each loads, and every sensor in it sees a room (most beams return).
    #[test]
    fn held_out_plans_load_and_every_sensor_sees_its_room() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans-heldout");
        for name in ["shop", "office", "expo"] {
            let (infos, per_sensor) = simulate_plan(&dir.join(format!("{name}.toml")), 0.1);
            assert!(infos.len() >= 4, "{name}: {} sensors", infos.len());
            for (info, scans) in infos.iter().zip(&per_sensor) {
                let ranges: Vec<f32> = scans.iter().flat_map(|s| s.ranges_m.clone()).collect();
                let returns = ranges.iter().filter(|r| **r > 0.0).count();
                assert!(
                    !ranges.is_empty() && returns * 2 > ranges.len(),
                    "{name}/{}: {returns} of {} beams return",
                    info.id,
                    ranges.len()
                );
            }
        }
    }

    /// Every sensor's scans over `seconds` of the plan at `path` (seed 1).
    fn simulate_plan(path: &std::path::Path, seconds: f64) -> (Vec<SensorInfo>, Vec<Vec<Scan>>) {
        let plan = Plan::load(path).unwrap();
        let mut s = Simulation::new(&plan, 1).unwrap();
        let infos = s.sensors().to_vec();
        let mut per_sensor: Vec<Vec<Scan>> = vec![Vec::new(); infos.len()];
        s.run(seconds, |i, scan| {
            per_sensor[i].push(scan);
            Ok::<(), ()>(())
        })
        .unwrap();
        (infos, per_sensor)
    }

    #[test]
    fn hall_fixture_scans_look_like_hokuyo_data() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans/hall.toml");
        let (infos, per_sensor) = simulate_plan(&path, 2.0);
        for (info, scans) in infos.iter().zip(&per_sensor) {
            let g = info.geometry.unwrap();
            let expected = (2.0 / g.period_s()) as usize;
            assert!(
                scans.len() + 1 >= expected && scans.len() <= expected,
                "{}: {} scans",
                info.id,
                scans.len()
            );
            let beams = scans.len() * g.step_count();
            let returns = scans
                .iter()
                .flat_map(|s| &s.ranges_m)
                .filter(|r| **r > 0.0)
                .count();
            let share = returns as f64 / beams as f64;
            assert!(
                (0.75..0.995).contains(&share),
                "{}: {share} of beams return",
                info.id
            );
            let mut intensities: Vec<f32> = scans
                .iter()
                .flat_map(|s| s.ranges_m.iter().zip(&s.intensities))
                .filter(|(r, _)| **r > 0.0)
                .map(|(_, i)| *i)
                .collect();
            if info.model == "UTM-30LX-EW" {
                intensities.sort_by(f32::total_cmp);
                let median = intensities[intensities.len() / 2];
                assert!(
                    (800.0..4000.0).contains(&median),
                    "{}: median intensity {median}",
                    info.id
                );
            } else {
                assert!(
                    intensities.is_empty(),
                    "{}: UXM sends no intensities by default",
                    info.id
                );
            }
        }
        // The tilted unit, 2.5 m up and pitched 20° down, sees the floor 7.31 m ahead.
        let tilt = infos.iter().position(|i| i.id == "tilt").unwrap();
        let g = ScanGeometry::UXM_30LX_E;
        let mut fronts: Vec<f64> = per_sensor[tilt]
            .iter()
            .map(|s| front(s, &g) as f64)
            .filter(|r| *r > 0.0)
            .collect();
        fronts.sort_by(f64::total_cmp);
        let median = fronts[fronts.len() / 2];
        assert!(
            (median - 2.5 / 20f64.to_radians().sin()).abs() < 0.01,
            "tilt front median {median}"
        );
    }
}
