//! What the page's WebSocket carries, daemon → page: the status socket's own lines (`EVENT`,
//! `FRAME`, `STATUS`, `POSES`, replies; `TRACKS` paced like one sensor's scans, every `ZONES`
//! and `CROSSING`), and three classes only the page needs (`MAP`, the
//! occupancy grid; `SENSORS`, each sensor's field of view; `DRAWING`, the building drawing's
//! walls in the site frame, sent once to each page). One [`Hub`] per server
//! subscribes to the [`Publisher`] as a `watch` client does, paces each sensor's scans to
//! `frames_per_s`, takes snapshots on a timer, and hands every line to every page through a
//! bounded broadcast: a page that falls `send_queue` lines behind is resent the latest state by
//! its own task ([`Hub::resubscribe`]), and nothing here ever waits for a page.

use std::collections::{BTreeMap, VecDeque};
use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use axum::extract::ws::Utf8Bytes;
use base64::Engine;
use serde::Serialize;
use tokio::sync::{Notify, broadcast};

use crate::daemon::pipeline::Pipeline;
use crate::daemon::protocol::{Event, EventKind, Message};
use crate::daemon::socket::{Publisher, StatusSource};
use crate::fuse::{Cell, OccupancyGrid};

/// Status, poses and fields of view are sent this often.
pub const STATE_EVERY: Duration = Duration::from_secs(1);
/// The occupancy grid is sent this often, when it changed.
pub const MAP_EVERY: Duration = Duration::from_secs(3);
/// A grid with more cells is sent coarser (cells merged), to keep `MAP` lines small.
pub const MAX_MAP_CELLS: usize = 250_000;
/// Events a page that opens gets from before it opened.
const EVENTS_KEPT: usize = 60;
/// A `DRAWING` line carries at most this many segments (the longest: walls before clutter).
pub const MAX_DRAWING_SEGMENTS: usize = 20_000;

/// What the page needs of the daemon beyond the status socket's requests.
pub trait PageSource: StatusSource {
    /// The occupancy grid now; `None` when there is none.
    fn occupancy(&self) -> Option<OccupancyGrid>;
    /// Each sensor's field of view: id, first and last beam angle (rad, sensor frame).
    fn fields_of_view(&self) -> Vec<(String, f64, f64)>;
    /// The `DRAWING` line (see [`drawing_line`]) when a drawing is set and the site is aligned
    /// to it; the same `Arc` until either changes.
    fn drawing(&self) -> Option<Arc<str>> {
        None
    }
}

impl PageSource for Pipeline {
    fn occupancy(&self) -> Option<OccupancyGrid> {
        Some(Pipeline::occupancy(self))
    }

    fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
        Pipeline::fields_of_view(self)
    }

    fn drawing(&self) -> Option<Arc<str>> {
        Pipeline::drawing_line(self)
    }
}

/// `{"class":"DRAWING","segments_m":[x0,y0,x1,y1,…]}`: the drawing's wall segments in the site
/// frame (the page's), mm-rounded.
#[derive(Debug, Serialize)]
#[serde(tag = "class", rename = "DRAWING")]
struct DrawingMessage {
    segments_m: Vec<f64>,
}

/// The `DRAWING` line of `drawing` placed by `building_from_site`: every segment moved into
/// the site frame (the inverse of the alignment), the longest [`MAX_DRAWING_SEGMENTS`] kept.
/// `None` when the site is not aligned to the drawing.
pub fn drawing_line(
    drawing: &crate::drawing::Drawing,
    building_from_site: &crate::drawing::BuildingFromSite,
) -> Option<String> {
    let t = building_from_site.similarity()?;
    if !(t.scale.is_finite() && t.scale > 0.0) {
        return None;
    }
    let to_site = |p: &nalgebra::Point2<f64>| {
        let q = t.to_site(p);
        [q.x, q.y]
    };
    let mut kept: Vec<&crate::drawing::WallSegment> = drawing.segments.iter().collect();
    if kept.len() > MAX_DRAWING_SEGMENTS {
        kept.sort_by(|a, b| b.length_m().total_cmp(&a.length_m()));
        kept.truncate(MAX_DRAWING_SEGMENTS);
    }
    let mm = |v: f64| (v * 1000.0).round() / 1000.0;
    let segments_m = kept
        .iter()
        .flat_map(|seg| {
            let ([ax, ay], [bx, by]) = (to_site(&seg.a), to_site(&seg.b));
            [mm(ax), mm(ay), mm(bx), mm(by)]
        })
        .filter(|v| v.is_finite())
        .collect::<Vec<f64>>();
    // A non-finite coordinate (never from a drawing read) would break the 4-per-segment
    // layout; drop the line rather than send a wrong one.
    if segments_m.len() != kept.len() * 4 {
        return None;
    }
    serde_json::to_string(&DrawingMessage { segments_m }).ok()
}

/// `{"class":"MAP",…}`: the grid's cells, row-major from the bottom row (y = `origin_y_m`)
/// up, one byte each (0 unknown, 1 free, 2 occupied), base64.
#[derive(Debug, Serialize)]
#[serde(tag = "class", rename = "MAP")]
struct MapMessage {
    cell_m: f64,
    origin_x_m: f64,
    origin_y_m: f64,
    width: usize,
    height: usize,
    cells: String,
}

/// `{"class":"SENSORS","sensors":[{"id","start_deg","end_deg"}]}`.
#[derive(Debug, Serialize)]
#[serde(tag = "class", rename = "SENSORS")]
struct SensorsMessage {
    sensors: Vec<FieldOfView>,
}

#[derive(Debug, Serialize)]
struct FieldOfView {
    id: String,
    start_deg: f64,
    end_deg: f64,
}

/// A grid's cells merged `k` × `k` so that at most [`MAX_MAP_CELLS`] remain: row-major from
/// the bottom row (y = the grid's origin) up, 0 unknown, 1 free, 2 occupied (a merged cell is
/// occupied if any of its cells is, else free if any is).
#[derive(Debug, Clone, PartialEq)]
pub struct CoarseGrid {
    pub cell_m: f64,
    pub origin_x_m: f64,
    pub origin_y_m: f64,
    pub width: usize,
    pub height: usize,
    pub cells: Vec<u8>,
}

/// `grid` coarsened to at most [`MAX_MAP_CELLS`] cells; `None` while empty.
pub fn coarse_grid(grid: &OccupancyGrid) -> Option<CoarseGrid> {
    let (w, h) = grid.size();
    if w == 0 || h == 0 {
        return None;
    }
    let k = ((w * h) as f64 / MAX_MAP_CELLS as f64)
        .sqrt()
        .ceil()
        .max(1.0) as usize;
    let (cw, ch) = (w.div_ceil(k), h.div_ceil(k));
    let mut cells = vec![0u8; cw * ch];
    for y in 0..h {
        for x in 0..w {
            let v = match grid.cell(x as i64, y as i64) {
                Cell::Unknown => 0,
                Cell::Free => 1,
                Cell::Occupied => 2,
            };
            if let Some(c) = cells.get_mut((y / k) * cw + x / k) {
                *c = (*c).max(v);
            }
        }
    }
    let origin = grid.origin();
    Some(CoarseGrid {
        cell_m: grid.params().cell_m * k as f64,
        origin_x_m: origin.x,
        origin_y_m: origin.y,
        width: cw,
        height: ch,
        cells,
    })
}

/// The `MAP` line of `grid` (coarsened as [`coarse_grid`] does); `None` while empty.
pub fn map_line(grid: &OccupancyGrid) -> Option<String> {
    let c = coarse_grid(grid)?;
    let message = MapMessage {
        cell_m: c.cell_m,
        origin_x_m: c.origin_x_m,
        origin_y_m: c.origin_y_m,
        width: c.width,
        height: c.height,
        cells: base64::engine::general_purpose::STANDARD.encode(&c.cells),
    };
    serde_json::to_string(&message).ok()
}

/// The `SENSORS` line.
pub fn sensors_line(fov: Vec<(String, f64, f64)>) -> String {
    let message = SensorsMessage {
        sensors: fov
            .into_iter()
            .map(|(id, a, b)| FieldOfView {
                id,
                start_deg: a.to_degrees(),
                end_deg: b.to_degrees(),
            })
            .collect(),
    };
    serde_json::to_string(&message).unwrap_or_default()
}

/// The sensor of a `FRAME` line (its first scan's), without parsing the points: ids are
/// plain (letters, digits, `_.-`), so the first `"sensor":"…"` is it.
pub fn frame_sensor(line: &str) -> Option<&str> {
    const KEY: &str = "\"sensor\":\"";
    let start = line.find(KEY)? + KEY.len();
    let rest = line.get(start..)?;
    rest.get(..rest.find('"')?)
}

/// The latest of everything, sent first to a page that opens.
#[derive(Default)]
struct Cache {
    status: Option<Utf8Bytes>,
    poses: Option<Utf8Bytes>,
    sensors: Option<Utf8Bytes>,
    map: Option<Utf8Bytes>,
    events: VecDeque<Utf8Bytes>,
    frames: BTreeMap<String, Utf8Bytes>,
    /// The latest `ZONES`.
    zones: Option<Utf8Bytes>,
    /// The `DRAWING` line, and the source's `Arc` it was made from (to notice a change
    /// without comparing the text).
    drawing: Option<(Arc<str>, Utf8Bytes)>,
}

/// The [`Pacer`] key of `TRACKS` (no sensor id can be it: ids are printable).
const TRACKS_KEY: &str = "\u{0}tracks";

/// Paces each sensor's scans: at most one per `gap`.
#[derive(Debug)]
pub struct Pacer {
    gap: Duration,
    last: BTreeMap<String, Instant>,
}

impl Pacer {
    pub fn new(frames_per_s: f64) -> Pacer {
        Pacer {
            gap: Duration::from_secs_f64(1.0 / frames_per_s.clamp(0.01, 1000.0)),
            last: BTreeMap::new(),
        }
    }

    /// True when `sensor`'s scan at `now` is to be sent.
    pub fn take(&mut self, sensor: &str, now: Instant) -> bool {
        match self.last.get(sensor) {
            Some(&t) if now.saturating_duration_since(t) < self.gap => false,
            _ => {
                self.last.insert(sensor.to_string(), now);
                true
            }
        }
    }
}

/// The one stream every page of a server shares.
pub struct Hub {
    tx: broadcast::Sender<Utf8Bytes>,
    cache: Mutex<Cache>,
    wake: Notify,
    frames_per_s: f64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn text(line: &str) -> Utf8Bytes {
    Utf8Bytes::from(line.trim_end().to_string())
}

impl Hub {
    /// A hub whose pages may fall `send_queue` lines behind.
    pub fn new(send_queue: usize, frames_per_s: f64) -> Arc<Hub> {
        Arc::new(Hub {
            tx: broadcast::channel(send_queue.max(1)).0,
            cache: Mutex::new(Cache::default()),
            wake: Notify::new(),
            frames_per_s,
        })
    }

    /// A new page's stream, and what to send it first: the latest status, poses, fields of
    /// view, map, recent events and each sensor's latest scan.
    pub fn subscribe(&self) -> (broadcast::Receiver<Utf8Bytes>, Vec<Utf8Bytes>) {
        self.subscribe_with(true)
    }

    /// A page that fell behind: a fresh stream and the latest state and scans, without the
    /// recent events it already has.
    pub fn resubscribe(&self) -> (broadcast::Receiver<Utf8Bytes>, Vec<Utf8Bytes>) {
        self.subscribe_with(false)
    }

    fn subscribe_with(&self, events: bool) -> (broadcast::Receiver<Utf8Bytes>, Vec<Utf8Bytes>) {
        let rx = self.tx.subscribe();
        let c = lock(&self.cache);
        let drawing = c.drawing.as_ref().map(|(_, line)| line);
        let mut first: Vec<Utf8Bytes> = [
            c.status.as_ref(),
            c.poses.as_ref(),
            c.sensors.as_ref(),
            drawing,
            c.map.as_ref(),
            c.zones.as_ref(),
        ]
        .into_iter()
        .flatten()
        .cloned()
        .collect();
        if events {
            first.extend(c.events.iter().cloned());
        }
        first.extend(c.frames.values().cloned());
        drop(c);
        self.wake.notify_one();
        (rx, first)
    }

    /// Tells every page an event the daemon's own stream does not carry (a page dropped).
    pub fn tell_pages(&self, kind: EventKind, message: String) {
        let line = Message::Event(Event::now(kind, None, message)).to_line();
        let _ = self.tx.send(text(&line));
    }

    /// Pages connected now.
    pub fn pages(&self) -> usize {
        self.tx.receiver_count()
    }

    fn send(&self, line: Utf8Bytes) {
        // An error only means no page is open.
        let _ = self.tx.send(line);
    }

    fn refresh_state<S: PageSource + ?Sized>(&self, source: &S) {
        let status = text(&Message::Status(source.status()).to_line());
        let poses = text(&Message::Poses(source.poses()).to_line());
        let sensors = text(&sensors_line(source.fields_of_view()));
        {
            let mut c = lock(&self.cache);
            c.status = Some(status.clone());
            c.poses = Some(poses.clone());
            c.sensors = Some(sensors.clone());
        }
        self.send(status);
        self.send(poses);
        self.send(sensors);
        // The drawing goes to each page once: in its first lines, or here when it changes.
        let drawing = source.drawing();
        let changed = {
            let mut c = lock(&self.cache);
            match (&drawing, &c.drawing) {
                (Some(now), Some((was, _))) if Arc::ptr_eq(now, was) => None,
                (None, None) => None,
                (None, Some(_)) => {
                    c.drawing = None;
                    None
                }
                (Some(now), _) => {
                    let line = text(now);
                    c.drawing = Some((Arc::clone(now), line.clone()));
                    Some(line)
                }
            }
        };
        if let Some(line) = changed {
            self.send(line);
        }
    }

    async fn refresh_map<S: PageSource + ?Sized>(&self, source: &Arc<S>) {
        let s = Arc::clone(source);
        let Ok(Some(line)) =
            tokio::task::spawn_blocking(move || s.occupancy().as_ref().and_then(map_line)).await
        else {
            return;
        };
        let line = text(&line);
        {
            let mut c = lock(&self.cache);
            if c.map.as_ref() == Some(&line) {
                return;
            }
            c.map = Some(line.clone());
        }
        self.send(line);
    }

    /// Runs until `shutdown`: forwards events always (the recent ones are kept for pages
    /// that open later), and scans, snapshots and the map while a page is open.
    pub async fn run<S: PageSource + ?Sized>(
        self: Arc<Self>,
        source: Arc<S>,
        publisher: Publisher,
        shutdown: impl Future<Output = ()>,
    ) {
        tokio::pin!(shutdown);
        let mut events = publisher.subscribe_events();
        let mut frames: Option<broadcast::Receiver<Arc<str>>> = None;
        let mut people: Option<broadcast::Receiver<Arc<Message>>> = None;
        let mut pacer = Pacer::new(self.frames_per_s);
        let mut state_tick = tokio::time::interval(STATE_EVERY);
        let mut map_tick = tokio::time::interval(MAP_EVERY);
        state_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        map_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let open = self.pages() > 0;
            // Subscribed to scans only while someone looks: the publisher encodes frames only
            // for subscribers.
            if open && frames.is_none() {
                frames = Some(publisher.subscribe_frames());
            } else if !open {
                frames = None;
            }
            // People too (the latest ZONES is kept for pages that open later by then).
            if open && people.is_none() {
                people = Some(publisher.subscribe_people());
            } else if !open {
                people = None;
            }
            tokio::select! {
                () = &mut shutdown => return,
                () = self.wake.notified() => {
                    self.refresh_state(source.as_ref());
                    if lock(&self.cache).map.is_none() {
                        self.refresh_map(&source).await;
                    }
                }
                event = events.recv() => match event {
                    Ok(line) => {
                        let line = text(&line);
                        {
                            let mut c = lock(&self.cache);
                            c.events.push_back(line.clone());
                            while c.events.len() > EVENTS_KEPT {
                                c.events.pop_front();
                            }
                        }
                        self.send(line);
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => return,
                },
                frame = async {
                    match frames.as_mut() {
                        Some(rx) => rx.recv().await,
                        None => std::future::pending().await,
                    }
                } => match frame {
                    Ok(line) => {
                        let Some(sensor) = frame_sensor(&line) else { continue };
                        if pacer.take(sensor, Instant::now()) {
                            let sensor = sensor.to_string();
                            let line = text(&line);
                            lock(&self.cache).frames.insert(sensor, line.clone());
                            self.send(line);
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => frames = None,
                },
                item = async {
                    match people.as_mut() {
                        Some(rx) => rx.recv().await,
                        None => std::future::pending().await,
                    }
                } => match item {
                    Ok(message) => {
                        match message.as_ref() {
                            Message::Tracks(_) if !pacer.take(TRACKS_KEY, Instant::now()) => continue,
                            Message::Tracks(_) | Message::Crossing(_) => {}
                            Message::Zones(_) => {}
                            _ => continue,
                        }
                        let line = text(&message.to_line());
                        if matches!(message.as_ref(), Message::Zones(_)) {
                            lock(&self.cache).zones = Some(line.clone());
                        }
                        self.send(line);
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => people = None,
                },
                _ = state_tick.tick(), if open => self.refresh_state(source.as_ref()),
                _ = map_tick.tick(), if open => self.refresh_map(&source).await,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::GridParams;
    use nalgebra::Point2;

    #[test]
    fn the_sensor_of_a_frame_line_is_read_without_parsing_the_points() {
        let line = r#"{"class":"FRAME","stamp_ns":5,"scans":[{"sensor":"dock-2.a","stamp_ns":5,"xy_m":[1.0,2.0]}]}"#;
        assert_eq!(frame_sensor(line), Some("dock-2.a"));
        assert_eq!(frame_sensor(r#"{"class":"FRAME","scans":[]}"#), None);
    }

    #[test]
    fn each_sensor_is_paced_on_its_own() {
        let mut p = Pacer::new(10.0);
        let t0 = Instant::now();
        assert!(p.take("a", t0));
        assert!(p.take("b", t0), "another sensor is not held back by a");
        assert!(!p.take("a", t0 + Duration::from_millis(50)));
        assert!(p.take("a", t0 + Duration::from_millis(100)));
    }

    #[test]
    fn a_large_grid_is_sent_coarser_and_keeps_its_walls() {
        let mut g = OccupancyGrid::new(GridParams::default());
        assert_eq!(map_line(&g), None, "nothing seen yet");
        // A 40 m wall seen from 30 m away: 800 × 600 cells at 5 cm, more than the limit.
        for i in 0..400 {
            let x = -20.0 + i as f64 * 0.1;
            g.insert_ray(Point2::new(0.0, 0.0), Point2::new(x, 30.0), true);
        }
        let line = map_line(&g).unwrap();
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["class"], "MAP");
        let (w, h) = (v["width"].as_u64().unwrap(), v["height"].as_u64().unwrap());
        assert!(w * h <= MAX_MAP_CELLS as u64, "{w} × {h}");
        assert!(v["cell_m"].as_f64().unwrap() > 0.05);
        let cells = base64::engine::general_purpose::STANDARD
            .decode(v["cells"].as_str().unwrap())
            .unwrap();
        assert_eq!(cells.len() as u64, w * h);
        assert!(
            cells.contains(&2) && cells.contains(&1),
            "walls and free space survive"
        );
    }

    /// A site with no sensors and, when set, an alignment and a `DRAWING` line: what the
    /// hub's tests need of a source.
    #[derive(Default)]
    struct Site {
        aligned: Option<crate::drawing::BuildingFromSite>,
        drawing: Mutex<Option<Arc<str>>>,
    }

    impl StatusSource for Site {
        fn status(&self) -> crate::daemon::protocol::Status {
            crate::daemon::protocol::Status {
                site: "s".into(),
                uptime_s: 0.0,
                queue_drops: 0,
                sensors: vec![],
                web: None,
                foxglove: None,
                zenoh: None,
                zones: Vec::new(),
            }
        }
        fn poses(&self) -> crate::daemon::protocol::Poses {
            crate::daemon::protocol::Poses {
                anchor: "a".into(),
                sensors: vec![],
                building_from_site: self.aligned.clone(),
                site_from_zone: None,
            }
        }
        fn reregister(&self, _: &str) -> Result<String, crate::daemon::socket::Refused> {
            Err(crate::daemon::socket::Refused("no".into()))
        }
        fn save(&self) -> Result<crate::daemon::protocol::Saved, crate::daemon::socket::Refused> {
            Err(crate::daemon::socket::Refused("no".into()))
        }
    }

    impl PageSource for Site {
        fn occupancy(&self) -> Option<OccupancyGrid> {
            None
        }
        fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
            Vec::new()
        }
        fn drawing(&self) -> Option<Arc<str>> {
            lock(&self.drawing).clone()
        }
    }

    fn drawing_of(segments: Vec<((f64, f64), (f64, f64))>) -> crate::drawing::Drawing {
        crate::drawing::Drawing {
            source: "plan.dxf".into(),
            segments: segments
                .into_iter()
                .map(|(a, b)| crate::drawing::WallSegment {
                    a: Point2::new(a.0, a.1),
                    b: Point2::new(b.0, b.1),
                    layer: "A-WALL".into(),
                })
                .collect(),
            units: "m".into(),
            bounds: (Point2::new(0.0, 0.0), Point2::new(1.0, 1.0)),
            layers: vec!["A-WALL".into()],
        }
    }

    fn aligned(x_m: f64, y_m: f64, yaw_deg: f64) -> crate::drawing::BuildingFromSite {
        crate::drawing::BuildingFromSite {
            x_m,
            y_m,
            yaw_deg,
            scale: 1.0,
            aligned: true,
            method: "automatic+lines".into(),
            reason: None,
            ..Default::default()
        }
    }

    fn segments_of(line: &str) -> Vec<f64> {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(v["class"], "DRAWING", "{line}");
        v["segments_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    }

    #[test]
    fn the_drawing_is_sent_in_the_site_frame_and_only_when_aligned() {
        // The site's origin stands at (10, 0) in the building, its x axis along the
        // building's y: the wall (10, 0)–(10, 5) is (0, 0)–(5, 0) on the page.
        let d = drawing_of(vec![((10.0, 0.0), (10.0, 5.0))]);
        let line = drawing_line(&d, &aligned(10.0, 0.0, 90.0)).unwrap();
        let got = segments_of(&line);
        let want = [0.0, 0.0, 5.0, 0.0];
        assert_eq!(got.len(), 4, "{line}");
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-3, "{line}");
        }
        let mut not = aligned(10.0, 0.0, 90.0);
        not.aligned = false;
        not.reason = Some("the hall is symmetric".into());
        assert_eq!(drawing_line(&d, &not), None);
    }

    #[test]
    fn a_large_drawing_keeps_its_longest_segments() {
        let n = MAX_DRAWING_SEGMENTS + 500;
        // Short clutter, and one long wall at the end.
        let mut segs: Vec<((f64, f64), (f64, f64))> = (0..n - 1)
            .map(|i| ((i as f64 * 0.01, 0.0), (i as f64 * 0.01, 0.05)))
            .collect();
        segs.push(((0.0, 10.0), (40.0, 10.0)));
        let line = drawing_line(&drawing_of(segs), &aligned(0.0, 0.0, 0.0)).unwrap();
        let got = segments_of(&line);
        assert_eq!(got.len(), MAX_DRAWING_SEGMENTS * 4);
        assert!(
            got.chunks(4).any(|c| c == [0.0, 10.0, 40.0, 10.0]),
            "the long wall is kept"
        );
    }

    /// A page gets the drawing once (in its first lines when it opens later), and again only
    /// when the drawing or the alignment changes.
    #[test]
    fn the_drawing_goes_to_each_page_once() {
        let first_line: Arc<str> = Arc::from(
            drawing_line(
                &drawing_of(vec![((0.0, 0.0), (4.0, 0.0))]),
                &aligned(0.0, 0.0, 0.0),
            )
            .unwrap(),
        );
        let source = Site {
            aligned: Some(aligned(0.0, 0.0, 0.0)),
            drawing: Mutex::new(Some(Arc::clone(&first_line))),
        };
        let hub = Hub::new(64, 10.0);
        let (mut page, first) = hub.subscribe();
        assert!(first.is_empty());
        let drawings = |page: &mut broadcast::Receiver<Utf8Bytes>| {
            let mut n = 0;
            while let Ok(line) = page.try_recv() {
                n += usize::from(line.as_str().starts_with(r#"{"class":"DRAWING""#));
            }
            n
        };
        for _ in 0..3 {
            hub.refresh_state(&source);
        }
        assert_eq!(drawings(&mut page), 1, "sent once, not every refresh");
        let (_, first) = hub.subscribe();
        assert!(
            first.iter().any(|l| l.as_str() == &*first_line),
            "a page that opens later gets it first"
        );
        *lock(&source.drawing) = Some(Arc::from(
            drawing_line(
                &drawing_of(vec![((0.0, 0.0), (4.0, 0.0))]),
                &aligned(1.0, 0.0, 0.0),
            )
            .unwrap(),
        ));
        hub.refresh_state(&source);
        hub.refresh_state(&source);
        assert_eq!(drawings(&mut page), 1, "a new alignment is sent once");
    }

    /// A hub's task running on an empty site, fed by `publisher`, until stopped; started once
    /// it takes the publisher's events and people (a page must be open for the people).
    struct Running {
        stop: tokio::sync::oneshot::Sender<()>,
        task: tokio::task::JoinHandle<()>,
    }

    impl Running {
        async fn start(hub: &Arc<Hub>, publisher: &Publisher) -> Running {
            let (stop, stop_rx) = tokio::sync::oneshot::channel::<()>();
            let task = tokio::spawn(Arc::clone(hub).run(
                Arc::new(Site::default()),
                publisher.clone(),
                async move {
                    let _ = stop_rx.await;
                },
            ));
            while publisher.event_watchers() == 0 || publisher.people_watchers() == 0 {
                tokio::task::yield_now().await;
            }
            Running { stop, task }
        }

        async fn stop(self) {
            let _ = self.stop.send(());
            self.task.await.unwrap();
        }
    }

    /// TRACKS reach a page paced like a sensor's scans; ZONES and CROSSING all reach it, and
    /// the latest ZONES is among the first lines of a page that opens later.
    #[tokio::test]
    async fn people_reach_pages_paced_and_zones_are_kept() {
        use crate::daemon::protocol::{Crossing, Side, Track, Tracks, ZoneCount, Zones};
        let publisher = Publisher::new(64);
        // One TRACKS per 1000 s: only the first of a burst passes.
        let hub = Hub::new(64, 0.001);
        let (mut page, _) = hub.subscribe();
        let running = Running::start(&hub, &publisher).await;
        let tracks = |t_ns| {
            Message::Tracks(Tracks {
                t_ns,
                tracks: vec![Track {
                    id: 4,
                    x_m: 1.0,
                    y_m: 2.0,
                    vx_m_s: 0.0,
                    vy_m_s: 0.0,
                    sigma_m: 0.1,
                    age_s: 1.0,
                    sensors: vec![],
                }],
            })
        };
        let zones = Message::Zones(Zones {
            t_ns: 2,
            zones: vec![ZoneCount {
                id: "desk".into(),
                count: 1,
                tracks: vec![4],
            }],
        });
        let crossing = Message::Crossing(Crossing {
            t_ns: 2,
            line: "door".into(),
            track: 4,
            to: Side::Left,
            left_total: 1,
            right_total: 0,
        });
        for m in [
            tracks(1),
            tracks(2),
            zones.clone(),
            crossing.clone(),
            tracks(3),
        ] {
            publisher.people(m);
        }
        let mut got = Vec::new();
        while got.len() < 3 {
            let line = page.recv().await.unwrap();
            // STATUS, POSES and SENSORS come too; only people are looked at.
            if let Ok(m @ (Message::Tracks(_) | Message::Zones(_) | Message::Crossing(_))) =
                serde_json::from_str::<Message>(line.as_str())
            {
                got.push(m);
            }
        }
        assert_eq!(got, vec![tracks(1), zones.clone(), crossing]);
        let (_, first) = hub.subscribe();
        assert!(
            first.iter().any(|l| l.as_str() == zones.to_line()),
            "a new page gets the latest ZONES first"
        );
        running.stop().await;
    }

    #[tokio::test]
    async fn a_page_that_fell_behind_gets_the_state_without_the_events_again() {
        use crate::daemon::protocol::Event;
        let publisher = Publisher::new(64);
        let hub = Hub::new(4, 10.0);
        let (mut page, _) = hub.subscribe();
        let running = Running::start(&hub, &publisher).await;
        for i in 0..12 {
            publisher.event(Event::now(EventKind::Saved, None, format!("event {i}")));
        }
        let class = |line: &Utf8Bytes| {
            serde_json::from_str::<serde_json::Value>(line.as_str()).unwrap()["class"]
                .as_str()
                .unwrap()
                .to_string()
        };
        // The page read nothing: its stream has lagged.
        let lagged = loop {
            match page.recv().await {
                Err(broadcast::error::RecvError::Lagged(n)) => break n,
                Err(e) => panic!("{e}"),
                Ok(_) => {}
            }
        };
        assert!(lagged > 0);
        let (_, again) = hub.resubscribe();
        let classes: Vec<String> = again.iter().map(class).collect();
        assert!(classes.contains(&"POSES".to_string()), "{classes:?}");
        assert!(!classes.contains(&"EVENT".to_string()), "{classes:?}");
        let (_, first) = hub.subscribe();
        assert!(
            first.iter().map(class).any(|c| c == "EVENT"),
            "a new page gets the recent events"
        );
        running.stop().await;
    }
}
