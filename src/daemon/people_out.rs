//! The tracking outputs: one task that subscribes to the people stream
//! ([`Publisher::subscribe_people`]), counts zones and lines on every `TRACKS`
//! ([`Counter`]), publishes the `ZONES` and `CROSSING` it causes back to the stream (for
//! socket watchers and the page), and sends everything on to OSC (UDP) and MQTT.
//!
//! Nothing here waits on a receiver: OSC datagrams are sent without blocking, MQTT
//! publications are queued with `try_publish` (a full queue drops the message), and the MQTT
//! connection lives in a task of its own that reconnects with backoff. A broker that is down
//! is one error (log and `EVENT`), then one line when it is back.
//!
//! OSC address layout (one datagram per message, no bundles; floats are 32-bit):
//! - `/scanfuse/frame  ,hi  t_ns count` — starts each `TRACKS`;
//! - `/scanfuse/track  ,iffff  id x_m y_m vx_m_s vy_m_s` — one per track of that frame;
//! - `/scanfuse/zone  ,si  id count` — one per zone of a `ZONES`;
//! - `/scanfuse/crossing  ,sisii  line track side left_total right_total` (side `left`/`right`).
//!
//! Zones and lines drawn in building coordinates (`[site] zones_frame = "building"`) are moved
//! into the site frame, where the tracks are, through `building_from_site` as it is known
//! (watched: an alignment made later places them then); until it is, nothing is counted and
//! an `EVENT` says so once, rather than counting in the wrong place.
//!
//! MQTT topics (payloads are the protocol's JSON lines): `<prefix>/tracks` (QoS 0),
//! `<prefix>/zones` (QoS 1, retained, published again on every reconnect) and
//! `<prefix>/crossing` (QoS 1).

use std::future::Future;
use std::net::{SocketAddr, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rosc::{OscMessage, OscPacket, OscType};
use rumqttc::{AsyncClient, Event as MqttEvent, MqttOptions, Packet, QoS};
use tokio::sync::broadcast;

use super::config::{MqttConfig, PeopleConfig, ZonesFrame};
use super::protocol::{EventKind, Message, Side};
use super::socket::Publisher;
use crate::drawing::BuildingFromSite;
use crate::drawing::align::Similarity;
use crate::track::zones::{CountLine, Counter, Xy, Zone};

/// First wait before reconnecting to a broker; doubles up to [`MQTT_BACKOFF_MAX`].
pub const MQTT_BACKOFF_MIN: Duration = Duration::from_millis(500);
/// Longest wait between reconnection attempts.
pub const MQTT_BACKOFF_MAX: Duration = Duration::from_secs(15);
/// MQTT publications queued while the broker is slow or away; more are dropped.
const MQTT_QUEUE: usize = 64;
/// Largest MQTT packet (a `TRACKS` of 100 people is about 20 kB).
const MQTT_MAX_PACKET: usize = 1 << 20;

/// True when the config asks for anything this task does.
pub fn wanted(config: &PeopleConfig) -> bool {
    !config.zones.is_empty()
        || !config.lines.is_empty()
        || !config.osc_targets.is_empty()
        || config.mqtt.is_some()
}

/// Zones and lines given in building coordinates, in the site frame: each point taken back
/// through `building_from_site` (`p_site = R(−yaw) (p_b − t) / scale`), the lines' hysteresis
/// with them.
pub fn to_site(zones: &[Zone], lines: &[CountLine], t: &Similarity) -> (Vec<Zone>, Vec<CountLine>) {
    let p = |q: Xy| -> Xy {
        let v = t.to_site(&nalgebra::Point2::new(q[0], q[1]));
        [v.x, v.y]
    };
    let zones = zones
        .iter()
        .map(|z| Zone {
            id: z.id.clone(),
            polygon: z.polygon.iter().map(|q| p(*q)).collect(),
        })
        .collect();
    let lines = lines
        .iter()
        .map(|l| CountLine {
            id: l.id.clone(),
            from: p(l.from),
            to: p(l.to),
            hysteresis_m: l.hysteresis_m / t.scale,
        })
        .collect();
    (zones, lines)
}

/// The counter of `config`'s zones and lines in the site frame; `None` while they are in
/// building coordinates and the site is not aligned to the drawing.
fn site_counter(config: &PeopleConfig, building: Option<&BuildingFromSite>) -> Option<Counter> {
    match config.zones_frame {
        ZonesFrame::Site => Some(Counter::new(config.zones.clone(), config.lines.clone())),
        ZonesFrame::Building => {
            let t = building.and_then(BuildingFromSite::similarity)?;
            let (zones, lines) = to_site(&config.zones, &config.lines, &t);
            Some(Counter::new(zones, lines))
        }
    }
}

/// Runs the outputs of `config` until `shutdown` or until the publisher is gone. `site`
/// names this daemon to the broker; `building` is `building_from_site` as it changes.
pub async fn run(
    config: PeopleConfig,
    site: String,
    publisher: Publisher,
    mut building: tokio::sync::watch::Receiver<Option<BuildingFromSite>>,
    shutdown: impl Future<Output = ()>,
) {
    tokio::pin!(shutdown);
    let mut rx = publisher.subscribe_people();
    let counts = !config.zones.is_empty() || !config.lines.is_empty();
    let mut counter = site_counter(&config, building.borrow_and_update().as_ref());
    // Said once: building-frame zones wait for an alignment.
    let mut said_waiting = false;
    let mut osc = match OscSink::bind(config.osc_targets.clone()) {
        Ok(sink) => sink,
        Err(e) => {
            let why = format!("OSC output off: cannot open a UDP socket ({e})");
            tracing::error!("{why}");
            publisher.announce(EventKind::Error, None, why);
            None
        }
    };
    let mut mqtt = match &config.mqtt {
        None => None,
        Some(m) => match MqttSink::start(m, &site, publisher.clone()) {
            Ok(sink) => Some(sink),
            Err(why) => {
                tracing::error!("{why}");
                publisher.announce(EventKind::Error, None, why);
                None
            }
        },
    };
    loop {
        let message = tokio::select! {
            () = &mut shutdown => break,
            m = rx.recv() => m,
        };
        let message = match message {
            Ok(m) => m,
            Err(broadcast::error::RecvError::Lagged(n)) => {
                tracing::warn!("people outputs fell {n} messages behind; those were skipped");
                continue;
            }
            Err(broadcast::error::RecvError::Closed) => break,
        };
        // ZONES and CROSSING on the stream are this task's own, sent back below.
        let Message::Tracks(tracks) = message.as_ref() else {
            continue;
        };
        if config.zones_frame == ZonesFrame::Building && building.has_changed().unwrap_or(false) {
            counter = site_counter(&config, building.borrow_and_update().as_ref());
            if counter.is_some() && counts {
                tracing::info!("zones and lines placed in the site through building_from_site");
            }
        }
        if counter.is_none() && counts && !said_waiting {
            said_waiting = true;
            publisher.announce(
                EventKind::Error,
                None,
                "zones and lines are in building coordinates ([site] zones_frame = \"building\") but the site is not aligned to the drawing yet: nothing is counted until it is (scanfuse align --save, or replay --drawing)",
            );
        }
        let derived = counter
            .as_mut()
            .map(|c| c.update(tracks))
            .unwrap_or_default();
        for m in std::iter::once(message.as_ref()).chain(&derived) {
            if let Some(osc) = osc.as_mut() {
                osc.send(m);
            }
            if let Some(mqtt) = mqtt.as_mut() {
                mqtt.send(m);
            }
        }
        for m in derived {
            publisher.people(m);
        }
    }
    if let Some(mqtt) = mqtt {
        mqtt.stop();
    }
}

/// The OSC messages of one protocol message (see the module doc); empty for other classes.
pub fn osc_messages(message: &Message) -> Vec<OscMessage> {
    let msg = |addr: &str, args: Vec<OscType>| OscMessage {
        addr: addr.to_string(),
        args,
    };
    // OSC's integers are 32-bit; ids and totals beyond that wrap, which no site reaches.
    let int = |v: u64| OscType::Int(v as i32);
    match message {
        Message::Tracks(t) => {
            let mut out = vec![msg(
                "/scanfuse/frame",
                vec![
                    OscType::Long(i64::try_from(t.t_ns).unwrap_or(i64::MAX)),
                    int(t.tracks.len() as u64),
                ],
            )];
            out.extend(t.tracks.iter().map(|tr| {
                msg(
                    "/scanfuse/track",
                    vec![
                        int(tr.id),
                        OscType::Float(tr.x_m as f32),
                        OscType::Float(tr.y_m as f32),
                        OscType::Float(tr.vx_m_s as f32),
                        OscType::Float(tr.vy_m_s as f32),
                    ],
                )
            }));
            out
        }
        Message::Zones(z) => z
            .zones
            .iter()
            .map(|zone| {
                msg(
                    "/scanfuse/zone",
                    vec![OscType::String(zone.id.clone()), int(u64::from(zone.count))],
                )
            })
            .collect(),
        Message::Crossing(c) => vec![msg(
            "/scanfuse/crossing",
            vec![
                OscType::String(c.line.clone()),
                int(c.track),
                OscType::String(
                    match c.to {
                        Side::Left => "left",
                        Side::Right => "right",
                    }
                    .into(),
                ),
                int(c.left_total),
                int(c.right_total),
            ],
        )],
        _ => Vec::new(),
    }
}

/// Sends OSC datagrams to every target without blocking.
struct OscSink {
    v4: Option<UdpSocket>,
    v6: Option<UdpSocket>,
    targets: Vec<SocketAddr>,
    /// Targets already reported failing (reported once each).
    failing: Vec<SocketAddr>,
}

impl OscSink {
    /// `None` without targets.
    fn bind(targets: Vec<SocketAddr>) -> std::io::Result<Option<OscSink>> {
        if targets.is_empty() {
            return Ok(None);
        }
        let open = |addr: &str| -> std::io::Result<UdpSocket> {
            let s = UdpSocket::bind(addr)?;
            s.set_nonblocking(true)?;
            Ok(s)
        };
        let v4 = match targets.iter().any(SocketAddr::is_ipv4) {
            true => Some(open("0.0.0.0:0")?),
            false => None,
        };
        let v6 = match targets.iter().any(SocketAddr::is_ipv6) {
            true => Some(open("[::]:0")?),
            false => None,
        };
        Ok(Some(OscSink {
            v4,
            v6,
            targets,
            failing: Vec::new(),
        }))
    }

    fn send(&mut self, message: &Message) {
        for m in osc_messages(message) {
            let Ok(bytes) = rosc::encoder::encode(&OscPacket::Message(m)) else {
                continue;
            };
            for target in &self.targets {
                let socket = if target.is_ipv4() { &self.v4 } else { &self.v6 };
                let Some(socket) = socket else { continue };
                match socket.send_to(&bytes, target) {
                    Ok(_) => {
                        self.failing.retain(|t| t != target);
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                    Err(e) => {
                        if !self.failing.contains(target) {
                            tracing::warn!("OSC to {target}: {e}; going on");
                            self.failing.push(*target);
                        }
                    }
                }
            }
        }
    }
}

/// Publishes to an MQTT broker through a connection task of its own.
struct MqttSink {
    client: AsyncClient,
    prefix: String,
    /// The latest `ZONES` line, published again (retained) after every reconnect.
    zones: Arc<Mutex<Option<String>>>,
    task: tokio::task::JoinHandle<()>,
    dropped: u64,
}

impl MqttSink {
    fn start(config: &MqttConfig, site: &str, publisher: Publisher) -> Result<MqttSink, String> {
        let id: String = format!("scanfuse-{site}-{}", std::process::id())
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '-'
                }
            })
            .collect();
        let mut options = MqttOptions::new(id, config.host.clone(), config.port);
        options
            .set_keep_alive(Duration::from_secs(15))
            .set_clean_session(true)
            .set_max_packet_size(MQTT_MAX_PACKET, MQTT_MAX_PACKET);
        if let Some(user) = &config.username {
            let password = match &config.password_file {
                Some(path) => std::fs::read_to_string(path)
                    .map_err(|e| {
                        format!(
                            "MQTT output off: cannot read mqtt.password_file {}: {e}",
                            path.display()
                        )
                    })?
                    .trim_end_matches(['\r', '\n'])
                    .to_string(),
                None => String::new(),
            };
            options.set_credentials(user.clone(), password);
        }
        let (client, eventloop) = AsyncClient::new(options, MQTT_QUEUE);
        let zones = Arc::new(Mutex::new(None));
        let task = tokio::spawn(connection(
            eventloop,
            client.clone(),
            config.url.clone(),
            format!("{}/zones", config.topic_prefix),
            Arc::clone(&zones),
            publisher,
        ));
        Ok(MqttSink {
            client,
            prefix: config.topic_prefix.clone(),
            zones,
            task,
            dropped: 0,
        })
    }

    fn send(&mut self, message: &Message) {
        let (topic, qos, retain) = match message {
            Message::Tracks(_) => ("tracks", QoS::AtMostOnce, false),
            Message::Zones(_) => ("zones", QoS::AtLeastOnce, true),
            Message::Crossing(_) => ("crossing", QoS::AtLeastOnce, false),
            _ => return,
        };
        let line = message.to_line();
        if retain {
            *self.zones.lock().unwrap_or_else(|e| e.into_inner()) = Some(line.clone());
        }
        let topic = format!("{}/{topic}", self.prefix);
        if self.client.try_publish(topic, qos, retain, line).is_err() {
            // The broker is away or slow; the connection task has said so once.
            self.dropped += 1;
            if self.dropped.is_power_of_two() {
                tracing::debug!("MQTT: {} messages dropped so far", self.dropped);
            }
        }
    }

    fn stop(self) {
        let _ = self.client.try_disconnect();
        self.task.abort();
    }
}

/// Drives the MQTT connection: reconnects with backoff, says once that the broker is away
/// and once that it is back.
async fn connection(
    mut eventloop: rumqttc::EventLoop,
    client: AsyncClient,
    url: String,
    zones_topic: String,
    zones: Arc<Mutex<Option<String>>>,
    publisher: Publisher,
) {
    let mut down = false;
    let mut backoff = MQTT_BACKOFF_MIN;
    loop {
        match eventloop.poll().await {
            Ok(MqttEvent::Incoming(Packet::ConnAck(_))) => {
                let message = if down {
                    format!("MQTT broker {url} is back; publishing tracks again")
                } else {
                    format!("MQTT: publishing tracks to {url}")
                };
                tracing::info!("{message}");
                publisher.announce(EventKind::Connected, None, message);
                down = false;
                backoff = MQTT_BACKOFF_MIN;
                let latest = zones.lock().unwrap_or_else(|e| e.into_inner()).clone();
                if let Some(line) = latest {
                    let _ = client.try_publish(zones_topic.clone(), QoS::AtLeastOnce, true, line);
                }
            }
            Ok(_) => {}
            Err(e) => {
                if !down {
                    let message = format!(
                        "MQTT broker {url} cannot be reached ({e}); tracks are not published there until it is back (retrying quietly)"
                    );
                    tracing::error!("{message}");
                    publisher.announce(EventKind::Error, None, message);
                    down = true;
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(MQTT_BACKOFF_MAX);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::{Crossing, Track, Tracks, ZoneCount, Zones};

    #[test]
    fn osc_layout() {
        let tracks = Message::Tracks(Tracks {
            t_ns: 5_000_000_000,
            tracks: vec![Track {
                id: 3,
                x_m: 1.5,
                y_m: -2.0,
                vx_m_s: 0.25,
                vy_m_s: 0.0,
                sigma_m: 0.1,
                age_s: 1.0,
                sensors: vec![],
            }],
        });
        let m = osc_messages(&tracks);
        assert_eq!(m.len(), 2);
        assert_eq!(m[0].addr, "/scanfuse/frame");
        assert_eq!(
            m[0].args,
            vec![OscType::Long(5_000_000_000), OscType::Int(1)]
        );
        assert_eq!(m[1].addr, "/scanfuse/track");
        assert_eq!(
            m[1].args,
            vec![
                OscType::Int(3),
                OscType::Float(1.5),
                OscType::Float(-2.0),
                OscType::Float(0.25),
                OscType::Float(0.0)
            ]
        );
        let zones = Message::Zones(Zones {
            t_ns: 0,
            zones: vec![ZoneCount {
                id: "desk".into(),
                count: 2,
                tracks: vec![1, 2],
            }],
        });
        assert_eq!(
            osc_messages(&zones)[0].args,
            vec![OscType::String("desk".into()), OscType::Int(2)]
        );
        let crossing = Message::Crossing(Crossing {
            t_ns: 0,
            line: "door".into(),
            track: 3,
            to: Side::Right,
            left_total: 4,
            right_total: 5,
        });
        let c = &osc_messages(&crossing)[0];
        assert_eq!(c.addr, "/scanfuse/crossing");
        assert_eq!(c.args[2], OscType::String("right".into()));
        assert_eq!(c.args[4], OscType::Int(5));
        assert!(osc_messages(&Message::error("x")).is_empty());
    }

    /// The task counts on every TRACKS and sends ZONES and CROSSING back to the stream,
    /// ignoring its own messages when they come round again.
    #[tokio::test]
    async fn zones_and_crossings_go_back_to_the_stream() {
        use crate::track::zones::{CountLine, Zone};
        let publisher = Publisher::new(64);
        let config = PeopleConfig {
            zones: vec![Zone {
                id: "north".into(),
                polygon: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]],
            }],
            lines: vec![CountLine {
                id: "door".into(),
                from: [0.0, 0.0],
                to: [4.0, 0.0],
                hysteresis_m: 0.2,
            }],
            ..PeopleConfig::default()
        };
        let mut watcher = publisher.subscribe_people();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let (_building, rx) = tokio::sync::watch::channel(None);
        let task = tokio::spawn(run(config, "t".into(), publisher.clone(), rx, async move {
            let _ = stop_rx.await;
        }));
        // Wait for the task's subscription, then walk one person north through the door.
        while publisher.people_watchers() < 2 {
            tokio::task::yield_now().await;
        }
        for (i, y) in [-1.0, -0.5, 0.5, 1.0].iter().enumerate() {
            publisher.people(Message::Tracks(Tracks {
                t_ns: i as u64,
                tracks: vec![Track {
                    id: 7,
                    x_m: 2.0,
                    y_m: *y,
                    vx_m_s: 0.0,
                    vy_m_s: 1.0,
                    sigma_m: 0.05,
                    age_s: 1.0,
                    sensors: vec![],
                }],
            }));
        }
        let mut seen = Vec::new();
        while seen.len() < 7 {
            let m = watcher.recv().await.unwrap();
            seen.push(m.as_ref().clone());
        }
        let classes: Vec<&str> = seen
            .iter()
            .map(|m| match m {
                Message::Tracks(_) => "T",
                Message::Zones(_) => "Z",
                Message::Crossing(_) => "C",
                _ => "?",
            })
            .collect();
        // 4 TRACKS; ZONES at start (0) and when 7 entered (t 2); the crossing at t 2.
        assert_eq!(
            classes.iter().filter(|c| **c == "T").count(),
            4,
            "{classes:?}"
        );
        assert_eq!(
            classes.iter().filter(|c| **c == "Z").count(),
            2,
            "{classes:?}"
        );
        let crossing = seen.iter().find_map(|m| match m {
            Message::Crossing(c) => Some(c.clone()),
            _ => None,
        });
        let c = crossing.expect("a crossing");
        assert_eq!((c.track, c.to, c.t_ns), (7, Side::Left, 2));
        let _ = stop_tx.send(());
        task.await.unwrap();
    }

    /// Zones drawn on the drawing are placed through building_from_site: counted nothing,
    /// with one EVENT, until the site is aligned; then counted where the drawing puts them.
    #[tokio::test]
    async fn building_frame_zones_wait_for_the_alignment_then_count_in_the_right_place() {
        let publisher = Publisher::new(64);
        // In the building 10–14 × 20–24; the site origin stands at (10, 20), turned 90°, so
        // the site point (2, −2) is the building's (12, 22): inside. The untransformed square
        // would not hold it.
        let config = PeopleConfig {
            zones: vec![Zone {
                id: "lobby".into(),
                polygon: vec![[10.0, 20.0], [14.0, 20.0], [14.0, 24.0], [10.0, 24.0]],
            }],
            zones_frame: ZonesFrame::Building,
            ..PeopleConfig::default()
        };
        let mut watcher = publisher.subscribe_people();
        let mut events = publisher.subscribe_events();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let (building, rx) = tokio::sync::watch::channel(None);
        let task = tokio::spawn(run(config, "t".into(), publisher.clone(), rx, async move {
            let _ = stop_rx.await;
        }));
        while publisher.people_watchers() < 2 {
            tokio::task::yield_now().await;
        }
        let tracks = |t_ns: u64| {
            Message::Tracks(Tracks {
                t_ns,
                tracks: vec![Track {
                    id: 3,
                    x_m: 2.0,
                    y_m: -2.0,
                    vx_m_s: 0.0,
                    vy_m_s: 0.0,
                    sigma_m: 0.05,
                    age_s: 1.0,
                    sensors: vec![],
                }],
            })
        };
        for t in 0..2 {
            publisher.people(tracks(t));
        }
        for _ in 0..2 {
            let m = watcher.recv().await.unwrap();
            assert!(matches!(m.as_ref(), Message::Tracks(_)), "{m:?}");
        }
        let said = events.recv().await.unwrap();
        assert!(said.contains("not aligned to the drawing yet"), "{said}");
        building
            .send(Some(BuildingFromSite {
                x_m: 10.0,
                y_m: 20.0,
                yaw_deg: 90.0,
                aligned: true,
                method: "pairs+lines".into(),
                ..BuildingFromSite::default()
            }))
            .unwrap();
        publisher.people(tracks(2));
        let mut zones = None;
        while zones.is_none() {
            if let Message::Zones(z) = watcher.recv().await.unwrap().as_ref() {
                zones = Some(z.clone());
            }
        }
        let z = zones.unwrap();
        assert_eq!(z.t_ns, 2, "nothing counted before the alignment: {z:?}");
        assert_eq!((z.zones[0].count, z.zones[0].tracks.clone()), (1, vec![3]));
        // Said once only.
        assert!(events.try_recv().is_err());
        let _ = stop_tx.send(());
        task.await.unwrap();
    }

    #[test]
    fn to_site_inverts_building_from_site_with_scale() {
        let t = Similarity {
            x_m: 5.0,
            y_m: -3.0,
            yaw_rad: 0.7,
            scale: 2.0,
        };
        let site_pt = nalgebra::Point2::new(1.5, 4.0);
        let b = t.apply(&site_pt);
        let (zones, lines) = to_site(
            &[Zone {
                id: "z".into(),
                polygon: vec![[b.x, b.y]],
            }],
            &[CountLine {
                id: "l".into(),
                from: [b.x, b.y],
                to: [b.x, b.y],
                hysteresis_m: 0.4,
            }],
            &t,
        );
        let p = zones[0].polygon[0];
        assert!(
            (p[0] - 1.5).abs() < 1e-9 && (p[1] - 4.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!((lines[0].hysteresis_m - 0.2).abs() < 1e-12);
    }
}
