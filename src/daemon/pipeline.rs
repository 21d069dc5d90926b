//! The running pipeline's shared state: every sensor's driver status, the latest scan of each,
//! the current poses and the occupancy grid; and the [`StatusSource`] the socket asks.
//!
//! Driver tasks write scans in ([`Pipeline::on_driver_event`], which also sends each posed
//! scan to `watch` clients as a frame at once), the registration worker (`pipeline_register`)
//! writes poses, the fuser (`pipeline_fuse`) integrates both into the map in batches. Each lock is held
//! only for a copy or a small update, so no stage waits on another's work.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use crossbeam_channel::Sender;
use tokio::sync::watch;

use super::config::{Config, Connect, ScanMode as ConfigMode, SensorConfig, Survey};
use super::pipeline_fuse::{Fuser, save_files, scan_frame};
use super::pipeline_register::{Command, WorkItem, surveyed};
use super::pipeline_track::TrackIn;
use super::protocol::{
    Event, EventKind, Frame, PoseSource, Poses, Saved, SensorPose, SensorState, SensorStatus,
    Status, Survey as SurveyReply,
};
use super::queue::DropOldestSender;
use super::rate::RateMeter;
use super::returns::{Returns, Verdict};
use super::socket::{Publisher, Refused, StatusSource, SurveyRequest};
use super::surveys;
use crate::geometry::{Mount, Pose3, ProjectParams};
use crate::scan::{Scan, ScanGeometry};
use crate::sensor::{Counters, DriverEvent, ScanMode};

/// Window of the scan-rate meter shown by `status`.
const RATE_WINDOW_S: f64 = 2.0;
/// A sensor's pose replaced by one this far off (m, °) is a sensor moved: the tracker
/// forgets what it learnt of its view. A refinement (walkers, a refining join) is nearer.
const FORGET_M: f64 = 0.1;
const FORGET_DEG: f64 = 1.0;

/// The rate `status` shows for a sensor in `state` whose meter reads `measured_hz`: only
/// while it streams (a disconnected, failed or stopped sensor has no rate, whatever came just
/// before), and only while scans arrive (the meter reads `None` after a window of silence).
fn shown_rate(state: SensorState, measured_hz: Option<f64>) -> Option<f64> {
    measured_hz.filter(|_| state == SensorState::Streaming)
}

/// What the pipeline needs to know about one configured sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSpec {
    pub id: String,
    /// The connection as configured (shown by `status`).
    pub connect: String,
    pub mode: ScanMode,
    pub mount: Mount,
    pub survey: Option<Survey>,
    /// A replayed sensor's scans carry their recorded time on the unit's clock: stamp =
    /// this + sensor ms (see [`restamp`]). `None`: the host's receive time, as live.
    pub stamp_base_ns: Option<u64>,
    /// With `stamp_base_ns`: the replay stands in for a live unit (`scanfuse run`), so a
    /// first scan takes the 24-bit wrap that puts it nearest the host's clock (a replay
    /// anchored to the wall clock may be hours into its loop).
    pub stamp_as_live: bool,
}

impl SensorSpec {
    /// From the config; `connect` is the configured URI, whatever the driver is later given.
    pub fn from_config(s: &SensorConfig) -> SensorSpec {
        SensorSpec {
            id: s.id.clone(),
            connect: s.connect.to_string(),
            mode: match s.mode {
                ConfigMode::MD => ScanMode::Md,
                ConfigMode::ME => ScanMode::Me,
                ConfigMode::ND => ScanMode::Nd,
            },
            mount: Mount {
                height_m: s.height_m,
                pitch_rad: s.pitch_rad,
            },
            survey: s.survey,
            stamp_base_ns: None,
            stamp_as_live: false,
        }
    }

    /// True when the sensor is served by an in-process emulator.
    pub fn is_replay(config: &SensorConfig) -> bool {
        matches!(config.connect, Connect::Replay { .. })
    }
}

/// A pose the pipeline holds, with how and when it was obtained.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEntry {
    /// x, y, yaw in the site (anchor) frame; z and pitch from the mount.
    pub site_from_sensor: Pose3,
    pub sigma_x_m: Option<f64>,
    pub sigma_y_m: Option<f64>,
    pub sigma_yaw_rad: Option<f64>,
    /// How the pose was obtained: what `poses.toml` records.
    pub source: PoseSource,
    /// Loaded from `poses.toml` at start (the socket then says `saved`).
    pub loaded: bool,
    /// What to check about the pose (`Placement::caveat`); the socket's `reason`.
    pub caveat: Option<String>,
    /// What placed it (`SiteResult::evidence`); the socket's `evidence`.
    pub evidence: Option<&'static str>,
    pub updated: SystemTime,
}

impl PoseEntry {
    /// σ of x, y and yaw, when it has all three.
    pub fn sigma(&self) -> Option<[f64; 3]> {
        Some([self.sigma_x_m?, self.sigma_y_m?, self.sigma_yaw_rad?])
    }

    /// The socket/file form.
    pub fn to_sensor_pose(&self, id: &str, now: SystemTime) -> SensorPose {
        let p = &self.site_from_sensor;
        SensorPose {
            id: id.to_string(),
            registered: true,
            x_m: Some(p.x_m),
            y_m: Some(p.y_m),
            yaw_deg: Some(p.yaw_rad.to_degrees()),
            z_m: Some(p.z_m),
            pitch_deg: Some(p.pitch_rad.to_degrees()),
            sigma_x_m: self.sigma_x_m,
            sigma_y_m: self.sigma_y_m,
            sigma_yaw_deg: self.sigma_yaw_rad.map(f64::to_degrees),
            reason: self.caveat.clone(),
            age_s: now
                .duration_since(self.updated)
                .ok()
                .map(|d| d.as_secs_f64()),
            source: Some(if self.loaded {
                PoseSource::Saved
            } else {
                self.source
            }),
            evidence: self.evidence.map(str::to_string),
            zone: None,
            stale: false,
        }
    }
}

/// One sensor's live state.
struct Slot {
    spec: SensorSpec,
    state: SensorState,
    counters: Arc<Counters>,
    rate: RateMeter,
    model: Option<String>,
    geometry: Option<ScanGeometry>,
    last_scan: Option<Scan>,
    last_scan_at: Option<Instant>,
    last_error_at: Option<Instant>,
    /// Why the sensor has no pose, when it has none.
    unposed_reason: String,
    /// The share of its beams that return.
    returns: Returns,
    /// Turns true to stop the sensor's driver.
    stop: watch::Sender<bool>,
}

/// The latest scan of a posed sensor, as the fuser takes it.
#[derive(Debug, Clone)]
pub struct PosedScan {
    pub index: u16,
    pub id: String,
    pub scan: Scan,
    pub geometry: Option<ScanGeometry>,
    pub mount: Mount,
    pub site_from_sensor: Pose3,
}

/// Reports for a terminal front end (`scanfuse run`, `scanfuse replay`).
#[derive(Debug, Clone)]
#[allow(
    clippy::large_enum_variant,
    reason = "one Tick a second to a terminal: boxing it would buy nothing"
)]
pub enum Report {
    Event(Event),
    /// Once a second: how things are.
    Tick {
        status: Status,
        poses: Poses,
    },
}

#[derive(Default)]
struct Inner {
    sensors: BTreeMap<String, Slot>,
    poses: BTreeMap<String, PoseEntry>,
    /// Surveys set by hand (`survey` requests), kept in `state_dir`; they stand before the
    /// config's.
    surveys: BTreeMap<String, Survey>,
    /// Sensors re-solved around one placed by hand: until the solve places them again they
    /// keep the pose they had (a person's drop must not unplace the others).
    resolving: std::collections::BTreeSet<String>,
}

/// The shared state of a running daemon.
pub struct Pipeline {
    site: String,
    anchor: String,
    state_dir: PathBuf,
    started: Instant,
    inner: Mutex<Inner>,
    queue: DropOldestSender<WorkItem>,
    commands: Sender<Command>,
    publisher: Publisher,
    tap: Option<std::sync::mpsc::Sender<Report>>,
    pub(super) fuser: Mutex<Fuser>,
    /// Projection of scans into `watch` frames (the fuser's own, copied).
    project: ProjectParams,
    /// Serializes file writes (`save` requests, the periodic save, shutdown).
    save_lock: Mutex<()>,
    /// Host time of the fuser's last pass, ns since the epoch (watchdog liveness).
    fuser_beat_ns: AtomicU64,
    /// Stream time: the newest scan stamp seen (the recordings' clock in a replay).
    stream_ns: AtomicU64,
    /// Where the page is served, or why it is not (`status`' `web`).
    web: Mutex<Option<String>>,
    /// The tracker's queue, once its task runs: every posed scan goes there too.
    tracker: std::sync::OnceLock<DropOldestSender<TrackIn>>,
    /// Where the Foxglove server listens, or why it does not (`status`' `foxglove`).
    foxglove: Mutex<Option<String>>,
    /// The zone on Zenoh, or why it is not on the network (`status`' `zenoh`).
    zenoh: Mutex<Option<String>>,
    /// The static views the registration worker last kept, for a site daemon's question;
    /// `None` until someone wants them (`want_views`).
    views: Mutex<Option<Vec<super::pipeline_register::StaticView>>>,
    /// Where the site frame lies in the building drawing's (from `poses.toml`), for `poses`,
    /// the page and the zones drawn in building coordinates (which watch it).
    building_from_site: tokio::sync::watch::Sender<Option<crate::drawing::BuildingFromSite>>,
    /// A zone daemon's: where the site daemon last placed its frame, for `poses`.
    site_from_zone: Mutex<Option<super::protocol::ZoneFrame>>,
    /// The building drawing (`[site] drawing`), and its `DRAWING` line for the page once the
    /// site is aligned to it.
    drawing: Mutex<PageDrawing>,
}

/// The drawing, its page line once the site is aligned to it, and the point pairs that align
/// it (`[site] drawing_pairs`; empty: automatically).
type PageDrawing = (
    Option<Arc<crate::drawing::Drawing>>,
    Option<Arc<str>>,
    Vec<crate::drawing::align::PointPair>,
);

/// A sensor's latest scan, placed or not, for outputs that draw scans in the sensor's own
/// frame (the Foxglove bridge).
#[derive(Debug, Clone)]
pub struct LatestScan {
    pub id: String,
    pub scan: Scan,
    pub geometry: Option<ScanGeometry>,
    pub mount: Mount,
    /// Its pose in the site frame, when it has one.
    pub site_from_sensor: Option<Pose3>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A poisoned lock means a panic elsewhere; the state is still the best we have.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The stamp of a replayed scan whose unit clock read `sensor_ms`: `base_ns` plus that
/// reading, taking the 24-bit wrap that puts it nearest `near_ns` (the sensor's previous
/// stamp: a reconnect restarts the driver's unwrapping, not the recording's clock; or, for a
/// first scan standing in for a live unit, the host's clock); none without it.
pub fn restamp(base_ns: u64, near_ns: Option<u64>, sensor_ms: u64) -> u64 {
    const WRAP_NS: i128 = crate::sensor::clock::WRAP_MS as i128 * 1_000_000;
    let raw_ns = (sensor_ms % crate::sensor::clock::WRAP_MS) as i128 * 1_000_000;
    let base = base_ns as i128;
    let wraps = match near_ns {
        Some(p) => ((p as i128 - base - raw_ns) as f64 / WRAP_NS as f64).round() as i128,
        None => 0,
    };
    (base + raw_ns + wraps.max(0) * WRAP_NS).clamp(0, u64::MAX as i128) as u64
}

pub(super) fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

impl Pipeline {
    pub(super) fn new(
        config: &Config,
        queue: DropOldestSender<WorkItem>,
        commands: Sender<Command>,
        publisher: Publisher,
        tap: Option<std::sync::mpsc::Sender<Report>>,
    ) -> Pipeline {
        Pipeline {
            site: config.site.name.clone(),
            anchor: config.site.anchor.clone(),
            state_dir: config.site.state_dir.clone(),
            started: Instant::now(),
            inner: Mutex::new(Inner::default()),
            queue,
            commands,
            publisher,
            tap,
            fuser: Mutex::new(Fuser::new(&config.publish)),
            project: *Fuser::new(&config.publish).project_params(),
            save_lock: Mutex::new(()),
            fuser_beat_ns: AtomicU64::new(now_ns()),
            stream_ns: AtomicU64::new(0),
            web: Mutex::new(None),
            tracker: std::sync::OnceLock::new(),
            foxglove: Mutex::new(None),
            zenoh: Mutex::new(None),
            views: Mutex::new(None),
            building_from_site: tokio::sync::watch::Sender::new(None),
            site_from_zone: Mutex::new(None),
            drawing: Mutex::new((None, None, Vec::new())),
        }
    }

    /// The site's alignment to the building drawing, shown in `poses` replies (and placing
    /// the drawing on the page).
    pub(super) fn set_building_from_site(&self, b: Option<crate::drawing::BuildingFromSite>) {
        self.building_from_site.send_replace(b);
        self.update_drawing_line();
    }

    /// Where the site daemon placed this zone's frame (None: not placed), for `poses`.
    pub(super) fn set_site_from_zone(&self, frame: Option<super::protocol::ZoneFrame>) {
        *lock(&self.site_from_zone) = frame;
    }

    /// The site's alignment to the building drawing as it stands.
    pub(super) fn building_from_site(&self) -> Option<crate::drawing::BuildingFromSite> {
        self.building_from_site.borrow().clone()
    }

    /// The building drawing (`[site] drawing`), once read.
    pub(super) fn drawing(&self) -> Option<Arc<crate::drawing::Drawing>> {
        lock(&self.drawing).0.clone()
    }

    /// `building_from_site` as it changes (the people outputs place building-frame zones
    /// through it).
    pub(super) fn watch_building_from_site(
        &self,
    ) -> tokio::sync::watch::Receiver<Option<crate::drawing::BuildingFromSite>> {
        self.building_from_site.subscribe()
    }

    /// The building drawing the page draws under the map once the site is aligned to it, and
    /// the point pairs that align it (none: automatically).
    pub(super) fn set_drawing(
        &self,
        d: Option<Arc<crate::drawing::Drawing>>,
        pairs: Vec<crate::drawing::align::PointPair>,
    ) {
        {
            let mut held = lock(&self.drawing);
            held.0 = d;
            held.2 = pairs;
        }
        self.update_drawing_line();
    }

    /// The point pairs that align the site to its drawing (empty: automatically).
    pub(super) fn drawing_pairs(&self) -> Vec<crate::drawing::align::PointPair> {
        lock(&self.drawing).2.clone()
    }

    /// The page's `DRAWING` line, when there is a drawing and an alignment to it.
    pub fn drawing_line(&self) -> Option<Arc<str>> {
        lock(&self.drawing).1.clone()
    }

    fn update_drawing_line(&self) {
        let building = self.building_from_site.borrow().clone();
        let mut d = lock(&self.drawing);
        let line = match (&d.0, &building) {
            (Some(drawing), Some(b)) => crate::web::bridge::drawing_line(drawing, b),
            _ => None,
        };
        d.1 = line.map(Arc::from);
    }

    /// What `status` says of the Foxglove server.
    pub(super) fn set_foxglove(&self, line: String) {
        *lock(&self.foxglove) = Some(line);
    }

    /// Each sensor's static view as the registration worker holds it: the ones it keeps
    /// (refreshed every 2 s once wanted), or asked of it, waiting at most `patience` (it
    /// answers between two scans, and not during a registration); empty if it has stopped.
    /// Blocking: call it off the async threads.
    #[cfg_attr(not(feature = "zenoh"), allow(dead_code))]
    pub(super) fn static_views(
        &self,
        patience: std::time::Duration,
    ) -> Vec<super::pipeline_register::StaticView> {
        if let Some(kept) = lock(&self.views).clone().filter(|v| !v.is_empty()) {
            return kept;
        }
        let (reply, answer) = crossbeam_channel::bounded(1);
        if self.commands.send(Command::Views { reply }).is_err() {
            return Vec::new();
        }
        answer.recv_timeout(patience).unwrap_or_default()
    }

    /// From now on the registration worker keeps the static views at hand (a zone on Zenoh
    /// serves them on request).
    #[cfg_attr(not(feature = "zenoh"), allow(dead_code))]
    pub(super) fn want_views(&self) {
        let mut views = lock(&self.views);
        if views.is_none() {
            *views = Some(Vec::new());
        }
    }

    pub(super) fn wants_views(&self) -> bool {
        lock(&self.views).is_some()
    }

    pub(super) fn keep_views(&self, views: Vec<super::pipeline_register::StaticView>) {
        *lock(&self.views) = Some(views);
    }

    /// What `status` says of the zone on Zenoh.
    #[cfg_attr(not(feature = "zenoh"), allow(dead_code))]
    pub(super) fn set_zenoh(&self, line: String) {
        *lock(&self.zenoh) = Some(line);
    }

    /// Every sensor's latest scan (a copy), with its pose when it has one.
    pub fn latest_scans(&self) -> Vec<LatestScan> {
        let inner = lock(&self.inner);
        inner
            .sensors
            .iter()
            .filter_map(|(id, slot)| {
                Some(LatestScan {
                    id: id.clone(),
                    scan: slot.last_scan.clone()?,
                    geometry: slot.geometry,
                    mount: slot.spec.mount,
                    site_from_sensor: inner.poses.get(id).map(|p| p.site_from_sensor),
                })
            })
            .collect()
    }

    /// How scans become points (what `watch` frames and the fused cloud use).
    pub fn project_params(&self) -> ProjectParams {
        self.project
    }

    /// Sends every posed scan to the tracker's queue from now on.
    pub(super) fn feed_tracker(&self, queue: DropOldestSender<TrackIn>) {
        let _ = self.tracker.set(queue);
    }

    /// What `status` says of the page.
    pub(super) fn set_web(&self, line: String) {
        *lock(&self.web) = Some(line);
    }

    pub fn anchor(&self) -> &str {
        &self.anchor
    }

    pub fn state_dir(&self) -> &std::path::Path {
        &self.state_dir
    }

    /// Publishes an event to watchers, the log and the terminal. The log line has the target
    /// `scanfuse::event`, which a terminal that prints the event itself leaves out.
    pub fn announce(&self, kind: EventKind, sensor: Option<&str>, message: impl Into<String>) {
        let message = message.into();
        let sensor_id = sensor.unwrap_or("");
        if kind == EventKind::Error {
            tracing::warn!(target: "scanfuse::event", sensor = %sensor_id, kind = ?kind, "{message}");
        } else {
            tracing::info!(target: "scanfuse::event", sensor = %sensor_id, kind = ?kind, "{message}");
        }
        self.publish_event(kind, sensor, message);
    }

    /// Publishes an event to watchers and the terminal, not the log: for what the driver has
    /// logged itself ("sensor connected", "sensor link lost"), so the journal has it once.
    fn publish_event(&self, kind: EventKind, sensor: Option<&str>, message: String) {
        let event = Event::now(kind, sensor, message);
        if let Some(tap) = &self.tap {
            let _ = tap.send(Report::Event(event.clone()));
        }
        self.publisher.event(event);
    }

    /// Sends the terminal a snapshot (no-op without a terminal).
    pub(super) fn tick(&self) {
        if let Some(tap) = &self.tap {
            let _ = tap.send(Report::Tick {
                status: self.status(),
                poses: self.poses(),
            });
        }
    }

    /// Adds a sensor whose driver is about to start; `stop` stops it.
    pub(super) fn add_sensor(
        &self,
        spec: SensorSpec,
        counters: Arc<Counters>,
        stop: watch::Sender<bool>,
    ) {
        let id = spec.id.clone();
        let mut inner = lock(&self.inner);
        if let Some(old) = inner.sensors.remove(&id) {
            let _ = old.stop.send(true);
        }
        let by_hand = inner.surveys.get(&id).copied();
        if let Some(survey) = &by_hand {
            // Placed by hand: it stands there, whatever was saved.
            let entry = surveyed(survey, &spec.mount, SystemTime::now());
            inner.poses.insert(id.clone(), entry);
        }
        let pose = inner.poses.get(&id).map(|p| p.site_from_sensor);
        let sigma = inner.poses.get(&id).and_then(PoseEntry::sigma);
        if pose.is_none()
            && let Some(survey) = &spec.survey
        {
            // Shown until registration confirms or replaces it.
            let entry = surveyed(survey, &spec.mount, SystemTime::now());
            inner.poses.insert(id.clone(), entry);
        }
        let _ = self.commands.send(Command::Add {
            id: id.clone(),
            mount: spec.mount,
            survey: by_hand.or(spec.survey),
            pose,
            sigma,
        });
        if by_hand.is_some() {
            let _ = self.commands.send(Command::Survey {
                id: id.clone(),
                survey: by_hand,
                pinned: pose,
            });
        }
        inner.sensors.insert(
            id,
            Slot {
                spec,
                state: SensorState::Connecting,
                counters,
                rate: RateMeter::new(RATE_WINDOW_S),
                model: None,
                geometry: None,
                last_scan: None,
                last_scan_at: None,
                last_error_at: None,
                unposed_reason: "waiting for a static view".into(),
                returns: Returns::default(),
                stop,
            },
        );
    }

    /// Takes the surveys set by hand in an earlier run (before the sensors are added).
    pub(super) fn restore_surveys(&self, surveys: BTreeMap<String, Survey>) {
        lock(&self.inner).surveys = surveys;
    }

    /// Stops a sensor's driver and forgets it (and its pose).
    pub(super) fn remove_sensor(&self, id: &str) {
        let _ = self.commands.send(Command::Remove(id.to_string()));
        let mut inner = lock(&self.inner);
        if let Some(slot) = inner.sensors.remove(id) {
            let _ = slot.stop.send(true);
        }
        inner.poses.remove(id);
        // Its tracks go on with the others; what the tracker learnt of its view goes.
        if let Some(queue) = self.tracker.get() {
            let _ = queue.push(TrackIn::Forget(id.to_string()));
        }
    }

    /// Stops a sensor's driver but keeps its state (a replay that reached its end).
    pub(super) fn stop_sensor(&self, id: &str, why: &str) {
        {
            let mut inner = lock(&self.inner);
            let Some(slot) = inner.sensors.get_mut(id) else {
                return;
            };
            let _ = slot.stop.send(true);
            slot.state = SensorState::Stopped;
        }
        self.announce(EventKind::Disconnected, Some(id), why);
    }

    /// Stops every driver (shutdown).
    pub(super) fn stop_all(&self) {
        let inner = lock(&self.inner);
        for slot in inner.sensors.values() {
            let _ = slot.stop.send(true);
        }
    }

    pub(super) fn sensor_ids(&self) -> Vec<String> {
        lock(&self.inner).sensors.keys().cloned().collect()
    }

    /// Takes one driver event of sensor `id`.
    pub fn on_driver_event(&self, id: &str, event: DriverEvent) {
        match event {
            DriverEvent::Connected(info) => {
                let message = format!(
                    "connected: {} {}",
                    info.model,
                    info.fields.get("SERI").map(String::as_str).unwrap_or("")
                );
                {
                    let mut inner = lock(&self.inner);
                    let Some(slot) = inner.sensors.get_mut(id) else {
                        return;
                    };
                    slot.state = SensorState::Connecting;
                    slot.returns.reset();
                    slot.model = Some(info.model.clone());
                    slot.geometry = info.geometry;
                }
                self.publish_event(EventKind::Connected, Some(id), message.trim_end().into());
            }
            DriverEvent::Scan(mut scan) => {
                let watched = self.publisher.frame_watchers() > 0;
                let tracked = self.tracker.get().is_some();
                let (geometry, posed, verdict) = {
                    let mut guard = lock(&self.inner);
                    let inner = &mut *guard;
                    let pose = inner.poses.get(id).map(|p| p.site_from_sensor);
                    let index = inner.sensors.keys().position(|k| k == id);
                    let Some(slot) = inner.sensors.get_mut(id) else {
                        return;
                    };
                    slot.state = SensorState::Streaming;
                    if let (Some(base_ns), Some(sensor_ms)) =
                        (slot.spec.stamp_base_ns, scan.scan.sensor_stamp_ms)
                    {
                        let near = slot.last_scan.as_ref().map(|s| s.stamp_ns);
                        let near = near.or(slot.spec.stamp_as_live.then(now_ns));
                        scan.scan.stamp_ns = restamp(base_ns, near, sensor_ms);
                    }
                    self.stream_ns
                        .fetch_max(scan.scan.stamp_ns, Ordering::Relaxed);
                    // Rates are of the wall clock (what `status` shows), whatever the stamps.
                    slot.rate.record(now_ns());
                    let verdict = slot.returns.observe(&scan.scan.ranges_m);
                    slot.last_scan = Some(scan.scan.clone());
                    slot.last_scan_at = Some(Instant::now());
                    let posed = match (watched || tracked, pose, index) {
                        (true, Some(site_from_sensor), Some(index)) => Some(PosedScan {
                            index: index as u16,
                            id: id.to_string(),
                            scan: scan.scan.clone(),
                            geometry: slot.geometry,
                            mount: slot.spec.mount,
                            site_from_sensor,
                        }),
                        _ => None,
                    };
                    (slot.geometry, posed, verdict)
                };
                match verdict {
                    Some(Verdict::Blind { .. }) => {
                        let why = self.blind_reason(id).unwrap_or_default();
                        self.announce(EventKind::Error, Some(id), format!("{id}: {why}"));
                    }
                    Some(Verdict::Seeing { share }) => self.announce(
                        EventKind::Connected,
                        Some(id),
                        format!(
                            "{id} sees again: {:.0} % of its beams return",
                            share * 100.0
                        ),
                    ),
                    None => {}
                }
                // The fused stream is event-driven: the scan goes to watchers now, outside
                // the lock; the grid takes it on the fuser's next pass.
                if let Some(posed) = posed {
                    if watched {
                        self.publisher.frame(Frame {
                            stamp_ns: posed.scan.stamp_ns,
                            scans: vec![scan_frame(&posed, &self.project)],
                        });
                    }
                    // The tracker's queue drops its oldest scan when full: never a wait here.
                    if let Some(queue) = self.tracker.get() {
                        let _ = queue.push(TrackIn::Scan(posed));
                    }
                }
                // A full queue drops the oldest scan; a stopped worker only ends registration.
                let _ = self.queue.push(WorkItem {
                    sensor: id.to_string(),
                    scan: scan.scan,
                    geometry,
                });
            }
            DriverEvent::Disconnected { reason } => {
                {
                    let mut inner = lock(&self.inner);
                    let Some(slot) = inner.sensors.get_mut(id) else {
                        return;
                    };
                    if slot.state == SensorState::Stopped {
                        return;
                    }
                    slot.state = SensorState::Disconnected;
                    slot.last_error_at = Some(Instant::now());
                }
                self.publish_event(EventKind::Disconnected, Some(id), reason);
            }
            DriverEvent::Failed { reason } => {
                {
                    let mut inner = lock(&self.inner);
                    let Some(slot) = inner.sensors.get_mut(id) else {
                        return;
                    };
                    if slot.state == SensorState::Stopped {
                        return;
                    }
                    slot.state = SensorState::Failed;
                    slot.last_error_at = Some(Instant::now());
                }
                self.announce(EventKind::Error, Some(id), format!("failed: {reason}"));
            }
            DriverEvent::Raw { .. } => {}
        }
    }

    /// Sets poses (from the worker or `poses.toml`); `None` with a reason unsets one.
    pub(super) fn set_pose(&self, id: &str, pose: Result<PoseEntry, String>) {
        let mut inner = lock(&self.inner);
        let before = inner.poses.get(id).map(|e| e.site_from_sensor.planar());
        match pose {
            Ok(entry) => {
                inner.resolving.remove(id);
                inner.poses.insert(id.to_string(), entry);
            }
            Err(reason) if inner.resolving.contains(id) && inner.poses.contains_key(id) => {
                if let Some(entry) = inner.poses.get_mut(id) {
                    entry.caveat = Some(format!(
                        "keeps its pose: the re-solve around the sensor placed by hand did not place it ({reason})"
                    ));
                }
            }
            Err(reason) => {
                inner.poses.remove(id);
                if let Some(slot) = inner.sensors.get_mut(id) {
                    slot.unposed_reason = reason;
                }
            }
        }
        // The tracker's background of a sensor is in the sensor's own frame: a pose that
        // went, or came back elsewhere (found moved), leaves it wrong, and a knocked unit's
        // new view would read as people for a minute and a half (`absorb_s`).
        let after = inner.poses.get(id).map(|e| e.site_from_sensor.planar());
        let elsewhere = match (before, after) {
            (Some(old), Some(new)) => {
                let (dt, dyaw) = crate::geometry::pose_error(&new, &old);
                dt > FORGET_M || dyaw > FORGET_DEG.to_radians()
            }
            (Some(_), None) => true,
            _ => false,
        };
        if elsewhere && let Some(queue) = self.tracker.get() {
            let _ = queue.push(TrackIn::Forget(id.to_string()));
        }
    }

    /// People walking confirmed the pose of sensor `id` that walls alone gave: its caveat goes.
    pub(super) fn confirm(&self, id: &str) {
        let mut inner = lock(&self.inner);
        if let Some(entry) = inner.poses.get_mut(id) {
            entry.caveat = entry
                .caveat
                .as_deref()
                .and_then(crate::register::site::confirmed_caveat);
        }
    }

    /// Why sensor `id` cannot be placed whatever registration says, while it sees almost
    /// nothing.
    pub fn blind_reason(&self, id: &str) -> Option<String> {
        lock(&self.inner)
            .sensors
            .get(id)
            .and_then(|s| s.returns.blind_reason())
    }

    /// The occupancy grid as the fuser holds it now (the page draws it).
    pub fn occupancy(&self) -> crate::fuse::OccupancyGrid {
        lock(&self.fuser).grid()
    }

    /// Each sensor's field of view from its latest scan: id, first and last beam angle (rad,
    /// in the sensor's frame). Sensors without a scan yet are left out.
    pub fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
        lock(&self.inner)
            .sensors
            .iter()
            .filter_map(|(id, slot)| {
                let scan = slot.last_scan.as_ref()?;
                Some((id.clone(), scan.start_angle_rad, scan.end_angle_rad))
            })
            .collect()
    }

    pub fn pose_of(&self, id: &str) -> Option<PoseEntry> {
        lock(&self.inner).poses.get(id).cloned()
    }

    /// The latest scan of every posed sensor, for the fuser.
    pub(super) fn posed_scans(&self) -> Vec<PosedScan> {
        let inner = lock(&self.inner);
        inner
            .sensors
            .iter()
            .enumerate()
            .filter_map(|(index, (id, slot))| {
                let pose = inner.poses.get(id)?;
                Some(PosedScan {
                    index: index as u16,
                    id: id.clone(),
                    scan: slot.last_scan.clone()?,
                    geometry: slot.geometry,
                    mount: slot.spec.mount,
                    site_from_sensor: pose.site_from_sensor,
                })
            })
            .collect()
    }

    pub(super) fn fuser_beat(&self) {
        self.fuser_beat_ns.store(now_ns(), Ordering::Relaxed);
    }

    /// The pipeline is alive when the fuser ran within `max_s` (the watchdog's test).
    pub fn alive(&self, max_s: f64) -> bool {
        let beat = self.fuser_beat_ns.load(Ordering::Relaxed);
        (now_ns().saturating_sub(beat) as f64) < max_s * 1e9
    }

    /// Writes poses and map files to the state directory now.
    pub fn save_now(&self) -> Result<Saved, Refused> {
        let _guard = lock(&self.save_lock);
        let anchor = self.anchor.clone();
        let (poses, grid, points) = {
            let now = SystemTime::now();
            let inner = lock(&self.inner);
            let poses: Vec<(SensorPose, PoseSource, SystemTime)> = inner
                .sensors
                .keys()
                .map(|id| match inner.poses.get(id) {
                    Some(p) => {
                        let mut pose = p.to_sensor_pose(id, now);
                        pose.age_s = None;
                        (pose, p.source, p.updated)
                    }
                    // No pose, so no source: `from_pose` leaves it out of the file.
                    None => (
                        SensorPose::unregistered(
                            id.clone(),
                            inner
                                .sensors
                                .get(id)
                                .map_or(String::new(), |s| s.unposed_reason.clone()),
                        ),
                        PoseSource::Registered,
                        now,
                    ),
                })
                .collect();
            drop(inner);
            let fuser = lock(&self.fuser);
            (poses, fuser.grid(), fuser.points())
        };
        let held = self.building_from_site().filter(|b| b.aligned);
        let files = save_files(
            &self.state_dir,
            &anchor,
            &poses,
            held.as_ref(),
            &grid,
            &points,
        )
        .map_err(|e| Refused(format!("{e}; check that the state directory is writable")))?;
        Ok(Saved {
            dir: self.state_dir.display().to_string(),
            files,
        })
    }
}

impl StatusSource for Pipeline {
    fn status(&self) -> Status {
        let now = now_ns();
        let mut inner = lock(&self.inner);
        let sensors = inner
            .sensors
            .iter_mut()
            .map(|(id, slot)| {
                let counters = slot.counters.snapshot();
                let mut s = SensorStatus::new(id.clone(), slot.state);
                s.connect = Some(slot.spec.connect.clone());
                s.model = slot.model.clone();
                s.rate_hz = shown_rate(slot.state, slot.rate.rate_hz(now));
                s.scans = counters.scans;
                s.checksum_errors = counters.checksum_errors;
                s.reconnects = counters.reconnects;
                s.last_scan_age_s = slot.last_scan_at.map(|t| t.elapsed().as_secs_f64());
                s.last_error = counters.last_error;
                s.last_error_age_s = slot.last_error_at.map(|t| t.elapsed().as_secs_f64());
                s.valid_returns = slot.returns.share();
                s.warning = slot.returns.blind_reason();
                s
            })
            .collect();
        Status {
            site: self.site.clone(),
            uptime_s: self.started.elapsed().as_secs_f64(),
            queue_drops: self.queue.drops(),
            sensors,
            web: lock(&self.web).clone(),
            foxglove: lock(&self.foxglove).clone(),
            zenoh: lock(&self.zenoh).clone(),
            zones: Vec::new(),
        }
    }

    fn poses(&self) -> Poses {
        let now = SystemTime::now();
        let inner = lock(&self.inner);
        let sensors = inner
            .sensors
            .iter()
            .map(|(id, slot)| match inner.poses.get(id) {
                Some(p) => p.to_sensor_pose(id, now),
                None => SensorPose::unregistered(
                    id.clone(),
                    slot.returns
                        .blind_reason()
                        .unwrap_or_else(|| slot.unposed_reason.clone()),
                ),
            })
            .collect();
        Poses {
            anchor: self.anchor.clone(),
            sensors,
            building_from_site: self.building_from_site.borrow().clone(),
            site_from_zone: *lock(&self.site_from_zone),
        }
    }

    fn reregister(&self, sensor: &str) -> Result<String, Refused> {
        if !lock(&self.inner).sensors.contains_key(sensor) {
            return Err(Refused(format!(
                "no sensor {sensor:?}; the configured sensors are {}",
                self.sensor_ids().join(", ")
            )));
        }
        // The anchor is placed against the others, whose poses stand (it was bumped): the site
        // frame stays where it stood. With no other unit placed there is nothing to place it
        // against, and it is the site frame wherever it points.
        let placed_other = lock(&self.inner).poses.keys().any(|id| id != sensor);
        if sensor == self.anchor && !placed_other {
            return Err(Refused(format!(
                "{sensor:?} is the anchor and no other unit is placed: there is nothing to register it against, and the site frame is its frame"
            )));
        }
        self.commands
            .send(Command::Reregister {
                id: sensor.to_string(),
                after_ns: self.stream_ns.load(Ordering::Relaxed),
            })
            .map_err(|_| Refused("the registration worker has stopped; restart scanfuse".into()))?;
        Ok(format!(
            "re-registering {sensor} from its next scans; a re-registered event follows"
        ))
    }

    fn align(&self, pairs: Option<&str>) -> Result<Poses, Refused> {
        let Some(drawing) = self.drawing() else {
            return Err(Refused(
                "no building drawing: set [site] drawing = \"plan.dxf\" in the config (and reload)"
                    .into(),
            ));
        };
        let pairs = match pairs.map(crate::drawing::align::parse_pairs_to_fit) {
            None => Vec::new(),
            Some(Ok(p)) => p,
            Some(Err(e)) => return Err(Refused(e.to_string())),
        };
        let scans = self.posed_scans();
        if scans.is_empty() {
            return Err(Refused(
                "no sensor is placed yet: nothing to align to the drawing".into(),
            ));
        }
        let params = crate::register::RegisterParams::default();
        let found = super::align_live::align_scans(&drawing, &scans, &pairs, &params);
        if !found.aligned {
            return Err(Refused(format!(
                "not aligned to the drawing ({}): {}; the alignment stays as it was",
                found.method,
                found.reason.as_deref().unwrap_or("no reason given")
            )));
        }
        super::align_live::publish(self, found);
        Ok(self.poses())
    }

    fn survey(&self, sensor: &str, request: Option<SurveyRequest>) -> Result<SurveyReply, Refused> {
        let mut inner = lock(&self.inner);
        let Some(slot) = inner.sensors.get(sensor) else {
            let known: Vec<&str> = inner.sensors.keys().map(String::as_str).collect();
            return Err(Refused(format!(
                "no sensor {sensor:?}; the configured sensors are {}",
                known.join(", ")
            )));
        };
        if sensor == self.anchor {
            return Err(Refused(format!(
                "{sensor:?} is the anchor: the site frame is where it stood when first placed (knocked, it is placed again against the others); survey the others"
            )));
        }
        let (mount, config_survey) = (slot.spec.mount, slot.spec.survey);
        let others: Vec<String> = inner
            .sensors
            .keys()
            .filter(|o| {
                o.as_str() != sensor && **o != self.anchor && !inner.surveys.contains_key(*o)
            })
            .cloned()
            .collect();
        let mut surveys = inner.surveys.clone();
        let unwritable = |e: super::state::StateError| {
            Refused(format!("{e}; check that the state directory is writable"))
        };
        let worker_gone =
            |_| Refused("the registration worker has stopped; restart scanfuse".into());
        match request {
            Some(r) => {
                let survey = surveys::check(r.x_m, r.y_m, r.yaw_deg, r.sigma_xy_m, r.sigma_yaw_deg)
                    .map_err(Refused)?;
                surveys.insert(sensor.to_string(), survey);
                surveys::save(&self.state_dir, &surveys).map_err(unwritable)?;
                inner.surveys = surveys;
                inner.resolving.remove(sensor);
                inner.resolving.extend(others);
                let entry = surveyed(&survey, &mount, SystemTime::now());
                let pinned = entry.site_from_sensor;
                inner.poses.insert(sensor.to_string(), entry);
                drop(inner);
                self.commands
                    .send(Command::Survey {
                        id: sensor.to_string(),
                        survey: Some(survey),
                        pinned: Some(pinned),
                    })
                    .map_err(worker_gone)?;
                let message = format!(
                    "{sensor} placed by hand at x {:.3} m, y {:.3} m, yaw {:.2}° (σ {} m, {}°); the others are re-solved around it",
                    r.x_m, r.y_m, r.yaw_deg, r.sigma_xy_m, r.sigma_yaw_deg
                );
                self.announce(EventKind::Surveyed, Some(sensor), message.clone());
                Ok(SurveyReply {
                    sensor: sensor.to_string(),
                    x_m: Some(r.x_m),
                    y_m: Some(r.y_m),
                    yaw_deg: Some(r.yaw_deg),
                    sigma_xy_m: Some(r.sigma_xy_m),
                    sigma_yaw_deg: Some(r.sigma_yaw_deg),
                    message,
                })
            }
            None => {
                if surveys.remove(sensor).is_none() {
                    return Err(Refused(format!(
                        "{sensor} has no survey set by hand, so there is nothing to clear (a survey in the config stays until the config changes)"
                    )));
                }
                surveys::save(&self.state_dir, &surveys).map_err(unwritable)?;
                inner.surveys = surveys;
                inner.resolving.remove(sensor);
                inner.resolving.extend(others);
                drop(inner);
                self.commands
                    .send(Command::Survey {
                        id: sensor.to_string(),
                        survey: config_survey,
                        pinned: None,
                    })
                    .map_err(worker_gone)?;
                let message = format!(
                    "{sensor}'s survey by hand cleared; registering it and the others from their scans again"
                );
                self.announce(EventKind::Surveyed, Some(sensor), message.clone());
                Ok(SurveyReply {
                    sensor: sensor.to_string(),
                    x_m: None,
                    y_m: None,
                    yaw_deg: None,
                    sigma_xy_m: None,
                    sigma_yaw_deg: None,
                    message,
                })
            }
        }
    }

    fn save(&self) -> Result<Saved, Refused> {
        let saved = self.save_now()?;
        self.announce(
            EventKind::Saved,
            None,
            format!("saved {} in {}", saved.files.join(", "), saved.dir),
        );
        Ok(saved)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::queue::drop_oldest;
    use crate::sensor::SensorScan;
    use crate::sensor::clock::WRAP_MS;

    fn pipeline() -> Pipeline {
        let (config, pipeline, _) = pipeline_of(&["a"]);
        let spec = SensorSpec::from_config(&config.sensors[0]);
        pipeline.add_sensor(spec, Arc::default(), watch::channel(false).0);
        pipeline
    }

    /// A pipeline of `ids` (the first the anchor), not yet added; the worker's command end.
    fn pipeline_of(ids: &[&str]) -> (Config, Pipeline, crossbeam_channel::Receiver<Command>) {
        pipeline_in(ids, None)
    }

    /// [`pipeline_of`], saving to `state_dir` when given.
    fn pipeline_in(
        ids: &[&str],
        state_dir: Option<&std::path::Path>,
    ) -> (Config, Pipeline, crossbeam_channel::Receiver<Command>) {
        let mut text = format!("[site]\nname = \"s\"\nanchor = \"{}\"\n", ids[0]);
        if let Some(dir) = state_dir {
            text.push_str(&format!("state_dir = \"{}\"\n", dir.display()));
        }
        for (i, id) in ids.iter().enumerate() {
            text.push_str(&format!(
                "[[sensor]]\nid = \"{id}\"\nconnect = \"tcp://127.0.0.1:{}\"\n",
                i + 1
            ));
        }
        let config = Config::parse(&text, std::path::Path::new("/c/site.toml")).unwrap();
        // The scan queue's worker end is dropped: scans pushed are simply not registered.
        let (queue, _worker) = drop_oldest(16);
        let (commands, worker) = crossbeam_channel::unbounded();
        let p = Pipeline::new(&config, queue, commands, Publisher::new(4), None);
        (config, p, worker)
    }

    /// A pose at x, 1 m, `yaw_deg` (placed by hand: the source does not matter here).
    fn placed_at(x_m: f64, yaw_deg: f64) -> PoseEntry {
        let survey = Survey {
            x_m,
            y_m: 1.0,
            yaw_rad: yaw_deg.to_radians(),
            sigma_xy_m: 0.05,
            sigma_yaw_rad: 0.03,
        };
        surveyed(&survey, &Mount::default(), SystemTime::now())
    }

    fn scan_at(stamp_ns: u64) -> DriverEvent {
        DriverEvent::Scan(SensorScan {
            scan: Scan {
                stamp_ns,
                sensor_stamp_ms: None,
                start_angle_rad: -1.0,
                end_angle_rad: 1.0,
                ranges_m: vec![1.0; 3],
                intensities: Vec::new(),
            },
            measured_ns: None,
            extra_echoes: Vec::new(),
        })
    }

    fn rate(p: &Pipeline) -> Option<f64> {
        p.status().sensors[0].rate_hz
    }

    #[test]
    fn a_rate_is_shown_only_while_scans_arrive() {
        let p = pipeline();
        assert_eq!(rate(&p), None, "before the first scan");
        // Rates are of arrival (wall) time, whatever the stamps: a replay's scans carry their
        // recorded time. (RateMeter's own tests cover the window running dry.)
        let recorded = 1_767_225_600_000_000_000;
        for i in 0..10 {
            p.on_driver_event("a", scan_at(recorded + i * 25_000_000));
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert!(rate(&p).is_some_and(|hz| hz > 0.0), "{:?}", rate(&p));
        // Disconnected right after: no rate, though the window still holds scans.
        p.on_driver_event(
            "a",
            DriverEvent::Disconnected {
                reason: "sensor closed the connection".into(),
            },
        );
        let status = p.status();
        assert_eq!(status.sensors[0].state, SensorState::Disconnected);
        assert_eq!(status.sensors[0].rate_hz, None);
        let line = super::super::protocol::Message::Status(status).to_line();
        assert!(!line.contains("rate_hz"), "{line}");
    }

    /// The tracker forgets a sensor's view when its pose goes or comes back elsewhere (found
    /// moved, placed again) and when the sensor is removed, not when a refinement nudges it.
    #[test]
    fn the_tracker_forgets_a_sensor_whose_pose_went_or_moved_not_one_nudged() {
        let p = pipeline();
        let (queue, tracker) = drop_oldest::<TrackIn>(16);
        p.feed_tracker(queue);
        let at = |x: f64, yaw_deg: f64| Ok(placed_at(x, yaw_deg));
        let forgot = || {
            tracker
                .try_iter()
                .filter(|t| matches!(t, TrackIn::Forget(id) if id == "a"))
                .count()
        };
        p.set_pose("a", at(1.0, 0.0));
        assert_eq!(forgot(), 0, "placed: nothing learnt to forget");
        p.set_pose("a", at(1.03, 0.5));
        assert_eq!(forgot(), 0, "nudged");
        p.set_pose("a", at(1.03, 5.0));
        assert_eq!(forgot(), 1, "turned");
        p.set_pose("a", Err("moved: re-registering it".into()));
        assert_eq!(forgot(), 1, "withdrawn");
        p.set_pose("a", at(1.5, 5.0));
        assert_eq!(forgot(), 0, "placed again: forgotten already");
        p.remove_sensor("a");
        assert_eq!(forgot(), 1, "removed by a reload");
    }

    /// The anchor is re-registered on request (placed against the others) once another
    /// unit is placed; alone, there is nothing to place it against.
    #[test]
    fn the_anchor_is_re_registered_only_once_another_unit_is_placed() {
        let (config, p, worker) = pipeline_of(&["a", "b"]);
        for s in &config.sensors {
            p.add_sensor(
                SensorSpec::from_config(s),
                Arc::default(),
                watch::channel(false).0,
            );
        }
        let asked = || {
            worker
                .try_iter()
                .filter(|c| matches!(c, Command::Reregister { id, .. } if id == "a"))
                .count()
        };
        let refused = p.reregister("a").expect_err("alone");
        assert!(
            refused.0.contains("no other unit is placed"),
            "{}",
            refused.0
        );
        assert_eq!(asked(), 0);
        p.set_pose("b", Ok(placed_at(3.0, 30.0)));
        p.reregister("a").expect("b is placed");
        assert_eq!(asked(), 1);
    }

    #[test]
    fn only_a_streaming_sensor_has_a_rate() {
        for state in [
            SensorState::Connecting,
            SensorState::Disconnected,
            SensorState::Failed,
            SensorState::Stopped,
        ] {
            assert_eq!(shown_rate(state, Some(40.0)), None, "{state:?}");
        }
        assert_eq!(shown_rate(SensorState::Streaming, Some(40.0)), Some(40.0));
        assert_eq!(shown_rate(SensorState::Streaming, None), None);
    }

    #[test]
    fn a_survey_by_hand_places_the_sensor_on_disk_and_the_others_keep_their_poses() {
        let dir = tempfile::tempdir().unwrap();
        let (config, p, worker) = pipeline_in(&["a", "b", "c"], Some(dir.path()));
        for s in &config.sensors {
            p.add_sensor(
                SensorSpec::from_config(s),
                Arc::default(),
                watch::channel(false).0,
            );
        }
        let mount = Mount {
            height_m: None,
            pitch_rad: 0.0,
        };
        let at = |x_m| Survey {
            x_m,
            y_m: 0.0,
            yaw_rad: 0.0,
            sigma_xy_m: 0.1,
            sigma_yaw_rad: 0.1,
        };
        let mut c = surveyed(&at(5.0), &mount, SystemTime::now());
        c.source = PoseSource::Registered;
        p.set_pose("c", Ok(c));
        let request = SurveyRequest {
            x_m: 1.0,
            y_m: 2.0,
            yaw_deg: 30.0,
            sigma_xy_m: 0.05,
            sigma_yaw_deg: 2.0,
        };
        let reply = p.survey("b", Some(request)).unwrap();
        assert_eq!((reply.x_m, reply.yaw_deg), (Some(1.0), Some(30.0)));
        let poses = p.poses();
        let b = poses.sensors.iter().find(|s| s.id == "b").unwrap();
        assert!(
            b.registered && b.source == Some(PoseSource::Surveyed),
            "{b:?}"
        );
        assert!((b.x_m.unwrap() - 1.0).abs() < 1e-12 && (b.yaw_deg.unwrap() - 30.0).abs() < 1e-9);
        assert_eq!(b.sigma_x_m, Some(0.05));
        assert!(
            surveys::load(dir.path()).unwrap().contains_key("b"),
            "kept on disk"
        );
        let sent: Vec<Command> = worker.try_iter().collect();
        assert!(
            sent.iter()
                .any(|c| matches!(c, Command::Survey { id, pinned: Some(_), .. } if id == "b")),
            "{sent:?}"
        );
        // The re-solve around b does not place c: c keeps its pose, and says why.
        p.set_pose("c", Err("no overlap".into()));
        let c = p.poses().sensors.into_iter().find(|s| s.id == "c").unwrap();
        assert!(c.registered, "{c:?}");
        assert!(
            c.reason
                .as_deref()
                .is_some_and(|r| r.contains("keeps its pose")),
            "{c:?}"
        );
        assert!(
            p.survey("a", Some(request))
                .unwrap_err()
                .0
                .contains("anchor")
        );
        assert!(p.survey("zz", None).unwrap_err().0.contains("no sensor"));
        let cleared = p.survey("b", None).unwrap();
        assert_eq!(cleared.x_m, None);
        assert!(surveys::load(dir.path()).unwrap().is_empty());
        assert!(
            p.survey("b", None)
                .unwrap_err()
                .0
                .contains("nothing to clear")
        );
    }

    #[test]
    fn a_survey_by_hand_from_an_earlier_run_stands_before_the_saved_pose() {
        let (config, p, worker) = pipeline_of(&["a", "b"]);
        // poses.toml had b elsewhere; surveys.toml has it placed by hand.
        let mount = Mount {
            height_m: None,
            pitch_rad: 0.0,
        };
        let survey = |x_m| Survey {
            x_m,
            y_m: 1.0,
            yaw_rad: 0.5,
            sigma_xy_m: 0.05,
            sigma_yaw_rad: 0.03,
        };
        let mut saved = surveyed(&survey(9.0), &mount, SystemTime::now());
        saved.loaded = true;
        p.set_pose("b", Ok(saved));
        p.restore_surveys(BTreeMap::from([("b".to_string(), survey(2.0))]));
        for s in &config.sensors {
            p.add_sensor(
                SensorSpec::from_config(s),
                Arc::default(),
                watch::channel(false).0,
            );
        }
        let b = p.poses().sensors.into_iter().find(|s| s.id == "b").unwrap();
        assert_eq!(
            (b.x_m, b.source),
            (Some(2.0), Some(PoseSource::Surveyed)),
            "{b:?}"
        );
        let sent: Vec<Command> = worker.try_iter().collect();
        assert!(
            sent.iter().any(|c| matches!(c, Command::Survey { id, pinned: Some(p), .. } if id == "b" && p.x_m == 2.0)),
            "the worker pins it: {sent:?}"
        );
    }

    #[test]
    fn a_replayed_stamp_is_the_base_plus_the_unit_clock_across_wraps_and_reconnects() {
        let base = 1_767_225_600_000_000_000;
        assert_eq!(restamp(base, None, 1_500), base + 1_500_000_000);
        // Unwrapped by the driver past the wrap: kept.
        let late = base + (WRAP_MS + 10) * 1_000_000;
        assert_eq!(restamp(base, Some(late - 25_000_000), WRAP_MS + 10), late);
        // A reconnect after the wrap restarts the driver's unwrapping at the raw reading.
        assert_eq!(restamp(base, Some(late - 25_000_000), 10), late);
        // A reading from before the previous one by a little is not a wrap forward.
        assert_eq!(
            restamp(base, Some(base + 2_000_000_000), 1_990),
            base + 1_990_000_000
        );
        // A first scan three days into a replay anchored to the wall clock, stamped as live:
        // the wrap nearest the host's clock, not the first.
        let three_days = 3 * 86_400_000_000_000u64 + 123_000_000;
        let raw_ms = (three_days / 1_000_000) % WRAP_MS;
        assert_eq!(
            restamp(base, Some(base + three_days + 40_000_000), raw_ms),
            base + three_days
        );
    }
}
