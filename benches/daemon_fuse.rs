//! The fuser's cost per fused frame: the five `hall` sensors' latest scans × their poses →
//! site-frame points (the `watch` frame and the `map.ply` cloud), and every
//! `GRID_UPDATE_S` per sensor the occupancy-grid rays. Replays the fixture's scans in stamp
//! order, fusing after each one, and prints p50/p99/max per frame.
//!
//! Run: `cargo bench --bench daemon_fuse`

use std::time::Instant;

use scanfuse::daemon::config::PublishConfig;
use scanfuse::daemon::pipeline::PosedScan;
use scanfuse::daemon::pipeline_fuse::Fuser;
use scanfuse::geometry::{Mount, Pose3, pose2};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/hall.mcap");
    let rec = scanfuse::record::read(&path)?;
    let mut latest: Vec<PosedScan> = Vec::new();
    let mut order = Vec::new();
    for (index, info) in rec.sensors.iter().enumerate() {
        let t = info.truth.ok_or("the fixture has truth")?;
        let pose = Pose3::from_planar(
            &pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()),
            info.height_m.unwrap_or(0.0),
            info.pitch_deg.unwrap_or(0.0).to_radians(),
        );
        for scan in rec.scans_of(&info.id) {
            order.push((index, scan.clone()));
        }
        latest.push(PosedScan {
            index: index as u16,
            id: info.id.clone(),
            scan: rec.scans_of(&info.id).first().ok_or("scans")?.clone(),
            geometry: info.geometry,
            mount: Mount {
                height_m: info.height_m,
                pitch_rad: info.pitch_deg.unwrap_or(0.0).to_radians(),
            },
            site_from_sensor: pose,
        });
    }
    order.sort_by_key(|(_, s)| s.stamp_ns);
    let mut fuser = Fuser::new(&PublishConfig::default());
    let mut times_us = Vec::new();
    let mut points = 0usize;
    for _ in 0..10 {
        for (index, scan) in &order {
            latest[*index].scan = scan.clone();
            let started = Instant::now();
            let frame = fuser.fuse(&latest);
            times_us.push(started.elapsed().as_secs_f64() * 1e6);
            points = frame.scans.iter().map(|s| s.xy_m.len() / 2).sum();
        }
    }
    times_us.sort_by(f64::total_cmp);
    let pct = |p: f64| times_us[((times_us.len() - 1) as f64 * p) as usize];
    println!(
        "daemon_fuse: {} frames of 5 sensors ({points} points/frame): p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs (grid rays included when due)",
        times_us.len(),
        pct(0.5),
        pct(0.99),
        pct(1.0)
    );
    Ok(())
}
