//! The serial path: the emulator on one end of a pty, the driver opening the other end as
//! `serial:///dev/pts/N`, exactly as it opens a USB Hokuyo.

use crate::driver_support;

use std::time::Duration;

use driver_support::{Harness, mm, recording};
use scanfuse::emulator::{Emulator, EmulatorConfig, Faults};
use scanfuse::sensor::ScanMode;
use scanfuse::sensor::transport::connect;
use serialport::{SerialPort, TTYPort};

#[tokio::test]
async fn scans_arrive_over_a_pty_and_a_corrupted_one_is_dropped() {
    let (info, scans) = recording(30);
    let faults = Faults {
        corrupt_every: Some(10),
        ..Faults::default()
    };
    let emulator = Emulator::new(
        &info,
        &scans,
        EmulatorConfig {
            faults,
            ..Default::default()
        },
    )
    .unwrap();
    let (master, slave) = TTYPort::pair().expect("this system can open a pty");
    let path = slave.name().expect("pty has a name");
    let serving = emulator.clone();
    tokio::spawn(async move {
        serving
            .serve_serial(Box::new(master) as Box<dyn SerialPort>)
            .await
    });

    // Two thread hops per direction can lag past 3 scan periods on a loaded machine; the
    // watchdog has its own exact test (driver_paused_clock.rs), here it must not interfere.
    let mut driver = Harness::start(&format!("serial://{path}"), ScanMode::Me, |c| {
        c.watchdog_periods = 40.0;
    });
    let got = driver.scans(27, Duration::from_secs(15)).await;
    assert_eq!(got.len(), 27, "every uncorrupted scan arrives over the pty");
    let expected: Vec<Vec<u32>> = scans
        .iter()
        .enumerate()
        .filter(|(k, _)| (k + 1) % 10 != 0)
        .map(|(_, s)| mm(&s.ranges_m))
        .collect();
    let published: Vec<Vec<u32>> = got.iter().map(|s| mm(&s.scan.ranges_m)).collect();
    assert_eq!(published, expected);
    let c = driver
        .counters_until(Duration::from_secs(2), |c| c.checksum_errors >= 3)
        .await;
    assert_eq!((c.connects, c.checksum_errors), (1, 3), "{c:?}");
    assert!(
        got.windows(2)
            .all(|w| w[1].scan.stamp_ns > w[0].scan.stamp_ns)
    );
    driver.stop().await;
    drop(slave);
}

/// A driver that drops its serial link (watchdog, error) must be able to open the same device
/// again at once, even when the device sends nothing: the bridge threads let go of the port.
#[tokio::test]
async fn a_dropped_serial_link_releases_the_port_for_the_next_open() {
    let (_master, slave) = TTYPort::pair().expect("this system can open a pty");
    let uri = format!("serial://{}", slave.name().expect("pty has a name"));
    let link = connect(&uri, Duration::from_secs(1))
        .await
        .expect("first open");
    drop(link);
    let deadline = tokio::time::Instant::now() + Duration::from_secs(3);
    loop {
        match connect(&uri, Duration::from_secs(1)).await {
            Ok(_) => break,
            Err(_) if tokio::time::Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Err(e) => panic!("the port was never released: {e}"),
        }
    }
    drop(slave);
}
