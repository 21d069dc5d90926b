//! Memory of the whole daemon over a long replay: the five `hall` sensors looped by in-process
//! emulators at 10× (an hour of stream in six minutes of wall time), drivers, registration,
//! the fuser and the status socket all running. Prints the process's resident set (VmRSS,
//! and VmHWM, its peak) every `SCANFUSE_BENCH_EVERY_S` (default 20 s) with the scans taken so
//! far, then the growth from the first sample after warm-up to the last.
//!
//! Run: `cargo bench --bench daemon_memory` (`SCANFUSE_BENCH_S=60` for a shorter run; 360 s
//! default; `SCANFUSE_BENCH_SPEED` to change the 10×).

mod common;

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use scanfuse::daemon::config::Config;
use scanfuse::daemon::protocol::Message;
use scanfuse::daemon::run::{RunOptions, run_daemon};

type Error = Box<dyn std::error::Error>;

const HALL: [(&str, &str); 5] = [
    ("gate", "height_m = 1.1"),
    ("dock", "height_m = 1.1"),
    ("mezz", "height_m = 1.0"),
    ("tough", "height_m = 1.2"),
    ("tilt", "height_m = 2.5\npitch_deg = -20.0"),
];

/// (VmRSS, VmHWM) of this process, MiB.
fn rss_mib() -> Result<(f64, f64), Error> {
    let status = std::fs::read_to_string("/proc/self/status")?;
    let field = |name: &str| -> Result<f64, Error> {
        let line = status
            .lines()
            .find(|l| l.starts_with(name))
            .ok_or_else(|| format!("no {name} in /proc/self/status"))?;
        let kib: f64 = line
            .split_whitespace()
            .nth(1)
            .ok_or("malformed /proc/self/status")?
            .parse()?;
        Ok(kib / 1024.0)
    };
    Ok((field("VmRSS:")?, field("VmHWM:")?))
}

/// Total scans and queue drops, from a `status` request.
fn scans(stream: &mut BufReader<UnixStream>) -> Result<(u64, u64, usize), Error> {
    stream.get_mut().write_all(b"{\"cmd\":\"status\"}\n")?;
    let mut line = String::new();
    loop {
        line.clear();
        if stream.read_line(&mut line)? == 0 {
            return Err("the daemon closed the socket".into());
        }
        if let Ok(Message::Status(s)) = serde_json::from_str::<Message>(&line) {
            let total = s.sensors.iter().map(|x| x.scans).sum();
            let streaming = s.sensors.iter().filter(|x| x.rate_hz.is_some()).count();
            return Ok((total, s.queue_drops, streaming));
        }
    }
}

fn main() -> Result<(), Error> {
    let seconds = common::env_f64("SCANFUSE_BENCH_S", 360.0);
    let every_s = common::env_f64("SCANFUSE_BENCH_EVERY_S", 20.0);
    let speed = common::env_f64("SCANFUSE_BENCH_SPEED", 10.0);
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/hall.mcap");
    let dir = tempfile::tempdir()?;
    let socket = dir.path().join("s.sock");
    let mut text = format!(
        "[site]\nname = \"memory\"\nstate_dir = \"{}\"\nsocket = \"{}\"\nanchor = \"gate\"\n",
        dir.path().join("state").display(),
        socket.display()
    );
    for (id, extra) in HALL {
        text.push_str(&format!(
            "\n[[sensor]]\nid = \"{id}\"\nconnect = \"replay:{}#{id}\"\nmode = \"MD\"\n{extra}\n",
            fixture.display()
        ));
    }
    text.push_str("\n[publish]\nsave_interval_s = 30\n");
    let config_path = dir.path().join("site.toml");
    std::fs::write(&config_path, text)?;
    let config = Config::load(&config_path)?;

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let options = RunOptions {
        duration: Some(Duration::from_secs_f64(seconds + 1.0)),
        replay_speed: speed,
        ..RunOptions::default()
    };
    let daemon = runtime.spawn(run_daemon(config, options));

    let started = Instant::now();
    let stream = common::connect_when_up(&socket)?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut client = BufReader::new(stream);
    // Ask at once: the daemon closes a connection that sends nothing within 5 s of its banner
    // (socket::FIRST_REQUEST_WITHIN); having asked once, it may stay quiet between samples.
    scans(&mut client)?;
    println!(
        "daemon_memory: hall × 5 sensors looped at {speed}× for {seconds:.0} s ({:.0} min of stream)",
        seconds * speed / 60.0
    );
    let mut samples: Vec<(f64, f64)> = Vec::new();
    let mut next = every_s;
    // Samples while the daemon still runs (it stops a second after `seconds`).
    while next <= seconds {
        let wait = next - started.elapsed().as_secs_f64();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
        next += every_s;
        let t = started.elapsed().as_secs_f64();
        let (rss, hwm) = rss_mib()?;
        let (total, drops, streaming) = scans(&mut client)?;
        println!(
            "  t {t:6.0} s  stream {:6.1} min  RSS {rss:7.1} MiB  peak {hwm:7.1} MiB  scans {total:8}  queue drops {drops:7}  streaming {streaming}/5",
            t * speed / 60.0
        );
        samples.push((t, rss));
    }
    drop(client);
    runtime.block_on(daemon)??;
    // Growth after the first minute (registration, buffers and grids settle there).
    let settled: Vec<&(f64, f64)> = samples.iter().filter(|(t, _)| *t >= 60.0).collect();
    if let (Some(first), Some(last)) = (settled.first(), settled.last()) {
        println!(
            "daemon_memory: RSS {:.1} MiB at {:.0} s → {:.1} MiB at {:.0} s: {:+.1} MiB ({:+.2} MiB per stream hour)",
            first.1,
            first.0,
            last.1,
            last.0,
            last.1 - first.1,
            (last.1 - first.1) / ((last.0 - first.0).max(1.0) * speed / 3600.0)
        );
    }
    Ok(())
}
