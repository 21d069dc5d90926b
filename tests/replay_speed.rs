//! Replay at any speed gives the poses of ×1: every timer of the pipeline follows the scans'
//! own clock, and a slow pipeline holds the replay back rather than dropping scans. `--max`
//! ends as soon as the data and the registration are done, and SIGTERM stops a replay at once.
//! Run on every committed fixture, and on the demo config through `scanfuse run`.

use crate::daemon_run_common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::state::PosesFile;

/// A hang guard, not a timing claim: the bug this replaces waited 120 s after the data.
const ENDS_WITHIN: Duration = Duration::from_secs(60);

/// `(id, registered, x, y, yaw°)` of each sensor in `dir/poses.toml`.
fn poses(dir: &Path) -> Vec<(String, bool, f64, f64, f64)> {
    let file = PosesFile::load(dir)
        .expect("poses.toml reads")
        .expect("poses.toml written");
    file.sensors
        .iter()
        .map(|s| {
            (
                s.id.clone(),
                s.registered,
                s.x_m.unwrap_or(f64::NAN),
                s.y_m.unwrap_or(f64::NAN),
                s.yaw_deg.unwrap_or(f64::NAN),
            )
        })
        .collect()
}

fn replay(file: &Path, pace: &[&str], out: &Path) -> Vec<(String, bool, f64, f64, f64)> {
    let log = std::fs::File::create(out.with_extension("log")).unwrap();
    let mut child = Proc(
        Command::new(bin())
            .arg("replay")
            .arg(file)
            .args(pace)
            .arg("--out")
            .arg(out)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap(),
    );
    let status = child.wait_exit(ENDS_WITHIN);
    assert!(status.success(), "replay {pace:?} of {}", file.display());
    poses(out)
}

fn assert_same(
    what: &str,
    a: &[(String, bool, f64, f64, f64)],
    b: &[(String, bool, f64, f64, f64)],
) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (p, q) in a.iter().zip(b) {
        assert_eq!((&p.0, p.1), (&q.0, q.1), "{what}: {a:?} vs {b:?}");
        if p.1 {
            let d = ((p.2 - q.2).powi(2) + (p.3 - q.3).powi(2)).sqrt();
            assert!(
                d < 1e-3 && (p.4 - q.4).abs() < 0.01,
                "{what}: {} moved {d:.4} m, {:.3}°",
                p.0,
                p.4 - q.4
            );
        }
    }
}

#[test]
fn every_fixture_replays_to_the_same_poses_at_x1_and_max() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["hall.mcap", "lab.mcap", "moved.mcap"] {
        let file = fixture(name);
        let at = |pace: &[&str], tag: &str| {
            replay(&file, pace, &dir.path().join(format!("{name}-{tag}")))
        };
        let x1 = at(&["--speed", "1"], "x1");
        assert!(
            x1.iter().filter(|p| p.1).count() >= 2,
            "{name}: ×1 registers: {x1:?}"
        );
        assert_same(&format!("{name} --max"), &x1, &at(&["--max"], "max"));
        if name == "hall.mcap" {
            assert_same(&format!("{name} ×4"), &x1, &at(&["--speed", "4"], "x4"));
        }
    }
}

#[test]
fn sigterm_stops_a_slow_replay_and_it_saves() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut child = Proc(
        Command::new(bin())
            .arg("replay")
            .arg(fixture("hall.mcap"))
            .args(["--speed", "0.1", "--out"])
            .arg(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // 20 s of replay at ×0.1; stop it early, once it is under way.
    std::thread::sleep(Duration::from_secs(2));
    child.signal("TERM");
    assert!(child.wait_exit(Duration::from_secs(15)).success());
    assert_eq!(poses(&out).len(), 5, "poses.toml holds every sensor");
}

/// `config/demo.toml` with its paths made absolute and its state in `dir`.
fn demo_config(dir: &Path) -> PathBuf {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(repo.join("config/demo.toml"))
        .unwrap()
        .replace("../target/demo", &dir.display().to_string())
        .replace("../fixtures", &repo.join("fixtures").display().to_string());
    let path = dir.join("demo.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn the_demo_config_at_x8_places_every_sensor_where_x1_does() {
    let run = |speed: &str| {
        let dir = tempfile::tempdir().unwrap();
        let config = demo_config(dir.path());
        let mut child = Proc(
            Command::new(bin())
                .args(["run", "--for", "4s", "--replay-speed", speed, "--config"])
                .arg(&config)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        assert!(child.wait_exit(ENDS_WITHIN).success(), "run at ×{speed}");
        poses(dir.path())
    };
    let x1 = run("1");
    assert!(x1.iter().all(|p| p.1), "×1 places every sensor: {x1:?}");
    assert_same("demo ×8", &x1, &run("8"));
}
