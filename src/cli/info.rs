//! `scanfuse info FILE.mcap`: a newcomer's first look at a recording.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, UNIX_EPOCH};

use anyhow::Context as _;
use scanfuse::record::{self, Recording, stats};
use scanfuse::scan::SensorInfo;

#[derive(clap::Args)]
pub struct Args {
    /// Recordings to describe.
    #[arg(required = true)]
    files: Vec<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut damaged = None;
    for (i, path) in args.files.iter().enumerate() {
        if i > 0 {
            println!();
        }
        let mut recording = record::read_lenient(path)?;
        let bytes = std::fs::metadata(path)
            .with_context(|| format!("{}", path.display()))?
            .len();
        print!("{}", describe(&recording, bytes));
        if let Some(damage) = recording.damage.take() {
            damaged.get_or_insert(damage);
        }
    }
    match damaged {
        Some(damage) => Err(anyhow::Error::new(damage)
            .context("the recording is damaged; everything above was read before the damage")),
        None => Ok(()),
    }
}

/// The whole report for one recording.
pub fn describe(rec: &Recording, file_bytes: u64) -> String {
    let all: Vec<stats::SensorStats> = rec
        .sensors
        .iter()
        .map(|s| stats::sensor_stats(s, rec.scans_of(&s.id)))
        .collect();
    let start = all.iter().filter_map(|s| s.first_ns).min();
    let end = all.iter().filter_map(|s| s.last_ns).max();
    let scans: usize = all.iter().map(|s| s.scans).sum();
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} sensor{}, {} scans, {}, {}",
        rec.path.display(),
        rec.sensors.len(),
        if rec.sensors.len() == 1 { "" } else { "s" },
        scans,
        match (start, end) {
            (Some(a), Some(b)) => format!("{:.3} s from {}", (b - a) as f64 * 1e-9, utc(a)),
            _ => "no scans".into(),
        },
        size(file_bytes),
    );
    out.push('\n');
    let _ = writeln!(
        out,
        "{:<12} {:<13} {:>5} {:>7} {:>13} {:>6} {:>16} {:>5} {:>7} {:>6} {:>7} {:>6}  truth x, y, yaw",
        "sensor",
        "model",
        "steps",
        "fov",
        "range",
        "scans",
        "rate (PP)",
        "gaps",
        "returns",
        "intens",
        "height",
        "pitch"
    );
    for (s, st) in rec.sensors.iter().zip(&all) {
        let _ = writeln!(out, "{}", sensor_row(s, st, rec));
    }
    out.push('\n');
    for s in &rec.sensors {
        let fields: Vec<String> = s.fields.iter().map(|(k, v)| format!("{k}={v}")).collect();
        let _ = writeln!(
            out,
            "{}: connect {}; {}",
            s.id,
            if s.connect.is_empty() {
                "unknown"
            } else {
                &s.connect
            },
            if fields.is_empty() {
                "no PP/VV fields (recorded by another writer?)".to_string()
            } else {
                fields.join(" ")
            }
        );
    }
    for (s, st) in rec.sensors.iter().zip(&all) {
        for gap in &st.gaps {
            let _ = writeln!(
                out,
                "gap: {} has no scan for {:.3} s after +{:.3} s",
                s.id,
                gap.length_s,
                since(start, gap.after_ns)
            );
        }
        if st.backwards > 0 {
            let _ = writeln!(
                out,
                "warning: {} has {} scans stamped before the scan they follow",
                s.id, st.backwards
            );
        }
    }
    for m in &rec.moves {
        let _ = writeln!(
            out,
            "move: {} at +{:.3} s → x {:.3} m, y {:.3} m, yaw {:.2}°",
            m.sensor_id,
            since(start, m.at_ns),
            m.pose.x_m,
            m.pose.y_m,
            m.pose.yaw_deg
        );
    }
    for (id, n) in &rec.scip_messages {
        let _ = writeln!(out, "raw SCIP: {id}: {n} messages on /{id}/scip");
    }
    for c in &rec.truth {
        let _ = writeln!(
            out,
            "truth: {} ({}, {}): {} messages, ground truth for eval and tests (never read as scans)",
            c.topic,
            if c.schema.is_empty() {
                "no schema"
            } else {
                &c.schema
            },
            c.encoding,
            c.messages
        );
    }
    for c in &rec.skipped {
        let _ = writeln!(
            out,
            "skipped: {} ({}, {}): {} messages scanfuse does not read",
            c.topic,
            if c.schema.is_empty() {
                "no schema"
            } else {
                &c.schema
            },
            c.encoding,
            c.messages
        );
    }
    out
}

fn sensor_row(s: &SensorInfo, st: &stats::SensorStats, rec: &Recording) -> String {
    let scans = rec.scans_of(&s.id);
    let fov = scans
        .first()
        .map(|sc| {
            format!(
                "{:.1}°",
                (sc.end_angle_rad - sc.start_angle_rad).to_degrees()
            )
        })
        .unwrap_or_else(|| "-".into());
    let steps = match st.ranges_per_scan {
        Some((a, b)) if a == b => a.to_string(),
        Some((a, b)) => format!("{a}-{b}"),
        None => "-".into(),
    };
    let range = s
        .geometry
        .map(|g| {
            format!(
                "{}-{} m",
                g.dmin_mm as f64 / 1000.0,
                g.dmax_mm as f64 / 1000.0
            )
        })
        .unwrap_or_else(|| "-".into());
    let rate = match (st.rate_hz, st.nominal_hz) {
        (Some(r), Some(n)) => format!("{r:.1} Hz ({n:.0})"),
        (Some(r), None) => format!("{r:.1} Hz"),
        (None, Some(n)) => format!("- ({n:.0})"),
        (None, None) => "-".into(),
    };
    let intens = match st.with_intensities {
        0 => "no".to_string(),
        n if n == st.scans => "yes".to_string(),
        n => format!("{n}/{}", st.scans),
    };
    let opt = |v: Option<f64>, unit: &str| {
        v.map(|v| format!("{v:.2}{unit}"))
            .unwrap_or_else(|| "-".into())
    };
    let truth = s
        .truth
        .map(|t| format!("{:.3}, {:.3}, {:.2}°", t.x_m, t.y_m, t.yaw_deg))
        .unwrap_or_else(|| "-".into());
    let model = if s.model.is_empty() {
        "unknown"
    } else {
        &s.model
    };
    format!(
        "{:<12} {:<13} {:>5} {:>7} {:>13} {:>6} {:>16} {:>5} {:>6.1}% {:>6} {:>7} {:>6}  {}",
        s.id,
        model,
        steps,
        fov,
        range,
        st.scans,
        rate,
        st.gaps.len(),
        st.return_fraction * 100.0,
        intens,
        opt(s.height_m, " m"),
        opt(s.pitch_deg, "°"),
        truth
    )
}

fn size(bytes: u64) -> String {
    match bytes {
        b if b < 10_000 => format!("{b} bytes"),
        b if b < 10_000_000 => format!("{:.1} kB", b as f64 / 1e3),
        b => format!("{:.1} MB", b as f64 / 1e6),
    }
}

fn utc(ns: u64) -> String {
    let t = UNIX_EPOCH + Duration::from_nanos(ns);
    humantime::format_rfc3339_millis(t).to_string()
}

fn since(start: Option<u64>, ns: u64) -> f64 {
    start.map_or(0.0, |s| (ns as f64 - s as f64) * 1e-9)
}
