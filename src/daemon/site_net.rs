//! The site daemon (`[site] role = "site"`) on the network: holds no sensors, joins the zones
//! of a site on Zenoh into one frame (what it knows and shows: `site_view`). It hosts the Zenoh router when it `listen`s (a small installation
//! needs no `zenohd`), follows each zone's liveliness and poses (`zone_net`'s keys), asks the
//! zones for their static views, places every zone in the anchor zone's frame
//! (`register::zones`), and serves the result: every sensor of every zone in the site frame on
//! its status socket, and `site_from_zone` of every zone under
//! `scanfuse/<site>/site/frame` (`scanfuse.site.frame/1`: `{"schema","site","anchor","t_ns",
//! "zones":[…]}`, each zone as the socket's `status.zones` has it), every second and at once
//! when it changes. Zones stay authoritative for their own sensors' relative poses: the site
//! daemon never re-places a sensor within its zone.
//!
//! Zones that send their detections (`[zenoh] detections = true`) are tracked as one site:
//! their sightings, moved into the site frame (`site_tracks`), feed one tracker whose `TRACKS`
//! (and zones, lines, OSC, MQTT, as the site file has them) the site daemon serves as a zone
//! daemon serves its own.
//!
//! A zone that is lost keeps its last poses, marked `stale`; when it returns, its poses and
//! views are taken afresh. A site daemon that restarts has nothing to restore: everything it
//! shows comes back from the zones within a second or two (their poses) and one join.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::config::{Config, SITE_KEY, ZenohConfig};
use super::pipeline_track::{Sightings, TrackIn, TrackerTask, track_queue_len};
use super::protocol::{EventKind, Poses, Status, ZoneStatus};
use super::queue::DropOldestSender;
use super::site_tracks::CrossZone;
use super::site_view::{Heard, KeptPair, Placed, SiteView, join_frame};
use super::socket::Publisher;
use super::zone_net::{
    DETECTIONS_SCHEMA, POSES_SCHEMA, Placed as PlacedKey, SCAN_SCHEMA, STATUS_SCHEMA, ViewPayload,
    key, now_ns, session_config, zone_taken,
};

/// The schema of the `site/frame` key's payload.
pub const FRAME_SCHEMA: &str = "scanfuse.site.frame/1";

/// How long a view query waits for a zone's replies.
const VIEWS_PATIENCE: Duration = Duration::from_secs(5);
/// What the zones publish must hold still this long before it is joined (a zone settling).
const SETTLE: Duration = Duration::from_secs(2);
/// A join is tried again this often while a zone with placed sensors is not placed (its
/// views fill in as the crowd moves on).
const RETRY: Duration = Duration::from_secs(30);
/// Once placed, the zones are joined again this often, `REFINES` times, on the views of
/// later moments: each link averages its pairs over them (one moment's views, through a
/// crowd, put a unit a few cm off), until what the zones publish changes.
const REFINE_EVERY: Duration = Duration::from_secs(5);
const REFINES: usize = 4;
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

/// A zone's `poses`, `status` or `detections` payload, as `zone_net` wraps them.
#[derive(Debug, Deserialize)]
struct ZonePayload {
    schema: String,
    zone: String,
    /// The zone's wall clock when it published (UNIX ns).
    t_ns: u64,
    poses: Option<Poses>,
    status: Option<Status>,
    scans: Option<Vec<Sightings>>,
}

/// The site's tracker queue holds this many sightings: a quarter second of 400 sensors.
const SITE_TRACK_SENSORS: usize = 400;

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
    let view = Arc::new(
        SiteView::new(&config.site.name, &config.site.anchor, publisher.clone())
            .with_map(&config.publish, &config.site.state_dir)
            .with_surveys(&config.surveys),
    );
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
        ServerOptions::of(&config.site),
    )?;
    let (stop_tx, stop_rx) = watch::channel(false);
    let stopped = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let serving = tokio::spawn(server.run(stopped(stop_rx.clone())));
    // One tracker for the whole site, fed by the zones that send their detections.
    let (tracker_queue, tracker) = if config.track.enabled {
        let (queue, task) = TrackerTask::start(
            publisher.clone(),
            config.track.params(),
            None,
            track_queue_len(SITE_TRACK_SENSORS),
        )?;
        (Some(queue), Some(task))
    } else {
        (None, None)
    };
    if super::people_out::wanted(&config.people) {
        // No drawing at the site daemon: zones and lines are in the site frame.
        let (_keep, building) = tokio::sync::watch::channel(None);
        tokio::spawn(super::people_out::run(
            config.people.clone(),
            config.site.name.clone(),
            publisher.clone(),
            building,
            stopped(stop_rx.clone()),
        ));
    }
    let page = start_page(&config, &view, &publisher, &stop_rx).await;
    let zenoh = config.zenoh.clone().map(|z| {
        tokio::spawn(run(
            Arc::clone(&view),
            z,
            tracker_queue,
            stopped(stop_rx.clone()),
        ))
    });
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
    if let Some(p) = page {
        let _ = p.await;
    }
    if let Some(t) = tracker {
        t.stop();
    }
    // The map as it stood, when there is one (the zones save their own poses).
    view.fuse_map();
    match view.save_map() {
        Ok(saved) => tracing::info!("saved {} in {}", saved.files.join(", "), saved.dir),
        Err(why) => tracing::info!("no map saved: {}", why.0),
    }
    Ok(())
}

/// Serves the site daemon's page when `[web] listen` asks for it (as a zone daemon's: the
/// default is 127.0.0.1:8080). One that cannot start is an error on the socket and the log,
/// and the site daemon goes on without it.
async fn start_page(
    config: &Config,
    view: &Arc<SiteView>,
    publisher: &Publisher,
    stop: &tokio::sync::watch::Receiver<bool>,
) -> Option<tokio::task::JoinHandle<()>> {
    let source: Arc<dyn crate::web::PageSource> = Arc::clone(view) as _;
    super::run::serve_page(&config.web, source, publisher, stop, |kind, line| {
        view.set_web(line.clone());
        view.announce(kind, line);
    })
    .await
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

/// The cross pairs the site's links were made of since what the zones publish last changed,
/// and how many joins made them: what a refining join registers again.
#[derive(Default)]
struct Links {
    pairs: Vec<KeptPair>,
    joins: usize,
}

/// Runs the site daemon's Zenoh side until `stop` resolves.
pub async fn run(
    view: Arc<SiteView>,
    cfg: ZenohConfig,
    tracker: Option<DropOldestSender<TrackIn>>,
    stop: impl std::future::Future<Output = ()>,
) {
    use zenoh::bytes::Encoding;
    use zenoh::sample::SampleKind;

    let site = view.site.clone();
    let refuse = |why: String| {
        let line = format!("the site daemon is not on Zenoh: {why}");
        view.set_zenoh(line.clone());
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
        let statuses = session
            .declare_subscriber(key(&site, "*", "status"))
            .await?;
        let detections = session
            .declare_subscriber(key(&site, "*", "detections"))
            .await?;
        let scans = session
            .declare_subscriber(key(&site, "*", "scan/*"))
            .await?;
        let frame = session
            .declare_publisher(key(&site, SITE_KEY, "frame"))
            .encoding(Encoding::APPLICATION_JSON)
            .await?;
        Ok::<_, zenoh::Error>((token, alive, poses, statuses, detections, scans, frame))
    };
    let (token, alive, poses, statuses, detections, scans, frame_pub) = match declared.await {
        Ok(d) => d,
        Err(e) => return refuse(format!("its keys were not declared: {e}")),
    };
    let line = format!("{}; anchor zone {}", cfg.describe(&site), view.anchor);
    tracing::info!("{line}");
    view.set_zenoh(line);

    let session = Arc::new(session);
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    let mut published: Option<(Instant, Vec<ZoneStatus>)> = None;
    let mut seen: Option<(Instant, Vec<(String, PlacedKey)>)> = None;
    let mut joined: Option<(Instant, Vec<(String, PlacedKey)>)> = None;
    // The join running, and whether it refines the links the site stands on.
    let mut joining: Option<Joining> = None;
    let mut links = Links::default();
    let mut cross = CrossZone::default();
    let mut fused = Instant::now();
    let mut fusing: Option<tokio::task::JoinHandle<()>> = None;
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => break,
            sample = alive.recv_async() => {
                let Ok(sample) = sample else { break };
                if let Some(zone) = zone_of(sample.key_expr().as_str()).filter(|z| *z != SITE_KEY) {
                    let alive = sample.kind() == SampleKind::Put;
                    view.liveliness(zone, alive);
                    if !alive {
                        cross.lost(zone);
                    }
                }
                continue;
            }
            sample = poses.recv_async() => {
                let Ok(sample) = sample else { break };
                heard(&view, &sample);
                continue;
            }
            sample = statuses.recv_async() => {
                let Ok(sample) = sample else { break };
                heard(&view, &sample);
                continue;
            }
            sample = detections.recv_async() => {
                let Ok(sample) = sample else { break };
                if let (Some((zone, scans)), Some(queue)) = (heard(&view, &sample), &tracker) {
                    let pose = view.site_from_zone_for_tracks(&zone);
                    for s in cross.take(&zone, pose.as_ref(), scans) {
                        // A full queue drops the oldest: the tracker never holds up the zones.
                        let _ = queue.push(TrackIn::Sighted(s));
                    }
                }
                continue;
            }
            sample = scans.recv_async() => {
                let Ok(sample) = sample else { break };
                heard_scan(&view, &sample);
                continue;
            }
            _ = tick.tick() => {}
        }
        // Fusing a large site's map takes a while: off the loop that hears the zones, one at
        // a time.
        if fused.elapsed() >= EVERY && fusing.as_ref().is_none_or(|f| f.is_finished()) {
            fused = Instant::now();
            let view = view.clone();
            fusing = Some(tokio::task::spawn_blocking(move || view.fuse_map()));
        }
        // A join finished: its frame is the site's.
        if joining.as_ref().is_some_and(|j| j.task.is_finished())
            && let Some(j) = joining.take()
            && let Ok(Some((frame, pairs))) = j.task.await
        {
            if j.again {
                view.refine_frame(frame);
            } else {
                view.join_afresh(frame, &j.holding);
            }
            view.say_unused_surveys();
            links = Links {
                pairs,
                joins: links.joins + 1,
            };
        }
        // A join starts when what the zones publish held still after a change, again after a
        // while when a zone is still not placed, and `REFINES` times after a change to
        // average the links over later moments.
        let now_key = view.join_key();
        if seen.as_ref().is_none_or(|(_, k)| *k != now_key) {
            seen = Some((Instant::now(), now_key.clone()));
        }
        let settled = seen.as_ref().is_some_and(|(at, _)| at.elapsed() >= SETTLE);
        let changed = joined.as_ref().is_some_and(|(_, k)| *k != now_key);
        let retry =
            joined.as_ref().is_some_and(|(at, _)| at.elapsed() >= RETRY) && view.someone_unplaced();
        let refine = joined
            .as_ref()
            .is_some_and(|(at, _)| at.elapsed() >= REFINE_EVERY && links.joins <= REFINES);
        let due = joined.is_none() || changed || retry || refine;
        if settled && due && joining.is_none() && !now_key.is_empty() {
            if changed {
                // A zone's own poses changed: what its pairs said before may no longer hold.
                links = Links::default();
            }
            // Refining registers again only the pairs that linked; a full join looks for more.
            let again = refine && !changed && !retry && !links.pairs.is_empty();
            // The zones whose frame still holds since the last join, and why.
            let holding = joined
                .as_ref()
                .map(|(_, before)| {
                    now_key
                        .iter()
                        .filter_map(|(zone, now)| {
                            let (_, then) = before.iter().find(|(z, _)| z == zone)?;
                            Some((zone.clone(), frame_holds(then, now)?))
                        })
                        .collect()
                })
                .unwrap_or_default();
            joined = Some((Instant::now(), now_key));
            let task = tokio::spawn(join(
                Arc::clone(&view),
                Arc::clone(&session),
                site.clone(),
                links.pairs.clone(),
                again,
            ));
            joining = Some(Joining {
                task,
                again,
                holding,
            });
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
    if let Some(Joining { task: j, .. }) = joining {
        j.abort();
    }
    drop(token);
    if let Ok(session) = Arc::try_unwrap(session)
        && let Err(e) = session.close().await
    {
        tracing::warn!("closing the Zenoh session: {e}");
    }
}

/// A zone's `poses`, `status` or `detections`, checked: its schema, and that the zone it
/// names is the one whose key it came under. What cannot be read is stated once per zone and
/// key (it comes every second) and shown in the zone's status until it reads again.
/// Detections are returned with their zone, for the tracker.
fn heard(view: &SiteView, sample: &zenoh::sample::Sample) -> Option<(String, Vec<Sightings>)> {
    let key = sample.key_expr().as_str();
    let Some(zone) = zone_of(key) else {
        tracing::warn!("{key}: not a zone's key");
        return None;
    };
    let leaf = key.rsplit('/').next().unwrap_or(key);
    let bytes = sample.payload().to_bytes();
    let p = match serde_json::from_slice::<ZonePayload>(&bytes) {
        Ok(p) => p,
        Err(e) => {
            view.heard_unreadable(zone, leaf, format!("not a zone's {leaf}: {e}"));
            return None;
        }
    };
    if zone != p.zone {
        view.heard_unreadable(zone, leaf, format!("it names zone {:?}", p.zone));
        return None;
    }
    let read = match (p.schema.as_str(), p.poses, p.status, p.scans) {
        (POSES_SCHEMA, Some(poses), _, _) => Some(ZoneSaid::Poses(poses)),
        (STATUS_SCHEMA, _, Some(status), _) => Some(ZoneSaid::Status(status)),
        (DETECTIONS_SCHEMA, _, _, Some(scans)) => match super::site_tracks::check(&scans, p.t_ns) {
            Ok(()) => Some(ZoneSaid::Detections(scans)),
            Err(why) => {
                view.heard_unreadable(zone, leaf, why);
                return None;
            }
        },
        _ => None,
    };
    let Some(read) = read else {
        let why = format!(
            "schema {:?} is not one this scanfuse reads ({POSES_SCHEMA}, {STATUS_SCHEMA}, {DETECTIONS_SCHEMA})",
            p.schema
        );
        view.heard_unreadable(zone, leaf, why);
        return None;
    };
    view.heard_readable(zone, leaf);
    view.heard_bytes(zone, bytes.len());
    // Its clock against ours: the link's delay (ms on a LAN) is within what is flagged.
    view.heard_clock(zone, (p.t_ns as f64 - now_ns() as f64) * 1e-9);
    match read {
        ZoneSaid::Poses(poses) => view.heard_poses(zone, poses),
        ZoneSaid::Status(status) => view.heard_status(zone, status),
        ZoneSaid::Detections(scans) => return Some((zone.to_string(), scans)),
    }
    None
}

/// A zone's scan of one unit, checked as `heard` checks the rest, into the map.
fn heard_scan(view: &SiteView, sample: &zenoh::sample::Sample) {
    let key = sample.key_expr().as_str();
    let Some(zone) = zone_of(key) else {
        return tracing::warn!("{key}: not a zone's key");
    };
    let bytes = sample.payload().to_bytes();
    let scan = match ViewPayload::parse_as(&bytes, SCAN_SCHEMA) {
        Ok(scan) if scan.zone != zone => Err(format!("it names zone {:?}", scan.zone)),
        Ok(scan) if !key.ends_with(&format!("/scan/{}", scan.sensor)) => {
            Err(format!("it names sensor {:?}", scan.sensor))
        }
        other => other,
    };
    match scan {
        Ok(scan) => {
            view.heard_readable(zone, "scan");
            view.heard_bytes(zone, bytes.len());
            view.heard_scan(zone, scan);
        }
        Err(why) => view.heard_unreadable(zone, "scan", why),
    }
}

/// What a zone's payload held.
enum ZoneSaid {
    Poses(Poses),
    Status(Status),
    Detections(Vec<Sightings>),
}

/// A join's frame, and the cross pairs it registered (with those it was given).
type Joined = (BTreeMap<String, Placed>, Vec<KeptPair>);

/// A join under way.
struct Joining {
    task: tokio::task::JoinHandle<Option<Joined>>,
    /// A refining join (the same pairs registered again on later views).
    again: bool,
    /// The zones whose frame holds since the join before, and why ([`frame_holds`]): a full
    /// join does not unplace them for want of evidence ([`SiteView::join_afresh`]).
    holding: BTreeMap<String, String>,
}

/// Why a zone's frame still stands where it did, from its placed units then and now (to the
/// cm and 0.1°): nothing changed, or some unit off the frame's origin kept its pose in it.
/// The frame is where the zone's anchor stood when first placed, and its placed units hold
/// it (a knocked unit, the anchor too, is placed again against the others), so while one
/// of them stays put its place in the site holds too. `None` when every one changed (the
/// zone registered afresh, from wherever its anchor points now).
fn frame_holds(then: &PlacedKey, now: &PlacedKey) -> Option<String> {
    if then == now {
        return Some("its own poses have not changed".to_string());
    }
    let kept: Vec<&str> = now
        .iter()
        .filter(|(_, registered, at)| *registered && *at != [0; 3])
        .filter(|unit| then.contains(unit))
        .map(|(id, _, _)| id.as_str())
        .collect();
    (!kept.is_empty()).then(|| {
        format!(
            "{} kept {} pose{} in it, so its frame has not moved",
            kept.join(", "),
            if kept.len() == 1 { "its" } else { "their" },
            if kept.len() == 1 { "" } else { "s" }
        )
    })
}

/// Asks every alive zone for its views and joins the zones, averaging each link with the
/// `earlier` joins' pairs (with `again`, registering only those sensor pairs anew); `None`
/// when no zone, or not the anchor zone, was heard.
async fn join(
    view: Arc<SiteView>,
    session: Arc<zenoh::Session>,
    site: String,
    earlier: Vec<KeptPair>,
    again: bool,
) -> Option<Joined> {
    let zones = view.to_ask();
    if zones.is_empty() {
        return None;
    }
    // Every zone asked at once: one slow zone does not hold up the others' answers.
    let asked = zones.into_iter().map(|(zone, placed)| {
        let (session, site) = (Arc::clone(&session), site.clone());
        tokio::spawn(async move {
            let views = if placed.is_empty() {
                Vec::new()
            } else {
                query_views(&session, &site, &zone).await
            };
            Heard {
                zone,
                placed,
                views,
            }
        })
    });
    let mut heard = Vec::new();
    for a in asked.collect::<Vec<_>>() {
        if let Ok(h) = a.await {
            heard.push(h);
        }
    }
    let (anchor, surveys) = (view.anchor.clone(), view.surveys.clone());
    tokio::task::spawn_blocking(move || {
        let joined = join_frame(&anchor, heard, earlier, again, &surveys);
        release_freed_heap();
        joined
    })
    .await
    .ok()
    .flatten()
}

/// Hands the heap a join freed back to the system. glibc keeps the freed pages of its
/// arenas: a site daemon of 200 units held 740 MiB between joins of their views, 408 MiB
/// once trimmed (`cargo bench --bench zones_site`).
fn release_freed_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim takes no pointers; it only returns free pages to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
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

    /// A zone's frame holds while some unit off its origin keeps its pose: a knocked unit
    /// placed again leaves it; every unit placed anew (registered afresh) does not.
    #[test]
    fn a_zone_frame_holds_while_a_unit_besides_its_anchor_keeps_its_pose() {
        let unit = |id: &str, at: [i64; 3]| (id.to_string(), true, at);
        let then = vec![
            unit("a", [0; 3]),
            unit("b", [400, 0, 9000]),
            unit("c", [0, 300, 0]),
        ];
        assert_eq!(
            frame_holds(&then, &then).as_deref(),
            Some("its own poses have not changed")
        );
        let c_moved = vec![then[0].clone(), then[1].clone(), unit("c", [20, 310, 50])];
        assert_eq!(
            frame_holds(&then, &c_moved).as_deref(),
            Some("b kept its pose in it, so its frame has not moved")
        );
        let a_moved = vec![
            then[0].clone(),
            unit("b", [390, 5, 8950]),
            unit("c", [5, 290, -50]),
        ];
        assert_eq!(frame_holds(&then, &a_moved), None);
        // A unit unplaced then and now kept nothing.
        let unplaced = |id: &str| (id.to_string(), false, [i64::MIN; 3]);
        let few = vec![then[0].clone(), unplaced("b")];
        assert_eq!(
            frame_holds(
                &few,
                &[then[0].clone(), unplaced("b"), then[2].clone()].to_vec()
            ),
            None
        );
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
