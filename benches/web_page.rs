//! The page's figures (issue 17): the daemon (`scanfuse run`, a child process) on the demo's
//! five `hall` sensors looped at ×1, its page on loopback, and:
//!
//! - page weight: bytes of the HTML `GET /` serves (target < 200 kB);
//! - time from opening the page's WebSocket to its first message and to its first scan
//!   (`FRAME`), on loopback (target < 1 s);
//! - the daemon's CPU (utime + stime of the child from /proc/PID/stat over a window) with no
//!   page open, then with 10 page clients reading everything (`[web] frames_per_s` = 10):
//!   the 10 clients should cost < 10 % of one core;
//! - bytes per second per page client, and which classes they go to;
//! - the same for one Foxglove client (`[foxglove]`, subscribed to every topic): the daemon's
//!   CPU with it and its bytes per second per topic.
//!
//! Run: `cargo build --release --bin scanfuse` then
//! `SCANFUSE_BIN=target/release/scanfuse cargo bench --bench web_page` (the daemon's figures
//! are the binary's: a debug build costs several times more). `SCANFUSE_BENCH_S` sets each
//! CPU window (default 20 s), `SCANFUSE_BENCH_CLIENTS` the clients (default 10).

mod common;

use std::collections::BTreeMap;
use std::io::{BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use scanfuse::daemon::protocol::Message;
use tokio_tungstenite::tungstenite::Message as Ws;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;

type Error = Box<dyn std::error::Error + Send + Sync>;

const HALL: [(&str, &str); 5] = [
    ("gate", "height_m = 1.1"),
    ("dock", "height_m = 1.1"),
    ("mezz", "height_m = 1.0"),
    ("tough", "height_m = 1.2"),
    ("tilt", "height_m = 2.5\npitch_deg = -20.0"),
];

/// CPU seconds (user + system) the process `pid` has used.
fn cpu_s(pid: u32, ticks_per_s: f64) -> Result<f64, Error> {
    Ok(common::cpu_ticks(pid)? as f64 / ticks_per_s)
}

/// `(placed, streaming)` sensors, from one `status` and one `poses` request.
fn site_state(socket: &std::path::Path) -> Result<(usize, usize), Error> {
    let mut stream = BufReader::new(common::connect_when_up(socket).map_err(|e| e.to_string())?);
    let mut ask = |req: &str| common::ask(&mut stream, req);
    let streaming = match ask("{\"cmd\":\"status\"}\n")? {
        Message::Status(s) => s.sensors.iter().filter(|x| x.rate_hz.is_some()).count(),
        _ => 0,
    };
    let placed = match ask("{\"cmd\":\"poses\"}\n")? {
        Message::Poses(p) => p.sensors.iter().filter(|x| x.registered).count(),
        _ => 0,
    };
    Ok((placed, streaming))
}

/// The body of `GET /`.
fn page(port: u16) -> Result<Vec<u8>, Error> {
    let mut s = TcpStream::connect(("127.0.0.1", port))?;
    write!(
        s,
        "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw)?;
    let at = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or("no HTTP header end")?;
    let head = String::from_utf8_lossy(&raw[..at]);
    if !head.starts_with("HTTP/1.1 200") {
        return Err(format!("GET / answered {}", head.lines().next().unwrap_or("")).into());
    }
    Ok(raw[at + 4..].to_vec())
}

/// The class of a page message, without parsing its points.
fn class(text: &str) -> &str {
    const KEY: &str = "\"class\":\"";
    text.find(KEY)
        .and_then(|i| {
            let rest = &text[i + KEY.len()..];
            rest.get(..rest.find('"')?)
        })
        .unwrap_or("?")
}

/// Opens the page's WebSocket: (time to the first message, time to the first FRAME).
async fn first_frame(port: u16) -> Result<(Duration, Duration), Error> {
    let start = Instant::now();
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/ws")).await?;
    let mut first = None;
    while let Some(m) = tokio::time::timeout(Duration::from_secs(10), ws.next()).await? {
        if let Ws::Text(t) = m? {
            first.get_or_insert(start.elapsed());
            if class(&t) == "FRAME" {
                return Ok((first.unwrap_or_default(), start.elapsed()));
            }
        }
    }
    Err("the page's WebSocket closed before a FRAME".into())
}

/// Bytes (payload) a page client received, per class.
#[derive(Default)]
struct Tally {
    bytes: BTreeMap<String, u64>,
}

/// One page client reading everything until `stop`; counts bytes per class while `counting`.
async fn client(
    port: u16,
    counting: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    total: Arc<AtomicU64>,
) -> Result<Tally, Error> {
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/ws")).await?;
    let mut tally = Tally::default();
    while !stop.load(Ordering::Relaxed) {
        let Ok(next) = tokio::time::timeout(Duration::from_millis(200), ws.next()).await else {
            continue;
        };
        let Some(m) = next else {
            return Err("a page client was closed".into());
        };
        if let Ws::Text(t) = m?
            && counting.load(Ordering::Relaxed)
        {
            *tally.bytes.entry(class(&t).to_string()).or_default() += t.len() as u64;
            total.fetch_add(t.len() as u64, Ordering::Relaxed);
        }
    }
    Ok(tally)
}

/// One Foxglove client subscribed to every channel for `window`: bytes of message data per
/// topic.
async fn foxglove_client(port: u16, window: Duration) -> Result<BTreeMap<String, u64>, Error> {
    let mut request = format!("ws://127.0.0.1:{port}").into_client_request()?;
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static("foxglove.sdk.v1"),
    );
    let (mut ws, _) = tokio_tungstenite::connect_async(request).await?;
    let mut topics: BTreeMap<u64, String> = BTreeMap::new();
    let mut subscriptions: BTreeMap<u32, String> = BTreeMap::new();
    let mut bytes: BTreeMap<String, u64> = BTreeMap::new();
    let end = tokio::time::Instant::now() + window;
    while let Ok(next) = tokio::time::timeout_at(end, ws.next()).await {
        match next.ok_or("the Foxglove server closed")?? {
            Ws::Text(t) => {
                let v: serde_json::Value = serde_json::from_str(&t)?;
                if v["op"] != "advertise" {
                    continue;
                }
                let mut subs = Vec::new();
                for ch in v["channels"].as_array().into_iter().flatten() {
                    let (Some(id), Some(topic)) = (ch["id"].as_u64(), ch["topic"].as_str()) else {
                        continue;
                    };
                    topics.insert(id, topic.to_string());
                    let sub = subscriptions.len() as u32 + 1;
                    subscriptions.insert(sub, topic.to_string());
                    subs.push(serde_json::json!({"id": sub, "channelId": id}));
                }
                let msg = serde_json::json!({"op": "subscribe", "subscriptions": subs});
                ws.send(Ws::Text(msg.to_string().into())).await?;
            }
            Ws::Binary(b) if b.first() == Some(&1) && b.len() >= 13 => {
                let sub = u32::from_le_bytes([b[1], b[2], b[3], b[4]]);
                let topic = subscriptions.get(&sub).cloned().unwrap_or_default();
                *bytes.entry(topic).or_default() += b.len() as u64;
            }
            _ => {}
        }
    }
    Ok(bytes)
}

fn main() -> Result<(), Error> {
    let window_s = common::env_f64("SCANFUSE_BENCH_S", 20.0);
    let clients = common::env_f64("SCANFUSE_BENCH_CLIENTS", 10.0) as usize;
    let bin = std::env::var("SCANFUSE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_scanfuse").to_string());
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/hall.mcap");
    let dir = tempfile::tempdir()?;
    let socket = dir.path().join("s.sock");
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let fox_port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let mut text = format!(
        "[site]\nname = \"web-bench\"\nstate_dir = \"{}\"\nsocket = \"{}\"\nanchor = \"gate\"\n",
        dir.path().join("state").display(),
        socket.display()
    );
    for (id, extra) in HALL {
        text.push_str(&format!(
            "\n[[sensor]]\nid = \"{id}\"\nconnect = \"replay:{}#{id}\"\nmode = \"MD\"\n{extra}\n",
            fixture.display()
        ));
    }
    text.push_str(&format!(
        "\n[web]\nlisten = \"127.0.0.1:{port}\"\nframes_per_s = 10\nmax_clients = {}\n",
        clients.max(1) + 2
    ));
    text.push_str(&format!(
        "\n[foxglove]\nlisten = \"127.0.0.1:{fox_port}\"\n"
    ));
    let config = dir.path().join("site.toml");
    std::fs::write(&config, text)?;
    let run_s = 3.0 * window_s + 120.0;
    let daemon = common::Daemon(
        Command::new(&bin)
            .args(["run", "--for", &format!("{run_s:.0}s"), "--config"])
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.path().join("daemon.log"))?)
            .spawn()?,
    );
    let pid = daemon.0.id();
    let ticks = common::ticks_per_s();
    println!("web_page: {bin}, hall × 5 sensors looped at ×1, page on 127.0.0.1:{port}");

    // Registered and streaming before anything is measured.
    let started = Instant::now();
    loop {
        let (placed, streaming) = site_state(&socket)?;
        if placed == 5 && streaming == 5 {
            break;
        }
        if started.elapsed() > Duration::from_secs(90) {
            return Err(format!("after 90 s: {placed} placed, {streaming} streaming").into());
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    println!(
        "  site ready after {:.1} s (5 placed, 5 streaming)",
        started.elapsed().as_secs_f64()
    );

    let html = page(port)?;
    println!(
        "  page weight: {} bytes ({:.1} kB; target < 200 kB)",
        html.len(),
        html.len() as f64 / 1000.0
    );

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let mut opens = Vec::new();
    for _ in 0..5 {
        opens.push(runtime.block_on(first_frame(port))?);
        std::thread::sleep(Duration::from_millis(300));
    }
    let worst_first = opens.iter().map(|o| o.0).max().unwrap_or_default();
    let worst_frame = opens.iter().map(|o| o.1).max().unwrap_or_default();
    let mut frames: Vec<f64> = opens.iter().map(|o| o.1.as_secs_f64() * 1e3).collect();
    frames.sort_by(f64::total_cmp);
    println!(
        "  open → first message: worst {:.1} ms; open → first FRAME: median {:.1} ms, worst {:.1} ms (5 opens; target < 1 s)",
        worst_first.as_secs_f64() * 1e3,
        frames[frames.len() / 2],
        worst_frame.as_secs_f64() * 1e3
    );

    // No page open: the daemon alone (the page's hub idles: no scans are encoded for it).
    std::thread::sleep(Duration::from_secs(2));
    let c0 = cpu_s(pid, ticks)?;
    let t0 = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(window_s));
    let idle = (cpu_s(pid, ticks)? - c0) / t0.elapsed().as_secs_f64();
    println!(
        "  daemon CPU, no page open:    {:5.1} % of one core",
        idle * 100.0
    );

    let counting = Arc::new(AtomicBool::new(false));
    let stop = Arc::new(AtomicBool::new(false));
    let total = Arc::new(AtomicU64::new(0));
    let tasks: Vec<_> = (0..clients)
        .map(|_| {
            runtime.spawn(client(
                port,
                Arc::clone(&counting),
                Arc::clone(&stop),
                Arc::clone(&total),
            ))
        })
        .collect();
    // Warm-up: every client past its first snapshot.
    std::thread::sleep(Duration::from_secs(3));
    counting.store(true, Ordering::Relaxed);
    let c0 = cpu_s(pid, ticks)?;
    let t0 = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(window_s));
    let busy = (cpu_s(pid, ticks)? - c0) / t0.elapsed().as_secs_f64();
    counting.store(false, Ordering::Relaxed);
    let window = t0.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let mut classes: BTreeMap<String, u64> = BTreeMap::new();
    let mut alive = 0;
    for t in tasks {
        match runtime.block_on(t)? {
            Ok(tally) => {
                alive += 1;
                for (k, v) in tally.bytes {
                    *classes.entry(k).or_default() += v;
                }
            }
            Err(e) => println!("  a client failed: {e}"),
        }
    }
    println!(
        "  daemon CPU, {clients} pages open: {:5.1} % of one core → the pages cost {:+.1} % (target < 10 %)",
        busy * 100.0,
        (busy - idle) * 100.0
    );
    let per_client = total.load(Ordering::Relaxed) as f64 / window / alive.max(1) as f64;
    println!(
        "  per page client: {:.0} kB/s ({alive} of {clients} clients kept up)",
        per_client / 1000.0
    );
    let sum: u64 = classes.values().sum();
    for (k, v) in &classes {
        println!(
            "    {k:<8} {:7.1} kB/s  {:4.1} %",
            *v as f64 / window / alive.max(1) as f64 / 1000.0,
            100.0 * *v as f64 / sum.max(1) as f64
        );
    }

    // One Foxglove client, no page open.
    std::thread::sleep(Duration::from_secs(2));
    let c0 = cpu_s(pid, ticks)?;
    let t0 = Instant::now();
    let topics = runtime.block_on(foxglove_client(fox_port, Duration::from_secs_f64(window_s)))?;
    let window = t0.elapsed().as_secs_f64();
    let fox = (cpu_s(pid, ticks)? - c0) / window;
    let sum: u64 = topics.values().sum();
    println!(
        "  daemon CPU, 1 Foxglove client: {:5.1} % of one core ({:+.1} %); {:.0} kB/s to it",
        fox * 100.0,
        (fox - idle) * 100.0,
        sum as f64 / window / 1000.0
    );
    for (k, v) in &topics {
        println!("    {k:<12} {:7.1} kB/s", *v as f64 / window / 1000.0);
    }
    Ok(())
}
