//! What `scanfuse replay` serves while it runs, seen from outside the process:
//!
//! - `--web ADDR`: the page answers (200, the embedded HTML);
//! - `--foxglove ADDR`: a Foxglove client from another codebase (tests/python/
//!   foxglove_client.py: Python `websockets` with the `foxglove.sdk.v1` subprotocol, decoding
//!   with the protobuf schemas the server advertises) receives a LaserScan with plausible
//!   ranges, FrameTransforms naming every placed sensor at the pose the status socket's
//!   `poses` reports, and the occupancy Grid. Needs SCANFUSE_TEST_PYTHON (skips without it,
//!   except under CI).

use crate::common;
use crate::daemon_run_common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::protocol::Status;

/// The port of the first `127.0.0.1:PORT` in a status line (`page at http://…`,
/// `Foxglove at ws://…`): the servers bind port 0 and say which port they got, so no test
/// races another process for a port it picked and let go.
fn port_in(line: &str) -> Option<u16> {
    let (_, rest) = line.split_once("127.0.0.1:")?;
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// The port a server of the replay `client` talks to says it bound (`line` picks its status
/// line), once it says.
fn bound_port(client: &mut Client, what: &str, line: impl Fn(&Status) -> Option<String>) -> u16 {
    wait_for(Duration::from_secs(60), what, || {
        line(&client.status()).as_deref().and_then(port_in)
    })
}

/// `scanfuse replay hall.mcap` at ×0.05 (the 2 s recording lasts 40 s) with `extra` flags.
fn start_replay(dir: &Path, extra: &[String]) -> Proc {
    let log = std::fs::File::create(dir.join("replay.log")).unwrap();
    Proc(
        Command::new(bin())
            .arg("replay")
            .arg(fixture("hall.mcap"))
            .args(["--speed", "0.05", "--out"])
            .arg(dir.join("out"))
            .args(extra)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("start scanfuse replay"),
    )
}

/// The status socket `start_serving` gives a replay in `dir`.
fn socket_in(dir: &Path) -> std::path::PathBuf {
    dir.join("s.sock")
}

/// `start_replay` serving `flag` (`--web`, `--foxglove`) at `addr`, with its status socket in
/// `dir` (`socket_in`), and a client of that socket.
fn start_serving(dir: &Path, flag: &str, addr: &str) -> (Proc, Client) {
    let sock = socket_in(dir);
    let replay = start_replay(
        dir,
        &[
            flag.into(),
            addr.into(),
            "--socket".into(),
            sock.display().to_string(),
        ],
    );
    (replay, Client::connect(&sock, Duration::from_secs(30)))
}

fn log_tail(dir: &Path) -> String {
    let log = std::fs::read_to_string(dir.join("replay.log")).unwrap_or_default();
    let mut lines: Vec<&str> = log.lines().rev().take(30).collect();
    lines.reverse();
    lines.join("\n")
}

/// One GET on loopback; the status line and the body.
fn get(port: u16, path: &str) -> Option<(String, String)> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).ok()?;
    let text = String::from_utf8_lossy(&raw).into_owned();
    let (head, body) = text.split_once("\r\n\r\n")?;
    Some((head.lines().next()?.to_string(), body.to_string()))
}

#[test]
fn replay_with_web_serves_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let (_replay, mut client) = start_serving(dir.path(), "--web", "127.0.0.1:0");
    let port = bound_port(&mut client, "the page's address", |s| s.web.clone());
    let (status, body) = wait_for(Duration::from_secs(60), "the page to answer", || {
        get(port, "/")
    });
    assert!(
        status.contains(" 200"),
        "{status}\n{}",
        log_tail(dir.path())
    );
    assert!(
        body.contains("<html") && body.contains("data-ready"),
        "the page itself: {}",
        &body[..body.len().min(300)]
    );
}

#[test]
fn a_foxglove_client_gets_scans_transforms_at_the_socket_poses_and_the_grid() {
    let test = "a_foxglove_client_gets_scans_transforms_at_the_socket_poses_and_the_grid";
    let Some(python) = common::test_python(test) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (_replay, mut client) = start_serving(dir.path(), "--foxglove", "127.0.0.1:0");
    let port = bound_port(&mut client, "the Foxglove server's address", |s| {
        s.foxglove.clone()
    });
    assert_eq!(
        client.status().foxglove.as_deref(),
        Some(format!("Foxglove at ws://127.0.0.1:{port}").as_str()),
        "status names the Foxglove server"
    );
    wait_for(Duration::from_secs(60), "two sensors registered", || {
        (client
            .poses()
            .sensors
            .iter()
            .filter(|p| p.registered)
            .count()
            >= 2)
            .then_some(())
    });
    let out = Command::new(python)
        .arg(common::repo().join("tests/python/foxglove_client.py"))
        .args(["--url", &format!("ws://127.0.0.1:{port}")])
        .arg("--socket")
        .arg(socket_in(dir.path()))
        .output()
        .expect("run the Foxglove client");
    assert!(
        out.status.success(),
        "the Foxglove client failed: {}\n{}\n--- replay log (end) ---\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
        log_tail(dir.path())
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).expect("a JSON summary");
    assert!(
        !summary["scan_topics"].as_array().unwrap().is_empty(),
        "{summary}"
    );
    assert!(
        summary["transforms"].as_object().unwrap().len() >= 2,
        "{summary}"
    );
    assert!(summary["grid"][0].as_u64().unwrap() > 10, "{summary}");
}

#[test]
fn a_taken_foxglove_port_is_reported_and_the_replay_goes_on() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let dir = tempfile::tempdir().unwrap();
    let (_replay, mut client) =
        start_serving(dir.path(), "--foxglove", &format!("127.0.0.1:{port}"));
    let status = client.status();
    let why = status.foxglove.unwrap_or_default();
    assert!(
        why.starts_with("no Foxglove server") && why.contains("taken"),
        "{why}"
    );
    wait_for(Duration::from_secs(60), "a sensor streaming", || {
        client
            .status()
            .sensors
            .iter()
            .any(|s| s.scans > 0)
            .then_some(())
    });
    assert!(
        log_tail(dir.path()).contains("no Foxglove server"),
        "an error line in the log"
    );
}
