//! The systemd unit passes `systemd-analyze verify` and scores OK in
//! `systemd-analyze security --offline`. Skipped (with a message) where systemd-analyze is not
//! installed; on Debian it comes with `apt-get install -y systemd`.

use std::path::Path;
use std::process::Command;

/// The unit with `/usr/bin/scanfuse` replaced by the binary under test, because `verify`
/// checks that ExecStart's program exists.
fn unit_for_test(dir: &Path) -> std::path::PathBuf {
    let unit = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/scanfuse.service"),
    )
    .unwrap();
    assert!(unit.contains("ExecStart=/usr/bin/scanfuse run --config"));
    let path = dir.join("scanfuse.service");
    std::fs::write(
        &path,
        unit.replace("/usr/bin/scanfuse", env!("CARGO_BIN_EXE_scanfuse")),
    )
    .unwrap();
    path
}

fn analyze_available() -> bool {
    let found = Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        eprintln!("SKIPPED: systemd-analyze is not installed (apt-get install -y systemd)");
    }
    found
}

#[test]
fn the_unit_verifies_cleanly() {
    if !analyze_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let unit = unit_for_test(dir.path());
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&unit)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.trim().is_empty(), "verify warns: {stderr}");
}

#[test]
fn the_unit_is_hardened() {
    if !analyze_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let unit = unit_for_test(dir.path());
    // Exposure is shown 0.0 (locked down) … 10.0 (unsafe); --threshold counts tenths. The unit
    // scores 1.7; anything above 3.0 means a hardening line was lost.
    let out = Command::new("systemd-analyze")
        .args(["security", "--offline=true", "--threshold=30"])
        .arg(&unit)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "exposure above 3:\n{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&unit).unwrap();
    for line in [
        "Type=notify",
        "WatchdogSec=",
        "DynamicUser=yes",
        "StateDirectory=scanfuse",
        "RuntimeDirectory=scanfuse",
        "ConfigurationDirectory=scanfuse",
        "ProtectSystem=strict",
        "ProtectHome=yes",
        "NoNewPrivileges=yes",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6",
        "DeviceAllow=char-ttyACM rw",
    ] {
        assert!(
            text.lines().any(|l| l.starts_with(line)),
            "the unit lacks {line}"
        );
    }
}
