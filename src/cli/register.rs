//! `scanfuse register FILE.mcap... [--anchor ID] [--json]`: every sensor's pose from the scans
//! alone. With `--json`, stdout is one object in the contract of issue 5 (DESIGN.md's pose
//! vocabulary); without, a table for a person and progress on stderr.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use rayon::prelude::*;
use scanfuse::daemon::protocol::SensorPose;
use scanfuse::features::crowd_proof_view;
use scanfuse::record;
use scanfuse::register::clocks::{Clock, MAX_CLOCK_OFFSET_S, align_clocks};
use scanfuse::register::site::{SensorInput, SiteParams, SiteResult, register_site};
use scanfuse::register::walkers::evidence;
use scanfuse::register::{RegisterParams, ScanModel};
use scanfuse::scan::{Scan, SensorInfo};
use serde::Serialize;

use super::BadInput;

/// Scans of this first stretch of each recording make the static view (people removed); the
/// people walking in the first `MotionParams::max_frames` ticks (30 s) check the poses.
const STATIC_WINDOW_S: f64 = 1.0;
/// The static view is what keeps coming back over this long (a crowd hides the walls at any
/// one moment; `features::persistent_view`).
const VIEW_WINDOW_S: f64 = 30.0;

#[derive(clap::Args)]
pub struct Args {
    /// Recordings holding the sensors to register.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// The sensor whose frame is the site frame (default: the first sensor found).
    #[arg(long)]
    pub anchor: Option<String>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Register from the walls alone: do not use people walking in the recordings, neither to
    /// rule out look-alike places nor to confirm poses (for recordings where no one walked, or
    /// made on machines whose clocks were not synchronised: walkers are compared by time).
    #[arg(long)]
    pub walls_only: bool,
    /// Align the site to this building drawing (.dxf, .svg, .png, .pgm) and give the poses in
    /// its frame: the same as `scanfuse align FILE… --drawing FILE`.
    #[arg(long)]
    pub drawing: Option<PathBuf>,
    /// With --drawing: the layers that hold walls, comma-separated.
    #[arg(long, value_delimiter = ',', requires = "drawing")]
    pub layers: Option<Vec<String>>,
    /// With --drawing: metres per drawing unit (SVG, rasters, a DXF without $INSUNITS).
    #[arg(long, requires = "drawing")]
    pub scale: Option<f64>,
}

#[derive(Serialize)]
pub(super) struct PairOut {
    a: String,
    b: String,
    #[serde(rename = "match")]
    match_score: f64,
    ambiguity: f64,
    overlap: f64,
    used: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
    /// What registered the pair: `walls`, `walls+walkers` or `walkers` (people alone);
    /// absent when it was neither registered nor used by the site.
    #[serde(skip_serializing_if = "Option::is_none")]
    evidence: Option<&'static str>,
    /// The walkers behind it, when they chose or placed it.
    #[serde(skip_serializing_if = "Option::is_none")]
    walkers: Option<WalkersOut>,
}

/// How many walker sightings both sensors shared at the pair's pose, over how long, and the
/// torsos' area their centres were placed with where it was measured (absent where it was
/// chosen: too few walkers seen from in front and from the side, or legs).
#[derive(Serialize)]
pub(super) struct WalkersOut {
    sightings: usize,
    seconds: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    torso_area_m2: Option<f64>,
}

/// A pair pair selection did not register, and why.
#[derive(Serialize)]
pub(super) struct SkippedOut {
    a: String,
    b: String,
    /// `no_shared_view` or `not_needed`.
    kind: &'static str,
    reason: String,
}

#[derive(Serialize)]
pub(super) struct Output {
    pub anchor: String,
    pub elapsed_ms: u64,
    pub sensors: Vec<SensorPose>,
    pub pairs: Vec<PairOut>,
    /// Pairs not registered (most pairs of a large site share no view).
    pub skipped: Vec<SkippedOut>,
}

/// Each sensor found, with its registration input when it had scans.
pub(super) type Prepared = Vec<(SensorInfo, Option<SensorInput>)>;

pub fn run(args: Args) -> Result<()> {
    if let Some(drawing) = args.drawing {
        return super::align::run(super::align::Args {
            files: args.files,
            drawing,
            layers: args.layers,
            pairs: None,
            similarity: false,
            scale: args.scale,
            anchor: args.anchor,
            walls_only: args.walls_only,
            save: None,
            json: args.json,
        });
    }
    let started = Instant::now();
    let (anchor_id, prepared, site) = register_files(
        &args.files,
        args.anchor.as_deref(),
        args.walls_only,
        !args.json,
    )?;
    let output = to_output(
        &anchor_id,
        &prepared,
        &site,
        started.elapsed().as_millis() as u64,
    );
    if args.json {
        println!("{}", serde_json::to_string(&output)?);
    } else {
        print_table(&output);
    }
    Ok(())
}

/// The sensors found in `files`, prepared and registered: what `register` prints and what
/// `align` aligns to a drawing.
pub(super) fn register_files(
    files: &[PathBuf],
    anchor: Option<&str>,
    walls_only: bool,
    progress: bool,
) -> Result<(String, Prepared, SiteResult)> {
    let prepared = prepare_files(files, walls_only, progress)?;
    let anchor_id = match anchor {
        Some(id) => id.to_string(),
        None => prepared
            .first()
            .map(|(s, _)| s.id.clone())
            .unwrap_or_default(),
    };
    if !prepared.iter().any(|(s, _)| s.id == anchor_id) {
        let known: Vec<&str> = prepared.iter().map(|(s, _)| s.id.as_str()).collect();
        return Err(BadInput(format!(
            "anchor {anchor_id:?} is not among the sensors found: {}",
            known.join(", ")
        ))
        .into());
    }
    let params = RegisterParams::default();
    let inputs: Vec<SensorInput> = prepared.iter().filter_map(|(_, s)| s.clone()).collect();
    let anchor = inputs.iter().position(|s| s.id == anchor_id);
    let Some(anchor) = anchor else {
        return Err(BadInput(format!(
            "anchor {anchor_id:?} has no scans to register with"
        ))
        .into());
    };
    let site_params = SiteParams::default();
    let n = inputs.len();
    let all = n * n.saturating_sub(1) / 2;
    if progress {
        // Pair selection registers each sensor with its most alike first and widens only
        // where that leaves gaps: how many is known at the end.
        if n > site_params.partners + 1 {
            eprintln!(
                "registering {n} sensors: each with its {} most alike first, more where that leaves gaps (of {all} pairs)…",
                site_params.partners
            );
        } else {
            eprintln!("registering {all} pairs…");
        }
    }
    let site = register_site(&inputs, anchor, &params, &site_params);
    if progress && n > site_params.partners + 1 {
        eprintln!(
            "registered {} of {all} pairs in {} round(s)",
            site.pairs.len(),
            site.rounds
        );
    }
    Ok((anchor_id, prepared, site))
}

/// One sensor's registration input from its scans (stamp order), as `register` makes it: its
/// static view through a crowd over the first [`VIEW_WINDOW_S`], and, unless `walls_only`,
/// the people it saw walk. `None` without a usable scan.
pub(super) fn prepare_sensor(
    info: &SensorInfo,
    scans: &[Scan],
    walls_only: bool,
    params: &RegisterParams,
) -> Option<SensorInput> {
    let view = crowd_proof_view(scans, VIEW_WINDOW_S, STATIC_WINDOW_S)?;
    let mount = info.mount();
    let geometry = info.geometry.as_ref();
    let mut model = ScanModel::from_scan(&view, geometry, &mount, params);
    if !walls_only {
        model = model.with_motion(scans, &view, geometry, &mount, params);
    }
    Some(SensorInput {
        id: info.id.clone(),
        model,
        mount,
        prior: None,
    })
}

/// The sensors found in `files`, each with its registration input (its static view's model)
/// when it had usable scans: what `register_files` registers and what `replay --drawing`
/// aligns to a drawing at the daemon's final poses.
pub(super) fn prepare_files(
    files: &[PathBuf],
    walls_only: bool,
    progress: bool,
) -> Result<Prepared> {
    // (sensor, its scans, the file it came from)
    let mut found: Vec<(SensorInfo, Vec<Scan>, PathBuf)> = Vec::new();
    for path in files {
        let mut recording = record::read(path)?;
        if recording.sensors.is_empty() {
            return Err(BadInput(format!(
                "{}: holds no sensors (no scanfuse.sensor metadata or scan channels)",
                path.display()
            ))
            .into());
        }
        for sensor in recording.sensors.drain(..) {
            if let Some((_, _, other)) = found.iter().find(|(s, _, _)| s.id == sensor.id) {
                return Err(BadInput(format!(
                    "{}: sensor id {:?} is also in {}; ids must be unique across the recordings",
                    path.display(),
                    sensor.id,
                    other.display()
                ))
                .into());
            }
            let scans = recording.scans.remove(&sensor.id).unwrap_or_default();
            found.push((sensor, scans, path.clone()));
        }
    }
    let params = RegisterParams::default();
    if progress {
        eprintln!("preparing {} sensors…", found.len());
    }
    // Which recording each sensor came from: their clocks may differ.
    let mut files: Vec<PathBuf> = Vec::new();
    let mut source_of: std::collections::HashMap<String, usize> = Default::default();
    for (info, _, path) in &found {
        let k = files.iter().position(|f| f == path).unwrap_or_else(|| {
            files.push(path.clone());
            files.len() - 1
        });
        source_of.insert(info.id.clone(), k);
    }
    // Sensors with no usable scan cannot take part; they are reported, not fatal.
    let prepared: Vec<(SensorInfo, Option<SensorInput>)> = found
        .into_par_iter()
        .map(|(info, scans, _)| {
            let input = prepare_sensor(&info, &scans, walls_only, &params);
            (info, input)
        })
        .collect();
    let mut prepared = prepared;
    if !walls_only && files.len() > 1 {
        let mut inputs: Vec<SensorInput> = prepared.iter().filter_map(|(_, s)| s.clone()).collect();
        let sources: Vec<usize> = inputs
            .iter()
            .map(|s| source_of.get(&s.id).copied().unwrap_or(0))
            .collect();
        // Every clock is read against the first recording's: the offsets need only agree.
        let reference = 0;
        let name = |k: usize| {
            files
                .get(k)
                .map_or(String::new(), |f| f.display().to_string())
        };
        for (k, clock) in align_clocks(&mut inputs, &sources, reference, &params) {
            // Said whatever the output format: it changes what the walkers may tell.
            match clock {
                Clock::Aligned {
                    offset_s,
                    reference_unit,
                    unit,
                } => eprintln!(
                    "clock of {} reads {offset_s:+.3} s against {} (walkers both {reference_unit} and {unit} saw); taken out",
                    name(k),
                    name(reference)
                ),
                Clock::Unknown => eprintln!(
                    "clock of {}: no offset within ±{MAX_CLOCK_OFFSET_S:.0} s against {} aligns walkers its units and the others saw; its units register from walls alone (synchronise the machines' clocks, or walk through views they share)",
                    name(k),
                    name(reference)
                ),
            }
        }
        let slots = prepared.iter_mut().filter_map(|(_, s)| s.as_mut());
        for (slot, input) in slots.zip(inputs) {
            *slot = input;
        }
    }
    Ok(prepared)
}

pub(super) fn to_output(
    anchor_id: &str,
    prepared: &[(SensorInfo, Option<SensorInput>)],
    site: &SiteResult,
    elapsed_ms: u64,
) -> Output {
    let sensors = prepared
        .iter()
        .map(|(info, input)| {
            let unregistered = |reason: String| SensorPose::unregistered(info.id.clone(), reason);
            if input.is_none() {
                return unregistered("no scans in the recording".into());
            }
            let index = site.sensors.iter().position(|p| p.id == info.id);
            let placement = index.and_then(|i| site.sensors.get(i));
            match placement.map(|p| &p.pose) {
                Some(Ok(placed)) => SensorPose {
                    id: info.id.clone(),
                    registered: true,
                    x_m: Some(placed.pose.x_m),
                    y_m: Some(placed.pose.y_m),
                    yaw_deg: Some(placed.pose.yaw_rad.to_degrees()),
                    z_m: Some(placed.pose.z_m),
                    pitch_deg: Some(placed.pose.pitch_rad.to_degrees()),
                    sigma_x_m: Some(placed.sigma_x_m),
                    sigma_y_m: Some(placed.sigma_y_m),
                    sigma_yaw_deg: Some(placed.sigma_yaw_rad.to_degrees()),
                    reason: placement.and_then(|p| p.caveat.clone()),
                    age_s: None,
                    source: None,
                    evidence: index.and_then(|i| site.evidence(i)).map(str::to_string),
                    zone: None,
                    stale: false,
                },
                Some(Err(reason)) => unregistered(reason.clone()),
                None => unregistered("not registered".into()),
            }
        })
        .collect();
    let id = |i: usize| {
        site.sensors
            .get(i)
            .map(|s| s.id.clone())
            .unwrap_or_default()
    };
    let pairs = site
        .pairs
        .iter()
        .map(|p| PairOut {
            a: id(p.a),
            b: id(p.b),
            match_score: p.result.match_score,
            ambiguity: p.result.ambiguity,
            overlap: p.result.overlap,
            used: p.used,
            reason: p.result.verdict.as_ref().err().map(|why| why.to_string()),
            // Also for an ambiguous pair whose candidate the join used.
            evidence: (p.result.registered() || p.used)
                .then(|| evidence(p.result.walkers.as_ref())),
            walkers: p.result.walkers.as_ref().map(|f| WalkersOut {
                sightings: f.inliers,
                seconds: f.span_s,
                torso_area_m2: f.torso_area_m2,
            }),
        })
        .collect();
    let skipped = site
        .skipped
        .iter()
        .map(|k| SkippedOut {
            a: id(k.a),
            b: id(k.b),
            kind: k.why.kind(),
            reason: k.why.describe(),
        })
        .collect();
    Output {
        anchor: anchor_id.to_string(),
        elapsed_ms,
        sensors,
        pairs,
        skipped,
    }
}

pub(super) fn print_table(o: &Output) {
    println!("site frame: sensor {:?}   ({} ms)", o.anchor, o.elapsed_ms);
    println!(
        "{:<12} {:>9} {:>9} {:>8} {:>6} {:>7} {:>8} {:>8} {:>8}  note",
        "sensor", "x m", "y m", "yaw °", "z m", "pitch °", "σx cm", "σy cm", "σyaw °"
    );
    for s in &o.sensors {
        match (s.x_m, s.y_m, s.yaw_deg) {
            (Some(x), Some(y), Some(yaw)) => println!(
                "{:<12} {:>9.3} {:>9.3} {:>8.2} {:>6.2} {:>7.1} {:>8.1} {:>8.1} {:>8.2}  {}",
                s.id,
                x,
                y,
                yaw,
                s.z_m.unwrap_or(0.0),
                s.pitch_deg.unwrap_or(0.0),
                s.sigma_x_m.unwrap_or(0.0) * 100.0,
                s.sigma_y_m.unwrap_or(0.0) * 100.0,
                s.sigma_yaw_deg.unwrap_or(0.0),
                s.reason.as_deref().unwrap_or("")
            ),
            _ => println!(
                "{:<12} {:>9}  not registered: {}",
                s.id,
                "—",
                s.reason.as_deref().unwrap_or("")
            ),
        }
    }
    println!(
        "\n{:<12} {:<12} {:>6} {:>9} {:>8} {:>5}  note",
        "a", "b", "match", "ambiguity", "overlap", "used"
    );
    for p in &o.pairs {
        println!(
            "{:<12} {:<12} {:>6.2} {:>9.2} {:>7.0}% {:>5}  {}",
            p.a,
            p.b,
            p.match_score,
            p.ambiguity,
            p.overlap * 100.0,
            if p.used { "yes" } else { "no" },
            match (&p.reason, &p.walkers) {
                // The pair alone abstains, but the site joined through it, checked against
                // the other units: say both, or "used" reads as contradicting the reason.
                (Some(why), _) if p.used =>
                    format!("used by the site, checked against the other units; alone: {why}"),
                (Some(why), _) => why.clone(),
                (None, Some(w)) if p.evidence == Some("walkers") => format!(
                    "placed by people alone: {} sightings both saw over {:.0} s",
                    w.sightings, w.seconds
                ),
                (None, Some(w)) if p.evidence == Some("walls+walkers") => format!(
                    "people chose among the walls' answers: {} sightings both saw over {:.0} s",
                    w.sightings, w.seconds
                ),
                _ => String::new(),
            }
        );
    }
    if !o.skipped.is_empty() {
        println!(
            "\n{} of {} pairs not registered (pair selection):",
            o.skipped.len(),
            o.skipped.len() + o.pairs.len()
        );
        for line in skipped_summary(o) {
            println!("{line}");
        }
    }
}

/// One line per sensor with skipped pairs: how many, for which reasons.
fn skipped_summary(o: &Output) -> Vec<String> {
    o.sensors
        .iter()
        .filter_map(|s| {
            let mine = || o.skipped.iter().filter(|k| k.a == s.id || k.b == s.id);
            let count = |kind: &str| mine().filter(|k| k.kind == kind).count();
            let (apart, unneeded) = (count("no_shared_view"), count("not_needed"));
            let mut said = Vec::new();
            if apart > 0 {
                said.push(format!(
                    "{apart} with sensors it shares (almost) no view with where the site places them"
                ));
            }
            if unneeded > 0 {
                said.push(format!(
                    "{unneeded} placed without them before their views ranked each other"
                ));
            }
            (!said.is_empty()).then(|| {
                format!("{:<12} {} skipped: {}", s.id, mine().count(), said.join("; "))
            })
        })
        .collect()
}
