//! `scanfuse align` against drawings made by another codebase: Python's ezdxf exports a
//! fixture plan to DXF (millimetres, walls as polylines, lines and blocks; pillars as nested,
//! rotated, unevenly scaled blocks; furniture, text, dimension and door layers; one wall moved
//! 20 cm "since the drawing") and writes the same plan as plain SVG
//! (tests/python/plan_to_drawing.py). A recording of the plan is simulated; the building frame
//! is the plan's, where the simulator's truth lies, and the site frame is the anchor sensor's,
//! offset and turned from it. Needs SCANFUSE_TEST_PYTHON with ezdxf (tests/python/
//! requirements.txt; .ci/run installs it); skips without it, except under CI.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::{repo, succeeded, test_python};
use serde_json::Value;

/// Errors allowed against truth in the building frame (the issue's target).
const MAX_ERR_M: f64 = 0.05;
const MAX_ERR_DEG: f64 = 0.3;

fn scanfuse() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scanfuse"))
}

/// Exports `plan` to `dir/plan.dxf` and `dir/plan.svg` with Python, and simulates it to
/// `dir/plan.mcap`. `None` when the test should skip.
fn prepare(test: &str, plan: &Path, dir: &Path, move_wall: Option<&str>) -> Option<()> {
    let python = test_python(test)?;
    let mut cmd = Command::new(python);
    cmd.arg(repo().join("tests/python/plan_to_drawing.py"))
        .arg(plan)
        .arg(dir.join("plan.dxf"))
        .arg(dir.join("plan.svg"));
    if let Some(m) = move_wall {
        cmd.args(["--move-wall", m]);
    }
    succeeded(&mut cmd);
    succeeded(
        scanfuse()
            .args(["simulate", "--seconds", "2", "--seed", "3"])
            .arg("--plan")
            .arg(plan)
            .arg("--out")
            .arg(dir.join("plan.mcap")),
    );
    Some(())
}

fn align(dir: &Path, args: &[&str]) -> Value {
    let out = succeeded(
        scanfuse()
            .arg("align")
            .arg(dir.join("plan.mcap"))
            .args(["--walls-only", "--json"])
            .args(args),
    );
    serde_json::from_slice(&out.stdout).expect("align --json prints one JSON object")
}

/// Every sensor within the target of the simulator's truth (in the plan's frame).
fn assert_within_truth(dir: &Path, out: &Value) {
    let rec = scanfuse::record::read(&dir.join("plan.mcap")).unwrap();
    let sensors = out["sensors"].as_array().unwrap();
    assert_eq!(sensors.len(), rec.sensors.len(), "{out}");
    for info in &rec.sensors {
        let truth = info.truth.expect("simulated recordings carry truth");
        let s = sensors
            .iter()
            .find(|s| s["id"] == info.id.as_str())
            .unwrap();
        assert_eq!(s["registered"], true, "{} not placed: {out}", info.id);
        let dx = s["x_m"].as_f64().unwrap() - truth.x_m;
        let dy = s["y_m"].as_f64().unwrap() - truth.y_m;
        let dyaw =
            (s["yaw_deg"].as_f64().unwrap() - truth.yaw_deg + 540.0).rem_euclid(360.0) - 180.0;
        assert!(
            dx.hypot(dy) < MAX_ERR_M && dyaw.abs() < MAX_ERR_DEG,
            "{}: {:.3} m / {:.3}° from truth ({s})",
            info.id,
            dx.hypot(dy),
            dyaw
        );
    }
}

/// The moved lines of the residual report.
fn moved(out: &Value) -> Vec<Value> {
    out["residuals"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["kind"] == "line" && r["moved"] == true)
        .cloned()
        .collect()
}

#[test]
fn dxf_from_ezdxf_aligns_automatically_within_5cm_and_names_the_moved_wall() {
    let dir = tempfile::tempdir().unwrap();
    let plan = repo().join("fixtures/plans/hall.toml");
    // The east wall, (35, 0)–(35, 14), drawn 20 cm west of where it stands.
    if prepare("dxf_automatic", &plan, dir.path(), Some("0:1:0.2")).is_none() {
        return;
    }
    let drawing = dir.path().join("plan.dxf");
    let out = align(
        dir.path(),
        &[
            "--drawing",
            drawing.to_str().unwrap(),
            "--layers",
            "A-WALL,A-COLS",
        ],
    );
    let b = &out["building_from_site"];
    assert_eq!(b["aligned"], true, "{out}");
    assert_eq!(b["method"], "automatic+lines", "{out}");
    assert!((b["scale"].as_f64().unwrap() - 1.0).abs() < 1e-9, "{out}");
    assert!(out["pairs"].is_array() && out["anchor"] == "gate", "{out}");
    // Its σ comes from the lines fitted, each once: millimetres, not the ≈ 0 that thousands
    // of points would claim, and not more than the target.
    for key in ["sigma_x_m", "sigma_y_m"] {
        let v = b[key].as_f64().unwrap_or(-1.0);
        assert!(v > 0.0005 && v < MAX_ERR_M, "{key}: {out}");
    }
    let v = b["sigma_yaw_deg"].as_f64().unwrap_or(-1.0);
    assert!(v > 0.001 && v < MAX_ERR_DEG, "sigma_yaw_deg: {out}");
    assert_within_truth(dir.path(), &out);
    // Exactly the moved wall is named, with how far (sign: along its left normal, west).
    let moved = moved(&out);
    assert_eq!(moved.len(), 1, "{out}");
    let m = &moved[0];
    assert!((m["a"][0].as_f64().unwrap() - 34.8).abs() < 0.01, "{m}");
    assert!((m["b"][0].as_f64().unwrap() - 34.8).abs() < 0.01, "{m}");
    assert!(
        (m["offset_m"].as_f64().unwrap().abs() - 0.2).abs() < 0.04,
        "{m}"
    );
    assert_eq!(m["layer"], "A-WALL");

    // The person's form says the same and exits 0; --save keeps it beside the poses.
    let state = dir.path().join("state");
    let human = succeeded(
        scanfuse()
            .arg("align")
            .arg(dir.path().join("plan.mcap"))
            .args(["--walls-only", "--layers", "A-WALL,A-COLS", "--drawing"])
            .arg(&drawing)
            .arg("--save")
            .arg(&state),
    );
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(
        text.contains("building_from_site:") && text.contains("MOVED wall (34.80, 0.00)"),
        "{text}"
    );
    let saved = scanfuse::daemon::state::PosesFile::load(&state)
        .unwrap()
        .unwrap();
    let bfs = saved
        .building_from_site
        .expect("building_from_site in poses.toml");
    assert!(bfs.aligned && (bfs.yaw_deg - b["yaw_deg"].as_f64().unwrap()).abs() < 1e-6);
    // The poses in the file stay in the anchor's frame.
    let anchor = saved.sensors.iter().find(|s| s.id == "gate").unwrap();
    assert_eq!((anchor.x_m, anchor.yaw_deg), (Some(0.0), Some(0.0)));
}

#[test]
fn svg_aligns_automatically_and_from_two_points_20cm_off_to_the_same_accuracy() {
    let dir = tempfile::tempdir().unwrap();
    let plan = repo().join("fixtures/plans/hall.toml");
    if prepare("svg_pairs", &plan, dir.path(), None).is_none() {
        return;
    }
    let drawing = dir.path().join("plan.svg");
    let svg = [
        "--drawing",
        drawing.to_str().unwrap(),
        "--scale",
        "0.01",
        "--layers",
        "A-WALL,A-COLS",
    ];
    let auto = align(dir.path(), &svg);
    assert_eq!(auto["building_from_site"]["aligned"], true, "{auto}");
    assert_within_truth(dir.path(), &auto);
    assert!(moved(&auto).is_empty(), "nothing moved: {auto}");

    // Two clicked points: the anchor (gate, at (1.2, 2.2) heading 73° in the plan) and a point
    // 5 m ahead and 3 m left of it, each clicked 12–16 cm off in the drawing.
    let yaw = 73f64.to_radians();
    let (x, y) = (5.0, 3.0);
    let (dx, dy) = (
        1.2 + yaw.cos() * x - yaw.sin() * y,
        2.2 + yaw.sin() * x + yaw.cos() * y,
    );
    let pairs = format!("0,0=1.32,2.1;{x},{y}={:.3},{:.3}", dx - 0.1, dy + 0.1);
    let mut args = svg.to_vec();
    args.extend(["--pairs", &pairs]);
    let out = align(dir.path(), &args);
    let b = &out["building_from_site"];
    assert_eq!(b["method"], "pairs+lines", "{out}");
    assert_within_truth(dir.path(), &out);
    let pair_res: Vec<f64> = out["residuals"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["kind"] == "pair")
        .map(|r| r["residual_m"].as_f64().unwrap())
        .collect();
    assert_eq!(pair_res.len(), 2, "{out}");
    assert!(
        pair_res.iter().all(|r| (0.08..0.25).contains(r)),
        "the clicks' own error shows: {out}"
    );
}

#[test]
fn a_symmetric_hall_abstains_and_asks_for_two_points() {
    let dir = tempfile::tempdir().unwrap();
    // A bare 20 × 12 m hall: turned 180° it looks the same from anywhere inside.
    let plan = dir.path().join("symmetric.toml");
    std::fs::write(
        &plan,
        r#"name = "symmetric"
[[wall]]
points = [[0, 0], [20, 0], [20, 12], [0, 12]]
closed = true
height_m = 3.0

[[sensor]]
id = "one"
model = "UTM-30LX-EW"
x = 6.0
y = 4.0
yaw_deg = 30
"#,
    )
    .unwrap();
    if prepare("symmetric", &plan, dir.path(), None).is_none() {
        return;
    }
    let drawing = dir.path().join("plan.dxf");
    let out = align(
        dir.path(),
        &["--drawing", drawing.to_str().unwrap(), "--layers", "A-WALL"],
    );
    let b = &out["building_from_site"];
    assert_eq!(b["aligned"], false, "{out}");
    let reason = b["reason"].as_str().unwrap();
    assert!(
        reason.contains("ambiguous") && reason.contains("two point"),
        "{reason}"
    );
    // The pose stays in the anchor's frame.
    let s = &out["sensors"][0];
    assert_eq!(
        (s["x_m"].as_f64(), s["yaw_deg"].as_f64()),
        (Some(0.0), Some(0.0)),
        "{out}"
    );
}

#[test]
fn a_bad_drawing_is_a_clear_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.dxf");
    std::fs::write(
        &bad,
        "0\nSECTION\n2\nHEADER\n9\n$ACADVER\n1\nAC9999\n0\nENDSEC\n0\nEOF\n",
    )
    .unwrap();
    let out = scanfuse()
        .arg("align")
        .arg(repo().join("fixtures/lab.mcap"))
        .arg("--drawing")
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("broken.dxf"), "{err}");
}

/// The lab fixture plan as a raster drawing (PGM, 2 cm per pixel, 1-pixel walls), written to
/// `dir/lab.pgm`; the raster's frame has its origin at the bottom-left corner, which is
/// (X0_M, Y0_M) in the plan's.
const RASTER_M_PER_PX: f64 = 0.02;
const X0_M: f64 = -1.0;
const Y0_M: f64 = -1.0;

fn lab_raster(dir: &Path) -> std::path::PathBuf {
    let plan = scanfuse::sim::plan::Plan::load(&repo().join("fixtures/plans/lab.toml")).unwrap();
    let (res, x0, y0, w, h) = (RASTER_M_PER_PX, X0_M, Y0_M, 1100usize, 700usize);
    let mut px = vec![255u8; w * h];
    let mut ink = |x: f64, y: f64| {
        let (c, r) = (
            ((x - x0) / res) as i64,
            h as i64 - 1 - ((y - y0) / res) as i64,
        );
        if c >= 0 && r >= 0 && (c as usize) < w && (r as usize) < h {
            px[r as usize * w + c as usize] = 0;
        }
    };
    for wall in &plan.walls {
        for (a, b) in wall.segments() {
            let steps = ((b[0] - a[0]).hypot(b[1] - a[1]) / (res / 4.0)) as usize;
            for k in 0..=steps {
                let t = k as f64 / steps.max(1) as f64;
                ink(a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t);
            }
        }
    }
    let mut pgm = format!("P5\n{w} {h}\n255\n").into_bytes();
    pgm.extend(px);
    let drawing = dir.join("lab.pgm");
    std::fs::write(&drawing, pgm).unwrap();
    drawing
}

/// `register --drawing` with a raster plan (PGM, 2 cm per pixel, 1-pixel walls drawn from the
/// fixture plan): the poses come out in the raster's frame (origin at its bottom-left corner).
#[test]
fn register_with_a_raster_drawing_gives_poses_in_its_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (x0, y0) = (X0_M, Y0_M);
    let drawing = lab_raster(dir.path());
    let rec_path = repo().join("fixtures/lab.mcap");
    let out = succeeded(
        scanfuse()
            .arg("register")
            .arg(&rec_path)
            .args(["--walls-only", "--json", "--scale", "0.02", "--drawing"])
            .arg(&drawing),
    );
    let out: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(out["building_from_site"]["aligned"], true, "{out}");
    let rec = scanfuse::record::read(&rec_path).unwrap();
    for info in &rec.sensors {
        let truth = info.truth.unwrap();
        let s = out["sensors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["id"] == info.id.as_str())
            .unwrap();
        let dx = s["x_m"].as_f64().unwrap() - (truth.x_m - x0);
        let dy = s["y_m"].as_f64().unwrap() - (truth.y_m - y0);
        let dyaw =
            (s["yaw_deg"].as_f64().unwrap() - truth.yaw_deg + 540.0).rem_euclid(360.0) - 180.0;
        assert!(
            dx.hypot(dy) < MAX_ERR_M && dyaw.abs() < 0.5,
            "{}: {:.3} m / {:.2}° ({s})",
            info.id,
            dx.hypot(dy),
            dyaw
        );
    }
}

/// `replay --drawing`: the daemon's final poses are aligned to the raster drawing, poses.toml
/// carries `building_from_site` beside the (site-frame) poses, and the map files are written
/// in building coordinates.
#[test]
fn replay_with_a_drawing_saves_building_from_site_and_building_map_files() {
    let dir = tempfile::tempdir().unwrap();
    let drawing = lab_raster(dir.path());
    let out_dir = dir.path().join("out");
    let rec_path = repo().join("fixtures/lab.mcap");
    let out = succeeded(
        scanfuse()
            .arg("replay")
            .arg(&rec_path)
            .args(["--max", "--scale", "0.02", "--out"])
            .arg(&out_dir)
            .arg("--drawing")
            .arg(&drawing),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("building_from_site:"), "{stdout}");
    let file = scanfuse::daemon::state::PosesFile::load(&out_dir)
        .unwrap()
        .expect("poses.toml");
    let b = file
        .building_from_site
        .clone()
        .expect("building_from_site in poses.toml");
    assert!(b.aligned, "{b:?}");
    let t = b.similarity().unwrap();
    let rec = scanfuse::record::read(&rec_path).unwrap();
    for info in &rec.sensors {
        let truth = info.truth.unwrap();
        let s = file.sensors.iter().find(|s| s.id == info.id).unwrap();
        assert!(s.registered, "{s:?}");
        let site = scanfuse::geometry::pose2(
            s.x_m.unwrap(),
            s.y_m.unwrap(),
            s.yaw_deg.unwrap().to_radians(),
        );
        let building = t.sensor(&site);
        let dx = building.translation.x - (truth.x_m - X0_M);
        let dy = building.translation.y - (truth.y_m - Y0_M);
        let dyaw = (building.rotation.angle().to_degrees() - truth.yaw_deg + 540.0)
            .rem_euclid(360.0)
            - 180.0;
        assert!(
            dx.hypot(dy) < MAX_ERR_M && dyaw.abs() < 0.5,
            "{}: {:.3} m / {:.2}° from truth",
            info.id,
            dx.hypot(dy),
            dyaw
        );
    }
    let yaml = std::fs::read_to_string(out_dir.join("map.yaml")).unwrap();
    assert!(yaml.contains("# frame: building"), "{yaml}");
    let ply = std::fs::read(out_dir.join("map.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..ply.len().min(512)]);
    assert!(header.contains("building frame"), "{header}");
}
