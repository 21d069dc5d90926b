//! Moved-sensor refresh through the live daemon (`scanfuse run`), asserted over the real
//! status socket. A longer `moved` recording is simulated into a temp dir (the lab, `bench`
//! knocked 0.5 m / 10° at [`MOVE_AT_S`]), served by the daemon's `replay:` emulators at 1×:
//! - a `moved` event for bench, and its refreshed pose within 10 cm / 1° of the truth after the
//!   move, published within 2 s of stream time after the move (the time is measured from the
//!   last `status` poll whose scan count of bench was still before the move, so polling can
//!   only make the figure worse);
//! - on the `hall` fixture (looped), no `moved` event at all.
//!
//! The 2 s target is asserted against a release daemon (`cargo test --release`, or
//! `SCANFUSE_BIN=target/release/scanfuse cargo test --test integration daemon_run_moved_live`,
//! with a release build there): it measured 1.0 s. The daemon plain `cargo test` builds (opt-
//! level 1 with debug assertions; `Cargo.toml`) measured 1.07 s run alone, and
//! at opt-level 0 it measured 1.96–2.86 s on a loaded 2-core machine: there the
//! test asserts [`DEBUG_BOUND_S`] instead — still far below a fall-back to the global search
//! (15 s unoptimized) — and prints the figure either way.

use crate::daemon_run_common;

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::Command;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use daemon_run_common::*;
use scanfuse::daemon::protocol::{Event, EventKind, Message, PoseSource};
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record;

/// Stream time of the knock; the daemon registers everyone well before it.
const MOVE_AT_S: f64 = 30.0;
const RECORD_S: f64 = 36.0;
/// The target: the new pose within this long of stream time after the move.
const TARGET_S: f64 = 2.0;
/// The bound asserted against an unoptimized daemon (see the module doc).
const DEBUG_BOUND_S: f64 = 6.0;

const LAB: [(&str, &str); 4] = [
    ("entrance", "height_m = 1.05"),
    ("bench", "height_m = 1.2"),
    ("north", "height_m = 1.0"),
    ("east", "height_m = 1.1"),
];

/// A second connection that watches events; each arrives with the time it was read.
fn watch_events(socket: &Path) -> mpsc::Receiver<(Instant, Event)> {
    let stream = UnixStream::connect(socket).expect("connect the watcher");
    let mut writer = stream.try_clone().expect("clone");
    writer
        .write_all(b"{\"cmd\":\"watch\",\"status\":true,\"map\":false}\n")
        .expect("watch");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _keep = writer;
        let mut reader = BufReader::new(stream);
        let mut line = String::new();
        loop {
            line.clear();
            match reader.read_line(&mut line) {
                Ok(0) | Err(_) => return,
                Ok(_) => {
                    if let Ok(Message::Event(e)) = serde_json::from_str::<Message>(&line)
                        && tx.send((Instant::now(), e)).is_err()
                    {
                        return;
                    }
                }
            }
        }
    });
    rx
}

fn simulate_moved(dir: &Path) -> std::path::PathBuf {
    let plan = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans/moved.toml"),
    )
    .expect("moved plan");
    assert!(
        plan.contains("at_s = 1.0"),
        "the plan's move is where the test expects it"
    );
    let plan = plan.replace("at_s = 1.0", &format!("at_s = {MOVE_AT_S:?}"));
    let plan_path = dir.join("moved-long.toml");
    std::fs::write(&plan_path, plan).expect("write plan");
    let out = dir.join("moved-long.mcap");
    let status = Command::new(bin())
        .args(["simulate", "--plan"])
        .arg(&plan_path)
        .args(["--seconds", &RECORD_S.to_string(), "--seed", "1", "--out"])
        .arg(&out)
        .status()
        .expect("scanfuse simulate runs");
    assert!(status.success(), "simulate failed");
    out
}

#[test]
fn a_knocked_sensor_is_refreshed_live_within_two_seconds_of_stream_time() {
    let dir = tempfile::tempdir().unwrap();
    let file = simulate_moved(dir.path());
    let rec = record::read(&file).unwrap();
    let the_move = rec
        .moves
        .iter()
        .find(|m| m.sensor_id == "bench")
        .expect("move truth");
    let bench_scans = rec.scans_of("bench");
    let first_ns = bench_scans.first().expect("scans").stamp_ns;
    // bench's scans before the move: once its driver has counted more, the move is in.
    let before_move = bench_scans
        .iter()
        .take_while(|s| s.stamp_ns < the_move.at_ns)
        .count() as u64;
    assert!(
        (the_move.at_ns - first_ns) as f64 / 1e9 > MOVE_AT_S - 0.5,
        "the move is {MOVE_AT_S} s in"
    );

    let sensors = replay_sensors(&file, &LAB);
    let config = write_config(dir.path(), "entrance", &sensors, "save_interval_s = 0");
    let _daemon = start_daemon(&config, dir.path());
    let socket = dir.path().join("s.sock");
    let mut client = Client::connect(&socket, Duration::from_secs(30));
    let events_rx = watch_events(&socket);

    let truth_of = |x: f64, y: f64, yaw_deg: f64| pose2(x, y, yaw_deg.to_radians());
    let world_from_anchor = {
        let t = rec.sensor("entrance").and_then(|s| s.truth).unwrap();
        truth_of(t.x_m, t.y_m, t.yaw_deg)
    };
    let after = {
        let p = the_move.pose;
        world_from_anchor.inverse() * truth_of(p.x_m, p.y_m, p.yaw_deg)
    };

    // Poll bench's scan count and pose until the refreshed pose is there.
    let started = Instant::now();
    let mut registered_before_move = false;
    let mut first_registered = None;
    let mut last_before_move: Option<Instant> = None;
    let refreshed = loop {
        assert!(
            started.elapsed() < Duration::from_secs(90),
            "no refreshed pose for bench; daemon log: {}",
            std::fs::read_to_string(dir.path().join("daemon.log")).unwrap_or_default()
        );
        let polled = Instant::now();
        let status = client.status();
        let scans = status
            .sensors
            .iter()
            .find(|s| s.id == "bench")
            .map_or(0, |s| s.scans);
        let poses = client.poses();
        let bench = poses
            .sensors
            .iter()
            .find(|p| p.id == "bench")
            .expect("bench in poses")
            .clone();
        if bench.registered && first_registered.is_none() {
            first_registered = Some((started.elapsed(), scans, bench.source));
        }
        if scans <= before_move {
            last_before_move = Some(polled);
            registered_before_move |= bench.registered;
        } else if bench.registered && bench.source == Some(PoseSource::ReRegistered) {
            break (Instant::now(), bench);
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(
        registered_before_move,
        "bench was registered before the move (else there is nothing to refresh); it was first registered (after, scans, source) {first_registered:?}, the move is after scan {before_move}; daemon log: {}",
        std::fs::read_to_string(dir.path().join("daemon.log")).unwrap_or_default()
    );
    let (seen_at, bench) = refreshed;
    let move_seen_by = last_before_move.expect("polled before the move");
    let latency_s = seen_at.duration_since(move_seen_by).as_secs_f64();

    let est = pose2(
        bench.x_m.unwrap(),
        bench.y_m.unwrap(),
        bench.yaw_deg.unwrap().to_radians(),
    );
    let (err_m, err_rad) = pose_error(&est, &after);
    // The event travels on the watch stream, apart from the poses reply: give it a moment.
    let mut events: Vec<(Instant, Event)> = events_rx.try_iter().collect();
    let is_refresh =
        |e: &Event| e.kind == EventKind::ReRegistered && e.sensor.as_deref() == Some("bench");
    let patience = Instant::now() + Duration::from_secs(5);
    while !events.iter().any(|(_, e)| is_refresh(e)) {
        let Some(left) = patience.checked_duration_since(Instant::now()) else {
            break;
        };
        match events_rx.recv_timeout(left) {
            Ok(event) => events.push(event),
            Err(_) => break,
        }
    }
    let moved: Vec<&Event> = events
        .iter()
        .map(|(_, e)| e)
        .filter(|e| e.kind == EventKind::Moved)
        .collect();
    let refresh = events.iter().map(|(_, e)| e).find(|e| is_refresh(e));
    println!(
        "bench refreshed {latency_s:.2} s of stream time after the move (target {TARGET_S} s), {err_m:.3} m / {:.2}° from truth; {}",
        err_rad.to_degrees(),
        refresh.map_or("no re-registered event", |e| e.message.as_str())
    );
    assert_eq!(moved.len(), 1, "{moved:?}");
    assert_eq!(moved[0].sensor.as_deref(), Some("bench"));
    assert!(refresh.is_some(), "a re-registered event for bench");
    assert!(
        err_m < 0.10 && err_rad.to_degrees() < 1.0,
        "bench after the move: {err_m:.3} m, {:.2}°",
        err_rad.to_degrees()
    );
    let optimized = std::env::var_os("SCANFUSE_BIN").is_some() || !cfg!(debug_assertions);
    let bound_s = if optimized { TARGET_S } else { DEBUG_BOUND_S };
    assert!(
        latency_s <= bound_s,
        "refreshed {latency_s:.2} s after the move; bound {bound_s} s ({}; the target is {TARGET_S} s)",
        if optimized {
            "optimized daemon"
        } else {
            "unoptimized debug daemon"
        }
    );
}

#[test]
fn no_sensor_is_called_moved_live_on_the_hall() {
    let dir = tempfile::tempdir().unwrap();
    let hall = fixture("hall.mcap");
    let sensors = replay_sensors(&hall, &HALL);
    let config = write_config(dir.path(), "gate", &sensors, "save_interval_s = 0");
    let _daemon = start_daemon(&config, dir.path());
    let socket = dir.path().join("s.sock");
    let mut client = Client::connect(&socket, Duration::from_secs(30));
    let events = watch_events(&socket);
    wait_for(Duration::from_secs(120), "every sensor registered", || {
        client
            .poses()
            .sensors
            .iter()
            .all(|p| p.registered)
            .then_some(())
    });
    // Ten more seconds: the 2 s fixture looped five times, people and all.
    std::thread::sleep(Duration::from_secs(10));
    let status = client.status();
    assert!(
        status.sensors.iter().all(|s| s.scans > 150),
        "everyone streamed: {:?}",
        status.sensors.iter().map(|s| s.scans).collect::<Vec<_>>()
    );
    let all: Vec<Event> = events.try_iter().map(|(_, e)| e).collect();
    let moved: Vec<&Event> = all.iter().filter(|e| e.kind == EventKind::Moved).collect();
    assert!(moved.is_empty(), "{moved:?}");
    assert!(
        all.iter().any(|e| e.kind == EventKind::Registered),
        "the watcher saw the registration: {all:?}"
    );
}
