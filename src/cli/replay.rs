//! `scanfuse replay FILE.mcap… [--speed N | --max] [--out DIR] [--socket PATH]`: what the
//! daemon would have done with these recordings. The sensors come from the recordings'
//! metadata; each is served by an in-process emulator, so the real driver path runs. Progress
//! on the terminal, poses and map files to DIR; ends when the recordings do.

use std::path::PathBuf;
use std::sync::mpsc;

use scanfuse::daemon::config::{
    self, Config, Connect, FoxgloveConfig, PublishConfig, RegistrationConfig, ScanMode,
    SensorConfig, SiteConfig, WebConfig,
};
use scanfuse::daemon::run::{RunOptions, run_daemon};
use scanfuse::record;

use super::BadInput;
use super::run::{Terminal, daemon_runtime, finish};

#[derive(clap::Args)]
pub struct Args {
    /// Recordings (MCAP); every sensor in them takes part.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Playback speed (2 = twice as fast as recorded).
    #[arg(long, default_value_t = 1.0, conflicts_with = "max")]
    speed: f64,
    /// Play as fast as the pipeline takes the scans in (the same poses as at ×1).
    #[arg(long)]
    max: bool,
    /// Where poses.toml and the map files go.
    #[arg(long, value_name = "DIR", default_value = "replay-out")]
    out: PathBuf,
    /// Serve the status socket here while the replay runs.
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Serve the live page here while the replay runs (e.g. 127.0.0.1:8080; loopback only:
    /// a page reachable from elsewhere needs `scanfuse run` with [web] token_file).
    #[arg(long, value_name = "ADDR")]
    web: Option<std::net::SocketAddr>,
    /// Serve the site to Foxglove/Lichtblick here while the replay runs (a Foxglove
    /// WebSocket, e.g. 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR")]
    foxglove: Option<std::net::SocketAddr>,
    /// The sensor whose frame is the site frame (default: the first one found).
    #[arg(long)]
    anchor: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let speed = if args.max { f64::INFINITY } else { args.speed };
    if !(speed > 0.0 && (speed.is_finite() || args.max)) {
        return Err(BadInput(format!("--speed {speed} must be a positive number")).into());
    }
    let mut sensors: Vec<SensorConfig> = Vec::new();
    let mut truth = std::collections::BTreeMap::new();
    let mut moved = std::collections::BTreeMap::new();
    for file in &args.files {
        let recording = record::read(file)?;
        if recording.sensors.is_empty() {
            return Err(BadInput(format!(
                "{}: holds no sensors (no scanfuse.sensor metadata or scan channels)",
                file.display()
            ))
            .into());
        }
        for info in &recording.sensors {
            if sensors.iter().any(|s| s.id == info.id) {
                return Err(BadInput(format!(
                    "{}: sensor id {:?} appears in two recordings; ids must be unique",
                    file.display(),
                    info.id
                ))
                .into());
            }
            if let Some(m) = super::run::recorded_moves(&recording).remove(&info.id) {
                moved.insert(info.id.clone(), m);
            }
            if let Some(t) = info.truth {
                truth.insert(info.id.clone(), t);
            }
            sensors.push(SensorConfig {
                id: info.id.clone(),
                connect: Connect::Replay {
                    file: file.clone(),
                    sensor: info.id.clone(),
                },
                mode: ScanMode::MD,
                height_m: info.height_m,
                pitch_rad: info.pitch_deg.unwrap_or(0.0).to_radians(),
                survey: None,
                line: 0,
            });
        }
    }
    let anchor = match &args.anchor {
        Some(a) if sensors.iter().any(|s| &s.id == a) => a.clone(),
        Some(a) => {
            let ids: Vec<&str> = sensors.iter().map(|s| s.id.as_str()).collect();
            return Err(BadInput(format!(
                "--anchor {a:?} is not among the sensors: {}",
                ids.join(", ")
            ))
            .into());
        }
        None => sensors.first().map(|s| s.id.clone()).unwrap_or_default(),
    };
    let config = Config {
        path: args.files.first().cloned().unwrap_or_default(),
        site: SiteConfig {
            name: "replay".into(),
            state_dir: args.out.clone(),
            socket: args.socket.clone().unwrap_or_default(),
            socket_mode: config::DEFAULT_SOCKET_MODE,
            anchor,
            max_clients: config::DEFAULT_MAX_CLIENTS,
        },
        sensors,
        registration: RegistrationConfig::default(),
        // Files are written once, at the end.
        publish: PublishConfig {
            save_interval_s: 0.0,
            ..PublishConfig::default()
        },
        web: WebConfig {
            listen: args.web,
            ..WebConfig::off()
        },
        people: config::PeopleConfig::default(),
        foxglove: FoxgloveConfig {
            listen: args.foxglove,
            ..FoxgloveConfig::default()
        },
    };
    if let Some(addr) = args.web
        && !addr.ip().is_loopback()
    {
        return Err(BadInput(format!(
            "--web {addr} is reachable from other machines, and the page can move sensors; use a loopback address such as 127.0.0.1:8080 here, or `scanfuse run` with [web] token_file"
        ))
        .into());
    }
    let pace = if args.max {
        "as fast as the pipeline takes them".to_string()
    } else {
        format!("at ×{speed}")
    };
    println!(
        "replaying {} sensors {pace}; poses and map files go to {}",
        config.sensors.len(),
        args.out.display()
    );
    let (tap, reports) = mpsc::channel();
    let options = RunOptions {
        serve_socket: args.socket.is_some(),
        replay_speed: speed,
        replay_loop: false,
        replay_recorded_time: true,
        stop_when_replay_ends: true,
        tap: Some(tap),
        ..RunOptions::default()
    };
    let printer =
        std::thread::spawn(move || Terminal::new(truth).with_moves(moved).follow(reports));
    let summary = daemon_runtime()?.block_on(run_daemon(config, options));
    let _ = printer.join();
    finish(summary?, &args.out)
}
