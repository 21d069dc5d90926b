//! The status socket end to end over real Unix sockets in temp dirs: banner, every request,
//! errors that keep the connection serving, the client cap, slow watchers, stale sockets,
//! shutdown.

use crate::daemon_common;

use std::os::unix::fs::PermissionsExt;
use std::time::Duration;

use daemon_common::{LineClient, error_text, start};
use scanfuse::daemon::protocol::{
    Crossing, EventKind, Frame, FrameScan, Message, SensorState, Side, Track, Tracks,
};
use scanfuse::daemon::socket::{FIRST_REQUEST_WITHIN, ServerOptions, SocketError, StatusServer};
use scanfuse::daemon::state::PosesFile;

fn options() -> ServerOptions {
    ServerOptions {
        socket_mode: 0o640,
        max_clients: 4,
        write_timeout: Duration::from_millis(300),
        first_request_within: FIRST_REQUEST_WITHIN,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn banner_then_every_request_is_answered() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("run/scanfuse.sock");
    let server = start(&sock, dir.path(), options(), 64);
    let mode = std::fs::metadata(&sock).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o640);

    let mut c = LineClient::connect_past_banner(&sock).await;
    match c.ask(r#"{"cmd":"status"}"#).await {
        Message::Status(s) => {
            assert_eq!(s.site, "test-hall");
            assert_eq!(s.sensors.len(), 2);
            assert_eq!(s.sensors[0].state, SensorState::Streaming);
            assert_eq!(s.sensors[1].reconnects, 2);
        }
        other => panic!("{other:?}"),
    }
    match c.ask(r#"{"cmd":"poses"}"#).await {
        Message::Poses(p) => {
            assert_eq!(p.anchor, "entrance");
            assert!(p.sensors[0].registered);
            assert_eq!(p.sensors[1].reason.as_deref(), Some("no static view yet"));
        }
        other => panic!("{other:?}"),
    }
    match c.ask(r#"{"cmd":"watch"}"#).await {
        Message::Watch(w) => assert!(w.status && !w.map),
        other => panic!("{other:?}"),
    }
    match c.ask(r#"{"cmd":"reregister","sensor":"dock"}"#).await {
        Message::Reregister(r) => {
            assert_eq!(r.sensor, "dock");
            assert!(r.message.contains("queued"));
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        *server.site.reregistered.lock().unwrap(),
        vec!["dock".to_string()]
    );
    let refused = c.ask(r#"{"cmd":"reregister","sensor":"roof"}"#).await;
    assert!(error_text(&refused).contains("the sensors are entrance, dock"));
    match c.ask(r#"{"cmd":"save"}"#).await {
        Message::Saved(s) => assert_eq!(s.files, vec!["poses.toml".to_string()]),
        other => panic!("{other:?}"),
    }
    let saved = PosesFile::load(dir.path())
        .unwrap()
        .expect("poses.toml written by save");
    assert_eq!(saved.anchor, "entrance");
    assert_eq!(saved.sensors.len(), 2);

    // The watch stream carries published events, in order.
    server
        .publisher
        .announce(EventKind::Moved, Some("dock"), "dock moved");
    server
        .publisher
        .announce(EventKind::ReRegistered, Some("dock"), "dock re-registered");
    for want in [EventKind::Moved, EventKind::ReRegistered] {
        match c.message().await {
            Some(Message::Event(e)) => {
                assert_eq!(e.kind, want);
                assert_eq!(e.sensor.as_deref(), Some("dock"));
                assert!(humantime::parse_rfc3339(&e.time).is_ok(), "{}", e.time);
            }
            other => panic!("{other:?}"),
        }
    }
    server.shutdown().await;
    assert!(!sock.exists(), "the socket file is removed at shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_lines_get_errors_and_the_connection_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 64);
    let mut c = LineClient::connect_past_banner(&sock).await;

    let huge = vec![b'x'; 70 * 1024];
    let cases: [(&[u8], &str); 6] = [
        (b"this is not json", "not valid JSON"),
        (&huge, "longer than 65536 bytes"),
        (br#"{"cmd":"launch"}"#, "unknown variant `launch`"),
        (br#"{"cmd":"reregister"}"#, "missing field `sensor`"),
        (br#"{"sensor":"dock"}"#, "no \"cmd\""),
        (br#"["status"]"#, "must be a JSON object"),
    ];
    for (line, want) in cases {
        let reply = c.ask(std::str::from_utf8(line).unwrap()).await;
        let text = error_text(&reply);
        assert!(text.contains(want), "{want}: {text}");
        // Each error says what would be valid.
        assert!(text.contains(r#"{"cmd":"status"}"#), "{text}");
        // …and the connection still serves.
        assert!(matches!(
            c.ask(r#"{"cmd":"status"}"#).await,
            Message::Status(_)
        ));
    }
    // An over-long line split across many writes is rejected once and the next line works.
    for _ in 0..20 {
        c.writer_send_raw(&[b'y'; 8 * 1024]).await;
    }
    // The ERROR comes as soon as the line passes the cap, before it even ends.
    let first = c.message().await.unwrap();
    assert!(error_text(&first).contains("discarded"));
    c.writer_send_raw(b"yyy\n").await;
    c.send(br#"{"cmd":"poses"}"#).await;
    assert!(matches!(c.message().await, Some(Message::Poses(_))));
    server.shutdown().await;
}

trait RawSend {
    async fn writer_send_raw(&mut self, bytes: &[u8]);
}

impl RawSend for LineClient {
    async fn writer_send_raw(&mut self, bytes: &[u8]) {
        use tokio::io::AsyncWriteExt;
        self.writer.write_all(bytes).await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_beyond_the_cap_are_told_and_closed() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let opts = ServerOptions {
        max_clients: 2,
        ..options()
    };
    let server = start(&sock, dir.path(), opts, 64);
    let a = LineClient::connect_past_banner(&sock).await;
    let mut b = LineClient::connect_past_banner(&sock).await;
    let mut c = LineClient::connect(&sock).await;
    let refusal = c.message().await.expect("an ERROR before closing");
    assert!(error_text(&refusal).contains("at most 2"), "{refusal:?}");
    assert_eq!(c.line().await, None, "the extra client is closed");
    // The admitted clients are unaffected.
    assert!(matches!(
        b.ask(r#"{"cmd":"status"}"#).await,
        Message::Status(_)
    ));
    // A slot frees when a client leaves (the server notices the EOF on its own task).
    drop(a);
    let mut admitted = false;
    for _ in 0..100 {
        let mut d = LineClient::connect(&sock).await;
        if matches!(d.message().await, Some(Message::Version(_))) {
            admitted = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(admitted, "a freed slot is reused");
    server.shutdown().await;
}

/// Connections that never ask anything cannot keep the operator out: each is told why and
/// closed once the first-request limit passes, while a watcher and a client that asked once
/// keep their connections.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_clients_are_closed_so_the_operator_gets_in() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let opts = ServerOptions {
        max_clients: 5,
        first_request_within: Duration::from_millis(300),
        ..options()
    };
    let server = start(&sock, dir.path(), opts, 64);
    let mut watcher = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        watcher.ask(r#"{"cmd":"watch"}"#).await,
        Message::Watch(_)
    ));
    let mut asker = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        asker.ask(r#"{"cmd":"status"}"#).await,
        Message::Status(_)
    ));
    let mut silent = Vec::new();
    for _ in 0..3 {
        let mut c = LineClient::connect_past_banner(&sock).await;
        // Blank lines are not requests.
        c.send(b"").await;
        silent.push(c);
    }
    // Every slot is taken now.
    let mut refused = LineClient::connect(&sock).await;
    let refusal = refused.message().await.expect("an ERROR");
    assert!(error_text(&refusal).contains("at most 5"), "{refusal:?}");
    // Each silent client is told why, then closed.
    for c in &mut silent {
        let goodbye = c.message().await.expect("an ERROR before closing");
        let text = error_text(&goodbye);
        assert!(text.contains("no request within 300 ms"), "{text}");
        assert!(text.contains(r#"{"cmd":"status"}"#), "{text}");
        assert_eq!(c.line().await, None, "then the connection is closed");
    }
    // The operator gets in (a freed slot may take the server a moment to notice).
    let mut answered = false;
    for _ in 0..100 {
        let mut operator = LineClient::connect(&sock).await;
        if matches!(operator.message().await, Some(Message::Version(_))) {
            assert!(matches!(
                operator.ask(r#"{"cmd":"status"}"#).await,
                Message::Status(_)
            ));
            answered = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(answered, "the operator's status request is answered");
    // The watcher and the client that asked once are still served.
    server
        .publisher
        .announce(EventKind::Moved, Some("dock"), "dock moved");
    match watcher.message().await {
        Some(Message::Event(e)) => assert_eq!(e.kind, EventKind::Moved),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        asker.ask(r#"{"cmd":"poses"}"#).await,
        Message::Poses(_)
    ));
    server.shutdown().await;
}

/// On a single-threaded runtime the watcher's task cannot run while the test publishes, so a
/// burst larger than the backlog makes it fall behind deterministically.
#[tokio::test(flavor = "current_thread")]
async fn a_watcher_that_falls_behind_the_backlog_gets_a_final_error() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 16);
    let mut w = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        w.ask(r#"{"cmd":"watch","status":true}"#).await,
        Message::Watch(_)
    ));
    for i in 0..100 {
        server
            .publisher
            .announce(EventKind::Connected, Some("dock"), format!("event {i}"));
    }
    let goodbye = w.message().await.expect("a final ERROR");
    let text = error_text(&goodbye);
    assert!(text.contains("fell 84 messages behind"), "{text}");
    assert_eq!(w.line().await, None, "then the watcher is closed");
    // The server goes on serving others.
    let mut c = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        c.ask(r#"{"cmd":"status"}"#).await,
        Message::Status(_)
    ));
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_watcher_that_stops_reading_is_dropped_while_a_fast_one_keeps_receiving() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    // A generous write timeout, so a busy machine never drops the fast reader by mistake.
    let opts = ServerOptions {
        write_timeout: Duration::from_secs(1),
        ..options()
    };
    let server = start(&sock, dir.path(), opts, 256);
    let mut slow = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        slow.ask(r#"{"cmd":"watch"}"#).await,
        Message::Watch(_)
    ));
    let mut fast = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        fast.ask(r#"{"cmd":"watch"}"#).await,
        Message::Watch(_)
    ));
    assert_eq!(server.publisher.event_watchers(), 2);

    // ~1 KiB events, in batches the fast reader keeps up with: far more than the slow
    // client's socket buffer holds.
    let padding = "p".repeat(1000);
    let total = 6000;
    let mut received = 0;
    for batch in 0..total / 100 {
        for i in 0..100 {
            let n = batch * 100 + i;
            server
                .publisher
                .announce(EventKind::Connected, None, format!("{n} {padding}"));
        }
        for _ in 0..100 {
            match fast.message().await {
                Some(Message::Event(e)) => {
                    let n: usize = e.message.split(' ').next().unwrap().parse().unwrap();
                    assert_eq!(n, received, "the fast watcher gets every event in order");
                    received += 1;
                }
                other => panic!("fast watcher got {other:?}"),
            }
        }
    }
    assert_eq!(received, total);
    // The slow watcher was dropped (its write timed out), the fast one is still subscribed.
    let mut dropped = false;
    for _ in 0..500 {
        if server.publisher.event_watchers() == 1 {
            dropped = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(dropped, "the slow watcher is dropped");
    let mut slow_got = 0;
    while let Some(line) = slow.line().await {
        if line.contains(r#""class":"EVENT""#) {
            slow_got += 1;
        }
    }
    assert!(
        slow_got < total,
        "the slow watcher got {slow_got} of {total} and then EOF"
    );
    assert!(matches!(
        fast.ask(r#"{"cmd":"status"}"#).await,
        Message::Status(_)
    ));
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn map_frames_go_only_to_map_watchers_and_watch_can_be_turned_off() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 64);
    let mut maps = LineClient::connect_past_banner(&sock).await;
    match maps
        .ask(r#"{"cmd":"watch","status":false,"map":true}"#)
        .await
    {
        Message::Watch(w) => assert!(!w.status && w.map),
        other => panic!("{other:?}"),
    }
    let mut events = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        events.ask(r#"{"cmd":"watch","status":true}"#).await,
        Message::Watch(_)
    ));
    assert_eq!(server.publisher.frame_watchers(), 1);
    server.publisher.frame(Frame {
        stamp_ns: 7,
        scans: vec![FrameScan {
            sensor: "entrance".into(),
            stamp_ns: 7,
            xy_m: vec![1.0, 2.0, 3.0, 4.0],
        }],
    });
    server.publisher.announce(EventKind::Saved, None, "saved");
    match maps.message().await {
        Some(Message::Frame(f)) => assert_eq!(f.scans[0].xy_m, vec![1.0, 2.0, 3.0, 4.0]),
        other => panic!("{other:?}"),
    }
    match events.message().await {
        Some(Message::Event(e)) => assert_eq!(e.kind, EventKind::Saved),
        other => panic!("{other:?} (a status watcher must not get frames)"),
    }
    // Turning both off stops the stream; the next reply is the one asked for.
    assert!(matches!(
        events
            .ask(r#"{"cmd":"watch","status":false,"map":false}"#)
            .await,
        Message::Watch(_)
    ));
    server
        .publisher
        .announce(EventKind::Saved, None, "not for you");
    assert!(matches!(
        events.ask(r#"{"cmd":"poses"}"#).await,
        Message::Poses(_)
    ));
    server.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stale_sockets_are_replaced_live_ones_and_other_files_refused() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");

    // A socket file left by a crashed daemon: nothing listens on it.
    drop(std::os::unix::net::UnixListener::bind(&sock).unwrap());
    assert!(sock.exists());
    let server = start(&sock, dir.path(), options(), 64);
    let mut c = LineClient::connect_past_banner(&sock).await;

    // A second daemon on the same path is refused, and the first keeps serving.
    let site = std::sync::Arc::new(daemon_common::MemorySite::two_sensors(dir.path()));
    let publisher = scanfuse::daemon::socket::Publisher::new(8);
    match StatusServer::bind(&sock, site.clone(), publisher.clone(), options()) {
        Err(e @ SocketError::AlreadyRunning { .. }) => {
            assert!(e.to_string().contains("already serving"), "{e}")
        }
        Err(e) => panic!("expected AlreadyRunning, got {e}"),
        Ok(_) => panic!("a second server bound a live socket"),
    }
    assert!(matches!(
        c.ask(r#"{"cmd":"status"}"#).await,
        Message::Status(_)
    ));

    // Shutdown closes connected clients and removes the socket.
    server.shutdown().await;
    assert_eq!(c.line().await, None);
    assert!(!sock.exists());

    // A regular file at the path is never removed.
    std::fs::write(&sock, b"precious").unwrap();
    match StatusServer::bind(&sock, site, publisher, options()) {
        Err(e @ SocketError::NotASocket { .. }) => {
            assert!(e.to_string().contains("not a socket"), "{e}")
        }
        Err(e) => panic!("expected NotASocket, got {e}"),
        Ok(_) => panic!("bound over a regular file"),
    }
    assert_eq!(std::fs::read(&sock).unwrap(), b"precious");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_watcher_that_closes_its_sending_side_keeps_receiving() {
    use tokio::io::AsyncWriteExt;
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 64);
    let mut w = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        w.ask(r#"{"cmd":"watch"}"#).await,
        Message::Watch(_)
    ));
    w.writer.shutdown().await.unwrap();
    // A plain client that closes its side is done and is closed in turn.
    let mut plain = LineClient::connect_past_banner(&sock).await;
    plain.writer.shutdown().await.unwrap();
    assert_eq!(plain.line().await, None);
    // The watcher's task has seen its EOF by now too (same server, earlier); events still flow.
    server
        .publisher
        .announce(EventKind::Registered, Some("dock"), "dock registered");
    match w.message().await {
        Some(Message::Event(e)) => assert_eq!(e.kind, EventKind::Registered),
        other => panic!("{other:?}"),
    }
    server.shutdown().await;
    assert_eq!(w.line().await, None);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_socket_never_appears_with_another_mode_than_configured() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    // A mode no umask gives: a socket seen at the path with any other was made there first
    // and chmod-ed after.
    let opts = ServerOptions {
        socket_mode: 0o604,
        ..options()
    };
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let looks = std::sync::Arc::new(AtomicUsize::new(0));
    let watcher = {
        let (sock, stop, looks) = (sock.clone(), stop.clone(), looks.clone());
        std::thread::spawn(move || {
            let mut seen = std::collections::BTreeSet::new();
            while !stop.load(Ordering::Relaxed) {
                if let Ok(meta) = std::fs::symlink_metadata(&sock) {
                    seen.insert(meta.permissions().mode() & 0o777);
                    looks.fetch_add(1, Ordering::Relaxed);
                }
            }
            seen
        })
    };
    let site = std::sync::Arc::new(daemon_common::MemorySite::two_sensors(dir.path()));
    let started = std::time::Instant::now();
    let mut binds = 0;
    // Bind over and over while the watcher looks, until it has looked often enough.
    while binds < 200
        || (looks.load(Ordering::Relaxed) < 1000 && started.elapsed() < Duration::from_secs(10))
    {
        binds += 1;
        let publisher = scanfuse::daemon::socket::Publisher::new(8);
        let server = StatusServer::bind(&sock, site.clone(), publisher, opts).unwrap();
        drop(server);
        // Dropped unserved, the file stays; a stale socket is replaced by the next bind.
    }
    stop.store(true, Ordering::Relaxed);
    let seen = watcher.join().unwrap();
    assert!(
        looks.load(Ordering::Relaxed) > 0,
        "the watcher saw the socket"
    );
    assert_eq!(
        seen.into_iter().collect::<Vec<_>>(),
        [0o604],
        "modes seen at the path"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("tmp"))
        .collect();
    assert!(left.is_empty(), "temporary names left behind: {left:?}");
}

fn tracks_at(t_ns: u64, ids: &[u64]) -> Message {
    Message::Tracks(Tracks {
        t_ns,
        tracks: ids
            .iter()
            .map(|&id| Track {
                id,
                x_m: id as f64,
                y_m: 2.0,
                vx_m_s: 0.5,
                vy_m_s: 0.0,
                sigma_m: 0.05,
                age_s: 1.5,
                sensors: vec!["entrance".into()],
            })
            .collect(),
    })
}

/// `"tracks":true` streams TRACKS, ZONES and CROSSING lines; a client that does not ask for
/// them (every client written before protocol 1.2) gets none, and its WATCH reply says so.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn people_go_only_to_tracks_watchers() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 64);
    let mut people = LineClient::connect_past_banner(&sock).await;
    match people
        .ask(r#"{"cmd":"watch","status":false,"tracks":true}"#)
        .await
    {
        Message::Watch(w) => assert!(!w.status && !w.map && w.tracks),
        other => panic!("{other:?}"),
    }
    let mut old = LineClient::connect_past_banner(&sock).await;
    old.send(br#"{"cmd":"watch"}"#).await;
    let reply = old.line().await.unwrap();
    assert_eq!(
        reply,
        r#"{"class":"WATCH","status":true,"map":false,"tracks":false}"#
    );
    assert_eq!(server.publisher.people_watchers(), 1);
    server.publisher.people(tracks_at(11, &[3, 5]));
    server.publisher.people(Message::Crossing(Crossing {
        t_ns: 11,
        line: "door".into(),
        track: 3,
        to: Side::Left,
        left_total: 1,
        right_total: 0,
    }));
    server.publisher.announce(EventKind::Saved, None, "saved");
    let line = people.line().await.unwrap();
    assert!(
        line.starts_with(r#"{"class":"TRACKS","t_ns":11,"tracks":[{"id":3,"x_m":3.0"#),
        "{line}"
    );
    match serde_json::from_str::<Message>(&line).unwrap() {
        Message::Tracks(t) => assert_eq!(t.tracks.len(), 2),
        other => panic!("{other:?}"),
    }
    match people.message().await {
        Some(Message::Crossing(c)) => assert_eq!((c.line.as_str(), c.to), ("door", Side::Left)),
        other => panic!("{other:?}"),
    }
    match old.message().await {
        Some(Message::Event(e)) => assert_eq!(e.kind, EventKind::Saved),
        other => panic!("{other:?} (a client that did not ask for tracks must not get them)"),
    }
    // Off again: no more people; the next line is the reply asked for.
    assert!(matches!(
        people
            .ask(r#"{"cmd":"watch","status":false,"tracks":false}"#)
            .await,
        Message::Watch(_)
    ));
    assert_eq!(server.publisher.people_watchers(), 0);
    server.publisher.people(tracks_at(12, &[3]));
    assert!(matches!(
        people.ask(r#"{"cmd":"poses"}"#).await,
        Message::Poses(_)
    ));
    server.shutdown().await;
}

/// The people stream is bounded like the others: a tracks watcher that falls behind is told
/// and dropped.
#[tokio::test(flavor = "current_thread")]
async fn a_tracks_watcher_that_falls_behind_gets_a_final_error() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("s.sock");
    let server = start(&sock, dir.path(), options(), 16);
    let mut w = LineClient::connect_past_banner(&sock).await;
    assert!(matches!(
        w.ask(r#"{"cmd":"watch","status":false,"tracks":true}"#)
            .await,
        Message::Watch(_)
    ));
    for i in 0..100 {
        server.publisher.people(tracks_at(i, &[1]));
    }
    let goodbye = w.message().await.expect("a final ERROR");
    let text = error_text(&goodbye);
    assert!(text.contains("fell 84 messages behind"), "{text}");
    assert_eq!(w.line().await, None, "then the watcher is closed");
    server.shutdown().await;
}
