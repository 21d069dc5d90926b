//! Driver ↔ emulator for every checked-in floor plan: each sensor of each plan, simulated for a
//! moment, is served by the emulator and read back by the driver over loopback; every scan
//! arrives with the simulated ranges (in mm, no-returns as no-returns).

use crate::driver_support;

use std::path::PathBuf;
use std::time::Duration;

use driver_support::{Harness, emulator};
use scanfuse::emulator::EmulatorConfig;
use scanfuse::scan::{Scan, ScanGeometry};
use scanfuse::sensor::ScanMode;
use scanfuse::sim::{Plan, Simulation};

/// What a sensor can send: mm, with anything outside DMIN..=DMAX (or NaN/0) as "no return".
fn sendable_mm(ranges_m: &[f32], g: &ScanGeometry) -> Vec<u32> {
    ranges_m
        .iter()
        .map(|&r| {
            let mm = if r.is_finite() && r > 0.0 {
                (r * 1000.0).round() as u32
            } else {
                0
            };
            if (g.dmin_mm..=g.dmax_mm).contains(&mm) {
                mm
            } else {
                0
            }
        })
        .collect()
}

#[tokio::test]
async fn every_plan_and_sensor_streams_through_emulator_and_driver() {
    let plans_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans");
    let mut plans: Vec<PathBuf> = std::fs::read_dir(&plans_dir)
        .expect("fixtures/plans exists")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    plans.sort();
    assert!(!plans.is_empty());
    let mut served = 0;
    for path in plans {
        let plan = Plan::load(&path).expect("plan loads");
        let mut sim = Simulation::new(&plan, 7).expect("plan simulates");
        let sensors = sim.sensors().to_vec();
        let mut scans: Vec<Vec<Scan>> = vec![Vec::new(); sensors.len()];
        sim.run(0.3, |index, scan| {
            if let Some(list) = scans.get_mut(index) {
                list.push(scan);
            }
            Ok::<(), std::convert::Infallible>(())
        })
        .expect("simulation runs");
        for (info, scans) in sensors.iter().zip(&scans) {
            let g = info
                .geometry
                .expect("simulated sensors state their geometry");
            let mode = if scans.iter().any(|s| !s.intensities.is_empty()) {
                ScanMode::Me
            } else {
                ScanMode::Md
            };
            let (_emu, uri) = emulator(info, scans, EmulatorConfig::default()).await;
            let mut driver = Harness::start(&uri, mode, |_| {});
            let got = driver.scans(scans.len(), Duration::from_secs(10)).await;
            let name = format!("{} / {}", path.display(), info.id);
            assert_eq!(got.len(), scans.len(), "{name}: every scan arrives");
            for (k, (out, src)) in got.iter().zip(scans).enumerate() {
                assert_eq!(
                    out.scan.ranges_m.len(),
                    src.ranges_m.len(),
                    "{name} scan {k}"
                );
                assert_eq!(
                    sendable_mm(&out.scan.ranges_m, &g),
                    sendable_mm(&src.ranges_m, &g),
                    "{name} scan {k}"
                );
            }
            assert!(
                got.windows(2)
                    .all(|w| w[1].scan.stamp_ns > w[0].scan.stamp_ns),
                "{name}: stamps increase"
            );
            driver.stop().await;
            served += 1;
        }
    }
    assert!(served >= 3, "plans hold several sensors");
}
