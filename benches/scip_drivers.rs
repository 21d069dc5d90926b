//! 32 emulated UTM-30LX-EW sensors at 40 Hz streamed over loopback TCP to 32 drivers in one
//! process. The drivers run alone on one thread, whose CPU time is read from
//! `/proc/thread-self/stat`; the emulators run on another runtime. Target: < 25 % of one core.
//!
//! `cargo bench --bench scip_drivers` (SENSORS=32 SECONDS=10 to change the load)

use std::time::{Duration, Instant};

use scanfuse::emulator::{Emulator, EmulatorConfig};
use scanfuse::scan::{Scan, ScanGeometry, SensorInfo};
use scanfuse::sensor::{Driver, DriverConfig, DriverEvent, ScanMode};
use tokio::sync::{mpsc, watch};

/// utime + stime of the calling thread, seconds (Linux).
fn thread_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    // Fields after the command name, which is in parentheses and may contain spaces.
    let rest = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0) // USER_HZ is 100 on Linux
}

fn recording() -> (SensorInfo, Vec<Scan>) {
    let g = ScanGeometry::UTM_30LX_EW;
    let mut info = SensorInfo::new("s", "UTM-30LX-EW");
    info.geometry = Some(g);
    let scans = (0..40u64)
        .map(|k| Scan {
            stamp_ns: k * 25_000_000,
            sensor_stamp_ms: None,
            start_angle_rad: g.angle_of_step_rad(g.amin),
            end_angle_rad: g.angle_of_step_rad(g.amax),
            ranges_m: (0..g.step_count())
                .map(|i| (1000 + (i as u64 * 7 + k) % 30_000) as f32 / 1000.0)
                .collect(),
            intensities: (0..g.step_count()).map(|i| (i % 3000) as f32).collect(),
        })
        .collect();
    (info, scans)
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    // `cargo bench` passes `--bench`; `cargo test --all-targets` does not: a short smoke run then.
    let full = std::env::args().any(|a| a == "--bench");
    let env = |key: &str| std::env::var(key).ok().and_then(|s| s.parse::<f64>().ok());
    let sensors = env("SENSORS").unwrap_or(if full { 32.0 } else { 2.0 }) as usize;
    let seconds = env("SECONDS").unwrap_or(if full { 10.0 } else { 1.0 });
    let (info, scans) = recording();
    let emulators = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let addrs: Vec<String> = emulators.block_on(async {
        let mut addrs = Vec::new();
        for _ in 0..sensors {
            let emulator = Emulator::new(
                &info,
                &scans,
                EmulatorConfig {
                    looping: true,
                    ..Default::default()
                },
            )
            .expect("emulator");
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            addrs.push(format!("tcp://{}", listener.local_addr().expect("addr")));
            tokio::spawn(async move { emulator.serve(listener).await });
        }
        addrs
    });
    let drivers = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async move {
            let (tx, mut rx) = mpsc::channel(8192);
            let (stop, stop_rx) = watch::channel(false);
            let mut counters = Vec::new();
            for (i, addr) in addrs.iter().enumerate() {
                let mut config = DriverConfig::new(format!("s{i}"), addr.clone());
                config.mode = ScanMode::Me;
                let driver = Driver::new(config);
                counters.push(driver.counters());
                tokio::spawn(driver.run(tx.clone(), stop_rx.clone()));
            }
            drop(tx);
            // Warm up: every driver connected and streaming.
            let mut scans = 0u64;
            let warm = Instant::now();
            while counters.iter().any(|c| c.snapshot().scans == 0)
                && warm.elapsed() < Duration::from_secs(30)
            {
                if let Ok(Some(DriverEvent::Scan(_))) =
                    tokio::time::timeout(Duration::from_millis(100), rx.recv()).await
                {
                }
            }
            let cpu0 = thread_cpu_s();
            let t0 = Instant::now();
            while t0.elapsed().as_secs_f64() < seconds {
                if let Ok(Some(DriverEvent::Scan(_))) =
                    tokio::time::timeout(Duration::from_millis(100), rx.recv()).await
                {
                    scans += 1;
                }
            }
            let wall = t0.elapsed().as_secs_f64();
            let cpu = thread_cpu_s().zip(cpu0).map(|(a, b)| a - b);
            let errors: u64 = counters
                .iter()
                .map(|c| {
                    let s = c.snapshot();
                    s.checksum_errors + s.decode_errors + s.reconnects
                })
                .sum();
            let _ = stop.send(true);
            (scans, wall, cpu, errors)
        })
    });
    let (scans, wall, cpu, errors) = drivers.join().expect("driver thread");
    let expected = sensors as f64 * 40.0 * wall;
    assert!(scans > 0, "no scan reached the drivers");
    println!("scip_drivers: {sensors} sensors × 40 Hz ME over loopback, {wall:.1} s");
    println!("  scans received {scans} (expected ≈ {expected:.0}), errors+reconnects {errors}");
    match cpu {
        Some(cpu) => println!(
            "  driver thread CPU {cpu:.2} s = {:.1} % of one core (target < 25 %)",
            100.0 * cpu / wall
        ),
        None => println!("  driver thread CPU: /proc/thread-self/stat unreadable (not Linux?)"),
    }
    emulators.shutdown_timeout(Duration::from_secs(1));
}
