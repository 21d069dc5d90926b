//! The status socket's objects, in gpsd's manner: one JSON object per line, each with a
//! `class`; a field that is unknown is absent, never `null`.
//!
//! Requests carry `cmd`; replies and stream items carry `class`. The pose fields are the same
//! vocabulary as `scanfuse register --json` and `poses.toml`.

use serde::{Deserialize, Serialize};

/// Major protocol version: bumped when a client written for the old one would misread.
pub const PROTO_MAJOR: u32 = 1;
/// Minor protocol version: bumped when fields or classes are added.
pub const PROTO_MINOR: u32 = 8;

/// Request lines longer than this are rejected (and discarded up to their newline).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// True for a number that is absent or not finite: serde_json would write NaN as `null`, and
/// the protocol has no nulls, so such a value is left out ("unknown").
pub fn unknown(value: &Option<f64>) -> bool {
    !value.is_some_and(f64::is_finite)
}

/// What a client may ask.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "cmd", rename_all = "lowercase", deny_unknown_fields)]
pub enum Request {
    /// `{"cmd":"status"}` → [`Status`]. (Empty braces, so unknown fields are rejected.)
    Status {},
    /// `{"cmd":"poses"}` → [`Poses`].
    Poses {},
    /// `{"cmd":"watch","status":true,"map":false,"tracks":false}` → [`Watch`], then a stream
    /// of [`Event`]s (`status`), [`Frame`]s (`map`) and [`Tracks`], [`Zones`] and
    /// [`Crossing`]s (`tracks`, since protocol 1.2). All false stops the stream.
    Watch {
        /// Stream events (connects, moves, registrations…); default true.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        status: Option<bool>,
        /// Stream fused frames; default false.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        map: Option<bool>,
        /// Stream people: `TRACKS`, `ZONES`, `CROSSING`; default false.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        tracks: Option<bool>,
    },
    /// `{"cmd":"reregister","sensor":"hall"}` → [`Reregister`].
    Reregister { sensor: String },
    /// `{"cmd":"save"}` → [`Saved`].
    Save {},
    /// `{"cmd":"survey","sensor":"dock","x_m":…,"y_m":…,"yaw_deg":…,"sigma_xy_m":…,
    /// "sigma_yaw_deg":…}` → [`Survey`]: places the sensor there by hand (as `survey = {…}` in
    /// the config, kept in `state_dir` across restarts) and re-solves the others around it.
    /// The sigmas default to [`DEFAULT_SURVEY_SIGMA_XY_M`] and [`DEFAULT_SURVEY_SIGMA_YAW_DEG`].
    Survey {
        sensor: String,
        x_m: f64,
        y_m: f64,
        yaw_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sigma_xy_m: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sigma_yaw_deg: Option<f64>,
    },
    /// `{"cmd":"unsurvey","sensor":"dock"}` → [`Survey`]: forgets the survey set by hand, and
    /// registers the sensor from its scans again (a survey in the config still counts).
    Unsurvey { sensor: String },
    /// `{"cmd":"align","pairs":"sx,sy=dx,dy; …"}` → [`Poses`] (with `building_from_site`), since
    /// protocol 1.5: aligns the placed site to `[site] drawing` now, from two or more point
    /// pairs (site point = drawing point, m, as `scanfuse align --pairs`) refined on the lines,
    /// or automatically without `pairs`; replaces the alignment only when it finds one.
    Align {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pairs: Option<String>,
    },
}

/// A survey set by hand is this sure of the position unless the request says otherwise, m.
pub const DEFAULT_SURVEY_SIGMA_XY_M: f64 = 0.05;
/// …and of the heading, degrees.
pub const DEFAULT_SURVEY_SIGMA_YAW_DEG: f64 = 2.0;

/// Every reply or stream item the daemon sends, tagged by `class`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "class", rename_all = "UPPERCASE")]
pub enum Message {
    Version(Version),
    Status(Status),
    Poses(Poses),
    Watch(Watch),
    Reregister(Reregister),
    Saved(Saved),
    Survey(Survey),
    Event(Event),
    Frame(Frame),
    Tracks(Tracks),
    Zones(Zones),
    Crossing(Crossing),
    Error(ErrorReply),
}

impl Message {
    /// One protocol line, without the newline.
    pub fn to_line(&self) -> String {
        // Serializing these types cannot fail: no maps with non-string keys, no foreign types.
        serde_json::to_string(self).unwrap_or_else(|e| {
            format!(r#"{{"class":"ERROR","message":"internal error encoding a reply: {e}"}}"#)
        })
    }

    /// The `ERROR` reply with `message`.
    pub fn error(message: impl Into<String>) -> Message {
        Message::Error(ErrorReply {
            message: message.into(),
        })
    }
}

/// The banner sent on connect.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Version {
    /// The daemon's release, e.g. `0.1.0`.
    pub release: String,
    pub proto_major: u32,
    pub proto_minor: u32,
}

impl Version {
    /// This build's banner.
    pub fn current() -> Version {
        Version {
            release: env!("CARGO_PKG_VERSION").to_string(),
            proto_major: PROTO_MAJOR,
            proto_minor: PROTO_MINOR,
        }
    }
}

/// How a sensor's driver is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SensorState {
    /// Opening the connection or setting the sensor up.
    Connecting,
    /// Scans arriving.
    Streaming,
    /// Lost; the driver is waiting to reconnect.
    Disconnected,
    /// Gave up or cannot start (bad device, refused configuration); needs a person.
    Failed,
    /// Shut down on purpose.
    Stopped,
}

impl SensorState {
    pub fn as_str(self) -> &'static str {
        match self {
            SensorState::Connecting => "connecting",
            SensorState::Streaming => "streaming",
            SensorState::Disconnected => "disconnected",
            SensorState::Failed => "failed",
            SensorState::Stopped => "stopped",
        }
    }
}

/// Reply to `status`: the site and every sensor's driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Status {
    /// Site name from the config.
    pub site: String,
    /// Seconds since the daemon started.
    pub uptime_s: f64,
    /// Scans the registration worker's full queue dropped (oldest first), all sensors.
    #[serde(default)]
    pub queue_drops: u64,
    pub sensors: Vec<SensorStatus>,
    /// Where the page is served (`page at http://…`), or why it is not; absent without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub web: Option<String>,
    /// Where the Foxglove server listens (`Foxglove at ws://…`), or why it does not; absent
    /// without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub foxglove: Option<String>,
    /// The zone this daemon holds of a site on Zenoh (`[zenoh]`) and its endpoints, or why it
    /// is not on the network; since protocol 1.6, absent without `[zenoh]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<String>,
    /// A site daemon's zones, each with where it stands in the site frame or why it does not;
    /// since protocol 1.7, absent on a daemon that holds sensors.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub zones: Vec<ZoneStatus>,
}

/// One zone of a site, as the site daemon sees it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZoneStatus {
    pub zone: String,
    /// Its liveliness token is held: the zone daemon runs and its link is up.
    pub alive: bool,
    /// Seconds since it became alive or was lost.
    pub for_s: f64,
    /// Its sensors, and how many of them its own registration placed, from its last poses.
    pub sensors: usize,
    pub placed: usize,
    /// Bytes a second it sends the site daemon (poses, status and, when on, detections), over
    /// the last 10 s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bytes_per_s: Option<f64>,
    /// Its clock minus the site daemon's (s), from its payloads' stamps (the link's delay
    /// included: ms on a LAN); an error event names a zone more than 0.5 s off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_offset_s: Option<f64>,
    /// Where the zone's frame stands in the site frame; absent when it is not placed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub site_from_zone: Option<ZoneFrame>,
    /// Why it is not placed (or what its placement rests on).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// What it sends that this daemon cannot read, and why (since protocol 1.8); absent when
    /// everything reads.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreadable: Option<String>,
}

/// `site_from_zone`: a zone frame's pose in the site frame, with σ, in the pose vocabulary's
/// units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ZoneFrame {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_deg: f64,
    pub sigma_x_m: f64,
    pub sigma_y_m: f64,
    pub sigma_yaw_deg: f64,
    /// Cross-zone sensor pairs its link rests on (0 for the anchor zone).
    pub pairs: usize,
}

/// One sensor's driver in a [`Status`] reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorStatus {
    pub id: String,
    pub state: SensorState,
    /// The config's `connect` URI.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub connect: Option<String>,
    /// Model from the sensor's VV/PP reply, once connected.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// Scans per second over the last few seconds; absent before the first scans.
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub rate_hz: Option<f64>,
    /// Scans received since start.
    #[serde(default)]
    pub scans: u64,
    /// Scans dropped for a bad checksum.
    #[serde(default)]
    pub checksum_errors: u64,
    /// Times the connection was re-established.
    #[serde(default)]
    pub reconnects: u64,
    /// Seconds since the last scan; absent before the first.
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub last_scan_age_s: Option<f64>,
    /// The latest error, a sentence.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_error: Option<String>,
    /// Seconds since `last_error`.
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub last_error_age_s: Option<f64>,
    /// Share of its beams that return (0–1, over about the last second); absent before
    /// the first scan.
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub valid_returns: Option<f64>,
    /// Something wrong with what it sees (a covered lens), a sentence; absent when all is well.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}

impl SensorStatus {
    /// A sensor with nothing known yet but its id and state.
    pub fn new(id: impl Into<String>, state: SensorState) -> Self {
        SensorStatus {
            id: id.into(),
            state,
            connect: None,
            model: None,
            rate_hz: None,
            scans: 0,
            checksum_errors: 0,
            reconnects: 0,
            last_scan_age_s: None,
            last_error: None,
            last_error_age_s: None,
            valid_returns: None,
            warning: None,
        }
    }
}

/// How a pose was obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PoseSource {
    /// Loaded from `poses.toml` at start.
    Saved,
    /// Worked out from the scans.
    Registered,
    /// Worked out again after the sensor moved or on request.
    ReRegistered,
    /// Taken from the config's surveyed pose.
    Surveyed,
}

impl PoseSource {
    pub fn as_str(self) -> &'static str {
        match self {
            PoseSource::Saved => "saved",
            PoseSource::Registered => "registered",
            PoseSource::ReRegistered => "re-registered",
            PoseSource::Surveyed => "surveyed",
        }
    }
}

/// Reply to `poses`: where every sensor stands in the anchor's (the site's) frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Poses {
    pub anchor: String,
    pub sensors: Vec<SensorPose>,
    /// Where the site frame lies in the building drawing's (`poses.toml`'s
    /// `[building_from_site]`, `scanfuse align --json`'s vocabulary), since protocol 1.3;
    /// absent when the site has none. The poses above stay in the site frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub building_from_site: Option<crate::drawing::BuildingFromSite>,
    /// A zone daemon's: where its frame stands in the site frame of its site on Zenoh, as the
    /// site daemon last said (since protocol 1.9); absent until the site daemon places the
    /// zone. The poses above stay in the zone's frame: a sensor's site pose is
    /// `site_from_zone · zone_from_sensor`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub site_from_zone: Option<ZoneFrame>,
}

/// Declares a struct in the pose vocabulary: `id`, `registered`, the pose and its sigmas (left
/// out when unknown) and `reason`, then the struct's own fields. It exists so the socket's
/// [`SensorPose`] and `poses.toml`'s `SavedPose` share one list of fields while staying
/// separate structs (the file refuses unknown keys, which serde's `flatten` would switch off).
macro_rules! pose_vocabulary {
    ($(#[$attr:meta])* pub struct $name:ident { $($own:tt)* }) => {
        $(#[$attr])*
        pub struct $name {
            pub id: String,
            pub registered: bool,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub x_m: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub y_m: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub yaw_deg: Option<f64>,
            /// Height of the optical centre above the floor.
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub z_m: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub pitch_deg: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub sigma_x_m: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub sigma_y_m: Option<f64>,
            #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
            pub sigma_yaw_deg: Option<f64>,
            /// Why the sensor is not registered (or a caveat about its pose).
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub reason: Option<String>,
            $($own)*
        }
    };
}
pub(crate) use pose_vocabulary;

pose_vocabulary! {
    /// One sensor's pose, the one vocabulary of the socket and `scanfuse register --json` (which
    /// leaves `age_s` and `source` absent). An unregistered sensor has `registered: false`, a
    /// `reason` and no pose fields.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    pub struct SensorPose {
        /// Seconds since the pose was obtained.
        #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
        pub age_s: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub source: Option<PoseSource>,
        /// What placed it, as `register --json`'s pairs say: `"walls"`, `"walls+walkers"`
        /// or `"walkers"` (people alone); since protocol 1.4. Absent for the anchor, a pose
        /// loaded or surveyed, and a sensor not placed.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub evidence: Option<String>,
        /// The zone that holds it, on a site daemon's socket (since protocol 1.7); absent
        /// elsewhere.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub zone: Option<String>,
        /// Its zone is lost: this is the last pose heard from it, not a live one (since 1.7).
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        pub stale: bool,
    }
}

impl SensorPose {
    /// An unregistered sensor, with the reason.
    pub fn unregistered(id: impl Into<String>, reason: impl Into<String>) -> Self {
        SensorPose {
            id: id.into(),
            registered: false,
            x_m: None,
            y_m: None,
            yaw_deg: None,
            z_m: None,
            pitch_deg: None,
            sigma_x_m: None,
            sigma_y_m: None,
            sigma_yaw_deg: None,
            reason: Some(reason.into()),
            age_s: None,
            source: None,
            evidence: None,
            zone: None,
            stale: false,
        }
    }
}

/// Reply to `watch`: what the stream will now carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Watch {
    pub status: bool,
    pub map: bool,
    /// Absent from daemons before protocol 1.2 (which had no such stream).
    #[serde(default)]
    pub tracks: bool,
}

/// Reply to `reregister`: the request was accepted; the outcome follows as an [`Event`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Reregister {
    pub sensor: String,
    pub message: String,
}

/// Reply to `save`: what was written where.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Saved {
    /// The state directory.
    pub dir: String,
    /// File names written, relative to `dir`.
    pub files: Vec<String>,
}

/// Reply to `survey` and `unsurvey`: the sensor's hand-set survey now (absent once cleared);
/// the re-solve of the others follows as events.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Survey {
    pub sensor: String,
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub x_m: Option<f64>,
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub y_m: Option<f64>,
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub yaw_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub sigma_xy_m: Option<f64>,
    #[serde(default, skip_serializing_if = "crate::daemon::protocol::unknown")]
    pub sigma_yaw_deg: Option<f64>,
    /// A sentence for a person: what happens now.
    pub message: String,
}

/// What an [`Event`] reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EventKind {
    Connected,
    Disconnected,
    /// Registration has started (no pose yet); `registered` follows per sensor.
    Registering,
    Registered,
    Moved,
    ReRegistered,
    Saved,
    ConfigReloaded,
    /// A survey was set or cleared by hand (`survey` / `unsurvey`).
    Surveyed,
    /// A placed pose that people walking later contradicted was taken back.
    Withdrawn,
    /// The site was aligned to the building drawing (`building_from_site`).
    Aligned,
    Error,
}

/// Something that happened, streamed to watchers with `status` on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// RFC 3339 UTC.
    pub time: String,
    pub kind: EventKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<String>,
    /// A sentence for a person.
    pub message: String,
}

impl Event {
    /// An event stamped now (the wall clock).
    pub fn now(kind: EventKind, sensor: Option<&str>, message: impl Into<String>) -> Event {
        Event {
            time: humantime::format_rfc3339_millis(std::time::SystemTime::now()).to_string(),
            kind,
            sensor: sensor.map(str::to_string),
            message: message.into(),
        }
    }
}

/// One fused frame, streamed to watchers with `map` on: scans as points in the site frame.
/// The daemon sends each posed sensor's scan in a frame of its own the moment it arrives
/// (lowest latency); a watcher that wants the whole site keeps the latest frame per sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Host time of the newest scan in the frame, ns since the Unix epoch.
    pub stamp_ns: u64,
    pub scans: Vec<FrameScan>,
}

/// One sensor's points in a [`Frame`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameScan {
    pub sensor: String,
    pub stamp_ns: u64,
    /// Points in the site frame, flattened: `[x0, y0, x1, y1, …]`, m, to the millimetre.
    /// Finite values only:
    /// JSON has no NaN (serde_json would write `null`).
    pub xy_m: Vec<f32>,
}

/// The people tracked at one instant, streamed to watchers with `tracks` on (and written by
/// `scanfuse track`, one per line). Only confirmed tracks are listed; tentative ones are not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tracks {
    /// The scans' clock (a recording's own stamps in a replay), ns since the Unix epoch.
    pub t_ns: u64,
    pub tracks: Vec<Track>,
}

/// One tracked person, site frame (building frame when a drawing is set).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Track {
    /// Never reused within a run.
    pub id: u64,
    pub x_m: f64,
    pub y_m: f64,
    pub vx_m_s: f64,
    pub vy_m_s: f64,
    /// One-sigma position uncertainty (m): the root of the larger eigenvalue of the filter's
    /// position covariance.
    pub sigma_m: f64,
    /// Seconds since the track was born.
    pub age_s: f64,
    /// Sensors whose detections updated the track at this instant (empty while coasting).
    pub sensors: Vec<String>,
}

/// How many people stand in each configured zone (`[[zone]]`), streamed with `tracks`
/// whenever a count changes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Zones {
    pub t_ns: u64,
    pub zones: Vec<ZoneCount>,
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ZoneCount {
    pub id: String,
    /// Confirmed tracks inside the polygon now.
    pub count: u32,
    /// Ids of those tracks.
    pub tracks: Vec<u64>,
}

/// Which way a track crossed a counting line (`[[line]] from → to`): to the left of the
/// directed line, or to its right.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    Left,
    Right,
}

/// A track crossed a counting line, streamed with `tracks`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Crossing {
    pub t_ns: u64,
    /// The line's `id` from the config.
    pub line: String,
    pub track: u64,
    /// The side it crossed to.
    pub to: Side,
    /// Crossings of this line since the daemon started, to each side.
    pub left_total: u64,
    pub right_total: u64,
}

/// A failure, with a sentence a person can act on.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ErrorReply {
    pub message: String,
}

/// The commands a client may send, for error messages.
pub const COMMANDS: &str = r#"{"cmd":"status"}, {"cmd":"poses"}, {"cmd":"watch","status":true,"map":false,"tracks":false}, {"cmd":"reregister","sensor":"ID"}, {"cmd":"save"}, {"cmd":"survey","sensor":"ID","x_m":0.0,"y_m":0.0,"yaw_deg":0.0,"sigma_xy_m":0.05,"sigma_yaw_deg":2.0}, {"cmd":"unsurvey","sensor":"ID"}"#;

/// Parses one request line, or explains what is wrong and what would be valid.
pub fn parse_request(line: &[u8]) -> Result<Request, String> {
    let text = std::str::from_utf8(line)
        .map_err(|_| format!("the request is not UTF-8 text; send one of {COMMANDS}"))?;
    let value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| format!("the request is not valid JSON ({e}); send one of {COMMANDS}"))?;
    let Some(object) = value.as_object() else {
        return Err(format!(
            "the request must be a JSON object, not {}; send one of {COMMANDS}",
            kind_of(&value)
        ));
    };
    match object.get("cmd") {
        None => {
            return Err(format!(
                "the request has no \"cmd\"; send one of {COMMANDS}"
            ));
        }
        Some(serde_json::Value::String(_)) => {}
        Some(other) => {
            return Err(format!(
                "\"cmd\" must be a string, not {}; send one of {COMMANDS}",
                kind_of(other)
            ));
        }
    }
    serde_json::from_value(value)
        .map_err(|e| format!("bad request: {e}; valid requests: {COMMANDS}"))
}

fn kind_of(value: &serde_json::Value) -> &'static str {
    match value {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Whatever a client sends, the parser answers (a request or a sentence), never panics.
        #[test]
        fn any_bytes_get_an_answer(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            if let Err(message) = parse_request(&bytes) {
                prop_assert!(message.contains(COMMANDS));
            }
        }

        /// Requests survive encoding and parsing.
        #[test]
        fn requests_round_trip(sensor in "[a-z0-9_.-]{1,12}", status in any::<Option<bool>>(), map in any::<Option<bool>>(), tracks in any::<Option<bool>>()) {
            for request in [
                Request::Status {},
                Request::Poses {},
                Request::Watch { status, map, tracks },
                Request::Reregister { sensor: sensor.clone() },
                Request::Save {},
            ] {
                let line = serde_json::to_string(&request).unwrap();
                prop_assert!(!line.contains("null"));
                prop_assert_eq!(parse_request(line.as_bytes()), Ok(request));
            }
        }
    }

    #[test]
    fn requests_parse_with_defaults() {
        assert_eq!(
            parse_request(br#"{"cmd":"status"}"#),
            Ok(Request::Status {})
        );
        assert_eq!(
            parse_request(br#" {"cmd":"poses"} "#),
            Ok(Request::Poses {})
        );
        assert_eq!(
            parse_request(br#"{"cmd":"watch","map":true}"#),
            Ok(Request::Watch {
                status: None,
                map: Some(true),
                tracks: None,
            })
        );
        assert_eq!(
            parse_request(br#"{"cmd":"watch","tracks":true}"#),
            Ok(Request::Watch {
                status: None,
                map: None,
                tracks: Some(true),
            })
        );
        assert_eq!(
            parse_request(br#"{"cmd":"reregister","sensor":"hall"}"#),
            Ok(Request::Reregister {
                sensor: "hall".into()
            })
        );
        assert_eq!(parse_request(br#"{"cmd":"save"}"#), Ok(Request::Save {}));
        assert_eq!(
            parse_request(br#"{"cmd":"survey","sensor":"dock","x_m":1.5,"y_m":-2,"yaw_deg":90}"#),
            Ok(Request::Survey {
                sensor: "dock".into(),
                x_m: 1.5,
                y_m: -2.0,
                yaw_deg: 90.0,
                sigma_xy_m: None,
                sigma_yaw_deg: None,
            })
        );
        assert_eq!(
            parse_request(br#"{"cmd":"unsurvey","sensor":"dock"}"#),
            Ok(Request::Unsurvey {
                sensor: "dock".into()
            })
        );
        assert!(
            parse_request(br#"{"cmd":"survey","sensor":"dock","x_m":1}"#)
                .unwrap_err()
                .contains("missing field `y_m`")
        );
    }

    #[test]
    fn bad_requests_say_what_is_wrong_and_what_is_valid() {
        let cases: [(&[u8], &str); 7] = [
            (b"{\"cmd\":", "not valid JSON"),
            (b"[1,2]", "must be a JSON object, not an array"),
            (br#"{"sensor":"a"}"#, "no \"cmd\""),
            (br#"{"cmd":7}"#, "must be a string, not a number"),
            (br#"{"cmd":"fly"}"#, "unknown variant `fly`"),
            (br#"{"cmd":"reregister"}"#, "missing field `sensor`"),
            (
                br#"{"cmd":"status","verbose":true}"#,
                "unknown field `verbose`",
            ),
        ];
        for (line, want) in cases {
            let err = parse_request(line).unwrap_err();
            assert!(err.contains(want), "{err}");
            assert!(err.contains(r#"{"cmd":"status"}"#), "{err}");
        }
        assert!(parse_request(b"\xff\xfe").unwrap_err().contains("UTF-8"));
    }

    #[test]
    fn a_watch_reply_from_an_older_daemon_still_parses() {
        let old: Message =
            serde_json::from_str(r#"{"class":"WATCH","status":true,"map":false}"#).unwrap();
        assert_eq!(
            old,
            Message::Watch(Watch {
                status: true,
                map: false,
                tracks: false
            })
        );
        let crossing = Message::Crossing(Crossing {
            t_ns: 1,
            line: "door".into(),
            track: 2,
            to: Side::Right,
            left_total: 0,
            right_total: 1,
        })
        .to_line();
        assert_eq!(
            crossing,
            r#"{"class":"CROSSING","t_ns":1,"line":"door","track":2,"to":"right","left_total":0,"right_total":1}"#
        );
    }

    #[test]
    fn absent_fields_are_omitted_never_null() {
        let pose = SensorPose::unregistered("b", "no overlap with any other sensor");
        let line = Message::Poses(Poses {
            anchor: "a".into(),
            sensors: vec![pose],
            building_from_site: None,
            site_from_zone: None,
        })
        .to_line();
        assert_eq!(
            line,
            r#"{"class":"POSES","anchor":"a","sensors":[{"id":"b","registered":false,"reason":"no overlap with any other sensor"}]}"#
        );
        let status = Message::Status(Status {
            site: "s".into(),
            uptime_s: 1.5,
            queue_drops: 0,
            sensors: vec![SensorStatus::new("a", SensorState::Connecting)],
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        })
        .to_line();
        assert!(!status.contains("null"), "{status}");
        assert!(status.starts_with(r#"{"class":"STATUS","#), "{status}");
    }

    #[test]
    fn poses_carry_building_from_site_only_when_one_is_set() {
        let mut poses = Poses {
            anchor: "a".into(),
            sensors: Vec::new(),
            building_from_site: None,
            site_from_zone: None,
        };
        let line = Message::Poses(poses.clone()).to_line();
        assert!(!line.contains("building_from_site"), "{line}");
        poses.building_from_site = Some(crate::drawing::BuildingFromSite {
            x_m: 12.5,
            y_m: -3.0,
            yaw_deg: 23.0,
            scale: 1.0,
            aligned: true,
            method: "pairs+lines".into(),
            reason: None,
            ..Default::default()
        });
        let line = Message::Poses(poses).to_line();
        assert!(!line.contains("null"), "{line}");
        assert!(
            line.ends_with(
                r#""building_from_site":{"x_m":12.5,"y_m":-3.0,"yaw_deg":23.0,"scale":1.0,"aligned":true,"method":"pairs+lines"}}"#
            ),
            "{line}"
        );
    }

    #[test]
    fn numbers_that_are_not_finite_are_left_out() {
        let mut pose = SensorPose::unregistered("b", "singular covariance");
        pose.sigma_x_m = Some(f64::NAN);
        pose.age_s = Some(f64::INFINITY);
        pose.sigma_y_m = Some(0.25);
        let line = serde_json::to_string(&pose).unwrap();
        assert!(!line.contains("null"), "{line}");
        assert!(
            !line.contains("sigma_x_m") && !line.contains("age_s"),
            "{line}"
        );
        assert!(line.contains(r#""sigma_y_m":0.25"#), "{line}");
        let mut status = SensorStatus::new("a", SensorState::Streaming);
        status.rate_hz = Some(f64::NAN);
        assert!(!serde_json::to_string(&status).unwrap().contains("rate_hz"));
    }

    #[test]
    fn every_class_round_trips() {
        let mut pose = SensorPose::unregistered("b", "x");
        pose.registered = true;
        pose.reason = None;
        pose.x_m = Some(1.0);
        pose.source = Some(PoseSource::ReRegistered);
        let messages = [
            Message::Version(Version::current()),
            Message::Status(Status {
                site: "s".into(),
                uptime_s: 2.0,
                queue_drops: 3,
                sensors: vec![SensorStatus::new("a", SensorState::Streaming)],
                web: Some("page at http://127.0.0.1:8080/".into()),
                foxglove: None,
                zenoh: None,
                zones: Vec::new(),
            }),
            Message::Poses(Poses {
                anchor: "a".into(),
                sensors: vec![pose.clone()],
                building_from_site: None,
                site_from_zone: None,
            }),
            Message::Poses(Poses {
                anchor: "a".into(),
                sensors: vec![pose],
                building_from_site: Some(crate::drawing::BuildingFromSite {
                    x_m: 12.5,
                    y_m: -3.0,
                    yaw_deg: 23.0,
                    scale: 1.0,
                    aligned: true,
                    method: "automatic+lines".into(),
                    reason: None,
                    ..Default::default()
                }),
                site_from_zone: Some(ZoneFrame {
                    x_m: 40.5,
                    y_m: -0.25,
                    yaw_deg: 90.0,
                    sigma_x_m: 0.01,
                    sigma_y_m: 0.02,
                    sigma_yaw_deg: 0.1,
                    pairs: 6,
                }),
            }),
            Message::Watch(Watch {
                status: true,
                map: false,
                tracks: true,
            }),
            Message::Tracks(Tracks {
                t_ns: 7,
                tracks: vec![Track {
                    id: 3,
                    x_m: 4.1,
                    y_m: 2.0,
                    vx_m_s: 0.5,
                    vy_m_s: -0.25,
                    sigma_m: 0.04,
                    age_s: 12.5,
                    sensors: vec!["a".into(), "b".into()],
                }],
            }),
            Message::Zones(Zones {
                t_ns: 7,
                zones: vec![ZoneCount {
                    id: "desk".into(),
                    count: 1,
                    tracks: vec![3],
                }],
            }),
            Message::Crossing(Crossing {
                t_ns: 7,
                line: "door".into(),
                track: 3,
                to: Side::Left,
                left_total: 1,
                right_total: 0,
            }),
            Message::Reregister(Reregister {
                sensor: "a".into(),
                message: "queued".into(),
            }),
            Message::Saved(Saved {
                dir: "/d".into(),
                files: vec!["poses.toml".into()],
            }),
            Message::Survey(Survey {
                sensor: "a".into(),
                x_m: Some(1.0),
                y_m: Some(2.0),
                yaw_deg: Some(3.0),
                sigma_xy_m: Some(0.05),
                sigma_yaw_deg: None,
                message: "m".into(),
            }),
            Message::Event(Event {
                time: "2026-01-01T00:00:00Z".into(),
                kind: EventKind::ReRegistered,
                sensor: Some("a".into()),
                message: "m".into(),
            }),
            Message::Frame(Frame {
                stamp_ns: 5,
                scans: vec![FrameScan {
                    sensor: "a".into(),
                    stamp_ns: 5,
                    xy_m: vec![1.0, 2.0],
                }],
            }),
            Message::error("e"),
        ];
        for m in messages {
            let line = m.to_line();
            let back: Message = serde_json::from_str(&line).unwrap();
            assert_eq!(back, m, "{line}");
        }
        assert!(
            Message::Version(Version::current())
                .to_line()
                .contains(r#""proto_major":1"#)
        );
        assert!(
            serde_json::to_string(&PoseSource::ReRegistered)
                .unwrap()
                .contains("re-registered")
        );
    }
}
