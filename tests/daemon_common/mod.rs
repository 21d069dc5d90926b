//! Shared by the `daemon_*` tests: an in-memory site behind the status socket, and a small
//! line client.
//!
//! `MemorySite` is a test double for the *pipeline* (drivers, registration, fuser), which do
//! not exist yet on this branch; the socket server, protocol and state files it is used to
//! test are the real ones.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use scanfuse::daemon::protocol::{
    Message, PoseSource, Poses, Saved, SensorPose, SensorState, SensorStatus, Status,
};
use scanfuse::daemon::socket::{Publisher, Refused, ServerOptions, StatusServer, StatusSource};
use scanfuse::daemon::state::{PosesFile, SavedPose};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::UnixStream;
use tokio::net::unix::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::oneshot;

/// A site whose state is whatever the test put in it.
pub struct MemorySite {
    pub status: Mutex<Status>,
    pub poses: Mutex<Poses>,
    pub state_dir: PathBuf,
    pub reregistered: Mutex<Vec<String>>,
}

impl MemorySite {
    /// Two sensors: `entrance` (anchor, streaming, surveyed) and `dock` (disconnected,
    /// unregistered).
    pub fn two_sensors(state_dir: &Path) -> MemorySite {
        let mut entrance = SensorStatus::new("entrance", SensorState::Streaming);
        entrance.rate_hz = Some(40.0);
        entrance.scans = 1200;
        entrance.connect = Some("tcp://127.0.0.1:10940".into());
        let mut dock = SensorStatus::new("dock", SensorState::Disconnected);
        dock.reconnects = 2;
        dock.last_error = Some("connection refused by 127.0.0.1:10941".into());
        dock.last_error_age_s = Some(4.0);
        let mut anchor = SensorPose::unregistered("entrance", "");
        anchor.registered = true;
        anchor.reason = None;
        anchor.x_m = Some(0.0);
        anchor.y_m = Some(0.0);
        anchor.yaw_deg = Some(0.0);
        anchor.sigma_x_m = Some(0.0);
        anchor.sigma_y_m = Some(0.0);
        anchor.sigma_yaw_deg = Some(0.0);
        anchor.source = Some(PoseSource::Surveyed);
        anchor.age_s = Some(12.0);
        MemorySite {
            status: Mutex::new(Status {
                site: "test-hall".into(),
                uptime_s: 30.0,
                queue_drops: 0,
                sensors: vec![entrance, dock],
                web: None,
                foxglove: None,
                zenoh: None,
                zones: Vec::new(),
            }),
            poses: Mutex::new(Poses {
                anchor: "entrance".into(),
                sensors: vec![
                    anchor,
                    SensorPose::unregistered("dock", "no static view yet"),
                ],
                building_from_site: None,
                site_from_zone: None,
            }),
            state_dir: state_dir.to_path_buf(),
            reregistered: Mutex::new(Vec::new()),
        }
    }
}

impl StatusSource for MemorySite {
    fn status(&self) -> Status {
        self.status
            .lock()
            .map(|s| s.clone())
            .unwrap_or_else(|e| e.into_inner().clone())
    }

    fn poses(&self) -> Poses {
        self.poses
            .lock()
            .map(|p| p.clone())
            .unwrap_or_else(|e| e.into_inner().clone())
    }

    fn reregister(&self, sensor: &str) -> Result<String, Refused> {
        let poses = self.poses();
        if !poses.sensors.iter().any(|s| s.id == sensor) {
            let ids: Vec<String> = poses.sensors.iter().map(|s| s.id.clone()).collect();
            return Err(Refused(format!(
                "no sensor {sensor:?}; the sensors are {}",
                ids.join(", ")
            )));
        }
        if let Ok(mut list) = self.reregistered.lock() {
            list.push(sensor.to_string());
        }
        Ok(format!("re-registration of {sensor} queued"))
    }

    fn save(&self) -> Result<Saved, Refused> {
        let poses = self.poses();
        let file = PosesFile {
            anchor: poses.anchor.clone(),
            sensors: poses
                .sensors
                .iter()
                .map(|p| {
                    SavedPose::from_pose(
                        p,
                        p.source.unwrap_or(PoseSource::Registered),
                        SystemTime::now(),
                    )
                })
                .collect(),
            building_from_site: None,
        };
        file.save(&self.state_dir)
            .map_err(|e| Refused(e.to_string()))?;
        Ok(Saved {
            dir: self.state_dir.display().to_string(),
            files: vec!["poses.toml".into()],
        })
    }
}

/// A server running on its own task; dropping `stop` (or sending on it) shuts it down.
pub struct Running {
    pub path: PathBuf,
    pub site: Arc<MemorySite>,
    pub publisher: Publisher,
    pub stop: Option<oneshot::Sender<()>>,
    pub task: tokio::task::JoinHandle<()>,
}

impl Running {
    /// Shuts the server down and waits for it to finish.
    pub async fn shutdown(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        tokio::time::timeout(Duration::from_secs(10), &mut self.task)
            .await
            .expect("server did not shut down within 10 s")
            .expect("server task panicked");
    }
}

/// Binds and runs a server at `path` over a [`MemorySite`] storing into `state_dir`.
pub fn start(path: &Path, state_dir: &Path, options: ServerOptions, backlog: usize) -> Running {
    let site = Arc::new(MemorySite::two_sensors(state_dir));
    let publisher = Publisher::new(backlog);
    let server = StatusServer::bind(path, Arc::clone(&site), publisher.clone(), options)
        .expect("bind the status socket");
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(server.run(async {
        let _ = stopped.await;
    }));
    Running {
        path: path.to_path_buf(),
        site,
        publisher,
        stop: Some(stop),
        task,
    }
}

/// A raw line client.
pub struct LineClient {
    pub reader: BufReader<OwnedReadHalf>,
    pub writer: OwnedWriteHalf,
}

impl LineClient {
    pub async fn connect(path: &Path) -> LineClient {
        let stream = UnixStream::connect(path)
            .await
            .expect("connect to the status socket");
        let (r, w) = stream.into_split();
        LineClient {
            reader: BufReader::new(r),
            writer: w,
        }
    }

    /// Connects and checks the banner.
    pub async fn connect_past_banner(path: &Path) -> LineClient {
        let mut client = LineClient::connect(path).await;
        match client.message().await {
            Some(Message::Version(v)) => assert_eq!((v.proto_major, v.proto_minor), (1, 8)),
            other => panic!("expected a VERSION banner, got {other:?}"),
        }
        client
    }

    pub async fn send(&mut self, line: &[u8]) {
        self.writer.write_all(line).await.expect("send");
        self.writer.write_all(b"\n").await.expect("send");
    }

    /// The next line, or `None` at EOF. Panics after 10 s of silence.
    pub async fn line(&mut self) -> Option<String> {
        let mut line = String::new();
        let n = tokio::time::timeout(Duration::from_secs(10), self.reader.read_line(&mut line))
            .await
            .expect("no line within 10 s")
            .ok()?;
        (n > 0).then(|| line.trim_end().to_string())
    }

    /// The next line parsed, or `None` at EOF.
    pub async fn message(&mut self) -> Option<Message> {
        let line = self.line().await?;
        assert!(!line.contains("null"), "nulls are not allowed: {line}");
        Some(serde_json::from_str(&line).unwrap_or_else(|e| panic!("bad line {line:?}: {e}")))
    }

    /// Sends `request` and returns the reply.
    pub async fn ask(&mut self, request: &str) -> Message {
        self.send(request.as_bytes()).await;
        self.message().await.expect("a reply, not EOF")
    }
}

/// The ERROR message, or a panic.
pub fn error_text(message: &Message) -> &str {
    match message {
        Message::Error(e) => &e.message,
        other => panic!("expected an ERROR, got {other:?}"),
    }
}
