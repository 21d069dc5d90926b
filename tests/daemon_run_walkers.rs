//! Registration among people through the daemon's replay (`scanfuse replay --max --socket`),
//! asserted over the real status socket (issue 16). The periodic corridor of
//! `fixtures/plans-walkers/periodic-corridor.toml` is simulated into a temp dir: its pilasters
//! repeat every 6 m, so walls alone leave s1 ambiguous ("a pose 6.00 m away scores …"), and
//! three people come into the units' reach about 8 s into the recording. Polled as it plays:
//! - while no one has come into reach, s1 is not placed (and says the walls left it open);
//! - once they have, s1 is placed within [`TARGET_S`] of stream time;
//! - every pose ever published is within 10 cm / 1° of the truth.
//!
//! Stream time is read from the scans the daemon has taken (`status`: 40 Hz units), so a poll
//! can only see a placement late, never early. About 10 s in a debug build.

use crate::daemon_run_common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use daemon_run_common::*;
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record;

/// Recorded length: the units' tries fall at about 1, 6 and 16 s of stream time (the last
/// with ~8 s of walkers in its buffer), and the replay must outlast the one that places.
const RECORD_S: f64 = 22.0;
/// The figure: every unit placed within this long of stream time once people walk.
const TARGET_S: f64 = 30.0;
/// A UTM-30LX-EW's reach (m): a person farther from both units is not yet walking for them.
const REACH_M: f64 = 30.0;
/// The simulated units' scan rate.
const SCANS_PER_S: f64 = 40.0;

#[test]
fn people_walking_place_the_unit_walls_leave_ambiguous_and_nothing_before() {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("corridor.mcap");
    let sim = Command::new(bin())
        .arg("simulate")
        .arg("--plan")
        .arg(fixture("plans-walkers/periodic-corridor.toml"))
        .args(["--seconds", &RECORD_S.to_string(), "--out"])
        .arg(&recording)
        .output()
        .unwrap();
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );

    let rec = record::read(&recording).unwrap();
    let truth = |id: &str| {
        let t = rec.sensor(id).and_then(|s| s.truth).expect("truth");
        pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
    };
    let start_ns = rec.first_stamp_ns().unwrap();
    // When the first person comes within reach of either unit.
    let units: Vec<_> = ["s0", "s1"].iter().map(|id| truth(id)).collect();
    let walk_s = record::read_truth_people(&recording)
        .unwrap()
        .iter()
        .find(|frame| {
            frame.people.iter().any(|q| {
                units.iter().any(|u| {
                    (u.translation.vector - nalgebra::Vector2::new(q.x_m, q.y_m)).norm() < REACH_M
                })
            })
        })
        .map(|frame| frame.t_ns.saturating_sub(start_ns) as f64 / 1e9)
        .expect("people come into reach");
    assert!(
        (7.0..12.0).contains(&walk_s),
        "the plan brings people into reach after the first tries: {walk_s:.1} s"
    );

    let socket = dir.path().join("s.sock");
    let _replay = Proc(
        Command::new(bin())
            .arg("replay")
            .arg(&recording)
            .args(["--max", "--anchor", "s0", "--out"])
            .arg(dir.path().join("out"))
            .arg("--socket")
            .arg(&socket)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start scanfuse replay"),
    );
    let mut client = Client::connect(&socket, Duration::from_secs(30));

    let s0_from_s1 = truth("s0").inverse() * truth("s1");
    // (stream s, s1 placed, its reason) per poll.
    let mut polls: Vec<(f64, bool, String)> = Vec::new();
    let started = Instant::now();
    let (placed_s, evidence) = loop {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "s1 not placed; polls (stream s, placed, reason): {:?}",
            polls.last()
        );
        // Scans first: the pose read next is at least this late in the stream.
        let stream_s = client
            .status()
            .sensors
            .iter()
            .map(|s| s.scans)
            .min()
            .unwrap_or(0) as f64
            / SCANS_PER_S;
        let poses = client.poses();
        assert_eq!(poses.anchor, "s0");
        let s1 = poses.sensors.iter().find(|p| p.id == "s1").expect("s1");
        if s1.registered {
            let est = pose2(
                s1.x_m.unwrap(),
                s1.y_m.unwrap(),
                s1.yaw_deg.unwrap().to_radians(),
            );
            let (err_m, err_rad) = pose_error(&est, &s0_from_s1);
            assert!(
                err_m < 0.10 && err_rad.to_degrees() < 1.0,
                "s1 placed wrong at {stream_s:.1} s: {err_m:.2} m, {:.2}°",
                err_rad.to_degrees()
            );
        }
        polls.push((
            stream_s,
            s1.registered,
            s1.reason.clone().unwrap_or_default(),
        ));
        if s1.registered {
            break (stream_s, s1.evidence.clone());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    println!(
        "people in reach at {walk_s:.1} s of stream time; s1 placed by {placed_s:.1} s ({:.1} s later; {} polls)",
        placed_s - walk_s,
        polls.len()
    );
    // Never before they walk, and not for want of looking: before anyone came into reach the
    // daemon had tried and said why it would not place s1 from the walls.
    assert!(
        placed_s >= walk_s,
        "s1 placed at {placed_s:.1} s, before anyone walked ({walk_s:.1} s)"
    );
    let waited = polls
        .iter()
        .filter(|(s, placed, reason)| *s < walk_s && !placed && reason.contains("ambiguous"))
        .count();
    assert!(
        waited > 0,
        "no poll before people walked saw the walls' ambiguity: {:?}",
        polls.first()
    );
    // The socket says what placed it, in `register --json`'s words: people were needed.
    assert!(
        evidence.as_deref().is_some_and(|e| e.contains("walkers")),
        "s1's evidence on the socket: {evidence:?}"
    );
    assert!(
        placed_s - walk_s <= TARGET_S,
        "placed {:.1} s after people walked",
        placed_s - walk_s
    );
}
