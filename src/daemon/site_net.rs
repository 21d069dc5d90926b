//! The site daemon (`[site] role = "site"`): holds no sensors, joins the zones of a site on
//! Zenoh into one frame. It hosts the Zenoh router when it `listen`s (a small installation
//! needs no `zenohd`), follows each zone's liveliness and poses (`zone_net`'s keys), asks the
//! zones for their static views, places every zone in the anchor zone's frame
//! (`register::zones`), and serves the result: every sensor of every zone in the site frame on
//! its status socket, and `site_from_zone` of every zone under
//! `scanfuse/<site>/site/frame` (`scanfuse.site.frame/1`: `{"schema","site","anchor","t_ns",
//! "zones":[…]}`, each zone as the socket's `status.zones` has it), every second and at once
//! when it changes. Zones stay authoritative for their own sensors' relative poses: the site
//! daemon never re-places a sensor within its zone.
//!
//! A zone that is lost keeps its last poses, marked `stale`; when it returns, its poses and
//! views are taken afresh. A site daemon that restarts has nothing to restore: everything it
//! shows comes back from the zones within a second or two (their poses) and one join.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::config::{Config, SITE_KEY, ZenohConfig};
use super::protocol::Saved;
use super::protocol::{EventKind, Poses, SensorPose, Status, ZoneFrame, ZoneStatus};
use super::socket::{Publisher, Refused, StatusSource};
use super::zone_net::{
    POSES_SCHEMA, Placed as PlacedKey, ViewPayload, key, now_ns, placed_key, session_config,
    zone_taken,
};
use crate::geometry::{Pose2, pose2};
use crate::register::zones::{ZoneInput, ZoneParams, ZoneSensor, join_zones};
use crate::register::{RegisterParams, ScanModel};

/// The schema of the `site/frame` key's payload.
pub const FRAME_SCHEMA: &str = "scanfuse.site.frame/1";

/// How long a view query waits for a zone's replies.
const VIEWS_PATIENCE: Duration = Duration::from_secs(5);
/// What the zones publish must hold still this long before it is joined (a zone settling).
const SETTLE: Duration = Duration::from_secs(2);
/// A join is tried again this often while a zone with placed sensors is not placed (its
/// views fill in as the crowd moves on).
const RETRY: Duration = Duration::from_secs(30);
/// How often the site frame is published though nothing changed.
const EVERY: Duration = Duration::from_secs(1);

/// `site/frame`'s payload.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FramePayload {
    pub schema: String,
    pub site: String,
    /// The zone whose frame is the site's.
    pub anchor: String,
    pub t_ns: u64,
    pub zones: Vec<ZoneStatus>,
}

impl FramePayload {
    /// Reads a payload; refuses a schema this build does not know.
    pub fn parse(bytes: &[u8]) -> Result<FramePayload, String> {
        let f: FramePayload =
            serde_json::from_slice(bytes).map_err(|e| format!("not a site frame: {e}"))?;
        if f.schema != FRAME_SCHEMA {
            return Err(format!(
                "schema {:?}: this scanfuse reads {FRAME_SCHEMA}",
                f.schema
            ));
        }
        Ok(f)
    }
}

/// A zone's `poses` payload, as `zone_net` wraps it.
#[derive(Debug, Deserialize)]
struct PosesPayload {
    schema: String,
    zone: String,
    poses: Poses,
}

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
}

/// Where a zone stands in the site frame, or why it does not.
type Placed = Result<(Pose2, [f64; 3], usize), String>;

#[derive(Debug, Default)]
struct Zones {
    zones: BTreeMap<String, Zone>,
    frame: BTreeMap<String, Placed>,
}

/// The site daemon's state, served on the socket.
pub struct SiteView {
    site: String,
    anchor: String,
    started: Instant,
    zenoh: Mutex<String>,
    state: Mutex<Zones>,
    publisher: Publisher,
}

impl SiteView {
    /// The view of site `site` whose frame is zone `anchor`'s.
    pub fn new(site: &str, anchor: &str, publisher: Publisher) -> SiteView {
        SiteView {
            site: site.to_string(),
            anchor: anchor.to_string(),
            started: Instant::now(),
            zenoh: Mutex::new("opening its Zenoh session".into()),
            state: Mutex::new(Zones::default()),
            publisher,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Zones> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn announce(&self, kind: EventKind, message: String) {
        if kind == EventKind::Error {
            tracing::warn!(target: "scanfuse::event", "{message}");
        } else {
            tracing::info!(target: "scanfuse::event", "{message}");
        }
        self.publisher.announce(kind, None, message);
    }

    /// A zone's liveliness token came or went.
    fn liveliness(&self, zone: &str, alive: bool) {
        let changed = {
            let mut s = self.lock();
            let z = s.zones.entry(zone.to_string()).or_insert(Zone {
                alive: !alive,
                since: Instant::now(),
                poses: None,
                fresh: false,
            });
            let changed = z.alive != alive;
            if changed {
                z.alive = alive;
                z.since = Instant::now();
                z.fresh = false;
            }
            changed
        };
        if changed && alive {
            self.announce(EventKind::Connected, format!("zone {zone} is alive"));
        } else if changed {
            self.announce(
                EventKind::Disconnected,
                format!("zone {zone} is lost: its poses stay as last heard, marked stale"),
            );
        }
    }

    fn heard_poses(&self, zone: &str, poses: Poses) {
        let mut s = self.lock();
        let z = s.zones.entry(zone.to_string()).or_insert(Zone {
            alive: true,
            since: Instant::now(),
            poses: None,
            fresh: false,
        });
        z.poses = Some(poses);
        z.fresh = z.alive;
    }

    /// What a join depends on: the alive zones' placed sensors, to the cm and 0.1°.
    fn join_key(&self) -> Vec<(String, PlacedKey)> {
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

    /// Some alive zone with placed sensors is not placed in the site frame.
    fn someone_unplaced(&self) -> bool {
        let s = self.lock();
        s.zones.iter().any(|(id, z)| {
            z.alive && placed_sensors(z) > 0 && !matches!(s.frame.get(id), Some(Ok(_)))
        })
    }

    /// Takes a join's result. A zone the join did not see (lost meanwhile) keeps where it
    /// stood, as its poses do. Says what changed: a zone placed, moved by more than 1 cm or
    /// 0.1°, or newly unplaced and why.
    fn set_frame(&self, frame: BTreeMap<String, Placed>) {
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

    fn zone_statuses(&self) -> Vec<ZoneStatus> {
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
                    None => (None, Some("not joined yet".into())),
                };
                ZoneStatus {
                    zone: id.clone(),
                    alive: z.alive,
                    for_s: z.since.elapsed().as_secs_f64(),
                    sensors: z.poses.as_ref().map_or(0, |p| p.sensors.len()),
                    placed: placed_sensors(z),
                    site_from_zone,
                    reason,
                }
            })
            .collect()
    }
}

fn placed_sensors(z: &Zone) -> usize {
    z.poses
        .as_ref()
        .map_or(0, |p| p.sensors.iter().filter(|s| s.registered).count())
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
            sensors: Vec::new(),
            web: None,
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
                            _ => "not joined yet".into(),
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
        }
    }

    fn reregister(&self, sensor: &str) -> Result<String, Refused> {
        let zone = self.lock().zones.iter().find_map(|(id, z)| {
            z.poses
                .as_ref()
                .is_some_and(|p| p.sensors.iter().any(|s| s.id == sensor))
                .then(|| id.clone())
        });
        Err(Refused(match zone {
            Some(z) => {
                format!("this is the site daemon; {sensor} is zone {z}'s: ask zone {z}'s daemon")
            }
            None => format!("this is the site daemon, and no zone has a sensor {sensor}"),
        }))
    }

    fn save(&self) -> Result<Saved, Refused> {
        Err(Refused(
            "the site daemon saves nothing: the zones save their own poses, and it rebuilds the site frame from them"
                .into(),
        ))
    }
}

/// Runs the site daemon (`scanfuse run` with `[site] role = "site"`) until SIGTERM, SIGINT
/// or `duration`: the status socket and the Zenoh side. Events (zones alive, lost, placed)
/// go to the socket's watchers and to `events`, when given.
pub async fn run_site_daemon(
    config: Config,
    duration: Option<Duration>,
    events: Option<tokio::sync::mpsc::UnboundedSender<Arc<str>>>,
) -> Result<(), super::run::RunError> {
    use super::signals::{Request, Signals};
    use super::socket::{ServerOptions, StatusServer};
    use tokio::sync::watch;

    let publisher = Publisher::new(config.publish.watch_backlog);
    let view = Arc::new(SiteView::new(
        &config.site.name,
        &config.site.anchor,
        publisher.clone(),
    ));
    if let Some(tx) = events {
        let mut rx = publisher.subscribe_events();
        tokio::spawn(async move {
            while let Ok(line) = rx.recv().await {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
    }
    let server = StatusServer::bind(
        &config.site.socket,
        Arc::clone(&view),
        publisher.clone(),
        ServerOptions {
            socket_mode: config.site.socket_mode,
            max_clients: config.site.max_clients,
            ..ServerOptions::default()
        },
    )?;
    let (stop_tx, stop_rx) = watch::channel(false);
    let stopped = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let serving = tokio::spawn(server.run(stopped(stop_rx.clone())));
    let zenoh = config
        .zenoh
        .clone()
        .map(|z| tokio::spawn(run(Arc::clone(&view), z, stopped(stop_rx.clone()))));
    let mut signals = Signals::install()?;
    let deadline = async {
        match duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(deadline);
    loop {
        tokio::select! {
            request = signals.next() => match request {
                Request::Terminate => break,
                Request::Reload => view.announce(
                    EventKind::ConfigReloaded,
                    "a site daemon reads its config only at start: restart it to apply a change (the zones keep running)".into(),
                ),
            },
            _ = &mut deadline => break,
        }
    }
    let _ = stop_tx.send(true);
    if let Some(z) = zenoh {
        let _ = z.await;
    }
    let _ = serving.await;
    Ok(())
}

/// The site daemon's Zenoh session: a router when it listens (the zones connect to it), a
/// peer of another router otherwise.
fn site_session_config(cfg: &ZenohConfig) -> Result<zenoh::Config, String> {
    let mut c = session_config(cfg)?;
    if !cfg.listen.is_empty() {
        c.insert_json5("mode", "\"router\"")
            .map_err(|e| format!("Zenoh config mode = router: {e}"))?;
    }
    Ok(c)
}

/// The zone a key `scanfuse/<site>/<zone>/<leaf>` names.
fn zone_of(key: &str) -> Option<&str> {
    key.split('/').nth(2)
}

/// Runs the site daemon's Zenoh side until `stop` resolves.
pub async fn run(
    view: Arc<SiteView>,
    cfg: ZenohConfig,
    stop: impl std::future::Future<Output = ()>,
) {
    use zenoh::bytes::Encoding;
    use zenoh::sample::SampleKind;

    let site = view.site.clone();
    let refuse = |why: String| {
        let line = format!("the site daemon is not on Zenoh: {why}");
        *view.zenoh.lock().unwrap_or_else(|e| e.into_inner()) = line.clone();
        view.announce(EventKind::Error, line);
    };
    let config = match site_session_config(&cfg) {
        Ok(c) => c,
        Err(e) => return refuse(e),
    };
    let session = match zenoh::open(config).await {
        Ok(s) => s,
        Err(e) => return refuse(format!("the session did not open: {e}")),
    };
    let alive_key = key(&site, SITE_KEY, "alive");
    if zone_taken(&session, &alive_key, SITE_KEY).await.is_some() {
        return refuse("another site daemon already runs for this site".into());
    }
    let declared = async {
        let token = session.liveliness().declare_token(&alive_key).await?;
        let alive = session
            .liveliness()
            .declare_subscriber(key(&site, "*", "alive"))
            .history(true)
            .await?;
        let poses = session.declare_subscriber(key(&site, "*", "poses")).await?;
        let frame = session
            .declare_publisher(key(&site, SITE_KEY, "frame"))
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        Ok::<_, zenoh::Error>((token, alive, poses, frame))
    };
    let (token, alive, poses, frame_pub) = match declared.await {
        Ok(d) => d,
        Err(e) => return refuse(format!("its keys were not declared: {e}")),
    };
    let line = format!("{}; anchor zone {}", cfg.describe(&site), view.anchor);
    tracing::info!("{line}");
    *view.zenoh.lock().unwrap_or_else(|e| e.into_inner()) = line;

    let session = Arc::new(session);
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let mut published: Option<(Instant, Vec<ZoneStatus>)> = None;
    let mut seen: Option<(Instant, Vec<(String, PlacedKey)>)> = None;
    let mut joined: Option<(Instant, Vec<(String, PlacedKey)>)> = None;
    let mut joining: Option<tokio::task::JoinHandle<Option<BTreeMap<String, Placed>>>> = None;
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => break,
            sample = alive.recv_async() => {
                let Ok(sample) = sample else { break };
                if let Some(zone) = zone_of(sample.key_expr().as_str()).filter(|z| *z != SITE_KEY) {
                    view.liveliness(zone, sample.kind() == SampleKind::Put);
                }
                continue;
            }
            sample = poses.recv_async() => {
                let Ok(sample) = sample else { break };
                let bytes = sample.payload().to_bytes();
                match serde_json::from_slice::<PosesPayload>(&bytes) {
                    Ok(p) if p.schema == POSES_SCHEMA && zone_of(sample.key_expr().as_str()) == Some(p.zone.as_str()) => {
                        view.heard_poses(&p.zone, p.poses);
                    }
                    Ok(p) => tracing::warn!("{}: schema {:?} or zone {:?} not understood", sample.key_expr(), p.schema, p.zone),
                    Err(e) => tracing::warn!("{}: not a zone's poses: {e}", sample.key_expr()),
                }
                continue;
            }
            _ = tick.tick() => {}
        }
        // A join finished: its frame is the site's.
        if joining.as_ref().is_some_and(|j| j.is_finished())
            && let Some(j) = joining.take()
            && let Ok(Some(frame)) = j.await
        {
            view.set_frame(frame);
        }
        // A join starts when what the zones publish held still after a change, or again
        // after a while when a zone is still not placed.
        let now_key = view.join_key();
        if seen.as_ref().is_none_or(|(_, k)| *k != now_key) {
            seen = Some((Instant::now(), now_key.clone()));
        }
        let settled = seen.as_ref().is_some_and(|(at, _)| at.elapsed() >= SETTLE);
        let due = match &joined {
            None => true,
            Some((at, k)) => *k != now_key || (at.elapsed() >= RETRY && view.someone_unplaced()),
        };
        if settled && due && joining.is_none() && !now_key.is_empty() {
            joined = Some((Instant::now(), now_key));
            joining = Some(tokio::spawn(join(
                Arc::clone(&view),
                Arc::clone(&session),
                site.clone(),
            )));
        }
        let zones = view.zone_statuses();
        let same = |a: &[ZoneStatus], b: &[ZoneStatus]| {
            a.len() == b.len()
                && a.iter().zip(b).all(|(x, y)| {
                    (&x.zone, x.alive, x.placed, &x.site_from_zone, &x.reason)
                        == (&y.zone, y.alive, y.placed, &y.site_from_zone, &y.reason)
                })
        };
        let due = published
            .as_ref()
            .is_none_or(|(at, before)| at.elapsed() >= EVERY || !same(before, &zones));
        if due {
            let payload = FramePayload {
                schema: FRAME_SCHEMA.into(),
                site: site.clone(),
                anchor: view.anchor.clone(),
                t_ns: now_ns(),
                zones: zones.clone(),
            };
            match serde_json::to_vec(&payload) {
                Ok(bytes) => {
                    if let Err(e) = frame_pub.put(bytes).await {
                        tracing::warn!("publishing the site frame failed: {e}");
                    }
                }
                Err(e) => tracing::warn!("the site frame did not serialise: {e}"),
            }
            published = Some((Instant::now(), zones));
        }
    }
    if let Some(j) = joining {
        j.abort();
    }
    drop(token);
    if let Ok(session) = Arc::try_unwrap(session)
        && let Err(e) = session.close().await
    {
        tracing::warn!("closing the Zenoh session: {e}");
    }
}

/// Asks every alive zone for its views and joins the zones; `None` when nothing could be
/// asked.
async fn join(
    view: Arc<SiteView>,
    session: Arc<zenoh::Session>,
    site: String,
) -> Option<BTreeMap<String, Placed>> {
    let zones: Vec<(String, Poses)> = {
        let s = view.lock();
        s.zones
            .iter()
            .filter(|(_, z)| z.alive && z.fresh)
            .filter_map(|(id, z)| Some((id.clone(), z.poses.clone()?)))
            .collect()
    };
    if zones.is_empty() {
        return None;
    }
    // Per zone: its placed sensors (id, pose in the zone, σ) and the views it sent.
    type Heard = (String, Vec<(String, Pose2, [f64; 3])>, Vec<ViewPayload>);
    let mut inputs: Vec<Heard> = Vec::new();
    for (id, poses) in zones {
        let placed: Vec<(String, Pose2, [f64; 3])> = poses
            .sensors
            .iter()
            .filter_map(|s| zone_pose(s).map(|(p, sigma)| (s.id.clone(), p, sigma)))
            .collect();
        let views = if placed.is_empty() {
            Vec::new()
        } else {
            query_views(&session, &site, &id).await
        };
        inputs.push((id, placed, views));
    }
    let anchor_id = view.anchor.clone();
    tokio::task::spawn_blocking(move || {
        let params = RegisterParams::default();
        let mut asked: Vec<String> = Vec::new();
        let zones: Vec<ZoneInput> = inputs
            .into_iter()
            .map(|(id, placed, views)| {
                if views.is_empty() && !placed.is_empty() {
                    asked.push(id.clone());
                }
                let sensors = placed
                    .into_iter()
                    .filter_map(|(sensor, zone_from_sensor, sigma)| {
                        let v = views.iter().find(|v| v.sensor == sensor)?.clone().into_view();
                        Some(ZoneSensor {
                            model: ScanModel::from_scan(&v.view, v.geometry.as_ref(), &v.mount, &params),
                            id: sensor,
                            zone_from_sensor,
                            sigma,
                        })
                    })
                    .collect();
                ZoneInput { id, sensors }
            })
            .collect();
        let mut frame: BTreeMap<String, Placed> = BTreeMap::new();
        let Some(anchor) = zones.iter().position(|z| z.id == anchor_id) else {
            for z in &zones {
                frame.insert(
                    z.id.clone(),
                    Err(format!("the anchor zone {anchor_id} has not been heard from; the site frame is its frame")),
                );
            }
            return Some(frame);
        };
        let result = join_zones(&zones, anchor, &ZoneParams {
            register: params,
            ..ZoneParams::default()
        });
        for (z, placement) in zones.iter().zip(result.zones) {
            let placed = match placement.site_from_zone {
                Ok((pose, sigma)) => Ok((pose, sigma, placement.pairs)),
                Err(_) if z.sensors.is_empty() && asked.contains(&z.id) => Err(format!(
                    "zone {} sent no static views when asked (it may still be starting)",
                    z.id
                )),
                Err(_) if z.sensors.is_empty() => {
                    Err(format!("zone {} has no placed sensors yet", z.id))
                }
                Err(why) => Err(why),
            };
            frame.insert(z.id.clone(), placed);
        }
        Some(frame)
    })
    .await
    .ok()
    .flatten()
}

/// Every view zone `zone` serves (`view/*`); none when it does not answer.
async fn query_views(session: &zenoh::Session, site: &str, zone: &str) -> Vec<ViewPayload> {
    let replies = match session
        .get(key(site, zone, "view/*"))
        .timeout(VIEWS_PATIENCE)
        .await
    {
        Ok(r) => r,
        Err(e) => {
            tracing::warn!("asking zone {zone} for its views: {e}");
            return Vec::new();
        }
    };
    let mut views = Vec::new();
    while let Ok(reply) = replies.recv_async().await {
        let Ok(sample) = reply.result() else { continue };
        match ViewPayload::parse(&sample.payload().to_bytes()) {
            Ok(v) if v.zone == zone => views.push(v),
            Ok(v) => tracing::warn!("zone {zone} answered with zone {}'s view", v.zone),
            Err(e) => tracing::warn!("zone {zone}'s view: {e}"),
        }
    }
    views
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
        }
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

        // Lost: its poses stay, stale, through a join that no longer sees it.
        view.liveliness("east", false);
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
    fn a_frame_of_another_schema_is_refused() {
        let good = FramePayload {
            schema: FRAME_SCHEMA.into(),
            site: "hall".into(),
            anchor: "west".into(),
            t_ns: 1,
            zones: Vec::new(),
        };
        let bytes = serde_json::to_vec(&good).unwrap();
        assert_eq!(FramePayload::parse(&bytes), Ok(good));
        let other = String::from_utf8(bytes).unwrap().replace("/1", "/2");
        assert!(
            FramePayload::parse(other.as_bytes())
                .unwrap_err()
                .contains("schema")
        );
    }
}
