//! The people tracker end to end on a simulated crowd, scored against the simulator's
//! `/truth/people` with CLEAR-MOT (0.5 m): in memory through `track::score`, and through
//! `scanfuse track` on a recording, a sensor unplugged mid-run leaving the tracks to the rest.

use std::process::Command;

use scanfuse::sim::Plan;
use scanfuse::track::TrackParams;
use scanfuse::track::score::{ScoreOptions, counting_layout, score_plan, variant};

/// A 12 × 8 m room, three scanners round it, a crowd of 6 coming and going.
const PLAN: &str = r#"
name = "room6"

[[wall]]
points = [[0, 0], [12, 0], [12, 8], [0, 8]]
closed = true
height_m = 3.0

[[door]]
at = [6, 0]
width_m = 1.6

[[box]]
center = [3, 5]
size = [1.0, 1.0]
height_m = 1.2

[[sensor]]
id = "sw"
model = "UTM-30LX-EW"
x = 0.4
y = 0.4
yaw_deg = 45

[[sensor]]
id = "ne"
model = "UTM-30LX-EW"
x = 11.6
y = 7.6
yaw_deg = -135

[[sensor]]
id = "se"
model = "UXM-30LX-E"
x = 11.6
y = 0.4
yaw_deg = 135

[[crowd]]
people = 6
rate_per_min = 20
stop_s = [2, 4]
"#;

fn plan() -> Plan {
    Plan::from_toml(PLAN, "room6").expect("the plan parses")
}

fn options(seconds: f64) -> ScoreOptions {
    ScoreOptions {
        seed: 3,
        seconds,
        ..ScoreOptions::default()
    }
}

#[test]
fn a_small_crowd_is_tracked_against_its_truth() {
    let plan = plan();
    let all = score_plan(&plan, &TrackParams::default(), &options(8.0)).expect("runs");
    let m = &all.mot;
    eprintln!(
        "all sensors: MOTA {:.3} MOTP {:.3} m, misses {}, false {}, switches {}, {} ids",
        m.mota(),
        m.motp_m(),
        m.misses,
        m.false_tracks,
        m.id_switches,
        all.ids
    );
    // 6 people over ~7 scored seconds: ~420 truths.
    assert!(m.truths >= 300, "{m:?}");
    assert!(m.mota() >= 0.9, "MOTA {:.3}: {m:?}", m.mota());
    assert!(m.motp_m() <= 0.08, "MOTP {:.3}", m.motp_m());
    assert!(m.id_switches <= 2, "{m:?}");
    // One sensor sees less than three (the baseline the fused tracker improves on).
    let one = score_plan(
        &variant(&plan, Some(1), None),
        &TrackParams::default(),
        &options(8.0),
    )
    .expect("runs");
    assert!(
        one.mot.mota() < m.mota(),
        "{:.3} vs {:.3}",
        one.mot.mota(),
        m.mota()
    );
}

#[test]
fn a_sensor_unplugged_mid_run_leaves_the_tracks_to_the_others() {
    let plan = plan();
    let o = ScoreOptions {
        drop_sensor: Some(("ne".into(), 3.0)),
        ..options(8.0)
    };
    let dropped = score_plan(&plan, &TrackParams::default(), &o).expect("runs");
    let m = &dropped.mot;
    eprintln!(
        "ne unplugged at 3 s: MOTA {:.3}, misses {}, false {}, switches {}",
        m.mota(),
        m.misses,
        m.false_tracks,
        m.id_switches
    );
    assert!(m.mota() >= 0.85, "MOTA {:.3}: {m:?}", m.mota());
    assert!(m.id_switches <= 3, "{m:?}");
}

#[test]
fn scanfuse_track_writes_tracks_lines_on_the_recordings_clock() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let plan_path = dir.path().join("room6.toml");
    std::fs::write(&plan_path, PLAN).expect("plan written");
    let mcap = dir.path().join("room6.mcap");
    let bin = env!("CARGO_BIN_EXE_scanfuse");
    let sim = Command::new(bin)
        .args(["simulate", "--plan"])
        .arg(&plan_path)
        .args(["--seconds", "4", "--seed", "3", "--out"])
        .arg(&mcap)
        .output()
        .expect("simulate runs");
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    // The true poses as the daemon would write them.
    let poses = dir.path().join("poses.toml");
    let mut text = String::from("anchor = \"sw\"\n");
    for s in &plan().sensors {
        text.push_str(&format!(
            "\n[[sensor]]\nid = \"{}\"\nregistered = true\nx_m = {}\ny_m = {}\nyaw_deg = {}\nsource = \"surveyed\"\nupdated = \"2026-01-01T00:00:00Z\"\n",
            s.id, s.x, s.y, s.yaw_deg
        ));
    }
    std::fs::write(&poses, text).expect("poses written");
    let out = dir.path().join("tracks.ndjson");
    // `scanfuse track` on the recording with the true poses, plus `extra` arguments.
    let track = |extra: &[&std::ffi::OsStr]| {
        Command::new(bin)
            .arg("track")
            .arg(&mcap)
            .arg("--poses")
            .arg(&poses)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .expect("track runs")
    };
    let run = track(&[]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let truth = scanfuse::record::read_truth_people(&mcap).expect("truth");
    let (t0, t1) = (
        truth.first().map(|t| t.t_ns).unwrap_or(0),
        truth.last().map(|t| t.t_ns).unwrap_or(0),
    );
    let text = std::fs::read_to_string(&out).expect("tracks written");
    let mut last_t = 0u64;
    let mut lines = 0;
    let mut with_tracks = 0;
    for line in text.lines() {
        let v: serde_json::Value = serde_json::from_str(line).expect("one JSON object a line");
        assert_eq!(v["class"], "TRACKS");
        let t = v["t_ns"].as_u64().expect("t_ns");
        assert!(t > last_t, "t_ns goes forward: {t} after {last_t}");
        assert!(
            t + 100_000_000 >= t0 && t <= t1 + 100_000_000,
            "{t} outside {t0}..{t1}"
        );
        last_t = t;
        lines += 1;
        let tracks = v["tracks"].as_array().expect("tracks");
        if !tracks.is_empty() {
            with_tracks += 1;
            for tr in tracks {
                for key in [
                    "id", "x_m", "y_m", "vx_m_s", "vy_m_s", "sigma_m", "age_s", "sensors",
                ] {
                    assert!(tr.get(key).is_some(), "{key} missing in {tr}");
                }
            }
        }
    }
    // 4 s at one step per 25 ms.
    assert!(lines >= 120, "{lines} lines");
    assert!(
        with_tracks * 2 >= lines,
        "{with_tracks} of {lines} lines hold tracks"
    );

    // A site file's [track] sets the tracker; a bad one is refused with its file, line and key.
    let site = |section: &str| {
        let path = dir.path().join("site.toml");
        std::fs::write(
            &path,
            format!(
                "[site]\nname = \"room6\"\nstate_dir = \"state\"\nsocket = \"s.sock\"\nanchor = \"sw\"\n\n\
                 [[sensor]]\nid = \"sw\"\nconnect = \"tcp://127.0.0.1:10940\"\n\n[track]\n{section}\n"
            ),
        )
        .expect("site file written");
        track(&["--config".as_ref(), path.as_os_str()])
    };
    let with = site("death_s = 0.3\nbackground_s = 120");
    let stderr = String::from_utf8_lossy(&with.stderr);
    assert!(with.status.success(), "{stderr}");
    assert!(
        stderr.contains("background after 120 s still, a track ends 0.3 s unseen ([track] of"),
        "{stderr}"
    );
    let bad = site("background_s = 20");
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("site.toml") && stderr.contains("track.background_s"),
        "{stderr}"
    );
}

#[test]
fn door_crossings_and_zone_occupancy_from_the_tracks_match_the_truth() {
    let plan = plan();
    let (lines, zones) = counting_layout(&plan);
    assert_eq!(lines.len(), 1, "one door: {lines:?}");
    let o = ScoreOptions {
        lines,
        zones,
        ..options(20.0)
    };
    let s = score_plan(&plan, &TrackParams::default(), &o).expect("runs");
    let line = &s.lines[0];
    eprintln!(
        "door line: truth in/out {:?}, counted {:?}; zones MAE {:.3} (mean truth {:.2}): {:?}",
        line.truth,
        line.counted,
        s.zone_mae(),
        s.zone_mean_truth(),
        s.zones
    );
    assert!(line.truth_total() >= 4, "people came and went: {line:?}");
    assert!(line.wrong() <= 1, "{line:?}");
    assert_eq!(s.zones.len(), 2);
    assert!(s.zones.iter().all(|z| z.frames >= 150), "{:?}", s.zones);
    assert!(s.zone_mean_truth() > 0.0, "someone was in a zone");
    assert!(s.zone_mae() <= 0.1, "MAE {:.3}", s.zone_mae());
}
