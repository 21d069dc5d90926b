//! The daemon at a hundred sensors (issue 20): a simulated concourse of
//! `SCANFUSE_BENCH_SENSORS` scanners (default 100, `sim::generate`, seed 1, 30 people walking)
//! is recorded once (`SCANFUSE_BENCH_REC_S` s, default 10, cached under
//! `target/bench-data/`), then every sensor is served by an emulator in this process on
//! loopback TCP, looped at ×1 (UTMs at 40 Hz, UXMs at 20 Hz), and the release daemon runs in
//! its own process (`scanfuse run`, the real drivers, registration worker with its walker
//! check, tracker, fuser, status socket) with the true poses in `poses.toml`. Two clients
//! watch the socket, one `map`, one `tracks`. Over `SCANFUSE_BENCH_S` s (default 20) after
//! every sensor streams it prints the daemon's CPU (fraction of one core, `/proc/PID/stat`),
//! its RSS now and at peak (VmRSS, VmHWM), scan in → fused frame out at the `map` watcher
//! p50/p99/max (receive time minus the scan's stamp, the host time its driver had the whole
//! SCIP reply), newest scan in → `TRACKS` out at the `tracks` watcher likewise, and each
//! sensor's scan rate. Targets: < 1 core, < 1 GB, frames p99 ≤ 2 ms, `TRACKS` p99 ≤ 5 ms.
//!
//! The emulators' own CPU and memory are this process's, not the daemon's; they run at a lower
//! priority (`daemon::priority`), as hardware on the wire takes none of the daemon's CPU.
//!
//! Run: `cargo bench --bench daemon_site` (`SCANFUSE_BIN` picks the daemon binary; default
//! the one cargo built for the bench).

mod common;

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use scanfuse::daemon::protocol::Message;
use scanfuse::emulator::playback::{DEFAULT_PERIOD_S, replay_span};
use scanfuse::emulator::{Emulator, EmulatorConfig, Gated, ReplayGate};

type Error = Box<dyn std::error::Error>;

/// CPU ticks of each thread of a process, by thread name (threads of one name added up).
fn thread_ticks(pid: u32) -> Result<std::collections::BTreeMap<String, u64>, Error> {
    let mut by_name = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(format!("/proc/{pid}/task"))? {
        let Ok(stat) = std::fs::read_to_string(entry?.path().join("stat")) else {
            continue;
        };
        let (Some(open), Some((_, rest))) = (stat.find('('), stat.rsplit_once(')')) else {
            continue;
        };
        let name = stat[open + 1..stat.len() - rest.len() - 1].to_string();
        let f: Vec<&str> = rest.split_whitespace().collect();
        let ticks = f.get(11).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0)
            + f.get(12).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0);
        *by_name.entry(name).or_insert(0) += ticks;
    }
    Ok(by_name)
}

/// This thread's CPU time, s (`/proc/thread-self/schedstat`).
fn own_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(0.0, |ns| ns * 1e-9)
}

/// (VmRSS, VmHWM) of a process, MiB.
fn rss_mib(pid: u32) -> Result<(f64, f64), Error> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let field = |name: &str| -> Result<f64, Error> {
        let line = status
            .lines()
            .find(|l| l.starts_with(name))
            .ok_or_else(|| format!("no {name} in /proc/{pid}/status"))?;
        Ok(line
            .split_whitespace()
            .nth(1)
            .ok_or("malformed status")?
            .parse::<f64>()?
            / 1024.0)
    };
    Ok((field("VmRSS:")?, field("VmHWM:")?))
}

/// Scans per sensor, the registration queue's drops, sensors placed.
type SiteState = (Vec<(String, u64)>, u64, usize);

/// Scans per sensor and the registration queue's drops (from `status`), and how many sensors
/// the daemon has placed.
fn site_state(socket: &Path) -> Result<SiteState, Error> {
    let mut stream = BufReader::new(common::connect_when_up(socket)?);
    let mut ask = |req: &str| common::ask(&mut stream, req);
    let (scans, drops) = match ask("{\"cmd\":\"status\"}\n")? {
        Message::Status(s) => (
            s.sensors.iter().map(|x| (x.id.clone(), x.scans)).collect(),
            s.queue_drops,
        ),
        _ => (Vec::new(), 0),
    };
    let placed = match ask("{\"cmd\":\"poses\"}\n")? {
        Message::Poses(p) => p.sensors.iter().filter(|x| x.registered).count(),
        _ => 0,
    };
    Ok((scans, drops, placed))
}

/// The last lines the daemon logged.
fn log_tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let mut tail: Vec<&str> = text.lines().rev().take(12).collect();
    tail.reverse();
    tail.join("\n")
}

fn main() -> Result<(), Error> {
    let n = common::env_f64("SCANFUSE_BENCH_SENSORS", 100.0) as usize;
    let window_s = common::env_f64("SCANFUSE_BENCH_S", 20.0);
    let rec_s = common::env_f64("SCANFUSE_BENCH_REC_S", 10.0);
    let crowd = common::env_f64("SCANFUSE_BENCH_CROWD", 30.0) as u32;
    let bin = std::env::var("SCANFUSE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_scanfuse").to_string());
    println!("daemon_site: {bin}, a concourse of {n} sensors, {crowd} people, looped at ×1");
    let file = common::concourse(&bin, n, rec_s, crowd)?;
    let rec = scanfuse::record::read(&file)?;

    // The emulators: one loopback port each, on this process's runtime. They stand in for
    // hardware that takes no CPU from the daemon's host, so they give way to it: their 100
    // scans encoded every 25 ms would otherwise queue the daemon's threads behind them.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .on_thread_start(scanfuse::daemon::priority::lower_this_thread)
        .enable_all()
        .build()?;
    // One clock for all of them, as `scanfuse run --replay` has: each sensor scans at its
    // recorded instants, so the units keep the phases the simulator gave them (real units
    // free-run) instead of all starting their loop the moment the daemon asks.
    let (origin_ns, pass_ns) = replay_span(rec.sensors.iter().filter_map(|info| {
        let scans = rec.scans_of(&info.id);
        let period_s = info.geometry.map_or(DEFAULT_PERIOD_S, |g| g.period_s());
        Some((scans.first()?.stamp_ns, scans.last()?.stamp_ns, period_s))
    }))
    .ok_or("the recording has no scans")?;
    let gate = ReplayGate::new(rec.sensors.len(), Some(1.0), None);
    let mut ports = Vec::new();
    for info in &rec.sensors {
        let emulator = Emulator::new(
            info,
            rec.scans_of(&info.id),
            EmulatorConfig {
                looping: true,
                gate: Some(Gated {
                    gate: gate.clone(),
                    id: info.id.clone(),
                    origin_ns,
                    pass_ns,
                }),
                ..EmulatorConfig::default()
            },
        )?;
        let listener = runtime.block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))?;
        ports.push(listener.local_addr()?.port());
        runtime.spawn(async move {
            let _ = emulator.serve(listener).await;
        });
    }

    // The site: every sensor on its emulator, the true poses saved, the anchor the first.
    let dir = tempfile::tempdir()?;
    let state = dir.path().join("state");
    std::fs::create_dir_all(&state)?;
    let socket = dir.path().join("s.sock");
    let anchor = rec
        .sensors
        .first()
        .ok_or("the recording has no sensors")?
        .id
        .clone();
    let port_of: std::collections::BTreeMap<&str, u16> = rec
        .sensors
        .iter()
        .map(|i| i.id.as_str())
        .zip(ports.iter().copied())
        .collect();
    let mut text = common::site_of_true_poses(&rec, "concourse", &anchor, &state, &socket, |id| {
        format!("tcp://127.0.0.1:{}", port_of.get(id).copied().unwrap_or(0))
    })?;
    text.push_str("\n[publish]\nsave_interval_s = 5\nwatch_backlog = 4096\n");
    // `SCANFUSE_BENCH_QUEUE`: the registration queue's size (the daemon's default otherwise).
    if let Ok(queue) = std::env::var("SCANFUSE_BENCH_QUEUE") {
        text.push_str(&format!("\n[registration]\nqueue_scans = {queue}\n"));
    }
    let config = dir.path().join("site.toml");
    std::fs::write(&config, text)?;
    let log = dir.path().join("daemon.log");
    let daemon = common::Daemon(
        Command::new(&bin)
            .args([
                "run",
                "--for",
                &format!("{:.0}s", window_s + 180.0),
                "--config",
            ])
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log)?)
            .spawn()?,
    );
    let pid = daemon.0.id();

    // Every sensor streaming before anything is measured.
    let started = Instant::now();
    loop {
        let (scans, _, placed) = site_state(&socket)?;
        let streaming = scans.iter().filter(|(_, s)| *s > 0).count();
        if streaming == n && placed == n {
            break;
        }
        if started.elapsed() > Duration::from_secs(120) {
            return Err(format!(
                "after 120 s: {streaming} of {n} streaming, {placed} placed; the daemon's log ends:\n{}",
                log_tail(&log)
            )
            .into());
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    println!(
        "  every sensor streaming and placed after {:.1} s",
        started.elapsed().as_secs_f64()
    );
    std::thread::sleep(Duration::from_secs(2));

    // The watcher, on its own thread: only the stamp is read from each FRAME line (a frame
    // holds one scan). A watcher that falls behind is dropped by the daemon; that is reported.
    let watch = std::env::var("SCANFUSE_BENCH_WATCH").map_or(true, |v| v != "0");
    let watcher = watch.then(|| {
        let socket = socket.clone();
        std::thread::spawn(move || watch_stream(&socket, window_s, &MAP))
    });
    let tracks_watcher = watch.then(|| {
        let socket = socket.clone();
        std::thread::spawn(move || watch_stream(&socket, window_s, &TRACKS))
    });
    let (before, drops0, _) = site_state(&socket)?;
    let ticks0 = common::cpu_ticks(pid)?;
    let threads0 = thread_ticks(pid)?;
    let t0 = Instant::now();
    let mut rss_max: f64 = 0.0;
    while t0.elapsed().as_secs_f64() < window_s {
        rss_max = rss_max.max(rss_mib(pid)?.0);
        std::thread::sleep(Duration::from_millis(500));
    }
    let elapsed = t0.elapsed().as_secs_f64();
    let cpu = (common::cpu_ticks(pid)? - ticks0) as f64 / common::ticks_per_s() / elapsed;
    let mut threads: Vec<(f64, String)> = thread_ticks(pid)?
        .into_iter()
        .map(|(name, t)| {
            let was = threads0.get(&name).copied().unwrap_or(0);
            (
                t.saturating_sub(was) as f64 / common::ticks_per_s() / elapsed,
                name,
            )
        })
        .filter(|(c, _)| *c >= 0.005)
        .collect();
    threads.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (after, drops1, placed) = site_state(&socket)?;
    let (rss, hwm) = rss_mib(pid)?;

    let mut rates: Vec<(f64, String)> = after
        .iter()
        .map(|(id, s)| {
            let was = before.iter().find(|(b, _)| b == id).map_or(0, |(_, s)| *s);
            (s.saturating_sub(was) as f64 / elapsed, id.clone())
        })
        .collect();
    rates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let silent = rates.iter().filter(|(r, _)| *r < 1.0).count();
    let total: f64 = rates.iter().map(|(r, _)| r).sum();
    println!(
        "  over {elapsed:.0} s: {} sensors streaming ({silent} silent), {total:.0} scans/s in all; slowest {:.1} Hz ({}), fastest {:.1} Hz ({}); {placed} placed at the end; the registration queue dropped {} scans",
        rates.len() - silent,
        rates.first().map_or(0.0, |r| r.0),
        rates.first().map_or("", |r| r.1.as_str()),
        rates.last().map_or(0.0, |r| r.0),
        rates.last().map_or("", |r| r.1.as_str()),
        drops1.saturating_sub(drops0),
    );
    println!(
        "  daemon CPU {:.2} of one core (target < 1); RSS {rss:.0} MiB now, {:.0} MiB sampled max, {hwm:.0} MiB peak (VmHWM; target < 1024)",
        cpu,
        rss_max.max(rss)
    );
    let threads: Vec<String> = threads.iter().map(|(c, n)| format!("{n} {c:.2}")).collect();
    println!("  daemon CPU by thread (cores): {}", threads.join(", "));
    if !watch {
        println!("  no watcher (SCANFUSE_BENCH_WATCH=0)");
    }
    for (watcher, what) in [(watcher, &MAP), (tracks_watcher, &TRACKS)] {
        let Some(watcher) = watcher else { continue };
        let (mut latencies_us, watched_s, ended, client_cpu_s) =
            watcher.join().map_err(|_| "a watcher panicked")??;
        if latencies_us.is_empty() {
            return Err(format!("no {} received ({ended})", what.items).into());
        }
        latencies_us.sort_by(f64::total_cmp);
        let pct = |p: f64| latencies_us[((latencies_us.len() - 1) as f64 * p) as usize];
        println!(
            "  {}: {} {} in {watched_s:.1} s ({:.0}/s; {ended}), p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs ({}); the watching thread used {:.2} of a core",
            what.title,
            latencies_us.len(),
            what.items,
            latencies_us.len() as f64 / watched_s.max(1e-9),
            pct(0.5),
            pct(0.99),
            pct(1.0),
            what.target,
            client_cpu_s / watched_s.max(1e-9)
        );
    }
    // The daemon runs until the watchers have watched their whole window.
    drop(daemon);
    Ok(())
}

/// One stream a bench client watches, and how its latency is read.
struct Stream {
    request: &'static [u8],
    /// The lines measured start so.
    class: &'static [u8],
    /// The stamp each carries (ns, the host clock the scans were stamped by).
    key: &'static [u8],
    title: &'static str,
    items: &'static str,
    target: &'static str,
}

/// Fused frames (one scan each), stamped with their scan's stamp.
const MAP: Stream = Stream {
    request: b"{\"cmd\":\"watch\",\"status\":false,\"map\":true}\n",
    class: b"{\"class\":\"FRAME\"",
    key: b"\"stamp_ns\":",
    title: "scan in → fused frame at a `map` watcher",
    items: "frames",
    target: "target p99 ≤ 2000 µs",
};

/// People: a `TRACKS` line per fused step, stamped with the newest scan in it. The step
/// closes when a scan 25 ms newer than the last step arrives, so this counts the wait for
/// that scan as well as the tracker's work and the socket.
const TRACKS: Stream = Stream {
    request: b"{\"cmd\":\"watch\",\"status\":false,\"tracks\":true}\n",
    class: b"{\"class\":\"TRACKS\"",
    key: b"\"t_ns\":",
    title: "newest scan in → `TRACKS` at a `tracks` watcher",
    items: "TRACKS lines",
    target: "target p99 ≤ 5000 µs",
};

/// Watches `what` for `window_s`: each line's receive time minus its stamp (µs), how long it
/// watched, how the watch ended, and the CPU this thread used.
fn watch_stream(
    socket: &Path,
    window_s: f64,
    what: &Stream,
) -> Result<(Vec<f64>, f64, String, f64), String> {
    let stream = common::connect_when_up(socket).map_err(|e| e.to_string())?;
    let err = |e: std::io::Error| e.to_string();
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .map_err(err)?;
    let mut writer = stream.try_clone().map_err(err)?;
    let mut reader = BufReader::with_capacity(1 << 20, stream);
    writer.write_all(what.request).map_err(err)?;
    let t0 = Instant::now();
    let mut latencies_us = Vec::new();
    let mut line = Vec::new();
    let key = what.key;
    let mut ended = "watched to the end".to_string();
    while t0.elapsed().as_secs_f64() < window_s {
        line.clear();
        if reader.read_until(b'\n', &mut line).map_err(err)? == 0 {
            ended = "dropped by the daemon: it fell behind the stream".into();
            break;
        }
        let received_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_err(|e| e.to_string())?
            .as_nanos() as u64;
        if !line.starts_with(what.class) {
            if line.starts_with(b"{\"class\":\"ERROR\"") {
                ended = format!("dropped: {}", String::from_utf8_lossy(&line).trim());
            }
            continue;
        }
        let Some(at) = line.windows(key.len()).position(|w| w == key) else {
            continue;
        };
        let digits: Vec<u8> = line[at + key.len()..]
            .iter()
            .copied()
            .take_while(u8::is_ascii_digit)
            .collect();
        if let Some(stamp_ns) = std::str::from_utf8(&digits)
            .ok()
            .and_then(|d| d.parse::<u64>().ok())
        {
            latencies_us.push(received_ns.saturating_sub(stamp_ns) as f64 / 1e3);
        }
    }
    Ok((latencies_us, t0.elapsed().as_secs_f64(), ended, own_cpu_s()))
}
