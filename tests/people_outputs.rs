//! The tracking outputs received by real clients from other codebases: OSC by a python-osc
//! listener, MQTT by `mosquitto_sub` through a `mosquitto` broker the test starts (and stops
//! and starts again, to see the output go quiet and come back).
//!
//! The test publishes `TRACKS` into the daemon's people stream itself, as the tracker task
//! does (so that what each client must receive is known exactly), and runs the output task
//! (`daemon::people_out`) as the daemon runs it.
//!
//! Needs `SCANFUSE_TEST_PYTHON` with python-osc (the venv `.ci/run` builds) and Debian's
//! `mosquitto` and `mosquitto-clients` (`.ci/run` installs them); each test skips with a note
//! when its client is missing, except under CI.

use crate::common;
use crate::daemon_run_common;

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use scanfuse::daemon::config::{MqttConfig, PeopleConfig};
use scanfuse::daemon::people_out;
use scanfuse::daemon::protocol::{EventKind, Message, Side, Track, Tracks};
use scanfuse::daemon::socket::Publisher;
use scanfuse::track::zones::{CountLine, Zone};
use tokio::sync::mpsc;

/// How long any one expected thing may take before the test gives up (not a timing assert).
const PATIENCE: Duration = Duration::from_secs(30);

/// A zone north of a door along the x axis from (0, 0) to (4, 0).
fn site() -> PeopleConfig {
    PeopleConfig {
        zones: vec![Zone {
            id: "north".into(),
            polygon: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]],
        }],
        lines: vec![CountLine {
            id: "door".into(),
            from: [0.0, 0.0],
            to: [4.0, 0.0],
            hysteresis_m: 0.2,
        }],
        ..PeopleConfig::default()
    }
}

/// Person `id` at (2, y), seen at `t_ns`.
fn at(t_ns: u64, id: u64, y_m: f64) -> Message {
    Message::Tracks(Tracks {
        t_ns,
        tracks: vec![Track {
            id,
            x_m: 2.0,
            y_m,
            vx_m_s: 0.0,
            vy_m_s: 1.0,
            sigma_m: 0.05,
            age_s: 1.0,
            sensors: vec!["entrance".into()],
        }],
    })
}

/// Lines of a child's stdout, as they come.
fn lines_of(child: &mut Child) -> mpsc::UnboundedReceiver<String> {
    let out = child.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::unbounded_channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

async fn next(rx: &mut mpsc::UnboundedReceiver<String>, what: &str) -> String {
    match tokio::time::timeout(PATIENCE, rx.recv()).await {
        Ok(Some(line)) => line,
        _ => panic!("no {what}"),
    }
}

/// Kills the child when dropped (a failing test leaves no broker behind).
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn osc_reaches_a_python_osc_listener() {
    let Some(python) = common::test_python("osc_reaches_a_python_osc_listener") else {
        return;
    };
    let mut listener = Command::new(python)
        .arg(common::repo().join("tests/python/osc_listen.py"))
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the python-osc listener");
    let mut lines = lines_of(&mut listener);
    let listener = Killed(listener);
    let port: u16 = next(&mut lines, "port from the listener")
        .await
        .trim()
        .parse()
        .unwrap();

    let publisher = Publisher::new(64);
    let config = PeopleConfig {
        osc_targets: vec![format!("127.0.0.1:{port}").parse().unwrap()],
        ..site()
    };
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(people_out::run(
        config,
        "test".into(),
        publisher.clone(),
        tokio::sync::watch::channel(None).1,
        async move {
            let _ = stop_rx.await;
        },
    ));
    while publisher.people_watchers() == 0 {
        tokio::task::yield_now().await;
    }
    // Walk person 7 north through the door.
    for (i, y) in [-1.0, -0.5, 0.5, 1.0].iter().enumerate() {
        publisher.people(at(1_000 + i as u64, 7, *y));
    }
    let mut got: Vec<serde_json::Value> = Vec::new();
    loop {
        let line = next(&mut lines, "/scanfuse/crossing").await;
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        let done = v[0] == "/scanfuse/crossing";
        got.push(v);
        if done {
            break;
        }
    }
    let with =
        |addr: &str| -> Vec<&serde_json::Value> { got.iter().filter(|v| v[0] == addr).collect() };
    let frames = with("/scanfuse/frame");
    assert_eq!(
        frames[0],
        &serde_json::json!(["/scanfuse/frame", 1000, 1]),
        "{got:?}"
    );
    let tracks = with("/scanfuse/track");
    assert_eq!(
        tracks[0],
        &serde_json::json!(["/scanfuse/track", 7, 2.0, -1.0, 0.0, 1.0])
    );
    let zones = with("/scanfuse/zone");
    assert_eq!(
        zones.first(),
        Some(&&serde_json::json!(["/scanfuse/zone", "north", 0]))
    );
    assert_eq!(
        zones.last(),
        Some(&&serde_json::json!(["/scanfuse/zone", "north", 1]))
    );
    assert_eq!(
        with("/scanfuse/crossing"),
        vec![&serde_json::json!([
            "/scanfuse/crossing",
            "door",
            7,
            "left",
            1,
            0
        ])]
    );
    drop(listener);
    let _ = stop_tx.send(());
    task.await.unwrap();
}

/// The broker binary, or `None` (skip) outside CI.
fn mosquitto(test: &str) -> Option<(PathBuf, PathBuf)> {
    let find = |name: &str| {
        ["/usr/sbin", "/usr/bin", "/usr/local/sbin", "/usr/local/bin"]
            .iter()
            .map(|d| Path::new(d).join(name))
            .find(|p| p.is_file())
    };
    match (find("mosquitto"), find("mosquitto_sub")) {
        (Some(broker), Some(sub)) => Some((broker, sub)),
        _ if std::env::var_os("CI").is_some() => {
            panic!(
                "{test}: mosquitto and mosquitto_sub are missing under CI; .ci/run installs them"
            )
        }
        _ => {
            eprintln!(
                "{test}: skipped: needs mosquitto and mosquitto_sub (apt-get install mosquitto mosquitto-clients; .ci/run does)"
            );
            None
        }
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A broker on `port`, accepting connections when this returns.
async fn start_broker(broker: &Path, dir: &Path, port: u16) -> Killed {
    let conf = dir.join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
    )
    .unwrap();
    let child = Command::new(broker)
        .arg("-c")
        .arg(&conf)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start mosquitto");
    let child = Killed(child);
    tokio::time::timeout(PATIENCE, async {
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("mosquitto listening");
    child
}

/// The next event of `kind` on the publisher's event stream, and the errors seen before it.
async fn event(
    events: &mut tokio::sync::broadcast::Receiver<std::sync::Arc<str>>,
    kind: EventKind,
) -> (String, usize) {
    let mut errors = 0;
    tokio::time::timeout(PATIENCE, async {
        loop {
            let line = events.recv().await.unwrap();
            if let Ok(Message::Event(e)) = serde_json::from_str::<Message>(&line) {
                if e.kind == kind {
                    return (e.message, errors);
                }
                if e.kind == EventKind::Error {
                    errors += 1;
                }
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no {kind:?} event"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mqtt_reaches_a_real_broker_and_survives_it_going_away() {
    let Some((broker, sub)) = mosquitto("mqtt_reaches_a_real_broker_and_survives_it_going_away")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let publisher = Publisher::new(256);
    let mut events = publisher.subscribe_events();
    let config = PeopleConfig {
        mqtt: Some(MqttConfig {
            url: format!("mqtt://127.0.0.1:{port}"),
            host: "127.0.0.1".into(),
            port,
            topic_prefix: "scanfuse/test".into(),
            username: None,
            password_file: None,
        }),
        ..site()
    };
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(people_out::run(
        config,
        "test".into(),
        publisher.clone(),
        tokio::sync::watch::channel(None).1,
        async move {
            let _ = stop_rx.await;
        },
    ));

    // No broker yet: one error, and publishing does not wait for it.
    let (down, _) = event(&mut events, EventKind::Error).await;
    assert!(down.contains("cannot be reached"), "{down}");
    publisher.people(at(1, 7, -1.0));
    let mut broker_process = start_broker(&broker, dir.path(), port).await;
    let (back, errors) = event(&mut events, EventKind::Connected).await;
    assert!(back.contains("is back"), "{back}");
    assert_eq!(errors, 0, "the retries while it was away are quiet");

    let mut subscriber = Command::new(&sub)
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &port.to_string(),
            "-t",
            "scanfuse/test/#",
            "-v",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start mosquitto_sub");
    let mut lines = lines_of(&mut subscriber);
    let _subscriber = Killed(subscriber);
    // The latest ZONES is retained: a subscriber that comes later gets it at once.
    let payload = loop {
        let line = next(&mut lines, "the retained zones").await;
        let (topic, payload) = line.split_once(' ').unwrap();
        // TRACKS queued while the broker was away may come first; ZONES is what is asked.
        if topic == "scanfuse/test/zones" {
            break payload.to_string();
        }
        assert_eq!(topic, "scanfuse/test/tracks");
    };
    match serde_json::from_str::<Message>(&payload).unwrap() {
        Message::Zones(z) => assert_eq!((z.zones[0].id.as_str(), z.zones[0].count), ("north", 0)),
        other => panic!("{other:?}"),
    }
    // Walk north through the door, as the tracker would report it.
    let mut received: Vec<(String, Message)> = Vec::new();
    for (t_ns, y) in [(2, -0.5), (3, 0.5), (4, 1.0)] {
        publisher.people(at(t_ns, 7, y));
    }
    while !received
        .iter()
        .any(|(topic, _)| topic == "scanfuse/test/crossing")
        || !received.iter().any(|(_, m)| matches!(m, Message::Zones(_)))
    {
        let line = next(&mut lines, "the crossing and the new zone count").await;
        let (topic, payload) = line.split_once(' ').unwrap();
        received.push((topic.to_string(), serde_json::from_str(payload).unwrap()));
    }
    let tracks: Vec<&Message> = received
        .iter()
        .filter(|(t, _)| t == "scanfuse/test/tracks")
        .map(|(_, m)| m)
        .collect();
    assert!(
        tracks
            .iter()
            .all(|m| matches!(m, Message::Tracks(t) if t.tracks[0].id == 7)),
        "{tracks:?}"
    );
    let crossing = received.iter().find_map(|(t, m)| match m {
        Message::Crossing(c) if t == "scanfuse/test/crossing" => Some(c.clone()),
        _ => None,
    });
    let c = crossing.unwrap();
    assert_eq!((c.line.as_str(), c.track, c.to), ("door", 7, Side::Left));
    assert_eq!((c.left_total, c.right_total), (1, 0));

    // The broker goes away and comes back: one error, one line when it is back.
    drop(broker_process);
    let (down, _) = event(&mut events, EventKind::Error).await;
    assert!(down.contains("cannot be reached"), "{down}");
    for i in 0..200 {
        publisher.people(at(100 + i, 7, 1.0));
    }
    broker_process = start_broker(&broker, dir.path(), port).await;
    let (back, errors) = event(&mut events, EventKind::Connected).await;
    assert!(back.contains("is back"), "{back}");
    assert_eq!(errors, 0);
    drop(broker_process);
    let _ = stop_tx.send(());
    task.await.unwrap();
}

/// The real daemon starts its people outputs from the site file: `scanfuse run` with `[mqtt]`
/// and a zone connects to the broker (its log says so once the broker acknowledged it).
#[test]
fn the_daemon_starts_its_outputs_from_the_config() {
    let test = "the_daemon_starts_its_outputs_from_the_config";
    let Some((broker, _)) = mosquitto(test) else {
        return;
    };
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = runtime.block_on(start_broker(&broker, dir.path(), port));
    let hall = daemon_run_common::fixture("hall.mcap");
    let sensors = daemon_run_common::replay_sensors(&hall, &daemon_run_common::HALL[..1]);
    let config = daemon_run_common::write_config(
        dir.path(),
        "gate",
        &sensors,
        &format!(
            "\n[[zone]]\nid = \"hall\"\npolygon = [[0, 0], [4, 0], [4, 4]]\n\n[mqtt]\nurl = \"mqtt://127.0.0.1:{port}\"\n"
        ),
    );
    let _daemon = daemon_run_common::start_daemon(&config, dir.path());
    let want = format!("MQTT: publishing tracks to mqtt://127.0.0.1:{port}");
    daemon_run_common::wait_for(PATIENCE, "the daemon connected to the broker", || {
        std::fs::read_to_string(dir.path().join("daemon.log"))
            .ok()
            .filter(|log| log.contains(&want))
    });
}
