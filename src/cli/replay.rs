//! `scanfuse replay FILE.mcap… [--speed N | --max] [--out DIR] [--socket PATH]`: what the
//! daemon would have done with these recordings. The sensors come from the recordings'
//! metadata; each is served by an in-process emulator, so the real driver path runs. Progress
//! on the terminal, poses and map files to DIR; ends when the recordings do. With
//! `--drawing FILE [--layers a,b] [--scale M]` the final poses are aligned to the building
//! drawing (as `scanfuse align` does): `poses.toml` carries `building_from_site` and the map
//! files are in building coordinates.

use std::path::PathBuf;
use std::sync::mpsc;

use scanfuse::daemon::config::{
    self, Config, Connect, FoxgloveConfig, PublishConfig, RegistrationConfig, ScanMode,
    SensorConfig, SiteConfig, WebConfig,
};
use scanfuse::daemon::protocol::Poses;
use scanfuse::daemon::run::{AlignAtEnd, RunOptions, run_daemon};
use scanfuse::drawing::align::{AlignSensor, align};
use scanfuse::drawing::{self, BuildingFromSite, Drawing, ReadOptions};
use scanfuse::geometry::pose2;
use scanfuse::record;
use scanfuse::register::RegisterParams;

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
    /// Align the final poses to this building drawing (.dxf, .svg, .png, .pgm): poses.toml
    /// gets `building_from_site` and the map files are written in building coordinates.
    #[arg(long)]
    drawing: Option<PathBuf>,
    /// With --drawing: the layers that hold walls, comma-separated.
    #[arg(long, value_delimiter = ',', requires = "drawing")]
    layers: Option<Vec<String>>,
    /// With --drawing: metres per drawing unit (SVG, rasters, a DXF without $INSUNITS).
    #[arg(long, requires = "drawing")]
    scale: Option<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let speed = if args.max { f64::INFINITY } else { args.speed };
    if !(speed > 0.0 && (speed.is_finite() || args.max)) {
        return Err(BadInput(format!("--speed {speed} must be a positive number")).into());
    }
    // A bad drawing is refused before the replay, not after it.
    let drawing = match &args.drawing {
        Some(path) => {
            let opts = ReadOptions {
                layers: args.layers.clone(),
                scale_m_per_unit: args.scale,
                ..ReadOptions::default()
            };
            let d = drawing::read(path, &opts).map_err(|e| BadInput(e.to_string()))?;
            println!(
                "drawing {}: {} segments in {}",
                path.display(),
                d.segments.len(),
                d.units
            );
            Some(std::sync::Arc::new(d))
        }
        None => None,
    };
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
            role: config::Role::Zone,
            max_clients: config::DEFAULT_MAX_CLIENTS,
            // The page draws it under the map once the site is aligned to it.
            drawing: args.drawing.clone().map(|path| config::DrawingConfig {
                path,
                layers: args.layers.clone(),
                scale_m_per_unit: args.scale,
                pairs: Vec::new(),
            }),
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
        track: config::TrackConfig::default(),
        // A replay is one machine's site, never a zone of one on the network.
        zenoh: None,
        surveys: Vec::new(),
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
        drawing: drawing.clone(),
        align_at_end: drawing.map(|d| {
            let files = args.files.clone();
            AlignAtEnd(std::sync::Arc::new(move |poses: &Poses| {
                align_replayed(&d, &files, poses)
            }))
        }),
        ..RunOptions::default()
    };
    let printer =
        std::thread::spawn(move || Terminal::new(truth).with_moves(moved).follow(reports));
    let summary = daemon_runtime()?.block_on(run_daemon(config, options));
    let _ = printer.join();
    finish(summary?, &args.out)
}

/// Aligns the replay's final poses to the drawing: each sensor's static view (prepared from
/// the recordings as `register` prepares it) at the pose the daemon ended with.
fn align_replayed(drawing: &Drawing, files: &[PathBuf], poses: &Poses) -> Option<BuildingFromSite> {
    println!(
        "aligning the final poses to the drawing {}…",
        drawing.source
    );
    let prepared = match super::register::prepare_files(files, false, false) {
        Ok(p) => p,
        Err(e) => {
            println!("not aligned to the drawing: {e:#}");
            return None;
        }
    };
    let sensors: Vec<AlignSensor<'_>> = prepared
        .iter()
        .filter_map(|(info, input)| {
            let input = input.as_ref()?;
            let p = poses.sensors.iter().find(|p| p.id == info.id)?;
            let (Some(x), Some(y), Some(yaw)) = (p.x_m, p.y_m, p.yaw_deg) else {
                return None;
            };
            p.registered.then_some(AlignSensor {
                id: &info.id,
                model: &input.model,
                site_from_sensor: pose2(x, y, yaw.to_radians()),
            })
        })
        .collect();
    let alignment = align(drawing, &sensors, &[], false, &RegisterParams::default());
    let b = BuildingFromSite::from_alignment(&alignment);
    if b.aligned {
        println!(
            "building_from_site: x {:.3} m, y {:.3} m, yaw {:.2}°, scale {:.4} ({}); map files in building coordinates",
            b.x_m, b.y_m, b.yaw_deg, b.scale, b.method
        );
    } else {
        println!(
            "not aligned to the drawing ({}): {}; map files stay in the anchor's frame",
            b.method,
            b.reason.as_deref().unwrap_or("")
        );
    }
    Some(b)
}
