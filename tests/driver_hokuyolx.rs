//! An independent client: hokuyolx (PyPI, a Python SCIP client nobody here wrote) reads scans
//! from the emulator and gets the recorded ranges.
//!
//! Needs a Python with hokuyolx and numpy: `$SCANFUSE_TEST_PYTHON` (the venv `.ci/run` builds
//! from tests/python/requirements.txt, which needs the lines `hokuyolx==0.9.0` and `numpy`),
//! `$HOKUYOLX_PYTHON`, or `target/hokuyolx-venv/bin/python`. Without one that can
//! `import hokuyolx` the test says it skipped and passes.

use crate::driver_support;

use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use driver_support::{emulator, mm, recording};
use scanfuse::emulator::EmulatorConfig;

fn python() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("SCANFUSE_TEST_PYTHON").map(PathBuf::from),
        std::env::var_os("HOKUYOLX_PYTHON").map(PathBuf::from),
        Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/hokuyolx-venv/bin/python")),
    ];
    candidates.into_iter().flatten().find(|python| {
        std::process::Command::new(python)
            .args(["-c", "import hokuyolx, numpy"])
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    })
}

#[tokio::test]
async fn hokuyolx_reads_the_recorded_ranges_from_the_emulator() {
    let Some(python) = python() else {
        // CI installs it (.ci/run, tests/python/requirements.txt): there, absence is a failure.
        assert!(
            std::env::var_os("CI").is_none(),
            "no Python with hokuyolx under CI: .ci/run should have installed it"
        );
        eprintln!(
            "SKIPPED: no Python with hokuyolx (set HOKUYOLX_PYTHON or make target/hokuyolx-venv)"
        );
        return;
    };
    let (info, scans) = recording(400);
    let (emu, uri) = emulator(
        &info,
        &scans,
        EmulatorConfig {
            looping: true,
            ..Default::default()
        },
    )
    .await;
    let addr = uri.trim_start_matches("tcp://");
    let (host, port) = addr.rsplit_once(':').unwrap();
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/driver_hokuyolx.py");
    let (host, port) = (host.to_string(), port.to_string());
    let run = tokio::task::spawn_blocking(move || {
        std::process::Command::new(python)
            .arg(script)
            .args([&host, &port, "40"])
            .stdin(Stdio::null())
            .output()
    });
    let output = tokio::time::timeout(Duration::from_secs(90), run)
        .await
        .expect("hokuyolx finishes within 90 s")
        .unwrap()
        .unwrap();
    assert!(
        output.status.success(),
        "hokuyolx failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let got: Vec<serde_json::Value> = String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    assert_eq!(got.len(), 41, "one GD and 40 ME scans");

    let as_u32 = |v: &serde_json::Value| -> Vec<u32> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap() as u32)
            .collect()
    };
    // GD before any stream: the recording's first scan.
    assert_eq!(got[0]["cmd"], "GD");
    assert_eq!(as_u32(&got[0]["ranges"]), mm(&scans[0].ranges_m));
    // ME: each scan is a recorded scan, in recorded order, with its intensities.
    let mut last_index = None;
    for scan in &got[1..] {
        let ranges = as_u32(&scan["ranges"]);
        let index = scans
            .iter()
            .position(|s| mm(&s.ranges_m) == ranges)
            .expect("a recorded scan");
        let intensities: Vec<f32> = as_u32(&scan["intensities"])
            .iter()
            .map(|&i| i as f32)
            .collect();
        assert_eq!(intensities, scans[index].intensities);
        if let Some(last) = last_index {
            assert!(index > last, "scans in recorded order: {last} then {index}");
        }
        last_index = Some(index);
    }
    assert!(emu.stats().scans_sent >= 40);
}
