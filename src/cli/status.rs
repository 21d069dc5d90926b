//! `scanfuse status`: asks a running daemon how things are, over its status socket, and prints
//! a table a person reads (or the raw JSON objects, or a stream of events).

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context as _, bail};
use scanfuse::daemon::config::{self, Config};
use scanfuse::daemon::protocol::{
    Crossing, Event, Message, PROTO_MAJOR, PoseSource, Poses, SensorPose, SensorStatus, Side,
    Status, Tracks, ZoneStatus, Zones,
};

use super::{BadInput, stdout_error};

/// How long to wait for a reply before deciding the daemon is wedged.
const REPLY_TIMEOUT: Duration = Duration::from_secs(10);

#[derive(clap::Args)]
pub struct Args {
    /// The daemon's status socket.
    #[arg(long, value_name = "PATH", default_value = config::DEFAULT_SOCKET, conflicts_with = "config")]
    socket: PathBuf,
    /// Take the socket path from this site config instead.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Print the daemon's JSON objects as they arrive, one per line.
    #[arg(long)]
    json: bool,
    /// After the table, follow events, and the people tracked (a summary a second, every zone
    /// change and line crossing), until the daemon stops (Ctrl-C to quit).
    #[arg(long)]
    watch: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let socket = match &args.config {
        Some(path) => {
            Config::load(path)
                .map_err(|e| BadInput(e.to_string()))?
                .site
                .socket
        }
        None => args.socket.clone(),
    };
    let mut client = Client::connect(&socket)?;
    let status_line = client.request(r#"{"cmd":"status"}"#)?;
    let poses_line = client.request(r#"{"cmd":"poses"}"#)?;
    let status = match parse(&status_line)? {
        Message::Status(s) => s,
        other => bail!("the daemon answered status with {other:?}"),
    };
    let poses = match parse(&poses_line)? {
        Message::Poses(p) => p,
        other => bail!("the daemon answered poses with {other:?}"),
    };
    let mut out = std::io::stdout().lock();
    if args.json {
        writeln!(out, "{status_line}\n{poses_line}").map_err(stdout_error)?;
    } else {
        write!(out, "{}", render_table(&status, &poses)).map_err(stdout_error)?;
    }
    out.flush().map_err(stdout_error)?;
    if !args.watch {
        return Ok(());
    }
    let reply = client.request(r#"{"cmd":"watch","status":true,"tracks":true}"#)?;
    if args.json {
        writeln!(out, "{reply}").map_err(stdout_error)?;
    } else {
        writeln!(out, "\nwatching events and people (Ctrl-C to stop)").map_err(stdout_error)?;
    }
    // TRACKS come at the fused rate; a person reads one summary a second.
    let mut last_tracks_ns: Option<u64> = None;
    out.flush().map_err(stdout_error)?;
    client.stream.set_read_timeout(None)?;
    loop {
        let Some(line) = client.next_line()? else {
            bail!("the daemon closed the connection (it stopped or dropped this client)");
        };
        if args.json {
            writeln!(out, "{line}").map_err(stdout_error)?;
        } else {
            match serde_json::from_str::<Message>(&line) {
                Ok(Message::Event(e)) => {
                    writeln!(out, "{}", render_event(&e)).map_err(stdout_error)?
                }
                Ok(Message::Tracks(t))
                    if last_tracks_ns.is_none_or(|last| {
                        t.t_ns < last || t.t_ns >= last.saturating_add(TRACKS_EVERY_NS)
                    }) =>
                {
                    last_tracks_ns = Some(t.t_ns);
                    writeln!(out, "{}", render_tracks(&t)).map_err(stdout_error)?
                }
                Ok(Message::Zones(z)) => {
                    writeln!(out, "{}", render_zones(&z)).map_err(stdout_error)?
                }
                Ok(Message::Crossing(c)) => {
                    writeln!(out, "{}", render_crossing(&c)).map_err(stdout_error)?
                }
                Ok(Message::Error(e)) => bail!("the daemon says: {}", e.message),
                _ => {}
            }
        }
        out.flush().map_err(stdout_error)?;
    }
}

/// A connection to the daemon, past its banner.
struct Client {
    stream: UnixStream,
    reader: BufReader<UnixStream>,
}

impl Client {
    fn connect(socket: &Path) -> anyhow::Result<Client> {
        let stream = UnixStream::connect(socket).map_err(|e| {
            let shown = socket.display();
            let start = "start it with `sudo systemctl start scanfuse` (or `scanfuse run --config FILE`), or point --socket at the socket named by site.socket in its config";
            match e.kind() {
                std::io::ErrorKind::NotFound => {
                    anyhow::anyhow!("scanfuse is not running at {shown} (no socket there); {start}")
                }
                std::io::ErrorKind::ConnectionRefused => anyhow::anyhow!(
                    "scanfuse is not running at {shown} (a socket file is there but nothing listens); {start}"
                ),
                std::io::ErrorKind::PermissionDenied => anyhow::anyhow!(
                    "not allowed to connect to {shown}: the socket is for the daemon's user and group (site.socket_mode); run as a member of that group or with sudo"
                ),
                _ => anyhow::anyhow!("cannot connect to scanfuse at {shown}: {e}"),
            }
        })?;
        stream.set_read_timeout(Some(REPLY_TIMEOUT))?;
        let reader = BufReader::new(stream.try_clone()?);
        let mut client = Client { stream, reader };
        let banner = client
            .next_line()?
            .context("the daemon closed the connection before its banner")?;
        match parse(&banner)? {
            Message::Version(v) if v.proto_major == PROTO_MAJOR => Ok(client),
            Message::Version(v) => bail!(
                "the daemon (release {}) speaks protocol {}.{}, this client {PROTO_MAJOR}.x; use the scanfuse that came with the daemon",
                v.release,
                v.proto_major,
                v.proto_minor
            ),
            Message::Error(e) => bail!("the daemon refused the connection: {}", e.message),
            other => bail!("expected the daemon's VERSION banner, got {other:?}"),
        }
    }

    fn next_line(&mut self) -> anyhow::Result<Option<String>> {
        let mut line = String::new();
        let n = self
            .reader
            .read_line(&mut line)
            .context("no answer from the daemon")?;
        Ok((n > 0).then(|| line.trim_end().to_string()))
    }

    /// Sends one request and returns the reply line; an ERROR reply becomes an error.
    fn request(&mut self, request: &str) -> anyhow::Result<String> {
        writeln!(self.stream, "{request}").context("cannot send to the daemon")?;
        let line = self
            .next_line()?
            .context("the daemon closed the connection without answering")?;
        if let Message::Error(e) = parse(&line)? {
            bail!("the daemon says: {}", e.message);
        }
        Ok(line)
    }
}

fn parse(line: &str) -> anyhow::Result<Message> {
    serde_json::from_str(line)
        .with_context(|| format!("cannot understand the daemon's reply {line:?}"))
}

/// The status table: one row per sensor, joined with its pose.
pub fn render_table(status: &Status, poses: &Poses) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "site {} · up {} · anchor {}",
        status.site,
        duration(status.uptime_s),
        poses.anchor
    );
    if status.queue_drops > 0 {
        let _ = write!(
            out,
            " · {} scans dropped by the registration queue",
            status.queue_drops
        );
    }
    if let Some(web) = &status.web {
        let _ = write!(out, " · {web}");
    }
    if let Some(foxglove) = &status.foxglove {
        let _ = write!(out, " · {foxglove}");
    }
    if let Some(zenoh) = &status.zenoh {
        let _ = write!(out, " · {zenoh}");
    }
    out.push('\n');
    let _ = writeln!(
        out,
        "{:<16} {:<12} {:>8} {:>9} {:>9} {:>8} {:>7} {:>7} {:>7}  {:<14} LAST ERROR",
        "SENSOR", "STATE", "RATE Hz", "X m", "Y m", "YAW °", "σX m", "σY m", "σYAW °", "POSE FROM"
    );
    let mut ids: Vec<&str> = status.sensors.iter().map(|s| s.id.as_str()).collect();
    for p in &poses.sensors {
        if !ids.contains(&p.id.as_str()) {
            ids.push(&p.id);
        }
    }
    let mut notes = Vec::new();
    for id in ids {
        let s = status.sensors.iter().find(|s| s.id == id);
        let p = poses.sensors.iter().find(|p| p.id == id);
        let _ = writeln!(out, "{}", row(id, s, p));
        match p {
            Some(p) if !p.registered => notes.push(format!(
                "{id}: not registered: {}",
                p.reason.as_deref().unwrap_or("no reason given")
            )),
            Some(SensorPose {
                reason: Some(caveat),
                ..
            }) => notes.push(format!("{id}: {caveat}")),
            _ => {}
        }
    }
    // A site daemon's zones, in the same columns: where each zone's frame lies in the site's.
    for z in &status.zones {
        let _ = writeln!(out, "{}", zone_row(z));
        if let Some(why) = &z.reason {
            notes.push(format!("zone {}: {why}", z.zone));
        }
        if let Some(why) = &z.unreadable {
            notes.push(format!("zone {} sends what cannot be read: {why}", z.zone));
        }
    }
    // Where the site frame lies in the building drawing, in the same columns: the row a
    // person reads to turn the poses above into drawing coordinates.
    if let Some(b) = &poses.building_from_site {
        let _ = writeln!(out, "{}", building_row(b));
        match (&b.reason, b.aligned) {
            (Some(why), false) => notes.push(format!(
                "building: not aligned to the drawing (the poses stay in the anchor's frame): {why}"
            )),
            (Some(why), true) => notes.push(format!("building: {why}")),
            _ => {}
        }
        if b.aligned && (b.scale - 1.0).abs() > 1e-9 {
            notes.push(format!(
                "building: the drawing's scale against the site's is {:.4}",
                b.scale
            ));
        }
    }
    for note in notes {
        let _ = writeln!(out, "{note}");
    }
    out
}

/// `building_from_site` as a row of the table: the site origin's place in the drawing.
fn building_row(b: &scanfuse::drawing::BuildingFromSite) -> String {
    let num = |v: Option<f64>, decimals: usize| match v.filter(|_| b.aligned) {
        Some(v) => format!("{v:.decimals$}"),
        None => "-".to_string(),
    };
    format!(
        "{:<16} {:<12} {:>8} {:>9} {:>9} {:>8} {:>7} {:>7} {:>7}  {:<14} -",
        "building←site",
        if b.aligned { "aligned" } else { "not aligned" },
        "-",
        num(Some(b.x_m), 3),
        num(Some(b.y_m), 3),
        num(Some(b.yaw_deg), 2),
        num(b.sigma_x_m, 3),
        num(b.sigma_y_m, 3),
        num(b.sigma_yaw_deg, 2),
        b.method,
    )
}

/// A zone of a site daemon as a row of the table: its frame's place in the site's.
fn zone_row(z: &ZoneStatus) -> String {
    let f = z.site_from_zone.as_ref();
    let num = |v: Option<f64>, decimals: usize| match v {
        Some(v) => format!("{v:.decimals$}"),
        None => "-".to_string(),
    };
    let from = match f {
        Some(f) if f.pairs == 0 => "anchor zone".to_string(),
        Some(f) => format!("{} pairs", f.pairs),
        None => "unplaced".to_string(),
    };
    let rate = z
        .bytes_per_s
        .map_or_else(String::new, |b| format!(", sends {:.1} kB/s", b / 1e3));
    format!(
        "{:<16} {:<12} {:>8} {:>9} {:>9} {:>8} {:>7} {:>7} {:>7}  {:<14} {} of {} sensors placed in the zone{rate}",
        format!("zone {}", z.zone),
        format!(
            "{} {}",
            if z.alive { "alive" } else { "lost" },
            duration(z.for_s)
        ),
        "-",
        num(f.map(|f| f.x_m), 3),
        num(f.map(|f| f.y_m), 3),
        num(f.map(|f| f.yaw_deg), 2),
        num(f.map(|f| f.sigma_x_m), 3),
        num(f.map(|f| f.sigma_y_m), 3),
        num(f.map(|f| f.sigma_yaw_deg), 2),
        from,
        z.placed,
        z.sensors,
    )
}

fn row(id: &str, s: Option<&SensorStatus>, p: Option<&SensorPose>) -> String {
    let num = |v: Option<f64>, decimals: usize| match v {
        Some(v) => format!("{v:.decimals$}"),
        None => "-".to_string(),
    };
    let registered = p.filter(|p| p.registered);
    let field = |f: fn(&SensorPose) -> Option<f64>| registered.and_then(f);
    let source = match p {
        Some(p) if !p.registered => "unregistered".to_string(),
        Some(p) => {
            let from = p.source.map_or("-", PoseSource::as_str);
            match p.age_s {
                Some(age) => format!("{from} {}", duration(age)),
                None => from.to_string(),
            }
        }
        None => "-".to_string(),
    };
    // What it sees outranks its last link error: that is what to go and fix.
    let error = match s.and_then(|s| s.warning.as_deref().or(s.last_error.as_deref())) {
        Some(e) if s.is_some_and(|s| s.warning.is_some()) => e.to_string(),
        Some(e) => match s.and_then(|s| s.last_error_age_s) {
            Some(age) => format!("{e} ({} ago)", duration(age)),
            None => e.to_string(),
        },
        None => "-".to_string(),
    };
    // On a site daemon a sensor has no driver here: its zone stands in for its state.
    let state = match (s, p.and_then(|p| p.zone.as_ref().map(|z| (z, p.stale)))) {
        (Some(s), _) => s.state.as_str().to_string(),
        (None, Some((zone, false))) => format!("zone {zone}"),
        (None, Some((zone, true))) => format!("{zone} stale"),
        (None, None) => "unknown".to_string(),
    };
    format!(
        "{:<16} {:<12} {:>8} {:>9} {:>9} {:>8} {:>7} {:>7} {:>7}  {:<14} {}",
        id,
        state,
        num(s.and_then(|s| s.rate_hz), 1),
        num(field(|p| p.x_m), 3),
        num(field(|p| p.y_m), 3),
        num(field(|p| p.yaw_deg), 2),
        num(field(|p| p.sigma_x_m), 3),
        num(field(|p| p.sigma_y_m), 3),
        num(field(|p| p.sigma_yaw_deg), 2),
        source,
        error
    )
}

/// One event as a line a person reads.
pub fn render_event(e: &Event) -> String {
    let kind = serde_json::to_value(e.kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    match &e.sensor {
        Some(sensor) => format!("{}  {sensor}  {kind}: {}", e.time, e.message),
        None => format!("{}  {kind}: {}", e.time, e.message),
    }
}

/// `status --watch` prints one `TRACKS` summary per this much of the scans' clock.
const TRACKS_EVERY_NS: u64 = 1_000_000_000;
/// Tracks named in a summary line; the rest are counted.
const TRACKS_SHOWN: usize = 10;

/// A `t_ns` (the scans' clock) as RFC 3339 UTC, like an event's time.
fn stamp(t_ns: u64) -> String {
    let t = std::time::UNIX_EPOCH + Duration::from_nanos(t_ns);
    humantime::format_rfc3339_millis(t).to_string()
}

/// `TRACKS` as one line: `… 12 people: t3 (4.1, 2.0) t5 (0.3, -1.2) …`.
pub fn render_tracks(t: &Tracks) -> String {
    let n = t.tracks.len();
    let mut line = format!(
        "{}  {n} {}",
        stamp(t.t_ns),
        if n == 1 { "person" } else { "people" }
    );
    if n > 0 {
        line.push(':');
    }
    for track in t.tracks.iter().take(TRACKS_SHOWN) {
        let _ = write!(line, " t{} ({:.1}, {:.1})", track.id, track.x_m, track.y_m);
    }
    if n > TRACKS_SHOWN {
        let _ = write!(line, " and {} more", n - TRACKS_SHOWN);
    }
    line
}

/// `ZONES` as one line: `… zones: desk 2 (t3, t5), hall 0`.
pub fn render_zones(z: &Zones) -> String {
    let zones: Vec<String> = z
        .zones
        .iter()
        .map(|zone| {
            if zone.tracks.is_empty() {
                format!("{} {}", zone.id, zone.count)
            } else {
                let ids: Vec<String> = zone.tracks.iter().map(|id| format!("t{id}")).collect();
                format!("{} {} ({})", zone.id, zone.count, ids.join(", "))
            }
        })
        .collect();
    format!("{}  zones: {}", stamp(z.t_ns), zones.join(", "))
}

/// `CROSSING` as one line: `… door: t3 crossed to the left (left 5, right 3)`.
pub fn render_crossing(c: &Crossing) -> String {
    let side = match c.to {
        Side::Left => "left",
        Side::Right => "right",
    };
    format!(
        "{}  {}: t{} crossed to the {side} (left {}, right {})",
        stamp(c.t_ns),
        c.line,
        c.track,
        c.left_total,
        c.right_total
    )
}

/// `42s`, `3m05s`, `2h01m`, `3d04h`.
fn duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s}s"),
        60..3600 => format!("{}m{:02}s", s / 60, s % 60),
        3600..86400 => format!("{}h{:02}m", s / 3600, s % 3600 / 60),
        _ => format!("{}d{:02}h", s / 86400, s % 86400 / 3600),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use scanfuse::daemon::protocol::SensorState;

    #[test]
    fn the_table_joins_status_and_poses_and_explains_the_unregistered() {
        let mut a = SensorStatus::new("entrance", SensorState::Streaming);
        a.rate_hz = Some(39.96);
        let mut b = SensorStatus::new("dock", SensorState::Disconnected);
        b.last_error = Some("connection refused".into());
        b.last_error_age_s = Some(75.0);
        let status = Status {
            site: "hall".into(),
            uptime_s: 3725.0,
            queue_drops: 3,
            sensors: vec![a, b],
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        };
        let mut pa = SensorPose::unregistered("entrance", "");
        pa.registered = true;
        pa.reason = None;
        pa.x_m = Some(0.0);
        pa.y_m = Some(0.0);
        pa.yaw_deg = Some(0.0);
        pa.sigma_x_m = Some(0.012);
        pa.source = Some(PoseSource::Surveyed);
        pa.age_s = Some(30.0);
        let poses = Poses {
            anchor: "entrance".into(),
            sensors: vec![pa, SensorPose::unregistered("dock", "no static view yet")],
            building_from_site: None,
            site_from_zone: None,
        };
        let table = render_table(&status, &poses);
        let lines: Vec<&str> = table.lines().collect();
        assert_eq!(lines.len(), 5, "{table}");
        assert!(lines[0].contains("up 1h02m"), "{table}");
        assert!(lines[0].contains("3 scans dropped"), "{table}");
        assert!(lines[2].starts_with("entrance"), "{table}");
        assert!(lines[2].contains("streaming"), "{table}");
        assert!(lines[2].contains(" 40.0 "), "{table}");
        assert!(lines[2].contains("0.012"), "{table}");
        assert!(lines[2].contains("surveyed 30s"), "{table}");
        assert!(lines[3].contains("disconnected"), "{table}");
        assert!(lines[3].contains("unregistered"), "{table}");
        assert!(
            lines[3].ends_with("connection refused (1m15s ago)"),
            "{table}"
        );
        assert_eq!(lines[4], "dock: not registered: no static view yet");
        // A registered sensor's reason is a caveat about its pose: shown as a note too.
        let mut poses = poses;
        poses.sensors[0].reason = Some("rests on one pair only (with dock)".into());
        let table = render_table(&status, &poses);
        let lines: Vec<&str> = table.lines().collect();
        assert_eq!(lines.len(), 6, "{table}");
        assert_eq!(lines[4], "entrance: rests on one pair only (with dock)");
        assert_eq!(lines[5], "dock: not registered: no static view yet");

        // building_from_site is a row of its own, with its σ; not aligned, it says why.
        poses.building_from_site = Some(scanfuse::drawing::BuildingFromSite {
            x_m: 31.5,
            y_m: -7.25,
            yaw_deg: 23.0,
            aligned: true,
            method: "automatic+lines".into(),
            sigma_x_m: Some(0.004),
            sigma_y_m: Some(0.006),
            sigma_yaw_deg: Some(0.03),
            ..Default::default()
        });
        let table = render_table(&status, &poses);
        let row = table
            .lines()
            .find(|l| l.starts_with("building←site"))
            .expect(&table);
        for part in [
            "aligned", "31.500", "-7.250", "23.00", "0.004", "0.006", "0.03",
        ] {
            assert!(row.contains(part), "{part}: {table}");
        }
        assert!(row.contains("automatic+lines"), "{table}");
        poses.building_from_site = Some(scanfuse::drawing::BuildingFromSite {
            method: "automatic".into(),
            reason: Some("ambiguous: a symmetric building?".into()),
            ..Default::default()
        });
        let table = render_table(&status, &poses);
        assert!(table.contains("building←site    not aligned"), "{table}");
        assert!(
            table.contains("building: not aligned to the drawing (the poses stay in the anchor's frame): ambiguous"),
            "{table}"
        );
    }

    #[test]
    fn durations_read_naturally() {
        assert_eq!(duration(0.4), "0s");
        assert_eq!(duration(59.0), "59s");
        assert_eq!(duration(61.0), "1m01s");
        assert_eq!(duration(7300.0), "2h01m");
        assert_eq!(duration(90_000.0), "1d01h");
    }

    #[test]
    fn people_read_as_one_line_each() {
        use scanfuse::daemon::protocol::{Track, ZoneCount};
        let track = |id, x_m, y_m| Track {
            id,
            x_m,
            y_m,
            vx_m_s: 0.0,
            vy_m_s: 0.0,
            sigma_m: 0.05,
            age_s: 3.0,
            sensors: vec![],
        };
        let t = Tracks {
            t_ns: 1_700_000_000_000_000_000,
            tracks: vec![track(3, 4.12, 2.0), track(5, 0.3, -1.25)],
        };
        assert_eq!(
            render_tracks(&t),
            "2023-11-14T22:13:20.000Z  2 people: t3 (4.1, 2.0) t5 (0.3, -1.2)"
        );
        let many = Tracks {
            t_ns: 0,
            tracks: (0..12).map(|i| track(i, 0.0, 0.0)).collect(),
        };
        assert!(render_tracks(&many).ends_with("t9 (0.0, 0.0) and 2 more"));
        let none = Tracks {
            t_ns: 0,
            tracks: vec![],
        };
        assert!(render_tracks(&none).ends_with("  0 people"));
        let z = Zones {
            t_ns: 0,
            zones: vec![
                ZoneCount {
                    id: "desk".into(),
                    count: 2,
                    tracks: vec![3, 5],
                },
                ZoneCount {
                    id: "hall".into(),
                    count: 0,
                    tracks: vec![],
                },
            ],
        };
        assert!(render_zones(&z).ends_with("  zones: desk 2 (t3, t5), hall 0"));
        let c = Crossing {
            t_ns: 0,
            line: "door".into(),
            track: 3,
            to: Side::Left,
            left_total: 5,
            right_total: 3,
        };
        assert!(render_crossing(&c).ends_with("  door: t3 crossed to the left (left 5, right 3)"));
    }
}
