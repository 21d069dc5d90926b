//! `scanfuse eval --only tracking`: the people tracker on simulated crowds (the plans of
//! `fixtures/plans-crowd/`), scored by CLEAR-MOT with a 0.5 m match radius against the
//! simulator's truth: per crowd size (5, 20, 50 people) and per number of sensors used (1, 2,
//! all) in one hall, then per scene. With the true poses, so that the tables measure tracking;
//! then per scene again with the poses `register` finds after the first 30 s of the same
//! crowd (`crowd::register_in_plan`), unplaced sensors feeding nothing: what a site tracks
//! when nobody measured its scanners.
//! Each row also counts crossings of the scene's counting lines and the occupancy of its zones
//! (`track::score::counting_layout`: across its two widest doors, 2 m in; just inside the
//! widest door and in the middle) from the tracks, against the same counted from the truth.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use rayon::prelude::*;
use scanfuse::geometry::{Pose2, pose_error};
use scanfuse::register::RegisterParams;
use scanfuse::sim::Plan;
use scanfuse::track::TrackParams;
use scanfuse::track::score::{SceneScore, ScoreOptions, counting_layout, score_plan, variant};
use scanfuse::track::zones::{CountLine, Zone};

/// The hall the crowd-size table is drawn in.
const SIZE_PLAN: &str = "hall20.toml";
const SIZES: [u32; 3] = [5, 20, 50];

/// One table row.
struct Row {
    label: String,
    sensors: String,
    score: SceneScore,
    seconds: f64,
}

fn header() {
    println!(
        "{:<22} {:>7} {:>7} {:>9} {:>7} {:>7} {:>6} {:>10} {:>8} {:>7} {:>6} {:>6} {:>7} {:>8} {:>9}",
        "scene",
        "sensors",
        "MOTA",
        "MOTP cm",
        "misses",
        "false",
        "idsw",
        "idsw/5pm",
        "pers·min",
        "hidden",
        "cross",
        "counted",
        "line err%",
        "zone MAE",
        "s"
    );
}

fn print(r: &Row) {
    let m = &r.score.mot;
    let per5 = if r.score.person_minutes > 0.0 {
        m.id_switches as f64 / r.score.person_minutes * 5.0
    } else {
        f64::NAN
    };
    println!(
        "{:<22} {:>7} {:>7.3} {:>9.1} {:>7} {:>7} {:>6} {:>10.2} {:>8.1} {:>7.1} {:>6} {:>7} {:>8.1}% {:>4.2}/{:<4.1} {:>6.1}",
        r.label,
        r.sensors,
        m.mota(),
        m.motp_m() * 100.0,
        m.misses,
        m.false_tracks,
        m.id_switches,
        per5,
        r.score.person_minutes,
        r.score.hidden_person_minutes,
        r.score.line_truth(),
        r.score.line_counted(),
        r.score.line_error_pct(),
        r.score.zone_mae(),
        r.score.zone_mean_truth(),
        r.seconds
    );
}

/// Sensors used: 1, 2 and all of them (fewer when the plan has fewer).
fn sensor_counts(plan: &Plan) -> Vec<(usize, String)> {
    let n = plan.sensors.len();
    let mut out = vec![(1, "1".to_string())];
    if n > 2 {
        out.push((2, "2".to_string()));
    }
    if n > 1 {
        out.push((n, format!("all {n}")));
    }
    out
}

/// One row to run: the plan (a variant), the counting lines and zones of the full plan (the
/// same whatever the sensors used), and the poses to track with (none: the truth).
struct Job {
    label: String,
    sensors: String,
    plan: Plan,
    layout: (Vec<CountLine>, Vec<Zone>),
    poses: BTreeMap<String, Pose2>,
    unplaced: BTreeSet<String>,
}

impl Job {
    fn truth(label: String, sensors: String, plan: Plan, full: &Plan) -> Job {
        Job {
            label,
            sensors,
            plan,
            layout: counting_layout(full),
            poses: BTreeMap::new(),
            unplaced: BTreeSet::new(),
        }
    }
}

fn run_rows(jobs: Vec<Job>, o: &ScoreOptions) -> Result<Vec<Row>> {
    let params = TrackParams::default();
    jobs.into_par_iter()
        .map(|job| {
            let (label, sensors) = (job.label, job.sensors);
            // Names the row in what the scoring logs (id switches at debug level).
            let _row = tracing::info_span!("row", %label, %sensors).entered();
            let t0 = Instant::now();
            let o = ScoreOptions {
                lines: job.layout.0,
                zones: job.layout.1,
                poses: job.poses,
                unplaced: job.unplaced,
                ..o.clone()
            };
            let score = score_plan(&job.plan, &params, &o)?;
            Ok(Row {
                label,
                sensors,
                score,
                seconds: t0.elapsed().as_secs_f64(),
            })
        })
        .collect()
}

/// Each plan registered from its crowd, and tracked with what was placed.
fn registered_rows(plans: &[Plan], o: &ScoreOptions) -> Result<()> {
    let params = RegisterParams::default();
    let registered: Vec<_> = plans
        .par_iter()
        .map(|plan| super::crowd::register_in_plan(plan, o.seed, &params))
        .collect::<Result<_>>()?;
    let mut jobs = Vec::new();
    let mut notes = Vec::new();
    for (plan, (infos, placed, ms)) in plans.iter().zip(registered) {
        let mut job = Job::truth(plan.name.clone(), String::new(), plan.clone(), plan);
        let (mut worst_m, mut worst_deg, mut wrong) = (0.0f64, 0.0f64, 0);
        for (id, pose) in placed {
            match pose {
                Some(p) => {
                    if let Some(t) = super::crowd::truth_of(&infos, &id) {
                        let (dt, dyaw) = pose_error(&p, &t);
                        worst_m = worst_m.max(dt);
                        worst_deg = worst_deg.max(dyaw.to_degrees());
                        wrong += usize::from(!super::crowd::is_right(&p, &t));
                    }
                    job.poses.insert(id, p);
                }
                None => {
                    job.unplaced.insert(id);
                }
            }
        }
        let n = plan.sensors.len();
        job.sensors = format!("{}/{n} reg", n - job.unplaced.len());
        notes.push(format!(
            "{}: {}/{n} placed in {ms} ms, {wrong} wrong, worst {:.1} cm / {:.2}°{}",
            plan.name,
            n - job.unplaced.len(),
            worst_m * 100.0,
            worst_deg,
            if job.unplaced.is_empty() {
                String::new()
            } else {
                format!(
                    " (not placed: {})",
                    job.unplaced.iter().cloned().collect::<Vec<_>>().join(", ")
                )
            }
        ));
        jobs.push(job);
    }
    header();
    for row in run_rows(jobs, o)? {
        print(&row);
    }
    for note in notes {
        println!("  {note}");
    }
    Ok(())
}

pub fn run(plans_dir: &Path, seconds: f64, seed: u64) -> Result<()> {
    let mut plans: Vec<Plan> = Vec::new();
    let mut entries: Vec<_> = std::fs::read_dir(plans_dir)
        .with_context(|| format!("{}: cannot list the crowd plans", plans_dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    entries.sort();
    for path in &entries {
        plans.push(Plan::load(path)?);
    }
    let o = ScoreOptions {
        seed,
        seconds,
        ..ScoreOptions::default()
    };
    let started = Instant::now();
    if let Some(hall) = entries
        .iter()
        .position(|p| p.file_name().is_some_and(|n| n == SIZE_PLAN))
        .and_then(|i| plans.get(i))
    {
        println!(
            "\n== Tracking: {} with a crowd of 5, 20, 50, by sensors used ({seconds:.0} s, seed {seed}, true poses; CLEAR-MOT at 0.5 m; targets all sensors 20 people MOTA ≥ 0.97, MOTP ≤ 5 cm, ≤ 1 id switch / 5 person-minutes; 40–50 people MOTA ≥ 0.95) ==",
            hall.name
        );
        let mut jobs = Vec::new();
        for people in SIZES {
            for (n, label) in sensor_counts(hall) {
                jobs.push(Job::truth(
                    format!("{} ×{people}", hall.name),
                    label,
                    variant(hall, Some(n), Some(people)),
                    hall,
                ));
            }
        }
        header();
        for row in run_rows(jobs, &o)? {
            print(&row);
        }
    }
    println!(
        "\n== Tracking per scene (fixtures/plans-crowd, each plan's own crowd; {seconds:.0} s, seed {seed}, true poses) =="
    );
    let mut jobs = Vec::new();
    for plan in &plans {
        for (n, label) in sensor_counts(plan) {
            if n == 2 {
                continue;
            }
            jobs.push(Job::truth(
                plan.name.clone(),
                label,
                variant(plan, Some(n), None),
                plan,
            ));
        }
    }
    header();
    for row in run_rows(jobs, &o)? {
        print(&row);
    }
    println!(
        "\n== Tracking per scene with registered poses (placed by `register` after the first 30 s of the same crowd, anchored at the first sensor; unplaced sensors feed nothing; {seconds:.0} s, seed {seed}) =="
    );
    registered_rows(&plans, &o)?;
    println!(
        "(tracking tables took {:.0} s; scored: the people some sensor used has in sight (past walls, shelves and pillars; not past other people); 'pers·min': person-minutes scored; 'hidden': person-minutes within the sensors' reach but behind the plan's walls, shelves or pillars from every one of them (not scored); 'idsw/5pm': id switches per 5 person-minutes; 'false': track-frames with no person within 0.5 m; 'cross' / 'counted': crossings of the counting lines after the first second, by the truth / by the tracks; 'line err%': miscounts each way over the true crossings (target within 2 % at 40–50 people); 'zone MAE': mean |tracks − truth| people in a zone per 0.1 s frame / mean true occupancy)",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
