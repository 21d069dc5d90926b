//! `scanfuse simulate --plan P.toml --seconds S --seed N --out X.mcap`: a floor plan, its
//! sensors and people, ray-cast into a recording with ground truth. `--generate concourse:N`
//! makes the plan instead (`sim::generate`), and `--plan-out` writes it as TOML.

use std::path::PathBuf;

use anyhow::Context as _;
use scanfuse::record::{self, RecordingWriter};
use scanfuse::sim::generate::{FloorSpec, concourse};
use scanfuse::sim::{Plan, SimEvent, Simulation};

use super::BadInput;

#[derive(clap::Args)]
pub struct Args {
    /// Floor plan (TOML), e.g. fixtures/plans/lab.toml.
    #[arg(
        long,
        required_unless_present = "generate",
        conflicts_with = "generate"
    )]
    plan: Option<PathBuf>,
    /// Generate the floor instead: `concourse:N`, a concourse with N scanners (2–500) installed,
    /// drawn from --seed.
    #[arg(long)]
    generate: Option<FloorSpec>,
    /// With --generate: people walking the concourse, in and out through the gates (0–100).
    #[arg(long, default_value_t = 0, requires = "generate")]
    crowd: u32,
    /// With --generate: also write the plan made (TOML, as --plan reads it) to this file.
    #[arg(long, requires = "generate")]
    plan_out: Option<PathBuf>,
    /// Simulated time to record, s.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Random seed: the same plan and seed give the same recording, bit for bit.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Recording to write (MCAP); may be left out when --plan-out is given.
    #[arg(long, required_unless_present = "plan_out")]
    out: Option<PathBuf>,
    /// zstd level, 1–22: higher is smaller and slower (fixtures use 19).
    #[arg(long, default_value_t = record::DEFAULT_ZSTD_LEVEL)]
    zstd_level: u32,
}

/// Longest simulation accepted: an hour is already ~5 GB of scans for a large site.
const MAX_SECONDS: f64 = 3600.0;

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.seconds > 0.0 && args.seconds <= MAX_SECONDS) {
        return Err(BadInput(format!(
            "--seconds {} is out of range: give a duration above 0 and at most {MAX_SECONDS}",
            args.seconds
        ))
        .into());
    }
    let (plan, source) = match (&args.plan, args.generate) {
        (Some(path), _) => (Plan::load(path)?, path.display().to_string()),
        (None, Some(spec)) => {
            let plan =
                concourse(spec, args.seed, args.crowd).map_err(|e| BadInput(e.to_string()))?;
            if let Some(path) = &args.plan_out {
                let text = plan.to_toml()?;
                std::fs::write(path, text)
                    .with_context(|| format!("{}: cannot write the plan", path.display()))?;
                println!(
                    "{}: {} ({} scanners, seed {})",
                    path.display(),
                    plan.name,
                    plan.sensors.len(),
                    args.seed
                );
            }
            let source = plan.origin.clone();
            (plan, source)
        }
        (None, None) => {
            return Err(BadInput("give --plan P.toml or --generate concourse:N".into()).into());
        }
    };
    let Some(out_path) = &args.out else {
        return Ok(());
    };
    let mut sim = Simulation::new(&plan, args.seed)?;
    let mut out = RecordingWriter::create_with_level(out_path, args.zstd_level)?;
    let sensors = sim.sensors().to_vec();
    for sensor in &sensors {
        out.add_sensor(sensor)?;
    }
    for moved in sim.moves() {
        out.add_move(moved)?;
    }
    let mut scans = 0usize;
    let mut next_report_s = 10.0;
    let mut first_ns = None;
    let mut truths = 0usize;
    sim.run_with_truth(args.seconds, |event| {
        let (index, scan) = match event {
            SimEvent::Scan(index, scan) => (index, scan),
            SimEvent::People(people) => {
                out.write_people_truth(&people)?;
                truths += 1;
                return anyhow::Ok(());
            }
        };
        let sensor = sensors.get(index).with_context(|| {
            format!("the simulator produced a scan for unknown sensor #{index}")
        })?;
        let t0 = *first_ns.get_or_insert(scan.stamp_ns);
        let t = scan.stamp_ns.saturating_sub(t0) as f64 * 1e-9;
        if t >= next_report_s {
            tracing::info!("simulated {t:.0} of {} s", args.seconds);
            next_report_s += 10.0;
        }
        out.write_scan(&sensor.id, &scan)?;
        scans += 1;
        anyhow::Ok(())
    })?;
    out.finish()?;
    let bytes = std::fs::metadata(out_path).map(|m| m.len()).unwrap_or(0);
    let truth = if truths > 0 {
        format!(
            ", {truths} people's truth messages on {}",
            record::PEOPLE_TRUTH_TOPIC
        )
    } else {
        String::new()
    };
    println!(
        "{}: {} sensors, {} scans{truth}, {} s simulated from {} (seed {}), {} bytes",
        out_path.display(),
        sensors.len(),
        scans,
        args.seconds,
        source,
        args.seed,
        bytes
    );
    Ok(())
}
