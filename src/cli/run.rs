//! `scanfuse run --config FILE [--for 30s]`: the daemon in the foreground. The terminal shows a
//! person what happens: sensors connecting, registration, the poses (next to the recording's
//! truth for `replay:` sensors that have one), then live rates; map files go to the state dir.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::Duration;

use anyhow::Context as _;
use scanfuse::daemon::config::{Config, Connect};
use scanfuse::daemon::pipeline::Report;
use scanfuse::daemon::protocol::{
    Event, EventKind, PoseSource, Poses, SensorPose, SensorState, Status,
};
use scanfuse::daemon::run::{RunOptions, RunSummary, run_daemon};
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record;
use scanfuse::scan::TruthPose;

use super::{BadInput, Console, stdout_error};

#[derive(clap::Args)]
pub struct Args {
    /// The site config (TOML).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Stop after this long (e.g. 30s, 2m); default: until Ctrl-C or SIGTERM.
    #[arg(long = "for", value_name = "DURATION", value_parser = humantime::parse_duration)]
    duration: Option<Duration>,
    /// Play `replay:` sensors this many times faster than recorded (tests, demos); the poses
    /// come out as at ×1, since every timer follows the scans' own clock.
    #[arg(long, value_name = "N", default_value_t = 1.0)]
    replay_speed: f64,
    /// Anchor `replay:` sensors to the wall clock: their recordings (looping) started playing
    /// at TIME (RFC 3339, e.g. 2026-11-29T07:00:00Z, or Unix seconds), so a daemon started or
    /// restarted later joins the replay where it stands by now, and scans are stamped with the
    /// time they would have been taken. Give every daemon replaying one site the same TIME and
    /// their replays run in step, as live units do.
    #[arg(long, value_name = "TIME", value_parser = parse_since)]
    replay_since: Option<std::time::SystemTime>,
}

/// `--replay-since`: RFC 3339 or Unix seconds.
fn parse_since(text: &str) -> Result<std::time::SystemTime, String> {
    if let Ok(s) = text.trim().parse::<f64>() {
        return if s.is_finite() && s >= 0.0 {
            Ok(std::time::UNIX_EPOCH + Duration::from_secs_f64(s))
        } else {
            Err(format!("{text:?} is not a time: give Unix seconds ≥ 0"))
        };
    }
    humantime::parse_rfc3339_weak(text.trim()).map_err(|e| {
        format!(
            "{text:?} is not a time ({e}): give RFC 3339 (2026-11-29T07:00:00Z) or Unix seconds"
        )
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = Config::load(&args.config).map_err(|e| BadInput(e.to_string()))?;
    if !(args.replay_speed.is_finite() && args.replay_speed > 0.0) {
        return Err(BadInput(format!(
            "--replay-speed {} must be a positive number",
            args.replay_speed
        ))
        .into());
    }
    if args.replay_since.is_some()
        && !config
            .sensors
            .iter()
            .any(|s| matches!(s.connect, Connect::Replay { .. }))
    {
        eprintln!(
            "--replay-since: {} has no replay: sensor; it anchors nothing",
            args.config.display()
        );
    }
    if config.site.role == scanfuse::daemon::config::Role::Site {
        return run_site(config, args.duration);
    }
    let (truth, moved) = replay_truth(&config);
    let (tap, reports) = mpsc::channel();
    let options = RunOptions {
        duration: args.duration,
        tap: Some(tap),
        replay_speed: args.replay_speed,
        replay_since: args.replay_since,
        ..RunOptions::default()
    };
    let mut out = std::io::stdout();
    writeln!(
        out,
        "site {:?}: {} sensors, anchor {}; map files go to {}; status socket {}",
        config.site.name,
        config.sensors.len(),
        config.site.anchor,
        config.site.state_dir.display(),
        config.site.socket.display()
    )
    .map_err(stdout_error)?;
    writeln!(
        out,
        "{}",
        match args.duration {
            Some(d) => format!(
                "running for {} (Ctrl-C stops sooner)",
                humantime::format_duration(d)
            ),
            None => "running until Ctrl-C".to_string(),
        }
    )
    .map_err(stdout_error)?;
    let printer =
        std::thread::spawn(move || Terminal::new(truth).with_moves(moved).follow(reports));
    let summary = daemon_runtime()?.block_on(run_daemon(config.clone(), options));
    let _ = printer.join();
    finish(summary?, &config.site.state_dir)
}

/// The site daemon in the foreground: what happens to the zones, one line each.
#[cfg(feature = "zenoh")]
fn run_site(config: Config, duration: Option<Duration>) -> anyhow::Result<()> {
    let mut out = std::io::stdout();
    writeln!(
        out,
        "site {:?}: the site daemon, joining zones on Zenoh into the frame of zone {}; status socket {}",
        config.site.name,
        config.site.anchor,
        config.site.socket.display()
    )
    .map_err(stdout_error)?;
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<std::sync::Arc<str>>();
    let printer = std::thread::spawn(move || {
        while let Some(line) = rx.blocking_recv() {
            let message = serde_json::from_str::<Event>(&line)
                .map(|e| e.message)
                .unwrap_or_else(|_| line.to_string());
            if writeln!(std::io::stdout(), "{message}").is_err() {
                break;
            }
        }
    });
    let ran = daemon_runtime()?.block_on(scanfuse::daemon::site_net::run_site_daemon(
        config,
        duration,
        Some(tx),
    ));
    let _ = printer.join();
    Ok(ran?)
}

#[cfg(not(feature = "zenoh"))]
fn run_site(_config: Config, _duration: Option<Duration>) -> anyhow::Result<()> {
    Err(BadInput(
        "this scanfuse was built without the `zenoh` feature: a site daemon needs it".into(),
    )
    .into())
}

/// A multi-threaded runtime: driver tasks, the socket and the emulators share it.
pub(super) fn daemon_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

pub(super) fn finish(summary: RunSummary, dir: &std::path::Path) -> anyhow::Result<()> {
    match summary.saved {
        Ok(saved) => writeln!(
            std::io::stdout(),
            "\nwrote {} in {}",
            saved.files.join(", "),
            dir.display()
        )
        .map_err(stdout_error),
        Err(e) => anyhow::bail!("the final save failed: {e}"),
    }
}

/// Where each sensor of `recording` stands after its last move, by its recorded id.
pub(super) fn recorded_moves(recording: &record::Recording) -> BTreeMap<String, TruthPose> {
    let mut moves: Vec<&scanfuse::scan::MoveTruth> = recording.moves.iter().collect();
    moves.sort_by_key(|m| m.at_ns);
    moves
        .into_iter()
        .map(|m| (m.sensor_id.clone(), m.pose))
        .collect()
}

/// The recordings' truth of every `replay:` sensor, by configured id.
fn replay_truth(config: &Config) -> (BTreeMap<String, TruthPose>, BTreeMap<String, TruthPose>) {
    let mut recordings = BTreeMap::new();
    let (mut truth, mut moved) = (BTreeMap::new(), BTreeMap::new());
    for s in &config.sensors {
        let Connect::Replay { file, sensor } = &s.connect else {
            continue;
        };
        let recording = recordings
            .entry(file.clone())
            .or_insert_with(|| record::read(file).ok());
        if let Some(t) = recording
            .as_ref()
            .and_then(|r| r.sensor(sensor))
            .and_then(|i| i.truth)
        {
            truth.insert(s.id.clone(), t);
        }
        if let Some(m) = recording
            .as_ref()
            .and_then(|r| recorded_moves(r).remove(sensor))
        {
            moved.insert(s.id.clone(), m);
        }
    }
    (truth, moved)
}

/// Prints reports: events as they come, the poses once registration has answered (again
/// whenever a sensor is placed or lost), then rates. On a terminal ([`Console::Human`]) every
/// line; otherwise the events are the log's, and only the pose table is printed here.
pub(super) struct Terminal {
    truth: BTreeMap<String, TruthPose>,
    /// Where a sensor the recording moves stands after its (last) move: a re-registered pose
    /// is compared with that.
    moved: BTreeMap<String, TruthPose>,
    console: Console,
    out: Box<dyn Write + Send>,
    /// Which sensors were placed in the pose table last printed; `None` before one.
    shown: Option<Vec<(String, bool)>>,
    last_waiting: String,
    ticks: u64,
    /// Stdout's reader went away: nothing more is printed.
    closed: bool,
}

impl Terminal {
    pub(super) fn new(truth: BTreeMap<String, TruthPose>) -> Terminal {
        Terminal::with(truth, Console::detect(), Box::new(std::io::stdout()))
    }

    /// The recordings' moves ([`recorded_moves`]).
    pub(super) fn with_moves(self, moved: BTreeMap<String, TruthPose>) -> Terminal {
        Terminal { moved, ..self }
    }

    fn with(
        truth: BTreeMap<String, TruthPose>,
        console: Console,
        out: Box<dyn Write + Send>,
    ) -> Terminal {
        Terminal {
            truth,
            moved: BTreeMap::new(),
            console,
            out,
            shown: None,
            last_waiting: String::new(),
            ticks: 0,
            closed: false,
        }
    }

    /// Prints `text` (lines); a reader that went away silences the rest, quietly.
    fn print(&mut self, text: &str) {
        if self.closed {
            return;
        }
        if writeln!(self.out, "{text}")
            .and_then(|()| self.out.flush())
            .is_err()
        {
            self.closed = true;
        }
    }

    pub(super) fn follow(mut self, reports: mpsc::Receiver<Report>) {
        let mut last = None;
        for report in reports {
            match report {
                Report::Event(e) => {
                    if e.kind == EventKind::ReRegistered {
                        self.shown = None;
                    }
                    if self.console == Console::Human
                        && let Some(line) = event_line(&e)
                    {
                        self.print(&line);
                    }
                }
                Report::Tick { status, poses } => {
                    self.tick(&status, &poses);
                    last = Some((status, poses));
                }
            }
        }
        if let Some((status, poses)) = last
            && self.shown.is_none()
        {
            self.print_poses(&poses);
            if self.console == Console::Human {
                self.print(&rate_line(&status));
            }
        }
    }

    fn tick(&mut self, status: &Status, poses: &Poses) {
        self.ticks += 1;
        if registration_answered(status, poses) {
            let placed = placement(poses);
            if self.shown.as_ref() != Some(&placed) {
                self.print_poses(poses);
                self.shown = Some(placed);
            } else if self.console == Console::Human && self.ticks.is_multiple_of(2) {
                self.print(&rate_line(status));
            }
            return;
        }
        let waiting = waiting_line(status, poses);
        if self.console == Console::Human && waiting != self.last_waiting {
            self.print(&format!("          {waiting}"));
            self.last_waiting = waiting;
        }
    }

    fn print_poses(&mut self, poses: &Poses) {
        let mut text = String::new();
        // Truth is in the simulator's world frame; the site frame is the anchor's.
        let world_from_anchor = self
            .truth
            .get(&poses.anchor)
            .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()));
        let _ = writeln!(
            text,
            "\nposes in the frame of {:?}:\n{:<10} {:>9} {:>9} {:>8} {:>7} {:>8}   {:>9} {:>9} {:>8}  {:>7} {:>6}",
            poses.anchor,
            "sensor",
            "x m",
            "y m",
            "yaw °",
            "σxy cm",
            "source",
            "truth x",
            "truth y",
            "yaw °",
            "err cm",
            "err °"
        );
        for p in &poses.sensors {
            let (Some(x), Some(y), Some(yaw)) = (p.x_m, p.y_m, p.yaw_deg) else {
                let _ = writeln!(text, "{}", unplaced_line(p));
                continue;
            };
            let sigma_cm = p.sigma_x_m.unwrap_or(0.0).max(p.sigma_y_m.unwrap_or(0.0)) * 100.0;
            let _ = write!(
                text,
                "{:<10} {x:>9.3} {y:>9.3} {yaw:>8.2} {sigma_cm:>7.1} {:>8}",
                p.id,
                p.source.map_or("", |s| s.as_str())
            );
            // A re-registered sensor of a recording that moves it stands where it was moved to
            // (in a looping replay, only until the recording starts over).
            let truth = match p.source {
                Some(PoseSource::ReRegistered) => self.moved.get(&p.id).or(self.truth.get(&p.id)),
                _ => self.truth.get(&p.id),
            };
            if let (Some(w_a), Some(t)) = (world_from_anchor, truth) {
                let truth = w_a.inverse() * pose2(t.x_m, t.y_m, t.yaw_deg.to_radians());
                let (err_m, err_rad) = pose_error(&pose2(x, y, yaw.to_radians()), &truth);
                let _ = write!(
                    text,
                    "   {:>9.3} {:>9.3} {:>8.2}  {:>7.1} {:>6.2}",
                    truth.translation.x,
                    truth.translation.y,
                    scanfuse::geometry::yaw_rad(&truth).to_degrees(),
                    err_m * 100.0,
                    err_rad.to_degrees().abs()
                );
            }
            text.push('\n');
        }
        for (id, caveat) in poses
            .sensors
            .iter()
            .filter(|p| p.registered)
            .filter_map(|p| Some((&p.id, p.reason.as_deref()?)))
        {
            let _ = writeln!(text, "{id}: {caveat}");
        }
        self.print(&text);
    }
}

/// An event as one line for a person, or `None` for one the pose table shows (a sensor's
/// registration). A message that starts with its sensor's id does not repeat it.
fn event_line(e: &Event) -> Option<String> {
    let time = e.time.get(11..19).unwrap_or(&e.time);
    let who = e.sensor.as_deref().unwrap_or("");
    let registration = matches!(
        e.kind,
        EventKind::Registering | EventKind::Registered | EventKind::ReRegistered
    );
    if who.is_empty() {
        return Some(if registration {
            format!("{time}  {}", e.message)
        } else {
            format!("{time}  {who:<8} {}", e.message)
        });
    }
    if registration && e.kind != EventKind::Registering {
        return None;
    }
    let message = e
        .message
        .strip_prefix(who)
        .and_then(|rest| rest.strip_prefix(' '))
        .unwrap_or(&e.message);
    Some(format!("{time}  {who:<8} {message}"))
}

/// The pose table's line for a sensor without a pose: its id once, then why.
fn unplaced_line(p: &SensorPose) -> String {
    format!(
        "{:<10} not registered: {}",
        p.id,
        p.reason.as_deref().unwrap_or("no reason given")
    )
}

/// True once registration has answered for every sensor that streams: each has a pose or a
/// reason it has none other than waiting for scans (`waiting …`).
fn registration_answered(status: &Status, poses: &Poses) -> bool {
    let answered = |id: &str| {
        poses.sensors.iter().any(|p| {
            p.id == id
                && (p.registered || !p.reason.as_deref().unwrap_or("").starts_with("waiting"))
        })
    };
    let streaming: Vec<&str> = status
        .sensors
        .iter()
        .filter(|s| s.state == SensorState::Streaming)
        .map(|s| s.id.as_str())
        .collect();
    !streaming.is_empty() && streaming.iter().all(|id| answered(id))
}

/// Which sensors are placed: the pose table is printed again when this changes.
fn placement(poses: &Poses) -> Vec<(String, bool)> {
    poses
        .sensors
        .iter()
        .map(|p| (p.id.clone(), p.registered))
        .collect()
}

/// The state line shown while registration has not answered.
fn waiting_line(status: &Status, poses: &Poses) -> String {
    let total = poses.sensors.len();
    let registered = poses.sensors.iter().filter(|p| p.registered).count();
    let streaming = status
        .sensors
        .iter()
        .filter(|s| s.state == SensorState::Streaming)
        .count();
    format!(
        "{streaming}/{total} sensors streaming, {registered}/{total} registered; registration waits for ~1 s of scans from each"
    )
}

/// Every sensor's rate, placed or not; a sensor whose scans stopped says for how long.
fn rate_line(status: &Status) -> String {
    let rates: Vec<String> = status
        .sensors
        .iter()
        .map(|s| match (s.state, s.rate_hz, s.last_scan_age_s) {
            (SensorState::Streaming, Some(hz), _) => format!("{} {hz:.1} Hz", s.id),
            (SensorState::Streaming, None, Some(age)) => format!(
                "{} no scans for {}",
                s.id,
                scanfuse::human::duration(Duration::from_secs_f64(age.max(0.0)))
            ),
            (state, _, _) => format!("{} {}", s.id, state.as_str()),
        })
        .collect();
    format!(
        "{:>8.0} s  {}  · queue drops {}",
        status.uptime_s,
        rates.join(" · "),
        status.queue_drops
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use scanfuse::daemon::protocol::{PoseSource, SensorStatus};
    use std::sync::{Arc, Mutex};

    fn event(kind: EventKind, sensor: Option<&str>, message: &str) -> Event {
        Event {
            time: "2026-01-31T12:00:01.250Z".into(),
            kind,
            sensor: sensor.map(str::to_string),
            message: message.into(),
        }
    }

    #[test]
    fn replay_since_takes_rfc3339_or_unix_seconds_and_says_what_it_wants() {
        let t = std::time::UNIX_EPOCH + Duration::from_secs(1_795_849_200);
        assert_eq!(parse_since("2026-11-28T07:00:00Z"), Ok(t));
        assert_eq!(parse_since("1795849200"), Ok(t));
        assert_eq!(
            parse_since("1795849200.5"),
            Ok(t + Duration::from_millis(500))
        );
        for bad in ["yesterday", "-5", "2026-13-01T00:00:00Z"] {
            let e = parse_since(bad).unwrap_err();
            assert!(e.contains("RFC 3339") || e.contains("Unix seconds"), "{e}");
        }
    }

    #[test]
    fn an_event_line_names_its_sensor_once() {
        let e = event(
            EventKind::Error,
            Some("ust"),
            "ust not registered: it shares no usable view; trying again in 30 s",
        );
        assert_eq!(
            event_line(&e).unwrap(),
            "12:00:01  ust      not registered: it shares no usable view; trying again in 30 s"
        );
        // A message that does not start with the id is kept whole.
        let e = event(
            EventKind::Connected,
            Some("gate"),
            "connected: UTM-30LX-EW H1",
        );
        assert_eq!(
            event_line(&e).unwrap(),
            "12:00:01  gate     connected: UTM-30LX-EW H1"
        );
        // An id that is only a prefix of the first word is not cut.
        let e = event(EventKind::Moved, Some("us"), "ust moved");
        assert!(event_line(&e).unwrap().ends_with("us       ust moved"));
        // A sensor's registration is the pose table's to show; the start of one is a line.
        let e = event(EventKind::Registered, Some("gate"), "gate at x 0 m");
        assert_eq!(event_line(&e), None);
        let e = event(EventKind::Registering, None, "registering a, b…");
        assert_eq!(event_line(&e).unwrap(), "12:00:01  registering a, b…");
    }

    #[test]
    fn the_pose_table_names_an_unplaced_sensor_once() {
        let p = SensorPose::unregistered("ust", "it shares no usable view");
        assert_eq!(
            unplaced_line(&p),
            "ust        not registered: it shares no usable view"
        );
    }

    #[test]
    fn a_rate_line_has_every_sensor_and_no_stale_rate() {
        let mut a = SensorStatus::new("a", SensorState::Streaming);
        a.rate_hz = Some(39.96);
        let mut b = SensorStatus::new("b", SensorState::Streaming);
        b.last_scan_age_s = Some(3.25);
        let c = SensorStatus::new("c", SensorState::Disconnected);
        let line = rate_line(&Status {
            site: "s".into(),
            uptime_s: 12.0,
            queue_drops: 0,
            sensors: vec![a, b, c],
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        });
        assert_eq!(
            line,
            "      12 s  a 40.0 Hz · b no scans for 3.2 s · c disconnected  · queue drops 0"
        );
    }

    /// A writer the test reads back.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn status(uptime_s: f64) -> Status {
        let sensors = ["gate", "ust"]
            .iter()
            .map(|id| {
                let mut s = SensorStatus::new(*id, SensorState::Streaming);
                s.rate_hz = Some(40.0);
                s
            })
            .collect();
        Status {
            site: "s".into(),
            uptime_s,
            queue_drops: 0,
            sensors,
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        }
    }

    fn poses(answered: bool) -> Poses {
        let mut gate = SensorPose::unregistered("gate", "waiting for a static view");
        let mut ust = gate.clone();
        ust.id = "ust".into();
        if answered {
            gate.registered = true;
            gate.reason = None;
            (gate.x_m, gate.y_m, gate.yaw_deg) = (Some(0.0), Some(0.0), Some(0.0));
            gate.source = Some(PoseSource::Registered);
            ust.reason = Some("it shares no usable view".into());
        }
        Poses {
            anchor: "gate".into(),
            sensors: vec![gate, ust],
            building_from_site: None,
            site_from_zone: None,
        }
    }

    /// The reports of a start where one sensor stays unplaced, through a terminal.
    fn console(console: Console) -> String {
        let out = Shared::default();
        let terminal = Terminal::with(BTreeMap::new(), console, Box::new(out.clone()));
        let (tx, rx) = mpsc::channel();
        let tick = |t: f64, answered: bool| Report::Tick {
            status: status(t),
            poses: poses(answered),
        };
        tx.send(Report::Event(event(
            EventKind::Connected,
            Some("gate"),
            "connected: UTM-30LX-EW H1",
        )))
        .unwrap();
        tx.send(tick(1.0, false)).unwrap();
        tx.send(Report::Event(event(
            EventKind::Registering,
            None,
            "registering gate, ust from their static views…",
        )))
        .unwrap();
        tx.send(Report::Event(event(
            EventKind::Registered,
            Some("gate"),
            "gate at x 0.000 m",
        )))
        .unwrap();
        tx.send(Report::Event(event(
            EventKind::Error,
            Some("ust"),
            "ust not registered: it shares no usable view; trying again in 30 s",
        )))
        .unwrap();
        for t in 2..8 {
            tx.send(tick(f64::from(t), true)).unwrap();
        }
        drop(tx);
        terminal.follow(rx);
        String::from_utf8(out.0.lock().unwrap().clone()).unwrap()
    }

    #[test]
    fn at_a_terminal_the_state_lines_stay_true_while_a_sensor_is_unplaced() {
        let text = console(Console::Human);
        let lines: Vec<&str> = text.lines().collect();
        let at = |needle: &str| {
            let found: Vec<usize> = (0..lines.len())
                .filter(|&i| lines[i].contains(needle))
                .collect();
            assert_eq!(found.len(), 1, "{needle:?} once in:\n{text}");
            found[0]
        };
        at("gate     connected: UTM-30LX-EW H1");
        let waiting = at("registration waits");
        let failed = at("ust      not registered: it shares no usable view; trying again");
        let table = at("poses in the frame of");
        at("ust        not registered: it shares no usable view");
        assert!(waiting < failed && failed < table, "{text}");
        assert_eq!(text.matches("ust ust").count(), 0, "{text}");
        // Rates go on after the table, the unplaced sensor's too.
        let rates: Vec<usize> = (0..lines.len())
            .filter(|&i| lines[i].contains("queue drops"))
            .collect();
        assert!(rates.len() >= 2, "{text}");
        assert!(rates.iter().all(|&i| i > table), "{text}");
        assert!(lines[rates[0]].contains("ust 40.0 Hz"), "{text}");
    }

    #[test]
    fn off_a_terminal_only_the_pose_table_is_printed() {
        let text = console(Console::Journal);
        assert!(text.contains("poses in the frame of \"gate\""), "{text}");
        assert!(text.contains("ust        not registered:"), "{text}");
        for absent in [
            "connected",
            "registering",
            "trying again",
            "waits",
            "queue drops",
        ] {
            assert!(!text.contains(absent), "{absent:?} in:\n{text}");
        }
    }

    #[test]
    fn a_re_registered_sensor_is_compared_with_where_the_recording_moved_it() {
        let t = |x_m: f64, yaw_deg: f64| TruthPose {
            x_m,
            y_m: 0.0,
            yaw_deg,
        };
        let truth = BTreeMap::from([("gate".to_string(), t(0.0, 0.0)), ("b".into(), t(2.0, 0.0))]);
        let moved = BTreeMap::from([("b".to_string(), t(2.5, 10.0))]);
        let out = Shared::default();
        let mut terminal =
            Terminal::with(truth, Console::Journal, Box::new(out.clone())).with_moves(moved);
        let pose = |id: &str, x_m: f64, yaw_deg: f64, source: PoseSource| {
            let mut p = SensorPose::unregistered(id, "");
            p.registered = true;
            p.reason = None;
            (p.x_m, p.y_m, p.yaw_deg, p.source) =
                (Some(x_m), Some(0.0), Some(yaw_deg), Some(source));
            p
        };
        terminal.print_poses(&Poses {
            anchor: "gate".into(),
            sensors: vec![
                pose("gate", 0.0, 0.0, PoseSource::Registered),
                pose("b", 2.5, 10.0, PoseSource::ReRegistered),
            ],
            building_from_site: None,
            site_from_zone: None,
        });
        let text = String::from_utf8(out.0.lock().unwrap().clone()).unwrap();
        let b = text
            .lines()
            .find(|l| l.starts_with("b "))
            .unwrap_or_default();
        assert!(
            b.ends_with("0.0   0.00"),
            "error against the moved truth: {b}"
        );
    }

    #[test]
    fn a_reader_that_went_away_silences_the_terminal_without_a_panic() {
        struct Closed;
        impl Write for Closed {
            fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
                Err(std::io::ErrorKind::BrokenPipe.into())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let mut t = Terminal::with(BTreeMap::new(), Console::Human, Box::new(Closed));
        t.print("a line");
        assert!(t.closed);
    }
}
