//! `scanfuse eval --only drawing`: the alignment of a site to its building drawing (issue 19),
//! measured. Each site is installed in a plan of `--plans` and registered from simulated scans
//! (its frame is the anchor's, so `building_from_site` is far from the identity); the drawing is
//! made from the plan as an architect's would be: walls (with their door openings) and
//! pillars, the furniture the scanners see left out, one or two walls drawn 20 cm off ("moved since the drawing"), and with
//! `--drawing-clutter N` N desks no scanner sees (a furniture layer nobody deselected). Each
//! sensor's building-frame pose is scored against the simulator's truth (plan frame = building
//! frame) for the automatic alignment and for two clicked points up to 20 cm off, refined. Two
//! sites in a hall that is the same turned 180° close the run: they must abstain. Where the
//! automatic alignment abstains, the eval says whether the walls could have told (the truth's
//! score against the best other alignment's).

use super::sim::{installed_sensors, simulate_models, truth_pose};
use super::{Args, quantile};
use anyhow::Result;
use nalgebra::{Point2, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::drawing::align::{
    AlignSensor, Alignment, LineIndex, MAX_AUTO_AMBIGUITY, MIN_AUTO_SCORE, MapPoint, Similarity,
    align, automatic, drawing_model, map_points, refine, site_score,
};
use scanfuse::drawing::{Drawing, WallSegment};
use scanfuse::geometry::{Pose2, pose_error, within_sigma};
use scanfuse::register::RegisterParams;
use scanfuse::register::site::{SiteParams, register_site};
use scanfuse::sim::plan::Plan;
use std::collections::BTreeMap;
use std::time::Instant;

/// The issue's target: every sensor within this of its truth in the building frame.
const TOL_M: f64 = 0.05;
const TOL_DEG: f64 = 0.3;
/// An alignment whose anchor lands farther than this from its truth put the site somewhere
/// else: confidently wrong (closer is right but not accurate enough).
const WRONG_M: f64 = 0.5;
const WRONG_DEG: f64 = 2.0;
/// How far a "moved" wall is drawn from where it stands, and how far off a click may be.
const MOVED_M: f64 = 0.2;
const CLICK_M: f64 = 0.2;
/// Sites in the symmetric hall, after those of `--plans`.
const SYMMETRIC_SITES: usize = 2;

/// A 30 × 16 m hall that is itself turned 180° about its centre (pillars and wall stubs
/// included); only furniture, which the drawing leaves out, tells the halves apart.
const SYMMETRIC_PLAN: &str = r#"
name = "symmetric"
ceiling_m = 5.0
[[wall]]
points = [[0, 0], [30, 0], [30, 16], [0, 16]]
closed = true
height_m = 5.0
[[wall]]
points = [[15, 0], [15, 4]]
height_m = 5.0
[[wall]]
points = [[15, 16], [15, 12]]
height_m = 5.0
[[box]]
center = [10, 8]
size = [0.6, 0.6]
height_m = 5.0
[[box]]
center = [20, 8]
size = [0.6, 0.6]
height_m = 5.0
[[box]]
center = [6, 3]
size = [2.4, 1.2]
height_m = 1.8
[[box]]
center = [23, 5]
size = [1.5, 3.0]
height_m = 1.8
[[box]]
center = [12, 13]
size = [3.0, 0.8]
height_m = 1.8
[[sensor]]
id = "s0"
model = "UTM-30LX-EW"
x = 5
y = 8
"#;

/// A pose error (m, rad) in m and degrees.
fn deg((m, r): (f64, f64)) -> (f64, f64) {
    (m, r.to_degrees())
}

/// How one way of aligning came out on one site.
#[derive(Clone)]
enum Verdict {
    /// Every placed sensor within the target.
    Ok,
    /// Near the truth but some sensor beyond the target.
    Off,
    /// Aligned somewhere else.
    Wrong,
    Abstained(String),
}

#[derive(Clone)]
struct PathOutcome {
    verdict: Verdict,
    /// The anchor's building-frame error (= the alignment's), m and degrees.
    anchor: (f64, f64),
    /// The largest placed sensor's building-frame error, m and degrees.
    worst: (f64, f64),
    within: usize,
    /// Placed sensors beyond the target whose error the alignment's own σ does not cover
    /// (more than 3σ off where it lands in the building): confidently off.
    uncovered: usize,
    /// The alignment's own σ (x, y, yaw), as reported.
    sigma: String,
    ms: f64,
}

impl PathOutcome {
    fn cell(&self) -> String {
        match &self.verdict {
            Verdict::Abstained(_) => "abstained".to_string(),
            v => format!(
                "{} {:.1}cm {:.2}°",
                match v {
                    Verdict::Ok => "ok",
                    Verdict::Off => "off",
                    _ => "WRONG",
                },
                self.worst.0 * 100.0,
                self.worst.1
            ),
        }
    }
}

/// Scores an alignment: each placed sensor (index, site pose, its σ x, y m and yaw rad in
/// the site) against its truth.
fn score(
    a: &Alignment,
    placed: &[(usize, Pose2, [f64; 3])],
    truths: &[Pose2],
    truth_bfs: &Pose2,
    ms: f64,
) -> PathOutcome {
    let Some(t) = a.building_from_site else {
        return PathOutcome {
            verdict: Verdict::Abstained(a.reason.clone().unwrap_or_default()),
            anchor: (f64::NAN, f64::NAN),
            worst: (f64::NAN, f64::NAN),
            within: 0,
            uncovered: 0,
            sigma: String::new(),
            ms,
        };
    };
    let anchor = deg(pose_error(&t.pose(), truth_bfs));
    let errors: Vec<(f64, f64)> = placed
        .iter()
        .map(|(k, site, _)| deg(pose_error(&t.sensor(site), &truths[*k])))
        .collect();
    let within = errors
        .iter()
        .filter(|e| e.0 <= TOL_M && e.1 <= TOL_DEG)
        .count();
    // σ in the building as `align` reports it: the sensor's own and the alignment's where
    // the sensor lands.
    let uncovered = placed
        .iter()
        .zip(&errors)
        .filter(|((_, site, own), e)| {
            let (ax, ay) = a.sigma_at(&Point2::from(site.translation.vector));
            let sigma_xy = [own[0].hypot(ax), own[1].hypot(ay)];
            let sigma_yaw = own[2].hypot(a.sigma().map_or(0.0, |s| s.2));
            let beyond = e.0 > TOL_M || e.1 > TOL_DEG;
            beyond && !within_sigma((e.0, e.1.to_radians()), sigma_xy, sigma_yaw, 3.0)
        })
        .count();
    let worst = errors
        .iter()
        .fold((0.0, 0.0), |w: (f64, f64), e| (w.0.max(e.0), w.1.max(e.1)));
    let verdict = if anchor.0 > WRONG_M || anchor.1 > WRONG_DEG {
        Verdict::Wrong
    } else if within == placed.len() {
        Verdict::Ok
    } else {
        Verdict::Off
    };
    PathOutcome {
        verdict,
        anchor,
        worst,
        within,
        uncovered,
        sigma: a.sigma().map_or(String::new(), |s| {
            format!(
                "{:.1} cm, {:.1} cm, {:.2}°",
                s.0 * 100.0,
                s.1 * 100.0,
                s.2.to_degrees()
            )
        }),
        ms,
    }
}

/// The drawing of `plan`: its walls with the doors cut out, the `moved` pieces drawn `MOVED_M`
/// along their left normal, and its pillars (boxes up to 1 m across and round columns reaching 2.5 m);
/// other boxes and circles are furniture and left out. `clutter` desks on FURNITURE are added.
fn plan_drawing(
    plan: &Plan,
    moved: &[usize],
    clutter: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Drawing> {
    let seg = |a: Point2<f64>, b: Point2<f64>, layer: &str| WallSegment {
        a,
        b,
        layer: layer.to_string(),
    };
    let mut out = Vec::new();
    for (k, (a, b)) in scanfuse::sim::wall_pieces(plan)?.into_iter().enumerate() {
        let (mut a, mut b) = (Point2::new(a[0], a[1]), Point2::new(b[0], b[1]));
        if moved.contains(&k) {
            let u = (b - a).normalize();
            let shift = Vector2::new(-u.y, u.x) * MOVED_M;
            (a, b) = (a + shift, b + shift);
        }
        out.push(seg(a, b, "A-WALL"));
    }
    let polygon = |out: &mut Vec<WallSegment>, pts: &[Point2<f64>]| {
        for k in 0..pts.len() {
            out.push(seg(pts[k], pts[(k + 1) % pts.len()], "A-COLS"));
        }
    };
    for b in plan
        .boxes
        .iter()
        .filter(|b| b.size[0].max(b.size[1]) <= 1.0)
    {
        let r = nalgebra::Rotation2::new(b.yaw_deg.to_radians());
        let c = Point2::new(b.center[0], b.center[1]);
        let (hx, hy) = (b.size[0] / 2.0, b.size[1] / 2.0);
        let pts: Vec<Point2<f64>> = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
            .iter()
            .map(|&(x, y)| c + r * Vector2::new(x, y))
            .collect();
        polygon(&mut out, &pts);
    }
    for c in plan.circles.iter().filter(|c| c.height_m >= 2.5) {
        let pts: Vec<Point2<f64>> = (0..24)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 24.0;
                Point2::new(c.center[0], c.center[1]) + Vector2::new(a.cos(), a.sin()) * c.radius_m
            })
            .collect();
        polygon(&mut out, &pts);
    }
    if clutter > 0 {
        let (mut lo, mut hi) = (
            Point2::new(f64::MAX, f64::MAX),
            Point2::new(f64::MIN, f64::MIN),
        );
        for s in &out {
            lo = lo.inf(&s.a).inf(&s.b);
            hi = hi.sup(&s.a).sup(&s.b);
        }
        for _ in 0..clutter {
            let c = Point2::new(rng.random_range(lo.x..hi.x), rng.random_range(lo.y..hi.y));
            let r = nalgebra::Rotation2::new(rng.random_range(0.0..std::f64::consts::PI));
            let pts: Vec<Point2<f64>> = [(-0.8, -0.4), (0.8, -0.4), (0.8, 0.4), (-0.8, 0.4)]
                .iter()
                .map(|&(x, y)| c + r * Vector2::new(x, y))
                .collect();
            let first = out.len();
            polygon(&mut out, &pts);
            for s in &mut out[first..] {
                s.layer = "FURNITURE".to_string();
            }
        }
    }
    Ok(Drawing::from_segments(
        &format!("{}.drawing", plan.name),
        out,
        "m",
    )?)
}

/// One or two wall pieces (of [`scanfuse::sim::wall_pieces`]) of at least 3 m to draw moved.
fn pick_moved(plan: &Plan, rng: &mut ChaCha8Rng) -> Result<Vec<usize>> {
    let long: Vec<usize> = scanfuse::sim::wall_pieces(plan)?
        .iter()
        .enumerate()
        .filter(|(_, (a, b))| (b[0] - a[0]).hypot(b[1] - a[1]) >= 3.0)
        .map(|(k, _)| k)
        .collect();
    let mut picked = Vec::new();
    for _ in 0..rng.random_range(1..=2) {
        if long.is_empty() {
            break;
        }
        let w = long[rng.random_range(0..long.len())];
        if !picked.contains(&w) {
            picked.push(w);
        }
    }
    Ok(picked)
}

/// Two clicked point pairs: two drawing corners far apart, each click up to `CLICK_M` off,
/// with the site point that truly lies at the corner.
fn clicked_pairs(
    drawing: &Drawing,
    truth_bfs: &Pose2,
    rng: &mut ChaCha8Rng,
) -> Vec<(Point2<f64>, Point2<f64>)> {
    let corners: Vec<Point2<f64>> = drawing
        .segments
        .iter()
        .filter(|s| s.layer == "A-WALL")
        .flat_map(|s| [s.a, s.b])
        .collect();
    let first = corners[rng.random_range(0..corners.len())];
    let far = corners
        .iter()
        .copied()
        .max_by(|x, y| (x - first).norm().total_cmp(&(y - first).norm()))
        .unwrap_or(first);
    let site_from_building = truth_bfs.inverse();
    [first, far]
        .into_iter()
        .map(|d| {
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            let r = CLICK_M * rng.random_range(0.0f64..1.0).sqrt();
            (
                site_from_building * d,
                d + Vector2::new(a.cos(), a.sin()) * r,
            )
        })
        .collect()
}

/// Where the automatic alignment abstained: could the walls have told the truth from the
/// other alignments? The truth's score (refined on the lines, as every candidate is) against
/// the best candidate clearly away from it (> 0.5 m or 5°), both as `align::automatic`
/// scores them.
struct Tell {
    truth: f64,
    rival: f64,
    /// How far the rival lies from the truth (m, degrees).
    rival_at: (f64, f64),
}

impl Tell {
    /// The truth fits clearly best, and well enough: abstaining threw an answer away.
    fn could(&self) -> bool {
        self.truth >= MIN_AUTO_SCORE && self.rival < MAX_AUTO_AMBIGUITY * self.truth
    }

    /// Another alignment fits clearly better than the truth: only its own runner-up kept the
    /// search from being wrong.
    fn misled(&self) -> bool {
        self.truth < MAX_AUTO_AMBIGUITY * self.rival
    }

    fn verdict(&self) -> &'static str {
        if self.could() {
            "COULD tell (the truth fits clearly best)"
        } else if self.misled() {
            "MISLEAD (another alignment fits clearly better than the truth)"
        } else {
            "cannot tell"
        }
    }
}

/// Measures [`Tell`] for a site the automatic alignment abstained on.
fn tell(
    drawing: &Drawing,
    sensors: &[AlignSensor<'_>],
    truth_bfs: &Pose2,
    params: &RegisterParams,
) -> Tell {
    let dmodel = drawing_model(drawing, params);
    let index = LineIndex::new(drawing);
    let (rival, rival_at) = automatic(&dmodel, &index, sensors, params)
        .candidates
        .iter()
        .map(|c| {
            (
                c.score,
                deg(pose_error(&c.refined.transform.pose(), truth_bfs)),
            )
        })
        .find(|(_, (m, d))| *m > 0.5 || *d > 5.0)
        .unwrap_or((0.0, (0.0, 0.0)));
    // The truth as the search would have found it: refined on the lines like every candidate
    // (the registration's few mm, and the walls drawn 20 cm off, move the best fit a little).
    let map: Vec<MapPoint> = sensors
        .iter()
        .flat_map(|s| map_points(s.model, &s.site_from_sensor))
        .collect();
    let truth = refine(&map, &index, &Similarity::rigid(truth_bfs), 0.5)
        .transform
        .pose();
    Tell {
        truth: site_score(&dmodel, sensors, &truth, params),
        rival,
        rival_at,
    }
}

/// One site's result.
struct SiteOutcome {
    plan: String,
    sensors: usize,
    placed: usize,
    /// Largest registration error of a placed sensor against its truth, in the site frame.
    site_err: (f64, f64),
    auto: PathOutcome,
    /// Where `auto` abstained: whether the walls could have told.
    tell: Option<Tell>,
    pairs: PathOutcome,
    /// Moved walls the refinement named, and how many were moved.
    named: (usize, usize),
    drawing_segments: usize,
}

/// Registers one simulated site, draws its drawing and aligns it both ways.
fn solve(
    plan: &Plan,
    args: &Args,
    params: &RegisterParams,
    symmetric: bool,
    rng: &mut ChaCha8Rng,
) -> Result<Option<SiteOutcome>> {
    let mut plan = plan.clone();
    plan.moves.clear();
    let Some(sensors) = installed_sensors(&plan, usize::from(args.site_sensors), &args.models, rng)
    else {
        return Ok(None);
    };
    plan.sensors = sensors;
    let Ok(models) = simulate_models(&plan, rng.random(), args.motion_seconds, params)? else {
        return Ok(None);
    };
    let truths: Vec<Pose2> = models.iter().filter_map(|(i, _)| truth_pose(i)).collect();
    if truths.len() != models.len() {
        return Ok(None);
    }
    let inputs = super::sim::site_inputs(models);
    let site = register_site(&inputs, 0, params, &SiteParams::default());
    let placed: Vec<(usize, Pose2, [f64; 3])> = site
        .sensors
        .iter()
        .enumerate()
        .filter_map(|(k, s)| {
            let p = s.pose.as_ref().ok()?;
            Some((
                k,
                p.pose.planar(),
                [p.sigma_x_m, p.sigma_y_m, p.sigma_yaw_rad],
            ))
        })
        .collect();
    let truth_bfs = truths[0];
    let site_err = placed.iter().fold((0.0f64, 0.0f64), |w, (k, p, _)| {
        let (m, r) = pose_error(p, &(truth_bfs.inverse() * truths[*k]));
        (w.0.max(m), w.1.max(r.to_degrees()))
    });
    let moved = if symmetric {
        Vec::new()
    } else {
        pick_moved(&plan, rng)?
    };
    let drawing = plan_drawing(&plan, &moved, args.drawing_clutter, rng)?;
    let align_sensors: Vec<AlignSensor<'_>> = placed
        .iter()
        .map(|(k, pose, _)| AlignSensor {
            id: &inputs[*k].id,
            model: &inputs[*k].model,
            site_from_sensor: *pose,
        })
        .collect();
    let t0 = Instant::now();
    let auto = align(&drawing, &align_sensors, &[], false, params);
    let auto_ms = t0.elapsed().as_secs_f64() * 1e3;
    let pairs = clicked_pairs(&drawing, &truth_bfs, rng);
    let t0 = Instant::now();
    let by_pairs = align(&drawing, &align_sensors, &pairs, false, params);
    let pairs_ms = t0.elapsed().as_secs_f64() * 1e3;
    // A moved wall is named when a line reported moved is that piece of the drawing.
    let pieces = scanfuse::sim::wall_pieces(&plan)?;
    let named = moved
        .iter()
        .filter(|k| {
            let (a, b) = pieces[**k];
            let mid = Point2::new((a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0);
            auto.refined
                .iter()
                .flat_map(|r| &r.lines)
                .any(|l| l.moved && ((l.a + l.b.coords) / 2.0 - mid).norm() < MOVED_M + 0.01)
        })
        .count();
    let auto = score(&auto, &placed, &truths, &truth_bfs, auto_ms);
    let tell = matches!(auto.verdict, Verdict::Abstained(_))
        .then(|| tell(&drawing, &align_sensors, &truth_bfs, params));
    Ok(Some(SiteOutcome {
        plan: plan.name.clone(),
        sensors: inputs.len(),
        placed: placed.len(),
        site_err,
        auto,
        tell,
        pairs: score(&by_pairs, &placed, &truths, &truth_bfs, pairs_ms),
        named: (named, moved.len()),
        drawing_segments: drawing.segments.len(),
    }))
}

/// Sums of one way of aligning over the sites.
#[derive(Default)]
struct Totals {
    n: usize,
    ok: usize,
    off: usize,
    /// Sites with a sensor off beyond its own 3σ.
    uncovered: usize,
    wrong: usize,
    reasons: BTreeMap<String, usize>,
    /// Abstentions measured for whether the walls could have told ([`Tell`]), those where
    /// the truth fit clearly best ([`Tell::could`]), and those where another alignment fit
    /// clearly better ([`Tell::misled`]).
    told: usize,
    could_tell: usize,
    misled: usize,
    ms: Vec<f64>,
}

impl Totals {
    fn add(&mut self, o: &PathOutcome, tell: Option<&Tell>) {
        self.n += 1;
        self.told += usize::from(tell.is_some());
        self.could_tell += usize::from(tell.is_some_and(Tell::could));
        self.misled += usize::from(tell.is_some_and(Tell::misled));
        self.ms.push(o.ms);
        match &o.verdict {
            Verdict::Ok => self.ok += 1,
            Verdict::Off => {
                self.off += 1;
                self.uncovered += usize::from(o.uncovered > 0);
            }
            Verdict::Wrong => self.wrong += 1,
            Verdict::Abstained(why) => {
                let key = why
                    .split([':', '('])
                    .next()
                    .unwrap_or("")
                    .trim()
                    .to_string();
                *self.reasons.entry(key).or_default() += 1;
            }
        }
    }

    fn print(&self, label: &str) {
        let pct = |k: usize| 100.0 * k as f64 / self.n.max(1) as f64;
        let abstained: usize = self.reasons.values().sum();
        println!(
            "{label}: {} sites, every sensor within {:.0} cm / {TOL_DEG}° on {} ({:.0} %), off (near, beyond target) {} ({} beyond their own 3σ), WRONG {}, abstained {} {:?}{}; align ms median {:.0}, max {:.0}",
            self.n,
            TOL_M * 100.0,
            self.ok,
            pct(self.ok),
            self.off,
            self.uncovered,
            self.wrong,
            abstained,
            self.reasons,
            if self.told > 0 {
                format!(
                    " (the truth fit the drawing clearly best in {}, another alignment clearly better in {})",
                    self.could_tell, self.misled
                )
            } else {
                String::new()
            },
            quantile(&self.ms, 0.5),
            quantile(&self.ms, 1.0)
        );
    }
}

/// Runs the sites of `--plans` (`--sites` of them, the plans in turn) and the symmetric hall.
pub(super) fn run(plans: &[Plan], args: &Args, params: &RegisterParams) -> Result<()> {
    let symmetric = Plan::from_toml(SYMMETRIC_PLAN, "eval: symmetric hall")?;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0xd7a3);
    println!(
        "\n== Sites of {} installed sensors aligned to their building drawing (walls and pillars; furniture left out; 1–2 walls drawn {:.0} cm off; {} desks of clutter): every sensor within {:.0} cm / {TOL_DEG}° of truth in the building frame? ==",
        args.site_sensors,
        MOVED_M * 100.0,
        args.drawing_clutter,
        TOL_M * 100.0
    );
    println!(
        "(auto: automatic + line refinement; pairs: two clicked corners, each up to {:.0} cm off, + line refinement; site err: the registration's own worst sensor, anchor frame; WRONG: anchor > {WRONG_M} m / {WRONG_DEG}° off)",
        CLICK_M * 100.0
    );
    println!(
        "{:<5} {:<10} {:>7} {:>8} {:>15} {:>22} {:>9} {:>22} {:>9} {:>6} {:>6}",
        "site",
        "plan",
        "placed",
        "segments",
        "site err",
        "auto",
        "auto ms",
        "pairs",
        "pairs ms",
        "moved",
        "named"
    );
    let (mut auto, mut pairs) = (Totals::default(), Totals::default());
    let (mut sym, mut sym_pairs) = (Totals::default(), Totals::default());
    let (mut named, mut moved) = (0, 0);
    let (mut done, mut attempts) = (0, 0);
    let total = args.sites + SYMMETRIC_SITES;
    while done < total && attempts < total * 50 {
        attempts += 1;
        let is_sym = done >= args.sites;
        let plan = if is_sym {
            &symmetric
        } else {
            &plans[attempts % plans.len()]
        };
        let Some(o) = solve(plan, args, params, is_sym, &mut rng)? else {
            continue;
        };
        done += 1;
        println!(
            "{:<5} {:<10} {:>5}/{} {:>8} {:>7.1}cm {:>4.2}° {:>22} {:>9.0} {:>22} {:>9.0} {:>6} {:>6}",
            done,
            o.plan,
            o.placed,
            o.sensors,
            o.drawing_segments,
            o.site_err.0 * 100.0,
            o.site_err.1,
            o.auto.cell(),
            o.auto.ms,
            o.pairs.cell(),
            o.pairs.ms,
            o.named.1,
            o.named.0
        );
        for (label, p) in [("auto", &o.auto), ("pairs", &o.pairs)] {
            match &p.verdict {
                Verdict::Abstained(why) => {
                    println!("      {label} abstained: {why}");
                    if let Some(t) = o.tell.as_ref().filter(|_| label == "auto") {
                        println!(
                            "      the walls {}: the truth scores {:.3}, an alignment {:.2} m / {:.0}° from it {:.3} ({:.0} %)",
                            t.verdict(),
                            t.truth,
                            t.rival_at.0,
                            t.rival_at.1,
                            t.rival,
                            100.0 * t.rival / t.truth.max(1e-9)
                        );
                    }
                }
                Verdict::Ok => {}
                _ => println!(
                    "      {label}: alignment (anchor) {:.1} cm {:.2}° off (its σ {}); {}/{} placed sensors within target, {} beyond 3σ",
                    p.anchor.0 * 100.0,
                    p.anchor.1,
                    p.sigma,
                    p.within,
                    o.placed,
                    p.uncovered
                ),
            }
        }
        if is_sym {
            sym.add(&o.auto, o.tell.as_ref());
            sym_pairs.add(&o.pairs, None);
        } else {
            auto.add(&o.auto, o.tell.as_ref());
            pairs.add(&o.pairs, None);
            named += o.named.0;
            moved += o.named.1;
        }
    }
    if done < total {
        println!("only {done} of {total} sites could be drawn");
    }
    auto.print("automatic");
    pairs.print("two clicked points");
    sym.print("symmetric hall, automatic (must abstain)");
    sym_pairs.print("symmetric hall, two clicked points");
    println!(
        "moved walls named by the refinement (automatic): {named} of {moved} (a wall no sensor sees cannot be named)"
    );
    Ok(())
}
