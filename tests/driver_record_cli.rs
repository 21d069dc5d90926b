//! `scanfuse record` against `scanfuse emulate`, both as processes: the recording made from the
//! emulated sensor holds the source recording's scans (ranges in mm, intensities) and its raw
//! SCIP bytes; against the emulator's faults, `record` says what is wrong with the unit and
//! leaves no file when it recorded nothing.

use crate::driver_support;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};

use driver_support::{mm, recording};
use scanfuse::record::{self, RecordingWriter};
use scanfuse::scan::{Scan, SensorInfo};
use tempfile::TempDir;

const BIN: &str = env!("CARGO_BIN_EXE_scanfuse");

/// Writes the recording every test here emulates (`scans` of `info`) to a new dir's `source.mcap`.
fn write_source(info: &SensorInfo, scans: &[Scan]) -> (TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let source = dir.path().join("source.mcap");
    let mut writer = RecordingWriter::create(&source).unwrap();
    writer.add_sensor(info).unwrap();
    for scan in scans {
        writer.write_scan(&info.id, scan).unwrap();
    }
    writer.finish().unwrap();
    (dir, source)
}

/// Starts `scanfuse emulate SOURCE ARGS…` and reads the first line it prints: where it serves.
fn emulate(source: &Path, args: &[&str]) -> (Child, String) {
    let mut emulate = Command::new(BIN)
        .arg("emulate")
        .arg(source.to_str().unwrap())
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(emulate.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (emulate, line.trim().to_string())
}

/// Runs `scanfuse record` against a running `emulate` as sensor `id` into `out`, then stops it.
fn record_from(
    mut emulate: Child,
    connect: &str,
    id: &str,
    out: &Path,
    args: &[&str],
) -> ExitStatus {
    let status = Command::new(BIN)
        .args(["record", "--connect", connect, "--id", id, "--out"])
        .arg(out.to_str().unwrap())
        .args(args)
        .stderr(Stdio::null())
        .status()
        .unwrap();
    let _ = emulate.kill();
    let _ = emulate.wait();
    status
}

#[test]
fn record_of_emulate_reproduces_the_source_scans() {
    let (info, scans) = recording(50);
    let (dir, source) = write_source(&info, &scans);

    let (emulate, addr) = emulate(&source, &["--sensor", "hall", "--listen", "127.0.0.1:0"]);
    assert!(addr.starts_with("127.0.0.1:"), "emulate printed {addr:?}");

    let out = dir.path().join("copy.mcap");
    let args = ["--scans", "50", "--seconds", "30"];
    let status = record_from(emulate, &format!("tcp://{addr}"), "copy", &out, &args);
    assert!(status.success());

    let copy = record::read(&out).unwrap();
    let sensor = copy.sensor("copy").expect("sensor recorded");
    assert_eq!(sensor.geometry, info.geometry);
    assert_eq!(
        sensor.fields.get("SERI").map(String::as_str),
        Some("H1234567")
    );
    let got = copy.scans_of("copy");
    assert_eq!(got.len(), scans.len());
    for (k, (a, b)) in got.iter().zip(&scans).enumerate() {
        assert_eq!(mm(&a.ranges_m), mm(&b.ranges_m), "scan {k}");
        assert_eq!(a.intensities, b.intensities, "scan {k}");
        assert!(a.sensor_stamp_ms.is_some() || a.stamp_ns > 0);
    }
    assert!(got.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
    assert!(
        copy.scip_messages.get("copy").copied().unwrap_or(0) > 0,
        "raw SCIP kept on /copy/scip"
    );
}

#[test]
fn emulate_and_record_refuse_bad_input_with_exit_code_2() {
    let (info, scans) = recording(2);
    let (dir, source) = write_source(&info, &scans[..1]);
    let out = Command::new(BIN)
        .args([
            "emulate",
            source.to_str().unwrap(),
            "--sensor",
            "nope",
            "--listen",
            "127.0.0.1:0",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("hall"),
        "names the sensors it has"
    );
    let out = Command::new(BIN)
        .args(["record", "--connect", "udp://x", "--id", "a", "--out"])
        .arg(dir.path().join("x.mcap"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("tcp://HOST:PORT"));
}

#[test]
fn record_reads_emulate_over_a_pty() {
    let (info, scans) = recording(20);
    let (dir, source) = write_source(&info, &scans);
    let (emulate, path) = emulate(&source, &["--pty"]);
    assert!(path.starts_with("/dev/"), "emulate printed {path:?}");
    let out = dir.path().join("copy.mcap");
    let args = ["--scans", "20", "--seconds", "30", "--mode", "MD"];
    let status = record_from(emulate, &format!("serial://{path}"), "usb", &out, &args);
    assert!(status.success());
    let copy = record::read(&out).unwrap();
    let got = copy.scans_of("usb");
    assert_eq!(got.len(), 20);
    for (a, b) in got.iter().zip(&scans) {
        assert_eq!(mm(&a.ranges_m), mm(&b.ranges_m));
        assert!(a.intensities.is_empty(), "MD carries no intensities");
    }
}

/// `record_from`, keeping what `record` printed.
fn record_output(mut emulate: Child, connect: &str, out: &Path, args: &[&str]) -> Output {
    let output = record_cmd(connect, out, args);
    let _ = emulate.kill();
    let _ = emulate.wait();
    output
}

fn record_cmd(connect: &str, out: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(["record", "--connect", connect, "--id", "copy", "--out"])
        .arg(out.to_str().unwrap())
        .args(args)
        .env("RUST_LOG", "info")
        .output()
        .unwrap()
}

/// Neither the recording nor its `.partial` exists.
fn assert_no_file(out: &Path) {
    assert!(!out.exists(), "{} written", out.display());
    let partial = record::partial_path(out);
    assert!(!partial.exists(), "{} left behind", partial.display());
}

#[test]
fn record_in_a_mode_the_unit_lacks_fails_at_once_and_writes_nothing() {
    let (info, scans) = recording(20);
    let (dir, source) = write_source(&info, &scans);
    let (emulate, addr) = emulate(
        &source,
        &["--listen", "127.0.0.1:0", "--loop", "--no-multi-echo"],
    );
    let out = dir.path().join("copy.mcap");
    let args = ["--mode", "ND", "--seconds", "60"];
    let output = record_output(emulate, &format!("tcp://{addr}"), &out, &args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr
            .contains("this UTM-30LX-EW answers 0E to ND: it has no multi-echo mode; use MD or ME"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("reconnecting"),
        "no reconnect loop:\n{stderr}"
    );
    assert_no_file(&out);
}

#[test]
fn record_of_a_unit_that_accepts_but_never_answers_names_another_client() {
    let dir = tempfile::tempdir().unwrap();
    // Accepts connections and holds them without a word, as a unit serving another client.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for stream in listener.incoming() {
            held.push(stream);
        }
    });
    let out = dir.path().join("copy.mcap");
    let output = record_cmd(&format!("tcp://{addr}"), &out, &["--seconds", "3"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr.contains("accepted the connection but sent no answer to QT within 2s: another client may hold the unit (Hokuyo units serve one client at a time)"),
        "{stderr}"
    );
    assert_no_file(&out);
}

#[test]
fn record_reboots_a_unit_in_its_abnormal_state_and_records_it() {
    let (info, scans) = recording(30);
    let (dir, source) = write_source(&info, &scans);
    let (emulate, addr) = emulate(
        &source,
        &["--listen", "127.0.0.1:0", "--abnormal-until-reboots", "1"],
    );
    let out = dir.path().join("copy.mcap");
    let args = ["--scans", "10", "--seconds", "60"];
    let output = record_output(emulate, &format!("tcp://{addr}"), &out, &args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("abnormal state (0L)"), "{stderr}");
    assert!(stderr.contains("rebooting it (RB twice)"), "{stderr}");
    let got = record::read(&out).unwrap().scans_of("copy").to_vec();
    assert_eq!(got.len(), 10);
    assert_eq!(mm(&got[0].ranges_m), mm(&scans[0].ranges_m));
}

#[test]
fn record_waits_out_a_booting_unit_and_says_it_is_booting() {
    let (info, scans) = recording(30);
    let (dir, source) = write_source(&info, &scans);
    let (emulate, addr) = emulate(
        &source,
        &["--listen", "127.0.0.1:0", "--booting-ms", "2500"],
    );
    let out = dir.path().join("copy.mcap");
    let args = ["--scans", "5", "--seconds", "60"];
    let output = record_output(emulate, &format!("tcp://{addr}"), &out, &args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("the unit is still booting"), "{stderr}");
    assert!(!stderr.contains("TM1"), "{stderr}");
    assert_eq!(record::read(&out).unwrap().scans_of("copy").len(), 5);
}

#[test]
fn record_of_a_unit_with_no_returns_keeps_its_empty_scans() {
    let (info, scans) = recording(10);
    let (dir, source) = write_source(&info, &scans);
    let (emulate, addr) = emulate(&source, &["--listen", "127.0.0.1:0", "--no-returns"]);
    let out = dir.path().join("copy.mcap");
    let args = ["--scans", "5", "--seconds", "60"];
    let output = record_output(emulate, &format!("tcp://{addr}"), &out, &args);
    assert!(output.status.success());
    let got = record::read(&out).unwrap().scans_of("copy").to_vec();
    assert_eq!(got.len(), 5);
    assert!(got.iter().all(|s| mm(&s.ranges_m).iter().all(|&r| r == 0)));
}
