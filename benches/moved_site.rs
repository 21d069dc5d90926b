//! A moved sensor's refresh in a site of a hundred (issue 20; target ≤ 2 s of stream time, as
//! in a site of five). A simulated concourse of `SCANFUSE_BENCH_SENSORS` scanners (default 100,
//! `sim::generate`, seed 1, 30 people walking) in which one sensor near the middle is knocked
//! by `SCANFUSE_BENCH_KNOCK` (`dx,dy,dyaw_deg`, default `0.3,0.1,4`: local refinement's case;
//! `1.5,0.5,25` is the global search's) `SCANFUSE_BENCH_MOVE_S` s in (default 8), recorded
//! for 4 s more (cached under `target/bench-data/`). Its scans are fed in stamp order to the
//! registration worker's core (`Registrar`), which registers whenever it is due, as the
//! daemon's worker does. It prints each registration's stream time and compute time, when the move was noticed, how
//! long after the move the new pose came (stream time: what the target is stated in; the
//! daemon adds that registration's compute), its error against the simulator's truth, and any
//! sensor called moved that was not.
//!
//! Run: `cargo bench --bench moved_site` (`SCANFUSE_BIN` picks the binary that simulates).

mod common;

use std::time::{Duration, Instant, SystemTime};

use scanfuse::geometry::{Pose2, pose_error, pose2};
use scanfuse::record::Recording;
use scanfuse::sim::Move;
use scanfuse::sim::generate::{FloorSpec, concourse};

type Error = Box<dyn std::error::Error>;

/// The knock from `SCANFUSE_BENCH_KNOCK`, or one small enough for local refinement.
fn knock() -> Result<(f64, f64, f64), Error> {
    let text = std::env::var("SCANFUSE_BENCH_KNOCK").unwrap_or_else(|_| "0.3,0.1,4".into());
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("SCANFUSE_BENCH_KNOCK={text}: {e} (want dx,dy,dyaw_deg)"))?;
    match v[..] {
        [dx, dy, dyaw] => Ok((dx, dy, dyaw)),
        _ => Err(format!("SCANFUSE_BENCH_KNOCK={text}: want three numbers, dx,dy,dyaw_deg").into()),
    }
}

/// Seconds recorded after the knock.
const AFTER_S: f64 = 4.0;

fn main() -> Result<(), Error> {
    let n = common::env_f64("SCANFUSE_BENCH_SENSORS", 100.0) as usize;
    let move_s = common::env_f64("SCANFUSE_BENCH_MOVE_S", 8.0);
    let bin = std::env::var("SCANFUSE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_scanfuse").to_string());
    let knock = knock()?;
    let rec = recording(&bin, n, move_s, knock)?;
    let the_move = rec.moves.first().ok_or("the recording has no move")?;
    println!(
        "moved_site: a concourse of {n} sensors, 30 people; {} knocked {:.1} m, {:.1} m, {:.0}° at {move_s} s",
        the_move.sensor_id, knock.0, knock.1, knock.2
    );

    let anchor = rec.sensors.first().ok_or("no sensors")?.id.clone();
    let (mut registrar, items) = common::registrar_fed(&rec, &anchor);
    let start_ns = items.first().map_or(0, |i| i.scan.stamp_ns);
    let stream_s = |ns: u64| ns.saturating_sub(start_ns) as f64 / 1e9;

    let mut noticed = Vec::new();
    let mut refreshed = None;
    for item in items {
        let now = item.scan.stamp_ns;
        if let Some(m) = registrar.push(item) {
            println!(
                "  {:.2} s: {} called moved ({:.0} % of its static view changed)",
                stream_s(now),
                m.id,
                m.fraction * 100.0
            );
            noticed.push((m.id, now));
        }
        if !registrar.due(now) {
            continue;
        }
        let started = Instant::now();
        let outcomes = registrar.register(now, SystemTime::UNIX_EPOCH + Duration::from_nanos(now));
        let compute_ms = started.elapsed().as_secs_f64() * 1e3;
        let placed = outcomes.iter().filter(|o| o.pose.is_ok()).count();
        println!(
            "  {:.2} s: registration of {} sensors, {placed} placed, {compute_ms:.0} ms of compute",
            stream_s(now),
            outcomes.len()
        );
        if now < the_move.at_ns {
            continue;
        }
        if let Some(o) = outcomes.iter().find(|o| o.id == the_move.sensor_id)
            && let Ok(pose) = &o.pose
            && refreshed.is_none()
        {
            refreshed = Some((now, pose.site_from_sensor.planar(), compute_ms, o.method));
        }
    }

    let truth = |x: f64, y: f64, yaw_deg: f64| pose2(x, y, yaw_deg.to_radians());
    let anchor_truth = rec
        .sensor(&anchor)
        .and_then(|s| s.truth)
        .ok_or("the anchor has no truth")?;
    let site_from_world: Pose2 =
        truth(anchor_truth.x_m, anchor_truth.y_m, anchor_truth.yaw_deg).inverse();
    let p = the_move.pose;
    let moved_truth = site_from_world * truth(p.x_m, p.y_m, p.yaw_deg);
    let false_alarms: Vec<&String> = noticed
        .iter()
        .map(|(id, _)| id)
        .filter(|id| **id != the_move.sensor_id)
        .collect();
    match noticed.iter().find(|(id, _)| *id == the_move.sensor_id) {
        Some((_, at)) => println!(
            "  the move noticed {:.2} s after it",
            at.saturating_sub(the_move.at_ns) as f64 / 1e9
        ),
        None => println!("  the move was NOT noticed"),
    }
    match refreshed {
        Some((at, pose, compute_ms, method)) => {
            let (err_m, err_rad) = pose_error(&pose, &moved_truth);
            println!(
                "  new pose ({method:?}) {:.2} s of stream time after the move (target ≤ 2 s), its registration {compute_ms:.0} ms of compute; {:.1} cm, {:.2}° from the truth",
                at.saturating_sub(the_move.at_ns) as f64 / 1e9,
                err_m * 100.0,
                err_rad.to_degrees().abs()
            );
        }
        None => println!("  NO new pose for {} by the end", the_move.sensor_id),
    }
    println!(
        "  other sensors called moved: {}",
        if false_alarms.is_empty() {
            "none".to_string()
        } else {
            format!("{false_alarms:?}")
        }
    );
    Ok(())
}

/// The concourse with its knock, simulated once and kept.
fn recording(
    bin: &str,
    n: usize,
    move_s: f64,
    (dx, dy, dyaw_deg): (f64, f64, f64),
) -> Result<Recording, Error> {
    let dir = common::bench_data()?;
    let name = format!("concourse-{n}-moved-{dx}-{dy}-{dyaw_deg}-at-{move_s}s");
    let path = dir.join(format!("{name}-crowd30-seed1.mcap"));
    if !path.exists() {
        let mut plan = concourse(FloorSpec { sensors: n }, 1, 30)?;
        let id = plan
            .sensors
            .get(plan.sensors.len() / 2)
            .ok_or("no sensors")?
            .id
            .clone();
        plan.moves.push(Move {
            line: None,
            sensor: id,
            at_s: move_s,
            dx,
            dy,
            dyaw_deg,
        });
        let plan_path = dir.join(format!("{name}.toml"));
        std::fs::write(&plan_path, plan.to_toml()?)?;
        let plan_arg = plan_path.to_string_lossy();
        common::simulate_once(bin, &["--plan", &plan_arg], move_s + AFTER_S, &path)?;
    }
    Ok(scanfuse::record::read(&path)?)
}
