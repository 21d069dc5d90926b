//! Time to place each unit among people (issue 16): sites where walls alone leave units
//! unplaced are simulated (`target/bench-data/`, cached), and their scans fed in stamp order to
//! the daemon's registration worker core ([`Registrar`], default `[registration]`: 30 s
//! motion buffer, tries at about 1, 6, 16 and 36 s, then every 30 s, and the 5 s walker check
//! that withdraws contradicted poses), as `scanfuse replay --max` would. Every timer runs on
//! stream time, so the figures do not depend on the machine. Per unit it prints when it was
//! first placed (stream s), when people first came within its 30 m reach, its error against
//! the truth, and withdrawals; per site, the compute each try took. Targets: every unit placed
//! within 30 s of stream time once people walk, none ever wrong (> 10 cm or > 1°).
//!
//! Sites (`fixtures/plans-walkers/`): `periodic-corridor` (2 units, pilasters every 6 m, people
//! from ~8 s), `corridor-8` (8 units along 120 m, pilasters every 6 m, 6 people from the start; the lead's site).
//!
//! Run: `cargo bench --bench daemon_walkers` (`SCANFUSE_BENCH_REC_S`, default 60: seconds
//! recorded).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant, SystemTime};

use scanfuse::daemon::pipeline_register::Verdict;
use scanfuse::geometry::{Pose2, pose_error, pose2};
use scanfuse::record::{self, Recording};

type Error = Box<dyn std::error::Error>;

/// A unit's reach (m): people farther from it are not walking for it.
const REACH_M: f64 = 30.0;
/// A placement further off than this is wrong.
const WRONG_M: f64 = 0.10;
const WRONG_DEG: f64 = 1.0;

/// Simulates `plan` for `seconds` into the bench cache (once per plan and length).
fn recording(plan: &str, seconds: f64) -> Result<PathBuf, Error> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target/bench-data");
    std::fs::create_dir_all(&dir)?;
    let out = dir.join(format!("walkers-{plan}-{seconds:.0}s.mcap"));
    if !out.exists() {
        let status = Command::new(env!("CARGO_BIN_EXE_scanfuse"))
            .arg("simulate")
            .arg("--plan")
            .arg(root.join(format!("fixtures/plans-walkers/{plan}.toml")))
            .args(["--seconds", &seconds.to_string(), "--out"])
            .arg(&out)
            .status()?;
        if !status.success() {
            return Err(format!("simulating {plan} failed").into());
        }
    }
    Ok(out)
}

fn truth(rec: &Recording, id: &str) -> Option<Pose2> {
    rec.sensor(id)
        .and_then(|s| s.truth)
        .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()))
}

/// What happened to one unit.
#[derive(Default)]
struct Unit {
    walk_s: Option<f64>,
    placed_s: Option<f64>,
    error: Option<(f64, f64)>,
    wrong: usize,
    withdrawn: usize,
}

fn site(plan: &str, seconds: f64) -> Result<(usize, usize, usize), Error> {
    let path = recording(plan, seconds)?;
    let rec = record::read(&path)?;
    let anchor = rec.sensors.first().ok_or("no sensors")?.id.clone();
    let start_ns = rec.first_stamp_ns().ok_or("no scans")?;
    let stream_s = |ns: u64| ns.saturating_sub(start_ns) as f64 / 1e9;
    let people = record::read_truth_people(&path)?;
    let mut units: Vec<(String, Unit)> = Vec::new();
    for info in &rec.sensors {
        let at = truth(&rec, &info.id).ok_or("no truth")?;
        let walk_s = people
            .iter()
            .find(|f| {
                f.people.iter().any(|q| {
                    (at.translation.vector - nalgebra::Vector2::new(q.x_m, q.y_m)).norm() < REACH_M
                })
            })
            .map(|f| stream_s(f.t_ns));
        units.push((
            info.id.clone(),
            Unit {
                walk_s,
                ..Unit::default()
            },
        ));
    }
    let world_from_anchor = truth(&rec, &anchor).ok_or("no anchor truth")?;

    let (mut r, items) = common::registrar_fed(&rec, &anchor);
    let mut tries: Vec<(f64, Duration)> = Vec::new();
    for item in items {
        let now = item.scan.stamp_ns;
        r.push(item);
        if r.due(now) {
            let started = Instant::now();
            let outcomes = r.register(now, SystemTime::UNIX_EPOCH + Duration::from_nanos(now));
            tries.push((stream_s(now), started.elapsed()));
            for o in outcomes {
                let (Ok(entry), Some((_, unit))) =
                    (o.pose, units.iter_mut().find(|(id, _)| *id == o.id))
                else {
                    continue;
                };
                let truth = world_from_anchor.inverse() * truth(&rec, &o.id).ok_or("no truth")?;
                let (dt, dyaw) = pose_error(&entry.site_from_sensor.planar(), &truth);
                if dt > WRONG_M || dyaw.to_degrees() > WRONG_DEG {
                    unit.wrong += 1;
                }
                unit.placed_s.get_or_insert(stream_s(now));
                unit.error = Some((dt, dyaw.to_degrees()));
            }
        }
        if r.check_due(now) {
            for v in r.check(now) {
                if let Verdict::Withdrawn { id, .. } = v
                    && let Some((_, unit)) = units.iter_mut().find(|(u, _)| *u == id)
                {
                    unit.withdrawn += 1;
                }
            }
        }
    }

    println!(
        "\n== {plan}: {} units, {seconds:.0} s recorded, anchor {anchor} ==",
        units.len()
    );
    println!(
        "unit      people in reach s   placed at s   after people s   error cm / °   wrong  withdrawn"
    );
    let (mut placed, mut wrong, mut late) = (0, 0, 0);
    for (id, u) in &units {
        let fmt = |v: Option<f64>| v.map_or("—".to_string(), |s| format!("{s:.1}"));
        // The anchor is placed by definition, people or not.
        let after = match (u.placed_s, u.walk_s) {
            (Some(p), Some(w)) if *id != anchor => Some(p - w),
            _ => None,
        };
        let error = u.error.map_or("—".to_string(), |(m, d)| {
            format!("{:.1} / {d:.2}", m * 100.0)
        });
        println!(
            "{id:<9} {:>17} {:>13} {:>16} {:>14} {:>7} {:>10}",
            fmt(u.walk_s),
            fmt(u.placed_s),
            fmt(after),
            error,
            u.wrong,
            u.withdrawn
        );
        placed += usize::from(u.placed_s.is_some());
        wrong += u.wrong;
        late += usize::from(after.is_some_and(|a| a > 30.0) || u.placed_s.is_none());
    }
    let compute: Vec<String> = tries
        .iter()
        .map(|(s, d)| format!("{s:.1} s: {:.0} ms", d.as_secs_f64() * 1e3))
        .collect();
    println!("tries (stream time: compute): {}", compute.join(", "));
    println!(
        "placed {placed}/{}, wrong placements {wrong}, unplaced or placed > 30 s after people walked: {late}",
        units.len()
    );
    Ok((placed, wrong, late))
}

fn main() -> Result<(), Error> {
    let seconds: f64 = std::env::var("SCANFUSE_BENCH_REC_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    for plan in ["periodic-corridor", "corridor-8"] {
        site(plan, seconds)?;
    }
    Ok(())
}
