//! Shared by the driver end-to-end tests: recordings built in memory, and a driver harness.
#![allow(dead_code)]

use std::time::Duration;

use scanfuse::emulator::{Emulator, EmulatorConfig, Faults};
use scanfuse::scan::{Scan, ScanGeometry, SensorInfo};
use scanfuse::sensor::{
    CounterSnapshot, Counters, Driver, DriverConfig, DriverEvent, ScanMode, SensorScan,
};
use std::sync::Arc;
use tokio::sync::{mpsc, watch};

/// A UTM-30LX-EW-like sensor and `n` scans at 40 Hz: every scan different, a few no-returns.
pub fn recording(n: usize) -> (SensorInfo, Vec<Scan>) {
    let g = ScanGeometry::UTM_30LX_EW;
    let mut info = SensorInfo::new("hall", "UTM-30LX-EW");
    info.geometry = Some(g);
    info.fields = g.to_fields();
    info.fields.insert("MODL".into(), "UTM-30LX-EW".into());
    info.fields.insert("SERI".into(), "H1234567".into());
    let scans = (0..n)
        .map(|k| Scan {
            stamp_ns: 1_700_000_000_000_000_000 + k as u64 * 25_000_000,
            sensor_stamp_ms: Some(1000 + k as u64 * 25),
            start_angle_rad: g.angle_of_step_rad(g.amin),
            end_angle_rad: g.angle_of_step_rad(g.amax),
            ranges_m: (0..g.step_count())
                .map(|i| {
                    if (i + k) % 97 == 0 {
                        0.0
                    } else {
                        (500 + (i * 37 + k * 11) % 20_000) as f32 / 1000.0
                    }
                })
                .collect(),
            intensities: (0..g.step_count())
                .map(|i| ((i * 13 + k) % 4000) as f32)
                .collect(),
        })
        .collect();
    (info, scans)
}

/// Ranges as the sensor sent them, mm.
pub fn mm(ranges_m: &[f32]) -> Vec<u32> {
    ranges_m
        .iter()
        .map(|r| (r * 1000.0).round() as u32)
        .collect()
}

pub struct Harness {
    pub events: mpsc::Receiver<DriverEvent>,
    pub counters: Arc<Counters>,
    pub shutdown: watch::Sender<bool>,
    pub task: tokio::task::JoinHandle<()>,
}

impl Harness {
    pub fn start(uri: &str, mode: ScanMode, tweak: impl FnOnce(&mut DriverConfig)) -> Harness {
        let mut config = DriverConfig::new("hall", uri);
        config.mode = mode;
        config.reply_timeout = Duration::from_millis(500);
        config.backoff_initial = Duration::from_millis(50);
        config.backoff_max = Duration::from_millis(400);
        tweak(&mut config);
        let driver = Driver::new(config);
        let counters = driver.counters();
        let (tx, events) = mpsc::channel(4096);
        let (shutdown, rx) = watch::channel(false);
        let task = tokio::spawn(driver.run(tx, rx));
        Harness {
            events,
            counters,
            shutdown,
            task,
        }
    }

    /// Collects `n` scans (or fewer if `within` runs out).
    pub async fn scans(&mut self, n: usize, within: Duration) -> Vec<SensorScan> {
        let mut out = Vec::new();
        let deadline = tokio::time::Instant::now() + within;
        while out.len() < n {
            match tokio::time::timeout_at(deadline, self.events.recv()).await {
                Ok(Some(DriverEvent::Scan(scan))) => out.push(scan),
                Ok(Some(_)) => {}
                Ok(None) | Err(_) => break,
            }
        }
        out
    }

    /// Waits until `pred` holds for the counters, or `within` runs out; returns the last snapshot.
    pub async fn counters_until(
        &mut self,
        within: Duration,
        pred: impl Fn(&CounterSnapshot) -> bool,
    ) -> CounterSnapshot {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            let snap = self.counters.snapshot();
            if pred(&snap) || tokio::time::Instant::now() >= deadline {
                return snap;
            }
            // Keep the channel drained so the driver never blocks.
            while self.events.try_recv().is_ok() {}
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    pub async fn stop(self) {
        let _ = self.shutdown.send(true);
        let _ = tokio::time::timeout(Duration::from_secs(2), self.task).await;
    }
}

/// Starts an emulator on an ephemeral loopback port.
pub async fn emulator(
    info: &SensorInfo,
    scans: &[Scan],
    config: EmulatorConfig,
) -> (Emulator, String) {
    let emulator = Emulator::new(info, scans, config).expect("valid recording");
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind loopback");
    let addr = listener.local_addr().expect("bound");
    let serving = emulator.clone();
    tokio::spawn(async move { serving.serve(listener).await });
    (emulator, format!("tcp://{addr}"))
}

/// An emulator injecting `faults`, replaying the recording once or `looping`.
pub async fn emulator_with(
    info: &SensorInfo,
    scans: &[Scan],
    faults: Faults,
    looping: bool,
) -> (Emulator, String) {
    let config = EmulatorConfig {
        faults,
        looping,
        ..Default::default()
    };
    emulator(info, scans, config).await
}
