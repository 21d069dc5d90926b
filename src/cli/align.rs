//! `scanfuse align FILE.mcap… --drawing FILE [--layers a,b] [--pairs "sx,sy=dx,dy;…"]
//! [--scale M_PER_UNIT] [--json] [--save DIR]`: registers the sensors as `register` does, then
//! aligns the site to the building drawing (`drawing::align`) and prints `building_from_site`,
//! each sensor's pose in building coordinates with σ, and the residuals (each point pair's,
//! each drawing line's, the moved walls first). Exits 0 with its answer also when it abstains;
//! then the poses stay in the anchor's frame.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use scanfuse::daemon::protocol::{PoseSource, SensorPose};
use scanfuse::daemon::state::{PosesFile, SavedPose};
use scanfuse::drawing::align::{AlignSensor, Alignment, align, parse_pairs_to_fit};
use scanfuse::drawing::{self, BuildingFromSite, ReadOptions};
use scanfuse::geometry::pose2;
use scanfuse::register::RegisterParams;
use serde::Serialize;

use super::BadInput;
use super::register::{Output, print_table, register_files, to_output};

#[derive(clap::Args)]
pub struct Args {
    /// Recordings holding the sensors to register and align.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// The building drawing: .dxf, .svg, .png or .pgm.
    #[arg(long)]
    pub drawing: PathBuf,
    /// Layers of the drawing that hold walls, comma-separated (default: all).
    #[arg(long, value_delimiter = ',')]
    pub layers: Option<Vec<String>>,
    /// Point pairs, site point = drawing point in metres: "sx,sy=dx,dy;sx,sy=dx,dy" (≥ 2).
    #[arg(long)]
    pub pairs: Option<String>,
    /// Fit a scale too from the point pairs (a similarity), for a drawing of unsure scale.
    #[arg(long)]
    pub similarity: bool,
    /// Metres per drawing unit: required for SVG (per SVG unit) and rasters (per pixel), and
    /// for a DXF without $INSUNITS; overrides $INSUNITS.
    #[arg(long)]
    pub scale: Option<f64>,
    /// The sensor whose frame is the site frame (default: the first sensor found).
    #[arg(long)]
    pub anchor: Option<String>,
    /// Register from the walls alone (as `register --walls-only`).
    #[arg(long)]
    pub walls_only: bool,
    /// Write DIR/poses.toml: the poses in the anchor's frame and `building_from_site` beside
    /// them (what the daemon reads from its state_dir).
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// Print one JSON object (`register --json`'s, poses in building coordinates, plus
    /// "building_from_site" and "residuals").
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
enum ResidualOut {
    /// A point pair under the final alignment.
    Pair {
        site: [f64; 2],
        drawing: [f64; 2],
        residual_m: f64,
    },
    /// A drawing line and how far the map's wall stands from it.
    Line {
        a: [f64; 2],
        b: [f64; 2],
        layer: String,
        offset_m: f64,
        points: usize,
        moved: bool,
    },
}

#[derive(Serialize)]
struct AlignOut {
    #[serde(flatten)]
    register: Output,
    building_from_site: BuildingFromSite,
    /// Time the alignment itself took (drawing model, hypotheses, refinement), ms; the
    /// registration before it is in `elapsed_ms`.
    align_ms: f64,
    /// Drawing segments aligned to (after the layer choice).
    drawing_segments: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    rms_m: Option<f64>,
    residuals: Vec<ResidualOut>,
}

pub fn run(args: Args) -> Result<()> {
    let started = Instant::now();
    let opts = ReadOptions {
        layers: args.layers.clone(),
        scale_m_per_unit: args.scale,
        ..ReadOptions::default()
    };
    let read_started = Instant::now();
    let drawing = drawing::read(&args.drawing, &opts).map_err(|e| BadInput(e.to_string()))?;
    let read_ms = read_started.elapsed().as_secs_f64() * 1e3;
    let pairs = match &args.pairs {
        Some(text) => parse_pairs_to_fit(text).map_err(|e| BadInput(format!("--pairs: {e}")))?,
        None => Vec::new(),
    };
    if !args.json {
        eprintln!(
            "drawing {}: {} segments in {} ({} layers), read in {read_ms:.0} ms",
            args.drawing.display(),
            drawing.segments.len(),
            drawing.units,
            drawing.layers.len()
        );
    }
    let (anchor_id, prepared, site) = register_files(
        &args.files,
        args.anchor.as_deref(),
        args.walls_only,
        !args.json,
    )?;
    let sensors: Vec<AlignSensor<'_>> = prepared
        .iter()
        .filter_map(|(info, input)| {
            let input = input.as_ref()?;
            let placed = site.sensors.iter().find(|p| p.id == info.id)?;
            let placed = placed.pose.as_ref().ok()?;
            Some(AlignSensor {
                id: &info.id,
                model: &input.model,
                site_from_sensor: placed.pose.planar(),
            })
        })
        .collect();
    if !args.json {
        eprintln!("aligning {} placed sensors to the drawing…", sensors.len());
    }
    let align_started = Instant::now();
    let alignment = align(
        &drawing,
        &sensors,
        &pairs,
        args.similarity,
        &RegisterParams::default(),
    );
    let align_ms = align_started.elapsed().as_secs_f64() * 1e3;
    let mut register = to_output(&anchor_id, &prepared, &site, 0);
    if let Some(t) = alignment.building_from_site {
        for s in &mut register.sensors {
            to_building(s, &t, &alignment);
        }
    }
    if let Some(dir) = &args.save {
        save(
            dir,
            &anchor_id,
            &to_output(&anchor_id, &prepared, &site, 0),
            &alignment,
        )?;
    }
    register.elapsed_ms = started.elapsed().as_millis() as u64;
    let out = AlignOut {
        register,
        building_from_site: BuildingFromSite::from_alignment(&alignment),
        align_ms,
        drawing_segments: drawing.segments.len(),
        rms_m: alignment
            .refined
            .as_ref()
            .map(|r| r.rms_m)
            .filter(|v| v.is_finite()),
        residuals: residuals(&alignment, &pairs),
    };
    if args.json {
        println!("{}", serde_json::to_string(&out)?);
    } else {
        print_human(&out);
    }
    Ok(())
}

/// A site-frame pose moved into the building: position and heading, σ turned with it and the
/// alignment's own σ at the sensor (its translation and, over the lever arm, its turn) added.
fn to_building(
    s: &mut SensorPose,
    t: &drawing::align::Similarity,
    alignment: &drawing::align::Alignment,
) {
    let (Some(x), Some(y), Some(yaw)) = (s.x_m, s.y_m, s.yaw_deg) else {
        return;
    };
    let b = t.sensor(&pose2(x, y, yaw.to_radians()));
    s.x_m = Some(b.translation.x);
    s.y_m = Some(b.translation.y);
    s.yaw_deg = Some(scanfuse::geometry::wrap_angle_rad(b.rotation.angle()).to_degrees());
    let (ax, ay) = alignment.sigma_at(&nalgebra::Point2::new(x, y));
    let ayaw = alignment.sigma().map_or(0.0, |s| s.2);
    let (c, sn) = (t.yaw_rad.cos(), t.yaw_rad.sin());
    if let (Some(sx), Some(sy)) = (s.sigma_x_m, s.sigma_y_m) {
        let (sx, sy) = (sx * t.scale, sy * t.scale);
        s.sigma_x_m = Some(((c * sx).powi(2) + (sn * sy).powi(2) + ax.powi(2)).sqrt());
        s.sigma_y_m = Some(((sn * sx).powi(2) + (c * sy).powi(2) + ay.powi(2)).sqrt());
    }
    if let Some(sw) = s.sigma_yaw_deg {
        s.sigma_yaw_deg = Some((sw.powi(2) + ayaw.to_degrees().powi(2)).sqrt());
    }
}

fn residuals(a: &Alignment, pairs: &[scanfuse::drawing::align::PointPair]) -> Vec<ResidualOut> {
    let mut out: Vec<ResidualOut> = pairs
        .iter()
        .zip(&a.pair_residuals_m)
        .map(|((s, d), r)| ResidualOut::Pair {
            site: [s.x, s.y],
            drawing: [d.x, d.y],
            residual_m: *r,
        })
        .collect();
    if let Some(r) = &a.refined {
        out.extend(r.lines.iter().map(|l| ResidualOut::Line {
            a: [l.a.x, l.a.y],
            b: [l.b.x, l.b.y],
            layer: l.layer.clone(),
            offset_m: l.offset_m,
            points: l.points,
            moved: l.moved,
        }));
    }
    out
}

fn save(dir: &std::path::Path, anchor: &str, site: &Output, a: &Alignment) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let now = std::time::SystemTime::now();
    let file = PosesFile {
        anchor: anchor.to_string(),
        sensors: site
            .sensors
            .iter()
            .map(|p| SavedPose::from_pose(p, PoseSource::Registered, now))
            .collect(),
        building_from_site: Some(BuildingFromSite::from_alignment(a)),
    };
    file.save(dir)?;
    Ok(())
}

fn print_human(o: &AlignOut) {
    let b = &o.building_from_site;
    if b.aligned {
        let pm = |v: Option<f64>, k: f64, unit: &str| {
            v.map_or(String::new(), |v| format!(" ± {:.2}{unit}", v * k))
        };
        println!(
            "building_from_site: x {:.3} m{}, y {:.3} m{}, yaw {:.2}°{}, scale {:.4}  ({}{})",
            b.x_m,
            pm(b.sigma_x_m, 100.0, " cm"),
            b.y_m,
            pm(b.sigma_y_m, 100.0, " cm"),
            b.yaw_deg,
            pm(b.sigma_yaw_deg, 1.0, "°"),
            b.scale,
            b.method,
            o.rms_m
                .map(|r| format!(", walls fit the drawing to {:.1} cm RMS", r * 100.0))
                .unwrap_or_default()
        );
        println!(
            "aligned to {} drawing segments in {:.0} ms; poses below are in the building's (drawing's) frame\n",
            o.drawing_segments, o.align_ms
        );
    } else {
        println!(
            "not aligned ({}, {} drawing segments, {:.0} ms): {}",
            b.method,
            o.drawing_segments,
            o.align_ms,
            b.reason.as_deref().unwrap_or("")
        );
        println!("poses below are in the anchor's frame\n");
    }
    print_table(&o.register);
    if o.residuals.is_empty() {
        return;
    }
    println!("\nresiduals");
    for r in &o.residuals {
        match r {
            ResidualOut::Pair {
                site,
                drawing,
                residual_m,
            } => println!(
                "  pair  site ({:.2}, {:.2}) = drawing ({:.2}, {:.2}): {:.1} cm",
                site[0],
                site[1],
                drawing[0],
                drawing[1],
                residual_m * 100.0
            ),
            ResidualOut::Line {
                a,
                b,
                layer,
                offset_m,
                points,
                moved,
            } => {
                if *moved {
                    println!(
                        "  MOVED wall ({:.2}, {:.2})–({:.2}, {:.2}) [{layer}]: the scans put it {:.0} cm off the drawing ({points} points); moved since the drawing was made?",
                        a[0],
                        a[1],
                        b[0],
                        b[1],
                        offset_m.abs() * 100.0
                    );
                }
            }
        }
    }
    let lines = o
        .residuals
        .iter()
        .filter(|r| matches!(r, ResidualOut::Line { .. }))
        .count();
    let moved = o
        .residuals
        .iter()
        .filter(|r| matches!(r, ResidualOut::Line { moved: true, .. }))
        .count();
    println!("  {lines} drawing lines fitted, {moved} off by more than 8 cm");
}
