//! `scanfuse eval --only crowd`: sites registered through a crowd (issue 16). Each crowd plan
//! named in [`PLANS`] (under `--track-plans`, default `fixtures/plans-crowd`) is simulated for
//! [`SECONDS`] with its crowd walking throughout, and again with no one in it; every sensor is
//! prepared as `scanfuse register` prepares it (static view through the crowd, the walkers it
//! saw) and the site registered, anchored at its first sensor. Printed per plan: units placed,
//! within 10 cm / 1° of the truth, and wrong, crowded against empty. Target: as many placed as
//! empty, none wrong.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::register::RegisterParams;
use scanfuse::register::site::{SensorInput, SiteParams, register_site};
use scanfuse::scan::Scan;
use scanfuse::sim::{Plan, Simulation};

use super::super::register::prepare_sensor;

/// The crowd plans scored (20 and 40 people in a hall, 20 in a shop).
const PLANS: [&str; 3] = ["hall20", "hall40", "shop20"];
/// Seconds simulated: `register` watches the first 30 s.
const SECONDS: f64 = 30.0;
const TOL_M: f64 = 0.10;
const TOL_DEG: f64 = 1.0;

/// Placed, right, wrong, sensors, ms.
type Tally = (usize, usize, usize, usize, u128);

/// Registers `plan` as `register` would; what it placed, against the truth.
fn register_plan(plan: &Plan, seed: u64, params: &RegisterParams) -> Result<Tally> {
    let mut sim = Simulation::new(plan, seed).with_context(|| format!("plan {}", plan.name))?;
    let infos = sim.sensors().to_vec();
    let mut scans: Vec<Vec<Scan>> = vec![Vec::new(); infos.len()];
    sim.run(SECONDS, |i, scan| {
        if let Some(v) = scans.get_mut(i) {
            v.push(scan);
        }
        Ok::<(), std::convert::Infallible>(())
    })
    .ok();
    let started = Instant::now();
    let inputs: Vec<SensorInput> = infos
        .iter()
        .zip(&scans)
        .filter_map(|(info, scans)| prepare_sensor(info, scans, false, params))
        .collect();
    let site = register_site(&inputs, 0, params, &SiteParams::default());
    let ms = started.elapsed().as_millis();
    let truth = |id: &str| {
        infos
            .iter()
            .find(|i| i.id == id)
            .and_then(|i| i.truth)
            .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()))
    };
    let anchor = inputs
        .first()
        .and_then(|s| truth(&s.id))
        .context("the anchor has no truth")?;
    let (mut placed, mut right, mut wrong) = (0, 0, 0);
    for s in &site.sensors {
        let (Ok(p), Some(t)) = (&s.pose, truth(&s.id)) else {
            continue;
        };
        placed += 1;
        let (dt, dyaw) = pose_error(&p.pose.planar(), &(anchor.inverse() * t));
        if dt <= TOL_M && dyaw.to_degrees() <= TOL_DEG {
            right += 1;
        } else {
            wrong += 1;
        }
    }
    Ok((placed, right, wrong, infos.len(), ms))
}

pub(super) fn run(plans_dir: &Path, seed: u64, params: &RegisterParams) -> Result<()> {
    println!(
        "\n== Sites through a crowd ({plans_dir}, {SECONDS:.0} s, seed {seed}; as `register`: static view through the crowd, walkers): placed / within 10 cm & 1° / wrong, crowded vs the same site empty ==",
        plans_dir = plans_dir.display()
    );
    println!(
        "{:<10} {:>7} {:>7}   {:>7} {:>6} {:>6}   {:>7} {:>6} {:>6}   {:>8}",
        "plan", "people", "units", "placed", "right", "wrong", "empty", "right", "wrong", "ms"
    );
    let (mut crowd_total, mut empty_total) = ((0, 0, 0), (0, 0, 0));
    for name in PLANS {
        let path = plans_dir.join(format!("{name}.toml"));
        let plan = Plan::load(&path).with_context(|| path.display().to_string())?;
        let people: u32 = plan.crowds.iter().map(|c| c.people).sum::<u32>()
            + plan.queues.iter().map(|q| q.people).sum::<u32>()
            + plan.people.len() as u32;
        let mut empty = plan.clone();
        empty.crowds.clear();
        empty.queues.clear();
        empty.people.clear();
        let c = register_plan(&plan, seed, params)?;
        let e = register_plan(&empty, seed, params)?;
        println!(
            "{name:<10} {people:>7} {:>7}   {:>7} {:>6} {:>6}   {:>7} {:>6} {:>6}   {:>8}",
            c.3, c.0, c.1, c.2, e.0, e.1, e.2, c.4
        );
        crowd_total = (
            crowd_total.0 + c.0,
            crowd_total.1 + c.1,
            crowd_total.2 + c.2,
        );
        empty_total = (
            empty_total.0 + e.0,
            empty_total.1 + e.1,
            empty_total.2 + e.2,
        );
    }
    println!(
        "all: crowded {} placed, {} right, {} wrong; empty {} placed, {} right, {} wrong",
        crowd_total.0, crowd_total.1, crowd_total.2, empty_total.0, empty_total.1, empty_total.2
    );
    Ok(())
}
