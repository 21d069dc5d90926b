//! The daemon against failures, with real processes: `scanfuse emulate` units over TCP and
//! `scanfuse run`. An emulator killed mid-stream → that sensor shows disconnected while the
//! others keep their rates, and it reconnects when the emulator returns. Kills during saves
//! leave `poses.toml` whole (the old or the new file, never a partial one). A stopping daemon
//! stops every laser (QT) before it closes the links. A unit that cannot stream (a mode it
//! lacks, a fault reboots do not clear) shows `failed` with the reason, the others stream on;
//! one that returns nothing is named as blind, on the socket and as its registration reason.

use crate::daemon_run_common;

use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::protocol::SensorState;
use scanfuse::daemon::state::PosesFile;

const LAB: [&str; 4] = ["entrance", "bench", "north", "east"];

#[test]
fn a_killed_emulator_disconnects_one_sensor_only_and_it_reconnects() {
    let dir = tempfile::tempdir().unwrap();
    let lab = fixture("lab.mcap");
    let mut emulators = Vec::new();
    let mut sensors = Vec::new();
    for id in LAB {
        let log = dir.path().join(format!("{id}.emulator.log"));
        let (proc, addr) = start_emulator_logged(&lab, id, "127.0.0.1:0", Some(&log));
        sensors.push((id, format!("tcp://{addr}"), ""));
        emulators.push((proc, addr));
    }
    let config = write_config(dir.path(), "entrance", &sensors, "save_interval_s = 0");
    let mut daemon = start_daemon(&config, dir.path());
    let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));
    let rate_of = |status: &scanfuse::daemon::protocol::Status, id: &str| {
        status.sensors.iter().find(|s| s.id == id).and_then(|s| {
            (s.state == SensorState::Streaming)
                .then_some(s.rate_hz)
                .flatten()
        })
    };
    wait_for(
        Duration::from_secs(30),
        "all four streaming at ~40 Hz",
        || {
            let status = client.status();
            LAB.iter()
                .all(|id| rate_of(&status, id).is_some_and(|hz| hz > 30.0))
                .then_some(())
        },
    );

    // Kill `north`'s emulator (SIGKILL: no goodbye on the wire).
    let (north, north_addr) = emulators.remove(2);
    drop(north);
    let status = wait_for(Duration::from_secs(15), "north disconnected", || {
        let status = client.status();
        let north = status.sensors.iter().find(|s| s.id == "north")?;
        (north.state == SensorState::Disconnected).then_some(status)
    });
    let north = status.sensors.iter().find(|s| s.id == "north").unwrap();
    assert!(north.last_error.is_some(), "{north:?}");
    // The others keep streaming at their rate while north is down (sampled a few times).
    for _ in 0..5 {
        let status = client.status();
        for id in ["entrance", "bench", "east"] {
            let hz = rate_of(&status, id);
            assert!(hz.is_some_and(|hz| hz > 30.0), "{id}: {hz:?}");
        }
        std::thread::sleep(Duration::from_millis(300));
    }

    // The emulator returns on the same port; the driver reconnects by itself.
    let (_north_again, _) = start_emulator(&lab, "north", &north_addr);
    let north = wait_for(Duration::from_secs(30), "north streaming again", || {
        let status = client.status();
        let north = status.sensors.iter().find(|s| s.id == "north")?.clone();
        (north.state == SensorState::Streaming && north.rate_hz.is_some_and(|hz| hz > 30.0))
            .then_some(north)
    });
    assert!(north.reconnects >= 1, "{north:?}");
    daemon.signal("TERM");
    assert!(daemon.wait_exit(Duration::from_secs(30)).success());
    // On the way out every driver stopped its laser (QT) before closing.
    for id in ["entrance", "bench", "east"] {
        let log = std::fs::read_to_string(dir.path().join(format!("{id}.emulator.log"))).unwrap();
        assert!(
            log.contains("QT while streaming"),
            "{id}'s emulator never saw the laser stopped:\n{log}"
        );
    }
}

#[test]
fn kills_during_saves_leave_poses_toml_old_or_new_never_partial() {
    let dir = tempfile::tempdir().unwrap();
    let lab = fixture("lab.mcap");
    let sensors: Vec<(&str, String, &str)> = LAB
        .iter()
        .map(|id| (*id, format!("replay:{}#{id}", lab.display()), ""))
        .collect();
    // Saves every second, and a client asks for more as fast as they are answered, so
    // signals land during writes.
    let config = write_config(dir.path(), "entrance", &sensors, "save_interval_s = 1");
    let state = dir.path().join("state");
    let mut replaced = 0;
    for (round, signal) in ["TERM", "KILL", "TERM", "KILL", "KILL"].iter().enumerate() {
        let mut daemon = start_daemon(&config, dir.path());
        let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));
        // The first round waits for poses; later rounds start from the saved ones.
        wait_for(Duration::from_secs(120), "poses", || {
            let all = client.poses().sensors.iter().all(|p| p.registered);
            (all && state.join("poses.toml").exists()).then_some(())
        });
        // Inode numbers are reused at once, so the write time tells files apart too.
        let inode = |path: &std::path::Path| {
            let meta = std::fs::metadata(path).unwrap();
            (
                std::os::unix::fs::MetadataExt::ino(&meta),
                meta.modified().unwrap(),
            )
        };
        let before = inode(&state.join("poses.toml"));
        let hammer = std::thread::spawn({
            let socket = dir.path().join("s.sock");
            move || save_until_gone(&socket)
        });
        std::thread::sleep(Duration::from_millis(300 + 137 * round as u64));
        daemon.signal(signal);
        daemon.wait_exit(Duration::from_secs(30));
        let saves = hammer.join().unwrap();
        assert!(saves > 0, "round {round}: no save was answered");
        let text = std::fs::read_to_string(state.join("poses.toml")).unwrap();
        let file = PosesFile::parse(&text, &state.join("poses.toml"))
            .unwrap_or_else(|e| panic!("round {round} ({signal}): {e}\n{text}"));
        assert_eq!(file.sensors.len(), 4);
        // Every save renames a fresh file into place.
        if inode(&state.join("poses.toml")) != before {
            replaced += 1;
        }
        let _ = std::fs::remove_file(dir.path().join("s.sock"));
    }
    assert!(
        replaced >= 4,
        "poses.toml was replaced in only {replaced} of 5 rounds"
    );
}

#[test]
fn units_that_cannot_stream_show_failed_with_the_reason_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let lab = fixture("lab.mcap");
    let (_entrance, entrance) = start_emulator(&lab, "entrance", "127.0.0.1:0");
    // bench has no multi-echo but is configured for ND; north stays in its abnormal state (0L).
    let (_bench, bench) =
        start_emulator_faulty(&lab, "bench", "127.0.0.1:0", None, &["--no-multi-echo"]);
    let never = u32::MAX.to_string();
    let (_north, north) = start_emulator_faulty(
        &lab,
        "north",
        "127.0.0.1:0",
        None,
        &["--abnormal-until-reboots", &never],
    );
    // east streams, but not a single beam returns (a covered lens).
    let (_east, east) = start_emulator_faulty(&lab, "east", "127.0.0.1:0", None, &["--no-returns"]);
    let sensors = [
        ("entrance", format!("tcp://{entrance}"), ""),
        ("bench", format!("tcp://{bench}"), "mode = \"ND\""),
        ("north", format!("tcp://{north}"), ""),
        ("east", format!("tcp://{east}"), ""),
    ];
    let config = write_config(dir.path(), "entrance", &sensors, "save_interval_s = 0");
    let mut daemon = start_daemon(&config, dir.path());
    let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));
    let sensor = |client: &mut Client, id: &str| {
        let status = client.status();
        status.sensors.into_iter().find(|s| s.id == id)
    };
    // While north is retried, the socket names its state.
    let named = wait_for(Duration::from_secs(30), "north's state named", || {
        sensor(&mut client, "north")?.last_error
    });
    assert!(named.contains("abnormal state (0L)"), "{named}");
    let bench = wait_for(Duration::from_secs(30), "bench failed", || {
        sensor(&mut client, "bench").filter(|s| s.state == SensorState::Failed)
    });
    assert!(
        bench.last_error.as_deref().is_some_and(
            |e| e.contains("answers 0E to ND: it has no multi-echo mode; use MD or ME")
        ),
        "{bench:?}"
    );
    assert_eq!(bench.reconnects, 0, "{bench:?}");
    // A unit that sees nothing is named, on the socket and as its registration reason.
    let east = wait_for(Duration::from_secs(30), "east named blind", || {
        sensor(&mut client, "east").filter(|s| s.warning.is_some())
    });
    assert_eq!(east.state, SensorState::Streaming, "{east:?}");
    assert_eq!(east.valid_returns, Some(0.0), "{east:?}");
    let blind = "it sees almost nothing: 0 % of its beams return";
    assert!(
        east.warning
            .as_deref()
            .is_some_and(|w| w.starts_with(blind)),
        "{east:?}"
    );
    let east_pose = client
        .poses()
        .sensors
        .into_iter()
        .find(|p| p.id == "east")
        .unwrap();
    assert!(!east_pose.registered, "{east_pose:?}");
    assert!(
        east_pose
            .reason
            .as_deref()
            .is_some_and(|r| r.starts_with(blind)),
        "{east_pose:?}"
    );
    // Three connections per reboot, two reboots, then it is given up (backoff up to 10 s).
    let north = wait_for(Duration::from_secs(120), "north failed", || {
        sensor(&mut client, "north").filter(|s| s.state == SensorState::Failed)
    });
    let error = north.last_error.unwrap_or_default();
    assert!(
        error.contains("abnormal state (0L), still after 2 reboots: power-cycle the unit"),
        "{error}"
    );
    let entrance = sensor(&mut client, "entrance").unwrap();
    assert_eq!(entrance.state, SensorState::Streaming, "{entrance:?}");
    daemon.signal("TERM");
    assert!(daemon.wait_exit(Duration::from_secs(30)).success());
}

/// Sends `save` requests back to back until the daemon goes away; returns how many were
/// answered.
fn save_until_gone(socket: &std::path::Path) -> usize {
    use std::io::{BufRead, BufReader, Write};
    let Ok(mut stream) = std::os::unix::net::UnixStream::connect(socket) else {
        return 0;
    };
    let Ok(read_half) = stream.try_clone() else {
        return 0;
    };
    let mut reader = BufReader::new(read_half);
    let mut line = String::new();
    let mut answered = 0;
    // The VERSION banner first.
    if reader.read_line(&mut line).unwrap_or(0) == 0 {
        return 0;
    }
    loop {
        if stream.write_all(b"{\"cmd\":\"save\"}\n").is_err() {
            return answered;
        }
        line.clear();
        match reader.read_line(&mut line) {
            Ok(n) if n > 0 && line.contains("SAVED") => answered += 1,
            _ => return answered,
        }
    }
}
