//! The sensor's 24-bit ms clock wraps every 2^24 ms (4 h 40 min). `scanfuse emulate
//! --clock-start-ms` starts it 1.5 s before the wrap (and `--clock-drift-ppm` makes it run
//! fast), so the driver, over loopback, crosses the wrap within seconds: its unwrapped sensor
//! stamps go on past 2^24 without a jump and every host-side stamp stays monotonic.

use crate::driver_support;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use driver_support::{Harness, recording};
use scanfuse::record::RecordingWriter;
use scanfuse::sensor::ScanMode;

const BIN: &str = env!("CARGO_BIN_EXE_scanfuse");
const WRAP_MS: u64 = 1 << 24;
const DRIFT_PPM: f64 = 20_000.0;

/// Kills the emulator process however the test ends.
struct Emulate(Child);

impl Drop for Emulate {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unwrapped_stamps_continue_across_the_24_bit_wrap() {
    let dir = tempfile::tempdir().unwrap();
    let source = dir.path().join("source.mcap");
    let (info, scans) = recording(40);
    let mut writer = RecordingWriter::create(&source).unwrap();
    writer.add_sensor(&info).unwrap();
    for scan in &scans {
        writer.write_scan(&info.id, scan).unwrap();
    }
    writer.finish().unwrap();

    let start_ms = WRAP_MS - 1500;
    let mut child = Command::new(BIN)
        .args(["emulate", source.to_str().unwrap(), "--sensor", "hall"])
        .args(["--listen", "127.0.0.1:0", "--loop"])
        .args(["--clock-start-ms", &start_ms.to_string()])
        .args(["--clock-drift-ppm", &DRIFT_PPM.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let _emulate = Emulate(child);
    let mut addr = String::new();
    BufReader::new(stdout).read_line(&mut addr).unwrap();
    let addr = addr.trim();
    assert!(addr.starts_with("127.0.0.1:"), "emulate printed {addr:?}");

    let mut driver = Harness::start(&format!("tcp://{addr}"), ScanMode::Me, |_| {});
    // 3.5 s of scans at 40 Hz: the wrap falls about 1.5 s in.
    let got = driver.scans(140, Duration::from_secs(20)).await;
    let c = driver.counters.snapshot();
    driver.stop().await;
    assert_eq!(got.len(), 140, "{c:?}");
    assert_eq!(c.connects, 1, "one connection throughout: {c:?}");

    let sensor: Vec<u64> = got
        .iter()
        .map(|s| s.scan.sensor_stamp_ms.unwrap())
        .collect();
    let first = sensor[0];
    let last = sensor[sensor.len() - 1];
    assert!(
        (start_ms..WRAP_MS).contains(&first),
        "starts just before the wrap: {first}"
    );
    assert!(last > WRAP_MS + 1000, "continues past the wrap: {last}");
    for (k, pair) in sensor.windows(2).enumerate() {
        let step = pair[1] as i64 - pair[0] as i64;
        // One recorded period (25 ms, 2 % fast) per scan; a missed wrap would be −2^24.
        assert!(
            (1..=60).contains(&step),
            "scan {k}: {} → {}",
            pair[0],
            pair[1]
        );
    }
    for (k, pair) in got.windows(2).enumerate() {
        assert!(
            pair[1].scan.stamp_ns > pair[0].scan.stamp_ns,
            "host stamps, scan {k}"
        );
        let (a, b) = (pair[0].measured_ns.unwrap(), pair[1].measured_ns.unwrap());
        assert!(
            b > a && b - a < 60_000_000,
            "measured stamps, scan {k}: {a} → {b}"
        );
    }

    // The drift is visible in the lower envelope of arrival − sensor time (transmission
    // delays only add): a clock 2 % fast gains ≈ 2 % of the elapsed time on the host's.
    let lag_ms = |s: &scanfuse::sensor::SensorScan| {
        s.scan.stamp_ns as f64 / 1e6 - s.scan.sensor_stamp_ms.unwrap() as f64
    };
    let early = got[..20].iter().map(lag_ms).fold(f64::INFINITY, f64::min);
    let late = got[got.len() - 20..]
        .iter()
        .map(lag_ms)
        .fold(f64::INFINITY, f64::min);
    let elapsed_ms = (last - first) as f64;
    let expected_gain_ms = elapsed_ms * DRIFT_PPM / (1e6 + DRIFT_PPM);
    let gain_ms = early - late;
    assert!(
        (gain_ms - expected_gain_ms).abs() < 25.0,
        "sensor clock gained {gain_ms:.1} ms over {elapsed_ms} ms, expected {expected_gain_ms:.1}"
    );
}
