//! How fast the simulator makes data: a minute of the 5-sensor hall (3 UTM + 2 UXM, four
//! people), scans streamed to a sink that only counts them. Prints the figures.
//!
//! Run: `cargo bench --bench sim_speed` (optionally `-- <plan.toml> <seconds>`).

use std::path::PathBuf;
use std::time::Instant;

use scanfuse::sim::{Plan, Simulation};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let plan_path = args.first().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans/hall.toml")
    });
    let seconds: f64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(60.0);

    let plan = Plan::load(&plan_path)?;
    let started = Instant::now();
    let mut sim = Simulation::new(&plan, 1)?;
    let mut scans = 0u64;
    let mut beams = 0u64;
    let mut returns = 0u64;
    sim.run(seconds, |_, scan| {
        scans += 1;
        beams += scan.ranges_m.len() as u64;
        returns += scan.ranges_m.iter().filter(|r| **r > 0.0).count() as u64;
        Ok::<(), std::convert::Infallible>(())
    })?;
    let wall_s = started.elapsed().as_secs_f64();
    println!(
        "sim_speed: {} ({} sensors, {} people), {seconds} s simulated in {wall_s:.2} s wall ({:.1}× real time)",
        plan_path.display(),
        plan.sensors.len(),
        plan.people.len(),
        seconds / wall_s
    );
    println!(
        "sim_speed: {scans} scans, {beams} beams ({:.1} M beams/s), {:.1} % returns",
        beams as f64 / wall_s / 1e6,
        100.0 * returns as f64 / beams.max(1) as f64
    );
    Ok(())
}
