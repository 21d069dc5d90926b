//! The live site in Foxglove and Lichtblick: a Foxglove WebSocket server (the `foxglove`
//! crate's, subprotocol `foxglove.sdk.v1`, protobuf schemas advertised with every channel).
//! It is read-only: no client publishing, services or parameters. Topics:
//!
//! - `/<id>/scan` — `foxglove.LaserScan` of each sensor, in its own frame (`frame_id` = id),
//!   at most `frames_per_s` a second;
//! - `/tf` — `foxglove.FrameTransforms`, `site` → every placed sensor (x, y, z, yaw, pitch
//!   as `poses` reports them); sent when a pose changes and to each new subscriber;
//! - `/points` — `foxglove.PointCloud`, the fused points (every placed sensor's latest scan)
//!   in `site`, fields `x`, `y`, `z` (float32) and `sensor` (uint32, its index);
//! - `/map` — `foxglove.Grid`, the occupancy map in `site`, field `occupancy` (int8: -1
//!   unknown, 0 free, 100 occupied, as a ROS occupancy grid); sent when it changes and to
//!   each new subscriber;
//! - `/sensors` — `foxglove.SceneUpdate`, each placed sensor as an arrow and its id.
//!
//! The server does not latch, so what a new subscriber needs first (transforms, map,
//! sensors) is kept here and sent to it alone. It is fed like the page: one task polls the
//! pipeline's latest scans and poses at `frames_per_s` (nothing runs on the scan path), and
//! each client's queue holds `send_queue` messages, dropping the oldest when full.

use std::collections::BTreeMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use foxglove::bytes::Bytes;
use foxglove::messages::{
    ArrowPrimitive, Color, FrameTransform, FrameTransforms, Grid, LaserScan, PackedElementField,
    PointCloud, Pose, Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate, TextPrimitive,
    Timestamp, Vector2, Vector3, packed_element_field::NumericType, scene_entity_deletion,
};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{Channel, Context, FoxgloveError, WebSocketServer, WebSocketServerHandle};
use nalgebra::UnitQuaternion;
use thiserror::Error;
use tokio::sync::{Notify, watch};

use super::bridge::{CoarseGrid, MAP_EVERY, PageSource, coarse_grid};
use crate::daemon::config::FoxgloveConfig;
use crate::daemon::pipeline::{LatestScan, Pipeline, PosedScan};
use crate::daemon::pipeline_fuse::scan_frame;
use crate::daemon::protocol::Poses;
use crate::geometry::{Pose3, ProjectParams};

/// The frame everything placed is in: the anchor's (the building's once a drawing is aligned).
pub const SITE_FRAME: &str = "site";
pub const TF_TOPIC: &str = "/tf";
pub const POINTS_TOPIC: &str = "/points";
pub const MAP_TOPIC: &str = "/map";
pub const SENSORS_TOPIC: &str = "/sensors";

/// What the Foxglove bridge needs of the daemon beyond the page's.
pub trait FoxgloveSource: PageSource {
    /// Every sensor's latest scan, with its pose when placed.
    fn latest_scans(&self) -> Vec<LatestScan>;
    /// How scans become site points.
    fn project_params(&self) -> ProjectParams;
}

impl FoxgloveSource for Pipeline {
    fn latest_scans(&self) -> Vec<LatestScan> {
        Pipeline::latest_scans(self)
    }

    fn project_params(&self) -> ProjectParams {
        Pipeline::project_params(self)
    }
}

#[derive(Debug, Error)]
pub enum FoxgloveBridgeError {
    #[error(
        "{addr} is taken (another program listens there); set [foxglove] listen to a free port"
    )]
    PortTaken { addr: SocketAddr },
    #[error("cannot serve Foxglove on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: FoxgloveError,
    },
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// What a new subscriber of these topics gets first.
#[derive(Default)]
struct Latched {
    tf: Option<FrameTransforms>,
    map: Option<Grid>,
    sensors: Option<SceneUpdate>,
}

struct Channels {
    tf: Channel<FrameTransforms>,
    points: Channel<PointCloud>,
    map: Channel<Grid>,
    sensors: Channel<SceneUpdate>,
}

/// Sends the latched messages to a client that subscribes, and wakes the bridge (a map not
/// made yet is made then).
struct Listener {
    channels: Arc<Channels>,
    latched: Arc<Mutex<Latched>>,
    wake: Arc<Notify>,
}

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let sink = client.sink_id();
        // Copied out: nothing is logged under the lock.
        let (tf, map, sensors) = {
            let l = lock(&self.latched);
            match channel.topic() {
                TF_TOPIC => (l.tf.clone(), None, None),
                MAP_TOPIC => (None, l.map.clone(), None),
                SENSORS_TOPIC => (None, None, l.sensors.clone()),
                _ => (None, None, None),
            }
        };
        if let Some(m) = tf {
            self.channels.tf.log_to_sink(&m, sink);
        }
        if let Some(m) = sensors {
            self.channels.sensors.log_to_sink(&m, sink);
        }
        match map {
            Some(m) => self.channels.map.log_to_sink(&m, sink),
            None if channel.topic() == MAP_TOPIC => self.wake.notify_one(),
            None => {}
        }
    }
}

/// A bound Foxglove server, ready to [`run`](FoxgloveServer::run).
pub struct FoxgloveServer {
    handle: WebSocketServerHandle,
    local: SocketAddr,
    ctx: Arc<Context>,
    channels: Arc<Channels>,
    latched: Arc<Mutex<Latched>>,
    wake: Arc<Notify>,
    frames_per_s: f64,
}

impl FoxgloveServer {
    /// Binds `config.listen`; `Ok(None)` when it names none. Call within the tokio runtime.
    pub async fn bind(
        config: &FoxgloveConfig,
    ) -> Result<Option<FoxgloveServer>, FoxgloveBridgeError> {
        let Some(addr) = config.listen else {
            return Ok(None);
        };
        let ctx = Context::new();
        let channels = Arc::new(Channels {
            tf: ctx.channel_builder(TF_TOPIC).build(),
            points: ctx.channel_builder(POINTS_TOPIC).build(),
            map: ctx.channel_builder(MAP_TOPIC).build(),
            sensors: ctx.channel_builder(SENSORS_TOPIC).build(),
        });
        let latched = Arc::new(Mutex::new(Latched::default()));
        let wake = Arc::new(Notify::new());
        let listener = Arc::new(Listener {
            channels: Arc::clone(&channels),
            latched: Arc::clone(&latched),
            wake: Arc::clone(&wake),
        });
        let handle = WebSocketServer::new()
            .name("scanfuse")
            .bind(addr.ip().to_string(), addr.port())
            .context(&ctx)
            .listener(listener)
            .message_backlog_size(config.send_queue)
            .start()
            .await
            .map_err(|source| match &source {
                FoxgloveError::Bind(e) if e.kind() == std::io::ErrorKind::AddrInUse => {
                    FoxgloveBridgeError::PortTaken { addr }
                }
                _ => FoxgloveBridgeError::Bind { addr, source },
            })?;
        let local = SocketAddr::new(addr.ip(), handle.port());
        Ok(Some(FoxgloveServer {
            handle,
            local,
            ctx,
            channels,
            latched,
            wake,
            frames_per_s: config.frames_per_s,
        }))
    }

    /// The address bound (the port is known even for `:0`).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// What to open in Foxglove ("Open connection", Foxglove WebSocket).
    pub fn url(&self) -> String {
        let ip = if self.local.ip().is_unspecified() {
            IpAddr::from([127, 0, 0, 1])
        } else {
            self.local.ip()
        };
        format!("ws://{}", SocketAddr::new(ip, self.local.port()))
    }

    /// Feeds the server until `stop` turns true, then closes it.
    pub async fn run(self, source: Arc<dyn FoxgloveSource>, mut stop: watch::Receiver<bool>) {
        let mut feed = Feed::new(&self.ctx, Arc::clone(&self.channels));
        let mut tick = tokio::time::interval(Duration::from_secs_f64(
            1.0 / self.frames_per_s.clamp(0.01, 1000.0),
        ));
        let mut map_tick = tokio::time::interval(MAP_EVERY);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        map_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let stopped = async move {
            let _ = stop.wait_for(|s| *s).await;
        };
        tokio::pin!(stopped);
        loop {
            let watched = self.handle.client_count() > 0;
            tokio::select! {
                () = &mut stopped => break,
                _ = tick.tick() => {
                    let poses = source.poses();
                    if let Some(update) = feed.poses(&poses) {
                        lock(&self.latched).tf = Some(update.0.clone());
                        lock(&self.latched).sensors = Some(update.1.clone());
                        self.channels.tf.log(&update.0);
                        self.channels.sensors.log(&update.1);
                    }
                    if watched {
                        feed.scans(source.latest_scans(), &source.project_params());
                    }
                }
                () = self.wake.notified() => self.refresh_map(&source, &feed).await,
                _ = map_tick.tick(), if watched => self.refresh_map(&source, &feed).await,
            }
        }
        self.handle.stop().wait().await;
    }

    async fn refresh_map(&self, source: &Arc<dyn FoxgloveSource>, feed: &Feed) {
        let s = Arc::clone(source);
        let Ok(Some(coarse)) =
            tokio::task::spawn_blocking(move || s.occupancy().as_ref().and_then(coarse_grid)).await
        else {
            return;
        };
        let grid = grid_message(&coarse, feed.stamp());
        {
            let mut l = lock(&self.latched);
            if l.map.as_ref().is_some_and(|m| m.data == grid.data) {
                return;
            }
            l.map = Some(grid.clone());
        }
        self.channels.map.log(&grid);
    }
}

/// The bridge's own state between ticks.
struct Feed {
    ctx: Arc<Context>,
    channels: Arc<Channels>,
    scans: BTreeMap<String, Channel<LaserScan>>,
    /// Stamp of the last scan sent per sensor.
    sent: BTreeMap<String, u64>,
    /// The placed sensors' poses last sent.
    placed: Option<Vec<(String, [f64; 5])>>,
    /// The newest scan stamp seen (the recordings' clock in a replay), ns.
    stream_ns: u64,
}

impl Feed {
    fn new(ctx: &Arc<Context>, channels: Arc<Channels>) -> Feed {
        Feed {
            ctx: Arc::clone(ctx),
            channels,
            scans: BTreeMap::new(),
            sent: BTreeMap::new(),
            placed: None,
            stream_ns: 0,
        }
    }

    /// Stream time, or now before the first scan.
    fn stamp(&self) -> Timestamp {
        if self.stream_ns > 0 {
            timestamp(self.stream_ns)
        } else {
            let now = SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64);
            timestamp(now)
        }
    }

    /// The transforms and scene to send when the placed sensors' poses changed.
    fn poses(&mut self, poses: &Poses) -> Option<(FrameTransforms, SceneUpdate)> {
        let placed = placed_poses(poses);
        if self.placed.as_ref() == Some(&placed) {
            return None;
        }
        let stamp = self.stamp();
        let update = (
            transforms(&placed, stamp),
            scene(&placed, &poses.anchor, stamp),
        );
        self.placed = Some(placed);
        Some(update)
    }

    /// Sends each sensor's scan that is new, and the fused cloud when any is.
    fn scans(&mut self, latest: Vec<LatestScan>, project: &ProjectParams) {
        let mut any = false;
        for s in &latest {
            self.stream_ns = self.stream_ns.max(s.scan.stamp_ns);
            if self.sent.get(&s.id) == Some(&s.scan.stamp_ns) {
                continue;
            }
            self.sent.insert(s.id.clone(), s.scan.stamp_ns);
            any = true;
            let ctx = &self.ctx;
            let channel = self
                .scans
                .entry(s.id.clone())
                .or_insert_with(|| ctx.channel_builder(format!("/{}/scan", s.id)).build());
            if channel.has_sinks() {
                channel.log(&laser_scan(s));
            }
        }
        if any && self.channels.points.has_sinks() {
            self.channels
                .points
                .log(&point_cloud(&latest, project, self.stamp()));
        }
    }
}

fn timestamp(ns: u64) -> Timestamp {
    Timestamp::new(
        u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
        (ns % 1_000_000_000) as u32,
    )
}

/// Every placed sensor: id and (x, y, z, yaw, pitch) in m and rad.
fn placed_poses(poses: &Poses) -> Vec<(String, [f64; 5])> {
    poses
        .sensors
        .iter()
        .filter(|p| p.registered)
        .filter_map(|p| {
            Some((
                p.id.clone(),
                [
                    p.x_m?,
                    p.y_m?,
                    p.z_m.unwrap_or(0.0),
                    p.yaw_deg?.to_radians(),
                    p.pitch_deg.unwrap_or(0.0).to_radians(),
                ],
            ))
        })
        .collect()
}

/// The pose of a sensor at (x, y, z, yaw, pitch): as [`Pose3::isometry`] turns it (yaw about
/// z, then pitch, positive up, about the turned y axis).
fn pose_parts(p: &[f64; 5]) -> (Vector3, Quaternion) {
    let iso = Pose3 {
        x_m: p[0],
        y_m: p[1],
        z_m: p[2],
        yaw_rad: p[3],
        pitch_rad: p[4],
    }
    .isometry();
    let q: UnitQuaternion<f64> = iso.rotation;
    (
        Vector3 {
            x: p[0],
            y: p[1],
            z: p[2],
        },
        Quaternion {
            x: q.i,
            y: q.j,
            z: q.k,
            w: q.w,
        },
    )
}

fn transforms(placed: &[(String, [f64; 5])], stamp: Timestamp) -> FrameTransforms {
    FrameTransforms {
        transforms: placed
            .iter()
            .map(|(id, p)| {
                let (translation, rotation) = pose_parts(p);
                FrameTransform {
                    timestamp: Some(stamp),
                    parent_frame_id: SITE_FRAME.into(),
                    child_frame_id: id.clone(),
                    translation: Some(translation),
                    rotation: Some(rotation),
                }
            })
            .collect(),
    }
}

/// Each placed sensor as an arrow along its heading and its id, in its own frame; the anchor
/// in another colour. Everything drawn before is deleted first.
fn scene(placed: &[(String, [f64; 5])], anchor: &str, stamp: Timestamp) -> SceneUpdate {
    let identity = Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    };
    SceneUpdate {
        deletions: vec![SceneEntityDeletion {
            timestamp: Some(stamp),
            r#type: scene_entity_deletion::Type::All as i32,
            id: String::new(),
        }],
        entities: placed
            .iter()
            .map(|(id, _)| {
                let color = if id == anchor {
                    Color {
                        r: 1.0,
                        g: 0.6,
                        b: 0.1,
                        a: 1.0,
                    }
                } else {
                    Color {
                        r: 0.2,
                        g: 0.6,
                        b: 1.0,
                        a: 1.0,
                    }
                };
                SceneEntity {
                    timestamp: Some(stamp),
                    frame_id: id.clone(),
                    id: id.clone(),
                    frame_locked: true,
                    arrows: vec![ArrowPrimitive {
                        pose: Some(identity),
                        shaft_length: 0.4,
                        shaft_diameter: 0.05,
                        head_length: 0.15,
                        head_diameter: 0.15,
                        color: Some(color),
                    }],
                    texts: vec![TextPrimitive {
                        pose: Some(identity),
                        billboard: true,
                        font_size: 14.0,
                        scale_invariant: true,
                        color: Some(color),
                        text: id.clone(),
                    }],
                    ..Default::default()
                }
            })
            .collect(),
    }
}

fn laser_scan(s: &LatestScan) -> LaserScan {
    LaserScan {
        timestamp: Some(timestamp(s.scan.stamp_ns)),
        frame_id: s.id.clone(),
        pose: None,
        start_angle: s.scan.start_angle_rad,
        end_angle: s.scan.end_angle_rad,
        ranges: s.scan.ranges_m.iter().map(|&r| f64::from(r)).collect(),
        intensities: s.scan.intensities.iter().map(|&i| f64::from(i)).collect(),
    }
}

/// Bytes per point of [`point_cloud`]: x, y, z float32 and the sensor's index, uint32.
const POINT_STRIDE: u32 = 16;

fn field(name: &str, offset: u32, kind: NumericType) -> PackedElementField {
    PackedElementField {
        name: name.into(),
        offset,
        r#type: kind as i32,
    }
}

/// Every placed sensor's latest scan as site points (as `watch` frames have them).
fn point_cloud(latest: &[LatestScan], project: &ProjectParams, stamp: Timestamp) -> PointCloud {
    let mut data = Vec::new();
    for (index, s) in latest.iter().enumerate() {
        let Some(site_from_sensor) = s.site_from_sensor else {
            continue;
        };
        let posed = PosedScan {
            index: index as u16,
            id: s.id.clone(),
            scan: s.scan.clone(),
            geometry: s.geometry,
            mount: s.mount,
            site_from_sensor,
        };
        let frame = scan_frame(&posed, project);
        for xy in frame.xy_m.chunks_exact(2) {
            data.extend_from_slice(&xy[0].to_le_bytes());
            data.extend_from_slice(&xy[1].to_le_bytes());
            data.extend_from_slice(&0f32.to_le_bytes());
            data.extend_from_slice(&(index as u32).to_le_bytes());
        }
    }
    PointCloud {
        timestamp: Some(stamp),
        frame_id: SITE_FRAME.into(),
        pose: None,
        point_stride: POINT_STRIDE,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("sensor", 12, NumericType::Uint32),
        ],
        data: Bytes::from(data),
    }
}

/// The map as a `foxglove.Grid`: int8 `occupancy`, -1 unknown, 0 free, 100 occupied, rows
/// from the origin's (bottom) up.
fn grid_message(c: &CoarseGrid, stamp: Timestamp) -> Grid {
    let data: Vec<u8> = c
        .cells
        .iter()
        .map(|&v| match v {
            1 => 0u8,
            2 => 100u8,
            _ => (-1i8) as u8,
        })
        .collect();
    Grid {
        timestamp: Some(stamp),
        frame_id: SITE_FRAME.into(),
        pose: Some(Pose {
            position: Some(Vector3 {
                x: c.origin_x_m,
                y: c.origin_y_m,
                z: 0.0,
            }),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
        column_count: c.width as u32,
        cell_size: Some(Vector2 {
            x: c.cell_m,
            y: c.cell_m,
        }),
        row_stride: c.width as u32,
        cell_stride: 1,
        fields: vec![field("occupancy", 0, NumericType::Int8)],
        data: Bytes::from(data),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::SensorPose;
    use nalgebra::Vector3 as V3;

    fn pose(id: &str, registered: bool, x: f64, y: f64, yaw_deg: f64) -> SensorPose {
        let mut p: SensorPose =
            serde_json::from_value(serde_json::json!({"id": id, "registered": registered}))
                .unwrap();
        if registered {
            p.x_m = Some(x);
            p.y_m = Some(y);
            p.yaw_deg = Some(yaw_deg);
        }
        p
    }

    #[test]
    fn transforms_name_every_placed_sensor_and_turn_like_its_pose() {
        let poses = Poses {
            anchor: "a".into(),
            sensors: vec![
                pose("a", true, 0.0, 0.0, 0.0),
                pose("b", true, 4.0, -2.0, 90.0),
                pose("c", false, 0.0, 0.0, 0.0),
            ],
            building_from_site: None,
            site_from_zone: None,
        };
        let placed = placed_poses(&poses);
        let tf = transforms(&placed, timestamp(5));
        let ids: Vec<&str> = tf
            .transforms
            .iter()
            .map(|t| t.child_frame_id.as_str())
            .collect();
        assert_eq!(ids, ["a", "b"], "the unplaced sensor has no transform");
        let b = &tf.transforms[1];
        assert_eq!(b.parent_frame_id, SITE_FRAME);
        let t = b.translation.unwrap();
        assert_eq!((t.x, t.y), (4.0, -2.0));
        // 90° about z: the sensor's +x is the site's +y.
        let q = b.rotation.unwrap();
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z));
        let x = q * V3::x();
        assert!((x - V3::y()).norm() < 1e-9, "{x}");
    }

    #[test]
    fn poses_are_sent_again_only_when_they_change() {
        let ctx = Context::new();
        let channels = Arc::new(Channels {
            tf: ctx.channel_builder(TF_TOPIC).build(),
            points: ctx.channel_builder(POINTS_TOPIC).build(),
            map: ctx.channel_builder(MAP_TOPIC).build(),
            sensors: ctx.channel_builder(SENSORS_TOPIC).build(),
        });
        let mut feed = Feed::new(&ctx, channels);
        let mut poses = Poses {
            anchor: "a".into(),
            sensors: vec![pose("a", true, 0.0, 0.0, 0.0)],
            building_from_site: None,
            site_from_zone: None,
        };
        assert!(feed.poses(&poses).is_some(), "the first are sent");
        assert!(feed.poses(&poses).is_none(), "unchanged: nothing");
        poses.sensors.push(pose("b", true, 1.0, 2.0, 3.0));
        let (tf, scene) = feed.poses(&poses).expect("a sensor placed: sent");
        assert_eq!(tf.transforms.len(), 2);
        assert_eq!(scene.entities.len(), 2);
        assert_eq!(scene.entities[1].frame_id, "b");
    }

    #[test]
    fn the_grid_keeps_walls_free_space_and_the_unknown() {
        let c = CoarseGrid {
            cell_m: 0.1,
            origin_x_m: -1.0,
            origin_y_m: -2.0,
            width: 3,
            height: 1,
            cells: vec![0, 1, 2],
        };
        let g = grid_message(&c, timestamp(1));
        assert_eq!(g.data.as_ref(), &[255u8, 0, 100]);
        assert_eq!((g.column_count, g.row_stride, g.cell_stride), (3, 3, 1));
        assert_eq!(g.pose.unwrap().position.unwrap().y, -2.0);
    }
}
