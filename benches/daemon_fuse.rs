//! Scan in → fused frame out, through the whole daemon: the five `hall` sensors replayed by
//! in-process emulators at 40/20 Hz over loopback TCP, the real drivers, the pipeline and the
//! status socket, poses loaded from a `poses.toml` of the true poses (so every scan is fused
//! from the first). A client watching `map` on the socket takes each FRAME line and measures,
//! per scan, its receive time minus the scan's stamp (the host time its driver had the whole
//! SCIP reply, before decoding). Prints p50/p99/max over the run.
//!
//! Run: `cargo bench --bench daemon_fuse` (`SCANFUSE_BENCH_S=60` for a longer run; 20 s
//! default).

mod common;

use std::io::{BufRead, BufReader, Write};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use scanfuse::daemon::config::Config;
use scanfuse::daemon::protocol::Message;
use scanfuse::daemon::run::{RunOptions, run_daemon};

type Error = Box<dyn std::error::Error>;

const ANCHOR: &str = "gate";

fn main() -> Result<(), Error> {
    let seconds: f64 = std::env::var("SCANFUSE_BENCH_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/hall.mcap");
    let rec = scanfuse::record::read(&fixture)?;
    let dir = tempfile::tempdir()?;
    let state = dir.path().join("state");
    std::fs::create_dir_all(&state)?;
    let socket = dir.path().join("s.sock");

    // The config, and poses.toml with the true poses in the anchor's frame.
    let mut text = common::site_of_true_poses(&rec, "bench", ANCHOR, &state, &socket, |id| {
        format!("replay:{}#{id}", fixture.display())
    })?;
    text.push_str("\n[publish]\nsave_interval_s = 0\n");
    let config_path = dir.path().join("site.toml");
    std::fs::write(&config_path, text)?;
    let config = Config::load(&config_path)?;

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let options = RunOptions {
        duration: Some(Duration::from_secs_f64(seconds + 3.0)),
        ..RunOptions::default()
    };
    let daemon = runtime.spawn(run_daemon(config, options));

    // The watcher: connect once the socket is there, skip the first second (connects).
    let started = Instant::now();
    let stream = common::connect_when_up(&socket)?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    let mut writer = stream.try_clone()?;
    let mut reader = BufReader::new(stream);
    writer.write_all(b"{\"cmd\":\"watch\",\"status\":false,\"map\":true}\n")?;
    let mut latencies_us: Vec<f64> = Vec::new();
    let mut per_sensor = std::collections::BTreeMap::<String, usize>::new();
    let mut line = String::new();
    let warm_up = Duration::from_secs(1);
    let measure_until = started + Duration::from_secs_f64(seconds);
    while Instant::now() < measure_until {
        line.clear();
        if reader.read_line(&mut line)? == 0 {
            break;
        }
        let received_ns = SystemTime::now().duration_since(UNIX_EPOCH)?.as_nanos() as u64;
        if started.elapsed() < warm_up {
            continue;
        }
        if let Ok(Message::Frame(frame)) = serde_json::from_str::<Message>(&line) {
            for scan in &frame.scans {
                latencies_us.push(received_ns.saturating_sub(scan.stamp_ns) as f64 / 1e3);
                *per_sensor.entry(scan.sensor.clone()).or_default() += 1;
            }
        }
    }
    drop(reader);
    drop(writer);
    runtime.block_on(daemon)??;

    if latencies_us.is_empty() {
        return Err("no frames received".into());
    }
    latencies_us.sort_by(f64::total_cmp);
    let pct = |p: f64| latencies_us[((latencies_us.len() - 1) as f64 * p) as usize];
    println!(
        "daemon_fuse: scan in → fused frame out over the status socket, {} scans in {:.0} s from {} sensors ({:?}): p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs (target p99 ≤ 2000 µs)",
        latencies_us.len(),
        seconds - warm_up.as_secs_f64(),
        per_sensor.len(),
        per_sensor,
        pct(0.5),
        pct(0.99),
        pct(1.0)
    );
    Ok(())
}
