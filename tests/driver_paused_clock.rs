//! The driver's timing on tokio's paused clock, with the emulator in the same process over an
//! in-memory link: backoff, watchdog and time sync are checked to the millisecond, in no time.

use crate::driver_support;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use driver_support::{mm, recording};
use scanfuse::emulator::{Emulator, EmulatorConfig, Faults};
use scanfuse::scan::{Scan, SensorInfo};
use scanfuse::sensor::driver::{ABNORMAL_SESSIONS_BEFORE_REBOOT, MAX_REBOOTS};
use scanfuse::sensor::{
    Connector, Driver, DriverConfig, DriverEvent, Link, ScanMode, TransportError,
};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;

/// Connects to `emulator` in memory, refusing the first `refuse` attempts; logs every attempt.
fn connector(emulator: Emulator, refuse: usize, attempts: Arc<Mutex<Vec<Instant>>>) -> Connector {
    Arc::new(move || {
        let emulator = emulator.clone();
        let attempts = attempts.clone();
        Box::pin(async move {
            let n = {
                let mut a = attempts.lock().unwrap();
                a.push(Instant::now());
                a.len()
            };
            if n <= refuse {
                return Err(TransportError::Io {
                    uri: "memory://emulator".into(),
                    source: std::io::ErrorKind::ConnectionRefused.into(),
                });
            }
            let (ours, theirs) = tokio::io::duplex(256 * 1024);
            tokio::spawn(async move { emulator.serve_stream(theirs).await });
            Ok(Link::Memory(ours))
        })
    })
}

fn config() -> DriverConfig {
    let mut config = DriverConfig::new("hall", "memory://emulator");
    config.mode = ScanMode::Me;
    config.backoff_initial = Duration::from_millis(100);
    config.backoff_max = Duration::from_millis(800);
    config
}

/// Every test's looping emulator, to serve in memory (`driver_support::emulator_with` binds TCP).
fn looping_emulator(info: &SensorInfo, scans: &[Scan], faults: Faults) -> Emulator {
    let config = EmulatorConfig {
        looping: true,
        faults,
        ..Default::default()
    };
    Emulator::new(info, scans, config).unwrap()
}

/// Starts `driver` as every test here does: its events, the stop switch and the task to await.
fn spawn(
    driver: Driver,
) -> (
    mpsc::Receiver<DriverEvent>,
    watch::Sender<bool>,
    JoinHandle<()>,
) {
    let (tx, rx) = mpsc::channel(1024);
    let (stop, stop_rx) = watch::channel(false);
    let task = tokio::spawn(driver.run(tx, stop_rx));
    (rx, stop, task)
}

#[tokio::test(start_paused = true)]
async fn backoff_doubles_up_to_its_cap() {
    let (info, scans) = recording(20);
    let emulator = looping_emulator(&info, &scans, Faults::default());
    let attempts = Arc::new(Mutex::new(Vec::new()));
    let driver = Driver::with_connector(config(), connector(emulator, 6, attempts.clone()));
    let counters = driver.counters();
    let (mut rx, stop, task) = spawn(driver);
    while !matches!(rx.recv().await, Some(DriverEvent::Scan(_))) {}
    let attempts = attempts.lock().unwrap().clone();
    let gaps_ms: Vec<u128> = attempts
        .windows(2)
        .map(|w| (w[1] - w[0]).as_millis())
        .collect();
    assert_eq!(gaps_ms, vec![100, 200, 400, 800, 800, 800]);
    let c = counters.snapshot();
    assert_eq!((c.reconnects, c.connects), (6, 1));
    assert!(c.last_error.unwrap().contains("memory://emulator"));
    stop.send(true).unwrap();
    task.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn watchdog_fires_three_periods_after_the_last_scan_and_sync_is_exact() {
    let (info, scans) = recording(40);
    let faults = Faults {
        stall: Some((5, Duration::from_secs(5))),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let driver = Driver::with_connector(config(), connector(emulator, 0, Arc::default()));
    let counters = driver.counters();
    let (mut rx, stop, task) = spawn(driver);
    let mut last_scan_at = None;
    let mut got = Vec::new();
    let silence = loop {
        match rx.recv().await.unwrap() {
            DriverEvent::Scan(scan) => {
                last_scan_at = Some(Instant::now());
                got.push(scan);
            }
            DriverEvent::Disconnected { reason } => {
                assert!(reason.contains("watchdog"), "{reason}");
                break Instant::now() - last_scan_at.unwrap();
            }
            _ => {}
        }
    };
    // UTM-30LX-EW: 25 ms per scan, watchdog 3 periods.
    assert_eq!(silence, Duration::from_millis(75));
    assert_eq!(got.len(), 5);
    for (k, scan) in got.iter().enumerate() {
        assert_eq!(mm(&scan.scan.ranges_m), mm(&scans[k].ranges_m));
        // No transmission delay in memory: the synced sensor time is the arrival time, to the ms.
        let error_ns = scan.measured_ns.unwrap() as i128 - scan.scan.stamp_ns as i128;
        assert!(
            error_ns.abs() < 1_000_000,
            "scan {k}: sync off by {error_ns} ns"
        );
    }
    // One block per recorded period on the sensor clock.
    let stamps: Vec<u64> = got
        .iter()
        .map(|s| s.scan.sensor_stamp_ms.unwrap())
        .collect();
    assert!(stamps.windows(2).all(|w| w[1] - w[0] == 25), "{stamps:?}");
    let c = counters.snapshot();
    assert_eq!((c.watchdog_timeouts, c.scans), (1, 5));
    stop.send(true).unwrap();
    task.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn tm0_refused_while_the_unit_boots_is_retried() {
    let (info, scans) = recording(20);
    let faults = Faults {
        booting_for: Some(Duration::from_millis(250)),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let driver = Driver::with_connector(config(), connector(emulator, 0, Arc::default()));
    let counters = driver.counters();
    let (mut rx, stop, task) = spawn(driver);
    let started = Instant::now();
    while !matches!(rx.recv().await, Some(DriverEvent::Scan(_))) {}
    // TM0 at 0 ms and 100 ms is refused; the third, at 300 ms, gets through on the same link.
    assert_eq!(started.elapsed(), Duration::from_millis(300));
    let c = counters.snapshot();
    assert_eq!((c.connects, c.reconnects, c.time_syncs), (1, 0, 1));
    let last_error = c.last_error.unwrap();
    assert!(
        last_error.contains("laser off (10)") && last_error.contains("may still be booting"),
        "{last_error}"
    );
    stop.send(true).unwrap();
    task.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn shutdown_waits_for_qt_no_longer_than_its_bound() {
    let (info, scans) = recording(20);
    // The unit goes silent after 3 scans for a minute: it reads nothing, so QT goes unanswered.
    let faults = Faults {
        stall: Some((3, Duration::from_secs(60))),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let attempts = Arc::new(Mutex::new(Vec::new()));
    let mut config = config();
    config.watchdog_periods = 10_000.0; // keep the link through the stall
    let driver = Driver::with_connector(config, connector(emulator.clone(), 0, attempts));
    let (mut rx, stop, task) = spawn(driver);
    let mut seen = 0;
    while seen < 3 {
        if let Some(DriverEvent::Scan(_)) = rx.recv().await {
            seen += 1;
        }
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(emulator.stats().stalls, 1);
    let quits = emulator.stats().quits;
    let asked = Instant::now();
    stop.send(true).unwrap();
    task.await.unwrap();
    assert_eq!(asked.elapsed(), scanfuse::sensor::QUIT_TIMEOUT);
    assert_eq!(
        emulator.stats().quits,
        quits,
        "the stalled unit never read the QT"
    );
}

/// A unit still booting when the driver's TM0 attempts run out: the connection ends with
/// "still booting; retrying" (not "no valid TM1 answer"), and the next one gets through.
#[tokio::test(start_paused = true)]
async fn a_unit_booting_longer_than_the_tm0_attempts_is_reported_as_booting() {
    let (info, scans) = recording(20);
    let faults = Faults {
        booting_for: Some(Duration::from_secs(2)),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let driver = Driver::with_connector(config(), connector(emulator, 0, Arc::default()));
    let counters = driver.counters();
    let (mut rx, stop, task) = spawn(driver);
    let mut reasons = Vec::new();
    loop {
        match rx.recv().await.unwrap() {
            DriverEvent::Scan(_) => break,
            DriverEvent::Disconnected { reason } => reasons.push(reason),
            _ => {}
        }
    }
    // Five TM0s 100..400 ms apart take the first connection to 1.5 s; the second gets through.
    assert_eq!(reasons.len(), 1, "{reasons:?}");
    assert_eq!(
        reasons[0],
        "the unit is still booting (it refused TM0 5 times, with laser off (10)); retrying"
    );
    let c = counters.snapshot();
    assert_eq!((c.connects, c.reconnects), (1, 1));
    stop.send(true).unwrap();
    task.await.unwrap();
}

/// Events until the driver ends by itself; panics on a scan.
async fn events_until_the_driver_ends(
    rx: &mut mpsc::Receiver<DriverEvent>,
) -> (Vec<String>, Option<String>) {
    let mut disconnects = Vec::new();
    let mut failed = None;
    while let Some(event) = rx.recv().await {
        match event {
            DriverEvent::Disconnected { reason } => disconnects.push(reason),
            DriverEvent::Failed { reason } => failed = Some(reason),
            DriverEvent::Scan(_) => panic!("a scan from a unit that cannot stream"),
            _ => {}
        }
    }
    (disconnects, failed)
}

#[tokio::test(start_paused = true)]
async fn a_unit_in_its_abnormal_state_is_rebooted_and_streams_again() {
    let (info, scans) = recording(20);
    let faults = Faults {
        abnormal_until_reboots: Some(1),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let attempts = Arc::new(Mutex::new(Vec::new()));
    let driver = Driver::with_connector(config(), connector(emulator.clone(), 0, attempts.clone()));
    let (mut rx, stop, task) = spawn(driver);
    let mut reasons = Vec::new();
    loop {
        match rx.recv().await.unwrap() {
            DriverEvent::Scan(_) => break,
            DriverEvent::Disconnected { reason } => reasons.push(reason),
            DriverEvent::Failed { reason } => panic!("failed: {reason}"),
            _ => {}
        }
    }
    // Connections 1 and 2 end in 0L, the 3rd too and reboots the unit; the 4th streams.
    assert_eq!(emulator.stats().reboots, 1);
    assert_eq!(
        attempts.lock().unwrap().len(),
        ABNORMAL_SESSIONS_BEFORE_REBOOT as usize + 1
    );
    assert_eq!(reasons.len(), ABNORMAL_SESSIONS_BEFORE_REBOOT as usize);
    for reason in &reasons {
        assert_eq!(reason, "sensor answered RS with abnormal state (0L)");
    }
    stop.send(true).unwrap();
    task.await.unwrap();
}

#[tokio::test(start_paused = true)]
async fn a_unit_that_stays_abnormal_through_the_reboots_is_failed_and_left_alone() {
    let (info, scans) = recording(20);
    let faults = Faults {
        abnormal_until_reboots: Some(u32::MAX),
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let attempts = Arc::new(Mutex::new(Vec::new()));
    let driver = Driver::with_connector(config(), connector(emulator.clone(), 0, attempts.clone()));
    let counters = driver.counters();
    let (mut rx, _stop, task) = spawn(driver);
    let (disconnects, failed) = events_until_the_driver_ends(&mut rx).await;
    // The driver ended by itself: no stop was sent.
    task.await.unwrap();
    let failed = failed.expect("a Failed event");
    assert_eq!(
        failed,
        format!(
            "sensor answered RS with abnormal state (0L), still after {MAX_REBOOTS} reboots: power-cycle the unit and check it (its LED, the manual's error list); scanfuse stopped retrying it"
        )
    );
    assert_eq!(emulator.stats().reboots, MAX_REBOOTS as u64);
    let sessions = (ABNORMAL_SESSIONS_BEFORE_REBOOT * (MAX_REBOOTS + 1)) as usize;
    assert_eq!(attempts.lock().unwrap().len(), sessions);
    assert_eq!(disconnects.len(), sessions - 1);
    assert_eq!(counters.snapshot().last_error, Some(failed));
}

#[tokio::test(start_paused = true)]
async fn a_mode_the_unit_lacks_fails_the_sensor_at_the_first_connection() {
    let (info, scans) = recording(20);
    let faults = Faults {
        no_multi_echo: true,
        ..Faults::default()
    };
    let emulator = looping_emulator(&info, &scans, faults);
    let attempts = Arc::new(Mutex::new(Vec::new()));
    let mut config = config();
    config.mode = ScanMode::Nd;
    let driver = Driver::with_connector(config, connector(emulator.clone(), 0, attempts.clone()));
    let counters = driver.counters();
    let (mut rx, _stop, task) = spawn(driver);
    let mut connected = false;
    let mut failed = None;
    while let Some(event) = rx.recv().await {
        match event {
            DriverEvent::Connected(_) => connected = true,
            DriverEvent::Failed { reason } => failed = Some(reason),
            DriverEvent::Disconnected { reason } => panic!("retried: {reason}"),
            _ => {}
        }
    }
    task.await.unwrap();
    assert_eq!(
        failed.as_deref(),
        Some("this UTM-30LX-EW answers 0E to ND: it has no multi-echo mode; use MD or ME")
    );
    assert!(
        !connected,
        "never reported connected in a mode it cannot stream"
    );
    assert_eq!(attempts.lock().unwrap().len(), 1);
    let c = counters.snapshot();
    assert_eq!((c.connects, c.reconnects), (0, 0));
    // The driver stopped the unit (QT) before leaving.
    assert!(emulator.stats().quits >= 2, "{:?}", emulator.stats());
}

/// A link that opens but never answers, as a TCP unit held by another client.
#[tokio::test(start_paused = true)]
async fn a_link_that_opens_but_never_answers_names_another_client() {
    let held = Arc::new(Mutex::new(Vec::new()));
    let connector: Connector = Arc::new({
        let held = held.clone();
        move || {
            let held = held.clone();
            Box::pin(async move {
                let (ours, theirs) = tokio::io::duplex(1024);
                held.lock().unwrap().push(theirs);
                Ok(Link::Memory(ours))
            })
        }
    });
    let driver = Driver::with_connector(config(), connector);
    let (mut rx, stop, task) = spawn(driver);
    let reason = loop {
        if let Some(DriverEvent::Disconnected { reason }) = rx.recv().await {
            break reason;
        }
    };
    assert_eq!(
        reason,
        "memory://emulator accepted the connection but sent no answer to QT within 2s: another client may hold the unit (Hokuyo units serve one client at a time), or it is not a SCIP 2.0 unit"
    );
    stop.send(true).unwrap();
    task.await.unwrap();
}
