//! Moved-sensor refresh on the fixtures, through the registration worker's core
//! ([`Registrar`]) fed the recordings' scans in time order: on `moved`, `bench` is found moved
//! and re-registered within 10 cm / 1° of its pose after the move, within 2 s of stream time,
//! by local refinement from its old pose (and, with the local search bounded below the move,
//! by the global search against its neighbours, the others' poses standing, after local
//! refinement is refused);
//! on `lab` and `hall` (played twice over), no sensor is ever called moved.

use std::time::{Duration, SystemTime};

use scanfuse::daemon::config::RegistrationConfig;
use scanfuse::daemon::pipeline_register::{Command, Method, Registrar, WorkItem};
use scanfuse::daemon::protocol::PoseSource;
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record::{self, Recording};

fn fixture(name: &str) -> Recording {
    record::read(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures")
            .join(name),
    )
    .unwrap()
}

/// Every scan of the recording as a work item, in stamp order; `passes` plays it again with
/// stamps shifted by its length (as the looping emulator does).
fn items(rec: &Recording, passes: u64) -> Vec<WorkItem> {
    let first = rec.first_stamp_ns().unwrap();
    let last = rec
        .scans
        .values()
        .filter_map(|s| s.last())
        .map(|s| s.stamp_ns)
        .max()
        .unwrap();
    let length = last - first + 25_000_000;
    let mut out = Vec::new();
    for pass in 0..passes {
        for info in &rec.sensors {
            for scan in rec.scans_of(&info.id) {
                let mut scan = scan.clone();
                scan.stamp_ns += pass * length;
                out.push(WorkItem {
                    sensor: info.id.clone(),
                    scan,
                    geometry: info.geometry,
                });
            }
        }
    }
    out.sort_by_key(|i| i.scan.stamp_ns);
    out
}

fn registrar(rec: &Recording, anchor: &str) -> Registrar {
    registrar_with(rec, anchor, &RegistrationConfig::default())
}

fn registrar_with(rec: &Recording, anchor: &str, config: &RegistrationConfig) -> Registrar {
    let mut r = Registrar::new(anchor, config);
    for info in &rec.sensors {
        r.command(
            Command::Add {
                id: info.id.clone(),
                mount: info.mount(),
                survey: None,
                pose: None,
                sigma: None,
            },
            0,
        );
    }
    r
}

/// Feeds everything; registers whenever due. Returns the moved events and, per
/// registration, the stamp it ran at and its outcomes.
fn play(
    r: &mut Registrar,
    items: Vec<WorkItem>,
) -> (
    Vec<scanfuse::daemon::pipeline_register::Moved>,
    Vec<(u64, Vec<scanfuse::daemon::pipeline_register::Outcome>)>,
) {
    let mut moved = Vec::new();
    let mut runs = Vec::new();
    for item in items {
        let now = item.scan.stamp_ns;
        if let Some(m) = r.push(item) {
            moved.push(m);
        }
        if r.due(now) {
            let when = SystemTime::UNIX_EPOCH + Duration::from_nanos(now);
            let started = std::time::Instant::now();
            let outcomes = r.register(now, when);
            println!(
                "registration at {:.2} s of stream: {:.0} ms of compute",
                now as f64 / 1e9,
                started.elapsed().as_secs_f64() * 1e3
            );
            runs.push((now, outcomes));
        }
    }
    (moved, runs)
}

/// Plays `moved` and checks the move is found and bench re-registered within target; returns
/// how its new pose was found and why local refinement was refused, if it was.
fn knocked(config: &RegistrationConfig) -> (Method, Option<String>) {
    let rec = fixture("moved.mcap");
    let anchor = "entrance";
    let mut r = registrar_with(&rec, anchor, config);
    let (moved, runs) = play(&mut r, items(&rec, 1));
    assert_eq!(moved.len(), 1, "{moved:?}");
    assert_eq!(moved[0].id, "bench");
    let the_move = rec
        .moves
        .iter()
        .find(|m| m.sensor_id == "bench")
        .expect("move truth");
    assert!(
        moved[0].since_ns >= the_move.at_ns,
        "the change began after the move"
    );

    // First run: everyone; second run: bench again.
    assert_eq!(runs.len(), 2, "{runs:?}");
    let (at_ns, outcomes) = &runs[1];
    let latency_s = at_ns.saturating_sub(the_move.at_ns) as f64 / 1e9;
    assert!(
        latency_s <= 2.0,
        "new pose {latency_s:.2} s of stream time after the move"
    );
    assert_eq!(outcomes.len(), 1);
    let bench = outcomes[0].pose.as_ref().expect("bench re-registered");
    assert_eq!(bench.source, PoseSource::ReRegistered);
    let truth_of = |x: f64, y: f64, yaw_deg: f64| pose2(x, y, yaw_deg.to_radians());
    let world_from_anchor = {
        let t = rec.sensor(anchor).and_then(|s| s.truth).unwrap();
        truth_of(t.x_m, t.y_m, t.yaw_deg)
    };
    let p = the_move.pose;
    let truth = world_from_anchor.inverse() * truth_of(p.x_m, p.y_m, p.yaw_deg);
    let (err_m, err_rad) = pose_error(&bench.site_from_sensor.planar(), &truth);
    assert!(
        err_m < 0.10 && err_rad.abs().to_degrees() < 1.0,
        "bench after the move: {err_m:.3} m, {:.2}°",
        err_rad.to_degrees()
    );
    println!(
        "bench: {:?} ({:?}), {latency_s:.2} s after the move, {err_m:.3} m, {:.2}°",
        outcomes[0].method,
        outcomes[0].local_refused,
        err_rad.to_degrees()
    );
    (outcomes[0].method, outcomes[0].local_refused.clone())
}

#[test]
fn a_knocked_sensor_is_found_moved_and_refined_locally_within_target() {
    let (method, refused) = knocked(&RegistrationConfig::default());
    assert_eq!(
        method,
        Method::Local,
        "local refinement refused: {refused:?}"
    );
}

#[test]
fn a_move_beyond_the_local_search_falls_back_to_the_global_search_within_target() {
    // bench moved 0.5 m and 10°; a local search of 10 cm / 2° cannot reach that.
    let config = RegistrationConfig {
        refine_radius_m: 0.1,
        refine_yaw_deg: 2.0,
        ..RegistrationConfig::default()
    };
    let (method, refused) = knocked(&config);
    // Against its neighbours, the placed site standing: not the whole site again.
    assert_eq!(method, Method::Added);
    assert!(refused.is_some(), "local refinement was tried first");
}

#[test]
fn no_sensor_is_called_moved_on_fixtures_without_a_move() {
    for (name, anchor) in [("lab.mcap", "entrance"), ("hall.mcap", "gate")] {
        let rec = fixture(name);
        let mut r = registrar(&rec, anchor);
        let (moved, runs) = play(&mut r, items(&rec, 2));
        assert!(moved.is_empty(), "{name}: {moved:?}");
        assert_eq!(runs.len(), 1, "{name}: registered once");
    }
}
