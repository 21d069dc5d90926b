//! The site config: one TOML file naming the site, where state and the socket live, and every
//! sensor with its connection, mount and optional surveyed pose.
//!
//! Parsing is pure ([`Config::parse`]); [`Config::load`] adds the file reads. Every error names
//! `file:line`, the key and what would be valid, so a person can fix the file without docs.

use std::collections::BTreeMap;
use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::Spanned;

use crate::scan::check_sensor_id;
use crate::track::zones::{self, CountLine, DEFAULT_HYSTERESIS_M, Zone};

/// Default state directory (systemd's `StateDirectory=scanfuse`).
pub const DEFAULT_STATE_DIR: &str = "/var/lib/scanfuse";
/// Default socket path (systemd's `RuntimeDirectory=scanfuse`).
pub const DEFAULT_SOCKET: &str = "/run/scanfuse/scanfuse.sock";
/// Default socket mode: owner and group may connect.
pub const DEFAULT_SOCKET_MODE: u32 = 0o660;
/// Default cap on simultaneous status-socket clients.
pub const DEFAULT_MAX_CLIENTS: usize = 16;
/// Default serial speed; SCIP over USB ignores it, but the tty wants one.
pub const DEFAULT_BAUD: u32 = 115_200;
/// Serial speeds SCIP 2.0 sensors accept.
pub const BAUD_RATES: [u32; 7] = [19_200, 38_400, 57_600, 115_200, 250_000, 500_000, 750_000];

/// A validated config. Paths are absolute or relative to the working directory (relative
/// paths in the file are resolved against the file's folder).
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The file this was read from.
    pub path: PathBuf,
    pub site: SiteConfig,
    pub sensors: Vec<SensorConfig>,
    pub registration: RegistrationConfig,
    pub publish: PublishConfig,
    pub web: WebConfig,
    /// `[[zone]]`, `[[line]]`, `[osc]`, `[mqtt]`: what is done with the tracks.
    pub people: PeopleConfig,
    pub foxglove: FoxgloveConfig,
    /// `[track]`: the people tracker.
    pub track: TrackConfig,
    /// `[zenoh]`: this daemon as one zone of a site spread over several machines; `None`
    /// runs the site alone.
    pub zenoh: Option<ZenohConfig>,
    /// `[[survey]]`, the site daemon's: units of its zones surveyed in the site frame (the
    /// anchor zone's), each a second anchor that holds its zone (`register::zones`).
    pub surveys: Vec<UnitSurvey>,
}

/// One `[[survey]]`: a zone's unit measured in the site frame.
#[derive(Debug, Clone, PartialEq)]
pub struct UnitSurvey {
    pub sensor: String,
    pub survey: Survey,
}

/// `[zenoh]`: the zone this daemon holds of a site that spans several machines, and how it
/// reaches the others (`crate::daemon::zone_net`). Explicit endpoints only: multicast
/// scouting stays off, as rmw_zenoh has it. (Not `[zone]`: `[[zone]]` is a counting area.)
#[derive(Debug, Clone, PartialEq)]
pub struct ZenohConfig {
    /// This daemon's zone of the site, unique per site; it names its keys
    /// (`scanfuse/<site>/<zone>/…`), so letters, digits, `-` and `_` only.
    pub zone: String,
    /// `tcp/HOST:PORT` endpoints to connect to: another daemon's `listen`, or a router's.
    pub connect: Vec<String>,
    /// `tcp/HOST:PORT` endpoints others connect to (a small site needs no router).
    pub listen: Vec<String>,
    /// A zone sends what its tracker's every scan saw (`detections`), so the site daemon
    /// tracks people across zones; off by default (a stream: ~6 kB/s per 20 Hz unit with a
    /// few people in view, `tests/zenoh_site.rs`).
    pub detections: bool,
    /// A zone sends each placed unit's latest scan this often (`scan/<sensor>`), for the site
    /// daemon's fused map; off when absent (a stream: ~7 kB per scan of a 1,081-beam unit).
    pub scans_hz: Option<f64>,
}

impl ZenohConfig {
    /// "zone east of site hall on Zenoh, listening on …, connecting to … (keys
    /// scanfuse/hall/east/…)", or for the site daemon "the site daemon of site hall on Zenoh,
    /// hosting the router on …", for `check` and `status`.
    pub fn describe(&self, site: &str) -> String {
        let mut ends = Vec::new();
        let site_daemon = self.zone == SITE_KEY;
        if !self.listen.is_empty() {
            let verb = if site_daemon {
                "hosting the router on"
            } else {
                "listening on"
            };
            ends.push(format!("{verb} {}", self.listen.join(", ")));
        }
        if !self.connect.is_empty() {
            ends.push(format!("connecting to {}", self.connect.join(", ")));
        }
        if self.detections {
            ends.push("sending what its tracker sees".to_string());
        }
        if let Some(hz) = self.scans_hz {
            ends.push(format!("sending each unit's scan {hz} times a second"));
        }
        let who = if site_daemon {
            "the site daemon".to_string()
        } else {
            format!("zone {}", self.zone)
        };
        format!(
            "{who} of site {site} on Zenoh, {} (keys scanfuse/{site}/{zone}/…)",
            ends.join(", "),
            zone = self.zone,
        )
    }
}

/// `[track]`: whether the daemon follows people, and the two times a site tunes.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackConfig {
    pub enabled: bool,
    /// Something that stands still this long becomes background (a box put down); a person
    /// standing still stays a person at least this long. At least 60 s.
    pub background_s: f64,
    /// A track unseen this long ends (a person hidden behind another keeps their id for this
    /// long).
    pub death_s: f64,
}

impl Default for TrackConfig {
    fn default() -> Self {
        let p = crate::track::TrackParams::default();
        TrackConfig {
            enabled: true,
            background_s: p.background.absorb_s,
            death_s: p.death_s,
        }
    }
}

impl TrackConfig {
    /// The tracker's settings: the defaults with this section's times.
    pub fn params(&self) -> crate::track::TrackParams {
        let mut p = crate::track::TrackParams::default();
        p.background.absorb_s = self.background_s;
        p.death_s = self.death_s;
        p
    }
}

/// The tracking outputs: zones and lines counted, and where tracks are sent besides the
/// status socket and the page.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PeopleConfig {
    pub zones: Vec<Zone>,
    pub lines: Vec<CountLine>,
    /// `[site] zones_frame`: the frame the zones' and lines' coordinates are in.
    pub zones_frame: ZonesFrame,
    /// `[osc] targets`: UDP addresses every OSC message goes to; empty sends none.
    pub osc_targets: Vec<std::net::SocketAddr>,
    /// `[mqtt]`; `None` publishes nothing.
    pub mqtt: Option<MqttConfig>,
}

/// The frame `[[zone]]` and `[[line]]` are drawn in (`[site] zones_frame`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ZonesFrame {
    /// The site frame (the anchor sensor's), as the tracks are.
    #[default]
    Site,
    /// The building drawing's: placed through `building_from_site` once the site is aligned
    /// to the drawing; nothing is counted before.
    Building,
}

/// MQTT broker port unless the url names one.
pub const DEFAULT_MQTT_PORT: u16 = 1883;

/// `[mqtt]`: the broker tracks, zones and crossings are published to.
#[derive(Debug, Clone, PartialEq)]
pub struct MqttConfig {
    /// The url as written, for messages.
    pub url: String,
    pub host: String,
    pub port: u16,
    /// Topics are `<topic_prefix>/tracks`, `/zones`, `/crossing`; default `scanfuse/<site>`.
    pub topic_prefix: String,
    pub username: Option<String>,
    /// A file holding the password (read when the daemon connects).
    pub password_file: Option<PathBuf>,
}

/// Where the page listens unless `[web] listen` says otherwise.
pub const DEFAULT_WEB_LISTEN: &str = "127.0.0.1:8080";

/// `[web]`: the live page (see `crate::web`).
#[derive(Debug, Clone, PartialEq)]
pub struct WebConfig {
    /// Where the page is served; `None` (`listen = ""`) serves none.
    pub listen: Option<std::net::SocketAddr>,
    /// The secret every client must give on a listener that is not loopback.
    pub token_file: Option<PathBuf>,
    /// Page clients served at once; more get 503.
    pub max_clients: usize,
    /// Scans of one sensor sent to each page per second at most.
    pub frames_per_s: f64,
    /// Messages a page may fall behind before it skips to the latest state.
    pub send_queue: usize,
}

impl Default for WebConfig {
    fn default() -> Self {
        WebConfig {
            listen: DEFAULT_WEB_LISTEN.parse().ok(),
            token_file: None,
            max_clients: 8,
            frames_per_s: 10.0,
            send_queue: 64,
        }
    }
}

impl WebConfig {
    /// No page (`scanfuse replay` without `--web`, in-process tests).
    pub fn off() -> WebConfig {
        WebConfig {
            listen: None,
            ..WebConfig::default()
        }
    }
}

/// `[foxglove]`: the live site as a Foxglove WebSocket server (see `crate::web::foxglove`).
/// Read-only: a Foxglove client sees the site but cannot change it.
#[derive(Debug, Clone, PartialEq)]
pub struct FoxgloveConfig {
    /// Where it is served; `None` (the default, or `listen = ""`) serves none.
    pub listen: Option<std::net::SocketAddr>,
    /// Scans of one sensor (and fused clouds) sent per second at most.
    pub frames_per_s: f64,
    /// Messages a client may fall behind; past that its oldest are dropped.
    pub send_queue: usize,
}

impl Default for FoxgloveConfig {
    fn default() -> Self {
        FoxgloveConfig {
            listen: None,
            frames_per_s: 10.0,
            send_queue: 256,
        }
    }
}

/// The token file's checks (`scanfuse check`, start): it exists, holds at least 128 bits as
/// text and is not readable by everyone.
pub fn check_token_file(path: &Path) -> Result<(), String> {
    use std::os::unix::fs::PermissionsExt;
    let make = "make one with: head -c 24 /dev/urandom | base64 > FILE && chmod 600 FILE";
    let meta = std::fs::metadata(path)
        .map_err(|e| format!("cannot read the token file {}: {e}; {make}", path.display()))?;
    if meta.permissions().mode() & 0o004 != 0 {
        return Err(format!(
            "the token file {} is readable by everyone; chmod 600 (or 640) it",
            path.display()
        ));
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read the token file {}: {e}", path.display()))?;
    let token = text.trim();
    if token.len() < MIN_TOKEN_CHARS || !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(format!(
            "the token file {} must hold one secret of at least {MIN_TOKEN_CHARS} printable characters without spaces (128 bits or more); {make}",
            path.display()
        ));
    }
    Ok(())
}

/// Shortest token accepted: 32 characters of base64 or hex carry at least 128 bits.
pub const MIN_TOKEN_CHARS: usize = 32;

/// `[site]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SiteConfig {
    pub name: String,
    /// Where `poses.toml` and the map files go.
    pub state_dir: PathBuf,
    /// The status socket's path.
    pub socket: PathBuf,
    /// Permission bits of the socket file.
    pub socket_mode: u32,
    /// The sensor whose frame is the site frame; for a site daemon (`role = "site"`), the
    /// zone whose frame is.
    pub anchor: String,
    /// `role`: a daemon that holds sensors (alone, or as one zone of a site with `[zenoh]`),
    /// or the site daemon that joins zones on Zenoh and holds none.
    pub role: Role,
    /// Status-socket clients served at once; more are refused.
    pub max_clients: usize,
    /// The building drawing (`drawing`, `drawing_layers`, `drawing_scale`, `drawing_pairs`):
    /// the placed site is aligned to it (`align_live`) and it is drawn under the map on the
    /// page once `building_from_site` is known.
    pub drawing: Option<DrawingConfig>,
}

/// What a daemon is (`[site] role`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Role {
    /// It holds sensors (`"zone"`, the default): the whole site, or one zone of it.
    #[default]
    Zone,
    /// It holds no sensors and joins the zones on Zenoh into one site frame (`"site"`).
    Site,
}

/// The zone name a site daemon takes in the key space (`scanfuse/<site>/site/…`); no zone may
/// be called so.
pub const SITE_KEY: &str = "site";

/// `[site] drawing = "FILE"` with its layers and scale (as `scanfuse align` takes them).
#[derive(Debug, Clone, PartialEq)]
pub struct DrawingConfig {
    pub path: PathBuf,
    /// Layers that hold walls; `None` keeps all.
    pub layers: Option<Vec<String>>,
    /// Metres per drawing unit (SVG, rasters, a DXF without `$INSUNITS`).
    pub scale_m_per_unit: Option<f64>,
    /// `drawing_pairs`: site points and the drawing points they lie at (m), as `scanfuse
    /// align --pairs` takes them; empty: aligned automatically.
    pub pairs: Vec<crate::drawing::align::PointPair>,
}

/// One `[[sensor]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorConfig {
    pub id: String,
    pub connect: Connect,
    pub mode: ScanMode,
    /// Height of the optical centre above the floor; unknown if absent.
    pub height_m: Option<f64>,
    /// Pitch of the scan plane, positive up.
    pub pitch_rad: f64,
    pub survey: Option<Survey>,
    /// Line of the sensor's `id` in the file, for later messages about it.
    pub line: usize,
}

/// Where a sensor's scans come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Connect {
    /// `tcp://HOST:PORT` (Ethernet units).
    Tcp { host: String, port: u16 },
    /// `serial:///dev/ttyACM0[?baud=115200]` (USB units).
    Serial { device: PathBuf, baud: u32 },
    /// `replay:FILE.mcap#ID`: sensor `ID` of a recording, served by an in-process emulator.
    Replay { file: PathBuf, sensor: String },
}

impl fmt::Display for Connect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Connect::Tcp { host, port } if host.contains(':') => write!(f, "tcp://[{host}]:{port}"),
            Connect::Tcp { host, port } => write!(f, "tcp://{host}:{port}"),
            Connect::Serial { device, baud } => {
                write!(f, "serial://{}?baud={baud}", device.display())
            }
            Connect::Replay { file, sensor } => write!(f, "replay:{}#{sensor}", file.display()),
        }
    }
}

const CONNECT_FORMS: &str =
    "tcp://HOST:PORT, serial:///dev/DEVICE[?baud=115200] or replay:FILE.mcap#SENSOR_ID";

impl Connect {
    /// Parses a `connect` URI; relative replay files are resolved against `base_dir`.
    pub fn parse(uri: &str, base_dir: &Path) -> Result<Connect, String> {
        if let Some(rest) = uri.strip_prefix("tcp://") {
            let rest = rest.strip_suffix('/').unwrap_or(rest);
            let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
                let Some((host, port)) = v6.split_once("]:") else {
                    return Err(format!(
                        "{uri:?}: an IPv6 address needs the form tcp://[ADDR]:PORT"
                    ));
                };
                (host, port)
            } else {
                let Some((host, port)) = rest.rsplit_once(':') else {
                    return Err(format!(
                        "{uri:?} has no port; write tcp://HOST:PORT, e.g. tcp://192.168.0.10:10940"
                    ));
                };
                if host.contains(':') {
                    return Err(format!(
                        "{uri:?}: put an IPv6 address in brackets, tcp://[ADDR]:PORT"
                    ));
                }
                (host, port)
            };
            let ok_host = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | ':' | '_');
            if host.is_empty() || !host.chars().all(ok_host) {
                return Err(format!("{uri:?}: {host:?} is not a host name or address"));
            }
            let port: u16 = match port.parse() {
                Ok(p) if p > 0 => p,
                _ => {
                    return Err(format!(
                        "{uri:?}: port {port:?} is not a number 1–65535 (Hokuyo's default is 10940)"
                    ));
                }
            };
            return Ok(Connect::Tcp {
                host: host.to_string(),
                port,
            });
        }
        if let Some(rest) = uri.strip_prefix("serial://") {
            let (device, query) = match rest.split_once('?') {
                Some((d, q)) => (d, Some(q)),
                None => (rest, None),
            };
            if !device.starts_with('/') || device.len() < 2 {
                return Err(format!(
                    "{uri:?}: the device must be an absolute path, e.g. serial:///dev/ttyACM0"
                ));
            }
            let mut baud = DEFAULT_BAUD;
            if let Some(query) = query {
                let Some(value) = query.strip_prefix("baud=") else {
                    return Err(format!(
                        "{uri:?}: the only option is ?baud=N, not {query:?}"
                    ));
                };
                baud = match value.parse() {
                    Ok(b) if BAUD_RATES.contains(&b) => b,
                    _ => {
                        return Err(format!(
                            "{uri:?}: baud {value:?} is not one of {BAUD_RATES:?}"
                        ));
                    }
                };
            }
            return Ok(Connect::Serial {
                device: PathBuf::from(device),
                baud,
            });
        }
        if let Some(rest) = uri.strip_prefix("replay:") {
            let Some((file, sensor)) = rest.rsplit_once('#') else {
                return Err(format!(
                    "{uri:?} names no sensor; write replay:FILE.mcap#SENSOR_ID"
                ));
            };
            if file.is_empty() {
                return Err(format!(
                    "{uri:?} names no file; write replay:FILE.mcap#SENSOR_ID"
                ));
            }
            check_sensor_id(sensor).map_err(|e| format!("{uri:?}: {e}"))?;
            let file = Path::new(file);
            let file = if file.is_absolute() {
                file.to_path_buf()
            } else {
                base_dir.join(file)
            };
            return Ok(Connect::Replay {
                file,
                sensor: sensor.to_string(),
            });
        }
        Err(format!("{uri:?} is not a connection; use {CONNECT_FORMS}"))
    }
}

/// SCIP streaming command a sensor is driven with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub enum ScanMode {
    /// Ranges only.
    MD,
    /// Ranges and intensities.
    ME,
    /// Multi-echo ranges (SCIP 2.2 units such as the UXM-30LX-E).
    ND,
}

/// A pose measured by other means (e.g. a total station), with its uncertainty; site frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Survey {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_rad: f64,
    pub sigma_xy_m: f64,
    pub sigma_yaw_rad: f64,
}

/// `[registration]`: the registration worker and moved-sensor detection.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegistrationConfig {
    /// Scans queued for the registration worker; when full the oldest is dropped and counted.
    /// The queue holds at least [`QUEUE_SCANS_PER_SENSOR`] per sensor whatever this says (see
    /// [`RegistrationConfig::queue_len`]).
    pub queue_scans: usize,
    /// Seconds of scans whose per-beam median is a sensor's static view (people walking by
    /// drop out); registration and moved detection wait for this much.
    pub static_view_s: f64,
    /// Fraction of a sensor's static background that must change for it to count as moved.
    pub moved_fraction: f64,
    /// The change must persist this long (rules out a person walking by, one glitchy scan).
    pub moved_persist_s: f64,
    /// Local refinement of a moved sensor searches this far from its old position first…
    pub refine_radius_m: f64,
    /// …and this far in heading, before falling back to a global search.
    pub refine_yaw_deg: f64,
    /// Seconds of people walking kept per sensor (one scan per 0.1 s, ranges only: about
    /// 1.3 MB for a 1081-beam unit over 30 s): unplaced sensors are tried again as walkers
    /// accrue, and placed ones that walkers contradict are withdrawn. 0 turns it off (the
    /// static view's window alone, where walkers only refute).
    pub motion_buffer_s: f64,
}

/// The registration queue holds at least this many scans per sensor: 1.6 s of a 40 Hz unit,
/// longer than the worker's walker check stalls it (~1.5 s at 100 units), so that a large
/// site does not lose scans to it.
pub const QUEUE_SCANS_PER_SENSOR: usize = 64;

impl RegistrationConfig {
    /// The registration queue's length for a site of `sensors` (at start): `queue_scans`,
    /// or [`QUEUE_SCANS_PER_SENSOR`] per sensor when that is more.
    pub fn queue_len(&self, sensors: usize) -> usize {
        self.queue_scans
            .max(QUEUE_SCANS_PER_SENSOR.saturating_mul(sensors))
    }
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        RegistrationConfig {
            queue_scans: 256,
            static_view_s: 1.0,
            moved_fraction: 0.3,
            moved_persist_s: 0.5,
            refine_radius_m: 0.5,
            refine_yaw_deg: 10.0,
            motion_buffer_s: 30.0,
        }
    }
}

/// `[publish]`: the fused map and what is written where.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PublishConfig {
    /// Occupancy grid cell size.
    pub map_cell_m: f64,
    /// Map files and `poses.toml` are written this often (and on `save` and at shutdown);
    /// 0 writes only on `save` and at shutdown.
    pub save_interval_s: f64,
    /// The fused cloud and occupancy grid take the latest scans this often (the `watch` map
    /// stream is not paced: every posed scan is sent as it arrives).
    pub map_rate_hz: f64,
    /// Messages a watcher may fall behind before it is dropped.
    pub watch_backlog: usize,
    /// `map.yaml`: cells at least this likely occupied are drawn occupied (ROS default 0.65).
    pub occupied_thresh: f64,
    /// `map.yaml`: cells at most this likely occupied are drawn free (ROS default 0.196).
    pub free_thresh: f64,
}

impl Default for PublishConfig {
    fn default() -> Self {
        PublishConfig {
            map_cell_m: 0.05,
            save_interval_s: 60.0,
            map_rate_hz: 10.0,
            watch_backlog: 256,
            occupied_thresh: 0.65,
            free_thresh: 0.196,
        }
    }
}

/// A config that cannot be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    #[error("cannot read the config {}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}", located(path, *line, key, message))]
    Invalid {
        path: PathBuf,
        /// 1-based line in the file.
        line: usize,
        /// Dotted key, e.g. `sensor.connect`; empty for a syntax error.
        key: String,
        /// What is wrong and what would be valid.
        message: String,
    },
}

fn located(path: &Path, line: usize, key: &str, message: &str) -> String {
    if key.is_empty() {
        format!("{}:{line}: {message}", path.display())
    } else {
        format!("{}:{line}: {key}: {message}", path.display())
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    site: Spanned<RawSite>,
    #[serde(default)]
    sensor: Vec<Spanned<RawSensor>>,
    #[serde(default)]
    registration: Option<Spanned<RegistrationConfig>>,
    #[serde(default)]
    publish: Option<Spanned<PublishConfig>>,
    #[serde(default)]
    web: Option<Spanned<RawWeb>>,
    #[serde(default)]
    zone: Vec<Spanned<RawZone>>,
    #[serde(default)]
    line: Vec<Spanned<RawLine>>,
    #[serde(default)]
    osc: Option<Spanned<RawOsc>>,
    #[serde(default)]
    mqtt: Option<Spanned<RawMqtt>>,
    #[serde(default)]
    foxglove: Option<Spanned<RawFoxglove>>,
    #[serde(default)]
    track: Option<Spanned<RawTrack>>,
    #[serde(default)]
    zenoh: Option<Spanned<RawZenoh>>,
    #[serde(default)]
    survey: Vec<Spanned<RawUnitSurvey>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawUnitSurvey {
    sensor: Spanned<String>,
    x_m: f64,
    y_m: f64,
    yaw_deg: f64,
    sigma_xy_m: f64,
    sigma_yaw_deg: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawZenoh {
    zone: Option<Spanned<String>>,
    #[serde(default)]
    connect: Vec<Spanned<String>>,
    #[serde(default)]
    listen: Vec<Spanned<String>>,
    detections: Option<Spanned<bool>>,
    scans_hz: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrack {
    enabled: Option<bool>,
    background_s: Option<Spanned<f64>>,
    death_s: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawZone {
    id: Spanned<String>,
    polygon: Spanned<Vec<Vec<f64>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLine {
    id: Spanned<String>,
    from: Spanned<Vec<f64>>,
    to: Spanned<Vec<f64>>,
    hysteresis_m: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOsc {
    #[serde(default)]
    targets: Vec<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMqtt {
    url: Spanned<String>,
    topic_prefix: Option<Spanned<String>>,
    username: Option<Spanned<String>>,
    password_file: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFoxglove {
    listen: Option<Spanned<String>>,
    frames_per_s: Option<Spanned<f64>>,
    send_queue: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWeb {
    listen: Option<Spanned<String>>,
    token_file: Option<Spanned<String>>,
    max_clients: Option<Spanned<i64>>,
    frames_per_s: Option<Spanned<f64>>,
    send_queue: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSite {
    name: Spanned<String>,
    state_dir: Option<Spanned<String>>,
    socket: Option<Spanned<String>>,
    socket_mode: Option<Spanned<String>>,
    anchor: Spanned<String>,
    role: Option<Spanned<String>>,
    max_clients: Option<Spanned<i64>>,
    drawing: Option<Spanned<String>>,
    drawing_layers: Option<Spanned<Vec<String>>>,
    drawing_scale: Option<Spanned<f64>>,
    drawing_pairs: Option<Spanned<String>>,
    zones_frame: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSensor {
    id: Spanned<String>,
    connect: Spanned<String>,
    mode: Option<Spanned<ScanMode>>,
    height_m: Option<Spanned<f64>>,
    pitch_deg: Option<Spanned<f64>>,
    survey: Option<Spanned<RawSurvey>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSurvey {
    x_m: f64,
    y_m: f64,
    yaw_deg: f64,
    sigma_xy_m: f64,
    sigma_yaw_deg: f64,
}

/// Builds errors that point into one file.
struct Locator<'a> {
    path: &'a Path,
    text: &'a str,
}

impl Locator<'_> {
    fn line_of(&self, offset: usize) -> usize {
        let end = offset.min(self.text.len());
        self.text
            .as_bytes()
            .get(..end)
            .map_or(1, |b| b.iter().filter(|&&c| c == b'\n').count() + 1)
    }

    fn at(&self, span: Range<usize>, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            line: self.line_of(span.start),
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// Turns toml's error into ours, working out the dotted key from the text around its span.
    /// An error at `key`'s own line inside the table starting at `table`, or at the table.
    fn in_table(&self, table: Range<usize>, key: &str, message: impl Into<String>) -> ConfigError {
        let after = self.text.get(table.start..).unwrap_or("");
        let mut offset = table.start;
        for line in after.split_inclusive('\n') {
            let t = line.trim_start();
            if offset > table.start && t.starts_with('[') {
                break;
            }
            if t.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
            {
                return self.at(offset..offset, key, message);
            }
            offset += line.len();
        }
        self.at(table, key, message)
    }

    fn toml_error(&self, err: &toml::de::Error) -> ConfigError {
        let span = err.span().unwrap_or(0..0);
        let message = err.message().trim().to_string();
        let named = backticked_after(&message, "unknown field ")
            .or_else(|| backticked_after(&message, "missing field "));
        let key = if message.starts_with("unknown field ") || message.starts_with("missing field ")
        {
            let mut parts = key_context(self.text, span.start, message.starts_with("missing"));
            // An unknown table is reported at its own header, which already names it.
            if parts.last() != named.as_ref() {
                parts.extend(named);
            }
            parts.join(".")
        } else if [
            "invalid type",
            "invalid value",
            "invalid length",
            "unknown variant",
        ]
        .iter()
        .any(|p| message.starts_with(p))
        {
            key_context(self.text, span.start, true).join(".")
        } else {
            String::new()
        };
        let message = match message.strip_prefix("unknown variant ") {
            Some(rest) => format!("unknown value {rest}"),
            None => message,
        };
        self.at(span, &key, message)
    }
}

/// The text between backticks right after `prefix` in `message`.
fn backticked_after(message: &str, prefix: &str) -> Option<String> {
    let rest = message.strip_prefix(prefix)?.strip_prefix('`')?;
    Some(rest.split('`').next()?.to_string())
}

/// The dotted key whose value (or, without `include_current`, whose table) holds byte
/// `offset`: the last `[table]` header above it, the inline tables it sits in, and the key
/// being assigned. Good enough for messages; not a TOML parser.
fn key_context(text: &str, offset: usize, include_current: bool) -> Vec<String> {
    let offset = offset.min(text.len());
    let before = text.get(..offset).unwrap_or("");
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let mut parts: Vec<String> = Vec::new();
    for line in before.get(..line_start).unwrap_or("").lines().rev() {
        let t = line.trim();
        if t.starts_with('[') {
            let name = t
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim();
            parts.extend(name.split('.').map(|s| s.trim().to_string()));
            break;
        }
    }
    let prefix = before.get(line_start..).unwrap_or("");
    let line = text
        .get(line_start..)
        .unwrap_or("")
        .lines()
        .next()
        .unwrap_or("");
    if line.trim_start().starts_with('[') {
        // The span is on a header line: the header is the context.
        let name = line
            .trim()
            .trim_start_matches('[')
            .split(']')
            .next()
            .unwrap_or("")
            .trim();
        parts.clear();
        parts.extend(name.split('.').map(|s| s.trim().to_string()));
        return parts;
    }
    let mut stack: Vec<String> = Vec::new();
    let mut current: Option<String> = None;
    let mut word = String::new();
    let mut last_word = String::new();
    for c in prefix.chars() {
        match c {
            c if c.is_ascii_alphanumeric() || c == '_' || c == '-' => word.push(c),
            '=' => {
                if !word.is_empty() {
                    last_word = std::mem::take(&mut word);
                }
                current = Some(last_word.clone());
            }
            '{' => {
                if let Some(k) = current.take() {
                    stack.push(k);
                }
            }
            '}' => {
                stack.pop();
                current = None;
            }
            _ => {
                if !word.is_empty() {
                    last_word = std::mem::take(&mut word);
                }
            }
        }
    }
    parts.extend(stack);
    if include_current {
        parts.extend(current);
    }
    parts
}

impl Config {
    /// Reads and validates `path`, including that replay recordings exist.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Config::parse_with(
            &text,
            path,
            &|file: &Path| file.is_file(),
            &check_token_file,
        )
    }

    /// Validates `text` as the contents of `path` (used for messages and to resolve relative
    /// paths). No I/O: replay recordings are not looked for.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        Config::parse_with(text, path, &|_: &Path| true, &|_: &Path| Ok(()))
    }

    /// [`Config::parse`], asking `exists` whether each replay recording is there.
    fn parse_with(
        text: &str,
        path: &Path,
        exists: &dyn Fn(&Path) -> bool,
        token_ok: &dyn Fn(&Path) -> Result<(), String>,
    ) -> Result<Config, ConfigError> {
        let loc = Locator { path, text };
        let raw: RawConfig = toml::from_str(text).map_err(|e| loc.toml_error(&e))?;
        let base_dir = path.parent().unwrap_or(Path::new(""));
        let resolve = |p: &str| {
            let p = Path::new(p);
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base_dir.join(p)
            }
        };

        let site_span = raw.site.span();
        let site = raw.site.into_inner();
        let zones_frame = site.zones_frame.clone();
        let name = site.name.get_ref().trim().to_string();
        let name_span = site.name.span();
        if name.is_empty() {
            return Err(loc.at(
                site.name.span(),
                "site.name",
                "must not be empty; name the site, e.g. \"hall-3f\"",
            ));
        }
        let state_dir = match &site.state_dir {
            Some(s) if s.get_ref().is_empty() => {
                return Err(loc.at(
                    s.span(),
                    "site.state_dir",
                    "must not be empty; e.g. \"/var/lib/scanfuse\"",
                ));
            }
            Some(s) => resolve(s.get_ref()),
            None => PathBuf::from(DEFAULT_STATE_DIR),
        };
        let drawing = match &site.drawing {
            Some(d) if d.get_ref().is_empty() => {
                return Err(loc.at(
                    d.span(),
                    "site.drawing",
                    "must not be empty; e.g. \"plan.dxf\"",
                ));
            }
            Some(d) => Some(DrawingConfig {
                path: resolve(d.get_ref()),
                layers: site.drawing_layers.as_ref().map(|l| l.get_ref().clone()),
                scale_m_per_unit: match &site.drawing_scale {
                    Some(v) if !(v.get_ref().is_finite() && *v.get_ref() > 0.0) => {
                        return Err(loc.at(
                            v.span(),
                            "site.drawing_scale",
                            "must be a positive number of metres per drawing unit",
                        ));
                    }
                    Some(v) => Some(*v.get_ref()),
                    None => None,
                },
                pairs: match &site.drawing_pairs {
                    Some(v) => match crate::drawing::align::parse_pairs_to_fit(v.get_ref()) {
                        Ok(pairs) => pairs,
                        Err(e) => {
                            return Err(loc.at(v.span(), "site.drawing_pairs", e.to_string()));
                        }
                    },
                    None => Vec::new(),
                },
            }),
            None => {
                if let Some(v) = &site.drawing_layers {
                    return Err(loc.at(v.span(), "site.drawing_layers", "needs site.drawing"));
                }
                if let Some(v) = &site.drawing_scale {
                    return Err(loc.at(v.span(), "site.drawing_scale", "needs site.drawing"));
                }
                if let Some(v) = &site.drawing_pairs {
                    return Err(loc.at(v.span(), "site.drawing_pairs", "needs site.drawing"));
                }
                None
            }
        };
        let socket = match &site.socket {
            Some(s) if s.get_ref().is_empty() => {
                return Err(loc.at(
                    s.span(),
                    "site.socket",
                    "must not be empty; e.g. \"/run/scanfuse/scanfuse.sock\"",
                ));
            }
            Some(s) => resolve(s.get_ref()),
            None => PathBuf::from(DEFAULT_SOCKET),
        };
        let socket_mode = match &site.socket_mode {
            Some(s) => {
                parse_mode(s.get_ref()).map_err(|m| loc.at(s.span(), "site.socket_mode", m))?
            }
            None => DEFAULT_SOCKET_MODE,
        };
        let max_clients = match &site.max_clients {
            Some(n) => match usize::try_from(*n.get_ref()) {
                Ok(n @ 1..=1024) => n,
                _ => return Err(loc.at(n.span(), "site.max_clients", "must be 1–1024")),
            },
            None => DEFAULT_MAX_CLIENTS,
        };

        let role = match &site.role {
            None => Role::Zone,
            Some(r) => match r.get_ref().trim() {
                "zone" => Role::Zone,
                "site" => Role::Site,
                other => {
                    return Err(loc.at(
                        r.span(),
                        "site.role",
                        format!("{other:?} is not a role: \"zone\" (holds sensors, the default) or \"site\" (joins zones on Zenoh, holds none)"),
                    ));
                }
            },
        };
        if role == Role::Site {
            if let Some(first) = raw.sensor.first() {
                return Err(loc.at(
                    first.span(),
                    "sensor",
                    "a site daemon (role = \"site\") holds no sensors: give them to a zone daemon's config",
                ));
            }
            if raw.zenoh.is_none() {
                return Err(loc.at(
                    site_span,
                    "site.role",
                    "a site daemon joins zones on Zenoh: add [zenoh] with listen = [\"tcp/0.0.0.0:7447\"] (the zones connect there)",
                ));
            }
        } else if raw.sensor.is_empty() {
            return Err(loc.at(
                site_span,
                "sensor",
                "the config has no [[sensor]] tables; add one per scanner",
            ));
        }
        let mut sensors: Vec<SensorConfig> = Vec::new();
        let mut first_line: BTreeMap<String, usize> = BTreeMap::new();
        let mut endpoints: BTreeMap<String, String> = BTreeMap::new();
        for raw_sensor in raw.sensor {
            let s = raw_sensor.into_inner();
            let id = s.id.get_ref().clone();
            check_sensor_id(&id).map_err(|m| loc.at(s.id.span(), "sensor.id", m))?;
            let line = loc.line_of(s.id.span().start);
            if let Some(first) = first_line.insert(id.clone(), line) {
                return Err(loc.at(s.id.span(), "sensor.id", format!("duplicate sensor id {id:?}, first used at line {first}; every sensor needs its own id")));
            }
            let connect = Connect::parse(s.connect.get_ref(), base_dir)
                .map_err(|m| loc.at(s.connect.span(), "sensor.connect", m))?;
            if let Connect::Replay { file, .. } = &connect
                && !exists(file)
            {
                return Err(loc.at(s.connect.span(), "sensor.connect", format!(
                    "the recording {} does not exist (relative paths are taken from the config's folder)",
                    file.display()
                )));
            }
            let endpoint = match &connect {
                Connect::Tcp { .. } => Some(connect.to_string()),
                Connect::Serial { device, .. } => Some(device.display().to_string()),
                Connect::Replay { .. } => None,
            };
            if let Some(endpoint) = endpoint
                && let Some(other) = endpoints.insert(endpoint.clone(), id.clone())
            {
                return Err(loc.at(s.connect.span(), "sensor.connect", format!("{endpoint} is already sensor {other:?}'s connection; one scanner cannot be two sensors")));
            }
            let height_m = match &s.height_m {
                Some(h) if !(0.0..=20.0).contains(h.get_ref()) => {
                    return Err(loc.at(
                        h.span(),
                        "sensor.height_m",
                        "must be 0–20 (metres above the floor)",
                    ));
                }
                Some(h) => Some(*h.get_ref()),
                None => None,
            };
            let pitch_deg = match &s.pitch_deg {
                Some(p) if !(-45.0..=45.0).contains(p.get_ref()) => {
                    return Err(loc.at(
                        p.span(),
                        "sensor.pitch_deg",
                        "must be −45–45 (degrees, positive up)",
                    ));
                }
                Some(p) => *p.get_ref(),
                None => 0.0,
            };
            let survey = match &s.survey {
                Some(sv) => Some(
                    check_survey(sv.get_ref())
                        .map_err(|(k, m)| loc.at(sv.span(), &format!("sensor.survey.{k}"), m))?,
                ),
                None => None,
            };
            sensors.push(SensorConfig {
                id,
                connect,
                mode: s.mode.map_or(ScanMode::ME, |m| *m.get_ref()),
                height_m,
                pitch_rad: pitch_deg.to_radians(),
                survey,
                line,
            });
        }
        let mut surveys: Vec<UnitSurvey> = Vec::new();
        for sv in &raw.survey {
            let r = sv.get_ref();
            if role != Role::Site {
                return Err(loc.at(
                    sv.span(),
                    "survey",
                    "[[survey]] is the site daemon's (role = \"site\"): a unit of a zone measured in the site frame. A zone daemon surveys its own units with survey = { … } in their [[sensor]]",
                ));
            }
            let sensor = r.sensor.get_ref().trim().to_string();
            if sensor.is_empty() {
                return Err(loc.at(
                    r.sensor.span(),
                    "survey.sensor",
                    "names no unit: give the id of a unit of one of the zones",
                ));
            }
            if surveys.iter().any(|u| u.sensor == sensor) {
                return Err(loc.at(
                    r.sensor.span(),
                    "survey.sensor",
                    format!("{sensor:?} is surveyed twice: keep one [[survey]] per unit"),
                ));
            }
            let survey = check_survey(&RawSurvey {
                x_m: r.x_m,
                y_m: r.y_m,
                yaw_deg: r.yaw_deg,
                sigma_xy_m: r.sigma_xy_m,
                sigma_yaw_deg: r.sigma_yaw_deg,
            })
            .map_err(|(k, m)| loc.at(sv.span(), &format!("survey.{k}"), m))?;
            surveys.push(UnitSurvey { sensor, survey });
        }
        let anchor = site.anchor.get_ref().clone();
        if role == Role::Site {
            if anchor == SITE_KEY || !key_safe(&anchor) {
                return Err(loc.at(
                    site.anchor.span(),
                    "site.anchor",
                    format!("{anchor:?} is not a zone id: a site daemon's anchor is the zone whose frame is the site's"),
                ));
            }
        } else if !first_line.contains_key(&anchor) {
            let ids: Vec<&str> = sensors.iter().map(|s| s.id.as_str()).collect();
            return Err(loc.at(
                site.anchor.span(),
                "site.anchor",
                format!(
                    "{anchor:?} is not one of the sensors; use one of {}",
                    ids.join(", ")
                ),
            ));
        }

        let registration = match raw.registration {
            Some(r) => {
                let span = r.span();
                let r = r.into_inner();
                check_registration(&r)
                    .map_err(|(k, m)| rename(loc.in_table(span, k, m), "registration"))?;
                r
            }
            None => RegistrationConfig::default(),
        };
        let publish = match raw.publish {
            Some(p) => {
                let span = p.span();
                let p = p.into_inner();
                check_publish(&p).map_err(|(k, m)| rename(loc.in_table(span, k, m), "publish"))?;
                p
            }
            None => PublishConfig::default(),
        };
        let web = match raw.web {
            Some(w) => parse_web(&loc, w, &resolve, token_ok)?,
            None => WebConfig::default(),
        };
        let people = parse_people(
            &loc,
            People {
                zones: raw.zone,
                lines: raw.line,
                osc: raw.osc,
                mqtt: raw.mqtt,
            },
            &name,
            &resolve,
        )?;
        let people = PeopleConfig {
            zones_frame: match &zones_frame {
                None => ZonesFrame::Site,
                Some(f) => match f.get_ref().as_str() {
                    "site" => ZonesFrame::Site,
                    "building" if role == Role::Site => {
                        return Err(loc.at(
                            f.span(),
                            "site.zones_frame",
                            "a site daemon has no drawing: draw its zones and lines in the site frame (the anchor zone's), zones_frame = \"site\"",
                        ));
                    }
                    "building" => ZonesFrame::Building,
                    other => {
                        return Err(loc.at(
                            f.span(),
                            "site.zones_frame",
                            format!(
                                "{other:?} is not a frame: use \"site\" (the anchor sensor's, the default) or \"building\" (the drawing's, through building_from_site)"
                            ),
                        ));
                    }
                },
            },
            ..people
        };
        let foxglove = match raw.foxglove {
            Some(f) => parse_foxglove(&loc, f)?,
            None => FoxgloveConfig::default(),
        };
        let track = match raw.track {
            Some(t) => parse_track(&loc, t.into_inner())?,
            None => TrackConfig::default(),
        };
        let zenoh = match raw.zenoh {
            Some(z) => Some(parse_zenoh(&loc, z, &name, name_span, role, track.enabled)?),
            None => None,
        };

        Ok(Config {
            path: path.to_path_buf(),
            site: SiteConfig {
                name,
                state_dir,
                socket,
                socket_mode,
                anchor,
                role,
                max_clients,
                drawing,
            },
            sensors,
            registration,
            publish,
            web,
            people,
            foxglove,
            track,
            zenoh,
            surveys,
        })
    }

    /// Where the page is served, a line of `summary`.
    fn page_line(&self) -> String {
        match (&self.web.listen, &self.web.token_file) {
            (None, _) => "  no page ([web] listen = \"\")\n".to_string(),
            (Some(a), None) => format!("  page at http://{a}/ (this machine only)\n"),
            (Some(a), Some(t)) => format!(
                "  page at http://{a}/ (token in {}; open http://HOST:{}/?token=…)\n",
                t.display(),
                a.port()
            ),
        }
    }

    /// A few lines for `scanfuse check`.
    pub fn summary(&self) -> String {
        if self.site.role == Role::Site {
            let mut out = format!(
                "{}: site {:?}, the site daemon (role = \"site\"): holds no sensors, joins the zones into the frame of zone {}\n  socket {} (mode {:04o}, at most {} clients); map files (of the scans the zones send) in {}\n",
                self.path.display(),
                self.site.name,
                self.site.anchor,
                self.site.socket.display(),
                self.site.socket_mode,
                self.site.max_clients,
                self.site.state_dir.display(),
            );
            out.push_str(&self.page_line());
            if let Some(z) = &self.zenoh {
                out.push_str(&format!("  {}\n", z.describe(&self.site.name)));
            }
            if !self.surveys.is_empty() {
                let ids: Vec<&str> = self.surveys.iter().map(|u| u.sensor.as_str()).collect();
                out.push_str(&format!(
                    "  {} unit(s) surveyed in the site frame, each holding its zone: {}\n",
                    ids.len(),
                    ids.join(", ")
                ));
            }
            if self.track.enabled {
                out.push_str(&format!(
                    "  tracks people across the zones that send their detections ([zenoh] detections = true in a zone's config); {} zone(s) and {} line(s) counted\n",
                    self.people.zones.len(),
                    self.people.lines.len()
                ));
            }
            return out;
        }
        let mut out = format!(
            "{}: site {:?}, {} sensor{}, anchor {}\n  state in {}, socket {} (mode {:04o}, at most {} clients)\n",
            self.path.display(),
            self.site.name,
            self.sensors.len(),
            if self.sensors.len() == 1 { "" } else { "s" },
            self.site.anchor,
            self.site.state_dir.display(),
            self.site.socket.display(),
            self.site.socket_mode,
            self.site.max_clients,
        );
        for s in &self.sensors {
            out.push_str(&format!("  {:<16} {:?}  {}", s.id, s.mode, s.connect));
            if let Some(sv) = &s.survey {
                out.push_str(&format!(
                    "  surveyed ({:.3} m, {:.3} m, {:.2}°)",
                    sv.x_m,
                    sv.y_m,
                    sv.yaw_rad.to_degrees()
                ));
            }
            out.push('\n');
        }
        out.push_str(&self.page_line());
        let p = &self.people;
        if !p.zones.is_empty() || !p.lines.is_empty() {
            out.push_str(&format!(
                "  {} zone{}, {} counting line{}{}\n",
                p.zones.len(),
                if p.zones.len() == 1 { "" } else { "s" },
                p.lines.len(),
                if p.lines.len() == 1 { "" } else { "s" },
                match p.zones_frame {
                    ZonesFrame::Site => "",
                    ZonesFrame::Building =>
                        " in building coordinates (counted once the site is aligned to the drawing)",
                },
            ));
        }
        if !p.osc_targets.is_empty() {
            let to: Vec<String> = p.osc_targets.iter().map(|a| a.to_string()).collect();
            out.push_str(&format!("  OSC to {}\n", to.join(", ")));
        }
        if let Some(m) = &p.mqtt {
            out.push_str(&format!("  MQTT to {} under {}/\n", m.url, m.topic_prefix));
        }
        if let Some(a) = &self.foxglove.listen {
            out.push_str(&format!(
                "  Foxglove at ws://{a} (read-only{})\n",
                if a.ip().is_loopback() {
                    ", this machine only"
                } else {
                    ", no token: anyone who reaches the port sees the site"
                }
            ));
        }
        if let Some(z) = &self.zenoh {
            out.push_str(&format!("  {}\n", z.describe(&self.site.name)));
        }
        out
    }
}

/// `[track]`, checked.
fn parse_track(loc: &Locator<'_>, raw: RawTrack) -> Result<TrackConfig, ConfigError> {
    let mut out = TrackConfig::default();
    if let Some(e) = raw.enabled {
        out.enabled = e;
    }
    if let Some(v) = &raw.background_s {
        out.background_s = *v.get_ref();
        if !(60.0..=86_400.0).contains(&out.background_s) {
            return Err(loc.at(
                v.span(),
                "track.background_s",
                "must be 60–86400 seconds: a person standing still must stay a person for at least a minute",
            ));
        }
    }
    if let Some(v) = &raw.death_s {
        out.death_s = *v.get_ref();
        if !(out.death_s >= 0.1 && out.death_s <= 60.0) {
            return Err(loc.at(v.span(), "track.death_s", "must be 0.1–60 seconds"));
        }
    }
    Ok(out)
}

/// `[zenoh]`, checked: ids that are safe in a key expression (the site's name names the keys
/// too), TCP endpoints (the one transport built in), and at least one of them.
fn parse_zenoh(
    loc: &Locator<'_>,
    raw: Spanned<RawZenoh>,
    site: &str,
    site_span: Range<usize>,
    role: Role,
    tracking: bool,
) -> Result<ZenohConfig, ConfigError> {
    let span = raw.span();
    let z = raw.into_inner();
    if !cfg!(feature = "zenoh") {
        return Err(loc.at(
            span,
            "zenoh",
            "this scanfuse was built without the `zenoh` feature; build it with `--features zenoh` (on by default)",
        ));
    }
    if !key_safe(site) {
        return Err(loc.at(
            site_span,
            "site.name",
            format!("{site:?} names the site's Zenoh keys: use letters, digits, - and _ only (at most 64)"),
        ));
    }
    let zone = match (role, &z.zone) {
        (Role::Site, None) => SITE_KEY.to_string(),
        (Role::Site, Some(zone)) => {
            return Err(loc.at(
                zone.span(),
                "zenoh.zone",
                "a site daemon holds no zone: leave zone out (its keys are scanfuse/<site>/site/…)",
            ));
        }
        (Role::Zone, None) => {
            return Err(loc.at(
                span,
                "zenoh.zone",
                "name this daemon's zone of the site, e.g. zone = \"east\"",
            ));
        }
        (Role::Zone, Some(zone)) => {
            let id = zone.get_ref().trim().to_string();
            if !key_safe(&id) || id == SITE_KEY {
                return Err(loc.at(
                    zone.span(),
                    "zenoh.zone",
                    format!("{id:?} is not a zone id: use letters, digits, - and _ only (at most 64; not \"{SITE_KEY}\"), e.g. \"east\""),
                ));
            }
            id
        }
    };
    let endpoints = |list: &[Spanned<String>], key: &str| {
        list.iter()
            .map(|e| {
                let text = e.get_ref().trim();
                let ok = text
                    .strip_prefix("tcp/")
                    .and_then(|a| a.rsplit_once(':'))
                    .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
                if ok {
                    Ok(text.to_string())
                } else {
                    Err(loc.at(e.span(), key, format!(
                        "{text:?} is not an endpoint: write tcp/HOST:PORT, e.g. \"tcp/10.0.0.5:7447\" (TCP is the one transport built in)"
                    )))
                }
            })
            .collect::<Result<Vec<String>, ConfigError>>()
    };
    let connect = endpoints(&z.connect, "zenoh.connect")?;
    let listen = endpoints(&z.listen, "zenoh.listen")?;
    if connect.is_empty() && listen.is_empty() {
        return Err(loc.at(
            span,
            "zenoh",
            "give connect = [\"tcp/HOST:PORT\"] (another daemon's or a router's) and/or listen = [\"tcp/IP:PORT\"]: multicast discovery is off",
        ));
    }
    let detections = match z.detections {
        Some(d) if *d.get_ref() && role == Role::Site => {
            return Err(loc.at(
                d.span(),
                "zenoh.detections",
                "a site daemon takes the zones' detections: set detections = true in each zone's [zenoh]",
            ));
        }
        Some(d) if *d.get_ref() && !tracking => {
            return Err(loc.at(
                d.span(),
                "zenoh.detections",
                "detections are what this zone's tracker sees, and [track] enabled = false turns it off: enable tracking or leave detections out",
            ));
        }
        Some(d) => *d.get_ref(),
        None => false,
    };
    let scans_hz = match z.scans_hz {
        Some(h) if role == Role::Site => {
            return Err(loc.at(
                h.span(),
                "zenoh.scans_hz",
                "a site daemon takes the zones' scans: set scans_hz in each zone's [zenoh]",
            ));
        }
        Some(h) => {
            let hz = *h.get_ref();
            if !(hz > 0.0 && hz <= 40.0) {
                return Err(loc.at(
                    h.span(),
                    "zenoh.scans_hz",
                    format!("{hz} is not a rate: give scans a second, above 0 and at most 40 (e.g. 2), or leave it out to send none"),
                ));
            }
            Some(hz)
        }
        None => None,
    };
    Ok(ZenohConfig {
        zone,
        connect,
        listen,
        detections,
        scans_hz,
    })
}

/// A name safe in a Zenoh key expression: a site, a zone.
fn key_safe(t: &str) -> bool {
    !t.is_empty()
        && t.len() <= 64
        && t.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// `[foxglove]`, checked. Any address is allowed: the server takes no requests that change
/// anything (no client publishing, services or parameters).
fn parse_foxglove(
    loc: &Locator<'_>,
    raw: Spanned<RawFoxglove>,
) -> Result<FoxgloveConfig, ConfigError> {
    let span = raw.span();
    let f = raw.into_inner();
    let mut out = FoxgloveConfig::default();
    if let Some(listen) = &f.listen {
        let text = listen.get_ref().trim();
        out.listen = if text.is_empty() {
            None
        } else {
            Some(text.parse().map_err(|_| {
                loc.at(listen.span(), "foxglove.listen", format!(
                    "{text:?} is not an address and port; write IP:PORT, e.g. \"127.0.0.1:8765\", or \"\" to serve none"
                ))
            })?)
        };
    }
    if let Some(v) = &f.frames_per_s {
        let v = *v.get_ref();
        positive("frames_per_s", v, 60.0)
            .map_err(|(k, m)| rename(loc.in_table(span.clone(), k, m), "foxglove"))?;
        out.frames_per_s = v;
    }
    if let Some(n) = &f.send_queue {
        out.send_queue = match usize::try_from(*n.get_ref()) {
            Ok(n @ 4..=65536) => n,
            _ => return Err(loc.at(n.span(), "foxglove.send_queue", "must be 4–65536 messages")),
        };
    }
    Ok(out)
}

/// `[web]`, checked: a listener that is not loopback needs a token file that passes
/// `token_ok`.
fn parse_web(
    loc: &Locator<'_>,
    raw: Spanned<RawWeb>,
    resolve: &dyn Fn(&str) -> PathBuf,
    token_ok: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<WebConfig, ConfigError> {
    let span = raw.span();
    let w = raw.into_inner();
    let mut web = WebConfig::default();
    if let Some(listen) = &w.listen {
        let text = listen.get_ref().trim();
        web.listen = if text.is_empty() {
            None
        } else {
            Some(text.parse().map_err(|_| {
                loc.at(listen.span(), "web.listen", format!(
                    "{text:?} is not an address and port; write IP:PORT, e.g. \"127.0.0.1:8080\" (this machine only) or \"0.0.0.0:8080\" (with token_file), or \"\" to serve no page"
                ))
            })?)
        };
    }
    if let Some(t) = &w.token_file {
        if t.get_ref().trim().is_empty() {
            return Err(loc.at(t.span(), "web.token_file", "must not be empty; name a file holding the secret, e.g. \"/etc/scanfuse/web.token\""));
        }
        let path = resolve(t.get_ref());
        token_ok(&path).map_err(|m| loc.at(t.span(), "web.token_file", m))?;
        web.token_file = Some(path);
    }
    if let Some(addr) = web.listen
        && !addr.ip().is_loopback()
        && web.token_file.is_none()
    {
        let at = w.listen.as_ref().map_or(span.clone(), |l| l.span());
        return Err(loc.at(at, "web.listen", format!(
            "{addr} is reachable from other machines, and the page can move sensors: set token_file to a file holding a secret (at least {MIN_TOKEN_CHARS} characters), or listen on 127.0.0.1"
        )));
    }
    if let Some(n) = &w.max_clients {
        web.max_clients = match usize::try_from(*n.get_ref()) {
            Ok(n @ 1..=256) => n,
            _ => return Err(loc.at(n.span(), "web.max_clients", "must be 1–256")),
        };
    }
    if let Some(f) = &w.frames_per_s {
        let f = *f.get_ref();
        positive("frames_per_s", f, 60.0)
            .map_err(|(k, m)| rename(loc.in_table(span.clone(), k, m), "web"))?;
        web.frames_per_s = f;
    }
    if let Some(n) = &w.send_queue {
        web.send_queue = match usize::try_from(*n.get_ref()) {
            Ok(n @ 4..=4096) => n,
            _ => return Err(loc.at(n.span(), "web.send_queue", "must be 4–4096 messages")),
        };
    }
    Ok(web)
}

/// The raw tables of [`PeopleConfig`].
struct People {
    zones: Vec<Spanned<RawZone>>,
    lines: Vec<Spanned<RawLine>>,
    osc: Option<Spanned<RawOsc>>,
    mqtt: Option<Spanned<RawMqtt>>,
}

/// `[[zone]]`, `[[line]]`, `[osc]` and `[mqtt]`, checked.
fn parse_people(
    loc: &Locator<'_>,
    raw: People,
    site: &str,
    resolve: &dyn Fn(&str) -> PathBuf,
) -> Result<PeopleConfig, ConfigError> {
    let mut people = PeopleConfig::default();
    let check_id = |id: &Spanned<String>, key: &str, seen: &mut BTreeMap<String, usize>| {
        let text = id.get_ref();
        check_sensor_id(text).map_err(|_| {
            loc.at(
                id.span(),
                key,
                format!("{text:?} is not valid: use 1–64 ASCII letters, digits, '_', '-' or '.'"),
            )
        })?;
        let line = loc.line_of(id.span().start);
        if let Some(first) = seen.insert(text.clone(), line) {
            return Err(loc.at(
                id.span(),
                key,
                format!("duplicate id {text:?}, first used at line {first}; give each its own id"),
            ));
        }
        Ok(())
    };
    let mut seen = BTreeMap::new();
    for z in raw.zones {
        let z = z.into_inner();
        check_id(&z.id, "zone.id", &mut seen)?;
        let polygon = z
            .polygon
            .get_ref()
            .iter()
            .map(|p| xy(p))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| {
                loc.at(
                    z.polygon.span(),
                    "zone.polygon",
                    "every point must be [x, y] (metres, site frame), e.g. [[0, 0], [4, 0], [4, 3]]",
                )
            })?;
        zones::check_polygon(&polygon)
            .map_err(|m| loc.at(z.polygon.span(), "zone.polygon", format!("the polygon {m}")))?;
        people.zones.push(Zone {
            id: z.id.into_inner(),
            polygon,
        });
    }
    let mut seen = BTreeMap::new();
    for l in raw.lines {
        let l = l.into_inner();
        check_id(&l.id, "line.id", &mut seen)?;
        let end = |v: &Spanned<Vec<f64>>, key: &str| {
            xy(v.get_ref()).ok_or_else(|| {
                loc.at(
                    v.span(),
                    key,
                    "must be [x, y] (metres, site frame), e.g. [2.0, 0.5]",
                )
            })
        };
        let (from, to) = (end(&l.from, "line.from")?, end(&l.to, "line.to")?);
        zones::check_line(from, to)
            .map_err(|m| loc.at(l.to.span(), "line.to", format!("the line {m}")))?;
        let hysteresis_m = match &l.hysteresis_m {
            Some(h) if !(0.0..=5.0).contains(h.get_ref()) => {
                return Err(loc.at(
                    h.span(),
                    "line.hysteresis_m",
                    "must be 0–5 (metres from the line before a side counts)",
                ));
            }
            Some(h) => *h.get_ref(),
            None => DEFAULT_HYSTERESIS_M,
        };
        people.lines.push(CountLine {
            id: l.id.into_inner(),
            from,
            to,
            hysteresis_m,
        });
    }
    if let Some(osc) = raw.osc {
        for t in &osc.get_ref().targets {
            let text = t.get_ref().trim();
            let addr = text.parse().map_err(|_| {
                loc.at(
                    t.span(),
                    "osc.targets",
                    format!("{text:?} is not an address and port; write IP:PORT, e.g. \"127.0.0.1:9000\""),
                )
            })?;
            people.osc_targets.push(addr);
        }
    }
    if let Some(mqtt) = raw.mqtt {
        let m = mqtt.into_inner();
        let (host, port) =
            parse_mqtt_url(m.url.get_ref()).map_err(|e| loc.at(m.url.span(), "mqtt.url", e))?;
        let topic_prefix = match &m.topic_prefix {
            Some(p) => {
                let text = p.get_ref().trim_end_matches('/');
                if text.is_empty() || text.contains(['+', '#']) || text.starts_with('/') {
                    return Err(loc.at(
                        p.span(),
                        "mqtt.topic_prefix",
                        "must be a topic without wildcards (+, #) or a leading /, e.g. \"scanfuse/hall-3f\"",
                    ));
                }
                text.to_string()
            }
            None => format!("scanfuse/{site}"),
        };
        let username = match &m.username {
            Some(u) if u.get_ref().is_empty() => {
                return Err(loc.at(
                    u.span(),
                    "mqtt.username",
                    "must not be empty; leave it out to connect without one",
                ));
            }
            Some(u) => Some(u.get_ref().clone()),
            None => None,
        };
        let password_file = match &m.password_file {
            Some(p) if p.get_ref().trim().is_empty() => {
                return Err(loc.at(
                    p.span(),
                    "mqtt.password_file",
                    "must not be empty; name a file holding the password",
                ));
            }
            Some(p) if username.is_none() => {
                return Err(loc.at(
                    p.span(),
                    "mqtt.password_file",
                    "needs mqtt.username: a broker takes a password only with a user name",
                ));
            }
            Some(p) => Some(resolve(p.get_ref())),
            None => None,
        };
        people.mqtt = Some(MqttConfig {
            url: m.url.get_ref().clone(),
            host,
            port,
            topic_prefix,
            username,
            password_file,
        });
    }
    Ok(people)
}

/// `[x, y]`, or `None` for another number of values.
fn xy(v: &[f64]) -> Option<[f64; 2]> {
    match v {
        [x, y] => Some([*x, *y]),
        _ => None,
    }
}

/// `mqtt://HOST[:PORT]` → host and port.
fn parse_mqtt_url(url: &str) -> Result<(String, u16), String> {
    let example = "write mqtt://HOST:PORT, e.g. \"mqtt://127.0.0.1:1883\"";
    let Some(rest) = url
        .strip_prefix("mqtt://")
        .or_else(|| url.strip_prefix("tcp://"))
    else {
        if url.starts_with("mqtts://") || url.starts_with("ssl://") {
            return Err(format!(
                "{url:?}: TLS is not supported; connect to a plain listener (e.g. on this machine or over a VPN); {example}"
            ));
        }
        return Err(format!("{url:?} is not an MQTT url; {example}"));
    };
    let rest = rest.trim_end_matches('/');
    let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
        let (h, after) = v6
            .split_once(']')
            .ok_or_else(|| format!("{url:?}: unclosed [; {example}"))?;
        (h, after.strip_prefix(':'))
    } else {
        match rest.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (rest, None),
        }
    };
    if host.is_empty() || host.contains(['/', '@', ' ']) {
        return Err(format!("{url:?} has no host name; {example}"));
    }
    let port = match port {
        Some(p) => match p.parse::<u16>() {
            Ok(p) if p > 0 => p,
            _ => return Err(format!("{url:?}: the port must be 1–65535; {example}")),
        },
        None => DEFAULT_MQTT_PORT,
    };
    Ok((host.to_string(), port))
}

/// Prefixes an error's key with its table's name.
fn rename(err: ConfigError, table: &str) -> ConfigError {
    match err {
        ConfigError::Invalid {
            path,
            line,
            key,
            message,
        } => ConfigError::Invalid {
            path,
            line,
            key: format!("{table}.{key}"),
            message,
        },
        other => other,
    }
}

/// What a reloaded config (SIGHUP) changes relative to the running one.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ConfigChanges {
    /// Sensors to start.
    pub added: Vec<String>,
    /// Sensors to stop.
    pub removed: Vec<String>,
    /// Sensors whose connection, mode, mount or survey changed: restart their driver, and
    /// re-register them if the mount or survey changed.
    pub changed: Vec<String>,
    /// Keys a reload cannot apply (the socket and state files stay where they are until a
    /// restart), e.g. `site.socket`.
    pub need_restart: Vec<&'static str>,
    /// The anchor changed: every pose is relative to it, so all sensors re-register.
    pub anchor_changed: bool,
    /// `[site] drawing` (its file, layers, scale or point pairs) changed: the alignment to the
    /// old one is dropped and the site aligned to the new one.
    pub drawing_changed: bool,
}

impl ConfigChanges {
    /// True when the reload changes nothing.
    pub fn is_empty(&self) -> bool {
        *self == ConfigChanges::default()
    }
}

impl Config {
    /// What replacing `self` by `new` changes, sensors in `new`'s order.
    pub fn changes_to(&self, new: &Config) -> ConfigChanges {
        let old_by_id: BTreeMap<&str, &SensorConfig> =
            self.sensors.iter().map(|s| (s.id.as_str(), s)).collect();
        let new_ids: std::collections::BTreeSet<&str> =
            new.sensors.iter().map(|s| s.id.as_str()).collect();
        let mut changes = ConfigChanges::default();
        for s in &new.sensors {
            match old_by_id.get(s.id.as_str()) {
                None => changes.added.push(s.id.clone()),
                Some(old) if !same_sensor(old, s) => changes.changed.push(s.id.clone()),
                Some(_) => {}
            }
        }
        changes.removed = self
            .sensors
            .iter()
            .filter(|s| !new_ids.contains(s.id.as_str()))
            .map(|s| s.id.clone())
            .collect();
        let (a, b) = (&self.site, &new.site);
        for (key, differs) in [
            ("site.state_dir", a.state_dir != b.state_dir),
            ("site.socket", a.socket != b.socket),
            ("site.socket_mode", a.socket_mode != b.socket_mode),
            ("site.max_clients", a.max_clients != b.max_clients),
            (
                "publish.watch_backlog",
                self.publish.watch_backlog != new.publish.watch_backlog,
            ),
            (
                "registration.queue_scans",
                self.registration.queue_scans != new.registration.queue_scans,
            ),
            ("zone", self.people.zones != new.people.zones),
            ("line", self.people.lines != new.people.lines),
            ("osc", self.people.osc_targets != new.people.osc_targets),
            ("mqtt", self.people.mqtt != new.people.mqtt),
            // The page and Foxglove servers are bound once, at start.
            ("web", self.web != new.web),
            ("foxglove", self.foxglove != new.foxglove),
            ("track", self.track != new.track),
            ("zenoh", self.zenoh != new.zenoh),
            ("site.role", a.role != b.role),
        ] {
            if differs {
                changes.need_restart.push(key);
            }
        }
        changes.anchor_changed = a.anchor != b.anchor;
        changes.drawing_changed = a.drawing != b.drawing;
        changes
    }
}

/// Same sensor, ignoring where in the file it is written.
fn same_sensor(a: &SensorConfig, b: &SensorConfig) -> bool {
    a.connect == b.connect
        && a.mode == b.mode
        && a.height_m == b.height_m
        && a.pitch_rad == b.pitch_rad
        && a.survey == b.survey
}

/// `socket_mode` is a string of octal digits, like `chmod`'s.
fn parse_mode(text: &str) -> Result<u32, String> {
    let valid = "write it as octal digits in a string, e.g. \"0660\" (owner and group) or \"0600\" (owner only)";
    let mode = match u32::from_str_radix(text, 8) {
        Ok(m) if !text.is_empty() && m <= 0o777 => m,
        _ => return Err(format!("{text:?} is not a permission mode; {valid}")),
    };
    if mode & 0o600 != 0o600 {
        return Err(format!(
            "{text:?} denies the daemon's own user read/write; {valid}"
        ));
    }
    Ok(mode)
}

fn check_survey(s: &RawSurvey) -> Result<Survey, (&'static str, String)> {
    for (key, v) in [("x_m", s.x_m), ("y_m", s.y_m), ("yaw_deg", s.yaw_deg)] {
        if !v.is_finite() || v.abs() > 1e5 {
            return Err((key, "must be a finite number within ±100000".into()));
        }
    }
    if !(s.sigma_xy_m > 0.0 && s.sigma_xy_m <= 10.0) {
        return Err((
            "sigma_xy_m",
            "must be greater than 0 and at most 10 (metres)".into(),
        ));
    }
    if !(s.sigma_yaw_deg > 0.0 && s.sigma_yaw_deg <= 180.0) {
        return Err((
            "sigma_yaw_deg",
            "must be greater than 0 and at most 180 (degrees)".into(),
        ));
    }
    Ok(Survey {
        x_m: s.x_m,
        y_m: s.y_m,
        yaw_rad: s.yaw_deg.to_radians(),
        sigma_xy_m: s.sigma_xy_m,
        sigma_yaw_rad: s.sigma_yaw_deg.to_radians(),
    })
}

fn check_registration(r: &RegistrationConfig) -> Result<(), (&'static str, String)> {
    if !(1..=100_000).contains(&r.queue_scans) {
        return Err(("queue_scans", "must be 1–100000".into()));
    }
    positive("static_view_s", r.static_view_s, 600.0)?;
    if !(r.moved_fraction > 0.0 && r.moved_fraction <= 1.0) {
        return Err((
            "moved_fraction",
            "must be greater than 0 and at most 1".into(),
        ));
    }
    positive("moved_persist_s", r.moved_persist_s, 60.0)?;
    positive("refine_radius_m", r.refine_radius_m, 10.0)?;
    positive("refine_yaw_deg", r.refine_yaw_deg, 180.0)?;
    if !(0.0..=60.0).contains(&r.motion_buffer_s) {
        return Err(("motion_buffer_s", "must be 0 (off) to 60".into()));
    }
    Ok(())
}

fn check_publish(p: &PublishConfig) -> Result<(), (&'static str, String)> {
    if !(p.map_cell_m >= 0.005 && p.map_cell_m <= 1.0) {
        return Err(("map_cell_m", "must be 0.005–1 (metres per cell)".into()));
    }
    if !(p.save_interval_s == 0.0 || (1.0..=86_400.0).contains(&p.save_interval_s)) {
        return Err((
            "save_interval_s",
            "must be 0 (only on save and shutdown) or 1–86400 seconds".into(),
        ));
    }
    positive("map_rate_hz", p.map_rate_hz, 100.0)?;
    if !(8..=65_536).contains(&p.watch_backlog) {
        return Err(("watch_backlog", "must be 8–65536 messages".into()));
    }
    if !(p.free_thresh > 0.0 && p.free_thresh < p.occupied_thresh && p.occupied_thresh < 1.0) {
        return Err((
            "occupied_thresh",
            "needs 0 < free_thresh < occupied_thresh < 1".into(),
        ));
    }
    Ok(())
}

fn positive(key: &'static str, v: f64, max: f64) -> Result<(), (&'static str, String)> {
    if v > 0.0 && v <= max {
        Ok(())
    } else {
        Err((key, format!("must be greater than 0 and at most {max}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Connections print as URIs that parse back to themselves.
        #[test]
        fn connect_uris_round_trip(
            host in "[a-z][a-z0-9.-]{0,20}",
            v6 in "[0-9a-f]{1,4}(:[0-9a-f]{1,4}){1,3}",
            port in 1u16..,
            device in "/dev/tty[A-Z]{3}[0-9]",
            baud in proptest::sample::select(BAUD_RATES.to_vec()),
            file in "/[a-z]{1,8}/[a-z#]{1,8}\\.mcap",
            id in "[A-Za-z0-9_.-]{1,64}",
        ) {
            let base = Path::new("/cfg");
            for connect in [
                Connect::Tcp { host: host.clone(), port },
                Connect::Tcp { host: v6.clone(), port },
                Connect::Serial { device: device.clone().into(), baud },
                Connect::Replay { file: file.clone().into(), sensor: id.clone() },
            ] {
                prop_assert_eq!(Connect::parse(&connect.to_string(), base), Ok(connect));
            }
        }

        /// Any text gets a config or an error with a line inside the file, never a panic.
        #[test]
        fn any_text_gets_a_located_answer(text in "(\\PC|\n|\\[|\\]|=|\"){0,300}") {
            let lines = text.lines().count().max(1);
            match Config::parse(&text, Path::new("x.toml")) {
                Ok(_) | Err(ConfigError::Read { .. }) => {}
                Err(ConfigError::Invalid { line, .. }) => prop_assert!(line >= 1 && line <= lines + 1),
            }
        }
    }

    const GOOD: &str = r#"
[site]
name = "hall-3f"
state_dir = "state"
socket = "/run/scanfuse/scanfuse.sock"
anchor = "entrance"

[[sensor]]
id = "entrance"
connect = "tcp://192.168.0.10:10940"
mode = "ME"
height_m = 1.0
pitch_deg = 0.0

[[sensor]]
id = "dock"
connect = "serial:///dev/ttyACM0?baud=115200"
survey = { x_m = 4.0, y_m = -2.0, yaw_deg = 90.0, sigma_xy_m = 0.02, sigma_yaw_deg = 0.5 }

[[sensor]]
id = "replayed"
connect = "replay:../fixtures/hall.mcap#east"
mode = "MD"

[publish]
map_cell_m = 0.1
"#;

    fn parse(text: &str) -> Result<Config, ConfigError> {
        Config::parse(text, Path::new("/etc/scanfuse/site.toml"))
    }

    /// The error's `line`, `key` and message, or a panic if it parsed.
    fn invalid(text: &str) -> (usize, String, String) {
        match parse(text) {
            Err(ConfigError::Invalid {
                line, key, message, ..
            }) => (line, key, message),
            other => panic!("expected an Invalid error, got {other:?}"),
        }
    }

    #[test]
    fn zones_frame_is_site_or_building_and_anything_else_is_named() {
        assert_eq!(parse(GOOD).unwrap().people.zones_frame, ZonesFrame::Site);
        let with = |v: &str| {
            GOOD.replace(
                "anchor = \"entrance\"\n",
                &format!("anchor = \"entrance\"\nzones_frame = {v}\n"),
            )
        };
        assert_eq!(
            parse(&with("\"building\"")).unwrap().people.zones_frame,
            ZonesFrame::Building
        );
        assert_eq!(
            parse(&with("\"site\"")).unwrap().people.zones_frame,
            ZonesFrame::Site
        );
        let (line, key, message) = invalid(&with("\"drawing\""));
        assert_eq!((line, key.as_str()), (7, "site.zones_frame"));
        assert!(
            message.contains("\"drawing\"") && message.contains("\"building\""),
            "{message}"
        );
    }

    #[test]
    fn a_drawing_is_resolved_beside_the_config_and_its_options_need_it() {
        assert_eq!(parse(GOOD).unwrap().site.drawing, None);
        let with = GOOD.replace(
            "anchor = \"entrance\"\n",
            "anchor = \"entrance\"\ndrawing = \"plan.svg\"\ndrawing_layers = [\"A-WALL\", \"S-COLS\"]\ndrawing_scale = 0.001\n",
        );
        assert_eq!(
            parse(&with).unwrap().site.drawing,
            Some(DrawingConfig {
                path: PathBuf::from("/etc/scanfuse/plan.svg"),
                layers: Some(vec!["A-WALL".into(), "S-COLS".into()]),
                scale_m_per_unit: Some(0.001),
                pairs: Vec::new(),
            })
        );
        let paired = with.replace(
            "drawing_scale = 0.001\n",
            "drawing_scale = 0.001\ndrawing_pairs = \"0,0=10,20; 5,0=15,20\"\n",
        );
        let pairs = parse(&paired).unwrap().site.drawing.unwrap().pairs;
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[1].1, nalgebra::Point2::new(15.0, 20.0));
        for (bad, says) in [("0,0=10,20", "two or more"), ("0,0=10", "0,0=10")] {
            let text = paired.replace("0,0=10,20; 5,0=15,20", bad);
            let (_, key, message) = invalid(&text);
            assert_eq!(key, "site.drawing_pairs");
            assert!(message.contains(says), "{message}");
        }
        let (_, key, _) = invalid(&GOOD.replace(
            "anchor = \"entrance\"\n",
            "anchor = \"entrance\"\ndrawing_scale = 0.001\n",
        ));
        assert_eq!(key, "site.drawing_scale");
        let (_, key, message) = invalid(&with.replace("0.001", "-1"));
        assert_eq!(key, "site.drawing_scale");
        assert!(message.contains("positive"), "{message}");
    }

    #[test]
    fn the_registration_queue_grows_with_the_site() {
        let r = RegistrationConfig::default();
        assert_eq!(r.queue_len(3), 256);
        assert_eq!(r.queue_len(100), 6400);
        let big = RegistrationConfig {
            queue_scans: 16384,
            ..RegistrationConfig::default()
        };
        assert_eq!(big.queue_len(100), 16384);
    }

    #[test]
    fn the_tracker_section_sets_its_times_and_refuses_a_background_under_a_minute() {
        assert_eq!(parse(GOOD).unwrap().track, TrackConfig::default());
        let with = format!("{GOOD}\n[track]\nbackground_s = 300\ndeath_s = 3\n");
        let t = parse(&with).unwrap().track;
        assert!(t.enabled);
        let p = t.params();
        assert_eq!((p.background.absorb_s, p.death_s), (300.0, 3.0));
        let off = parse(&format!("{GOOD}\n[track]\nenabled = false\n")).unwrap();
        assert!(!off.track.enabled);
        let (line, key, message) = invalid(&with.replace("300", "20"));
        assert_eq!(
            (line, key.as_str()),
            (GOOD.lines().count() + 3, "track.background_s")
        );
        assert!(message.contains("at least a minute"), "{message}");
        let (_, key, _) = invalid(&with.replace("death_s = 3", "death_s = 0"));
        assert_eq!(key, "track.death_s");
        let (_, key, _) = invalid(&format!("{GOOD}\n[track]\nbirth_s = 1\n"));
        assert_eq!(key, "track.birth_s");
    }

    #[test]
    fn a_good_config_parses_with_defaults_and_resolved_paths() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.site.name, "hall-3f");
        assert_eq!(c.site.state_dir, PathBuf::from("/etc/scanfuse/state"));
        assert_eq!(c.site.socket_mode, 0o660);
        assert_eq!(c.site.max_clients, DEFAULT_MAX_CLIENTS);
        assert_eq!(c.sensors.len(), 3);
        assert_eq!(
            c.sensors[0].connect,
            Connect::Tcp {
                host: "192.168.0.10".into(),
                port: 10940
            }
        );
        assert_eq!(c.sensors[0].height_m, Some(1.0));
        assert_eq!(c.sensors[0].line, 9);
        assert_eq!(
            c.sensors[1].connect,
            Connect::Serial {
                device: "/dev/ttyACM0".into(),
                baud: 115_200
            }
        );
        assert_eq!(c.sensors[1].mode, ScanMode::ME);
        let survey = c.sensors[1].survey.unwrap();
        assert!((survey.yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert_eq!(
            c.sensors[2].connect,
            Connect::Replay {
                file: "/etc/scanfuse/../fixtures/hall.mcap".into(),
                sensor: "east".into()
            }
        );
        assert_eq!(c.publish.map_cell_m, 0.1);
        assert_eq!(c.publish.save_interval_s, 60.0);
        assert_eq!(c.registration, RegistrationConfig::default());
        assert!(c.summary().contains("3 sensors, anchor entrance"));
    }

    #[test]
    fn connect_uris_are_checked() {
        let base = Path::new("/cfg");
        assert_eq!(
            Connect::parse("tcp://[fe80::1]:10940", base),
            Ok(Connect::Tcp {
                host: "fe80::1".into(),
                port: 10940
            })
        );
        assert_eq!(
            Connect::parse("tcp://[fe80::1]:10940", base)
                .unwrap()
                .to_string(),
            "tcp://[fe80::1]:10940"
        );
        // The last `#` separates the sensor, so a file name may contain one.
        assert_eq!(
            Connect::parse("replay:/abs/x.mcap#a#b", base),
            Ok(Connect::Replay {
                file: "/abs/x.mcap#a".into(),
                sensor: "b".into()
            })
        );
        for (bad, why) in [
            ("tcp://host", "no port"),
            ("tcp://host:0", "1–65535"),
            ("tcp://host:99999", "1–65535"),
            ("tcp://:10940", "not a host"),
            ("tcp://fe80::1:10940", "brackets"),
            ("serial://dev/ttyACM0", "absolute path"),
            ("serial:///dev/ttyACM0?baud=12", "not one of"),
            ("serial:///dev/ttyACM0?speed=9600", "only option"),
            ("replay:hall.mcap", "names no sensor"),
            ("replay:#a", "names no file"),
            ("replay:hall.mcap#a/b", "not valid"),
            ("http://x:1", "tcp://HOST:PORT, serial://"),
        ] {
            let err = Connect::parse(bad, base).unwrap_err();
            assert!(err.contains(why), "{bad}: {err}");
        }
    }

    #[test]
    fn unknown_keys_name_line_key_and_valid_keys() {
        let (line, key, msg) =
            invalid(&GOOD.replace("mode = \"MD\"", "mode = \"MD\"\nrate_hz = 40"));
        assert_eq!((line, key.as_str()), (24, "sensor.rate_hz"));
        assert!(msg.contains("expected one of"), "{msg}");
        let (line, key, _) =
            invalid(&GOOD.replace("sigma_yaw_deg = 0.5 }", "sigma_yaw_deg = 0.5, z_m = 1 }"));
        assert_eq!((line, key.as_str()), (18, "sensor.survey.z_m"));
        let (line, key, _) = invalid(&GOOD.replace("[publish]", "[publish]\ncell = 1"));
        assert_eq!((line, key.as_str()), (26, "publish.cell"));
        let (line, key, msg) = invalid(&format!("{GOOD}\n[extra]\n"));
        assert_eq!((line, key.as_str()), (28, "extra"));
        assert!(msg.contains("`registration`"), "{msg}");
    }

    #[test]
    fn bad_values_name_line_key_and_what_is_valid() {
        let cases: [(&str, &str, usize, &str, &str); 12] = [
            (
                "mode = \"ME\"",
                "mode = \"XX\"",
                11,
                "sensor.mode",
                "`MD`, `ME`, `ND`",
            ),
            (
                "height_m = 1.0",
                "height_m = \"tall\"",
                12,
                "sensor.height_m",
                "expected f64",
            ),
            (
                "height_m = 1.0",
                "height_m = 99.0",
                12,
                "sensor.height_m",
                "0–20",
            ),
            (
                "pitch_deg = 0.0",
                "pitch_deg = 60.0",
                13,
                "sensor.pitch_deg",
                "−45–45",
            ),
            (
                "id = \"dock\"",
                "id = \"entrance\"",
                16,
                "sensor.id",
                "first used at line 9",
            ),
            (
                "id = \"dock\"",
                "id = \"do ck\"",
                16,
                "sensor.id",
                "ASCII letters",
            ),
            (
                "tcp://192.168.0.10:10940",
                "udp://x:1",
                10,
                "sensor.connect",
                "tcp://HOST:PORT",
            ),
            (
                "?baud=115200",
                "?baud=7",
                17,
                "sensor.connect",
                "not one of",
            ),
            (
                "anchor = \"entrance\"",
                "anchor = \"roof\"",
                6,
                "site.anchor",
                "entrance, dock, replayed",
            ),
            (
                "map_cell_m = 0.1",
                "map_cell_m = 0.0",
                26,
                "publish.map_cell_m",
                "0.005–1",
            ),
            (
                "sigma_xy_m = 0.02",
                "sigma_xy_m = 0.0",
                18,
                "sensor.survey.sigma_xy_m",
                "greater than 0",
            ),
            (
                "socket = \"/run/scanfuse/scanfuse.sock\"",
                "socket = \"/s\"\nsocket_mode = \"0999\"",
                6,
                "site.socket_mode",
                "octal",
            ),
        ];
        for (from, to, want_line, want_key, want_msg) in cases {
            let text = GOOD.replacen(from, to, 1);
            assert_ne!(text, GOOD, "{from}");
            let (line, key, msg) = invalid(&text);
            assert_eq!((line, key.as_str()), (want_line, want_key), "{to}: {msg}");
            assert!(msg.contains(want_msg), "{to}: {msg}");
        }
    }

    #[test]
    fn missing_and_structural_errors() {
        let (line, key, msg) =
            invalid("[site]\nname = \"a\"\n\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://a:1\"\n");
        assert_eq!((line, key.as_str()), (1, "site.anchor"), "{msg}");
        let (line, key, _) =
            invalid("[site]\nname = \"a\"\nanchor = \"a\"\n\n[[sensor]]\nid = \"a\"\n");
        assert_eq!((line, key.as_str()), (5, "sensor.connect"));
        let (_, key, msg) = invalid("[site]\nname = \"a\"\nanchor = \"a\"\n");
        assert_eq!(key, "sensor");
        assert!(msg.contains("no [[sensor]]"), "{msg}");
        let (line, key, _) = invalid("[site]\nname = \"a\n");
        assert_eq!((line, key.as_str()), (2, ""));
        let two_on_one_port = GOOD.replace(
            "serial:///dev/ttyACM0?baud=115200",
            "tcp://192.168.0.10:10940",
        );
        let (line, key, msg) = invalid(&two_on_one_port);
        assert_eq!((line, key.as_str()), (17, "sensor.connect"));
        assert!(msg.contains("\"entrance\""), "{msg}");
    }

    #[test]
    fn the_error_reads_file_line_key_message() {
        let err = parse(&GOOD.replace("mode = \"ME\"", "mode = \"XX\"")).unwrap_err();
        let text = err.to_string();
        assert!(
            text.starts_with("/etc/scanfuse/site.toml:11: sensor.mode: "),
            "{text}"
        );
    }

    #[test]
    fn a_reload_reports_what_changed() {
        let old = parse(GOOD).unwrap();
        assert!(old.changes_to(&old).is_empty());
        let moved_down = GOOD.replace("id = \"entrance\"\nconnect", "\nid = \"entrance\"\nconnect");
        assert!(
            old.changes_to(&parse(&moved_down).unwrap()).is_empty(),
            "line numbers are not changes"
        );
        let new_text = GOOD
            .replace(
                "id = \"replayed\"\nconnect = \"replay:../fixtures/hall.mcap#east\"",
                "id = \"roof\"\nconnect = \"tcp://10.0.0.9:10940\"",
            )
            .replace("height_m = 1.0", "height_m = 1.2")
            .replace(
                "socket = \"/run/scanfuse/scanfuse.sock\"",
                "socket = \"/tmp/s.sock\"",
            );
        let changes = old.changes_to(&parse(&new_text).unwrap());
        assert_eq!(changes.added, vec!["roof"]);
        assert_eq!(changes.removed, vec!["replayed"]);
        assert_eq!(changes.changed, vec!["entrance"]);
        assert_eq!(changes.need_restart, vec!["site.socket"]);
        // The people outputs start with the daemon; a reload says they wait for a restart.
        let zoned = parse(&format!(
            "{GOOD}\n[[line]]\nid = \"door\"\nfrom = [0, 0]\nto = [1, 0]\n"
        ))
        .unwrap();
        assert_eq!(old.changes_to(&zoned).need_restart, vec!["line"]);
        assert!(!changes.anchor_changed);
        let re_anchored =
            parse(&GOOD.replace("anchor = \"entrance\"", "anchor = \"dock\"")).unwrap();
        assert!(old.changes_to(&re_anchored).anchor_changed);
    }

    #[test]
    fn a_reload_says_the_page_and_foxglove_need_a_restart() {
        let a = parse(GOOD).unwrap();
        let b = parse(&format!(
            "{GOOD}\n[web]\nframes_per_s = 5\n\n[foxglove]\nlisten = \"127.0.0.1:8765\"\n"
        ))
        .unwrap();
        assert_eq!(a.changes_to(&b).need_restart, ["web", "foxglove"]);
        assert!(a.changes_to(&a).is_empty());
    }

    #[test]
    fn a_reload_applies_a_changed_drawing_live() {
        let a = parse(GOOD).unwrap();
        let drawn = |more: &str| {
            parse(&GOOD.replace(
                "anchor = \"entrance\"",
                &format!(
                    "anchor = \"entrance\"\ndrawing = \"plan.pgm\"\ndrawing_scale = 0.1{more}"
                ),
            ))
            .unwrap()
        };
        let b = drawn("");
        let changes = a.changes_to(&b);
        assert!(changes.drawing_changed && changes.need_restart.is_empty());
        let paired = drawn("\ndrawing_pairs = \"0,0=1,1; 5,0=6,1\"");
        assert!(b.changes_to(&paired).drawing_changed);
        assert!(!b.changes_to(&b).drawing_changed && b.changes_to(&a).drawing_changed);
    }

    #[test]
    fn zenoh_takes_a_key_safe_zone_and_tcp_endpoints_and_names_the_line_of_a_bad_one() {
        assert_eq!(parse(GOOD).unwrap().zenoh, None);
        let with = |table: &str| format!("{GOOD}\n[zenoh]\n{table}\n");
        let z = parse(&with(
            "zone = \"east\"\nconnect = [\"tcp/10.0.0.5:7447\"]\nlisten = [\"tcp/0.0.0.0:7447\"]",
        ))
        .unwrap()
        .zenoh
        .unwrap();
        assert_eq!(
            (z.zone.as_str(), z.connect, z.listen),
            (
                "east",
                vec!["tcp/10.0.0.5:7447".to_string()],
                vec!["tcp/0.0.0.0:7447".to_string()]
            )
        );
        let zenoh_line = GOOD.lines().count() + 2;
        for (table, key, says, line) in [
            (
                "zone = \"east/2\"\nlisten = [\"tcp/1.2.3.4:1\"]",
                "zenoh.zone",
                "not a zone id",
                1,
            ),
            (
                "zone = \"east\"\nconnect = [\"udp/1.2.3.4:7447\"]",
                "zenoh.connect",
                "tcp/HOST:PORT",
                2,
            ),
            (
                "zone = \"east\"\nlisten = [\"tcp/1.2.3.4\"]",
                "zenoh.listen",
                "tcp/HOST:PORT",
                2,
            ),
            ("zone = \"east\"", "zenoh", "multicast discovery is off", 0),
            (
                "zone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]\ndetections = true\n\n[track]\nenabled = false",
                "zenoh.detections",
                "enable tracking",
                3,
            ),
            (
                "zone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]\nscans_hz = 0",
                "zenoh.scans_hz",
                "not a rate",
                3,
            ),
        ] {
            let (at, k, msg) = invalid(&with(table));
            assert_eq!((k.as_str(), at), (key, zenoh_line + line), "{table}: {msg}");
            assert!(msg.contains(says), "{table}: {msg}");
        }
        let (_, k, msg) = invalid(&format!(
            "{}\n[zenoh]\nzone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]\n",
            GOOD.replace("name = \"hall-3f\"", "name = \"hall 3f\"")
        ));
        assert_eq!(k, "site.name", "{msg}");
        let a = parse(GOOD).unwrap();
        let b = parse(&with("zone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]")).unwrap();
        assert_eq!(a.changes_to(&b).need_restart, ["zenoh"]);
        assert!(!b.zenoh.unwrap().detections, "off unless asked for");
        let d = parse(&with(
            "zone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]\ndetections = true",
        ))
        .unwrap();
        let d = d.zenoh.unwrap();
        assert!(d.detections && d.scans_hz.is_none());
        let z = parse(&with(
            "zone = \"east\"\nlisten = [\"tcp/1.2.3.4:1\"]\nscans_hz = 2.5",
        ))
        .unwrap()
        .zenoh
        .unwrap();
        assert_eq!(z.scans_hz, Some(2.5));
        assert!(z.describe("hall").contains("scan 2.5 times a second"));
    }

    #[test]
    fn a_site_daemon_holds_no_sensors_and_anchors_on_a_zone_it_reaches_on_zenoh() {
        let site = "[site]\nname = \"hall\"\nrole = \"site\"\nanchor = \"west\"\n";
        let zenoh = "\n[zenoh]\nlisten = [\"tcp/0.0.0.0:7447\"]\n";
        let c = parse(&format!("{site}{zenoh}")).unwrap();
        assert_eq!((c.site.role, c.site.anchor.as_str()), (Role::Site, "west"));
        assert_eq!(c.zenoh.as_ref().map(|z| z.zone.as_str()), Some(SITE_KEY));
        assert!(c.summary().contains("the site daemon"), "{}", c.summary());
        assert!(
            c.summary()
                .contains("hosting the router on tcp/0.0.0.0:7447")
        );
        let sensor = "\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://10.0.0.1:10940\"\n";
        let survey = "\n[[survey]]\nsensor = \"dock\"\nx_m = 30.5\ny_m = -2\nyaw_deg = 0.5\nsigma_xy_m = 0.02\nsigma_yaw_deg = 0.2\n";
        for (text, key, says) in [
            (site.to_string(), "site.role", "add [zenoh]"),
            (
                format!("{site}{zenoh}{sensor}"),
                "sensor",
                "holds no sensors",
            ),
            (
                format!("{site}{zenoh}zone = \"west\"\n"),
                "zenoh.zone",
                "holds no zone",
            ),
            (
                format!("{site}{zenoh}detections = true\n"),
                "zenoh.detections",
                "in each zone's [zenoh]",
            ),
            (
                format!("{site}{zenoh}scans_hz = 2\n"),
                "zenoh.scans_hz",
                "in each zone's [zenoh]",
            ),
            (
                format!("{site}zones_frame = \"building\"\n{zenoh}"),
                "site.zones_frame",
                "has no drawing",
            ),
            (
                format!("{}{zenoh}", site.replace("\"west\"", "\"a/b\"")),
                "site.anchor",
                "not a zone id",
            ),
            (
                format!("{}{zenoh}", site.replace("\"site\"", "\"router\"")),
                "site.role",
                "not a role",
            ),
            (
                format!("{GOOD}\n[zenoh]\nzone = \"site\"\nlisten = [\"tcp/1.2.3.4:1\"]\n"),
                "zenoh.zone",
                "not \"site\"",
            ),
            (
                format!("{GOOD}\n[zenoh]\nlisten = [\"tcp/1.2.3.4:1\"]\n"),
                "zenoh.zone",
                "name this daemon's zone",
            ),
            (
                format!("{GOOD}\n{survey}"),
                "survey",
                "survey = { … } in their [[sensor]]",
            ),
            (
                format!("{site}{zenoh}{survey}{survey}"),
                "survey.sensor",
                "surveyed twice",
            ),
            (
                format!("{site}{zenoh}{}", survey.replace("0.02", "0")),
                "survey.sigma_xy_m",
                "greater than 0",
            ),
        ] {
            let (_, k, msg) = invalid(&text);
            assert_eq!(k, key, "{text}: {msg}");
            assert!(msg.contains(says), "{text}: {msg}");
        }
        let c = parse(&format!("{site}{zenoh}{survey}")).unwrap();
        assert_eq!(c.surveys.len(), 1);
        assert_eq!(c.surveys[0].sensor, "dock");
        assert!((c.surveys[0].survey.yaw_rad - 0.5f64.to_radians()).abs() < 1e-12);
        assert!(
            c.summary().contains("1 unit(s) surveyed in the site frame"),
            "{}",
            c.summary()
        );
    }

    #[test]
    fn foxglove_is_off_by_default_and_its_errors_name_the_line() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.foxglove.listen, None);
        let on = parse(&format!(
            "{GOOD}\n[foxglove]\nlisten = \"127.0.0.1:8765\"\nframes_per_s = 5\nsend_queue = 32\n"
        ))
        .unwrap();
        assert_eq!(on.foxglove.listen, Some("127.0.0.1:8765".parse().unwrap()));
        assert_eq!(
            (on.foxglove.frames_per_s, on.foxglove.send_queue),
            (5.0, 32)
        );
        assert!(on.summary().contains("Foxglove at ws://127.0.0.1:8765"));
        let off = parse(&format!("{GOOD}\n[foxglove]\nlisten = \"\"\n")).unwrap();
        assert_eq!(off.foxglove.listen, None);
        let (line, key, msg) = invalid(&format!("{GOOD}\n[foxglove]\nlisten = \"localhost\"\n"));
        assert_eq!(
            (line, key.as_str()),
            (GOOD.lines().count() + 3, "foxglove.listen"),
            "{msg}"
        );
        let (_, key, _) = invalid(&format!("{GOOD}\n[foxglove]\nframes_per_s = 0\n"));
        assert_eq!(key, "foxglove.frames_per_s");
        let (_, key, _) = invalid(&format!("{GOOD}\n[foxglove]\nsend_queue = 1\n"));
        assert_eq!(key, "foxglove.send_queue");
        let (_, key, _) = invalid(&format!("{GOOD}\n[foxglove]\nport = 1\n"));
        assert_eq!(key, "foxglove.port");
    }

    #[test]
    fn the_page_is_on_loopback_by_default_and_elsewhere_only_with_a_token() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.web.listen, Some("127.0.0.1:8080".parse().unwrap()));
        let off = parse(&format!("{GOOD}\n[web]\nlisten = \"\"\n")).unwrap();
        assert_eq!(off.web.listen, None);
        let (line, key, msg) = invalid(&format!("{GOOD}\n[web]\nlisten = \"0.0.0.0:8080\"\n"));
        assert_eq!(key, "web.listen");
        assert_eq!(line, GOOD.lines().count() + 3, "{msg}");
        assert!(msg.contains("token_file"), "{msg}");
        let (_, key, msg) = invalid(&format!("{GOOD}\n[web]\nlisten = \"localhost\"\n"));
        assert_eq!(key, "web.listen", "{msg}");
        let (line, key, _) = invalid(&format!("{GOOD}\n[web]\nport = 1\n"));
        assert_eq!((line, key.as_str()), (GOOD.lines().count() + 3, "web.port"));
        let (_, key, _) = invalid(&format!("{GOOD}\n[web]\nframes_per_s = 0\n"));
        assert_eq!(key, "web.frames_per_s");
        let ok = parse(&format!(
            "{GOOD}\n[web]\nlisten = \"0.0.0.0:8080\"\ntoken_file = \"web.token\"\nmax_clients = 3\nsend_queue = 8\n"
        ))
        .unwrap();
        assert_eq!(
            ok.web.token_file,
            Some(PathBuf::from("/etc/scanfuse/web.token"))
        );
        assert_eq!((ok.web.max_clients, ok.web.send_queue), (3, 8));
    }

    #[test]
    fn a_token_file_must_exist_hold_128_bits_and_not_be_world_readable() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("web.token");
        assert!(check_token_file(&path).unwrap_err().contains("cannot read"));
        std::fs::write(&path, "short\n").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert!(check_token_file(&path).unwrap_err().contains("at least 32"));
        std::fs::write(&path, "0123456789abcdef0123456789abcdef\n").unwrap();
        assert_eq!(check_token_file(&path), Ok(()));
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert!(
            check_token_file(&path)
                .unwrap_err()
                .contains("readable by everyone")
        );
    }

    #[test]
    fn socket_modes() {
        assert_eq!(parse_mode("0660"), Ok(0o660));
        assert_eq!(parse_mode("600"), Ok(0o600));
        for bad in ["", "0o660", "1777", "0440", "rw"] {
            assert!(parse_mode(bad).is_err(), "{bad}");
        }
    }
    const SITE: &str = "[site]\nname = \"hall\"\nanchor = \"a\"\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://10.0.0.1:10940\"\n";

    #[test]
    fn zones_lines_osc_and_mqtt_parse() {
        let c = parse(&format!(
            "{SITE}[[zone]]\nid = \"desk\"\npolygon = [[0, 0], [4, 0], [4, 3.5], [0, 3]]\n[[line]]\nid = \"door\"\nfrom = [0, 0]\nto = [2, 0]\n[[line]]\nid = \"gate\"\nfrom = [5, 0]\nto = [5, 2]\nhysteresis_m = 0.3\n[osc]\ntargets = [\"127.0.0.1:9000\", \"[::1]:9001\"]\n[mqtt]\nurl = \"mqtt://broker.local\"\nusername = \"sf\"\npassword_file = \"mqtt.pw\"\n"
        ))
        .unwrap();
        let p = &c.people;
        assert_eq!(p.zones.len(), 1);
        assert_eq!(p.zones[0].polygon[2], [4.0, 3.5]);
        assert_eq!(p.lines[0].hysteresis_m, DEFAULT_HYSTERESIS_M);
        assert_eq!(p.lines[1].hysteresis_m, 0.3);
        assert_eq!(p.osc_targets.len(), 2);
        let m = p.mqtt.as_ref().unwrap();
        assert_eq!((m.host.as_str(), m.port), ("broker.local", 1883));
        assert_eq!(m.topic_prefix, "scanfuse/hall");
        assert_eq!(
            m.password_file.as_deref(),
            Some(Path::new("/etc/scanfuse/mqtt.pw"))
        );
        let none = parse(SITE).unwrap().people;
        assert_eq!(none, PeopleConfig::default());
    }

    #[test]
    fn bad_zones_lines_and_outputs_name_line_key_and_fix() {
        let cases: [(&str, usize, &str, &str); 11] = [
            (
                "[[zone]]\nid = \"z\"\npolygon = [[0, 0], [1, 0]]\n",
                9,
                "zone.polygon",
                "at least 3 corners",
            ),
            (
                "[[zone]]\nid = \"z\"\npolygon = [[0, 0], [2, 2], [2, 0], [0, 2]]\n",
                9,
                "zone.polygon",
                "crosses itself",
            ),
            (
                "[[zone]]\nid = \"z\"\npolygon = [[0, 0], [1, 0], [0, 1]]\n[[zone]]\nid = \"z\"\npolygon = [[0, 0], [1, 0], [0, 1]]\n",
                11,
                "zone.id",
                "duplicate id \"z\", first used at line 8",
            ),
            (
                "[[zone]]\nid = \"a b\"\npolygon = [[0, 0], [1, 0], [0, 1]]\n",
                8,
                "zone.id",
                "not valid",
            ),
            (
                "[[line]]\nid = \"l\"\nfrom = [1, 1]\nto = [1, 1]\n",
                10,
                "line.to",
                "the same point",
            ),
            (
                "[[line]]\nid = \"l\"\nfrom = [1, 1]\nto = [1, 2]\n[[line]]\nid = \"l\"\nfrom = [1, 1]\nto = [1, 2]\n",
                12,
                "line.id",
                "duplicate id",
            ),
            (
                "[[line]]\nid = \"l\"\nfrom = [1, 1]\nto = [1, 2]\nhysteresis_m = -1\n",
                11,
                "line.hysteresis_m",
                "0–5",
            ),
            (
                "[osc]\ntargets = [\"localhost\"]\n",
                8,
                "osc.targets",
                "IP:PORT",
            ),
            (
                "[mqtt]\nurl = \"http://x\"\n",
                8,
                "mqtt.url",
                "mqtt://HOST:PORT",
            ),
            (
                "[mqtt]\nurl = \"mqtts://x:8883\"\n",
                8,
                "mqtt.url",
                "TLS is not supported",
            ),
            (
                "[mqtt]\nurl = \"mqtt://x\"\npassword_file = \"p\"\n",
                9,
                "mqtt.password_file",
                "needs mqtt.username",
            ),
        ];
        for (tail, line, key, want) in cases {
            let (l, k, m) = invalid(&format!("{SITE}{tail}"));
            assert_eq!((l, k.as_str()), (line, key), "{tail}: {m}");
            assert!(m.contains(want), "{tail}: {m}");
        }
        let (_, k, m) = invalid(&format!(
            "{SITE}[[zone]]\nid = \"z\"\npolygon = [[0, 0, 1], [1, 0], [0, 1]]\n"
        ));
        assert_eq!(k, "zone.polygon", "{m}");
        assert!(m.contains("every point must be [x, y]"), "{m}");
        let (_, k, _) = invalid(&format!(
            "{SITE}[[line]]\nid = \"l\"\nfrom = [1]\nto = [1, 2]\n"
        ));
        assert_eq!(k, "line.from");
    }
}
