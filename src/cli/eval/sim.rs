//! Simulated pairs and sites for `scanfuse eval`: random placements in the floor plans of `--plans`,
//! simulated for a moment with people walking, each sensor's static view prepared.

use super::site::{SiteTotals, solve_site};
use super::{Args, BINS, Case, Floor, bin_of};
use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::features::static_view;
use scanfuse::geometry::{Pose2, pose2, raycast};
use scanfuse::register::site::SensorInput;
use scanfuse::register::{RegisterParams, ScanModel};
use scanfuse::scan::{Scan, SensorInfo};
use scanfuse::sim::generate::{FloorSpec, concourse};
use scanfuse::sim::plan::{Model, Plan, SensorPlan};
use scanfuse::sim::{Simulation, view_overlap};

/// Every plan (`*.toml`) in `dir`, by file name. Plans that move a sensor mid-run are scenes
/// for the daemon's move tests (`moved.toml` is the lab with a knock), not places to draw
/// sensors in: eval draws its own, so those are left out, and says so.
pub(super) fn load_plans(dir: &std::path::Path) -> Result<Vec<Plan>> {
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list the plans", dir.display()))?;
    let mut paths = Vec::new();
    for entry in entries {
        let path = entry
            .with_context(|| format!("{}: cannot list the plans", dir.display()))?
            .path();
        if path.extension().is_some_and(|e| e == "toml") {
            paths.push(path);
        }
    }
    paths.sort();
    let mut plans = Vec::new();
    for path in paths {
        let plan = Plan::load(&path)
            .with_context(|| format!("{}: cannot load the plan", path.display()))?;
        if plan.moves.is_empty() {
            plans.push(plan);
        } else {
            eprintln!(
                "eval: leaving out {}: it moves a sensor mid-run (eval draws its own sensors)",
                path.display()
            );
        }
    }
    if plans.is_empty() {
        anyhow::bail!(
            "{}: no floor plans (*.toml without [[move]]) to draw sensors in",
            dir.display()
        );
    }
    Ok(plans)
}

/// The models of `--models`, once each, in [`Model::ALL`]'s order: the order given on the
/// command line does not change the draw.
pub(super) fn model_mix(models: &[Model]) -> Vec<Model> {
    Model::ALL
        .into_iter()
        .filter(|m| models.contains(m))
        .collect()
}

/// How often a model is drawn, relative to the others in the mix: the UTM is the common unit.
fn weight(model: Model) -> u32 {
    match model {
        Model::Utm30lxEw => 7,
        Model::Uxm30lxE | Model::Urg04lx => 3,
    }
}

/// One of `models`, by [`weight`]: a Bernoulli draw per model but the last, each for its share
/// of the weight left. For the default UTM + UXM that is the single `random_bool(0.7)` eval
/// drew before `--models`, so a seed gives the same pairs as it did; a lone model draws nothing.
fn random_model(models: &[Model], rng: &mut ChaCha8Rng) -> Model {
    let mix = model_mix(models);
    let mut left: u32 = mix.iter().map(|m| weight(*m)).sum();
    for (i, model) in mix.iter().enumerate() {
        let w = weight(*model);
        if i + 1 == mix.len() || rng.random_bool(f64::from(w) / f64::from(left)) {
            return *model;
        }
        left -= w;
    }
    // Only for an empty list, which clap does not let through (`--models` needs a name).
    Model::Utm30lxEw
}

/// A random sensor inside `plan` (`enclosed`): a model from `models`, one in five tilted like a
/// ceiling unit.
fn random_sensor(
    plan: &Plan,
    id: &str,
    near: Option<(f64, f64)>,
    models: &[Model],
    rng: &mut ChaCha8Rng,
) -> SensorPlan {
    let (mut lo, mut hi) = (
        (f64::INFINITY, f64::INFINITY),
        (f64::NEG_INFINITY, f64::NEG_INFINITY),
    );
    for w in &plan.walls {
        for p in &w.points {
            lo = (lo.0.min(p[0]), lo.1.min(p[1]));
            hi = (hi.0.max(p[0]), hi.1.max(p[1]));
        }
    }
    let walls = wall_segments(plan);
    let mut draw = || match near {
        Some((x0, y0)) => {
            let d = rng.random_range(2.0..12.0);
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            (x0 + d * a.cos(), y0 + d * a.sin())
        }
        None => (rng.random_range(lo.0..hi.0), rng.random_range(lo.1..hi.1)),
    };
    let mut spot = draw();
    for _ in 0..100 {
        if enclosed(&walls, spot) {
            break;
        }
        spot = draw();
    }
    let (x, y) = spot;
    let model = random_model(models, rng);
    let tilted = rng.random_bool(0.2);
    SensorPlan {
        line: None,
        id: id.to_string(),
        model,
        x,
        y,
        yaw_deg: rng.random_range(-180.0..180.0),
        height_m: if tilted {
            rng.random_range(2.0..2.6)
        } else {
            rng.random_range(0.8..1.5)
        },
        pitch_deg: if tilted {
            -rng.random_range(8.0..20.0)
        } else {
            0.0
        },
        intensities: None,
    }
}

/// Every wall of `plan` as 2D segments (doors ignored: a wall with a door still encloses).
pub(super) fn wall_segments(plan: &Plan) -> Vec<raycast::Wall> {
    plan.walls
        .iter()
        .flat_map(|w| w.segments())
        .map(|(a, b)| raycast::Wall::new(a[0], a[1], b[0], b[1]))
        .collect()
}

/// Walls stand on all four sides of `(x, y)`: a spot inside the building, where an installer
/// mounts units, not the street beyond a shop front or a corridor glimpsed through a door
/// (those are in the plan to be seen, and widen its bounds).
fn enclosed(walls: &[raycast::Wall], (x, y): (f64, f64)) -> bool {
    let at = nalgebra::Point2::new(x, y);
    [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
        .iter()
        .all(|&(dx, dy)| raycast::cast(walls, at, nalgebra::Vector2::new(dx, dy)).is_some())
}

/// The simulated sensors as a site's inputs, with no prior.
pub(super) fn site_inputs(models: Vec<(SensorInfo, ScanModel)>) -> Vec<SensorInput> {
    models
        .into_iter()
        .map(|(info, model)| SensorInput {
            id: info.id.clone(),
            mount: info.mount(),
            model,
            prior: None,
        })
        .collect()
}

/// A drawn placement's sensors with their models, or why the draw was refused.
pub(super) type Drawn = std::result::Result<Vec<(SensorInfo, ScanModel)>, String>;

/// Simulates `plan` and prepares every sensor's static view (over the first `SIM_SECONDS`)
/// and the people it saw walk (over `motion_seconds`, when longer); refused, saying which
/// sensor, when one stands somewhere useless (inside furniture, outside the building).
pub(super) fn simulate_models(
    plan: &Plan,
    seed: u64,
    motion_seconds: f64,
    params: &RegisterParams,
) -> Result<Drawn> {
    // A placement the simulator refuses (inside furniture, in a wall) is simply not drawn.
    let mut sim = match Simulation::new(plan, seed) {
        Ok(sim) => sim,
        Err(e) => return Ok(Err(format!("the simulator refused it: {e}"))),
    };
    let infos: Vec<SensorInfo> = sim.sensors().to_vec();
    let mut scans: Vec<Vec<Scan>> = vec![Vec::new(); infos.len()];
    sim.run(SIM_SECONDS.max(motion_seconds), |i, scan| {
        if let Some(v) = scans.get_mut(i) {
            v.push(scan);
        }
        Ok::<(), std::convert::Infallible>(())
    })
    .ok();
    let mut out = Vec::new();
    for (info, scans) in infos.into_iter().zip(scans) {
        let at = || match truth_pose(&info) {
            Some(pose) => describe(&info, &pose),
            None => format!("{}, no true pose", info.model),
        };
        let Some(view) = static_view(&scans, SIM_SECONDS) else {
            return Ok(Err(format!("{} ({}) gave no static view", info.id, at())));
        };
        let returns: Vec<f32> = view.ranges_m.iter().copied().filter(|r| *r > 0.0).collect();
        // Outside the building most beams of a long-range unit return nothing (a short-range
        // one may just stand in a large hall, so for it only `enclosed` decides); inside a box
        // everything is close.
        let long_range = info
            .geometry
            .is_some_and(|g| g.dmax_mm >= LONG_RANGE_DMAX_MM);
        if long_range && returns.len() * 2 < view.ranges_m.len() {
            return Ok(Err(format!(
                "{} ({}) has no return on most beams: outside the building?",
                info.id,
                at()
            )));
        }
        if returns.iter().filter(|r| **r > 1.0).count() * 2 < returns.len().max(1) {
            return Ok(Err(format!(
                "{} ({}) sees most of its returns within 1 m: boxed in?",
                info.id,
                at()
            )));
        }
        let mount = info.mount();
        let mut model = ScanModel::from_scan(&view, info.geometry.as_ref(), &mount, params);
        if motion_seconds > SIM_SECONDS {
            model = model.with_motion(&scans, &view, info.geometry.as_ref(), &mount, params);
        }
        out.push((info, model));
    }
    Ok(Ok(out))
}

/// A unit that reaches this far (DMAX, mm) sees a wall along most beams from anywhere indoors.
const LONG_RANGE_DMAX_MM: u32 = 20_000;

/// Seconds simulated per placement; the static view is the median over them.
const SIM_SECONDS: f64 = 0.5;

/// "UTM-30LX-EW at (24.2 15.6) 35° 1.2 m", with " pitched −12°" for a tilted unit: enough to
/// put the sensor back on the plan and simulate the pair again.
fn describe(info: &SensorInfo, site_from_sensor: &Pose2) -> String {
    let t = site_from_sensor.translation.vector;
    let pitch = match info.pitch_deg {
        Some(p) if p != 0.0 => format!(" pitched {p:.0}°"),
        _ => String::new(),
    };
    let height = info
        .height_m
        .map_or(String::new(), |h| format!(" {h:.1} m"));
    let yaw = site_from_sensor.rotation.angle().to_degrees();
    format!(
        "{} at ({:.1} {:.1}) {yaw:.0}°{height}{pitch}",
        info.model, t.x, t.y
    )
}

pub(super) fn truth_pose(info: &SensorInfo) -> Option<Pose2> {
    info.truth
        .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()))
}

/// Random pairs in the plans, spread over the overlap bins.
pub(super) fn sim_cases(plans: &[Plan], args: &Args, params: &RegisterParams) -> Result<Vec<Case>> {
    let count = args.pairs;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0x51a);
    let quota = count.div_ceil(BINS.len());
    let mut filled = [0usize; BINS.len()];
    let mut cases = Vec::new();
    let mut attempts = 0;
    while cases.len() < count && attempts < count * 60 {
        attempts += 1;
        let Some(base) = plans.get(rng.random_range(0..plans.len())) else {
            break;
        };
        let mut plan = base.clone();
        plan.moves.clear();
        let a = random_sensor(&plan, "a", None, &args.models, &mut rng);
        let b = random_sensor(&plan, "b", Some((a.x, a.y)), &args.models, &mut rng);
        plan.sensors = vec![a, b];
        // Overlap first (cheap): skip placements whose bin is already full.
        let Ok(overlap) = view_overlap(&plan, "a", "b", 0.1) else {
            continue;
        };
        let bin = bin_of(overlap);
        if filled[bin] >= quota {
            continue;
        }
        let Ok(models) = simulate_models(&plan, rng.random(), args.motion_seconds, params)? else {
            continue;
        };
        let [(ia, ma), (ib, mb)] = <[(SensorInfo, ScanModel); 2]>::try_from(models)
            .map_err(|_| anyhow::anyhow!("expected two sensors"))?;
        let (Some(ta), Some(tb)) = (truth_pose(&ia), truth_pose(&ib)) else {
            continue;
        };
        filled[bin] += 1;
        if cases.len() % 25 == 0 {
            eprintln!("simulated {} of {count} pairs…", cases.len());
        }
        cases.push(Case {
            label: format!(
                "{} {} → {}",
                plan.name,
                describe(&ia, &ta),
                describe(&ib, &tb)
            ),
            a: ma,
            b: mb,
            a_from_b: ta.inverse() * tb,
            overlap,
        });
    }
    Ok(cases)
}

/// How a site's sensors are drawn.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum SiteDraw {
    /// Anywhere in the plan's bounds, any heading: many share no view with any other sensor.
    Random,
    /// As an installer covers a floor: each sensor within 2–12 m of one placed before it and
    /// sharing at least `INSTALLED_OVERLAP` of its view with it (the overlap the method is
    /// promised to work at), so every sensor is reachable from the first in principle.
    Installed,
}

pub(super) const INSTALLED_OVERLAP: f64 = 0.3;

/// `n` sensors as `SiteDraw::Installed` describes, or `None` when a sensor finds no spot
/// within a few tries (the caller draws another site).
pub(super) fn installed_sensors(
    plan: &Plan,
    n: usize,
    models: &[Model],
    rng: &mut ChaCha8Rng,
) -> Option<Vec<SensorPlan>> {
    let mut trial = plan.clone();
    trial.sensors = vec![random_sensor(plan, "s0", None, models, rng)];
    for k in 1..n {
        let id = format!("s{k}");
        let placed = (0..40).find_map(|_| {
            let parent = trial.sensors[rng.random_range(0..trial.sensors.len())].clone();
            let sensor = random_sensor(plan, &id, Some((parent.x, parent.y)), models, rng);
            trial.sensors.push(sensor);
            let shared = view_overlap(&trial, &parent.id, &id, 0.1).unwrap_or(0.0);
            let sensor = trial.sensors.pop()?;
            (shared >= INSTALLED_OVERLAP).then_some(sensor)
        })?;
        trial.sensors.push(placed);
    }
    Some(trial.sensors)
}

/// Sites of `--site-sensors` sensors: the joint solve's error against truth, and its time.
pub(super) fn sites(
    plans: &[Plan],
    args: &Args,
    params: &RegisterParams,
    draw: SiteDraw,
) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(match draw {
        SiteDraw::Random => args.seed ^ 0x5173,
        SiteDraw::Installed => args.seed ^ 0x1257a11,
    });
    SiteTotals::header("≤10cm/1°");
    let mut done = 0;
    let mut attempts = 0;
    let mut totals = SiteTotals::default();
    let (count, n) = (args.sites, usize::from(args.site_sensors));
    while done < count && attempts < count * 50 {
        attempts += 1;
        let mut plan = match args.floor {
            Some(Floor::Concourse) => {
                let spec = FloorSpec { sensors: n };
                concourse(spec, args.seed.wrapping_add(attempts as u64 - 1), 0)
                    .with_context(|| format!("--floor concourse --site-sensors {n}"))?
            }
            None => match plans.get(attempts % plans.len()) {
                Some(base) => base.clone(),
                None => break,
            },
        };
        plan.moves.clear();
        plan.sensors = match draw {
            SiteDraw::Random => (0..n)
                .map(|k| random_sensor(&plan, &format!("s{k}"), None, &args.models, &mut rng))
                .collect(),
            // The generator installed them already.
            SiteDraw::Installed if args.floor.is_some() => plan.sensors.clone(),
            SiteDraw::Installed => match installed_sensors(&plan, n, &args.models, &mut rng) {
                Some(sensors) => sensors,
                None => {
                    totals.refused(format!(
                        "no way found to install {n} sensors in {} each sharing view with one already placed",
                        plan.name
                    ));
                    continue;
                }
            },
        };
        let models = match simulate_models(&plan, rng.random(), args.motion_seconds, params)? {
            Ok(models) => models,
            Err(why) => {
                totals.refused(why);
                continue;
            }
        };
        if let Some(dir) = &args.site_plans_out {
            let kind = match draw {
                SiteDraw::Random => "random",
                SiteDraw::Installed => "installed",
            };
            let path = dir.join(format!("{kind}-{}.toml", done + 1));
            let text = plan.to_toml()?;
            std::fs::create_dir_all(dir)
                .and_then(|()| std::fs::write(&path, text))
                .with_context(|| format!("--site-plans-out: writing {}", path.display()))?;
        }
        let truths: Vec<Pose2> = models.iter().filter_map(|(i, _)| truth_pose(i)).collect();
        let inputs = site_inputs(models);
        let outcome = solve_site(
            &inputs,
            &truths,
            params,
            (0.10, 1f64.to_radians()),
            args.site_compare,
            args.partners,
        );
        done += 1;
        outcome.print(done, &plan.name);
        totals.add(&outcome);
    }
    totals.print("10 cm / 1°");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default mix draws exactly as eval did before `--models` (one `random_bool(0.7)`),
    /// whatever order the models are named in, and a lone model draws nothing.
    #[test]
    fn default_mix_draws_as_before_and_a_lone_model_draws_nothing() {
        let (utm, uxm, urg) = (Model::Utm30lxEw, Model::Uxm30lxE, Model::Urg04lx);
        let mut now = ChaCha8Rng::seed_from_u64(7);
        let mut before = ChaCha8Rng::seed_from_u64(7);
        let mut swapped = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..1000 {
            let old = if before.random_bool(0.7) { utm } else { uxm };
            assert_eq!(random_model(&[utm, uxm], &mut now), old);
            assert_eq!(random_model(&[uxm, utm, uxm], &mut swapped), old);
        }
        let mut lone = ChaCha8Rng::seed_from_u64(7);
        assert_eq!(random_model(&[urg], &mut lone), urg);
        assert_eq!(
            lone.random::<u64>(),
            ChaCha8Rng::seed_from_u64(7).random::<u64>()
        );
        // All three: 7 : 3 : 3.
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let n = 13_000;
        let urgs = (0..n)
            .filter(|_| random_model(&[urg, uxm, utm], &mut rng) == urg)
            .count();
        assert!((2700..3300).contains(&urgs), "{urgs} URGs in {n}");
    }
}
