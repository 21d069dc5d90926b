//! `scanfuse track FILE.mcap… [--poses poses.toml] [--out tracks.ndjson] [--config site.toml]`:
//! the people tracker on recordings, with a site file's `[track]` times when given. The sensors are registered first, as `scanfuse register` does (unless a
//! `poses.toml` as the daemon writes it is given); each sensor's background starts from its
//! persistent view; then every scan goes through the tracker in stamp order and each fused
//! step is one `TRACKS` line (NDJSON, `t_ns` the recording's clock). A summary on stderr.

use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result};
use rayon::prelude::*;
use scanfuse::daemon::config::Config;
use scanfuse::daemon::protocol::Message;
use scanfuse::daemon::state::PosesFile;
use scanfuse::features::{crowd_proof_view, persistent_view};
use scanfuse::geometry::{Mount, Pose2, pose2};
use scanfuse::record;
use scanfuse::register::site::{SensorInput, SiteParams, register_site};
use scanfuse::register::{RegisterParams, ScanModel};
use scanfuse::scan::{Scan, SensorInfo};
use scanfuse::track::{SensorScan, TrackParams, Tracker};

use super::BadInput;

/// As `scanfuse register`: the static view from the first stretch, what keeps coming back over
/// `VIEW_WINDOW_S`; the tracker's background starts from the latter.
const STATIC_WINDOW_S: f64 = 1.0;
const VIEW_WINDOW_S: f64 = 30.0;

#[derive(clap::Args)]
pub struct Args {
    /// Recordings (MCAP); every sensor in them takes part.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Sensor poses (a `poses.toml` as the daemon writes it) instead of registering.
    #[arg(long, value_name = "FILE")]
    poses: Option<PathBuf>,
    /// Where the TRACKS lines go (default: stdout).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// The sensor whose frame is the site frame when registering (default: the first found).
    #[arg(long)]
    anchor: Option<String>,
    /// A site file (as `scanfuse run` reads it) whose `[track]` section sets the tracker, so a
    /// recording is tracked as the daemon would track it (default: the built-in times).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

struct Sensor {
    info: SensorInfo,
    scans: Vec<Scan>,
    mount: Mount,
}

pub fn run(args: Args) -> Result<()> {
    // A bad site file fails before minutes of registering.
    let params = match &args.config {
        Some(path) => {
            let config = Config::load(path).map_err(|e| BadInput(e.to_string()))?;
            if !config.track.enabled {
                eprintln!(
                    "note: {} has [track] enabled = false (the daemon runs no tracker); tracking with its times anyway",
                    path.display()
                );
            }
            config.track.params()
        }
        None => TrackParams::default(),
    };
    eprintln!(
        "tracker: background after {:.0} s still, a track ends {:.1} s unseen{}",
        params.background.absorb_s,
        params.death_s,
        args.config
            .as_ref()
            .map_or(String::new(), |p| format!(" ([track] of {})", p.display()))
    );
    let mut sensors: Vec<Sensor> = Vec::new();
    for path in &args.files {
        let mut recording = record::read(path)?;
        if recording.sensors.is_empty() {
            return Err(BadInput(format!(
                "{}: holds no sensors (no scanfuse.sensor metadata or scan channels)",
                path.display()
            ))
            .into());
        }
        for info in recording.sensors.drain(..) {
            if sensors.iter().any(|s| s.info.id == info.id) {
                return Err(BadInput(format!(
                    "{}: sensor id {:?} appears in two recordings; ids must be unique",
                    path.display(),
                    info.id
                ))
                .into());
            }
            let scans = recording.scans.remove(&info.id).unwrap_or_default();
            let mount = info.mount();
            sensors.push(Sensor { info, scans, mount });
        }
    }
    let poses = match &args.poses {
        Some(path) => poses_from_file(path, &sensors)?,
        None => register(&sensors, args.anchor.as_deref())?,
    };
    let placed = poses.iter().filter(|p| p.is_some()).count();
    eprintln!(
        "tracking with {placed} of {} sensors placed ({})",
        sensors.len(),
        if args.poses.is_some() {
            "poses from the file"
        } else {
            "registered from the scans"
        }
    );
    for (s, p) in sensors.iter().zip(&poses) {
        if p.is_none() {
            eprintln!("  {}: not placed, contributes nothing", s.info.id);
        }
    }

    let mut tracker = Tracker::new(params.clone());
    for s in &sensors {
        if let Some(view) = persistent_view(&s.scans, VIEW_WINDOW_S, 0.15, 0.05) {
            let ranges =
                Tracker::horizontal_ranges(&view, s.info.geometry.as_ref(), &s.mount, &params);
            tracker.seed_background(&s.info.id, ranges);
        }
    }
    // Every scan, in stamp order across sensors.
    let mut order: Vec<(u64, usize, usize)> = sensors
        .iter()
        .enumerate()
        .flat_map(|(i, s)| {
            s.scans
                .iter()
                .enumerate()
                .map(move |(k, scan)| (scan.stamp_ns, i, k))
        })
        .collect();
    order.sort_unstable();

    let mut out: Box<dyn std::io::Write> = match &args.out {
        Some(path) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(path)
                .with_context(|| format!("{}: cannot create", path.display()))?,
        )),
        None => Box::new(std::io::BufWriter::new(std::io::stdout().lock())),
    };
    let (mut lines, mut most, mut ids) = (0usize, 0usize, std::collections::BTreeSet::new());
    for (_, i, k) in order {
        let (Some(s), Some(pose)) = (sensors.get(i), poses.get(i)) else {
            continue;
        };
        let Some(scan) = s.scans.get(k) else {
            continue;
        };
        let step = tracker.push(SensorScan {
            id: &s.info.id,
            scan,
            geometry: s.info.geometry.as_ref(),
            mount: s.mount,
            site_from_sensor: *pose,
        });
        if let Some(tracks) = step {
            most = most.max(tracks.tracks.len());
            ids.extend(tracks.tracks.iter().map(|t| t.id));
            writeln!(out, "{}", Message::Tracks(tracks).to_line()).map_err(super::stdout_error)?;
            lines += 1;
        }
    }
    out.flush().map_err(super::stdout_error)?;
    eprintln!(
        "{lines} TRACKS lines{}; {} people tracked, at most {most} at once",
        args.out
            .as_ref()
            .map(|p| format!(" written to {}", p.display()))
            .unwrap_or_default(),
        ids.len()
    );
    Ok(())
}

/// Each sensor's pose from a `poses.toml` (`None` for a sensor it does not place).
fn poses_from_file(path: &PathBuf, sensors: &[Sensor]) -> Result<Vec<Option<Pose2>>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let file = PosesFile::parse(&text, path).map_err(|e| BadInput(e.to_string()))?;
    let poses: Vec<Option<Pose2>> = sensors
        .iter()
        .map(|s| {
            let saved = file.sensors.iter().find(|p| p.id == s.info.id)?;
            match (saved.registered, saved.x_m, saved.y_m, saved.yaw_deg) {
                (true, Some(x), Some(y), Some(yaw)) => Some(pose2(x, y, yaw.to_radians())),
                _ => None,
            }
        })
        .collect();
    if poses.iter().all(Option::is_none) {
        return Err(BadInput(format!(
            "{}: places none of the recordings' sensors",
            path.display()
        ))
        .into());
    }
    Ok(poses)
}

/// Each sensor's pose from the scans, as `scanfuse register` finds it.
fn register(sensors: &[Sensor], anchor: Option<&str>) -> Result<Vec<Option<Pose2>>> {
    let anchor_id = anchor
        .map(str::to_string)
        .or_else(|| sensors.first().map(|s| s.info.id.clone()))
        .unwrap_or_default();
    let params = RegisterParams::default();
    eprintln!("registering {} sensors…", sensors.len());
    let inputs: Vec<SensorInput> = sensors
        .par_iter()
        .filter_map(|s| {
            let view = crowd_proof_view(&s.scans, VIEW_WINDOW_S, STATIC_WINDOW_S)?;
            let geometry = s.info.geometry.as_ref();
            let model = ScanModel::from_scan(&view, geometry, &s.mount, &params)
                .with_motion(&s.scans, &view, geometry, &s.mount, &params);
            Some(SensorInput {
                id: s.info.id.clone(),
                model,
                mount: s.mount,
                prior: None,
            })
        })
        .collect();
    let Some(anchor) = inputs.iter().position(|s| s.id == anchor_id) else {
        return Err(BadInput(format!(
            "anchor {anchor_id:?} is not among the sensors with scans"
        ))
        .into());
    };
    let site = register_site(&inputs, anchor, &params, &SiteParams::default());
    Ok(sensors
        .iter()
        .map(|s| {
            let placed = site.sensors.iter().find(|p| p.id == s.info.id)?;
            placed.pose.as_ref().ok().map(|p| p.pose.planar())
        })
        .collect())
}
