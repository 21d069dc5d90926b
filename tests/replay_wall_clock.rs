//! Replays anchored to the wall clock (`scanfuse run --replay-since`): daemons started at
//! different times replay one site in step, as live units are. A file of its own: its two
//! daemons would load the machine under `replay_speed`'s ×8 run, which does not wait for the
//! pipeline (as live units do not).

use crate::daemon_run_common;

use std::path::Path;
use std::time::Duration;

use daemon_run_common::*;

/// A hang guard, not a timing claim.
const ENDS_WITHIN: Duration = Duration::from_secs(60);

/// `(t_ns, [(x, y)])` of every `TRACKS` line a daemon streams for `secs` seconds.
fn watch_tracks(socket: &Path, secs: f64) -> Vec<(u64, Vec<(f64, f64)>)> {
    use scanfuse::daemon::protocol::Message;
    let mut client = Client::connect(socket, ENDS_WITHIN);
    match client.request(r#"{"cmd":"watch","status":false,"tracks":true}"#) {
        Message::Watch(w) => assert!(w.tracks, "{w:?}"),
        other => panic!("watch answered {other:?}"),
    }
    let until = std::time::Instant::now() + Duration::from_secs_f64(secs);
    let mut lines = Vec::new();
    while std::time::Instant::now() < until {
        if let Message::Tracks(t) = client.read() {
            let at = t.tracks.iter().map(|k| (k.x_m, k.y_m)).collect();
            lines.push((t.t_ns, at));
        }
    }
    lines
}

/// Two daemons replaying the hall, the second started 1 s after the first, both anchored to
/// one wall-clock time (`--replay-since`): they replay in step, as live units are: their
/// scans of one moment carry one stamp, at which both track the hall's people at the same
/// places, and the stamps are the wall clock's. Unanchored, the second would loop the 2 s
/// recording from its own start: at a stamp both fused, it would show the people of another
/// moment of the loop (9.5 cm median apart for the luckiest start seen, ~70 ms off).
#[test]
fn daemons_anchored_to_one_time_replay_in_step() {
    let now_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    // An anchor 1000 s ago: each daemon joins a replay 500 loops under way.
    let since = format!("{:.3}", now_s - 1000.0);
    let dirs: Vec<tempfile::TempDir> = (0..2).map(|_| tempfile::tempdir().unwrap()).collect();
    let sensors = replay_sensors(&fixture("hall.mcap"), &HALL);
    let mut daemons = Vec::new();
    for (k, dir) in dirs.iter().enumerate() {
        if k > 0 {
            std::thread::sleep(Duration::from_secs(1));
        }
        let config = write_config(dir.path(), "gate", &sensors, "");
        daemons.push(start_daemon_with(
            &config,
            dir.path(),
            &["--replay-since", &since],
        ));
    }
    // Both tracking (every unit placed) before the watch that is compared.
    let ids: Vec<&str> = HALL.iter().map(|(id, _)| *id).collect();
    for dir in &dirs {
        let mut client = Client::connect(&dir.path().join("s.sock"), ENDS_WITHIN);
        wait_for(ENDS_WITHIN, "every unit placed", || {
            let poses = client.poses();
            ids.iter()
                .all(|id| poses.sensors.iter().any(|s| s.id == *id && s.registered))
                .then_some(())
        });
    }
    let watched: Vec<_> = dirs
        .iter()
        .map(|d| {
            let socket = d.path().join("s.sock");
            std::thread::spawn(move || watch_tracks(&socket, 4.0))
        })
        .collect();
    let watched: Vec<_> = watched.into_iter().map(|w| w.join().unwrap()).collect();
    let (a, b) = (&watched[0], &watched[1]);
    let wall_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as f64;
    let newest = a.iter().map(|l| l.0).max().expect("TRACKS lines") as f64;
    assert!(
        (wall_ns - newest).abs() < 1e9,
        "stamped {:.2} s from the wall clock",
        (newest - wall_ns) / 1e9
    );
    // Each track of the first at a stamp, against the nearest of the second's at that stamp.
    let mut gaps = Vec::new();
    for (t, tracks) in a {
        let Some((_, other)) = b.iter().find(|(u, _)| u.abs_diff(*t) <= 1_000_000) else {
            continue;
        };
        for (x, y) in tracks {
            let nearest = other
                .iter()
                .map(|(u, v)| (u - x).hypot(v - y))
                .fold(f64::INFINITY, f64::min);
            if nearest.is_finite() {
                gaps.push(nearest);
            }
        }
    }
    gaps.sort_by(f64::total_cmp);
    assert!(gaps.len() >= 50, "{} tracks at shared stamps", gaps.len());
    let median = gaps[gaps.len() / 2];
    println!(
        "{} tracks at stamps both daemons fused: the other's nearest median {:.3} m, p90 {:.3} m",
        gaps.len(),
        median,
        gaps[gaps.len() * 9 / 10]
    );
    assert!(median < 0.05, "median {median:.3} m: out of step");
}
