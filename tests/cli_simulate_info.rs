//! `scanfuse simulate` and `scanfuse info` as a user runs them: the built binary, real files.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scanfuse(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_scanfuse"))
        .args(args)
        .output()
        .expect("the scanfuse binary runs")
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn simulate(plan: &str, seconds: &str, seed: &str, out: &Path) -> Output {
    let plan = common::repo().join("fixtures/plans").join(plan);
    scanfuse(&[
        "simulate",
        "--plan",
        plan.to_str().unwrap(),
        "--seconds",
        seconds,
        "--seed",
        seed,
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn the_same_seed_gives_the_same_file_and_another_seed_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let [a, b, c]: [PathBuf; 3] = ["a", "b", "c"].map(|n| dir.path().join(format!("{n}.mcap")));
    for (path, seed) in [(&a, "3"), (&b, "3"), (&c, "4")] {
        let out = simulate("lab.toml", "0.3", seed, path);
        assert!(out.status.success(), "{}", text(&out));
    }
    let bytes = |p: &Path| std::fs::read(p).unwrap();
    assert_eq!(bytes(&a), bytes(&b));
    assert_ne!(bytes(&a), bytes(&c));
}

#[test]
fn info_describes_a_simulated_recording() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lab.mcap");
    assert!(simulate("lab.toml", "0.5", "1", &path).status.success());
    let out = scanfuse(&["info", path.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out));
    let report = text(&out);
    let rec = scanfuse::record::read(&path).unwrap();
    assert!(
        report.contains(&format!("{} sensors", rec.sensors.len())),
        "{report}"
    );
    for s in &rec.sensors {
        let t = s.truth.expect("simulated sensors carry truth");
        assert!(report.contains(&s.id), "{report}");
        assert!(
            report.contains(&format!("{:.3}, {:.3}, {:.2}°", t.x_m, t.y_m, t.yaw_deg)),
            "{report}"
        );
        // 0.5 s at 40 Hz: 20 scans, give or take one at the edges.
        let n = rec.scans_of(&s.id).len();
        assert!((19..=21).contains(&n), "{} has {n} scans", s.id);
    }
    assert!(report.contains("40.0 Hz (40)"), "{report}");
}

#[test]
fn info_on_a_cut_recording_shows_what_was_read_and_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lab.mcap");
    assert!(simulate("lab.toml", "1", "1", &path).status.success());
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out = scanfuse(&["info", cut.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    let report = text(&out);
    assert!(report.contains("cut.mcap"), "{report}");
    assert!(report.contains("damaged"), "{report}");
    assert!(
        report.contains("sensor "),
        "the table is still printed: {report}"
    );
}

#[test]
fn bad_input_exits_2_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let plan = dir.path().join("broken.toml");
    std::fs::write(
        &plan,
        "name = \"x\"\n[[sensor]]\nid = \"a\"\nmodle = \"UTM-30LX-EW\"\n",
    )
    .unwrap();
    let out_path = dir.path().join("x.mcap");
    let out = scanfuse(&[
        "simulate",
        "--plan",
        plan.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    assert!(text(&out).contains("broken.toml"), "{}", text(&out));
    assert!(!out_path.exists());

    let out = scanfuse(&["info", plan.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out).contains("not an MCAP"), "{}", text(&out));

    let out = simulate("lab.toml", "0", "1", &out_path);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out).contains("--seconds"), "{}", text(&out));
}

#[test]
fn eval_refuses_a_csv_no_part_it_runs_would_write() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("pairs.csv");
    let out = scanfuse(&["eval", "--only", "crowd", "--csv", csv.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out));
    assert!(text(&out).contains("--csv"), "{}", text(&out));
    assert!(!csv.exists());
}

#[test]
fn every_committed_fixture_reads_whole_and_carries_truth() {
    for name in ["lab", "hall", "moved"] {
        let path = common::repo().join(format!("fixtures/{name}.mcap"));
        let rec = scanfuse::record::read(&path).unwrap();
        assert!(!rec.sensors.is_empty(), "{name}");
        for s in &rec.sensors {
            assert!(s.truth.is_some() && s.geometry.is_some(), "{name}/{}", s.id);
            assert!(!rec.scans_of(&s.id).is_empty(), "{name}/{}", s.id);
        }
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(
            size <= 2_000_000,
            "{name}.mcap is {size} bytes, over the 2 MB budget"
        );
        assert_eq!(rec.moves.is_empty(), name != "moved", "{name}");
    }
}

/// A crowd plan's recording carries `/truth/people` every 0.1 s; the scan reader leaves it
/// out of the sensors and scans, `read_truth_people` reads it back, and `info` lists it.
#[test]
fn crowd_truth_is_written_read_back_apart_from_scans_and_listed_by_info() {
    let dir = tempfile::tempdir().unwrap();
    let plan = dir.path().join("crowd.toml");
    std::fs::write(
        &plan,
        r#"
name = "crowd"
[[wall]]
points = [[0, 0], [12, 0], [12, 8], [0, 8]]
closed = true
[[door]]
at = [6, 0]
width_m = 1.5
[[sensor]]
id = "a"
model = "UTM-30LX-EW"
x = 1.0
y = 1.0
yaw_deg = 45
[[crowd]]
people = 6
"#,
    )
    .unwrap();
    let path = dir.path().join("crowd.mcap");
    let out = scanfuse(&[
        "simulate",
        "--plan",
        plan.to_str().unwrap(),
        "--seconds",
        "1",
        "--out",
        path.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("10 people's truth messages"),
        "{}",
        text(&out)
    );

    let rec = scanfuse::record::read(&path).unwrap();
    assert_eq!(rec.sensors.len(), 1, "the truth is not a sensor");
    assert_eq!(rec.scans.keys().collect::<Vec<_>>(), ["a"]);
    assert!(rec.skipped.is_empty(), "{:?}", rec.skipped);
    assert_eq!(rec.truth.len(), 1);
    assert_eq!(rec.truth[0].topic, "/truth/people");
    assert_eq!(rec.truth[0].messages, 10);

    let truth = scanfuse::record::read_truth_people(&path).unwrap();
    assert_eq!(truth.len(), 10);
    let start = rec.scans_of("a")[0].stamp_ns / 1_000_000_000 * 1_000_000_000;
    for (k, t) in truth.iter().enumerate() {
        assert_eq!(t.t_ns, start + k as u64 * 100_000_000);
        assert_eq!(t.people.len(), 6, "{t:?}");
        for p in &t.people {
            assert!(p.id.starts_with('p'), "{p:?}");
            // In the room, or in its door at y = 0 on the way out (people leave 1 m past it).
            assert!(
                (0.0..12.0).contains(&p.x_m) && (-1.1..8.0).contains(&p.y_m),
                "{p:?}"
            );
        }
    }
    // A recording without truth gives none.
    let lab = common::repo().join("fixtures/lab.mcap");
    assert!(
        scanfuse::record::read_truth_people(&lab)
            .unwrap()
            .is_empty()
    );

    let out = scanfuse(&["info", path.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out));
    let report = text(&out);
    assert!(
        report.contains("truth: /truth/people (scanfuse.PeopleTruth, json): 10 messages"),
        "{report}"
    );
    assert!(!report.contains("skipped:"), "{report}");
}
