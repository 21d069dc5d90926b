//! What the status socket costs: request round trips, and fused frames fanned out to map
//! watchers (16 sensors × 1,081 points per frame). Prints the figures.
//!
//! Run: `cargo bench --bench status_socket`

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use scanfuse::daemon::protocol::{
    Frame, FrameScan, PoseSource, Poses, Saved, SensorPose, SensorState, SensorStatus, Status,
};
use scanfuse::daemon::socket::{Publisher, Refused, ServerOptions, StatusServer, StatusSource};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

const SENSORS: usize = 16;
const POINTS: usize = 1081;

/// A fixed 16-sensor site: the answers cost what the real pipeline's snapshots will.
struct FixedSite {
    status: Status,
    poses: Poses,
}

impl StatusSource for FixedSite {
    fn status(&self) -> Status {
        self.status.clone()
    }
    fn poses(&self) -> Poses {
        self.poses.clone()
    }
    fn reregister(&self, sensor: &str) -> Result<String, Refused> {
        Ok(format!("re-registration of {sensor} queued"))
    }
    fn save(&self) -> Result<Saved, Refused> {
        Err(Refused("not in a benchmark".into()))
    }
}

fn site() -> FixedSite {
    let ids: Vec<String> = (0..SENSORS).map(|i| format!("sensor-{i:02}")).collect();
    let sensors = ids
        .iter()
        .map(|id| {
            let mut s = SensorStatus::new(id.clone(), SensorState::Streaming);
            s.rate_hz = Some(40.0);
            s.scans = 123_456;
            s
        })
        .collect();
    let poses = ids
        .iter()
        .enumerate()
        .map(|(i, id)| {
            let mut p = SensorPose::unregistered(id.clone(), "");
            p.registered = true;
            p.reason = None;
            p.x_m = Some(i as f64 * 1.5);
            p.y_m = Some(-(i as f64));
            p.yaw_deg = Some(i as f64 * 10.0);
            p.sigma_x_m = Some(0.01);
            p.sigma_y_m = Some(0.01);
            p.sigma_yaw_deg = Some(0.1);
            p.source = Some(PoseSource::Registered);
            p.age_s = Some(60.0);
            p
        })
        .collect();
    FixedSite {
        status: Status {
            site: "bench".into(),
            uptime_s: 1.0,
            queue_drops: 0,
            sensors,
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        },
        poses: Poses {
            anchor: ids[0].clone(),
            sensors: poses,
            building_from_site: None,
            site_from_zone: None,
        },
    }
}

fn frame(k: u64) -> Frame {
    Frame {
        stamp_ns: k,
        scans: (0..SENSORS)
            .map(|s| FrameScan {
                sensor: format!("sensor-{s:02}"),
                stamp_ns: k,
                xy_m: (0..POINTS * 2)
                    .map(|i| ((i * 7 + s) % 1000) as f32 * 0.0123)
                    .collect(),
            })
            .collect(),
    }
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

async fn client(
    path: &Path,
) -> (
    BufReader<tokio::net::unix::OwnedReadHalf>,
    tokio::net::unix::OwnedWriteHalf,
) {
    let (r, w) = UnixStream::connect(path).await.unwrap().into_split();
    let mut r = BufReader::new(r);
    let mut banner = String::new();
    r.read_line(&mut banner).await.unwrap();
    (r, w)
}

fn main() {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.sock");
        let publisher = Publisher::new(64);
        let server = StatusServer::bind(
            &path,
            Arc::new(site()),
            publisher.clone(),
            ServerOptions {
                write_timeout: Duration::from_secs(30),
                ..ServerOptions::default()
            },
        )
        .unwrap();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(server.run(async {
            let _ = stop_rx.await;
        }));

        // Round trips: status and poses of 16 sensors.
        let (mut r, mut w) = client(&path).await;
        for cmd in ["status", "poses"] {
            let request = format!("{{\"cmd\":\"{cmd}\"}}\n");
            let mut times = Vec::new();
            let mut line = String::new();
            let mut bytes = 0;
            for i in 0..6000 {
                let t = Instant::now();
                w.write_all(request.as_bytes()).await.unwrap();
                line.clear();
                r.read_line(&mut line).await.unwrap();
                if i >= 1000 {
                    times.push(t.elapsed());
                }
                bytes = line.len();
            }
            times.sort();
            println!(
                "status_socket: {cmd} round trip ({SENSORS} sensors, {bytes} B reply): p50 {:.1} µs, p99 {:.1} µs",
                percentile(&times, 0.5).as_secs_f64() * 1e6,
                percentile(&times, 0.99).as_secs_f64() * 1e6
            );
        }

        // Fan-out: fused frames to 4 map watchers that read everything.
        let watchers = 4;
        let frames_n = 400u64;
        let mut readers = Vec::new();
        for _ in 0..watchers {
            let (mut r, mut w) = client(&path).await;
            w.write_all(b"{\"cmd\":\"watch\",\"status\":false,\"map\":true}\n").await.unwrap();
            let mut ack = String::new();
            r.read_line(&mut ack).await.unwrap();
            readers.push(tokio::spawn(async move {
                let _keep = w;
                let mut line = String::new();
                let mut got = 0u64;
                let mut bytes = 0usize;
                while got < frames_n {
                    line.clear();
                    if r.read_line(&mut line).await.unwrap() == 0 {
                        break;
                    }
                    bytes = line.len();
                    got += 1;
                }
                (got, bytes)
            }));
        }
        let frames: Vec<Frame> = (0..frames_n).map(frame).collect();
        let started = Instant::now();
        let mut publish_time = Duration::ZERO;
        for f in frames {
            let t = Instant::now();
            publisher.frame(f);
            publish_time += t.elapsed();
            // A 10 Hz stream compressed in time: a short pause lets the watchers drain, so
            // none falls the backlog behind.
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        let mut line_bytes = 0;
        for r in readers {
            let (got, bytes) = r.await.unwrap();
            assert_eq!(got, frames_n, "a watcher missed frames");
            line_bytes = bytes;
        }
        let wall = started.elapsed();
        println!(
            "status_socket: FRAME of {SENSORS}×{POINTS} points = {:.0} KiB per line; encode + send {:.2} ms per frame on the publishing task",
            line_bytes as f64 / 1024.0,
            publish_time.as_secs_f64() * 1e3 / frames_n as f64
        );
        println!(
            "status_socket: {frames_n} frames to {watchers} watchers in {:.2} s ({:.0} frames/s delivered per watcher with 2 ms pacing)",
            wall.as_secs_f64(),
            frames_n as f64 / wall.as_secs_f64()
        );
        let _ = stop_tx.send(());
        task.await.unwrap();
    });
}
