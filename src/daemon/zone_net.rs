//! A zone daemon on Zenoh (`[zenoh]`): one site spread over several machines, each daemon
//! holding one zone of it. This file owns the key space and what a zone puts there and
//! answers. The site daemon (`site_net`) joins the zones into one frame; a zone hears where it
//! puts it (`site/frame`) and says so on its status line.
//!
//! Under `scanfuse/<site>/<zone>/` (`<site>` the `[site] name`, `<zone>` the `[zenoh] zone`):
//! - `alive`: a liveliness token, held while the daemon runs. Zenoh withdraws it when the
//!   daemon stops, dies, or its link goes quiet for the lease (1 s here), so the others see
//!   a zone go within a second or two.
//! - `poses`: `{"schema":"scanfuse.zone.poses/1","site","zone","t_ns","poses":{…}}`, where
//!   `poses` is the status socket's `poses` reply (the same fields) in the zone's own frame
//!   (its anchor's), JSON (`application/json`), every second and within 0.25 s of a change.
//! - `status`: likewise `scanfuse.zone.status/1` with the socket's `status` reply, every
//!   second.
//! - `view/<sensor>`: a queryable, not a stream: each sensor's static view as registration
//!   sees it (through a crowd), `scanfuse.zone.view/1` ([`ViewPayload`]), for the site daemon
//!   to register sensors of different zones against each other. `view/*` asks for all.
//! - `detections` (opt-in: `[zenoh] detections = true`): `scanfuse.zone.detections/1`,
//!   `{…,"scans":[{"sensor","t_ns","people":[[x,y],…]}]}`, what each scan of the zone's placed
//!   sensors saw ([`Sightings`]: body centres in the zone's frame, m; a scan that saw no one
//!   is listed with none, so that the site daemon knows it looked), every 0.1 s. `t_ns` of a
//!   scan is its stamp on the zone's clock. The site daemon tracks people across zones from
//!   these.
//! - `scan/<sensor>` (opt-in: `[zenoh] scans_hz = 2`): each placed sensor's latest scan, at
//!   most that often, `scanfuse.zone.scan/1` (a view's fields: [`ViewPayload`]), for the
//!   site daemon's fused map.
//!
//! `t_ns` is the zone's wall clock (UNIX ns) when it published. The schema's number is its
//! major version: a reader refuses one it does not know.

use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::config::{SITE_KEY, ZenohConfig};
use super::pipeline::Pipeline;
use super::pipeline_register::StaticView;
use super::pipeline_track::Sightings;
use super::protocol::{Poses, Status};
use super::queue::WorkerEnd;
use super::site_net::FramePayload;
use crate::geometry::Mount;
use crate::scan::{Scan, ScanGeometry};

/// The schema of the `poses` key's payload.
pub const POSES_SCHEMA: &str = "scanfuse.zone.poses/1";
/// The schema of the `status` key's payload.
pub const STATUS_SCHEMA: &str = "scanfuse.zone.status/1";

/// The schema of the `detections` key's payload.
pub const DETECTIONS_SCHEMA: &str = "scanfuse.zone.detections/1";

/// The schema of a `view/<sensor>` reply.
pub const VIEW_SCHEMA: &str = "scanfuse.zone.view/1";
/// The schema of a `scan/<sensor>` sample: the same fields as a view, of a scan.
pub const SCAN_SCHEMA: &str = "scanfuse.zone.scan/1";

/// A `view/<sensor>` reply, or a `scan/<sensor>` sample: one sensor's static view (or latest
/// scan) and what turns it into points (`ScanModel::from_scan`), with its zone's names
/// around it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewPayload {
    pub schema: String,
    pub site: String,
    pub zone: String,
    pub sensor: String,
    /// The view's stamp (its newest scan's), UNIX ns.
    pub t_ns: u64,
    /// Height of the optical centre above the floor (m), when configured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height_m: Option<f64>,
    /// Pitch of the scan plane, positive up.
    pub pitch_deg: f64,
    pub start_angle_rad: f64,
    pub end_angle_rad: f64,
    /// Ranges in m; 0 means no return (JSON has no NaN).
    pub ranges_m: Vec<f32>,
    /// The unit's PP geometry, once it answered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<ScanGeometry>,
}

impl ViewPayload {
    pub fn new(site: &str, zone: &str, v: &StaticView) -> ViewPayload {
        ViewPayload::of(
            VIEW_SCHEMA,
            site,
            zone,
            &v.id,
            &v.view,
            &v.mount,
            v.geometry,
        )
    }

    /// Sensor `sensor`'s `scan` under `schema` (a view's or a scan's).
    pub fn of(
        schema: &str,
        site: &str,
        zone: &str,
        sensor: &str,
        scan: &Scan,
        mount: &Mount,
        geometry: Option<ScanGeometry>,
    ) -> ViewPayload {
        ViewPayload {
            schema: schema.to_string(),
            site: site.to_string(),
            zone: zone.to_string(),
            sensor: sensor.to_string(),
            t_ns: scan.stamp_ns,
            height_m: mount.height_m,
            pitch_deg: mount.pitch_rad.to_degrees(),
            start_angle_rad: scan.start_angle_rad,
            end_angle_rad: scan.end_angle_rad,
            ranges_m: scan
                .ranges_m
                .iter()
                .map(|r| if r.is_finite() { *r } else { 0.0 })
                .collect(),
            geometry,
        }
    }

    /// Reads a view reply; refuses a schema this build does not know.
    pub fn parse(bytes: &[u8]) -> Result<ViewPayload, String> {
        ViewPayload::parse_as(bytes, VIEW_SCHEMA)
    }

    /// Reads a payload of `schema` (`VIEW_SCHEMA`, `SCAN_SCHEMA`); refuses another, and
    /// ranges that are not ranges.
    pub fn parse_as(bytes: &[u8], schema: &str) -> Result<ViewPayload, String> {
        let v: ViewPayload =
            serde_json::from_slice(bytes).map_err(|e| format!("not a sensor's scan: {e}"))?;
        if v.schema != schema {
            return Err(format!(
                "schema {:?}: this scanfuse reads {schema} here",
                v.schema
            ));
        }
        let angles = [v.start_angle_rad, v.end_angle_rad, v.pitch_deg];
        if !(2..=MAX_BEAMS).contains(&v.ranges_m.len())
            || angles.iter().any(|a| !a.is_finite())
            || v.end_angle_rad <= v.start_angle_rad
            || v.ranges_m.iter().any(|r| !r.is_finite() || *r < 0.0)
        {
            return Err(format!(
                "sensor {}'s scan holds no valid beams (angles {:.3}..{:.3} rad, {} ranges)",
                v.sensor,
                v.start_angle_rad,
                v.end_angle_rad,
                v.ranges_m.len()
            ));
        }
        Ok(v)
    }

    /// The view as the scan, mount and geometry it came from.
    pub fn into_view(self) -> StaticView {
        StaticView {
            id: self.sensor,
            view: Scan {
                stamp_ns: self.t_ns,
                sensor_stamp_ms: None,
                start_angle_rad: self.start_angle_rad,
                end_angle_rad: self.end_angle_rad,
                ranges_m: self.ranges_m,
                intensities: Vec::new(),
            },
            mount: Mount {
                height_m: self.height_m,
                pitch_rad: self.pitch_deg.to_radians(),
            },
            geometry: self.geometry,
        }
    }
}

/// No scanner has more beams than this (a UTM-30LX-EW has 1,081).
const MAX_BEAMS: usize = 20_000;

/// How long a starting zone asks whether its zone is already held.
const TAKEN_PATIENCE: Duration = Duration::from_millis(1200);

/// How long a query waits for the registration worker's views.
const VIEWS_PATIENCE: Duration = Duration::from_secs(2);

/// Zenoh's link lease (ms): a peer silent this long is gone, its tokens withdrawn.
const LEASE_MS: u64 = 1000;
/// How often poses are looked at for a change.
const LOOK: Duration = Duration::from_millis(250);
/// How often the detections gathered are sent (what the site daemon's tracks lag by, at
/// most, beyond the link).
const DETECTIONS_EVERY: Duration = Duration::from_millis(100);
/// How often everything is published even when nothing changed (a daemon that starts later
/// has it within this).
const EVERY: Duration = Duration::from_secs(1);
/// The site daemon publishes its frame every second; this long without one, it is gone
/// or cut off.
const SITE_SILENT: Duration = Duration::from_secs(3);

/// The key of `leaf` (`alive`, `poses`, `status`) of `zone` of `site`.
pub fn key(site: &str, zone: &str, leaf: &str) -> String {
    format!("scanfuse/{site}/{zone}/{leaf}")
}

/// One payload: a schema-named wrapper around a socket reply.
#[derive(Debug, Serialize)]
struct Wrapped<'a> {
    schema: &'static str,
    site: &'a str,
    zone: &'a str,
    t_ns: u64,
    #[serde(flatten)]
    body: Body<'a>,
}

/// What a payload carries, under its own key (`poses`, `status` or `scans`).
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum Body<'a> {
    Poses { poses: &'a Poses },
    Status { status: &'a Status },
    Detections { scans: &'a [Sightings] },
}

/// Each sensor: id, registered, pose in mm and thousandths of a degree.
pub(super) type Placed = Vec<(String, bool, [i64; 3])>;

/// What of the poses counts as a change worth publishing at once: who is placed, and where
/// to the millimetre and the thousandth of a degree (not the ages that tick every second).
pub(super) fn placed_key(poses: &Poses) -> Placed {
    let q = |v: Option<f64>, per: f64| v.map_or(i64::MIN, |v| (v * per).round() as i64);
    poses
        .sensors
        .iter()
        .map(|s| {
            (
                s.id.clone(),
                s.registered,
                [q(s.x_m, 1e3), q(s.y_m, 1e3), q(s.yaw_deg, 1e3)],
            )
        })
        .collect()
}

pub(super) fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The Zenoh session config: peer mode, the endpoints given, no multicast scouting, a short
/// lease.
pub(super) fn session_config(cfg: &ZenohConfig) -> Result<zenoh::Config, String> {
    let list = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    // A peer that listens nowhere never has its liveliness queries answered (zenoh 1.10: seen
    // with eclipse-zenoh's peer too), so one not told where listens on loopback only.
    let listen = if cfg.listen.is_empty() {
        vec!["tcp/127.0.0.1:0".to_string()]
    } else {
        cfg.listen.clone()
    };
    let mut c = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_string()),
        ("scouting/multicast/enabled", "false".to_string()),
        ("connect/endpoints", list(&cfg.connect)),
        ("listen/endpoints", list(&listen)),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
        ("transport/link/tx/keep_alive", "4".to_string()),
    ] {
        c.insert_json5(key, &value)
            .map_err(|e| format!("Zenoh config {key} = {value}: {e}"))?;
    }
    Ok(c)
}

/// Runs the zone until `stop` resolves: holds its liveliness token and publishes its poses
/// and status. A session that cannot open (an endpoint taken, say) is an error on the log,
/// the socket and the terminal, and the daemon goes on serving its sensors without it.
pub async fn run(
    pipeline: Arc<Pipeline>,
    cfg: ZenohConfig,
    site: String,
    sightings: Option<WorkerEnd<Sightings>>,
    stop: impl std::future::Future<Output = ()>,
) {
    use super::protocol::EventKind;
    use super::socket::StatusSource;
    use zenoh::bytes::Encoding;

    let refuse = |why: String| {
        let line = format!("zone {} is not on Zenoh: {why}", cfg.zone);
        pipeline.set_zenoh(line.clone());
        pipeline.announce(EventKind::Error, None, line);
    };
    let config = match session_config(&cfg) {
        Ok(c) => c,
        Err(e) => return refuse(e),
    };
    let session = match zenoh::open(config).await {
        Ok(s) => s,
        Err(e) => return refuse(format!("the session did not open: {e}")),
    };
    let (alive, poses_key, status_key) = (
        key(&site, &cfg.zone, "alive"),
        key(&site, &cfg.zone, "poses"),
        key(&site, &cfg.zone, "status"),
    );
    // Two daemons holding one zone would publish two frames under one key: the second refuses.
    if let Some(why) = zone_taken(&session, &alive, &cfg.zone).await {
        return refuse(why);
    }
    let token = match session.liveliness().declare_token(&alive).await {
        Ok(t) => t,
        Err(e) => return refuse(format!("{alive} was not declared: {e}")),
    };
    let publishers = async {
        let poses = session
            .declare_publisher(poses_key.clone())
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        let status = session
            .declare_publisher(status_key.clone())
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        Ok::<_, zenoh::Error>((poses, status))
    };
    let (poses_pub, status_pub) = match publishers.await {
        Ok(p) => p,
        Err(e) => return refuse(format!("its publishers were not declared: {e}")),
    };
    let detections_key = key(&site, &cfg.zone, "detections");
    let detections = match &sightings {
        Some(rx) => match session
            .declare_publisher(detections_key.clone())
            .encoding(Encoding::APPLICATION_JSON)
            .await
        {
            Ok(p) => Some((rx, p)),
            Err(e) => return refuse(format!("{detections_key} was not declared: {e}")),
        },
        None => None,
    };
    let mut send = tokio::time::interval(DETECTIONS_EVERY);
    let mut scans =
        tokio::time::interval(Duration::from_secs_f64(1.0 / cfg.scans_hz.unwrap_or(1.0)));
    // Each sensor's newest scan sent, so that a scan is sent once.
    let mut sent: std::collections::BTreeMap<String, u64> = Default::default();
    let views_key = key(&site, &cfg.zone, "view/*");
    let views = match session.declare_queryable(views_key.clone()).await {
        Ok(q) => q,
        Err(e) => return refuse(format!("{views_key} was not declared: {e}")),
    };
    // Where the site daemon puts this zone, said on its status line.
    let frames = match session
        .declare_subscriber(key(&site, SITE_KEY, "frame"))
        .await
    {
        Ok(s) => s,
        Err(e) => return refuse(format!("the site frame was not subscribed to: {e}")),
    };
    pipeline.want_views();
    let described = cfg.describe(&site);
    tracing::info!("{described}");
    pipeline.set_zenoh(described.clone());
    // What the site daemon last said of this zone, and when it was heard.
    let mut in_site: Option<(String, std::time::Instant)> = None;
    let mut look = tokio::time::interval(LOOK);
    let mut last: Option<(std::time::Instant, Placed)> = None;
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => break,
            _ = look.tick() => {}
            _ = scans.tick(), if cfg.scans_hz.is_some() => {
                for posed in pipeline.posed_scans() {
                    if sent.get(&posed.id).is_some_and(|t| *t >= posed.scan.stamp_ns) {
                        continue;
                    }
                    sent.insert(posed.id.clone(), posed.scan.stamp_ns);
                    let payload = ViewPayload::of(
                        SCAN_SCHEMA,
                        &site,
                        &cfg.zone,
                        &posed.id,
                        &posed.scan,
                        &posed.mount,
                        posed.geometry,
                    );
                    let k = key(&site, &cfg.zone, &format!("scan/{}", posed.id));
                    let put = match serde_json::to_vec(&payload) {
                        Ok(bytes) => session.put(&k, bytes).encoding(Encoding::APPLICATION_JSON).await,
                        Err(e) => {
                            tracing::warn!("{k} did not serialise: {e}");
                            continue;
                        }
                    };
                    if let Err(e) = put {
                        tracing::warn!("publishing {k} failed: {e}");
                    }
                }
                continue;
            }
            _ = send.tick(), if detections.is_some() => {
                if let Some((rx, publisher)) = &detections {
                    let scans: Vec<Sightings> = std::iter::from_fn(|| rx.try_recv().ok()).collect();
                    if scans.is_empty() {
                        continue;
                    }
                    let payload = serde_json::to_vec(&Wrapped {
                        schema: DETECTIONS_SCHEMA,
                        site: &site,
                        zone: &cfg.zone,
                        t_ns: now_ns(),
                        body: Body::Detections { scans: &scans },
                    });
                    match payload {
                        Ok(bytes) => {
                            if let Err(e) = publisher.put(bytes).await {
                                tracing::warn!("publishing {detections_key} failed: {e}");
                            }
                        }
                        Err(e) => tracing::warn!("the zone's detections did not serialise: {e}"),
                    }
                }
                continue;
            }
            sample = frames.recv_async() => {
                let Ok(sample) = sample else { break };
                let said = match FramePayload::parse(&sample.payload().to_bytes()) {
                    Ok(frame) => {
                        let mine = frame.zones.iter().find(|z| z.zone == cfg.zone);
                        pipeline.set_site_from_zone(mine.and_then(|z| z.site_from_zone));
                        in_site_frame(&frame, &cfg.zone)
                    }
                    Err(e) => format!("the site daemon's frame is unreadable: {e}"),
                };
                // Said again when it changed, or after a silence the line has told of.
                let stale = in_site.as_ref().is_none_or(|(before, at)| {
                    *before != said || at.elapsed() >= SITE_SILENT
                });
                if stale {
                    pipeline.set_zenoh(format!("{described}; {said}"));
                }
                in_site = Some((said, std::time::Instant::now()));
                continue;
            }
            query = views.recv_async() => {
                match query {
                    // Off the loop: the worker may take a moment, and the poses go on.
                    Ok(query) => {
                        tokio::spawn(answer_views(
                            Arc::clone(&pipeline),
                            site.clone(),
                            cfg.zone.clone(),
                            query,
                        ));
                    }
                    // Only a closed session ends it: nothing more can be published either.
                    Err(e) => {
                        tracing::warn!("the views queryable ended: {e}");
                        break;
                    }
                }
                continue;
            }
        }
        // The site daemon speaks every second: once it has not for a while, what it last
        // said is no longer so, and the line says so.
        if let Some((said, at)) = &in_site
            && at.elapsed() >= SITE_SILENT
        {
            pipeline.set_zenoh(format!(
                "{described}; the site daemon has not been heard for {:.0} s (it had said: {said})",
                at.elapsed().as_secs_f64()
            ));
        }
        // What crosses is the zone's own frame: the site daemon knows where it put it.
        let poses = Poses {
            site_from_zone: None,
            ..pipeline.poses()
        };
        let placed = placed_key(&poses);
        let due = last
            .as_ref()
            .is_none_or(|(at, before)| at.elapsed() >= EVERY || *before != placed);
        if !due {
            continue;
        }
        let t_ns = now_ns();
        let status = pipeline.status();
        let wrap = |schema, body| {
            serde_json::to_vec(&Wrapped {
                schema,
                site: &site,
                zone: &cfg.zone,
                t_ns,
                body,
            })
        };
        let payloads = (
            wrap(POSES_SCHEMA, Body::Poses { poses: &poses }),
            wrap(STATUS_SCHEMA, Body::Status { status: &status }),
        );
        let (Ok(p), Ok(s)) = payloads else {
            tracing::warn!("the zone's poses or status did not serialise");
            continue;
        };
        if let Err(e) = poses_pub.put(p).await {
            tracing::warn!("publishing {poses_key} failed: {e}");
        }
        if let Err(e) = status_pub.put(s).await {
            tracing::warn!("publishing {status_key} failed: {e}");
        }
        last = Some((std::time::Instant::now(), placed));
    }
    // Withdrawn on purpose, so the others see the zone leave at once rather than at the lease.
    drop(token);
    if let Err(e) = session.close().await {
        tracing::warn!("closing the Zenoh session: {e}");
    }
}

/// Where the site daemon's `frame` puts `zone`, as a clause of the status line.
fn in_site_frame(frame: &FramePayload, zone: &str) -> String {
    match frame.zones.iter().find(|z| z.zone == zone) {
        Some(z) => match (&z.site_from_zone, &z.reason) {
            (Some(_), _) if z.zone == frame.anchor => {
                "the site frame's anchor zone: its frame is the site's".to_string()
            }
            (Some(f), _) => format!(
                "in the site frame (zone {}'s) at ({:.3} m, {:.3} m, {:.2}°), σ ({:.3} m, {:.3} m, {:.2}°), from {} pairs across zones",
                frame.anchor,
                f.x_m,
                f.y_m,
                f.yaw_deg,
                f.sigma_x_m,
                f.sigma_y_m,
                f.sigma_yaw_deg,
                f.pairs
            ),
            (None, Some(why)) => format!("not placed in the site frame: {why}"),
            (None, None) => "not placed in the site frame yet".to_string(),
        },
        None => "the site daemon has not heard this zone yet".to_string(),
    }
}

/// Why this daemon may not hold `zone`: another's token is already at `alive`. Asked a few
/// times over `TAKEN_PATIENCE`: a peer's routes settle some 0.1–0.2 s after its session opens,
/// and a query before then reaches no one. Nobody reachable at all: it cannot know, and holds it.
pub(super) async fn zone_taken(
    session: &zenoh::Session,
    alive: &str,
    zone: &str,
) -> Option<String> {
    const TRIES: u32 = 4;
    for _ in 0..TRIES {
        let replies = match session
            .liveliness()
            .get(alive)
            .timeout(TAKEN_PATIENCE / TRIES)
            .await
        {
            Ok(r) => r,
            Err(e) => return Some(format!("could not ask whether zone {zone} is taken: {e}")),
        };
        let started = tokio::time::Instant::now();
        while let Ok(reply) = replies.recv_async().await {
            if reply.result().is_ok() {
                return Some(format!(
                    "another daemon already holds zone {zone} of this site; give each daemon its own [zenoh] zone"
                ));
            }
        }
        tokio::time::sleep_until(started + TAKEN_PATIENCE / TRIES).await;
    }
    None
}

/// Answers a query on `view/…` with each sensor's view whose key it matches.
async fn answer_views(
    pipeline: Arc<Pipeline>,
    site: String,
    zone: String,
    query: zenoh::query::Query,
) {
    use zenoh::bytes::Encoding;
    use zenoh::key_expr::KeyExpr;

    let views = tokio::task::spawn_blocking(move || pipeline.static_views(VIEWS_PATIENCE))
        .await
        .unwrap_or_default();
    let (site, zone) = (site.as_str(), zone.as_str());
    for v in &views {
        let Ok(k) = KeyExpr::try_from(key(site, zone, &format!("view/{}", v.id))) else {
            continue;
        };
        if !query.key_expr().intersects(&k) {
            continue;
        }
        let Ok(bytes) = serde_json::to_vec(&ViewPayload::new(site, zone, v)) else {
            continue;
        };
        if let Err(e) = query
            .reply(k, bytes)
            .encoding(Encoding::APPLICATION_JSON)
            .await
        {
            tracing::warn!("replying with {}'s view failed: {e}", v.id);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::SensorPose;

    #[test]
    fn a_change_is_who_is_placed_and_where_not_the_clock() {
        let mut a = SensorPose::unregistered("a", "waiting");
        let b = SensorPose::unregistered("b", "waiting");
        let poses = |a: &SensorPose| Poses {
            anchor: "a".into(),
            sensors: vec![a.clone(), b.clone()],
            building_from_site: None,
            site_from_zone: None,
        };
        let before = placed_key(&poses(&a));
        assert_eq!(before, placed_key(&poses(&a)));
        a.registered = true;
        (a.x_m, a.y_m, a.yaw_deg) = (Some(1.0), Some(2.0), Some(30.0));
        let placed = placed_key(&poses(&a));
        assert_ne!(before, placed);
        a.x_m = Some(1.0004);
        assert_eq!(placed, placed_key(&poses(&a)), "under a millimetre");
        a.x_m = Some(1.002);
        assert_ne!(placed, placed_key(&poses(&a)));
        assert_eq!(key("hall", "east", "poses"), "scanfuse/hall/east/poses");
    }

    /// A view read back is the view that was sent: the same points (a return lost to NaN
    /// stays no return), and a schema this build does not know is refused.
    #[test]
    fn a_view_reply_reads_back_as_the_view() {
        let mut ranges: Vec<f32> = (0..541).map(|k| 2.0 + (k % 37) as f32 * 0.1).collect();
        ranges[7] = f32::NAN;
        let sent = StaticView {
            id: "gate".into(),
            view: Scan {
                stamp_ns: 1_700_000_000_000_000_000,
                sensor_stamp_ms: Some(5),
                start_angle_rad: -2.356,
                end_angle_rad: 2.356,
                ranges_m: ranges,
                intensities: Vec::new(),
            },
            mount: Mount {
                height_m: Some(1.1),
                pitch_rad: -0.1,
            },
            geometry: None,
        };
        let bytes = serde_json::to_vec(&ViewPayload::new("hall", "east", &sent)).unwrap();
        let got = ViewPayload::parse(&bytes).unwrap();
        assert_eq!((got.zone.as_str(), got.sensor.as_str()), ("east", "gate"));
        let back = got.into_view();
        let p = crate::register::RegisterParams::default();
        let model = |v: &StaticView| {
            crate::register::ScanModel::from_scan(&v.view, v.geometry.as_ref(), &v.mount, &p)
        };
        // The pitch goes through degrees: the same points to well under a micrometre.
        let (b, s) = (model(&back), model(&sent));
        assert_eq!(b.points().len(), s.points().len());
        assert!(!s.points().is_empty());
        for (q, r) in b.points().iter().zip(s.points()) {
            assert!((q - r).norm() < 1e-9, "{q} vs {r}");
        }
        assert!((back.mount.pitch_rad - sent.mount.pitch_rad).abs() < 1e-12);
        let other = String::from_utf8(bytes)
            .unwrap()
            .replace(VIEW_SCHEMA, "scanfuse.zone.view/2");
        let why = ViewPayload::parse(other.as_bytes()).unwrap_err();
        assert!(why.contains("view/2"), "{why}");
        // A scan sample has a view's fields under its own schema; neither stands in for the
        // other, and beams that cannot be beams are refused.
        let scan = ViewPayload::of(
            SCAN_SCHEMA,
            "hall",
            "east",
            "gate",
            &sent.view,
            &sent.mount,
            None,
        );
        let bytes = serde_json::to_vec(&scan).unwrap();
        assert_eq!(ViewPayload::parse_as(&bytes, SCAN_SCHEMA), Ok(scan.clone()));
        assert!(
            ViewPayload::parse(&bytes)
                .unwrap_err()
                .contains("zone.scan/1")
        );
        for bad in [
            ViewPayload {
                end_angle_rad: scan.start_angle_rad,
                ..scan.clone()
            },
            ViewPayload {
                ranges_m: vec![-1.0; 10],
                ..scan.clone()
            },
            ViewPayload {
                ranges_m: vec![1.0; MAX_BEAMS + 1],
                ..scan.clone()
            },
        ] {
            let why =
                ViewPayload::parse_as(&serde_json::to_vec(&bad).unwrap(), SCAN_SCHEMA).unwrap_err();
            assert!(why.contains("no valid beams"), "{why}");
        }
    }
}
