//! The live page in a real browser: `scanfuse run` on the replayed `hall` site serves it on
//! loopback, and tests/python/web_page.py (Playwright driving Debian's headless Chromium)
//! opens it, waits for `data-ready`, checks every drawn sensor's `data-sensor` and
//! `data-pose` against the status socket's `poses`, drags one sensor and checks that `poses`
//! then shows it surveyed where it was dropped. The same page and daemon carry the building
//! drawing: Python's ezdxf exports the hall's plan to DXF (tests/python/plan_to_drawing.py),
//! `[site] drawing` names it and `poses.toml` holds the poses (the recording's truth) but no
//! `building_from_site`: the daemon must align itself to the drawing (the plan's frame is the
//! building's, so it must find the anchor's true pose) and save it, and the page must draw
//! the drawing under the map, its walls on the scans' walls. It leaves a screenshot in `target/web-page.png` (the one in docs/ is such a
//! picture).
//!
//! Needs SCANFUSE_TEST_PYTHON (the venv .ci/run builds) and /usr/bin/chromium (.ci/run
//! installs it); skips without them, except under CI.

use crate::common;
use crate::daemon_run_common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::protocol::Message;

const CHROMIUM: &str = "/usr/bin/chromium";

#[test]
fn the_page_shows_every_sensor_where_poses_has_it_and_a_drag_surveys_one() {
    let test = "the_page_shows_every_sensor_where_poses_has_it_and_a_drag_surveys_one";
    let Some(python) = common::test_python(test) else {
        return;
    };
    if !Path::new(CHROMIUM).exists() {
        assert!(
            std::env::var_os("CI").is_none(),
            "{CHROMIUM} is missing under CI; .ci/run installs Debian's chromium"
        );
        eprintln!("{test}: skipped: no {CHROMIUM} (apt-get install chromium)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hall = fixture("hall.mcap");
    let sensors = replay_sensors(&hall, &HALL);
    let config = write_config(
        dir.path(),
        "gate",
        &sensors,
        // Port 0, the page's URL read from `status`: a port picked free here and released
        // was once taken, before the page bound it, by one of the daemon's own replay
        // emulators (the browser got SCIP: ERR_INVALID_HTTP_RESPONSE).
        "\n[web]\nlisten = \"127.0.0.1:0\"\n",
    );
    let (drawing, gate) = with_drawing(&python, &hall, &config, dir.path());
    let _daemon = start_daemon(&config, dir.path());
    let sock = dir.path().join("s.sock");
    let mut client = Client::connect(&sock, Duration::from_secs(30));
    wait_for(Duration::from_secs(120), "two sensors registered", || {
        (client
            .poses()
            .sensors
            .iter()
            .filter(|p| p.registered)
            .count()
            >= 2)
            .then_some(())
    });
    // Nothing said where the site lies in the building: the daemon aligns itself to the
    // drawing, and the plan's frame is the building's, so it must find the anchor's truth.
    let building = wait_for(Duration::from_secs(60), "aligned to the drawing", || {
        client.poses().building_from_site.filter(|b| b.aligned)
    });
    assert_at_truth("live alignment", &building, &gate);
    assert!((building.scale - 1.0).abs() < 1e-9, "{building:?}");
    // Saved right after it is shown on the socket.
    wait_for(
        Duration::from_secs(10),
        "building_from_site in poses.toml",
        || {
            std::fs::read_to_string(dir.path().join("state/poses.toml"))
                .ok()
                .filter(|saved| saved.contains("[building_from_site]"))
        },
    );
    let status = client.status();
    let url = status
        .web
        .as_deref()
        .and_then(|w| w.strip_prefix("page at "))
        .unwrap_or_else(|| panic!("no page: status' web is {:?}", status.web))
        .to_string();
    let screenshot = common::repo().join("target/web-page.png");
    let out = Command::new(python)
        .arg(common::repo().join("tests/python/web_page.py"))
        .args(["--url", &url])
        .arg("--socket")
        .arg(&sock)
        .arg("--screenshot")
        .arg(&screenshot)
        .args(["--browser", CHROMIUM, "--drawing"])
        .env("PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD", "1")
        .output()
        .expect("run the browser test");
    let log = std::fs::read_to_string(dir.path().join("daemon.log")).unwrap_or_default();
    assert!(
        out.status.success(),
        "the browser test failed: {}\n{}\n--- daemon log (end) ---\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
        log.lines().rev().take(30).collect::<Vec<_>>().join("\n")
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("a JSON summary");
    eprintln!("browser summary: {summary}");
    assert!(summary["moved_m"].as_f64().unwrap() > 0.05, "{summary}");
    // Every wall of the drawing drawn, lying on the scans' walls within a couple of pixels.
    assert_eq!(
        summary["drawing_segments"].as_u64(),
        Some(drawing.segments.len() as u64),
        "{summary}"
    );
    assert!(
        summary["drawing_points"].as_u64().unwrap() > 200
            && summary["drawing_median_px"].as_f64().unwrap() < 2.0,
        "{summary}"
    );
    assert!(
        std::fs::metadata(&screenshot).is_ok_and(|m| m.len() > 10_000),
        "a screenshot"
    );
    // Two map points picked on the page and paired 10 cm off on the drawing, aligned from.
    let b: scanfuse::drawing::BuildingFromSite =
        serde_json::from_value(summary["page_align"].clone()).expect("page_align");
    assert_at_truth("aligned from the page's pairs", &b, &gate);
    assert_eq!(b.method, "pairs+lines");
    // The socket's `align` (the verb the page sends): two point pairs 10 cm off, refined on
    // the drawing's lines; bad pairs are refused.
    let mut client = Client::connect(&sock, Duration::from_secs(10));
    let site_points = [(0.0, 0.0), (8.0, 3.0)];
    let pairs: Vec<String> = site_points
        .iter()
        .map(|&(x, y)| {
            let d = gate * nalgebra::Point2::new(x, y);
            format!("{x},{y}={},{}", d.x + 0.1, d.y - 0.1)
        })
        .collect();
    let line = serde_json::json!({"cmd": "align", "pairs": pairs.join("; ")}).to_string();
    match client.request(&line) {
        Message::Poses(p) => {
            let b = p.building_from_site.expect("building_from_site");
            assert_at_truth("aligned from two pairs 10 cm off", &b, &gate);
            assert_eq!(b.method, "pairs+lines");
        }
        other => panic!("align answered {other:?}"),
    }
    match client.request(r#"{"cmd":"align","pairs":"1,2=3"}"#) {
        Message::Error(e) => assert!(e.message.contains("1,2=3"), "{}", e.message),
        other => panic!("bad pairs answered {other:?}"),
    }

    // The drop is kept in state_dir, to survive a restart.
    let surveys = std::fs::read_to_string(dir.path().join("state/surveys.toml")).unwrap();
    let dragged = summary["dragged"].as_str().unwrap();
    assert!(
        surveys.contains(&format!("id = \"{dragged}\"")),
        "{surveys}"
    );
}

/// That `b` puts the site within 5 cm / 0.3° of the truth (the anchor's true pose in the
/// plan's frame, which is the building's); says how far, as `what`.
fn assert_at_truth(
    what: &str,
    b: &scanfuse::drawing::BuildingFromSite,
    gate: &scanfuse::geometry::Pose2,
) {
    let off = (b.x_m - gate.translation.x).hypot(b.y_m - gate.translation.y);
    let dyaw = (b.yaw_deg - gate.rotation.angle().to_degrees() + 540.0) % 360.0 - 180.0;
    eprintln!(
        "{what}: {b:?}; off the truth by {:.1} cm, {dyaw:.3}°",
        off * 100.0
    );
    assert!(
        off < 0.05 && dyaw.abs() < 0.3,
        "{what}: {b:?} against the truth {gate:?}"
    );
}

/// Exports the hall's plan to `dir/plan.dxf`, names it in the config's `[site]` (walls and
/// columns only) and writes `state/poses.toml` with every sensor's true pose in the anchor's
/// frame (and no `building_from_site`); gives the drawing and the anchor's true pose (the
/// plan's frame is the building's).
fn with_drawing(
    python: &Path,
    hall: &Path,
    config: &Path,
    dir: &Path,
) -> (scanfuse::drawing::Drawing, scanfuse::geometry::Pose2) {
    let plan = common::repo().join("fixtures/plans/hall.toml");
    let dxf = dir.join("plan.dxf");
    common::succeeded(
        Command::new(python)
            .arg(common::repo().join("tests/python/plan_to_drawing.py"))
            .arg(&plan)
            .arg(&dxf)
            .arg(dir.join("plan.svg")),
    );
    let layers = vec!["A-WALL".to_string(), "A-COLS".to_string()];
    let text = std::fs::read_to_string(config).unwrap().replacen(
        "anchor = \"gate\"\n",
        &format!(
            "anchor = \"gate\"\ndrawing = \"{}\"\ndrawing_layers = [\"A-WALL\", \"A-COLS\"]\n",
            dxf.display()
        ),
        1,
    );
    std::fs::write(config, text).unwrap();
    let recording = scanfuse::record::read(hall).unwrap();
    let truth = |id: &str| {
        let t = recording
            .sensors
            .iter()
            .find(|s| s.id == id)
            .and_then(|s| s.truth)
            .expect("the hall recording carries truth");
        scanfuse::geometry::pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
    };
    let gate = truth("gate");
    let now = std::time::SystemTime::now();
    std::fs::create_dir_all(dir.join("state")).unwrap();
    let sensors = HALL
        .iter()
        .map(|(id, _)| {
            let p = gate.inverse() * truth(id);
            let mut pose = scanfuse::daemon::protocol::SensorPose::unregistered(*id, "");
            pose.registered = true;
            pose.reason = None;
            pose.x_m = Some(p.translation.x);
            pose.y_m = Some(p.translation.y);
            pose.yaw_deg = Some(p.rotation.angle().to_degrees());
            scanfuse::daemon::state::SavedPose::from_pose(
                &pose,
                scanfuse::daemon::protocol::PoseSource::Registered,
                now,
            )
        })
        .collect();
    scanfuse::daemon::state::PosesFile {
        anchor: "gate".into(),
        sensors,
        building_from_site: None,
    }
    .save(&dir.join("state"))
    .unwrap();
    let drawing = scanfuse::drawing::read(
        &dxf,
        &scanfuse::drawing::ReadOptions {
            layers: Some(layers),
            ..Default::default()
        },
    )
    .unwrap();
    (drawing, gate)
}
