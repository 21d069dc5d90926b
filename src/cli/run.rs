//! `scanfuse run --config FILE [--for 30s]`: the daemon in the foreground. The terminal shows a
//! person what happens: sensors connecting, registration, the poses (next to the recording's
//! truth for `replay:` sensors that have one), then live rates; map files go to the state dir.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::Duration;

use anyhow::Context as _;
use scanfuse::daemon::config::{Config, Connect};
use scanfuse::daemon::pipeline::Report;
use scanfuse::daemon::protocol::{EventKind, Poses, SensorState, Status};
use scanfuse::daemon::run::{RunOptions, RunSummary, run_daemon};
use scanfuse::geometry::{pose_error, pose2};
use scanfuse::record;
use scanfuse::scan::TruthPose;

use super::BadInput;

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
    let truth = replay_truth(&config);
    let (tap, reports) = mpsc::channel();
    let options = RunOptions {
        duration: args.duration,
        tap: Some(tap),
        replay_speed: args.replay_speed,
        ..RunOptions::default()
    };
    println!(
        "site {:?}: {} sensors, anchor {}; map files go to {}; status socket {}",
        config.site.name,
        config.sensors.len(),
        config.site.anchor,
        config.site.state_dir.display(),
        config.site.socket.display()
    );
    println!(
        "{}",
        match args.duration {
            Some(d) => format!(
                "running for {} (Ctrl-C stops sooner)",
                humantime::format_duration(d)
            ),
            None => "running until Ctrl-C".to_string(),
        }
    );
    let printer = std::thread::spawn(move || Terminal::new(truth).follow(reports));
    let summary = daemon_runtime()?.block_on(run_daemon(config.clone(), options));
    let _ = printer.join();
    finish(summary?, &config.site.state_dir)
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
        Ok(saved) => {
            println!("\nwrote {} in {}", saved.files.join(", "), dir.display());
            Ok(())
        }
        Err(e) => anyhow::bail!("the final save failed: {e}"),
    }
}

/// The recordings' truth of every `replay:` sensor, by configured id.
fn replay_truth(config: &Config) -> BTreeMap<String, TruthPose> {
    let mut recordings = BTreeMap::new();
    let mut truth = BTreeMap::new();
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
    }
    truth
}

/// Prints reports for a person: events as they come, the poses once registered, then rates.
pub(super) struct Terminal {
    truth: BTreeMap<String, TruthPose>,
    shown_poses: bool,
    last_waiting: String,
    ticks: u64,
}

impl Terminal {
    pub(super) fn new(truth: BTreeMap<String, TruthPose>) -> Terminal {
        Terminal {
            truth,
            shown_poses: false,
            last_waiting: String::new(),
            ticks: 0,
        }
    }

    pub(super) fn follow(mut self, reports: mpsc::Receiver<Report>) {
        let mut last = None;
        for report in reports {
            match report {
                Report::Event(e) => {
                    let who = e.sensor.as_deref().unwrap_or("");
                    let time = e.time.get(11..19).unwrap_or(&e.time);
                    match e.kind {
                        EventKind::Registering
                        | EventKind::Registered
                        | EventKind::ReRegistered
                            if who.is_empty() =>
                        {
                            println!("{time}  {}", e.message)
                        }
                        EventKind::Registered | EventKind::ReRegistered => {}
                        _ => println!("{time}  {who:<8} {}", e.message),
                    }
                    if e.kind == EventKind::ReRegistered {
                        self.shown_poses = false;
                    }
                }
                Report::Tick { status, poses } => {
                    self.tick(&status, &poses);
                    last = Some((status, poses));
                }
            }
        }
        if let Some((status, poses)) = last
            && !self.shown_poses
        {
            self.print_poses(&poses);
            self.print_rates(&status);
        }
    }

    fn tick(&mut self, status: &Status, poses: &Poses) {
        self.ticks += 1;
        let registered = poses.sensors.iter().filter(|p| p.registered).count();
        let total = poses.sensors.len();
        if registered == total && total > 0 {
            if !self.shown_poses {
                self.print_poses(poses);
                self.shown_poses = true;
            } else if self.ticks.is_multiple_of(2) {
                self.print_rates(status);
            }
            return;
        }
        let streaming = status
            .sensors
            .iter()
            .filter(|s| s.state == SensorState::Streaming)
            .count();
        let waiting = format!(
            "{streaming}/{total} sensors streaming, {registered}/{total} registered; registration waits for ~1 s of scans from each"
        );
        if waiting != self.last_waiting {
            println!("          {waiting}");
            self.last_waiting = waiting;
        }
    }

    fn print_poses(&self, poses: &Poses) {
        // Truth is in the simulator's world frame; the site frame is the anchor's.
        let world_from_anchor = self
            .truth
            .get(&poses.anchor)
            .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()));
        println!(
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
                println!(
                    "{:<10} not registered: {}",
                    p.id,
                    p.reason.as_deref().unwrap_or("")
                );
                continue;
            };
            let sigma_cm = p.sigma_x_m.unwrap_or(0.0).max(p.sigma_y_m.unwrap_or(0.0)) * 100.0;
            let mut line = format!(
                "{:<10} {x:>9.3} {y:>9.3} {yaw:>8.2} {sigma_cm:>7.1} {:>8}",
                p.id,
                p.source.map_or("", |s| s.as_str())
            );
            if let (Some(w_a), Some(t)) = (world_from_anchor, self.truth.get(&p.id)) {
                let truth = w_a.inverse() * pose2(t.x_m, t.y_m, t.yaw_deg.to_radians());
                let (err_m, err_rad) = pose_error(&pose2(x, y, yaw.to_radians()), &truth);
                line.push_str(&format!(
                    "   {:>9.3} {:>9.3} {:>8.2}  {:>7.1} {:>6.2}",
                    truth.translation.x,
                    truth.translation.y,
                    scanfuse::geometry::yaw_rad(&truth).to_degrees(),
                    err_m * 100.0,
                    err_rad.to_degrees().abs()
                ));
            }
            println!("{line}");
        }
        for (id, caveat) in poses
            .sensors
            .iter()
            .filter(|p| p.registered)
            .filter_map(|p| Some((&p.id, p.reason.as_deref()?)))
        {
            println!("{id}: {caveat}");
        }
        println!();
    }

    fn print_rates(&self, status: &Status) {
        let rates: Vec<String> = status
            .sensors
            .iter()
            .map(|s| match (s.state, s.rate_hz) {
                (SensorState::Streaming, Some(hz)) => format!("{} {hz:.1} Hz", s.id),
                (state, _) => format!("{} {}", s.id, state.as_str()),
            })
            .collect();
        println!(
            "{:>8.0} s  {}  · queue drops {}",
            status.uptime_s,
            rates.join(" · "),
            status.queue_drops
        );
    }
}
