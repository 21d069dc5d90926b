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
use super::pipeline_register::{Command, Consumed, Registrar, run_worker};
use super::pipeline_track::{TrackerTask, track_queue_len};
use super::protocol::{EventKind, Saved};
use super::queue::drop_oldest;
use super::signals::{Request, Signals};
use super::socket::{Publisher, ServerOptions, SocketError, StatusServer, StatusSource};
use super::state::PosesFile;
use crate::emulator::playback::{DEFAULT_PERIOD_S, replay_span};
use crate::emulator::{Emulator, EmulatorConfig, EmulatorError, Gated, ReplayGate};
use crate::geometry::{Pose3, pose2};
use crate::record::{self, RecordError};
use crate::sensor::{Driver, DriverConfig, QUIT_TIMEOUT};

/// Scans a driver may hand over before its forwarding task takes them.
const DRIVER_CHANNEL: usize = 256;
/// A replayed unit's watchdog, in scan periods (its clock waits for the pipeline).
const REPLAY_WATCHDOG_PERIODS: f64 = 2400.0;
/// systemd's STATUS= line is refreshed this often.
const STATUS_EVERY_S: u64 = 5;
/// The fuser must have run within this long for the watchdog to be fed.
const ALIVE_WITHIN_S: f64 = 10.0;
/// After a replay's last scan, each driver has this long to hand over what it still holds.
const REPLAY_DRAIN: Duration = Duration::from_secs(2);
/// A replay may run ahead of the registration worker by at most this share of its queue.
const REPLAY_LEAD_OF_QUEUE: f64 = 0.5;

/// How to run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Stop after this long (`--for`).
    pub duration: Option<Duration>,
    /// Serve the status socket at `config.site.socket`.
    pub serve_socket: bool,
    /// Serve the page at `config.web.listen` and Foxglove at `config.foxglove.listen` (when
    /// they name one).
    pub serve_web: bool,
    /// Playback of `replay:` sensors: times the recorded rate; `f64::INFINITY` as fast as the
    /// pipeline takes the scans. Either way nothing is dropped on the way to registration.
    pub replay_speed: f64,
    pub replay_loop: bool,
    /// `scanfuse run --replay-since`: the wall-clock time `replay:` sensors' stream started
    /// (looping): a daemon started or restarted later joins it where it stands, so that
    /// several daemons replaying one site stay in step. `None`: it starts with the daemon.
    /// Only with `replay_loop` and without `replay_recorded_time`.
    pub replay_since: Option<std::time::SystemTime>,
    /// `scanfuse replay`: stamp replayed scans with their recorded time, and hold the replay
    /// back while the pipeline catches up, so that no scan is dropped. Otherwise (`scanfuse
    /// run` on `replay:` sensors) they stand in for live units: stamped as if now, and never
    /// waiting for the pipeline.
    pub replay_recorded_time: bool,
    /// Stop once every `replay:` emulator has served its recording (needs `replay_loop` off).
    pub stop_when_replay_ends: bool,
    /// Events and once-a-second snapshots for a terminal.
    pub tap: Option<std::sync::mpsc::Sender<Report>>,
    /// Run the people tracker (`TRACKS` on the people stream); on by default.
    pub track: bool,
    /// `scanfuse replay --drawing`: align the final poses to a building drawing before the
    /// final save, so that `poses.toml` carries `building_from_site` and the map files are in
    /// building coordinates.
    pub align_at_end: Option<AlignAtEnd>,
    /// `[site] drawing`, already read by the caller (`scanfuse replay --drawing` reads it to
    /// refuse a bad one before replaying): drawn on the page instead of reading it again.
    pub drawing: Option<Arc<crate::drawing::Drawing>>,
}

/// Finds `building_from_site` for the final poses (in the site frame); `None` keeps what
/// the state directory already holds.
#[derive(Clone)]
pub struct AlignAtEnd(pub Arc<AlignFn>);

/// What [`AlignAtEnd`] calls.
pub type AlignFn =
    dyn Fn(&super::protocol::Poses) -> Option<crate::drawing::BuildingFromSite> + Send + Sync;

impl std::fmt::Debug for AlignAtEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("AlignAtEnd(..)")
    }
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            duration: None,
            serve_socket: true,
            serve_web: true,
            replay_speed: 1.0,
            replay_loop: true,
            replay_since: None,
            replay_recorded_time: false,
            stop_when_replay_ends: false,
            tap: None,
            track: true,
            align_at_end: None,
            drawing: None,
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
    /// Tasks handing each driver's events to the pipeline; done once a stopped driver's last
    /// scan is in.
    forwarders: Vec<JoinHandle<()>>,
    clock: Option<ReplayClock>,
}

/// The clock every `replay:` sensor of one run plays on.
#[derive(Debug, Clone)]
struct ReplayClock {
    gate: ReplayGate,
    /// The recorded stamp at stream offset 0: the earliest first scan of the recordings.
    origin_ns: u64,
    /// One loop of all the recordings: the latest last scan, plus a scan period.
    pass_ns: u64,
    /// The stamp replayed scans get at stream offset 0.
    base_ns: u64,
}

impl Emulators {
    /// Reads the recordings of `replay:` sensors and sets up their shared clock; `None`
    /// without any. A recording that cannot be read is left for [`start_sensor`] to report.
    fn replay_clock(&mut self, config: &Config, options: &RunOptions) -> Option<ReplayClock> {
        let mut units = Vec::new();
        let mut scans_per_s = 0.0;
        let mut longest_period_s = DEFAULT_PERIOD_S;
        let mut count = 0;
        for sensor in &config.sensors {
            let Connect::Replay { file, sensor: rid } = &sensor.connect else {
                continue;
            };
            count += 1;
            let Some(recording) = self.recording(file).ok() else {
                continue;
            };
            let period_s = recording
                .sensor(rid)
                .and_then(|i| i.geometry)
                .map(|g| g.period_s());
            if let Some(p) = period_s {
                scans_per_s += 1.0 / p.max(1e-3);
                longest_period_s = longest_period_s.max(p);
            }
            let scans = recording.scans_of(rid);
            if let (Some(first), Some(last)) = (scans.first(), scans.last()) {
                units.push((
                    first.stamp_ns,
                    last.stamp_ns,
                    period_s.unwrap_or(DEFAULT_PERIOD_S),
                ));
            }
        }
        if count == 0 {
            return None;
        }
        let (origin_ns, pass_ns) =
            replay_span(units).unwrap_or((0, (longest_period_s * 1e9) as u64));
        let speed = options.replay_speed;
        // Two scans of the slowest unit ahead, less if the queue could not hold that much.
        let lead_s = (2.0 * longest_period_s)
            .min(
                REPLAY_LEAD_OF_QUEUE * config.registration.queue_len(config.sensors.len()) as f64
                    / scans_per_s.max(1.0),
            )
            .max(1.2 * longest_period_s);
        let lead = options
            .replay_recorded_time
            .then(|| Duration::from_secs_f64(lead_s));
        let since = options
            .replay_since
            .filter(|_| options.replay_loop && !options.replay_recorded_time);
        if let Some(since) = since {
            // Seconds since the anchor, negative before it.
            let since_s = match std::time::SystemTime::now().duration_since(since) {
                Ok(d) => d.as_secs_f64(),
                Err(e) => -e.duration().as_secs_f64(),
            };
            let since_ns = since
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            return Some(ReplayClock {
                gate: ReplayGate::anchored(count, speed, since_s),
                origin_ns,
                pass_ns,
                base_ns: since_ns,
            });
        }
        Some(ReplayClock {
            gate: ReplayGate::new(count, speed.is_finite().then_some(speed), lead),
            origin_ns,
            pass_ns,
            base_ns: if options.replay_recorded_time {
                origin_ns
            } else {
                super::pipeline::now_ns()
            },
        })
    }

    fn recording(&mut self, file: &PathBuf) -> Result<Arc<record::Recording>, RecordError> {
        if let Some(r) = self.recordings.get(file) {
            return Ok(Arc::clone(r));
        }
        let r = Arc::new(record::read(file)?);
        self.recordings.insert(file.clone(), Arc::clone(&r));
        Ok(r)
    }
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
        let recording = self.recording(file).map_err(|source| RunError::Recording {
            sensor: id.to_string(),
            file: file.clone(),
            source,
        })?;
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
    let mut spec = SensorSpec::from_config(sensor);
    let mut replayed = false;
    let uri = match &sensor.connect {
        Connect::Replay { file, sensor: rid } => {
            let config = EmulatorConfig {
                speed: options.replay_speed,
                looping: options.replay_loop,
                gate: emulators.clock.as_ref().map(|c| Gated {
                    gate: c.gate.clone(),
                    id: sensor.id.clone(),
                    origin_ns: c.origin_ns,
                    pass_ns: c.pass_ns,
                }),
                ..EmulatorConfig::default()
            };
            spec.stamp_base_ns = emulators.clock.as_ref().map(|c| c.base_ns);
            spec.stamp_as_live = !options.replay_recorded_time;
            replayed = true;
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
    if replayed {
        // The replay's clock pauses while the pipeline catches up: that is no dead link.
        driver_config.watchdog_periods = REPLAY_WATCHDOG_PERIODS;
    }
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
    emulators.forwarders.retain(|f| !f.is_finished());
    emulators.forwarders.push(tokio::spawn(async move {
        while let Some(event) = rx.recv().await {
            p.on_driver_event(&id, event);
        }
    }));
    Ok(())
}

/// Reads `[site] drawing` for the page's underlay and the live alignment. A drawing that
/// cannot be read is an error on the log, the socket and the terminal, and the daemon goes on
/// without it.
async fn load_drawing(d: super::config::DrawingConfig, pipeline: &Pipeline) {
    let opts = crate::drawing::ReadOptions {
        layers: d.layers.clone(),
        scale_m_per_unit: d.scale_m_per_unit,
        ..crate::drawing::ReadOptions::default()
    };
    let path = d.path.clone();
    match tokio::task::spawn_blocking(move || crate::drawing::read(&path, &opts)).await {
        Ok(Ok(drawing)) => pipeline.set_drawing(Some(Arc::new(drawing)), d.pairs),
        Ok(Err(e)) => pipeline.announce(
            EventKind::Error,
            None,
            format!("the drawing is not drawn on the page: {e}"),
        ),
        Err(e) => tracing::warn!("reading the drawing {} failed: {e}", d.path.display()),
    }
}

/// Loads `poses.toml` when it fits the config; says why not otherwise.
fn load_saved_poses(config: &Config, pipeline: &Pipeline) {
    match PosesFile::load_matching(config) {
        Ok(Some(file)) => {
            pipeline.set_building_from_site(file.building_from_site.clone());
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
                        evidence: None,
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

/// Serves the page when `[web] listen` asks for it. A page that cannot be served (the port
/// taken) is an error on the log, the socket (`status`' `web`, an event) and the terminal,
/// and the daemon goes on serving its sensors without it.
async fn start_page(
    config: &Config,
    pipeline: &Arc<Pipeline>,
    publisher: &Publisher,
    stop: &watch::Receiver<bool>,
) -> Option<JoinHandle<()>> {
    let source: Arc<dyn crate::web::PageSource> = Arc::clone(pipeline) as _;
    serve_page(&config.web, source, publisher, stop, |kind, line| {
        pipeline.set_web(line.clone());
        pipeline.announce(kind, None, line);
    })
    .await
}

/// Serves `source`'s page as `web` asks (the zone daemon's and the site daemon's): `say`
/// takes the `status.web` line, and the kind of event it is (the page's address, or why
/// there is no page and the daemon goes on without one).
pub(super) async fn serve_page(
    web: &super::config::WebConfig,
    source: Arc<dyn crate::web::PageSource>,
    publisher: &Publisher,
    stop: &watch::Receiver<bool>,
    say: impl Fn(EventKind, String),
) -> Option<JoinHandle<()>> {
    match crate::web::WebServer::bind(web).await {
        Ok(None) => None,
        Ok(Some(server)) => {
            say(EventKind::Connected, format!("page at {}", server.url()));
            Some(tokio::spawn(server.run(
                source,
                publisher.clone(),
                stop.clone(),
            )))
        }
        Err(e) => {
            say(
                EventKind::Error,
                format!("no page: {e}; the daemon goes on without it"),
            );
            None
        }
    }
}

/// Serves the site to Foxglove when `[foxglove] listen` asks for it. A server that cannot
/// start (the port taken) is an error on the log, the socket (`status`' `foxglove`, an event)
/// and the terminal, and the daemon goes on without it, as for the page.
async fn start_foxglove(
    config: &Config,
    pipeline: &Arc<Pipeline>,
    stop: &watch::Receiver<bool>,
) -> Option<JoinHandle<()>> {
    #[cfg(feature = "foxglove")]
    match crate::web::foxglove::FoxgloveServer::bind(&config.foxglove).await {
        Ok(None) => None,
        Ok(Some(server)) => {
            let line = format!("Foxglove at {}", server.url());
            pipeline.set_foxglove(line.clone());
            pipeline.announce(EventKind::Connected, None, line);
            let source: Arc<dyn crate::web::foxglove::FoxgloveSource> = Arc::clone(pipeline) as _;
            Some(tokio::spawn(server.run(source, stop.clone())))
        }
        Err(e) => {
            let why = format!("no Foxglove server: {e}; the sensors are served as before");
            pipeline.set_foxglove(why.clone());
            pipeline.announce(EventKind::Error, None, why);
            None
        }
    }
    #[cfg(not(feature = "foxglove"))]
    {
        let _ = stop;
        if let Some(a) = config.foxglove.listen {
            let why = format!(
                "no Foxglove server at {a}: this scanfuse was built without the foxglove feature"
            );
            pipeline.set_foxglove(why.clone());
            pipeline.announce(EventKind::Error, None, why);
        }
        None
    }
}

/// Runs the daemon on `config` until a stop (see the module doc), then saves.
pub async fn run_daemon(mut config: Config, options: RunOptions) -> Result<RunSummary, RunError> {
    let notifier = Notifier::from_env();
    let (queue_tx, queue_rx) = drop_oldest(config.registration.queue_len(config.sensors.len()));
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
    if let Some(d) = options.drawing.clone() {
        let pairs = config.site.drawing.as_ref().map(|d| d.pairs.clone());
        pipeline.set_drawing(Some(d), pairs.unwrap_or_default());
    } else if let Some(d) = config.site.drawing.clone() {
        load_drawing(d, &pipeline).await;
    }
    // A zone that sends its detections (`[zenoh] detections`) hands them from the tracker
    // to its Zenoh side, a second of them queued at most.
    let tracking = options.track && config.track.enabled;
    let sends_sightings = config.zenoh.as_ref().is_some_and(|z| z.detections);
    let (sightings_tx, sightings_rx) = if sends_sightings && tracking {
        let (tx, rx) = drop_oldest(track_queue_len(config.sensors.len()) * 4);
        (Some(tx), Some(rx))
    } else {
        (None, None)
    };
    if sends_sightings && !tracking {
        pipeline.announce(
            EventKind::Error,
            None,
            "[zenoh] detections = true, but this run tracks no one: the site daemon gets no detections from this zone",
        );
    }
    #[cfg(not(feature = "zenoh"))]
    let _ = sightings_rx;
    let tracker = if tracking {
        let (queue, task) = TrackerTask::start(
            publisher.clone(),
            config.track.params(),
            sightings_tx,
            track_queue_len(config.sensors.len()),
        )?;
        pipeline.feed_tracker(queue);
        Some(task)
    } else {
        None
    };
    match super::surveys::load(&config.site.state_dir) {
        Ok(surveys) => pipeline.restore_surveys(surveys),
        Err(e) => pipeline.announce(
            EventKind::Error,
            None,
            format!("{e}; the surveys set by hand are ignored"),
        ),
    }

    let mut emulators = Emulators::default();
    emulators.clock = emulators.replay_clock(&config, &options);
    let worker_pipeline = Arc::clone(&pipeline);
    let registrar = Registrar::new(config.site.anchor.clone(), &config.registration);
    let consumed = emulators.clock.as_ref().map(|c| Consumed {
        gate: c.gate.clone(),
        base_ns: c.base_ns,
    });
    std::thread::Builder::new()
        .name("registration".into())
        .spawn(move || {
            super::priority::lower_this_thread();
            run_worker(worker_pipeline, queue_rx, command_rx, registrar, consumed)
        })?;

    let fuser_stop = Arc::new(AtomicBool::new(false));
    let fuser_thread = {
        let pipeline = Arc::clone(&pipeline);
        let stop = Arc::clone(&fuser_stop);
        let period = Duration::from_secs_f64(1.0 / config.publish.map_rate_hz.clamp(0.1, 100.0));
        std::thread::Builder::new()
            .name("fuser".into())
            .spawn(move || {
                // Frames go to watchers as scans arrive; this pass only feeds the map.
                super::priority::lower_this_thread();
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
            ServerOptions::of(&config.site),
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
    let web = if options.serve_web {
        start_page(&config, &pipeline, &publisher, &server_stop_rx).await
    } else {
        None
    };
    #[cfg(feature = "zenoh")]
    if let Some(z) = config.zenoh.clone() {
        let mut rx = server_stop_rx.clone();
        tokio::spawn(super::zone_net::run(
            Arc::clone(&pipeline),
            z,
            config.site.name.clone(),
            sightings_rx,
            async move {
                let _ = rx.wait_for(|s| *s).await;
            },
        ));
    }
    // Always: a drawing set at a reload is aligned to as one read at start.
    {
        let mut rx = server_stop_rx.clone();
        tokio::spawn(super::align_live::run(Arc::clone(&pipeline), async move {
            let _ = rx.wait_for(|s| *s).await;
        }));
    }
    // Zones, lines, OSC and MQTT: fed by the people stream (the tracker publishes TRACKS).
    if super::people_out::wanted(&config.people) {
        let mut rx = server_stop_rx.clone();
        tokio::spawn(super::people_out::run(
            config.people.clone(),
            config.site.name.clone(),
            publisher.clone(),
            pipeline.watch_building_from_site(),
            async move {
                let _ = rx.wait_for(|s| *s).await;
            },
        ));
    }
    let foxglove = if options.serve_web {
        start_foxglove(&config, &pipeline, &server_stop_rx).await
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
                tokio::select! {
                    _ = finish_replay(&pipeline, &mut emulators, &command_tx) => {}
                    _ = signals.next() => {
                        pipeline.announce(EventKind::Saved, None, "stopping: saving poses and map files");
                    }
                }
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
    if let Some(AlignAtEnd(align)) = options.align_at_end.clone() {
        let p = Arc::clone(&pipeline);
        match tokio::task::spawn_blocking(move || {
            let found = align(&p.poses())?;
            p.set_building_from_site(Some(found.clone()));
            Some(super::state::keep_building_from_site(
                p.state_dir(),
                p.anchor(),
                Some(found),
            ))
        })
        .await
        {
            Ok(Some(Err(e))) => pipeline.announce(EventKind::Error, None, e.to_string()),
            Ok(_) => {}
            Err(e) => tracing::warn!("alignment to the drawing failed: {e}"),
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
    if let Some(foxglove) = foxglove {
        let _ = foxglove.await;
    }
    if let Some(web) = web {
        let _ = web.await;
    }
    let _ = tokio::task::spawn_blocking(move || fuser_thread.join()).await;
    if let Some(tracker) = tracker {
        let _ = tokio::task::spawn_blocking(move || tracker.stop()).await;
    }
    pipeline.tick();
    Ok(RunSummary { saved })
}

/// After a replay's last scan: once every driver has handed over what it holds, the worker
/// takes the rest of its queue and registers what it can (on the scans' clock, so no waiting
/// in wall time); returns when it has answered.
async fn finish_replay(
    pipeline: &Pipeline,
    emulators: &mut Emulators,
    commands: &crossbeam_channel::Sender<Command>,
) {
    // Each driver was stopped when its recording ended; its forwarder ends after its last scan.
    let drained = tokio::time::Instant::now() + REPLAY_DRAIN;
    for forwarder in emulators.forwarders.drain(..) {
        if tokio::time::timeout_at(drained, forwarder).await.is_err() {
            tracing::warn!("a replayed sensor's last scans were not handed over in time");
            break;
        }
    }
    let (done, answered) = crossbeam_channel::bounded(1);
    if commands.send(Command::Finish { done }).is_err() {
        return;
    }
    if let Err(e) = tokio::task::spawn_blocking(move || answered.recv()).await {
        pipeline.announce(
            EventKind::Error,
            None,
            format!("the registration worker did not finish: {e}"),
        );
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
    if changes.drawing_changed {
        notes.push(redraw(pipeline, new.site.drawing.clone()).await);
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
    // Keep what cannot change live; take the sensors and the drawing.
    Config {
        sensors: new.sensors,
        site: super::config::SiteConfig {
            drawing: new.site.drawing,
            ..config.site
        },
        ..config
    }
}

/// A changed `[site] drawing` at a reload: the alignment to the old drawing no longer holds,
/// so it is forgotten (on the socket, the page and in `poses.toml`), the new drawing is read,
/// and the live alignment aligns the site to it. Returns what the reload event says of it.
async fn redraw(pipeline: &Pipeline, d: Option<super::config::DrawingConfig>) -> String {
    pipeline.set_drawing(None, Vec::new());
    pipeline.set_building_from_site(None);
    if let Err(e) =
        super::state::keep_building_from_site(pipeline.state_dir(), pipeline.anchor(), None)
    {
        pipeline.announce(
            EventKind::Error,
            None,
            format!("the alignment to the old drawing is still in poses.toml: {e}"),
        );
    }
    let Some(d) = d else {
        return "the drawing was removed: poses and maps are in the anchor's frame".to_string();
    };
    let path = d.path.display().to_string();
    load_drawing(d, pipeline).await;
    if pipeline.drawing().is_some() {
        format!("the drawing is now {path}: the site is aligned to it again")
    } else {
        format!("the drawing {path} could not be read: the site has no drawing")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::{Message, PoseSource, SensorPose};
    use crate::daemon::state::SavedPose;
    use crate::drawing::BuildingFromSite;

    /// A site aligned to its drawing (`scanfuse align --save`, `replay --drawing`) says so in
    /// every `poses` reply after a restart; one that is not leaves the field out.
    #[test]
    fn saved_building_from_site_is_in_the_poses_reply() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!(
            "[site]\nname = \"s\"\nanchor = \"a\"\nstate_dir = \"{}\"\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://127.0.0.1:1\"\n",
            dir.path().display()
        );
        let config = Config::parse(&text, std::path::Path::new("/c/site.toml")).unwrap();
        let pipeline = || {
            let (queue, _worker) = drop_oldest(16);
            let (commands, _rx) = crossbeam_channel::unbounded();
            let p = Pipeline::new(&config, queue, commands, Publisher::new(4), None);
            for s in &config.sensors {
                p.add_sensor(
                    SensorSpec::from_config(s),
                    Arc::default(),
                    watch::channel(false).0,
                );
            }
            load_saved_poses(&config, &p);
            p
        };
        let mut anchor = SensorPose::unregistered("a", "");
        anchor.registered = true;
        anchor.reason = None;
        (anchor.x_m, anchor.y_m, anchor.yaw_deg) = (Some(0.0), Some(0.0), Some(0.0));
        let mut file = PosesFile {
            anchor: "a".into(),
            sensors: vec![SavedPose::from_pose(
                &anchor,
                PoseSource::Registered,
                std::time::SystemTime::now(),
            )],
            building_from_site: None,
        };
        file.save(dir.path()).unwrap();
        let line = Message::Poses(pipeline().poses()).to_line();
        assert!(!line.contains("building_from_site"), "{line}");

        let b = BuildingFromSite {
            x_m: 31.5,
            y_m: 7.25,
            yaw_deg: -23.0,
            scale: 1.0,
            aligned: true,
            method: "automatic+lines".into(),
            reason: None,
            ..Default::default()
        };
        file.building_from_site = Some(b.clone());
        file.save(dir.path()).unwrap();
        let poses = pipeline().poses();
        assert_eq!(poses.building_from_site, Some(b));
        let line = Message::Poses(poses).to_line();
        assert!(
            line.contains(r#""building_from_site":{"x_m":31.5,"y_m":7.25,"yaw_deg":-23.0,"scale":1.0,"aligned":true,"method":"automatic+lines"}"#),
            "{line}"
        );
    }

    /// `[site] drawing` is read at start and reaches the page (its `DRAWING` line) once the
    /// site is aligned to it; a drawing that cannot be read leaves the daemon running without.
    #[tokio::test]
    async fn a_configured_drawing_is_on_the_page_once_the_site_is_aligned() {
        let dir = tempfile::tempdir().unwrap();
        // A 40 × 40 px raster with a dark bar 20 px long: its faces are wall segments.
        let (w, h) = (40usize, 40usize);
        let mut px = vec![255u8; w * h];
        for r in 18..22 {
            for c in 10..30 {
                px[r * w + c] = 0;
            }
        }
        let mut pgm = format!("P5\n{w} {h}\n255\n").into_bytes();
        pgm.extend(px);
        std::fs::write(dir.path().join("plan.pgm"), pgm).unwrap();
        let config_for = |drawing: &str| {
            let text = format!(
                "[site]\nname = \"s\"\nanchor = \"a\"\nstate_dir = \"{}\"\ndrawing = \"{drawing}\"\ndrawing_scale = 0.1\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://127.0.0.1:1\"\n",
                dir.path().display()
            );
            Config::parse(&text, &dir.path().join("site.toml")).unwrap()
        };
        let start = |config: &Config| {
            let (queue, _worker) = drop_oldest(16);
            let (commands, _rx) = crossbeam_channel::unbounded();
            let p = Pipeline::new(config, queue, commands, Publisher::new(4), None);
            for s in &config.sensors {
                p.add_sensor(
                    SensorSpec::from_config(s),
                    Arc::default(),
                    watch::channel(false).0,
                );
            }
            load_saved_poses(config, &p);
            p
        };
        let mut anchor = SensorPose::unregistered("a", "");
        anchor.registered = true;
        anchor.reason = None;
        (anchor.x_m, anchor.y_m, anchor.yaw_deg) = (Some(0.0), Some(0.0), Some(0.0));
        let mut file = PosesFile {
            anchor: "a".into(),
            sensors: vec![SavedPose::from_pose(
                &anchor,
                PoseSource::Registered,
                std::time::SystemTime::now(),
            )],
            building_from_site: Some(BuildingFromSite {
                x_m: 0.0,
                y_m: 0.0,
                yaw_deg: 0.0,
                scale: 1.0,
                aligned: false,
                method: "automatic".into(),
                reason: Some("symmetric".into()),
                ..Default::default()
            }),
        };
        file.save(dir.path()).unwrap();
        let config = config_for("plan.pgm");
        let p = start(&config);
        load_drawing(config.site.drawing.clone().unwrap(), &p).await;
        assert_eq!(p.drawing_line(), None, "not aligned: nothing to draw");

        file.building_from_site = Some(BuildingFromSite {
            aligned: true,
            method: "pairs".into(),
            reason: None,
            ..file.building_from_site.clone().unwrap()
        });
        file.save(dir.path()).unwrap();
        let p = start(&config);
        load_drawing(config.site.drawing.clone().unwrap(), &p).await;
        let line = p.drawing_line().expect("a DRAWING line");
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["class"], "DRAWING");
        let n = v["segments_m"].as_array().unwrap().len();
        assert!(n >= 8 && n.is_multiple_of(4), "{line}");

        let config = config_for("missing.pgm");
        let p = start(&config);
        load_drawing(config.site.drawing.clone().unwrap(), &p).await;
        assert_eq!(p.drawing_line(), None);

        // A reload with another drawing: the alignment to the old one is forgotten on the
        // socket, the page and in poses.toml (the poses stay), and the new one is read.
        std::fs::copy(dir.path().join("plan.pgm"), dir.path().join("plan2.pgm")).unwrap();
        let config = config_for("plan.pgm");
        let p = start(&config);
        load_drawing(config.site.drawing.clone().unwrap(), &p).await;
        assert!(p.building_from_site().is_some_and(|b| b.aligned));
        let said = redraw(&p, config_for("plan2.pgm").site.drawing).await;
        assert!(
            said.contains("plan2.pgm") && said.contains("aligned to it again"),
            "{said}"
        );
        assert!(p.drawing().is_some_and(|d| d.source.contains("plan2.pgm")));
        assert_eq!((p.building_from_site(), p.drawing_line()), (None, None));
        let saved = PosesFile::load(dir.path()).unwrap().unwrap();
        assert_eq!(saved.building_from_site, None);
        assert_eq!(saved.sensors.len(), 1);
        let said = redraw(&p, config_for("gone.pgm").site.drawing).await;
        assert!(said.contains("could not be read"), "{said}");
        assert!(p.drawing().is_none());
        let said = redraw(&p, None).await;
        assert!(said.contains("removed"), "{said}");
    }
}
