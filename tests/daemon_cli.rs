//! `scanfuse check` and `scanfuse status`, run as the built binary.

use crate::daemon_common;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use daemon_common::start;
use scanfuse::daemon::protocol::{Crossing, EventKind, Message, Side, Track, Tracks};
use scanfuse::daemon::socket::ServerOptions;

const BIN: &str = env!("CARGO_BIN_EXE_scanfuse");

fn scanfuse(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().expect("run scanfuse")
}

const GOOD: &str = r#"[site]
name = "t"
state_dir = "state"
socket = "run/s.sock"
anchor = "a"

[[sensor]]
id = "a"
connect = "tcp://127.0.0.1:10940"

[[sensor]]
id = "b"
connect = "replay:rec.mcap#b"
"#;

#[test]
fn check_accepts_a_good_config_and_the_documented_example() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("site.toml");
    std::fs::write(&path, GOOD).unwrap();
    std::fs::write(dir.path().join("rec.mcap"), b"").unwrap();
    let out = scanfuse(&["check", "--config", path.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("2 sensors, anchor a"), "{stdout}");
    assert!(stdout.contains("no saved poses yet"), "{stdout}");
    assert!(stdout.trim_end().ends_with("config OK"), "{stdout}");

    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/site-example.toml");
    let out = scanfuse(&["check", "--config", example.to_str().unwrap()]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn check_exits_2_naming_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rec.mcap"), b"").unwrap();
    let path = dir.path().join("site.toml");
    let shown = path.display().to_string();
    let cases = [
        (
            GOOD.replace("id = \"b\"", "id = \"b\"\nspeed = 3"),
            "13: sensor.speed: unknown field `speed`",
        ),
        (
            GOOD.replace("id = \"b\"", "id = \"a\""),
            "12: sensor.id: duplicate sensor id \"a\", first used at line 8",
        ),
        (
            GOOD.replace("tcp://127.0.0.1:10940", "tcp://127.0.0.1"),
            "9: sensor.connect: \"tcp://127.0.0.1\" has no port",
        ),
        (
            GOOD.replace("anchor = \"a\"", "anchor = \"c\""),
            "5: site.anchor: \"c\" is not one of the sensors; use one of a, b",
        ),
        (
            GOOD.replace("rec.mcap", "gone.mcap"),
            "13: sensor.connect: the recording",
        ),
        (
            GOOD.replace("[site]", "[site]\nname2 = 1"),
            "2: site.name2: unknown field `name2`, expected one of",
        ),
    ];
    for (text, want) in cases {
        std::fs::write(&path, &text).unwrap();
        let out = scanfuse(&["check", "--config", path.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{want}: {stderr}");
        assert!(
            stderr.contains(&format!("{shown}:{want}")),
            "want {want:?} in: {stderr}"
        );
    }
    // The page: anywhere but loopback needs a token file only its owner (and group) can read.
    let token = dir.path().join("web.token");
    std::fs::write(&token, "0123456789abcdef0123456789abcdef\n").unwrap();
    std::fs::set_permissions(&token, std::os::unix::fs::PermissionsExt::from_mode(0o644)).unwrap();
    let web = |lines: &str| format!("{GOOD}\n[web]\nlisten = \"0.0.0.0:8080\"\n{lines}");
    for (text, want, code) in [
        (
            web(""),
            "16: web.listen: 0.0.0.0:8080 is reachable from other machines",
            2,
        ),
        (
            web("token_file = \"web.token\"\n"),
            "17: web.token_file: the token file",
            2,
        ),
    ] {
        std::fs::write(&path, &text).unwrap();
        let out = scanfuse(&["check", "--config", path.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{want}: {stderr}");
        assert!(
            stderr.contains(&format!("{shown}:{want}")),
            "want {want:?} in: {stderr}"
        );
    }
    std::fs::set_permissions(&token, std::os::unix::fs::PermissionsExt::from_mode(0o600)).unwrap();
    std::fs::write(&path, web("token_file = \"web.token\"\n")).unwrap();
    let out = scanfuse(&["check", "--config", path.to_str().unwrap()]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let out = scanfuse(&[
        "check",
        "--config",
        dir.path().join("none.toml").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot read the config"));
}

#[test]
fn status_says_the_daemon_is_not_running_and_how_to_start_it() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("none.sock");
    let out = scanfuse(&["status", "--socket", sock.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("scanfuse is not running at {}", sock.display())),
        "{stderr}"
    );
    assert!(stderr.contains("systemctl start scanfuse"), "{stderr}");

    // A socket file with nobody listening.
    drop(std::os::unix::net::UnixListener::bind(&sock).unwrap());
    let out = scanfuse(&["status", "--socket", sock.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("nothing listens"), "{stderr}");
}

async fn run_blocking(args: Vec<String>) -> Output {
    tokio::task::spawn_blocking(move || {
        Command::new(BIN)
            .args(&args)
            .output()
            .expect("run scanfuse")
    })
    .await
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_prints_a_table_or_the_raw_objects() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), ServerOptions::default(), 64);
    let socket_arg = sock.to_str().unwrap().to_string();

    let out = run_blocking(vec!["status".into(), "--socket".into(), socket_arg.clone()]).await;
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    assert!(lines[0].starts_with("site test-hall"), "{stdout}");
    assert!(lines[1].starts_with("SENSOR"), "{stdout}");
    assert!(
        lines[2].starts_with("entrance") && lines[2].contains("streaming"),
        "{stdout}"
    );
    assert!(
        lines[2].contains("40.0") && lines[2].contains("surveyed"),
        "{stdout}"
    );
    assert!(
        lines[3].starts_with("dock") && lines[3].contains("disconnected"),
        "{stdout}"
    );
    assert!(
        lines[3].contains("connection refused by 127.0.0.1:10941 (4s ago)"),
        "{stdout}"
    );
    assert_eq!(lines[4], "dock: not registered: no static view yet");

    // --config takes the socket from the site config.
    let config = dir.path().join("site.toml");
    let text = GOOD
        .replace("run/s.sock", &socket_arg)
        .replace("replay:rec.mcap#b", "tcp://127.0.0.1:10941");
    std::fs::write(&config, text).unwrap();
    let args = vec![
        "status".into(),
        "--config".into(),
        config.to_str().unwrap().into(),
    ];
    let out = run_blocking(args).await;
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("site test-hall"));

    let out = run_blocking(vec![
        "status".into(),
        "--json".into(),
        "--socket".into(),
        socket_arg,
    ])
    .await;
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0));
    let objects: Vec<Message> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(
        matches!(objects.as_slice(), [Message::Status(_), Message::Poses(_)]),
        "{stdout}"
    );
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_watch_follows_events() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), ServerOptions::default(), 64);
    let mut child = Command::new(BIN)
        .args(["status", "--watch", "--socket", sock.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let next = async |rx: &mut tokio::sync::mpsc::UnboundedReceiver<String>| {
        tokio::time::timeout(Duration::from_secs(10), rx.recv())
            .await
            .ok()
            .flatten()
    };
    // Wait until it is watching, then publish.
    loop {
        let line = next(&mut rx)
            .await
            .expect("the table and the watching line");
        if line.starts_with("watching events") {
            break;
        }
    }
    server
        .publisher
        .announce(EventKind::Moved, Some("dock"), "dock moved by 0.8 m");
    let line = next(&mut rx).await.expect("an event line");
    assert!(line.ends_with("dock  moved: dock moved by 0.8 m"), "{line}");
    // People: a summary per second of the scans' clock, every crossing.
    let track = |id: u64, x_m: f64| Track {
        id,
        x_m,
        y_m: 2.0,
        vx_m_s: 0.0,
        vy_m_s: 0.0,
        sigma_m: 0.05,
        age_s: 1.0,
        sensors: vec![],
    };
    for (i, x) in [4.1, 4.15, 4.2].iter().enumerate() {
        server.publisher.people(Message::Tracks(Tracks {
            t_ns: 1_000_000_000 + i as u64 * 100_000_000,
            tracks: vec![track(3, *x), track(5, 0.3)],
        }));
    }
    server.publisher.people(Message::Crossing(Crossing {
        t_ns: 1_300_000_000,
        line: "door".into(),
        track: 5,
        to: Side::Right,
        left_total: 0,
        right_total: 1,
    }));
    let line = next(&mut rx).await.expect("a people line");
    assert!(
        line.ends_with("2 people: t3 (4.1, 2.0) t5 (0.3, 2.0)"),
        "{line}"
    );
    let line = next(&mut rx).await.expect("a crossing line");
    assert!(
        line.ends_with("door: t5 crossed to the right (left 0, right 1)"),
        "{line} (the other TRACKS of that second are not printed)"
    );
    // When the daemon stops, the client says so and exits 1.
    server.shutdown().await;
    let status = tokio::task::spawn_blocking(move || child.wait().unwrap())
        .await
        .unwrap();
    assert_eq!(status.code(), Some(1));
}

/// `scanfuse status --watch | head -5`: once its reader has gone, the client exits 0 at its
/// next line, with nothing on stderr.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_watch_whose_reader_went_away_exits_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), ServerOptions::default(), 64);
    let mut child = Command::new(BIN)
        .args(["status", "--watch", "--socket", sock.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    // Read up to the watching line, as `head` would, then close the pipe.
    let read = tokio::task::spawn_blocking(move || {
        use std::io::BufRead;
        let mut lines = Vec::new();
        let mut reader = std::io::BufReader::new(stdout);
        loop {
            let mut line = String::new();
            if reader.read_line(&mut line).unwrap() == 0 {
                break;
            }
            let watching = line.starts_with("watching events");
            lines.push(line);
            if watching {
                break;
            }
        }
        lines
    });
    let lines = tokio::time::timeout(Duration::from_secs(20), read)
        .await
        .expect("the table and the watching line")
        .unwrap();
    assert!(
        lines
            .last()
            .is_some_and(|l| l.starts_with("watching events")),
        "{lines:?}"
    );
    // The reader is dropped: the next event the client prints meets a closed pipe.
    let mut exited = None;
    for i in 0..200 {
        server
            .publisher
            .announce(EventKind::Moved, Some("dock"), format!("dock moved {i}"));
        if let Some(status) = child.try_wait().unwrap() {
            exited = Some(status);
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let status = exited.expect("the client exits once its reader is gone");
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    assert_eq!(status.code(), Some(0), "{stderr}");
    assert_eq!(stderr, "", "nothing on stderr");
    server.shutdown().await;
}
