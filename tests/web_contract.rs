//! The page's WebSocket, from a client of another codebase (tokio-tungstenite) against the
//! real `scanfuse run` on the replayed `hall` site, serving the page on every interface
//! (`0.0.0.0`, so with a token) and reached only through 127.0.0.1:
//!
//! - a page gets the banner, `STATUS`, `POSES`, `FRAME`s with points, `EVENT`s and `MAP`;
//! - `survey` over the WebSocket places a sensor where it was dropped (`poses` says
//!   `surveyed`, with the σ sent, kept in `state_dir`), the others are re-solved without
//!   pulling it back, its survey is named as off its scans, and `unsurvey` clears it;
//! - without the token (even from loopback) HTTP and the upgrade get 401; an upgrade from
//!   another Origin and a request for another Host get 403;
//! - a client that reads nothing is dropped while one that reads keeps getting scans.
//!
//! One daemon for the whole file, so one test.

use crate::daemon_run_common;

use std::net::SocketAddr;
use std::time::Duration;

use daemon_run_common::*;
use futures_util::{SinkExt, StreamExt};
use scanfuse::daemon::protocol::{EventKind, Message, PoseSource};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::{Error as WsError, Message as Ws};
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

const TOKEN: &str = "page-contract-0123456789abcdef0123456789";

type Socket = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// The upgrade request to 127.0.0.1:`port`, with the token and `origin` when given.
fn request(
    port: u16,
    token: Option<&str>,
    origin: Option<&str>,
) -> tokio_tungstenite::tungstenite::handshake::client::Request {
    let mut r = format!("ws://127.0.0.1:{port}/ws")
        .into_client_request()
        .unwrap();
    if let Some(t) = token {
        r.headers_mut().insert(
            "Authorization",
            HeaderValue::from_str(&format!("Bearer {t}")).unwrap(),
        );
    }
    if let Some(o) = origin {
        r.headers_mut()
            .insert("Origin", HeaderValue::from_str(o).unwrap());
    }
    r
}

async fn open(port: u16) -> Socket {
    let (socket, response) = tokio_tungstenite::connect_async(request(port, Some(TOKEN), None))
        .await
        .expect("the page's WebSocket opens with the token");
    assert_eq!(response.status(), 101);
    socket
}

/// The next protocol object, or `None` once the server has closed.
async fn next(socket: &mut Socket) -> Option<Message> {
    loop {
        match tokio::time::timeout(Duration::from_secs(30), socket.next()).await {
            Err(_) => panic!("nothing from the page's WebSocket for 30 s"),
            Ok(None | Some(Err(_))) | Ok(Some(Ok(Ws::Close(_)))) => return None,
            Ok(Some(Ok(Ws::Text(text)))) => {
                let value: serde_json::Value = serde_json::from_str(&text).unwrap();
                // MAP and SENSORS are the page's own classes; the rest is the socket's.
                match value["class"].as_str() {
                    Some("MAP") => {
                        assert!(value["width"].as_u64().unwrap() > 0, "{value}");
                        return Some(Message::error("MAP"));
                    }
                    Some("SENSORS") => continue,
                    _ => return Some(serde_json::from_value(value).unwrap()),
                }
            }
            Ok(Some(Ok(_))) => continue,
        }
    }
}

/// Reads until `pick` returns `Some` (within `limit` messages).
async fn until<T>(
    socket: &mut Socket,
    limit: usize,
    what: &str,
    mut pick: impl FnMut(&Message) -> Option<T>,
) -> T {
    for _ in 0..limit {
        let m = next(socket)
            .await
            .unwrap_or_else(|| panic!("closed waiting for {what}"));
        if let Some(t) = pick(&m) {
            return t;
        }
    }
    panic!("no {what} in {limit} messages");
}

async fn send(socket: &mut Socket, request: serde_json::Value) {
    socket
        .send(Ws::text(request.to_string()))
        .await
        .expect("send");
}

/// A plain HTTP request's status code.
async fn http_status(port: u16, head: &str) -> u16 {
    let mut s = TcpStream::connect(("127.0.0.1", port)).await.unwrap();
    s.write_all(format!("{head}Connection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut reply = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut reply)).await;
    let text = String::from_utf8_lossy(&reply);
    text.split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("no status line: {text:?}"))
}

fn upgrade_refused(result: Result<impl Sized, WsError>) -> u16 {
    match result {
        Err(WsError::Http(response)) => response.status().as_u16(),
        Err(e) => panic!("refused otherwise: {e}"),
        Ok(_) => panic!("the upgrade was accepted"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_pages_websocket_keeps_its_contract() {
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("web.token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).unwrap();
    std::fs::set_permissions(
        &token_file,
        std::os::unix::fs::PermissionsExt::from_mode(0o600),
    )
    .unwrap();
    let hall = fixture("hall.mcap");
    let sensors = replay_sensors(&hall, &HALL);
    // Port 0, read back from `status`: a port picked free here and released can be taken
    // by one of the daemon's own replay emulators before the page binds it.
    let web = format!(
        "\n[web]\nlisten = \"0.0.0.0:0\"\ntoken_file = \"{}\"\nsend_queue = 16\n",
        token_file.display()
    );
    let config = write_config(dir.path(), "gate", &sensors, &web);
    let _daemon = start_daemon(&config, dir.path());
    let sock = dir.path().join("s.sock");
    let poses = tokio::task::spawn_blocking(move || {
        let mut client = Client::connect(&sock, Duration::from_secs(30));
        // The anchor and at least one other: enough for everything here, whatever a busy
        // machine does to the others' registration.
        wait_for(Duration::from_secs(120), "two sensors registered", || {
            let poses = client.poses();
            (poses.sensors.iter().filter(|p| p.registered).count() >= 2).then_some(poses)
        })
    })
    .await
    .unwrap();
    let status = tokio::task::spawn_blocking({
        let sock = dir.path().join("s.sock");
        move || Client::connect(&sock, Duration::from_secs(5)).status()
    })
    .await
    .unwrap();
    // "page at http://127.0.0.1:PORT/" (the wildcard shown as loopback).
    let port: u16 = status
        .web
        .as_deref()
        .and_then(|w| w.strip_prefix("page at http://127.0.0.1:"))
        .and_then(|rest| rest.split('/').next()?.parse().ok())
        .unwrap_or_else(|| panic!("status names the page: {:?}", status.web));
    assert_ne!(port, 0, "the port it bound");
    eprintln!("daemon started; page on 0.0.0.0:{port}");

    // --- what a page gets ----------------------------------------------------------------
    let mut page = open(port).await;
    assert!(
        matches!(next(&mut page).await, Some(Message::Version(v)) if v.proto_minor >= 1),
        "the banner first"
    );
    let (mut status, mut poses_seen, mut points, mut events, mut map) =
        (false, false, false, false, false);
    for _ in 0..400 {
        match next(&mut page).await.expect("open") {
            Message::Status(s) => status |= s.sensors.len() == 5,
            Message::Poses(p) => {
                poses_seen |= p.sensors.iter().filter(|s| s.registered).count() >= 2
            }
            Message::Frame(f) => points |= f.scans.iter().any(|s| s.xy_m.len() > 100),
            Message::Event(_) => events = true,
            Message::Error(e) if e.message == "MAP" => map = true,
            _ => {}
        }
        if status && poses_seen && points && events && map {
            break;
        }
    }
    assert!(
        status && poses_seen && points && events && map,
        "status {status}, poses {poses_seen}, points {points}, events {events}, map {map}"
    );

    // --- placing a sensor by hand, and clearing it ----------------------------------------
    let sensor = poses
        .sensors
        .iter()
        .find(|p| p.id != "gate" && p.registered)
        .expect("a sensor besides the anchor");
    let id = sensor.id.clone();
    let (x, y) = (sensor.x_m.unwrap() + 1.25, sensor.y_m.unwrap() - 0.5);
    send(
        &mut page,
        serde_json::json!({"cmd":"survey","sensor":id,"x_m":x,"y_m":y,"yaw_deg":45.0,"sigma_xy_m":0.1,"sigma_yaw_deg":3.0}),
    )
    .await;
    let reply = until(&mut page, 2000, "the SURVEY reply", |m| match m {
        Message::Survey(s) => Some(s.clone()),
        Message::Error(e) if e.message != "MAP" => panic!("refused: {}", e.message),
        _ => None,
    })
    .await;
    assert_eq!(reply.sensor, id);
    assert!(reply.x_m.is_some_and(|v| (v - x).abs() < 1e-9), "{reply:?}");
    assert_eq!(reply.yaw_deg, Some(45.0));
    let surveyed = std::fs::read_to_string(dir.path().join("state/surveys.toml")).unwrap();
    assert!(surveyed.contains(&format!("id = \"{id}\"")), "{surveyed}");
    // The others are re-solved around it; it stays where it was put.
    eprintln!("placed {id} by hand; waiting for the others' re-solve");
    until(&mut page, 5000, "the others re-solved", |m| match m {
        Message::Event(e)
            if matches!(e.kind, EventKind::ReRegistered | EventKind::Error)
                && e.sensor.as_deref().is_some_and(|s| s != id && s != "gate") =>
        {
            Some(())
        }
        _ => None,
    })
    .await;
    // Dropped 1.35 m and 17° from where its scans put it: that is said, once the re-solve
    // has run, and the others were placed by their scans alone (not pulled towards it).
    let said = until(
        &mut page,
        5000,
        "the survey named as off its scans",
        |m| match m {
            Message::Event(e)
                if e.kind == EventKind::Error
                    && e.sensor.as_deref() == Some(id.as_str())
                    && e.message.contains("from where its scans put it") =>
            {
                Some(e.message.clone())
            }
            _ => None,
        },
    )
    .await;
    eprintln!("{said}");
    // A page always watches everything, people included (protocol 1.2).
    send(&mut page, serde_json::json!({"cmd":"watch","tracks":true})).await;
    let watch = until(&mut page, 2000, "the WATCH reply", |m| match m {
        Message::Watch(w) => Some(*w),
        _ => None,
    })
    .await;
    assert!(watch.status && watch.map && watch.tracks, "{watch:?}");
    send(&mut page, serde_json::json!({"cmd":"poses"})).await;
    let after = until(&mut page, 2000, "the POSES reply", |m| match m {
        Message::Poses(p) => p.sensors.iter().find(|s| s.id == id).cloned(),
        _ => None,
    })
    .await;
    assert_eq!(after.source, Some(PoseSource::Surveyed), "{after:?}");
    assert!(after.registered);
    assert!(
        (after.x_m.unwrap() - x).abs() < 1e-9 && (after.y_m.unwrap() - y).abs() < 1e-9,
        "{after:?}"
    );
    assert!((after.yaw_deg.unwrap() - 45.0).abs() < 1e-9, "{after:?}");
    assert_eq!(after.sigma_x_m, Some(0.1));

    send(&mut page, serde_json::json!({"cmd":"unsurvey","sensor":id})).await;
    let cleared = until(
        &mut page,
        2000,
        "the SURVEY reply to unsurvey",
        |m| match m {
            Message::Survey(s) => Some(s.clone()),
            Message::Error(e) if e.message != "MAP" => panic!("refused: {}", e.message),
            _ => None,
        },
    )
    .await;
    assert_eq!(cleared.x_m, None, "{cleared:?}");
    assert!(!dir.path().join("state/surveys.toml").exists());
    // Registered from its scans again (or, if they do not place it now, unplaced with a
    // reason): no longer where it was put by hand.
    until(
        &mut page,
        5000,
        "the sensor no longer surveyed",
        |m| match m {
            Message::Poses(p) => p
                .sensors
                .iter()
                .find(|s| s.id == id && s.source != Some(PoseSource::Surveyed))
                .map(|_| ()),
            _ => None,
        },
    )
    .await;
    // Anything else is refused with a sentence.
    send(
        &mut page,
        serde_json::json!({"cmd":"survey","sensor":"gate","x_m":1,"y_m":1,"yaw_deg":0}),
    )
    .await;
    let refused = until(&mut page, 2000, "the ERROR reply", |m| match m {
        Message::Error(e) if e.message != "MAP" => Some(e.message.clone()),
        _ => None,
    })
    .await;
    assert!(refused.contains("anchor"), "{refused}");
    drop(page);

    eprintln!("survey set and cleared");
    // --- who may connect -------------------------------------------------------------------
    let host = format!("Host: 127.0.0.1:{port}\r\n");
    assert_eq!(
        http_status(port, &format!("GET / HTTP/1.1\r\n{host}")).await,
        401,
        "no token, even from loopback"
    );
    assert_eq!(
        http_status(port, &format!("GET /?token=wrong HTTP/1.1\r\n{host}")).await,
        401
    );
    assert_eq!(
        http_status(port, &format!("GET /?token={TOKEN} HTTP/1.1\r\n{host}")).await,
        200
    );
    assert_eq!(
        upgrade_refused(tokio_tungstenite::connect_async(request(port, None, None)).await),
        401
    );
    assert_eq!(
        upgrade_refused(
            tokio_tungstenite::connect_async(request(
                port,
                Some(TOKEN),
                Some("http://evil.example")
            ))
            .await
        ),
        403,
        "an upgrade from another origin"
    );
    assert_eq!(
        http_status(
            port,
            &format!("GET /?token={TOKEN} HTTP/1.1\r\nHost: evil.example:{port}\r\n")
        )
        .await,
        403,
        "a request for another host name (DNS rebinding)"
    );
    assert_eq!(
        http_status(
            port,
            &format!(
                "POST /ws HTTP/1.1\r\n{host}Authorization: Bearer {TOKEN}\r\nContent-Length: 0\r\n"
            )
        )
        .await,
        405
    );

    eprintln!("access checked");
    // --- a slow page is dropped, a fast one keeps up -----------------------------------------
    let slow_socket = tokio::net::TcpSocket::new_v4().unwrap();
    slow_socket.set_recv_buffer_size(4096).unwrap();
    let stream = slow_socket
        .connect(SocketAddr::from(([127, 0, 0, 1], port)))
        .await
        .unwrap();
    let (mut slow, _) = tokio_tungstenite::client_async(
        request(port, Some(TOKEN), None),
        MaybeTlsStream::Plain(stream),
    )
    .await
    .expect("the slow page opens");
    let mut fast = open(port).await;
    until(&mut fast, 100_000, "the slow page dropped", |m| match m {
        Message::Event(e) if e.message.contains("page client") && e.message.contains("dropped") => {
            Some(())
        }
        _ => None,
    })
    .await;
    eprintln!("the slow page was dropped");
    let mut frames = 0;
    while frames < 20 {
        if let Some(Message::Frame(_)) = next(&mut fast).await {
            frames += 1;
        }
    }
    // The slow page, reading at last, finds its buffered messages and then the end.
    let mut read = 0usize;
    let ended = tokio::time::timeout(Duration::from_secs(60), async {
        while let Some(item) = slow.next().await {
            match item {
                Ok(Ws::Close(_)) | Err(_) => return,
                Ok(_) => read += 1,
            }
        }
    })
    .await;
    assert!(
        ended.is_ok(),
        "the slow page was not dropped (read {read} messages)"
    );
}
