//! What the site daemon knows and shows (no I/O): each zone's liveliness and last poses,
//! where each zone stands in the site frame, and from these every sensor of every zone in the
//! site frame, served on the status socket (`StatusSource`). `join_frame` turns what the zones
//! sent (poses and static views) into the site frame (`register::zones`). `site_net` feeds it
//! from Zenoh.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::config::PublishConfig;
use super::protocol::{
    EventKind, Poses, Saved, SensorPose, SensorState, SensorStatus, Status, ZoneFrame, ZoneStatus,
};
use super::site_map::SiteMap;
use super::socket::{Publisher, Refused, StatusSource};
use super::zone_net::{Placed as PlacedKey, ViewPayload, placed_key};
use crate::geometry::{Pose2, pose2};
use crate::register::site::Prior;
use crate::register::zones::{CrossPair, ZoneInput, ZoneParams, ZoneSensor, join_zones_with};
use crate::register::{PairResult, RegisterParams, ScanModel};

/// What the site daemon knows of one zone.
#[derive(Debug, Clone)]
struct Zone {
    alive: bool,
    /// When it became alive or was lost.
    since: Instant,
    /// Its last poses, in its own frame.
    poses: Option<Poses>,
    /// The poses were heard since it was last alive (a zone back from the dead may have
    /// re-registered: until it speaks, its old poses are stale).
    fresh: bool,
    /// Its last status: its sensors' drivers.
    status: Option<Status>,
    /// Bytes of what it sent (poses, status, detections), by when, over the last `RATE_OVER`.
    heard: VecDeque<(Instant, usize)>,
    /// Its clock minus the site daemon's (s) as its last payloads said, newest last.
    clock: VecDeque<f64>,
    /// Its clock was said to be off (so it is said once, and again when it is right).
    clock_off: bool,
    /// Why what it sends under a key (`poses`, `status`) cannot be read, until it can.
    unreadable: BTreeMap<String, String>,
}

/// A zone clock this far (s) from the site daemon's is named: walkers are compared by time,
/// and the zones' stamps must agree.
const CLOCK_OFF_S: f64 = 0.5;
/// The clock offset is the median of this many payloads' (a second or two of them).
const CLOCK_OVER: usize = 8;

/// What a zone sends is averaged over this long.
const RATE_OVER: Duration = Duration::from_secs(10);

impl Zone {
    fn new(alive: bool) -> Zone {
        Zone {
            alive,
            since: Instant::now(),
            poses: None,
            fresh: false,
            status: None,
            heard: VecDeque::new(),
            clock: VecDeque::new(),
            clock_off: false,
            unreadable: BTreeMap::new(),
        }
    }
}

/// Where a zone stands in the site frame, or why it does not.
pub(super) type Placed = Result<(Pose2, [f64; 3], usize), String>;

#[derive(Debug, Default)]
struct Zones {
    zones: BTreeMap<String, Zone>,
    frame: BTreeMap<String, Placed>,
    /// Sensor ids two zones share, as already said.
    clashes: std::collections::BTreeSet<String>,
    /// `[[survey]]` units the joins cannot use, as already said (and why).
    unused_surveys: BTreeMap<String, String>,
}

impl Zones {
    /// The zones whose last poses list a sensor `id`, in id order.
    fn zones_with(&self, id: &str) -> impl Iterator<Item = &str> {
        self.zones
            .iter()
            .filter(move |(_, z)| {
                z.poses
                    .as_ref()
                    .is_some_and(|p| p.sensors.iter().any(|s| s.id == id))
            })
            .map(|(zone, _)| zone.as_str())
    }

    /// The zone something was just heard from (alive, if it is new).
    fn heard(&mut self, zone: &str) -> &mut Zone {
        self.zones
            .entry(zone.to_string())
            .or_insert_with(|| Zone::new(true))
    }
}

/// The site daemon's state, served on the socket.
pub struct SiteView {
    pub(super) site: String,
    /// The zone whose frame is the site's.
    pub(super) anchor: String,
    started: Instant,
    /// The status line of its Zenoh side, and of its page.
    zenoh: Mutex<String>,
    web: Mutex<Option<String>>,
    state: Mutex<Zones>,
    publisher: Publisher,
    /// The fused map of the zones' scans, and where `save` writes it.
    map: Mutex<SiteMap>,
    state_dir: Option<std::path::PathBuf>,
    /// `[[survey]]`: units surveyed in the site frame, by id (see [`join_frame`]).
    pub(super) surveys: BTreeMap<String, Prior>,
}

impl SiteView {
    /// The view of site `site` whose frame is zone `anchor`'s.
    pub fn new(site: &str, anchor: &str, publisher: Publisher) -> SiteView {
        SiteView {
            site: site.to_string(),
            anchor: anchor.to_string(),
            started: Instant::now(),
            zenoh: Mutex::new("opening its Zenoh session".into()),
            web: Mutex::new(None),
            state: Mutex::new(Zones::default()),
            publisher,
            map: Mutex::new(SiteMap::new(&PublishConfig::default())),
            state_dir: None,
            surveys: BTreeMap::new(),
        }
    }

    /// With the units `[[survey]]` measured in the site frame.
    pub fn with_surveys(self, surveys: &[super::config::UnitSurvey]) -> SiteView {
        let surveys = surveys
            .iter()
            .map(|u| {
                let s = &u.survey;
                let at = pose2(s.x_m, s.y_m, s.yaw_rad);
                (
                    u.sensor.clone(),
                    Prior::new(at, s.sigma_xy_m, s.sigma_yaw_rad),
                )
            })
            .collect();
        SiteView { surveys, ..self }
    }

    /// Its map fused on `publish`'s grid, saved into `state_dir`.
    pub fn with_map(self, publish: &PublishConfig, state_dir: &std::path::Path) -> SiteView {
        SiteView {
            map: Mutex::new(SiteMap::new(publish)),
            state_dir: Some(state_dir.to_path_buf()),
            ..self
        }
    }

    /// Says how its page stands (`status.web`).
    pub(super) fn set_web(&self, line: String) {
        *self.web.lock().unwrap_or_else(|e| e.into_inner()) = Some(line);
    }

    fn map(&self) -> std::sync::MutexGuard<'_, SiteMap> {
        self.map.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A zone's latest scan of one of its units: into the map, and to `map` watchers, when
    /// the unit is placed in the site frame (else it leaves the map).
    pub(super) fn heard_scan(&self, zone: &str, scan: ViewPayload) {
        let pose = {
            let s = self.lock();
            site_pose(&s, zone, &scan.sensor)
        };
        let mut map = self.map();
        match pose {
            Some(pose) => {
                let frame = map.take(scan, &pose);
                if self.publisher.frame_watchers() > 0 {
                    self.publisher.frame(frame);
                }
            }
            None => map.forget(&scan.sensor),
        }
    }

    /// Fuses the latest scans into the map (a blocking call: the site daemon makes it off its
    /// async loop).
    pub(super) fn fuse_map(&self) {
        // The scans taken under the map's lock, fused under the fuser's alone: a zone's scan
        // heard meanwhile is not held up.
        let (fuser, scans) = self.map().to_fuse();
        super::site_map::lock(&fuser).integrate(&scans);
    }

    /// Writes the map files, when any zone sends its scans; what was written.
    pub(super) fn save_map(&self) -> Result<Saved, Refused> {
        let Some(dir) = &self.state_dir else {
            return Err(Refused("this site daemon has no state directory".into()));
        };
        let map = self.map();
        if map.units() == 0 {
            return Err(Refused(
                "no map yet: no zone placed in the site frame sends its scans (set scans_hz = 2 in a zone's [zenoh]); the zones save their own poses and maps".into(),
            ));
        }
        match map.save(dir, &self.anchor) {
            Ok(files) => Ok(Saved {
                dir: dir.display().to_string(),
                files,
            }),
            Err(e) => Err(Refused(e.to_string())),
        }
    }

    /// Says how its Zenoh side stands (`status.zenoh`).
    pub(super) fn set_zenoh(&self, line: String) {
        *self.zenoh.lock().unwrap_or_else(|e| e.into_inner()) = line;
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Zones> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(super) fn announce(&self, kind: EventKind, message: String) {
        if kind == EventKind::Error {
            tracing::warn!(target: "scanfuse::event", "{message}");
        } else {
            tracing::info!(target: "scanfuse::event", "{message}");
        }
        self.publisher.announce(kind, None, message);
    }

    /// A zone's liveliness token came or went. A lost zone's scans leave the map (what they
    /// showed is no longer known); its poses stay, marked stale.
    pub(super) fn liveliness(&self, zone: &str, alive: bool) {
        let (changed, gone) = {
            let mut s = self.lock();
            let z = s
                .zones
                .entry(zone.to_string())
                .or_insert_with(|| Zone::new(!alive));
            let changed = z.alive != alive;
            if changed {
                z.alive = alive;
                z.since = Instant::now();
                z.fresh = false;
            }
            let units: Vec<String> = match (&z.poses, changed && !alive) {
                (Some(p), true) => p.sensors.iter().map(|u| u.id.clone()).collect(),
                _ => Vec::new(),
            };
            // A unit id another zone still alive lists too is that zone's to show.
            let gone: Vec<String> = units
                .into_iter()
                .filter(|id| {
                    s.zones_with(id)
                        .all(|other| other == zone || !s.zones.get(other).is_some_and(|z| z.alive))
                })
                .collect();
            (changed, gone)
        };
        if !gone.is_empty() {
            let mut map = self.map();
            for id in &gone {
                map.forget(id);
            }
        }
        if changed && alive {
            self.announce(EventKind::Connected, format!("zone {zone} is alive"));
        } else if changed {
            self.announce(
                EventKind::Disconnected,
                format!(
                    "zone {zone} is lost: its poses stay as last heard, marked stale; its scans leave the map"
                ),
            );
        }
    }

    /// A zone's poses. A sensor id another zone uses too is named once: the site's lists
    /// and the `reregister` request go by id, so ids must be unique across the site.
    pub(super) fn heard_poses(&self, zone: &str, poses: Poses) {
        let clashes: Vec<String> = {
            let mut s = self.lock();
            let clashes: Vec<String> = poses
                .sensors
                .iter()
                .filter_map(|p| {
                    let other = s.zones_with(&p.id).find(|other| *other != zone)?;
                    Some(format!(
                        "sensor id {} is used by zone {zone} and by zone {other}: give each sensor an id of its own across the site",
                        p.id
                    ))
                })
                .collect();
            let fresh: Vec<String> = clashes
                .into_iter()
                .filter(|c| s.clashes.insert(c.clone()))
                .collect();
            let z = s.heard(zone);
            z.poses = Some(poses);
            z.fresh = z.alive;
            fresh
        };
        for c in clashes {
            self.announce(EventKind::Error, c);
        }
    }

    pub(super) fn heard_status(&self, zone: &str, status: Status) {
        let mut s = self.lock();
        let z = s.heard(zone);
        z.status = Some(status);
    }

    /// A zone's payload was stamped `offset_s` from the site daemon's clock when it arrived.
    /// Says so when the zone's clock is off by more than `CLOCK_OFF_S`, and when it is right
    /// again.
    pub(super) fn heard_clock(&self, zone: &str, offset_s: f64) {
        let said = {
            let mut s = self.lock();
            let z = s.heard(zone);
            z.clock.push_back(offset_s);
            while z.clock.len() > CLOCK_OVER {
                z.clock.pop_front();
            }
            let offset = clock_offset(z);
            let off = offset.is_some_and(|o| o.abs() > CLOCK_OFF_S);
            let changed = offset.is_some() && off != z.clock_off;
            if changed {
                z.clock_off = off;
            }
            changed.then(|| (off, offset.unwrap_or(0.0)))
        };
        match said {
            Some((true, o)) => self.announce(
                EventKind::Error,
                format!(
                    "zone {zone}'s clock is {:.2} s {} the site daemon's: set both to one time source (NTP, chrony); times compared across zones are wrong until then, and its people are left out of the site's tracks",
                    o.abs(),
                    if o > 0.0 { "ahead of" } else { "behind" }
                ),
            ),
            Some((false, o)) => self.announce(
                EventKind::Connected,
                format!("zone {zone}'s clock agrees with the site daemon's again ({o:+.3} s)"),
            ),
            None => {}
        }
    }

    /// What zone `zone` sent under `leaf` cannot be read (`why`): an error event when that
    /// is new or the reason changed (it comes every second), and the zone's status says so.
    pub(super) fn heard_unreadable(&self, zone: &str, leaf: &str, why: String) {
        let new = {
            let mut s = self.lock();
            let z = s.heard(zone);
            z.unreadable.insert(leaf.to_string(), why.clone()).as_ref() != Some(&why)
        };
        if new {
            self.announce(
                EventKind::Error,
                format!(
                    "zone {zone}'s {leaf} cannot be read: {why}; it is ignored until it can (run one scanfuse version across the site)"
                ),
            );
        }
    }

    /// What zone `zone` sent under `leaf` was read: said once if it could not be before.
    pub(super) fn heard_readable(&self, zone: &str, leaf: &str) {
        let was = {
            let mut s = self.lock();
            s.zones
                .get_mut(zone)
                .and_then(|z| z.unreadable.remove(leaf))
        };
        if was.is_some() {
            self.announce(
                EventKind::Connected,
                format!("zone {zone}'s {leaf} is read again"),
            );
        }
    }

    /// `bytes` of a zone's poses, status or detections arrived.
    pub(super) fn heard_bytes(&self, zone: &str, bytes: usize) {
        let mut s = self.lock();
        let z = s.heard(zone);
        let now = Instant::now();
        z.heard.push_back((now, bytes));
        while z
            .heard
            .front()
            .is_some_and(|(at, _)| now.duration_since(*at) > RATE_OVER)
        {
            z.heard.pop_front();
        }
    }

    /// What a join depends on: the alive zones' placed sensors, to the cm and 0.1°.
    pub(super) fn join_key(&self) -> Vec<(String, PlacedKey)> {
        let s = self.lock();
        s.zones
            .iter()
            .filter(|(_, z)| z.alive && z.fresh)
            .map(|(id, z)| {
                let mut placed = z.poses.as_ref().map(placed_key).unwrap_or_default();
                for p in &mut placed {
                    p.2 = [p.2[0] / 10, p.2[1] / 10, p.2[2] / 100];
                }
                (id.clone(), placed)
            })
            .collect()
    }

    /// Why a zone has not been joined yet.
    fn not_joined(&self, s: &Zones) -> String {
        if s.zones.get(&self.anchor).is_some_and(|z| z.alive) {
            "not joined yet".to_string()
        } else {
            format!(
                "waiting for the anchor zone {} (the site frame is its frame)",
                self.anchor
            )
        }
    }

    /// Where zone `zone` stands in the site frame, for its people: `None` while it is lost,
    /// not placed, or its clock is off (its people would be put at the wrong moment).
    pub(super) fn site_from_zone_for_tracks(&self, zone: &str) -> Option<Pose2> {
        let s = self.lock();
        let z = s.zones.get(zone)?;
        match s.frame.get(zone) {
            Some(Ok((pose, _, _))) if z.alive && !z.clock_off => Some(*pose),
            _ => None,
        }
    }

    /// Some alive zone with placed sensors is not placed in the site frame.
    pub(super) fn someone_unplaced(&self) -> bool {
        let s = self.lock();
        s.zones.iter().any(|(id, z)| {
            z.alive && placed_sensors(z) > 0 && !matches!(s.frame.get(id), Some(Ok(_)))
        })
    }

    /// Takes a refining join's result (the links averaged over more moments): it may move a
    /// placed zone by a little, never far and never unplace it. A placement more than
    /// `REFINE_MAX_M` or `REFINE_MAX_DEG` from where the zone stands is another pose, not a
    /// refinement of this one (a later moment's look-alike): the zone stays, and that is said.
    pub(super) fn refine_frame(&self, mut frame: BTreeMap<String, Placed>) {
        let standing = self.lock().frame.clone();
        for (zone, placed) in frame.iter_mut() {
            let Some(Ok(old)) = standing.get(zone) else {
                continue;
            };
            let far = match placed {
                Ok((pose, _, _)) => {
                    let (dt, dyaw) = crate::geometry::pose_error(pose, &old.0);
                    (dt > REFINE_MAX_M || dyaw > REFINE_MAX_DEG.to_radians()).then_some((dt, dyaw))
                }
                Err(_) => None,
            };
            if let Some((dt, dyaw)) = far {
                self.announce(
                    EventKind::Error,
                    format!(
                        "zone {zone}: a later moment's views link it {dt:.2} m / {:.1}° from where it stands; it stays where it is (a look-alike, or the zone was moved: its own poses would then change and it is joined afresh)",
                        dyaw.to_degrees()
                    ),
                );
            }
            if far.is_some() || placed.is_err() {
                *placed = Ok(*old);
            }
        }
        self.set_frame(frame);
    }

    /// Says once of each `[[survey]]` unit that the joins cannot use why: one of the anchor
    /// zone (its frame is the site's: there is nothing to hold), or one no zone lists.
    pub(super) fn say_unused_surveys(&self) {
        let mut said = Vec::new();
        {
            let mut s = self.lock();
            for id in self.surveys.keys() {
                let zones: Vec<String> = s.zones_with(id).map(str::to_string).collect();
                let why = if zones.contains(&self.anchor) {
                    format!(
                        "[[survey]] of {id} is not used: {id} is a unit of the anchor zone {}, whose frame is the site's; survey units of the other zones",
                        self.anchor
                    )
                } else if zones.is_empty() {
                    format!(
                        "[[survey]] of {id} is not used yet: no zone lists a unit {id} (check the id against the zones' units)"
                    )
                } else {
                    s.unused_surveys.remove(id);
                    continue;
                };
                if s.unused_surveys.get(id) != Some(&why) {
                    s.unused_surveys.insert(id.clone(), why.clone());
                    said.push(why);
                }
            }
        }
        for why in said {
            self.announce(EventKind::Error, why);
        }
    }

    /// Takes a full join's result (one that looked for pairs afresh, after some zone's own
    /// poses changed). A placed zone whose frame holds (`holding`, with why: its poses have
    /// not changed, or some unit kept its pose in it) and that this join could not
    /// place stays where it stands, and that is said: the join may have missed its views (a
    /// zone slow to answer under load, or a moved unit that was its only link), and nothing
    /// says its place no longer holds. Any other zone takes the join's word.
    pub(super) fn join_afresh(
        &self,
        mut frame: BTreeMap<String, Placed>,
        holding: &BTreeMap<String, String>,
    ) {
        let standing = self.lock().frame.clone();
        for (zone, placed) in frame.iter_mut() {
            let (Err(why), Some(Ok(old))) = (&*placed, standing.get(zone)) else {
                continue;
            };
            let Some(holds) = holding.get(zone) else {
                continue;
            };
            self.announce(
                EventKind::Registering,
                format!(
                    "zone {zone}: this join could not place it ({why}); {holds}, so it stays where it stands"
                ),
            );
            *placed = Ok(*old);
        }
        self.set_frame(frame);
    }

    /// Takes a join's result. A zone the join did not see (lost meanwhile) keeps where it
    /// stood, as its poses do. Says what changed: a zone placed, moved by more than 1 cm or
    /// 0.1°, or newly unplaced and why.
    pub(super) fn set_frame(&self, frame: BTreeMap<String, Placed>) {
        let before = {
            let mut s = self.lock();
            let before = s.frame.clone();
            s.frame.extend(frame.clone());
            before
        };
        for (zone, placed) in &frame {
            let was = before.get(zone);
            match placed {
                Ok((pose, _, pairs)) => {
                    let moved = match was {
                        Some(Ok((old, _, _))) => {
                            let (dt, dyaw) = crate::geometry::pose_error(pose, old);
                            dt > 0.01 || dyaw > 0.1f64.to_radians()
                        }
                        _ => true,
                    };
                    if !moved {
                        continue;
                    }
                    let from = if *zone == self.anchor {
                        " (the anchor zone)".to_string()
                    } else {
                        format!(" from {pairs} sensor pair(s) across zones")
                    };
                    self.announce(
                        EventKind::Registered,
                        format!(
                            "zone {zone} placed in the site frame at ({:.3} m, {:.3} m, {:.2}°){from}",
                            pose.translation.x,
                            pose.translation.y,
                            pose.rotation.angle().to_degrees(),
                        ),
                    );
                }
                Err(why) if was != Some(placed) => self.announce(
                    EventKind::Registering,
                    format!("zone {zone} is not placed in the site frame: {why}"),
                ),
                Err(_) => {}
            }
        }
    }

    pub(super) fn zone_statuses(&self) -> Vec<ZoneStatus> {
        let s = self.lock();
        s.zones
            .iter()
            .map(|(id, z)| {
                let (site_from_zone, reason) = match s.frame.get(id) {
                    Some(Ok((pose, sigma, pairs))) => (
                        Some(ZoneFrame {
                            x_m: pose.translation.x,
                            y_m: pose.translation.y,
                            yaw_deg: pose.rotation.angle().to_degrees(),
                            sigma_x_m: sigma[0],
                            sigma_y_m: sigma[1],
                            sigma_yaw_deg: sigma[2].to_degrees(),
                            pairs: *pairs,
                        }),
                        None,
                    ),
                    Some(Err(why)) => (None, Some(why.clone())),
                    None => (None, Some(self.not_joined(&s))),
                };
                ZoneStatus {
                    zone: id.clone(),
                    alive: z.alive,
                    for_s: z.since.elapsed().as_secs_f64(),
                    sensors: z.poses.as_ref().map_or(0, |p| p.sensors.len()),
                    placed: placed_sensors(z),
                    bytes_per_s: bytes_per_s(z, self.started),
                    clock_offset_s: clock_offset(z),
                    site_from_zone,
                    reason,
                    unreadable: (!z.unreadable.is_empty()).then(|| {
                        let whys: Vec<String> = z
                            .unreadable
                            .iter()
                            .map(|(leaf, why)| format!("its {leaf}: {why}"))
                            .collect();
                        whys.join("; ")
                    }),
                }
            })
            .collect()
    }
}

/// What a zone sent (poses, status, detections) a second, over the last `RATE_OVER` (or since the
/// site daemon started); absent before anything came.
fn bytes_per_s(z: &Zone, started: Instant) -> Option<f64> {
    let total: usize = z.heard.iter().map(|(_, b)| b).sum();
    let over = started.elapsed().min(RATE_OVER).as_secs_f64();
    (total > 0 && over > 0.0).then(|| total as f64 / over)
}

/// The zone's clock minus the site daemon's (s): the median of its last payloads' stamps
/// against their arrival, once there are a few.
fn clock_offset(z: &Zone) -> Option<f64> {
    if z.clock.len() < CLOCK_OVER / 2 {
        return None;
    }
    let mut v: Vec<f64> = z.clock.iter().copied().collect();
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

fn placed_sensors(z: &Zone) -> usize {
    z.poses
        .as_ref()
        .map_or(0, |p| p.sensors.iter().filter(|s| s.registered).count())
}

/// Where sensor `sensor` of zone `zone` stands in the site frame, when its zone placed it and
/// the zone is placed.
fn site_pose(s: &Zones, zone: &str, sensor: &str) -> Option<Pose2> {
    let z = s.zones.get(zone)?;
    let (pose, _) = zone_pose(z.poses.as_ref()?.sensors.iter().find(|p| p.id == sensor)?)?;
    match s.frame.get(zone) {
        Some(Ok((site_from_zone, _, _))) => Some(site_from_zone * pose),
        _ => None,
    }
}

/// A sensor's pose in its zone's frame, with σ (x, y, yaw rad), when its zone placed it.
fn zone_pose(s: &SensorPose) -> Option<(Pose2, [f64; 3])> {
    if !s.registered {
        return None;
    }
    let pose = pose2(s.x_m?, s.y_m?, s.yaw_deg?.to_radians());
    let sigma = [
        s.sigma_x_m.unwrap_or(0.0),
        s.sigma_y_m.unwrap_or(0.0),
        s.sigma_yaw_deg.unwrap_or(0.0).to_radians(),
    ];
    Some((pose, sigma))
}

impl StatusSource for SiteView {
    fn status(&self) -> Status {
        Status {
            site: self.site.clone(),
            uptime_s: self.started.elapsed().as_secs_f64(),
            queue_drops: 0,
            sensors: self.sensor_statuses(),
            web: self.web.lock().unwrap_or_else(|e| e.into_inner()).clone(),
            foxglove: None,
            zenoh: Some(self.zenoh.lock().unwrap_or_else(|e| e.into_inner()).clone()),
            zones: self.zone_statuses(),
        }
    }

    /// Every sensor of every zone, in the site frame where its zone is placed.
    fn poses(&self) -> Poses {
        let s = self.lock();
        let anchor = s
            .zones
            .get(&self.anchor)
            .and_then(|z| z.poses.as_ref())
            .map_or_else(|| format!("zone {}", self.anchor), |p| p.anchor.clone());
        let mut sensors = Vec::new();
        for (id, z) in &s.zones {
            let Some(poses) = &z.poses else { continue };
            let frame = s.frame.get(id);
            for p in &poses.sensors {
                let mut out = match (frame, zone_pose(p)) {
                    (Some(Ok((site_from_zone, zs, _))), Some((pose, sigma))) => {
                        let site = site_from_zone * pose;
                        // The zone's σ and the sensor's within it, as independent; the zone's
                        // yaw σ moves the sensor by its distance from the zone's origin.
                        let lever = pose.translation.vector.norm() * zs[2];
                        let add = |a: f64, b: f64| (a * a + b * b).sqrt();
                        SensorPose {
                            x_m: Some(site.translation.x),
                            y_m: Some(site.translation.y),
                            yaw_deg: Some(site.rotation.angle().to_degrees()),
                            sigma_x_m: Some(add(add(zs[0], sigma[0]), lever)),
                            sigma_y_m: Some(add(add(zs[1], sigma[1]), lever)),
                            sigma_yaw_deg: Some(add(zs[2], sigma[2]).to_degrees()),
                            ..p.clone()
                        }
                    }
                    (_, Some(_)) => {
                        let why = match frame {
                            Some(Err(why)) => why.clone(),
                            _ => self.not_joined(&s),
                        };
                        SensorPose::unregistered(
                            p.id.clone(),
                            format!(
                                "placed in zone {id}, but zone {id} is not placed in the site frame: {why}"
                            ),
                        )
                    }
                    (_, None) => p.clone(),
                };
                out.zone = Some(id.clone());
                out.stale = !(z.alive && z.fresh);
                sensors.push(out);
            }
        }
        Poses {
            anchor,
            sensors,
            building_from_site: None,
            site_from_zone: None,
        }
    }

    fn reregister(&self, sensor: &str) -> Result<String, Refused> {
        Err(self.ask_its_zone(sensor))
    }

    /// The page's drag of a unit: its zone places it, not the site daemon.
    fn survey(
        &self,
        sensor: &str,
        _: Option<super::socket::SurveyRequest>,
    ) -> Result<super::protocol::Survey, Refused> {
        Err(self.ask_its_zone(sensor))
    }

    /// The site's map files; the zones save their own poses, and the site frame is
    /// rebuilt from them.
    fn save(&self) -> Result<Saved, Refused> {
        self.save_map()
    }
}

impl SiteView {
    /// Why the site daemon does not change a unit's pose: its zone's daemon does.
    fn ask_its_zone(&self, sensor: &str) -> Refused {
        let zones: Vec<String> = self.lock().zones_with(sensor).map(str::to_string).collect();
        Refused(match zones.as_slice() {
            [] => format!("this is the site daemon, and no zone has a sensor {sensor}"),
            [z] => {
                format!("this is the site daemon; {sensor} is zone {z}'s: ask zone {z}'s daemon")
            }
            many => format!(
                "this is the site daemon, and zones {} each have a sensor {sensor}: ask the daemon of the zone you mean, and give each sensor an id of its own across the site",
                many.join(" and ")
            ),
        })
    }
}

/// The site daemon's page: every zone's units in the site frame, the map of the scans the
/// zones send, the tracks.
impl crate::web::PageSource for SiteView {
    fn occupancy(&self) -> Option<crate::fuse::OccupancyGrid> {
        let map = self.map();
        (map.units() > 0).then(|| map.grid())
    }

    fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
        self.map().fields_of_view()
    }
}

/// A zone's placed sensors: id, pose in the zone's frame, σ (x m, y m, yaw rad).
pub(super) type PlacedInZone = Vec<(String, Pose2, [f64; 3])>;

/// What one zone sent for a join: its placed sensors and the static views it answered with.
pub(super) struct Heard {
    pub zone: String,
    pub placed: PlacedInZone,
    pub views: Vec<ViewPayload>,
}

impl SiteView {
    /// Every zone's sensors' drivers, as their zones last said.
    /// A lost zone's drivers are not known to stream: they read disconnected, with why.
    fn sensor_statuses(&self) -> Vec<SensorStatus> {
        let s = self.lock();
        let mut out = Vec::new();
        for (id, z) in &s.zones {
            let Some(st) = &z.status else { continue };
            for sensor in &st.sensors {
                let mut sensor = sensor.clone();
                if !z.alive {
                    sensor.state = SensorState::Disconnected;
                    sensor.rate_hz = None;
                    sensor.last_error = Some(format!(
                        "zone {id} is lost: the site daemon no longer hears it (its daemon stopped, or the link is down)"
                    ));
                    sensor.last_error_age_s = Some(z.since.elapsed().as_secs_f64());
                }
                out.push(sensor);
            }
        }
        out
    }

    /// The zones to ask for views: alive, heard since, each with its placed sensors.
    pub(super) fn to_ask(&self) -> Vec<(String, PlacedInZone)> {
        let s = self.lock();
        s.zones
            .iter()
            .filter(|(_, z)| z.alive && z.fresh)
            .filter_map(|(id, z)| {
                let placed = z
                    .poses
                    .as_ref()?
                    .sensors
                    .iter()
                    .filter_map(|s| zone_pose(s).map(|(p, sigma)| (s.id.clone(), p, sigma)))
                    .collect();
                Some((id.clone(), placed))
            })
            .collect()
    }
}

/// A cross pair a join linked two zones by, by zone and sensor ids: the next joins of the
/// same zones average it with theirs. Only linking pairs are kept: a look-alike pair that
/// registered but was outvoted must not gather votes over the moments.
#[derive(Debug, Clone)]
pub(super) struct KeptPair {
    za: String,
    s: String,
    zb: String,
    t: String,
    result: PairResult,
}

/// How many moments' registrations of one sensor pair are kept (the newest).
const MOMENTS_KEPT: usize = 5;
/// A refining join moves a placed zone at most this far (see [`SiteView::refine_frame`]).
const REFINE_MAX_M: f64 = 0.3;
const REFINE_MAX_DEG: f64 = 1.0;

/// Where each zone that sent something stands in the frame of zone `anchor`, or why not,
/// from the cross pairs registered now and `earlier` (see [`KeptPair`]; with `again`, only
/// those sensor pairs are registered now), with the registered pairs to keep for the next
/// join; `None` without the anchor zone among them (the frame is its frame: what was placed
/// before stays placed). CPU-bound (it registers the cross pairs): run it off the async
/// runtime.
pub(super) fn join_frame(
    anchor: &str,
    heard: Vec<Heard>,
    earlier: Vec<KeptPair>,
    again: bool,
    surveys: &BTreeMap<String, Prior>,
) -> Option<(BTreeMap<String, Placed>, Vec<KeptPair>)> {
    if !heard.iter().any(|h| h.zone == anchor) {
        return None;
    }
    let params = RegisterParams::default();
    let mut unanswered: Vec<String> = Vec::new();
    let zones: Vec<ZoneInput> = heard
        .into_iter()
        .map(|h| {
            if h.views.is_empty() && !h.placed.is_empty() {
                unanswered.push(h.zone.clone());
            }
            let sensors = h
                .placed
                .into_iter()
                .filter_map(|(sensor, zone_from_sensor, sigma)| {
                    let v = h.views.iter().find(|v| v.sensor == sensor)?;
                    let v = v.clone().into_view();
                    let model =
                        ScanModel::from_scan(&v.view, v.geometry.as_ref(), &v.mount, &params);
                    Some(ZoneSensor {
                        model,
                        surveyed: surveys.get(&sensor).copied(),
                        id: sensor,
                        zone_from_sensor,
                        sigma,
                    })
                })
                .collect();
            ZoneInput {
                id: h.zone,
                sensors,
            }
        })
        .collect();
    let a = zones.iter().position(|z| z.id == anchor)?;
    let p = ZoneParams {
        register: params,
        ..ZoneParams::default()
    };
    let at = |zone: &str, sensor: &str| {
        let z = zones.iter().position(|z| z.id == zone)?;
        Some((z, zones[z].sensors.iter().position(|s| s.id == sensor)?))
    };
    let earlier: Vec<CrossPair> = earlier
        .into_iter()
        .filter_map(|k| {
            let ((za, s), (zb, t)) = (at(&k.za, &k.s)?, at(&k.zb, &k.t)?);
            Some(CrossPair {
                za,
                s,
                zb,
                t,
                result: k.result,
                used: false,
            })
        })
        .collect();
    let result = join_zones_with(&zones, a, &p, earlier, again);
    // This join's pairs come first: the newest of each sensor pair are kept.
    let mut kept: Vec<KeptPair> = Vec::new();
    for c in result.pairs.iter().filter(|c| c.used) {
        let k = KeptPair {
            za: zones[c.za].id.clone(),
            s: zones[c.za].sensors[c.s].id.clone(),
            zb: zones[c.zb].id.clone(),
            t: zones[c.zb].sensors[c.t].id.clone(),
            result: c.result.clone(),
        };
        let times = kept.iter().filter(|o| (&o.s, &o.t) == (&k.s, &k.t)).count();
        if times < MOMENTS_KEPT {
            kept.push(k);
        }
    }
    let placed: BTreeMap<String, Placed> = zones
        .iter()
        .zip(result.zones)
        .map(|(z, placement)| {
            let placed = match placement.site_from_zone {
                Ok((pose, sigma)) => Ok((pose, sigma, placement.pairs)),
                Err(_) if z.sensors.is_empty() && unanswered.contains(&z.id) => Err(format!(
                    "zone {} sent no static views when asked (it may still be starting)",
                    z.id
                )),
                Err(_) if z.sensors.is_empty() => {
                    Err(format!("zone {} has no placed sensors yet", z.id))
                }
                Err(why) => Err(why),
            };
            (z.id.clone(), placed)
        })
        .collect();
    Some((placed, kept))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn placed(id: &str, x: f64, y: f64, yaw_deg: f64) -> SensorPose {
        SensorPose {
            registered: true,
            x_m: Some(x),
            y_m: Some(y),
            yaw_deg: Some(yaw_deg),
            sigma_x_m: Some(0.01),
            sigma_y_m: Some(0.01),
            sigma_yaw_deg: Some(0.1),
            reason: None,
            ..SensorPose::unregistered(id, "")
        }
    }

    fn poses(anchor: &str, sensors: Vec<SensorPose>) -> Poses {
        Poses {
            anchor: anchor.into(),
            sensors,
            building_from_site: None,
            site_from_zone: None,
        }
    }

    #[test]
    fn without_the_anchor_zone_nothing_is_joined_and_the_others_wait_for_it() {
        let heard = |zone: &str| Heard {
            zone: zone.into(),
            placed: Vec::new(),
            views: Vec::new(),
        };
        assert!(
            join_frame(
                "west",
                vec![heard("east")],
                Vec::new(),
                false,
                &BTreeMap::new()
            )
            .is_none()
        );
        let (frame, _) = join_frame(
            "west",
            vec![heard("west"), heard("east")],
            Vec::new(),
            false,
            &BTreeMap::new(),
        )
        .unwrap();
        let east = frame["east"].as_ref().unwrap_err();
        assert!(east.contains("no placed sensors"), "{east}");
        let view = SiteView::new("hall", "west", Publisher::new(16));
        view.liveliness("east", true);
        let reason = view.status().zones[0].reason.clone().unwrap();
        assert!(
            reason.contains("waiting for the anchor zone west"),
            "{reason}"
        );
    }

    /// A `[[survey]]` the joins cannot use is named once, with why; when it becomes usable
    /// nothing more is said.
    #[test]
    fn a_survey_of_an_anchor_zone_unit_or_of_no_unit_is_named_once() {
        use crate::daemon::config::{Survey, UnitSurvey};
        let publisher = Publisher::new(16);
        let mut events = publisher.subscribe_events();
        let at = Survey {
            x_m: 1.0,
            y_m: 2.0,
            yaw_rad: 0.1,
            sigma_xy_m: 0.02,
            sigma_yaw_rad: 0.01,
        };
        let survey = |id: &str| UnitSurvey {
            sensor: id.into(),
            survey: at,
        };
        let view = SiteView::new("hall", "west", publisher)
            .with_surveys(&[survey("gate"), survey("dock")]);
        assert_eq!(
            view.surveys["dock"],
            Prior::new(pose2(1.0, 2.0, 0.1), 0.02, 0.01)
        );
        view.heard_poses("west", poses("gate", vec![placed("gate", 0.0, 0.0, 0.0)]));
        for _ in 0..2 {
            view.say_unused_surveys();
        }
        let mut said = vec![events.try_recv().unwrap(), events.try_recv().unwrap()];
        said.sort();
        assert!(
            said[0].contains("[[survey]] of dock is not used yet: no zone lists"),
            "{said:?}"
        );
        assert!(
            said[1].contains("gate is a unit of the anchor zone west"),
            "{said:?}"
        );
        assert!(events.try_recv().is_err(), "named more than once");
        view.heard_poses("east", poses("dock", vec![placed("dock", 0.0, 0.0, 0.0)]));
        view.say_unused_surveys();
        assert!(events.try_recv().is_err(), "dock's survey is used now");
    }

    #[test]
    fn a_sensor_id_two_zones_use_is_named_once() {
        let publisher = Publisher::new(16);
        let mut events = publisher.subscribe_events();
        let view = SiteView::new("hall", "west", publisher);
        view.heard_poses("west", poses("gate", vec![placed("gate", 0.0, 0.0, 0.0)]));
        view.heard_poses("east", poses("dock", vec![placed("dock", 0.0, 0.0, 0.0)]));
        assert!(events.try_recv().is_err());
        for _ in 0..3 {
            view.heard_poses("east", poses("gate", vec![placed("gate", 0.0, 0.0, 0.0)]));
        }
        let said = events.try_recv().expect("the clash named");
        assert!(
            said.contains("sensor id gate is used by zone east and by zone west"),
            "{said}"
        );
        assert!(events.try_recv().is_err(), "named more than once");
        // Asked to register it again, the site daemon names both zones, not the first found.
        let Err(Refused(why)) = view.reregister("gate") else {
            panic!("the site daemon registers nothing itself")
        };
        assert!(
            why.contains("zones east and west each have a sensor gate"),
            "{why}"
        );
        let Err(Refused(why)) = view.reregister("dock") else {
            panic!("the site daemon registers nothing itself")
        };
        // East's last poses no longer list dock.
        assert!(why.contains("no zone has a sensor dock"), "{why}");
        // Dragged on the site daemon's page, a unit is its zone's to place.
        view.heard_poses("east", poses("east1", vec![placed("east1", 0.0, 0.0, 0.0)]));
        let Err(Refused(why)) = view.survey("east1", None) else {
            panic!("the site daemon places nothing itself")
        };
        assert!(why.contains("ask zone east's daemon"), "{why}");
    }

    /// A site anchored on west, zone east just come alive, and its events from then on.
    fn east_alive() -> (
        SiteView,
        tokio::sync::broadcast::Receiver<std::sync::Arc<str>>,
    ) {
        let publisher = Publisher::new(16);
        let mut events = publisher.subscribe_events();
        let view = SiteView::new("hall", "west", publisher);
        view.liveliness("east", true);
        let _ = events.try_recv();
        (view, events)
    }

    #[test]
    fn a_zone_whose_clock_is_off_is_named_once_and_again_when_it_is_right() {
        let (view, mut events) = east_alive();
        // A few ms of link delay is no offset; a jitter of one payload is outvoted.
        for o in [-0.004, -0.003, 2.0, -0.005, -0.004] {
            view.heard_clock("east", o);
        }
        assert!(events.try_recv().is_err(), "a right clock was named");
        let offset = view.status().zones[0].clock_offset_s.unwrap();
        assert!(offset.abs() < 0.01, "{offset}");
        for _ in 0..CLOCK_OVER {
            view.heard_clock("east", -12.5);
        }
        let said = events.try_recv().expect("the clock named");
        assert!(said.contains("12.50 s behind"), "{said}");
        assert!(events.try_recv().is_err(), "named twice");
        for _ in 0..CLOCK_OVER {
            view.heard_clock("east", 0.002);
        }
        let said = events.try_recv().expect("the clock right again");
        assert!(said.contains("agrees"), "{said}");
    }

    /// A refining join moves a placed zone a little; a placement far from where it stands
    /// (a later moment's look-alike) or none at all leaves it where it is.
    #[test]
    fn a_refining_join_moves_a_zone_a_little_never_far_and_never_unplaces_it() {
        let view = SiteView::new("hall", "west", Publisher::new(16));
        let at = |x: f64, yaw: f64| -> Placed { Ok((pose2(x, 0.0, yaw), [0.01, 0.01, 0.001], 2)) };
        let east = |v: &SiteView| v.lock().frame["east"].clone();
        let one = |p: Placed| BTreeMap::from([("east".to_string(), p)]);
        view.set_frame(one(at(20.0, 0.0)));
        view.refine_frame(one(at(20.02, 0.001)));
        assert_eq!(east(&view), at(20.02, 0.001));
        view.refine_frame(one(at(180.0, std::f64::consts::PI)));
        assert_eq!(
            east(&view),
            at(20.02, 0.001),
            "turned round: not a refinement"
        );
        view.refine_frame(one(Err("their sensor pairs disagree".into())));
        assert_eq!(east(&view), at(20.02, 0.001));
        // A join afresh (a zone's own poses changed) may move it anywhere.
        view.set_frame(one(at(180.0, 0.0)));
        assert_eq!(east(&view), at(180.0, 0.0));
    }

    /// A join afresh that cannot place a placed zone leaves it where it stands when the
    /// zone's frame holds (its views were missed), not when it may have moved.
    #[test]
    fn a_join_afresh_unplaces_only_a_zone_whose_frame_may_have_moved() {
        let view = SiteView::new("hall", "west", Publisher::new(16));
        let at = |x: f64| -> Placed { Ok((pose2(x, 0.0, 0.0), [0.01, 0.01, 0.001], 2)) };
        let zone = |v: &SiteView, z: &str| v.lock().frame[z].clone();
        let both = |e: Placed, n: Placed| {
            BTreeMap::from([("east".to_string(), e), ("north".to_string(), n)])
        };
        view.set_frame(both(at(20.0), at(-5.0)));
        let no = || -> Placed { Err("no chain of them reaches zone west".into()) };
        let holding =
            BTreeMap::from([("east".to_string(), "its own poses have not changed".into())]);
        view.join_afresh(both(no(), no()), &holding);
        assert_eq!(zone(&view, "east"), at(20.0), "its views were missed");
        assert_eq!(zone(&view, "north"), no(), "its own poses changed");
        view.join_afresh(both(at(20.5), at(-5.0)), &holding);
        assert_eq!(zone(&view, "east"), at(20.5), "placed anew: moved");
    }

    #[test]
    fn what_a_zone_sends_that_cannot_be_read_is_named_once_shown_and_cleared_when_it_reads() {
        let (view, mut events) = east_alive();
        // Every second the same unreadable status: one event, not one a second.
        for _ in 0..3 {
            view.heard_unreadable("east", "status", "schema \"x/2\"".into());
        }
        let said = events.try_recv().expect("the unreadable status named");
        assert!(said.contains("zone east's status cannot be read"), "{said}");
        assert!(events.try_recv().is_err(), "named twice");
        let shown = view.status().zones[0].unreadable.clone();
        assert_eq!(shown.as_deref(), Some("its status: schema \"x/2\""));
        // Poses that read say nothing; the status read again is said once and cleared.
        view.heard_readable("east", "poses");
        assert!(events.try_recv().is_err(), "a readable payload was named");
        view.heard_readable("east", "status");
        let said = events.try_recv().expect("read again");
        assert!(said.contains("read again"), "{said}");
        assert_eq!(view.status().zones[0].unreadable, None);
    }

    #[test]
    fn a_zone_is_moved_whole_into_the_site_frame_and_kept_stale_when_lost() {
        let view = SiteView::new("hall", "west", Publisher::new(16));
        view.liveliness("west", true);
        view.liveliness("east", true);
        view.heard_poses("west", poses("gate", vec![placed("gate", 0.0, 0.0, 0.0)]));
        view.heard_poses(
            "east",
            poses(
                "dock",
                vec![
                    placed("dock", 0.0, 0.0, 0.0),
                    placed("tough", 2.0, 0.0, 90.0),
                    SensorPose::unregistered("far", "waiting"),
                ],
            ),
        );
        // East's frame stands 10 m along x, turned 90°, in the site's.
        let frame = BTreeMap::from([
            ("west".to_string(), Ok((Pose2::identity(), [0.0; 3], 0))),
            (
                "east".to_string(),
                Ok((pose2(10.0, 0.0, 90f64.to_radians()), [0.02, 0.02, 0.001], 2)),
            ),
        ]);
        view.set_frame(frame);
        let got = view.poses();
        assert_eq!(got.anchor, "gate");
        let by = |id: &str| got.sensors.iter().find(|s| s.id == id).unwrap().clone();
        let tough = by("tough");
        assert_eq!(tough.zone.as_deref(), Some("east"));
        assert!((tough.x_m.unwrap() - 10.0).abs() < 1e-9, "{tough:?}");
        assert!((tough.y_m.unwrap() - 2.0).abs() < 1e-9, "{tough:?}");
        assert!((tough.yaw_deg.unwrap() - 180.0).abs() < 1e-9, "{tough:?}");
        // Its σ holds the zone's, and the zone's yaw σ over its 2 m from the zone's origin.
        assert!(tough.sigma_x_m.unwrap() > 0.02 && tough.sigma_x_m.unwrap() < 0.03);
        assert!(!by("far").registered && !tough.stale);
        let status = view.status();
        let east = status.zones.iter().find(|z| z.zone == "east").unwrap();
        assert_eq!((east.sensors, east.placed), (3, 2));
        assert_eq!(east.site_from_zone.map(|f| f.pairs), Some(2));

        // Its drivers, as it says; lost, they are no longer known to stream.
        let mut streaming = SensorStatus::new("tough", SensorState::Streaming);
        streaming.rate_hz = Some(40.0);
        let mut east_status = view.status();
        east_status.sensors = vec![streaming];
        view.heard_status("east", east_status);
        let driver = |view: &SiteView| {
            let s = view.status().sensors;
            s.into_iter().find(|s| s.id == "tough").unwrap()
        };
        assert_eq!(driver(&view).state, SensorState::Streaming);

        // Lost: its poses stay, stale, through a join that no longer sees it.
        view.liveliness("east", false);
        let lost = driver(&view);
        assert_eq!(
            (lost.state, lost.rate_hz),
            (SensorState::Disconnected, None)
        );
        assert!(lost.last_error.unwrap().contains("zone east is lost"));
        view.set_frame(BTreeMap::from([(
            "west".to_string(),
            Ok((Pose2::identity(), [0.0; 3], 0)),
        )]));
        let tough = view
            .poses()
            .sensors
            .into_iter()
            .find(|s| s.id == "tough")
            .unwrap();
        assert!(tough.registered && tough.stale, "{tough:?}");
        // Back: stale until it speaks again.
        view.liveliness("east", true);
        assert!(
            view.poses()
                .sensors
                .iter()
                .any(|s| s.id == "tough" && s.stale)
        );
        assert!(view.join_key().iter().all(|(z, _)| z != "east"));
        view.heard_poses("east", poses("dock", vec![placed("dock", 0.0, 0.0, 0.0)]));
        assert!(view.poses().sensors.iter().all(|s| !s.stale));

        // A zone the join could not place says why on each of its sensors.
        view.set_frame(BTreeMap::from([(
            "east".to_string(),
            Err("their sensor pairs disagree".to_string()),
        )]));
        let dock = view
            .poses()
            .sensors
            .into_iter()
            .find(|s| s.id == "dock")
            .unwrap();
        assert!(!dock.registered);
        assert!(dock.reason.unwrap().contains("disagree"));
    }

    #[test]
    fn a_lost_zones_scans_leave_the_map_and_its_poses_stay() {
        use crate::daemon::zone_net::{SCAN_SCHEMA, ViewPayload};
        use crate::geometry::Mount;
        use crate::geometry::raycast::{polygon, scan_270};
        use crate::web::PageSource;
        let (view, _events) = east_alive();
        view.liveliness("west", true);
        view.heard_poses("west", poses("gate", vec![placed("gate", 0.0, 0.0, 0.0)]));
        view.heard_poses("east", poses("dock", vec![placed("dock", 0.0, 0.0, 0.0)]));
        view.set_frame(BTreeMap::from([
            ("west".to_string(), Ok((Pose2::identity(), [0.0; 3], 0))),
            ("east".to_string(), Ok((pose2(20.0, 0.0, 0.0), [0.0; 3], 3))),
        ]));
        let room = polygon(&[(-5.0, -4.0), (5.0, -4.0), (5.0, 4.0), (-5.0, 4.0)]);
        let s = scan_270(&room, &Pose2::identity(), 0.5, 1_000_000_000);
        for (zone, unit) in [("west", "gate"), ("east", "dock")] {
            let payload =
                ViewPayload::of(SCAN_SCHEMA, "hall", zone, unit, &s, &Mount::default(), None);
            view.heard_scan(zone, payload);
        }
        view.fuse_map();
        let units = |view: &SiteView| {
            let mut ids: Vec<String> = view.fields_of_view().into_iter().map(|f| f.0).collect();
            ids.sort();
            ids
        };
        assert_eq!(units(&view), ["dock", "gate"]);
        view.liveliness("east", false);
        assert_eq!(units(&view), ["gate"]);
        view.fuse_map();
        assert!(view.occupancy().is_some());
        assert!(
            view.poses()
                .sensors
                .iter()
                .any(|s| s.id == "dock" && s.stale)
        );
    }
}
