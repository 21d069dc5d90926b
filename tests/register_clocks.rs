//! `scanfuse register` on recordings made by machines whose clocks differ: the offset is found
//! from the walkers and taken out, or, where it cannot be found, those walkers are not used
//! (never compared at skewed times).

use crate::common;

use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record::RecordingWriter;
use scanfuse::sim::Simulation;
use scanfuse::sim::plan::Plan;
use std::path::Path;
use std::process::Command;

/// A room that is the same turned end for end, a unit at each end facing the other, people
/// coming in through doors at both ends: the walls leave two poses, the walkers one.
const TWIN: &str = r#"
name = "twin"
[[wall]]
points = [[0, 0], [12, 0], [12, 6], [0, 6]]
closed = true
[[door]]
at = [0, 3]
width_m = 1.0
[[door]]
at = [12, 3]
width_m = 1.0
[[sensor]]
id = "a"
model = "UTM-30LX-EW"
x = 2.0
y = 3.0
[[sensor]]
id = "b"
model = "UTM-30LX-EW"
x = 10.0
y = 3.0
yaw_deg = 180
[[crowd]]
people = 2
max_people = 5
rate_per_min = 20
stop_share = 0.0
group_share = 0.0
"#;

/// Records `a` to one file and `b` to another whose clock reads `b_ahead_ms` more.
fn record_apart(dir: &Path, b_ahead_ms: u64) -> [std::path::PathBuf; 2] {
    let plan = Plan::from_toml(TWIN, "twin").unwrap();
    let mut sim = Simulation::new(&plan, 5).unwrap();
    let infos = sim.sensors().to_vec();
    let paths = [dir.join("a.mcap"), dir.join("b.mcap")];
    let mut writers: Vec<RecordingWriter> = paths
        .iter()
        .map(|p| RecordingWriter::create(p).unwrap())
        .collect();
    for (w, info) in writers.iter_mut().zip(&infos) {
        w.add_sensor(info).unwrap();
    }
    sim.run(15.0, |i, mut scan| {
        if i == 1 {
            scan.stamp_ns += b_ahead_ms * 1_000_000;
        }
        writers[i].write_scan(&infos[i].id, &scan)
    })
    .unwrap();
    for w in writers {
        w.finish().unwrap();
    }
    paths
}

fn register(paths: &[std::path::PathBuf; 2]) -> (serde_json::Value, String) {
    let out = common::succeeded(
        Command::new(env!("CARGO_BIN_EXE_scanfuse"))
            .arg("register")
            .args(paths)
            .args(["--anchor", "a", "--json"]),
    );
    (
        serde_json::from_slice(&out.stdout).unwrap(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn b_of(json: &serde_json::Value) -> serde_json::Value {
    json["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["id"] == "b")
        .cloned()
        .unwrap()
}

#[test]
fn a_clock_300_ms_ahead_is_found_and_taken_out_and_one_beyond_reach_leaves_walls_alone() {
    let dir = tempfile::tempdir().unwrap();
    let paths = record_apart(dir.path(), 300);
    let (json, said) = register(&paths);
    let offset_s: f64 = said
        .split("reads ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no offset reported: {said}"));
    assert!((offset_s - 0.3).abs() <= 0.02, "{said}");
    let b = b_of(&json);
    let est = pose2(
        b["x_m"].as_f64().unwrap_or(f64::NAN),
        b["y_m"].as_f64().unwrap_or(f64::NAN),
        b["yaw_deg"].as_f64().unwrap_or(f64::NAN).to_radians(),
    );
    let (dt, dyaw) = pose_error(&est, &pose2(8.0, 0.0, std::f64::consts::PI));
    assert!(dt < 0.05 && dyaw < 0.5f64.to_radians(), "b: {b}\n{said}");

    // Five seconds apart: not searched; the walls alone cannot tell the room from itself
    // turned, so b is not placed (and never placed wrong by skewed walkers).
    let far = tempfile::tempdir().unwrap();
    let paths = record_apart(far.path(), 5000);
    let (json, said) = register(&paths);
    assert!(said.contains("no offset within"), "{said}");
    let b = b_of(&json);
    assert!(b["x_m"].is_null(), "b placed: {b}\n{said}");
}
