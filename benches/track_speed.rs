//! What the people tracker costs (issue 18): 8 sensors at 40 Hz (all UTM-30LX-EW) in the
//! 32 × 20 m hall of `fixtures/plans-crowd/hall40.toml` plus two units on the side walls, with a
//! crowd of 100. The scans are simulated first (not timed), then fed to the tracker core in
//! stamp order, one thread, as the daemon's tracker thread does. Prints the figures: CPU time
//! per second of scans (target < 15 % of one core) and the time from a scan into
//! [`Tracker::push`] to the `TRACKS` it yields, p50 / p99 (target p99 ≤ 5 ms).
//!
//! The latency is the tracker core's only: the socket, JSON and the 25 ms the tracker waits
//! for a step's scans are not in it.
//!
//! Run: `cargo bench --bench track_speed` (optionally `-- <seconds> <people> [low]`; default
//! 10 s, 100 people). `low` mounts every unit at 0.3 m: they see legs, and each leg goes to
//! the track it lies nearest (`tracker::legs_to_tracks`, an assignment per unit and step).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use scanfuse::features::persistent_view;
use scanfuse::geometry::{Mount, Pose2, pose2};
use scanfuse::scan::Scan;
use scanfuse::sim::{Model, Plan, SensorPlan, Simulation};
use scanfuse::track::score::variant;
use scanfuse::track::{SensorScan, TrackParams, Tracker};

/// Scans before this (s) are fed but not timed: the crowd's tracks are being born.
const WARMUP_S: f64 = 1.0;

/// This thread's CPU time (Linux: `/proc/thread-self/schedstat`, first field, ns).
fn thread_cpu() -> Option<Duration> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = s.split_whitespace().next()?.parse().ok()?;
    Some(Duration::from_nanos(ns))
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let seconds: f64 = args.first().map(|s| s.parse()).transpose()?.unwrap_or(10.0);
    let people: u32 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let low = args.get(2).is_some_and(|a| a == "low");

    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans-crowd/hall40.toml");
    let mut plan: Plan = variant(&Plan::load(&path)?, None, Some(people));
    for s in &mut plan.sensors {
        s.model = Model::Utm30lxEw;
    }
    let side = |id: &str, x: f64, y: f64, yaw_deg: f64| -> Option<SensorPlan> {
        let mut s = plan.sensors.first()?.clone();
        s.id = id.into();
        s.x = x;
        s.y = y;
        s.yaw_deg = yaw_deg;
        Some(s)
    };
    let extra: Vec<SensorPlan> = [side("w", 0.6, 9.5, 0.0), side("e", 31.4, 5.0, 180.0)]
        .into_iter()
        .flatten()
        .collect();
    plan.sensors.extend(extra);
    if low {
        for s in &mut plan.sensors {
            s.height_m = 0.3;
            s.pitch_deg = 0.0;
        }
    }
    plan.name = format!(
        "{}+2 ×{people}{}",
        plan.name,
        if low { ", units at 0.3 m (legs)" } else { "" }
    );

    // The scans, simulated up front.
    let sim_started = Instant::now();
    let mut sim = Simulation::new(&plan, 1)?;
    let infos = sim.sensors().to_vec();
    let mut scans: Vec<(usize, Scan)> = Vec::new();
    sim.run(seconds, |i, scan| {
        scans.push((i, scan));
        Ok::<(), std::convert::Infallible>(())
    })?;
    scans.sort_by_key(|(_, s)| s.stamp_ns);
    let sim_s = sim_started.elapsed().as_secs_f64();
    let start_ns = scans.first().map_or(0, |(_, s)| s.stamp_ns);
    let warm_ns = start_ns + (WARMUP_S * 1e9) as u64;

    let params = TrackParams::default();
    let mounts: Vec<Mount> = infos.iter().map(|i| i.mount()).collect();
    let poses: Vec<Option<Pose2>> = infos
        .iter()
        .map(|i| i.truth.map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())))
        .collect();
    let mut tracker = Tracker::new(params.clone());
    // The background as learnt while the hall was empty (as `track::score` seeds it).
    let mut empty = plan.clone();
    empty.crowds.clear();
    empty.people.clear();
    empty.queues.clear();
    empty.truth_people = Some(false);
    let mut seed: Vec<Vec<Scan>> = vec![Vec::new(); infos.len()];
    Simulation::new(&empty, 1)?.run(1.0, |i, scan| {
        if let Some(v) = seed.get_mut(i) {
            v.push(scan);
        }
        Ok::<(), std::convert::Infallible>(())
    })?;
    for (i, info) in infos.iter().enumerate() {
        if let Some(view) = persistent_view(&seed[i], 1.0, 0.15, 0.05) {
            let ranges =
                Tracker::horizontal_ranges(&view, info.geometry.as_ref(), &mounts[i], &params);
            tracker.seed_background(&info.id, ranges);
        }
    }

    let mut busy = Duration::ZERO;
    let mut cpu = Duration::ZERO;
    let mut yielding: Vec<Duration> = Vec::new();
    let mut all: Vec<Duration> = Vec::new();
    let mut tracks_sum = 0usize;
    let mut most_tracks = 0usize;
    let mut timed_scans = 0usize;
    for (i, scan) in &scans {
        let timed = scan.stamp_ns >= warm_ns;
        let cpu0 = if timed { thread_cpu() } else { None };
        let t0 = Instant::now();
        let out = tracker.push(SensorScan {
            id: &infos[*i].id,
            scan,
            geometry: infos[*i].geometry.as_ref(),
            mount: mounts[*i],
            site_from_sensor: poses[*i],
        });
        let took = t0.elapsed();
        if !timed {
            continue;
        }
        if let (Some(a), Some(b)) = (cpu0, thread_cpu()) {
            cpu += b.saturating_sub(a);
        }
        busy += took;
        timed_scans += 1;
        all.push(took);
        if let Some(out) = out {
            yielding.push(took);
            tracks_sum += out.tracks.len();
            most_tracks = most_tracks.max(out.tracks.len());
        }
    }
    yielding.sort();
    all.sort();
    let span_s = (seconds - WARMUP_S).max(1e-9);
    let steps = yielding.len().max(1);

    println!(
        "track_speed: {} ({} sensors at 40 Hz, {people} people), {seconds} s of scans simulated in {sim_s:.1} s; timed after {WARMUP_S} s",
        plan.name,
        infos.len()
    );
    println!(
        "track_speed: {timed_scans} scans, {} fused steps, confirmed tracks mean {:.1}, most {most_tracks}",
        yielding.len(),
        tracks_sum as f64 / steps as f64
    );
    println!("{:<44} {:>10} {:>10}", "figure", "value", "target");
    println!(
        "{:<44} {:>9.1}% {:>10}",
        "wall time in push per second of scans",
        100.0 * busy.as_secs_f64() / span_s,
        "< 15 %"
    );
    println!(
        "{:<44} {:>9.1}% {:>10}",
        "CPU time (thread) per second of scans",
        100.0 * cpu.as_secs_f64() / span_s,
        "< 15 %"
    );
    println!(
        "{:<44} {:>8.3}ms {:>10}",
        "scan in → TRACKS out, p50",
        ms(percentile(&yielding, 0.5)),
        ""
    );
    println!(
        "{:<44} {:>8.3}ms {:>10}",
        "scan in → TRACKS out, p99",
        ms(percentile(&yielding, 0.99)),
        "≤ 5 ms"
    );
    println!(
        "{:<44} {:>8.3}ms {:>10}",
        "scan in → TRACKS out, max",
        ms(yielding.last().copied().unwrap_or_default()),
        ""
    );
    println!(
        "{:<44} {:>8.3}ms {:>10}",
        "any push (scan only, no step), p99",
        ms(percentile(&all, 0.99)),
        ""
    );
    Ok(())
}
