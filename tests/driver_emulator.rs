//! Driver ↔ emulator over real loopback sockets: every scan arrives with the recorded ranges,
//! and each injected fault is recovered from with the counters saying what happened.

use crate::driver_support;

use std::time::Duration;

use driver_support::{Harness, emulator, emulator_with, mm, recording};
use scanfuse::emulator::faults::GARBAGE;
use scanfuse::emulator::{EmulatorConfig, Faults, SyntheticEchoes};
use scanfuse::scip::Echo;
use scanfuse::sensor::ScanMode;

#[tokio::test]
async fn every_scan_arrives_with_the_recorded_ranges_and_monotonic_stamps() {
    let (info, scans) = recording(60);
    let (emu, uri) = emulator(&info, &scans, EmulatorConfig::default()).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(60, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 60, "every recorded scan arrives");
    for (k, (out, src)) in got.iter().zip(&scans).enumerate() {
        assert_eq!(
            mm(&out.scan.ranges_m),
            mm(&src.ranges_m),
            "scan {k}: ranges in mm"
        );
        assert_eq!(
            out.scan.intensities, src.intensities,
            "scan {k}: intensities"
        );
        assert!((out.scan.start_angle_rad - src.start_angle_rad).abs() < 1e-9);
        assert!((out.scan.end_angle_rad - src.end_angle_rad).abs() < 1e-9);
    }
    for pair in got.windows(2) {
        assert!(
            pair[1].scan.stamp_ns > pair[0].scan.stamp_ns,
            "host stamps increase"
        );
        let (a, b) = (
            pair[0].scan.sensor_stamp_ms.unwrap(),
            pair[1].scan.sensor_stamp_ms.unwrap(),
        );
        // One block per recorded period (25 ms), on the emulator's TM1 clock.
        assert!(b > a && b - a < 60, "sensor stamps {a} → {b}");
        let (ma, mb) = (pair[0].measured_ns.unwrap(), pair[1].measured_ns.unwrap());
        assert!(mb > ma);
    }
    // The TM1-synced sensor time is never after the host received the scan (beyond jitter).
    for s in &got {
        let lead_ms = (s.measured_ns.unwrap() as i128 - s.scan.stamp_ns as i128) as f64 / 1e6;
        assert!(lead_ms < 5.0, "measured {lead_ms} ms after arrival");
    }
    let counters = driver.counters.snapshot();
    assert_eq!(
        (counters.connects, counters.scans, counters.checksum_errors),
        (1, 60, 0)
    );
    assert_eq!(counters.time_syncs, 1);
    assert_eq!(emu.stats().scans_sent, 60);
    driver.stop().await;
}

#[tokio::test]
async fn md_and_nd_streams_carry_ranges_without_intensities() {
    let (info, scans) = recording(8);
    for mode in [ScanMode::Md, ScanMode::Nd] {
        let (_emu, uri) = emulator(&info, &scans, EmulatorConfig::default()).await;
        let mut driver = Harness::start(&uri, mode, |_| {});
        let got = driver.scans(8, Duration::from_secs(5)).await;
        assert_eq!(got.len(), 8, "{mode:?}");
        assert_eq!(mm(&got[3].scan.ranges_m), mm(&scans[3].ranges_m));
        assert!(got[3].scan.intensities.is_empty());
        driver.stop().await;
    }
}

#[tokio::test]
async fn a_dropped_connection_is_reconnected_and_counted() {
    let (info, scans) = recording(40);
    let faults = Faults {
        drop_after_scans: Some(10),
        ..Faults::default()
    };
    let (emu, uri) = emulator_with(&info, &scans, faults, true).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(30, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 30);
    let c = driver.counters.snapshot();
    assert_eq!(emu.stats().dropped, 1);
    assert_eq!(c.connects, 2, "{c:?}");
    assert!(c.reconnects >= 1, "{c:?}");
    assert!(
        c.last_error.as_deref().unwrap_or("").contains("closed"),
        "{c:?}"
    );
    // Ranges still match the recording (scan k of the loop is recorded scan k % 40).
    let last = got.last().unwrap();
    assert!(
        scans
            .iter()
            .any(|s| mm(&s.ranges_m) == mm(&last.scan.ranges_m))
    );
    driver.stop().await;
}

#[tokio::test]
async fn corrupted_scans_are_dropped_and_counted_never_published() {
    let (info, scans) = recording(40);
    let faults = Faults {
        corrupt_every: Some(5),
        ..Faults::default()
    };
    let (emu, uri) = emulator_with(&info, &scans, faults, false).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(32, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 32);
    emu.finished().await;
    let c = driver
        .counters_until(Duration::from_secs(2), |c| c.checksum_errors >= 8)
        .await;
    assert_eq!(emu.stats().corrupted, 8);
    assert_eq!((c.scans, c.checksum_errors), (32, 8), "{c:?}");
    // The published ones are exactly the uncorrupted recorded scans (every 5th is missing).
    let expected: Vec<Vec<u32>> = scans
        .iter()
        .enumerate()
        .filter(|(k, _)| (k + 1) % 5 != 0)
        .map(|(_, s)| mm(&s.ranges_m))
        .collect();
    let published: Vec<Vec<u32>> = got.iter().map(|s| mm(&s.scan.ranges_m)).collect();
    assert_eq!(published, expected);
    driver.stop().await;
}

#[tokio::test]
async fn injected_garbage_is_skipped_and_counted_byte_for_byte() {
    let (info, scans) = recording(20);
    let faults = Faults {
        garbage_every: Some(4),
        ..Faults::default()
    };
    let (emu, uri) = emulator_with(&info, &scans, faults, false).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(20, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 20, "garbage costs no scan");
    let bursts = emu.stats().garbage_bursts;
    assert_eq!(bursts, 5);
    let c = driver
        .counters_until(Duration::from_secs(1), |c| {
            c.skipped_bytes >= bursts * GARBAGE.len() as u64
        })
        .await;
    assert_eq!(c.skipped_bytes, bursts * GARBAGE.len() as u64, "{c:?}");
    assert_eq!(c.reconnects, 0);
    driver.stop().await;
}

#[tokio::test]
async fn a_stalled_sensor_trips_the_watchdog_and_the_driver_reconnects() {
    let (info, scans) = recording(40);
    let faults = Faults {
        stall: Some((10, Duration::from_millis(800))),
        ..Faults::default()
    };
    let (emu, uri) = emulator_with(&info, &scans, faults, true).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(30, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 30);
    let c = driver.counters.snapshot();
    assert_eq!(emu.stats().stalls, 1);
    assert!(c.watchdog_timeouts >= 1, "{c:?}");
    assert!(c.connects >= 2, "{c:?}");
    assert!(
        c.last_error.as_deref().unwrap_or("").contains("watchdog"),
        "{c:?}"
    );
    driver.stop().await;
}

#[tokio::test]
async fn refused_connections_are_retried_with_backoff() {
    let (info, scans) = recording(20);
    let faults = Faults {
        refuse_for: Some(Duration::from_millis(500)),
        ..Faults::default()
    };
    let (emu, uri) = emulator_with(&info, &scans, faults, true).await;
    let started = tokio::time::Instant::now();
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(5, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 5);
    assert!(started.elapsed() >= Duration::from_millis(500));
    let c = driver.counters.snapshot();
    let refused = emu.stats().refused;
    // Backoff 50, 100, 200, 400 (capped) ms: a handful of attempts in 0.5 s, not hundreds.
    assert!((2..=6).contains(&refused), "refused {refused}");
    assert_eq!(c.reconnects, refused, "{c:?}");
    assert_eq!(c.connects, 1);
    driver.stop().await;
}

#[tokio::test]
async fn an_absent_sensor_is_retried_without_end_and_reports_why() {
    // A port nobody listens on.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    drop(listener);
    let mut driver = Harness::start(&format!("tcp://{addr}"), ScanMode::Me, |_| {});
    let c = driver
        .counters_until(Duration::from_secs(3), |c| c.reconnects >= 3)
        .await;
    assert!(c.reconnects >= 3, "{c:?}");
    assert_eq!(c.connects, 0);
    assert!(
        c.last_error
            .as_deref()
            .unwrap_or("")
            .contains(&addr.to_string()),
        "{c:?}"
    );
    driver.stop().await;
}

#[tokio::test]
async fn stopping_the_driver_sends_qt_and_closes_the_link() {
    let (info, scans) = recording(20);
    let (emu, uri) = emulator(
        &info,
        &scans,
        EmulatorConfig {
            looping: true,
            ..Default::default()
        },
    )
    .await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    assert_eq!(driver.scans(5, Duration::from_secs(5)).await.len(), 5);
    let before = emu.stats();
    // The handshake's QT (stopping a stream left by an earlier client) is the only one so far.
    assert_eq!((before.quits, before.client_closes), (1, 0), "{before:?}");
    driver.shutdown.send(true).unwrap();
    tokio::time::timeout(Duration::from_secs(3), driver.task)
        .await
        .expect("the driver stops within its QT bound")
        .expect("no panic");
    // The emulator reads the QT and then the end of the stream (it may lag the driver a bit).
    let deadline = tokio::time::Instant::now() + Duration::from_secs(2);
    let after = loop {
        let s = emu.stats();
        if s.client_closes == 1 || tokio::time::Instant::now() > deadline {
            break s;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    assert_eq!((after.quits, after.client_closes), (2, 1), "{after:?}");
    assert_eq!(after.dropped, 0);
}

#[tokio::test]
async fn multi_echo_streams_carry_the_emulators_synthetic_second_echoes() {
    // Recordings hold one echo per step; the emulator makes up a second one 500 mm behind
    // every 10th value so the ND/NE path is exercised end to end.
    let (info, scans) = recording(8);
    let synthetic = SyntheticEchoes {
        every: 10,
        behind_mm: 500,
    };
    for mode in [ScanMode::Nd, ScanMode::Ne] {
        let (_emu, uri) = emulator(
            &info,
            &scans,
            EmulatorConfig {
                synthetic_echoes: Some(synthetic),
                ..Default::default()
            },
        )
        .await;
        let mut driver = Harness::start(&uri, mode, |_| {});
        let got = driver.scans(8, Duration::from_secs(5)).await;
        assert_eq!(got.len(), 8, "{mode:?}");
        for (k, (out, src)) in got.iter().zip(&scans).enumerate() {
            let ranges = mm(&src.ranges_m);
            assert_eq!(
                mm(&out.scan.ranges_m),
                ranges,
                "{mode:?} scan {k}: first echoes"
            );
            let expected: Vec<Echo> = ranges
                .iter()
                .enumerate()
                .filter(|(i, r)| i % 10 == 0 && **r > 0)
                .map(|(i, &r)| Echo {
                    index: i as u32,
                    range_mm: r + 500,
                    intensity: if mode == ScanMode::Ne {
                        src.intensities[i] as u32 / 2
                    } else {
                        0
                    },
                })
                .collect();
            assert!(!expected.is_empty());
            assert_eq!(
                out.extra_echoes, expected,
                "{mode:?} scan {k}: second echoes"
            );
            if mode == ScanMode::Ne {
                assert_eq!(out.scan.intensities, src.intensities);
            }
        }
        assert_eq!(driver.counters.snapshot().decode_errors, 0);
        driver.stop().await;
    }
}

/// `no_returns`: a unit that sees nothing (covered window) still streams, every range 0.
#[tokio::test]
async fn a_unit_with_no_returns_streams_scans_without_a_single_range() {
    let (info, scans) = recording(10);
    let faults = Faults {
        no_returns: true,
        ..Faults::default()
    };
    let (_emu, uri) = emulator_with(&info, &scans, faults, false).await;
    let mut driver = Harness::start(&uri, ScanMode::Me, |_| {});
    let got = driver.scans(10, Duration::from_secs(10)).await;
    assert_eq!(got.len(), 10);
    for scan in &got {
        assert_eq!(scan.scan.ranges_m.len(), scans[0].ranges_m.len());
        assert!(scan.scan.ranges_m.iter().all(|&r| r == 0.0 || r.is_nan()));
        assert!(scan.scan.intensities.iter().all(|&i| i == 0.0));
    }
    driver.stop().await;
}
