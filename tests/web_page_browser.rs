//! The live page in a real browser: `scanfuse run` on the replayed `hall` site serves it on
//! loopback, and tests/python/web_page.py (Playwright driving Debian's headless Chromium)
//! opens it, waits for `data-ready`, checks every drawn sensor's `data-sensor` and
//! `data-pose` against the status socket's `poses`, drags one sensor and checks that `poses`
//! then shows it surveyed where it was dropped. It leaves a screenshot in
//! `target/web-page.png` (the one in docs/ is such a picture).
//!
//! Needs SCANFUSE_TEST_PYTHON (the venv .ci/run builds) and /usr/bin/chromium (.ci/run
//! installs it); skips without them, except under CI.

mod common;
mod daemon_run_common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use daemon_run_common::*;

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
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port");
    let hall = fixture("hall.mcap");
    let sensors = replay_sensors(&hall, &HALL);
    let config = write_config(
        dir.path(),
        "gate",
        &sensors,
        &format!("\n[web]\nlisten = \"127.0.0.1:{port}\"\n"),
    );
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
    let screenshot = common::repo().join("target/web-page.png");
    let out = Command::new(python)
        .arg(common::repo().join("tests/python/web_page.py"))
        .args(["--url", &format!("http://127.0.0.1:{port}/")])
        .arg("--socket")
        .arg(&sock)
        .arg("--screenshot")
        .arg(&screenshot)
        .args(["--browser", CHROMIUM])
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
    assert!(summary["moved_m"].as_f64().unwrap() > 0.05, "{summary}");
    assert!(
        std::fs::metadata(&screenshot).is_ok_and(|m| m.len() > 10_000),
        "a screenshot"
    );
    // The drop is kept in state_dir, to survive a restart.
    let surveys = std::fs::read_to_string(dir.path().join("state/surveys.toml")).unwrap();
    let dragged = summary["dragged"].as_str().unwrap();
    assert!(
        surveys.contains(&format!("id = \"{dragged}\"")),
        "{surveys}"
    );
}
