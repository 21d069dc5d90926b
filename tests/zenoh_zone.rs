//! A zone daemon on Zenoh, heard by a peer from another codebase (eclipse-zenoh, Python,
//! tests/python/zenoh_site.py) that stands where the site daemon will: the real `scanfuse
//! run` with `[zenoh]` replays three hall units, connects to the peer, and the peer hears its
//! liveliness token and its poses (the socket's `poses` reply, schema-named), and gets each
//! unit's static view when it asks. Frozen (its
//! link up but silent, as a zone cut off), the zone is lost to the peer within 2 s (the lease)
//! and rejoins when it thaws; killed, it is gone at once; started again, it comes back, with
//! no restart of the peer.
//!
//! Needs `SCANFUSE_TEST_PYTHON` with eclipse-zenoh (the venv `.ci/run` builds); skips with a
//! note without it, except under CI.
#![cfg(feature = "zenoh")]

use crate::common;
use crate::daemon_run_common;

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use daemon_run_common::{
    Client, HALL, Proc, fixture, replay_sensors, start_daemon, wait_for, write_config,
};
use serde_json::Value;

/// How long any one expected thing may take before the test gives up (not a timing assert).
const PATIENCE: Duration = Duration::from_secs(60);

/// The Python peer: its stdin (closing it ends the peer) and its lines as they come.
struct Peer {
    child: Child,
    stdin: ChildStdin,
    lines: mpsc::Receiver<Value>,
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Peer {
    fn start(python: &std::path::Path, endpoint: &str) -> Peer {
        let mut child = Command::new(python)
            .arg(common::repo().join("tests/python/zenoh_site.py"))
            .args([endpoint, "test"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start the Python Zenoh peer");
        let stdin = child.stdin.take().expect("piped stdin");
        let out = child.stdout.take().expect("piped stdout");
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                let v: Value = serde_json::from_str(&line)
                    .unwrap_or_else(|e| panic!("the peer printed {line:?}: {e}"));
                if tx.send(v).is_err() {
                    break;
                }
            }
        });
        let mut peer = Peer {
            child,
            stdin,
            lines,
        };
        peer.next_where("the peer listening", |v| v["event"] == "listening");
        peer
    }

    /// The replies to a query on `key_expr`, as they come, until the peer says it is done.
    fn get(&mut self, key_expr: &str) -> Vec<Value> {
        writeln!(self.stdin, "{key_expr}").expect("write to the peer");
        let mut replies = Vec::new();
        loop {
            let v = self.next_where("a reply", |v| {
                v["event"] == "reply" || v["event"] == "replied"
            });
            if v["event"] == "replied" {
                return replies;
            }
            replies.push(v);
        }
    }

    /// The next line that `want`s, skipping the others (named, if it never comes: what the
    /// peer did hear meanwhile is what tells a lost event from a late one).
    fn next_where(&mut self, what: &str, want: impl Fn(&Value) -> bool) -> Value {
        let until = Instant::now() + PATIENCE;
        let mut skipped: Vec<String> = Vec::new();
        loop {
            let left = until.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(v) if want(&v) => return v,
                Ok(v) => skipped.push(format!("{} {}", v["event"], v["key"])),
                Err(e) => panic!(
                    "waiting for {what}: {e}; the peer heard meanwhile ({} lines, the last 20): {:?}",
                    skipped.len(),
                    &skipped[skipped.len().saturating_sub(20)..]
                ),
            }
        }
    }
}

fn alive(kind: &'static str) -> impl Fn(&Value) -> bool {
    move |v| v["event"] == "alive" && v["key"] == "scanfuse/test/east/alive" && v["kind"] == kind
}

/// Poses of the zone with every unit of it placed.
fn all_placed(v: &Value) -> bool {
    v["event"] == "poses"
        && v["poses"]["sensors"]
            .as_array()
            .is_some_and(|s| s.len() == 3 && s.iter().all(|s| s["registered"] == true))
}

#[test]
fn a_zone_is_heard_on_zenoh_lost_when_silent_gone_when_killed_and_comes_back() {
    let Some(python) = common::test_python("zenoh_zone") else {
        return;
    };
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut peer = Peer::start(&python, &endpoint);

    let dir = tempfile::tempdir().unwrap();
    let sensors = replay_sensors(&fixture("hall.mcap"), &HALL[..3]);
    let config = write_config(
        dir.path(),
        "gate",
        &sensors,
        &format!("\n[zenoh]\nzone = \"east\"\nconnect = [\"{endpoint}\"]\n"),
    );
    let mut daemon = start_daemon(&config, dir.path());
    peer.next_where("the zone's token", alive("put"));
    let heard = peer.next_where("the zone's poses, all placed", all_placed);
    assert_eq!(heard["key"], "scanfuse/test/east/poses");
    assert_eq!(heard["schema"], "scanfuse.zone.poses/1");
    assert_eq!(
        (&heard["site"], &heard["zone"]),
        (&"test".into(), &"east".into())
    );
    assert!(
        heard["encoding"]
            .as_str()
            .is_some_and(|e| e.contains("json")),
        "{heard}"
    );
    assert!(
        heard["t_ns"]
            .as_u64()
            .is_some_and(|t| t > 1_600_000_000_000_000_000)
    );
    // The same vocabulary and the same poses as the daemon's own socket.
    let mut client = Client::connect(&dir.path().join("s.sock"), PATIENCE);
    let status = client.status();
    let line = status.zenoh.expect("status says the zone is on Zenoh");
    assert!(
        line.contains("zone east") && line.contains(&endpoint),
        "{line}"
    );
    let socket = client.poses();
    assert_eq!(heard["poses"]["anchor"], socket.anchor);
    for s in &socket.sensors {
        let on_zenoh = heard["poses"]["sensors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|h| h["id"] == s.id.as_str())
            .unwrap_or_else(|| panic!("{} not on Zenoh: {heard}", s.id));
        let x = on_zenoh["x_m"].as_f64().unwrap();
        assert!(
            (x - s.x_m.unwrap()).abs() < 1e-3,
            "{}: {x} vs {:?}",
            s.id,
            s.x_m
        );
    }
    drop(client);
    // Static views on request: every unit's, or one.
    let views = peer.get("scanfuse/test/east/view/*");
    let mut ids: Vec<&str> = views.iter().filter_map(|v| v["sensor"].as_str()).collect();
    ids.sort_unstable();
    assert_eq!(ids, ["dock", "gate", "mezz"], "{views:?}");
    for v in &views {
        assert_eq!(v["schema"], "scanfuse.zone.view/1", "{v}");
        assert_eq!(
            v["key"],
            format!("scanfuse/test/east/view/{}", v["sensor"].as_str().unwrap())
        );
        assert!(v["ranges_m"].as_u64().is_some_and(|n| n > 500), "{v}");
        assert!(v["height_m"].as_f64().is_some(), "{v}");
    }
    assert_eq!(peer.get("scanfuse/test/east/view/mezz").len(), 1);
    assert_eq!(peer.get("scanfuse/test/east/view/nobody").len(), 0);

    // Frozen (SIGSTOP: its link stays up but goes quiet, as a zone cut off by the network):
    // the peer sees the token go when the lease runs out; thawed, it rejoins by itself.
    let frozen = Instant::now();
    daemon.signal("STOP");
    peer.next_where("the frozen zone's token withdrawn", alive("delete"));
    let lost = frozen.elapsed();
    println!("zone frozen → lost to the peer in {lost:?}");
    daemon.signal("CONT");
    peer.next_where("the thawed zone's token", alive("put"));
    let back = frozen.elapsed() - lost;
    println!("zone thawed → back in {back:?}");
    peer.next_where("the thawed zone's poses", all_placed);
    assert!(lost < Duration::from_secs(2), "{lost:?}");

    // Killed (no goodbye): the peer sees the token go.
    let killed = Instant::now();
    daemon.0.kill().unwrap();
    let _ = daemon.0.wait();
    peer.next_where("the zone's token withdrawn", alive("delete"));
    let gone = killed.elapsed();
    println!("zone killed → gone from the peer's view in {gone:?}");
    assert!(gone < Duration::from_secs(2), "{gone:?}");

    // Started again: it comes back to the same peer, which was never restarted.
    let daemon: Proc = start_daemon(&config, dir.path());
    peer.next_where("the zone's token again", alive("put"));
    peer.next_where("the zone's poses again", all_placed);
    // A second daemon claiming the same zone refuses it, says why, and serves its own socket.
    let other = tempfile::tempdir().unwrap();
    let twin_config = write_config(
        other.path(),
        "gate",
        &sensors,
        &format!("\n[zenoh]\nzone = \"east\"\nconnect = [\"{endpoint}\"]\n"),
    );
    let _twin = start_daemon(&twin_config, other.path());
    let mut twin = Client::connect(&other.path().join("s.sock"), PATIENCE);
    let said = wait_for(PATIENCE, "the twin to say the zone is taken", || {
        twin.status()
            .zenoh
            .filter(|z| z.contains("already holds zone east"))
    });
    println!("the twin: {said}");
    drop(daemon);
    peer.next_where("the zone's token withdrawn again", alive("delete"));
}
