//! The daemon's lifecycle: start the emulators behind `replay:` connections, the driver tasks,
//! the registration worker and the fuser; bind the status socket and tell systemd; then serve
//! until SIGTERM/SIGINT (or a time limit, or the end of a replay), re-reading the config on
//! SIGHUP and saving the map files every `save_interval_s`; on the way out, save once more.

use std::collections::BTreeMap;
use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::config::{Config, Connect, SensorConfig};
use super::notify::{Notifier, status_line};
use super::pipeline::{Pipeline, PoseEntry, Report, SensorSpec};
use super::pipeline_register::{Command, Registrar, run_worker};
use super::protocol::{EventKind, Saved};
use super::queue::drop_oldest;
use super::signals::{Request, Signals};
use super::socket::{Publisher, ServerOptions, SocketError, StatusServer, StatusSource};
use super::state::PosesFile;
use crate::emulator::{Emulator, EmulatorConfig, EmulatorError};
use crate::geometry::{Pose3, pose2};
use crate::record::{self, RecordError};
use crate::sensor::{Driver, DriverConfig, QUIT_TIMEOUT};

/// Scans a driver may hand over before its forwarding task takes them.
const DRIVER_CHANNEL: usize = 256;
/// systemd's STATUS= line is refreshed this often.
const STATUS_EVERY_S: u64 = 5;
/// The fuser must have run within this long for the watchdog to be fed.
const ALIVE_WITHIN_S: f64 = 10.0;
/// After a replay ends, registration still running may take this long to finish.
const REPLAY_SETTLE: Duration = Duration::from_secs(120);

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Stop after this long (`--for`).
    pub duration: Option<Duration>,
    /// Serve the status socket at `config.site.socket`.
    pub serve_socket: bool,
    /// Playback of `replay:` sensors.
    pub replay_speed: f64,
    pub replay_loop: bool,
    /// Stop once every `replay:` emulator has served its recording (needs `replay_loop` off).
    pub stop_when_replay_ends: bool,
    /// Events and once-a-second snapshots for a terminal.
    pub tap: Option<std::sync::mpsc::Sender<Report>>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: None,
            serve_socket: true,
            replay_speed: 1.0,
            replay_loop: true,
            stop_when_replay_ends: false,
            tap: None,
        }
    }
}

/// The daemon could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunError {
    #[error(transparent)]
    Socket(#[from] SocketError),
    #[error("{sensor}: cannot replay {}: {source}", file.display())]
    Recording {
        sensor: String,
        file: PathBuf,
        source: RecordError,
    },
    #[error("{sensor}: cannot replay {}: it has no sensor {sensor:?} (it has {known})", file.display())]
    NoSuchSensor {
        sensor: String,
        file: PathBuf,
        known: String,
    },
    #[error("{sensor}: cannot emulate it: {source}")]
    Emulator {
        sensor: String,
        source: EmulatorError,
    },
    #[error("cannot start: {0}")]
    Io(#[from] io::Error),
}

/// What a finished run leaves.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// The files of the final save, or why it failed.
    pub saved: Result<Saved, String>,
}

/// In-process emulators for `replay:` sensors, each on its own loopback port; and every
/// driver task, awaited at shutdown so each can stop its laser (QT) first.
#[derive(Default)]
struct Emulators {
    recordings: BTreeMap<PathBuf, Arc<record::Recording>>,
    running: BTreeMap<String, (Emulator, JoinHandle<()>)>,
    drivers: Vec<JoinHandle<()>>,
}

impl Emulators {
    /// Starts an emulator of `sensor` in `file`; returns the driver's `tcp://` URI.
    async fn start(
        &mut self,
        id: &str,
        file: &PathBuf,
        sensor: &str,
        config: EmulatorConfig,
    ) -> Result<String, RunError> {
        self.stop(id);
        let recording = match self.recordings.get(file) {
            Some(r) => Arc::clone(r),
            None => {
                let r = record::read(file).map_err(|source| RunError::Recording {
                    sensor: id.to_string(),
                    file: file.clone(),
                    source,
                })?;
                let r = Arc::new(r);
                self.recordings.insert(file.clone(), Arc::clone(&r));
                r
            }
        };
        let info = recording
            .sensor(sensor)
            .ok_or_else(|| RunError::NoSuchSensor {
                sensor: sensor.to_string(),
                file: file.clone(),
                known: recording
                    .sensors
                    .iter()
                    .map(|s| s.id.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        let emulator =
            Emulator::new(info, recording.scans_of(sensor), config).map_err(|source| {
                RunError::Emulator {
                    sensor: id.to_string(),
                    source,
                }
            })?;
        let listener = TcpListener::bind(("127.0.0.1", 0)).await?;
        let port = listener.local_addr()?.port();
        let serving = emulator.clone();
        let id_owned = id.to_string();
        let task = tokio::spawn(async move {
            if let Err(e) = serving.serve(listener).await {
                tracing::warn!(sensor = %id_owned, "emulator stopped: {e}");
            }
        });
        self.running.insert(id.to_string(), (emulator, task));
        Ok(format!("tcp://127.0.0.1:{port}"))
    }

    fn stop(&mut self, id: &str) {
        if let Some((_, task)) = self.running.remove(id) {
            task.abort();
        }
    }
}

/// Everything started for one sensor lives in the pipeline (its slot) and in these tasks.
async fn start_sensor(
    pipeline: &Arc<Pipeline>,
    emulators: &mut Emulators,
    sensor: &SensorConfig,
    options: &RunOptions,
) -> Result<(), RunError> {
    let spec = SensorSpec::from_config(sensor);
    let uri = match &sensor.connect {
        Connect::Replay { file, sensor: rid } => {
            let config = EmulatorConfig {
                speed: options.replay_speed,
                looping: options.replay_loop,
                ..EmulatorConfig::default()
            };
            let uri = emulators.start(&sensor.id, file, rid, config).await?;
            if let Some((emulator, _)) = emulators.running.get(&sensor.id)
                && !options.replay_loop
            {
                // The end of a recording is not a failure: stop the driver instead of retrying.
                let (emulator, p, id) = (emulator.clone(), Arc::clone(pipeline), sensor.id.clone());
                tokio::spawn(async move {
                    emulator.finished().await;
                    p.stop_sensor(&id, "the recording ended");
                });
            }
            uri
        }
        other => other.to_string(),
    };
    let mut driver_config = DriverConfig::new(&sensor.id, uri);
    driver_config.mode = spec.mode;
    let driver = Driver::new(driver_config);
    let (stop_tx, stop_rx) = watch::channel(false);
    pipeline.add_sensor(spec, driver.counters(), stop_tx);
    let (tx, mut rx) = mpsc::channel(DRIVER_CHANNEL);
    emulators.drivers.retain(|d| !d.is_finished());
    emulators
        .drivers
        .push(tokio::spawn(driver.run(tx, stop_rx)));
    let p = Arc::clone(pipeline);
    let id = sensor.id.clone();
    tokio::spawn(async move {
        while let Some(event) = rx.recv().await {
            p.on_driver_event(&id, event);
        }
    });
    Ok(())
}

/// Loads `poses.toml` when it fits the config; says why not otherwise.
fn load_saved_poses(config: &Config, pipeline: &Pipeline) {
    match PosesFile::load_matching(config) {
        Ok(Some(file)) => {
            for s in file.sensors.iter().filter(|s| s.registered) {
                let (Some(x_m), Some(y_m), Some(yaw_deg), Some(source)) =
                    (s.x_m, s.y_m, s.yaw_deg, s.source)
                else {
                    continue;
                };
                let updated = humantime::parse_rfc3339(&s.updated)
                    .unwrap_or_else(|_| std::time::SystemTime::now());
                pipeline.set_pose(
                    &s.id,
                    Ok(PoseEntry {
                        site_from_sensor: Pose3::from_planar(
                            &pose2(x_m, y_m, yaw_deg.to_radians()),
                            s.z_m.unwrap_or(0.0),
                            s.pitch_deg.unwrap_or(0.0).to_radians(),
                        ),
                        sigma_x_m: s.sigma_x_m,
                        sigma_y_m: s.sigma_y_m,
                        sigma_yaw_rad: s.sigma_yaw_deg.map(f64::to_radians),
                        source,
                        loaded: true,
                        caveat: s.reason.clone(),
                        updated,
                    }),
                );
            }
            pipeline.announce(
                EventKind::Registered,
                None,
                format!(
                    "loaded the saved poses from {}",
                    config
                        .site
                        .state_dir
                        .join(super::state::POSES_FILE)
                        .display()
                ),
            );
        }
        Ok(None) => {}
        Err(e) => pipeline.announce(EventKind::Error, None, e.to_string()),
    }
}

/// Runs the daemon on `config` until a stop (see the module doc), then saves.
pub async fn run_daemon(mut config: Config, options: RunOptions) -> Result<RunSummary, RunError> {
    let notifier = Notifier::from_env();
    let (queue_tx, queue_rx) = drop_oldest(config.registration.queue_scans);
    let (command_tx, command_rx) = crossbeam_channel::unbounded();
    let publisher = Publisher::new(config.publish.watch_backlog);
    let pipeline = Arc::new(Pipeline::new(
        &config,
        queue_tx,
        command_tx.clone(),
        publisher.clone(),
        options.tap.clone(),
    ));
    load_saved_poses(&config, &pipeline);

    let worker_pipeline = Arc::clone(&pipeline);
    let registrar = Registrar::new(config.site.anchor.clone(), &config.registration);
    std::thread::Builder::new()
        .name("registration".into())
        .spawn(move || run_worker(worker_pipeline, queue_rx, command_rx, registrar))?;

    let fuser_stop = Arc::new(AtomicBool::new(false));
    let fuser_thread = {
        let pipeline = Arc::clone(&pipeline);
        let stop = Arc::clone(&fuser_stop);
        let period = Duration::from_secs_f64(1.0 / config.publish.map_rate_hz.clamp(0.1, 100.0));
        std::thread::Builder::new()
            .name("fuser".into())
            .spawn(move || {
                // Frames go to watchers as scans arrive; this pass only feeds the map.
                while !stop.load(Ordering::Relaxed) {
                    let scans = pipeline.posed_scans();
                    pipeline
                        .fuser
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .integrate(&scans);
                    pipeline.fuser_beat();
                    std::thread::sleep(period);
                }
            })?
    };

    let mut emulators = Emulators::default();
    for sensor in &config.sensors {
        if let Err(e) = start_sensor(&pipeline, &mut emulators, sensor, &options).await {
            // A recording that cannot be replayed is the user's mistake: refuse to start.
            fuser_stop.store(true, Ordering::Relaxed);
            pipeline.stop_all();
            let _ = command_tx.send(Command::Shutdown);
            return Err(e);
        }
    }

    let (server_stop_tx, server_stop_rx) = watch::channel(false);
    let server = if options.serve_socket {
        let server = StatusServer::bind(
            &config.site.socket,
            Arc::clone(&pipeline),
            publisher.clone(),
            ServerOptions {
                socket_mode: config.site.socket_mode,
                max_clients: config.site.max_clients,
                ..ServerOptions::default()
            },
        )?;
        let mut rx = server_stop_rx.clone();
        Some(tokio::spawn(async move {
            server
                .run(async move {
                    let _ = rx.wait_for(|s| *s).await;
                })
                .await
        }))
    } else {
        None
    };
    if let Err(e) = notifier.ready(&status_line(&pipeline.status(), &pipeline.poses())) {
        tracing::warn!("{e}");
    }
    {
        let p = Arc::clone(&pipeline);
        let mut rx = server_stop_rx.clone();
        tokio::spawn(
            notifier.run_watchdog(move || p.alive(ALIVE_WITHIN_S), async move {
                let _ = rx.wait_for(|s| *s).await;
            }),
        );
    }

    let mut signals = Signals::install()?;
    let save_every = (config.publish.save_interval_s > 0.0)
        .then(|| Duration::from_secs_f64(config.publish.save_interval_s));
    let mut save_tick = tokio::time::interval(save_every.unwrap_or(Duration::from_secs(24 * 3600)));
    save_tick.tick().await;
    let mut second = tokio::time::interval(Duration::from_secs(1));
    let mut seconds: u64 = 0;
    let deadline = async {
        match options.duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(deadline);
    // Clones, so a reload may still start and stop emulators meanwhile.
    let replayed: Vec<Emulator> = emulators.running.values().map(|(e, _)| e.clone()).collect();
    let stop_at_end = options.stop_when_replay_ends && !replayed.is_empty();
    let replay_end = async move {
        if stop_at_end {
            for emulator in &replayed {
                emulator.finished().await;
            }
        } else {
            std::future::pending::<()>().await;
        }
    };
    tokio::pin!(replay_end);

    loop {
        tokio::select! {
            request = signals.next() => match request {
                Request::Terminate => {
                    pipeline.announce(EventKind::Saved, None, "stopping: saving poses and map files");
                    break;
                }
                Request::Reload => {
                    if let Err(e) = notifier.reloading() {
                        tracing::warn!("{e}");
                    }
                    config = reload(config, &pipeline, &mut emulators, &options).await;
                    if let Err(e) = notifier.ready(&status_line(&pipeline.status(), &pipeline.poses())) {
                        tracing::warn!("{e}");
                    }
                }
            },
            _ = save_tick.tick(), if save_every.is_some() => {
                let p = Arc::clone(&pipeline);
                match tokio::task::spawn_blocking(move || p.save_now()).await {
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => pipeline.announce(EventKind::Error, None, e.to_string()),
                    Err(e) => tracing::warn!("save task failed: {e}"),
                }
            }
            _ = second.tick() => {
                seconds += 1;
                pipeline.tick();
                if seconds.is_multiple_of(STATUS_EVERY_S)
                    && let Err(e) = notifier.status(&status_line(&pipeline.status(), &pipeline.poses()))
                {
                    tracing::warn!("{e}");
                }
            }
            _ = &mut deadline => break,
            _ = &mut replay_end => {
                settle_registration(&pipeline).await;
                break;
            }
        }
    }

    if let Err(e) = notifier.stopping() {
        tracing::warn!("{e}");
    }
    // The map is integrated on a timer: take the latest scans once more, so poses that arrived
    // after its last pass (a short replay) are in the saved map.
    {
        let scans = pipeline.posed_scans();
        let mut fuser = pipeline.fuser.lock().unwrap_or_else(|e| e.into_inner());
        fuser.integrate(&scans);
    }
    pipeline.stop_all();
    // Each driver sends QT and closes on its stop; its own bound keeps this short.
    let drivers_done = tokio::time::Instant::now() + QUIT_TIMEOUT + Duration::from_millis(200);
    for driver in emulators.drivers.drain(..) {
        if tokio::time::timeout_at(drivers_done, driver).await.is_err() {
            tracing::warn!("a driver did not stop its laser in time; leaving it");
            break;
        }
    }
    let p = Arc::clone(&pipeline);
    let saved = tokio::task::spawn_blocking(move || p.save_now())
        .await
        .map_err(|e| e.to_string())
        .and_then(|r| r.map_err(|e| e.to_string()));
    let _ = command_tx.send(Command::Shutdown);
    fuser_stop.store(true, Ordering::Relaxed);
    let _ = server_stop_tx.send(true);
    if let Some(server) = server {
        let _ = server.await;
    }
    let _ = tokio::task::spawn_blocking(move || fuser_thread.join()).await;
    pipeline.tick();
    Ok(RunSummary { saved })
}

/// After a replay: wait (boundedly) until every sensor that streamed has a pose.
async fn settle_registration(pipeline: &Pipeline) {
    let started = tokio::time::Instant::now();
    while started.elapsed() < REPLAY_SETTLE {
        let status = pipeline.status();
        let poses = pipeline.poses();
        let waiting = status.sensors.iter().any(|s| {
            s.scans > 0
                && poses.sensors.iter().any(|p| {
                    p.id == s.id
                        && !p.registered
                        && p.reason
                            .as_deref()
                            .is_some_and(|r| r.starts_with("waiting"))
                })
        });
        if !waiting {
            return;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// SIGHUP: re-reads the config and applies what can change live (sensors added, removed or
/// changed); a config that does not load leaves everything as it was.
async fn reload(
    config: Config,
    pipeline: &Arc<Pipeline>,
    emulators: &mut Emulators,
    options: &RunOptions,
) -> Config {
    let new = match Config::load(&config.path) {
        Ok(new) => new,
        Err(e) => {
            pipeline.announce(
                EventKind::Error,
                None,
                format!("reload refused, still running the old config: {e}"),
            );
            return config;
        }
    };
    let changes = config.changes_to(&new);
    for id in changes.removed.iter().chain(&changes.changed) {
        pipeline.remove_sensor(id);
        emulators.stop(id);
    }
    for id in changes.added.iter().chain(&changes.changed) {
        let Some(sensor) = new.sensors.iter().find(|s| &s.id == id) else {
            continue;
        };
        if let Err(e) = start_sensor(pipeline, emulators, sensor, options).await {
            pipeline.announce(EventKind::Error, Some(id), e.to_string());
        }
    }
    let mut notes = Vec::new();
    if !changes.need_restart.is_empty() {
        notes.push(format!(
            "{} take effect after a restart",
            changes.need_restart.join(", ")
        ));
    }
    if changes.anchor_changed {
        notes.push("the anchor changes after a restart".to_string());
    }
    pipeline.announce(
        EventKind::ConfigReloaded,
        None,
        format!(
            "config reloaded: {} added, {} removed, {} changed{}{}",
            changes.added.len(),
            changes.removed.len(),
            changes.changed.len(),
            if notes.is_empty() { "" } else { "; " },
            notes.join("; ")
        ),
    );
    // Keep what cannot change live; take the sensors.
    Config {
        sensors: new.sensors,
        ..config
    }
}
