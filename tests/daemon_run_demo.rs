//! The daemon (`scanfuse run`) on the demo site: the five `hall` sensors replayed through
//! in-process emulators. Over the real status socket: every sensor streams and is registered
//! within 10 cm / 1° of the recording's truth; `save` and SIGTERM leave whole map files; a
//! restart takes the saved poses without registering again.

use crate::daemon_run_common;

use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::protocol::{Message, PoseSource, SensorState};
use scanfuse::daemon::state::PosesFile;
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record;

#[test]
fn the_demo_site_streams_registers_to_truth_and_saves_whole_files() {
    let dir = tempfile::tempdir().unwrap();
    let hall = fixture("hall.mcap");
    let sensors = replay_sensors(&hall, &HALL);
    let config = write_config(dir.path(), "gate", &sensors, "save_interval_s = 2.0");
    let mut daemon = start_daemon(&config, dir.path());
    let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));

    let poses = wait_for(Duration::from_secs(120), "every sensor registered", || {
        let poses = client.poses();
        poses.sensors.iter().all(|p| p.registered).then_some(poses)
    });
    let status = client.status();
    assert_eq!(status.sensors.len(), 5);
    for s in &status.sensors {
        assert_eq!(s.state, SensorState::Streaming, "{s:?}");
        assert!(s.rate_hz.is_some_and(|hz| hz > 10.0), "{s:?}");
        assert!(
            s.model.as_deref().is_some_and(|m| m.starts_with("U")),
            "{s:?}"
        );
    }

    let recording = record::read(&hall).unwrap();
    let truth = |id: &str| {
        let t = recording.sensor(id).and_then(|s| s.truth).expect("truth");
        pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
    };
    assert_eq!(poses.anchor, "gate");
    for p in &poses.sensors {
        let est = pose2(
            p.x_m.unwrap(),
            p.y_m.unwrap(),
            p.yaw_deg.unwrap().to_radians(),
        );
        let (err_m, err_rad) = pose_error(&est, &(truth("gate").inverse() * truth(&p.id)));
        assert!(
            err_m < 0.10 && err_rad.abs().to_degrees() < 1.0,
            "{}: {err_m:.3} m, {:.2}°",
            p.id,
            err_rad.to_degrees()
        );
        assert_eq!(p.source, Some(PoseSource::Registered));
        assert!(p.age_s.is_some_and(|a| a >= 0.0));
    }

    // The grid integrates at map_rate_hz: a save the instant the last pose lands may find
    // nothing fused yet, and then writes the poses alone, as it says.
    let saved = wait_for(
        Duration::from_secs(10),
        "a save with the map files",
        || match client.request(r#"{"cmd":"save"}"#) {
            Message::Saved(saved) => saved.files.iter().any(|f| f == "map.pgm").then_some(saved),
            other => panic!("save answered {other:?}"),
        },
    );
    for f in ["poses.toml", "map.pgm", "map.yaml", "map.ply"] {
        assert!(saved.files.iter().any(|s| s == f), "{saved:?}");
    }
    let state = dir.path().join("state");
    check_map_files(&state);

    daemon.signal("TERM");
    assert!(daemon.wait_exit(Duration::from_secs(30)).success());
    check_map_files(&state);
    let saved = PosesFile::load(&state).unwrap().expect("poses.toml");
    assert_eq!(saved.sensors.len(), 5);
    assert!(
        saved
            .sensors
            .iter()
            .all(|s| s.registered && s.source == Some(PoseSource::Registered))
    );
    assert!(
        !dir.path().join("s.sock").exists(),
        "the socket file is removed on exit"
    );

    // A restart on the same state takes the saved poses at once.
    let mut daemon = start_daemon(&config, dir.path());
    let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));
    let poses = client.poses();
    assert!(
        poses
            .sensors
            .iter()
            .all(|p| p.registered && p.source == Some(PoseSource::Saved)),
        "{poses:?}"
    );
    daemon.signal("TERM");
    assert!(daemon.wait_exit(Duration::from_secs(30)).success());
}

#[test]
fn a_replay_writes_poses_and_map_files_to_its_folder() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let output = std::process::Command::new(bin())
        .arg("replay")
        .arg(fixture("lab.mcap"))
        .args(["--speed", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        stdout.contains("poses in the frame of \"entrance\""),
        "{stdout}"
    );
    let saved = PosesFile::load(&out).unwrap().expect("poses.toml");
    assert_eq!(saved.anchor, "entrance");
    assert_eq!(saved.sensors.len(), 4);
    assert!(saved.sensors.iter().all(|s| s.registered), "{saved:?}");
    check_map_files(&out);
}

#[test]
fn a_replay_of_a_missing_file_is_bad_input() {
    let output = std::process::Command::new(bin())
        .args(["replay", "/nonexistent/x.mcap"])
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
}
