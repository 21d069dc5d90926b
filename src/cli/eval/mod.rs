//! `scanfuse eval`: measures registration as issue 5 asks and prints the tables: success per
//! overlap bin, errors, confident-wrong and abstentions with reasons, time per pair, plain
//! point-to-point ICP baselines side by side, real-data pairs from the CARMEN logs, sites
//! (simulated: installed and dropped at random; real: CARMEN scans drawn as installed), and ICP
//! iterations with point classes on vs. off.

use anyhow::{Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::geometry::Mount;
use scanfuse::geometry::{Pose2, pose_error, pose2};
use scanfuse::register::model::NearestGrid;
use scanfuse::register::site::{SensorInput, SiteParams, register_site};
use scanfuse::register::{RegisterParams, ScanModel, polish, register_pair};
use scanfuse::sim::Model;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

mod crowd;
mod drawing;
mod real;
mod sim;
mod site;
mod tracking;
mod zones;

use real::{Logs, load_logs, real_cases, real_sites};
use sim::{SiteDraw, load_plans, sim_cases, sites};

#[derive(clap::Args)]
pub struct Args {
    /// Simulated pairs to draw.
    #[arg(long, default_value_t = 300)]
    pub pairs: usize,
    /// Real-data pairs to draw.
    #[arg(long, default_value_t = 300)]
    pub real_pairs: usize,
    /// Folder of the CARMEN `*-corrected.log.gz` logs (skipped with a message when absent).
    #[arg(long, default_value = "../shared/datasets/radish-carmen-corrected")]
    pub real_data: PathBuf,
    /// Seed of every random draw.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Folder of the floor plans random placements are drawn in.
    #[arg(long, default_value = "fixtures/plans")]
    pub plans: PathBuf,
    /// Sensor models simulated pairs and sites are drawn from, comma separated: UTM-30LX-EW,
    /// UXM-30LX-E, URG-04LX (any case; or utm, uxm, urg). Seven UTMs to three of each other.
    #[arg(long, value_delimiter = ',', default_value = "UTM-30LX-EW,UXM-30LX-E")]
    pub models: Vec<Model>,
    /// Sites to solve, per kind (installed, random, real).
    #[arg(long, default_value_t = 3)]
    pub sites: usize,
    /// Zones a concourse is split into along its length (`--only zones`).
    #[arg(long, default_value_t = 10)]
    pub zones: usize,
    /// With `--only zones`: survey the last zone's first unit at its true pose in the site
    /// frame (σ 2 cm, 0.2°), a second anchor at the far end of the chain of zones.
    #[arg(long)]
    pub zone_survey: bool,
    /// Sensors per site (at least 2; at most 500 with --floor).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u16).range(2..))]
    pub site_sensors: u16,
    /// Draw the simulated sites on generated floors instead of the plans of --plans: `concourse`
    /// makes a concourse of --site-sensors scanners per site (seeds --seed, --seed + 1, …);
    /// "installed" sites keep the generator's scanners, "random" ones drop that many anywhere.
    #[arg(long, value_enum)]
    pub floor: Option<Floor>,
    /// Seconds of people walking each simulated sensor keeps beside its still view, for the
    /// check that both sensors saw the same walkers (0: walls only, as a single scan).
    #[arg(long, default_value_t = 10.0)]
    pub motion_seconds: f64,
    /// Simulated seconds of each tracking scene (`--only tracking`).
    #[arg(long, default_value_t = 30.0)]
    pub track_seconds: f64,
    /// Folder of the crowd plans tracking and the crowded sites are scored in (`--only
    /// tracking`, `--only crowd`).
    #[arg(long, default_value = "fixtures/plans-crowd")]
    pub track_plans: PathBuf,
    /// Parts to run: sim, site, real, classes (comma separated; default all), and tracking,
    /// crowd, drawing and zones (only when named).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Desks of clutter added to each building drawing (`--only drawing`): entities no scanner
    /// sees, as in a drawing whose furniture layer was not left out.
    #[arg(long, default_value_t = 0)]
    pub drawing_clutter: usize,
    /// For each pair at ≥ 30 % overlap that was not registered correctly, and each pair placed
    /// wrong at any overlap, print which stage lost the true pose (rotation candidates,
    /// translation hypotheses, coarse ranking or refinement) and what the walkers' fit says.
    #[arg(long)]
    pub diagnose: bool,
    /// Also write one CSV row per pair of the pair tables (`sim`, `real`: truth error,
    /// verdict, ambiguity, score, estimated overlap, violation) to this file, for choosing
    /// thresholds. Refused when `--only` names neither.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Also solve every site registering all pairs, and print where pair selection differs
    /// (sensors placed, poses in mm) and what all pairs cost.
    #[arg(long)]
    pub site_compare: bool,
    /// Pair selection for the sites: register each sensor's K most alike views first
    /// (`SiteParams::partners`, default 8; a K of the site's size or more registers every pair).
    #[arg(long)]
    pub partners: Option<usize>,
    /// Write each simulated site's plan (TOML, as `simulate --plan` reads it) to this folder as
    /// `<kind>-<k>.toml`, so a site that went wrong can be simulated and registered on its own.
    #[arg(long)]
    pub site_plans_out: Option<PathBuf>,
}

/// A generated floor (`sim::generate`) for `--floor`.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Floor {
    Concourse,
}

pub fn run(args: Args) -> Result<()> {
    let wants = |part: &str| args.only.is_empty() || args.only.iter().any(|o| o == part);
    let params = RegisterParams::default();
    if let Some(path) = &args.csv
        && !(wants("sim") || wants("real"))
    {
        return Err(super::BadInput(format!(
            "--csv {}: only the pair tables (--only sim, real) write rows, and --only {} names neither",
            path.display(),
            args.only.join(",")
        ))
        .into());
    }
    let mut csv = match &args.csv {
        Some(path) => {
            let mut f = std::fs::File::create(path)
                .with_context(|| format!("{}: cannot create", path.display()))?;
            writeln!(
                f,
                "set,pair,overlap,registered,reason,err_m,err_deg,ambiguity,score,est_overlap,violation,match,sigma_m,sigma_yaw_deg,ms,walkers_seen,walkers_through,evidence"
            )?;
            Some(f)
        }
        None => None,
    };
    if wants("sim") || wants("site") {
        let plans = load_plans(&args.plans)?;
        if wants("sim") {
            let cases = sim_cases(&plans, &args, &params)?;
            println!(
                "\n== Simulated pairs (plans {}; {}, tilted units, people), success ≤ 10 cm and ≤ 1° ==",
                plan_names(&plans),
                model_names(&args.models)
            );
            pair_tables(&cases, "sim", (0.10, 1.0), &params, &args, &mut csv)?;
            println!(
                "\n== ICP with point classes on vs. off (simulated pairs ≥ 30 % overlap, start 0.3 m / 3° off) =="
            );
            classes_on_off(&cases, &params, args.seed);
        }
        if wants("site") && args.floor.is_some() {
            println!(
                "\n== Simulated concourses of {} scanners installed four per column bay (sim::generate, seeds from {}): every sensor within 10 cm / 1°? ==",
                args.site_sensors, args.seed
            );
            sites(&plans, &args, &params, SiteDraw::Installed)?;
            println!(
                "\n== Simulated concourses for {} scanners, the scanners dropped at random (some share no view with any other): every sensor within 10 cm / 1°? ==",
                args.site_sensors
            );
            sites(&plans, &args, &params, SiteDraw::Random)?;
        } else if wants("site") {
            println!(
                "\n== Simulated sites of {} installed sensors (each shares ≥ 30 % of its view with one placed before it): every sensor within 10 cm / 1°? ==",
                args.site_sensors
            );
            sites(&plans, &args, &params, SiteDraw::Installed)?;
            println!(
                "\n== Simulated sites of {} sensors dropped at random (some share no view with any other): every sensor within 10 cm / 1°? ==",
                args.site_sensors
            );
            sites(&plans, &args, &params, SiteDraw::Random)?;
        }
    }
    if args.only.iter().any(|o| o == "drawing") {
        drawing::run(&load_plans(&args.plans)?, &args, &params)?;
    }
    if args.only.iter().any(|o| o == "zones") {
        zones::run(&args, &params)?;
    }
    if args.only.iter().any(|o| o == "crowd") {
        crowd::run(&args.track_plans, args.seed, &params)?;
    }
    if args.only.iter().any(|o| o == "tracking") {
        tracking::run(&args.track_plans, args.track_seconds, args.seed)?;
    }
    if wants("real") || wants("classes") {
        if args.real_data.is_dir() {
            let mut logs = Logs::new(load_logs(&args)?, &params);
            let cases = real_cases(&args, &mut logs)?;
            if wants("real") {
                println!("\n== Real data: CARMEN 180° scans, success ≤ 15 cm and ≤ 1.5° ==");
                pair_tables(&cases, "real", (0.15, 1.5), &params, &args, &mut csv)?;
                println!(
                    "\n== Real sites: {} CARMEN scans of one log, each sharing ≥ 30 % of its view with one drawn before it: every scan within 15 cm / 1.5°? ==",
                    args.site_sensors
                );
                real_sites(&args, &mut logs)?;
            }
            if wants("classes") {
                println!(
                    "\n== ICP with point classes on vs. off (real pairs ≥ 30 % overlap, start 0.3 m / 3° off) =="
                );
                classes_on_off(&cases, &params, args.seed);
            }
        } else {
            println!(
                "\nreal data: {} is absent, skipping (it ships beside the repository, not in it)",
                args.real_data.display()
            );
        }
    }
    Ok(())
}

/// The pair tables of one set (`sim`, `real`) at a tolerance (m, degrees), its CSV rows and,
/// with `--diagnose`, where each miss was lost.
fn pair_tables(
    cases: &[Case],
    set: &str,
    (tol_m, tol_deg): (f64, f64),
    params: &RegisterParams,
    args: &Args,
    csv: &mut Option<std::fs::File>,
) -> Result<()> {
    if cases.is_empty() {
        println!(
            "no {set} pairs drawn: --pairs (sim) or --real-pairs (real) is 0, or no draw fitted"
        );
        return Ok(());
    }
    let csv = csv.as_mut().map(|f| (set, f));
    evaluate(cases, tol_m, tol_deg.to_radians(), params, args.seed, csv)?;
    if args.diagnose {
        diagnose(cases, tol_m, tol_deg.to_radians(), params);
    }
    Ok(())
}

/// "lab, hall": which plans a table was drawn in.
fn plan_names(plans: &[scanfuse::sim::plan::Plan]) -> String {
    let names: Vec<&str> = plans.iter().map(|p| p.name.as_str()).collect();
    names.join(", ")
}

/// "both models" for eval's default draw (as the heading has always read), otherwise which.
fn model_names(models: &[Model]) -> String {
    let mix = sim::model_mix(models);
    if mix == [Model::Utm30lxEw, Model::Uxm30lxE] {
        return "both models".to_string();
    }
    let names: Vec<&str> = mix.iter().map(|m| m.name()).collect();
    names.join(", ")
}

/// One pair to register, with the truth.
pub struct Case {
    pub label: String,
    pub a: ScanModel,
    pub b: ScanModel,
    pub a_from_b: Pose2,
    /// Share of B's points within 10 cm of A's under the true pose.
    pub overlap: f64,
}

const BINS: [(f64, f64, &str); 5] = [
    (0.0, 0.1, "0–10 %"),
    (0.1, 0.2, "10–20 %"),
    (0.2, 0.3, "20–30 %"),
    (0.3, 0.5, "30–50 %"),
    (0.5, 1.01, "50–100 %"),
];

#[derive(Default, Clone)]
struct Tally {
    n: usize,
    ok: usize,
    abstained: usize,
    wrong: usize,
    err_m: Vec<f64>,
    err_deg: Vec<f64>,
}

impl Tally {
    fn add(&mut self, estimate: Option<&Pose2>, truth: &Pose2, tol_m: f64, tol_rad: f64) {
        self.n += 1;
        match estimate {
            None => self.abstained += 1,
            Some(e) => {
                let (dt, dyaw) = pose_error(e, truth);
                self.err_m.push(dt);
                self.err_deg.push(dyaw.to_degrees());
                if dt <= tol_m && dyaw <= tol_rad {
                    self.ok += 1;
                } else {
                    self.wrong += 1;
                }
            }
        }
    }
    fn merge(&mut self, o: &Tally) {
        self.n += o.n;
        self.ok += o.ok;
        self.abstained += o.abstained;
        self.wrong += o.wrong;
        self.err_m.extend(&o.err_m);
        self.err_deg.extend(&o.err_deg);
    }
    fn pct(&self, k: usize) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            100.0 * k as f64 / self.n as f64
        }
    }
}

fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn bin_of(overlap: f64) -> usize {
    BINS.iter()
        .position(|(lo, hi, _)| overlap >= *lo && overlap < *hi)
        .unwrap_or(BINS.len() - 1)
}

/// Registers every case with scanfuse and the two ICP baselines and prints the tables.
pub fn evaluate(
    cases: &[Case],
    tol_m: f64,
    tol_rad: f64,
    params: &RegisterParams,
    seed: u64,
    mut csv: Option<(&str, &mut std::fs::File)>,
) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1c9);
    let methods = [
        "scanfuse, pair alone",
        "scanfuse register, the two as a site",
        "ICP from identity",
        "ICP from 1 m / 10° off",
    ];
    let mut tallies = vec![vec![Tally::default(); BINS.len()]; methods.len()];
    let mut times_ms = vec![Vec::new(); methods.len()];
    let mut reasons: BTreeMap<String, usize> = BTreeMap::new();
    let mut wrong_examples = Vec::new();
    // Confident-wrong pairs whose answer is where the scans settle from the reference pose.
    let (mut disputed, mut wrong) = (0usize, 0usize);
    let (mut recall_hits, mut recall_n) = (0usize, 0usize);
    for case in cases {
        let bin = bin_of(case.overlap);
        let t0 = Instant::now();
        let r = register_pair(&case.a, &case.b, params);
        times_ms[0].push(t0.elapsed().as_secs_f64() * 1e3);
        let estimate = r.registered().then_some(r.a_from_b);
        if let Some((set, f)) = csv.as_mut() {
            let (dt, dyaw) = pose_error(&r.a_from_b, &case.a_from_b);
            let reason = r
                .verdict
                .as_ref()
                .err()
                .map(|w| w.to_string())
                .unwrap_or_default();
            writeln!(
                f,
                "{set},\"{}\",{:.3},{},\"{}\",{:.3},{:.2},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.2},{:.1},{},{},{}",
                case.label,
                case.overlap,
                r.registered(),
                reason,
                dt,
                dyaw.to_degrees(),
                r.ambiguity,
                r.score.value,
                r.overlap,
                r.score.violation(),
                r.match_score,
                r.covariance[(0, 0)].max(r.covariance[(1, 1)]).sqrt(),
                r.covariance[(2, 2)].sqrt().to_degrees(),
                times_ms[0].last().copied().unwrap_or(0.0),
                r.motion.map_or(String::new(), |m| m.seen.to_string()),
                r.motion
                    .map_or(String::new(), |m| m.seen_through.to_string()),
                scanfuse::register::walkers::evidence(r.walkers.as_ref()),
            )?;
        }
        if case.overlap >= 0.3 {
            recall_n += 1;
            let near = |c: &scanfuse::register::Candidate| {
                let (dt, dyaw) = pose_error(&c.a_from_b, &case.a_from_b);
                dt <= tol_m && dyaw <= tol_rad
            };
            if r.candidates.iter().any(near) {
                recall_hits += 1;
            }
        }
        tallies[0][bin].add(estimate.as_ref(), &case.a_from_b, tol_m, tol_rad);
        if let Err(why) = &r.verdict {
            let key = format!("{why}");
            let key = key.split([':', '(']).next().unwrap_or("");
            let key = key.split(" along").next().unwrap_or("").trim().to_string();
            *reasons.entry(key).or_default() += 1;
        } else if let Some(e) = estimate {
            let (dt, dyaw) = pose_error(&e, &case.a_from_b);
            if dt > tol_m || dyaw > tol_rad {
                wrong += 1;
                if reference_disputed(case, &e, params) {
                    disputed += 1;
                }
            }
            if (dt > tol_m || dyaw > tol_rad) && wrong_examples.len() < 12 {
                // Would the truth have won? The score of the refined true pose tells recall
                // failures (truth scores higher) from scoring failures (it scores lower).
                let s_truth = score_at_truth(case, params);
                wrong_examples.push(format!(
                    "{}: overlap {:.0} %, error {:.2} m {:.1}°, ambiguity {:.2}, est. overlap {:.2}, violation {:.3}, score {:.3} vs {:.3} at truth (violation {:.3})",
                    case.label,
                    case.overlap * 100.0,
                    dt,
                    dyaw.to_degrees(),
                    r.ambiguity,
                    r.overlap,
                    r.score.violation(),
                    r.score.value,
                    s_truth.value,
                    s_truth.violation()
                ));
            }
        }
        let t0 = Instant::now();
        let placed = two_as_site(case, params);
        times_ms[1].push(t0.elapsed().as_secs_f64() * 1e3);
        tallies[1][bin].add(placed.as_ref(), &case.a_from_b, tol_m, tol_rad);
        let t0 = Instant::now();
        let icp = point_to_point_icp(&case.a, &case.b, &Pose2::identity());
        times_ms[2].push(t0.elapsed().as_secs_f64() * 1e3);
        tallies[2][bin].add(Some(&icp), &case.a_from_b, tol_m, tol_rad);
        let direction = rng.random_range(0.0..std::f64::consts::TAU);
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let start =
            case.a_from_b * pose2(direction.cos(), direction.sin(), sign * 10f64.to_radians());
        let t0 = Instant::now();
        let icp = point_to_point_icp(&case.a, &case.b, &start);
        times_ms[3].push(t0.elapsed().as_secs_f64() * 1e3);
        tallies[3][bin].add(Some(&icp), &case.a_from_b, tol_m, tol_rad);
    }
    for (m, name) in methods.iter().enumerate() {
        println!("\n{name} ({} pairs)", cases.len());
        println!(
            "{:<10} {:>5} {:>7} {:>9} {:>7} {:>8} {:>8} {:>8} {:>8}",
            "overlap",
            "pairs",
            "success",
            "abstained",
            "wrong",
            "med cm",
            "med °",
            "p95 cm",
            "p95 °"
        );
        let mut at30 = Tally::default();
        let mut all = Tally::default();
        for (b, (lo, _, label)) in BINS.iter().enumerate() {
            let t = &tallies[m][b];
            print_row(label, t);
            if *lo >= 0.3 {
                at30.merge(t);
            }
            all.merge(t);
        }
        print_row("≥ 30 %", &at30);
        print_row("all", &all);
        println!(
            "time per pair: median {:.1} ms, p95 {:.1} ms",
            quantile(&times_ms[m], 0.5),
            quantile(&times_ms[m], 0.95)
        );
    }
    println!(
        "\nscanfuse hypothesis recall at ≥ 30 % overlap (a refined candidate within tolerance): {recall_hits}/{recall_n}"
    );
    println!("scanfuse abstentions by reason:");
    for (why, n) in &reasons {
        println!("  {n:>4}  {why}");
    }
    if wrong > 0 {
        println!(
            "scanfuse confident-wrong where polishing from the reference pose settles on the answer (within {DISPUTE_M:.2} m / {DISPUTE_DEG:.1}°, so the scans dispute the reference): {disputed}/{wrong}"
        );
    }
    if !wrong_examples.is_empty() {
        println!("scanfuse confident-wrong examples:");
        for w in wrong_examples {
            println!("  {w}");
        }
    }
    Ok(())
}

/// Where `scanfuse register` puts B given only these two scans: a site of two, anchored at A.
/// The site places B only through its join checks, which are not the pair's own verdict.
fn two_as_site(case: &Case, params: &RegisterParams) -> Option<Pose2> {
    let input = |id: &str, model: &ScanModel| SensorInput {
        id: id.to_string(),
        model: model.clone(),
        mount: Mount::default(),
        prior: None,
    };
    let inputs = [input("a", &case.a), input("b", &case.b)];
    let site = register_site(&inputs, 0, params, &SiteParams::default());
    let b = site.sensors.get(1)?;
    b.pose.as_ref().ok().map(|placed| placed.pose.planar())
}

/// How close to the answer the scans must settle from the reference for it to count as disputed.
const DISPUTE_M: f64 = 0.05;
const DISPUTE_DEG: f64 = 0.3;

/// Whether the scans, polished from the reference pose, settle on `answer`: then the reference
/// (a dataset's SLAM pose, good to ~5 cm but not always in heading) is what they disagree with.
/// Never true for a simulated pair that is truly wrong by more than the tolerance.
fn reference_disputed(case: &Case, answer: &Pose2, params: &RegisterParams) -> bool {
    let settled = polish(&case.a, &case.b, &case.a_from_b, params);
    let (dt, dyaw) = pose_error(&settled, answer);
    dt <= DISPUTE_M && dyaw <= DISPUTE_DEG.to_radians()
}

/// The score of the true pose after refinement: higher than the answer's means the search
/// missed it, lower means the scans themselves prefer the answer.
fn score_at_truth(case: &Case, params: &RegisterParams) -> scanfuse::register::score::PoseScore {
    let at_truth = scanfuse::register::icp::refine(
        &case.a,
        &case.b,
        &case.a_from_b,
        params,
        params.class_aware,
    );
    scanfuse::register::score::score(&case.a, &case.b, &at_truth.a_from_b, params)
}

/// Where the true pose was lost, for every pair at ≥ 30 % overlap not registered correctly.
fn diagnose(cases: &[Case], tol_m: f64, tol_rad: f64, params: &RegisterParams) {
    use scanfuse::register::hypotheses::{hypotheses, rotation_candidates};
    use scanfuse::register::score::score_coarse;
    println!(
        "\ndiagnosis of pairs at ≥ 30 % overlap not registered correctly, and of every wrong pose:"
    );
    println!(
        "{:<26} {:>5} {:>6} {:>5} {:>6} {:>7} {:>5} {:>7} {:>7}  verdict",
        "pair", "ovl", "rot°", "segs", "hyp cm", "hyp °", "rank", "of", "truth−best"
    );
    let mut lost = [0usize; 4];
    for case in cases {
        let r = register_pair(&case.a, &case.b, params);
        let (dt, dyaw) = pose_error(&r.a_from_b, &case.a_from_b);
        let right = dt <= tol_m && dyaw <= tol_rad;
        // Every miss at ≥ 30 % overlap, and every wrong pose at any.
        if (r.registered() && right) || (case.overlap < 0.3 && !r.registered()) {
            continue;
        }
        let true_yaw = case.a_from_b.rotation.angle();
        let rot_err = rotation_candidates(&case.a, &case.b, params)
            .iter()
            .map(|t| scanfuse::geometry::wrap_angle_rad(t - true_yaw).abs())
            .fold(f64::INFINITY, f64::min);
        let mut coarse: Vec<(f64, Pose2)> = hypotheses(&case.a, &case.b, params)
            .into_iter()
            .map(|(_, h)| (score_coarse(&case.a, &case.b, &h, params).value, h))
            .collect();
        coarse.sort_by(|x, y| y.0.total_cmp(&x.0));
        let nearest = coarse
            .iter()
            .enumerate()
            .map(|(k, (_, h))| (k, pose_error(h, &case.a_from_b)))
            .min_by(|x, y| (x.1.0 + x.1.1).total_cmp(&(y.1.0 + y.1.1)));
        let (rank, (hyp_m, hyp_rad)) = nearest.unwrap_or((usize::MAX, (f64::NAN, f64::NAN)));
        let s_truth = score_at_truth(case, params);
        let stage = if rot_err > 2f64.to_radians() {
            0
        } else if hyp_m > 0.3 || hyp_rad > 2f64.to_radians() {
            1
        } else if rank >= params.refine_best * 3 {
            2
        } else {
            3
        };
        lost[stage] += 1;
        let verdict = match &r.verdict {
            Ok(()) => format!("WRONG by {:.2} m {:.1}°", dt, dyaw.to_degrees()),
            Err(why) if dt <= tol_m && dyaw <= tol_rad => format!("(best right) {why}"),
            Err(why) => format!("(best {:.2} m {:.1}° off) {why}", dt, dyaw.to_degrees()),
        };
        let dir = |d: &scanfuse::register::score::DirScore| {
            format!("{:.2}/{:.2}/{:.2}", d.hit, d.overlap, d.violation)
        };
        println!(
            "    truth: {} {} = {:.3}   best: {} {} = {:.3}",
            dir(&s_truth.a_in_b),
            dir(&s_truth.b_in_a),
            s_truth.value,
            dir(&r.score.a_in_b),
            dir(&r.score.b_in_a),
            r.score.value
        );
        if let (Some(ma), Some(mb)) = (case.a.motion.as_ref(), case.b.motion.as_ref())
            && let Some(f) =
                scanfuse::register::walkers::fit_walkers(ma, mb, &params.walkers, &params.motion)
        {
            let (fit_m, fit_rad) = pose_error(&f.a_from_b, &case.a_from_b);
            let (s_m, s_rad) = scanfuse::register::pair::pose_sigmas(&f.covariance);
            let e = scanfuse::register::motion::co_motion(ma, mb, &case.a_from_b, &params.motion);
            println!(
                "    walkers: fit {:.2} m {:.1}° off, σ {:.1} cm {:.2}°, inliers {}, span {:.1} s, spread {:.1} m, rms {:.2}, walks {} vs {}, decisive {} (with rivals ruled out: {}), alone {}; at truth seen {} through {}",
                fit_m,
                fit_rad.to_degrees(),
                s_m * 100.0,
                s_rad.to_degrees(),
                f.inliers,
                f.span_s,
                f.spread_m,
                f.rms_m,
                f.walks,
                f.runner_up_walks,
                f.decisive(&params.walkers),
                scanfuse::register::pair::deciding(&case.a, &case.b, f.clone(), params).is_some(),
                f.places_alone_but_for_its_rival(&params.walkers),
                e.seen,
                e.seen_through
            );
        }
        println!(
            "{:<26} {:>4.0}% {:>6.1} {:>2}/{:<2} {:>6.0} {:>7.1} {:>5} {:>7} {:>+7.3}  {verdict}",
            case.label,
            case.overlap * 100.0,
            rot_err.to_degrees(),
            case.a.features.segments.len(),
            case.b.features.segments.len(),
            hyp_m * 100.0,
            hyp_rad.to_degrees(),
            rank,
            coarse.len(),
            s_truth.value - r.score.value,
        );
    }
    println!(
        "lost at: rotation {}, translation {}, coarse rank {}, refinement/verdict {}",
        lost[0], lost[1], lost[2], lost[3]
    );
    walker_calibration(cases, params);
}

/// How far decisive walker fits are from the truth against the σ they give (with their
/// bias, as the walls are joined with them): a fit whose errors run past its σ would let
/// a pose the walkers fix be placed wrong.
fn walker_calibration(cases: &[Case], params: &RegisterParams) {
    let (mut d2, mut along, mut yaw) = (Vec::new(), Vec::new(), Vec::new());
    for case in cases {
        let Some(fit) = scanfuse::register::pair::decisive_walkers(&case.a, &case.b, params) else {
            continue;
        };
        let c = fit.biased_covariance(&params.walkers);
        let e = scanfuse::geometry::pose_delta(&case.a_from_b, &fit.a_from_b);
        // A wrong look-alike is not a calibration question.
        if e.xy().norm() > 1.0 || e.z.abs() > 5f64.to_radians() {
            continue;
        }
        if let Some(info) = c.try_inverse() {
            d2.push((e.transpose() * info * e)[(0, 0)]);
        }
        let (s_m, s_rad) = scanfuse::register::pair::pose_sigmas(&c);
        along.push(e.xy().norm() / s_m.max(1e-9));
        yaw.push(e.z.abs() / s_rad.max(1e-12));
    }
    if d2.is_empty() {
        return;
    }
    let q = |v: &[f64], p: f64| quantile(v, p);
    println!(
        "decisive walker fits near the truth: {}; Mahalanobis² (x, y, yaw) median {:.1} p90 {:.1} p95 {:.1} max {:.1} (calibrated: 2.4, 6.3, 7.8); position err/σ median {:.2} p95 {:.2}; heading err/σ median {:.2} p95 {:.2}",
        d2.len(),
        q(&d2, 0.5),
        q(&d2, 0.9),
        q(&d2, 0.95),
        q(&d2, 1.0),
        q(&along, 0.5),
        q(&along, 0.95),
        q(&yaw, 0.5),
        q(&yaw, 0.95),
    );
}

fn print_row(label: &str, t: &Tally) {
    // A bin where nothing was registered has no error to show.
    let q = |v: &[f64], q: f64, scale: f64, digits: usize| {
        if v.is_empty() {
            "–".to_string()
        } else {
            format!("{:.digits$}", quantile(v, q) * scale)
        }
    };
    println!(
        "{:<10} {:>5} {:>6.1}% {:>8.1}% {:>6.1}% {:>8} {:>8} {:>8} {:>8}",
        label,
        t.n,
        t.pct(t.ok),
        t.pct(t.abstained),
        t.pct(t.wrong),
        q(&t.err_m, 0.5, 100.0, 1),
        q(&t.err_deg, 0.5, 1.0, 2),
        q(&t.err_m, 0.95, 100.0, 1),
        q(&t.err_deg, 0.95, 1.0, 2)
    );
}

/// The baseline: plain point-to-point ICP (closed-form 2D alignment), nearest neighbours
/// within 1 m, 50 iterations, no rejection beyond that; it never abstains.
pub fn point_to_point_icp(a: &ScanModel, b: &ScanModel, start: &Pose2) -> Pose2 {
    let grid = NearestGrid::new(a.points(), 0.1, 1.0);
    let mut pose = *start;
    for _ in 0..50 {
        let pairs: Vec<(nalgebra::Point2<f64>, nalgebra::Point2<f64>)> = b
            .icp_sample
            .iter()
            .filter_map(|&i| {
                let q = pose * b.points()[i];
                let j = grid.nearest(&q)?;
                let p = *a.points().get(j)?;
                ((p - q).norm() <= 1.0).then_some((q, p))
            })
            .collect();
        if pairs.len() < 3 {
            break;
        }
        let n = pairs.len() as f64;
        let cq = pairs
            .iter()
            .fold(nalgebra::Vector2::zeros(), |s, (q, _)| s + q.coords)
            / n;
        let cp = pairs
            .iter()
            .fold(nalgebra::Vector2::zeros(), |s, (_, p)| s + p.coords)
            / n;
        let (mut sxx, mut sxy) = (0.0, 0.0);
        for (q, p) in &pairs {
            let (u, v) = (q.coords - cq, p.coords - cp);
            sxx += u.dot(&v);
            sxy += u.perp(&v);
        }
        let dtheta = sxy.atan2(sxx);
        let rot = nalgebra::Rotation2::new(dtheta);
        let dt = cp - rot * cq;
        pose = pose2(dt.x, dt.y, dtheta) * pose;
        if dt.norm() < 1e-5 && dtheta.abs() < 1e-6 {
            break;
        }
    }
    pose
}

/// Seed 002's measurement: ICP from the truth perturbed by 0.3 m / 3°, classes on vs. off.
fn classes_on_off(cases: &[Case], params: &RegisterParams, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xc1a55);
    let mut rows = Vec::new();
    let chosen: Vec<&Case> = cases.iter().filter(|c| c.overlap >= 0.3).collect();
    if chosen.is_empty() {
        println!("no pairs at ≥ 30 % overlap to compare");
        return;
    }
    let starts: Vec<Pose2> = chosen
        .iter()
        .map(|c| {
            let d = rng.random_range(0.0..std::f64::consts::TAU);
            let s = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            c.a_from_b * pose2(0.3 * d.cos(), 0.3 * d.sin(), s * 3f64.to_radians())
        })
        .collect();
    for on in [false, true] {
        let (mut iters, mut times, mut errs) = (Vec::new(), Vec::new(), Vec::new());
        let mut within = 0usize;
        for (c, start) in chosen.iter().zip(&starts) {
            let t0 = Instant::now();
            let r = scanfuse::register::icp::refine(&c.a, &c.b, start, params, on);
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            iters.push(r.iterations as f64);
            let (dt, dyaw) = pose_error(&r.a_from_b, &c.a_from_b);
            errs.push(dt * 100.0);
            if dt <= 0.15 && dyaw <= 1.5f64.to_radians() {
                within += 1;
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        rows.push((
            on,
            mean(&iters),
            mean(&times),
            quantile(&errs, 0.5),
            chosen.len(),
            within,
        ));
    }
    println!(
        "{:<12} {:>6} {:>11} {:>10} {:>12} {:>16}",
        "classes", "pairs", "mean iters", "mean ms", "median cm", "≤15 cm & ≤1.5°"
    );
    for (on, it, ms, err, n, within) in rows {
        println!(
            "{:<12} {:>6} {:>11.1} {:>10.2} {:>12.1} {:>16}",
            if on { "on" } else { "off" },
            n,
            it,
            ms,
            err,
            within
        );
    }
}
