//! Walker correspondences as pose hypotheses. A person two sensors see at the same moment is a
//! point correspondence, and a few seconds of people walking fix the pose without any wall
//! (Glas et al., IROS 2010, registered a network of laser scanners from walking trajectories
//! alone). What is not known is which of A's walkers at a tick is which of B's: RANSAC over
//! pairs of simultaneous candidates proposes poses, the one most simultaneous walkers agree
//! with, over enough time and floor, is refined by least squares. The walkers themselves are
//! [`super::motion`]'s (one detector for registration and, later, tracking).

use nalgebra::{Matrix3, Point2, Rotation2, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::motion::{MotionParams, MotionTrack, co_motion};
use super::pair::pose_sigmas;
use crate::geometry::{Pose2, pose_error};
use crate::track::detect::{Body, torso_area};

/// Thresholds of the walker fit.
#[derive(Debug, Clone, PartialEq)]
pub struct WalkerParams {
    /// Bodies a walker fit is tried with besides a round one, where both scanners cut people
    /// level across the torso (`MotionTrack::sees_torsos`) but too few walkers were seen to
    /// measure the torsos' area (`min_silhouettes`): centrally symmetric ones of these areas
    /// (m², `detect::Body::Area`), from a slim person's hips to a broad torso. The one whose
    /// centres the people agree on best is kept.
    pub body_areas_m2: Vec<f64>,
    /// The torsos' area is measured from their silhouettes (`detect::torso_area`) only with
    /// this many seen from in front and as many from the side; `body_areas_m2` otherwise.
    pub min_silhouettes: usize,
    /// Sightings of one tick that cannot be carried to a common time are paired only this close
    /// in time (s): a walker moves 2 cm in 15 ms, and the same way every time along a corridor.
    pub max_skew_s: f64,
    /// The two correspondences a hypothesis is made of stand at least this far apart (m), and
    /// their distances in the two frames agree within `pair_tol_m`.
    pub min_apart_m: f64,
    pub pair_tol_m: f64,
    /// A mapped walker agrees when it lands this close to one of the other's (m).
    pub inlier_m: f64,
    /// Hypotheses drawn, and ticks scored per hypothesis (the final fit uses all).
    pub iterations: usize,
    pub ticks_scored: usize,
    /// A fit decides only with this many agreeing walker sightings, over at least `min_span_s`
    /// and across `min_spread_m` of floor, with an RMS residual under `max_rms_m`, and when the
    /// best other pose has fewer than `max_ambiguity` times its agreements (in registration,
    /// the best other the walls' free space and the walkers seen through leave standing:
    /// `WalkerFit::without`).
    pub min_inliers: usize,
    pub min_span_s: f64,
    pub min_spread_m: f64,
    pub max_rms_m: f64,
    pub max_ambiguity: f64,
    /// Two hypotheses this close are one (m, rad).
    pub same_m: f64,
    pub same_rad: f64,
    /// The pose the walkers lead with must see almost none of the walkers through: at most
    /// this share of those both saw (a right pose has next to none).
    pub max_through_share: f64,
    /// Consecutive sightings of one walker are not independent: the residual variance is
    /// inflated by this much in the covariance.
    pub correlation: f64,
    /// Walkers place a pair alone (no wall candidate in their basin, the walls undecided) only
    /// past all of these, stricter than a fit that merely chooses: this many agreeing
    /// sightings over this long and this much floor, a rival of at most
    /// `alone_max_ambiguity` as many walks ([`WalkerFit::rival_share`]; more only where
    /// the rival fails the walls' free space or the walkers seen through), and their own σ
    /// within these (m, rad). The σ limit is tight (2 cm) where a body's shape was chosen, not
    /// measured: its bias averages out only over many walks (a fit of σ 2.6 cm from ten walks
    /// in an open hall, its rival far behind, was 13 cm off; with the area measured, 2 cm).
    /// The residual limit is a deciding fit's own (`max_rms_m`): people walking a corridor
    /// seen from both ends show one unit their front and the other their back, which keeps
    /// a right fit's residual near 10 cm (one of 1004 sightings and σ 9 mm, 1 cm from the
    /// truth, had 10.1 cm and left a corridor crossing's arm unplaced: corridor-cross, seed
    /// 2); strong fits of 10–12 cm were 1–6 cm off (held-out plans, 30 s, seed 1: 10 of 10).
    pub alone_min_inliers: usize,
    pub alone_min_span_s: f64,
    pub alone_min_spread_m: f64,
    pub alone_max_ambiguity: f64,
    pub alone_max_sigma_m: f64,
    /// The position σ limit where the torsos' area was measured (`WalkerFit::torso_area_m2`):
    /// the centres are then placed without a shape's bias, and the σ says what it is.
    pub alone_max_sigma_measured_m: f64,
    pub alone_max_sigma_rad: f64,
    /// A walker-only pose is biased by a body's shape and the time between two scans; this
    /// much (m) is added in quadrature to its position σ so that the site weighs it honestly,
    /// and so that the walls joined with it weigh it so.
    pub alone_bias_m: f64,
    /// The same where the torsos' area was measured (`WalkerFit::torso_area_m2`): the shape's
    /// bias gone, the time's is left. Decisive fits with the area measured were 1–6 cm from
    /// the truth (rms 3.4 cm; `eval --only crowd --seed 1`, session 36) against 3–12 cm chosen.
    pub measured_bias_m: f64,
    /// Where decisive walkers chose the pose, the walls' free space is contradicted only by a
    /// beam less than this much (m) above what the other unit saw (`RegisterParams::
    /// free_space_dz_m` otherwise): people checked the free space already.
    pub chosen_free_space_dz_m: f64,
    /// Where decisive walkers chose the pose and the walkers both saw there confirm it
    /// (`MotionEvidence::confirms`), the walls' shared view need reach only this
    /// (`RegisterParams::min_overlap` otherwise; `min_score` scales down with it).
    pub chosen_min_overlap: f64,
}

impl Default for WalkerParams {
    fn default() -> Self {
        WalkerParams {
            body_areas_m2: vec![0.06, 0.08, 0.10, 0.12],
            min_silhouettes: 20,
            max_skew_s: 0.015,
            min_apart_m: 1.0,
            pair_tol_m: 0.2,
            inlier_m: 0.25,
            iterations: 1500,
            ticks_scored: 60,
            min_inliers: 25,
            min_span_s: 2.0,
            min_spread_m: 1.5,
            max_rms_m: 0.12,
            max_ambiguity: 0.6,
            same_m: 0.3,
            same_rad: 3f64.to_radians(),
            max_through_share: 0.1,
            correlation: 4.0,
            alone_min_inliers: 150,
            alone_min_span_s: 5.0,
            alone_min_spread_m: 3.0,
            alone_max_ambiguity: 0.25,
            alone_max_sigma_m: 0.02,
            alone_max_sigma_measured_m: 0.035,
            alone_max_sigma_rad: 0.3f64.to_radians(),
            alone_bias_m: 0.05,
            measured_bias_m: 0.03,
            chosen_free_space_dz_m: 0.05,
            chosen_min_overlap: 0.05,
        }
    }
}

/// The pose the walkers agree on.
#[derive(Debug, Clone, PartialEq)]
pub struct WalkerFit {
    pub a_from_b: Pose2,
    /// Walker sightings that agree (simultaneous, within `inlier_m`).
    pub inliers: usize,
    /// Time between the first and last agreeing sighting (s).
    pub span_s: f64,
    /// Largest distance between agreeing sightings on the floor (m).
    pub spread_m: f64,
    pub rms_m: f64,
    /// Every clearly different pose the leaders refined to, with its agreements (the most of
    /// them: [`runner_up`](Self::runner_up)).
    pub others: Vec<(usize, Pose2)>,
    /// How many walks agree with the fit, and the most with any clearly different pose: runs
    /// of one person followed walking in both views (`TOGETHER_S`, `TOGETHER_M`). The other
    /// agreements chance may give (people crossing, a queue); a walk is one person's word.
    pub walks: usize,
    pub runner_up_walks: usize,
    /// The pose those most walks of any clearly different pose agree with.
    pub rival: Option<Pose2>,
    /// Of (x, y, yaw).
    pub covariance: Matrix3<f64>,
    /// The pair's pose is this fit's own, placed by the walkers alone (the walls had no
    /// answer there), not a wall candidate they chose.
    pub alone: bool,
    /// The torsos' area (m²) the centres were placed with, where it was measured from the
    /// walkers' silhouettes (`detect::torso_area`); `None` where a body was chosen instead.
    pub torso_area_m2: Option<f64>,
}

impl WalkerFit {
    /// Enough walkers, over enough time and floor, agree, and no other pose comes close.
    pub fn decisive(&self, p: &WalkerParams) -> bool {
        self.inliers >= p.min_inliers
            && self.span_s >= p.min_span_s
            && self.spread_m >= p.min_spread_m
            && self.rms_m <= p.max_rms_m
            && (self.runner_up() as f64) < p.max_ambiguity * self.inliers as f64
    }

    /// Agreements of the best clearly different pose.
    pub fn runner_up(&self) -> usize {
        self.others.iter().map(|(n, _)| *n).max().unwrap_or(0)
    }

    /// The fit with the other poses that `refuted` rules out no longer counting as its
    /// runner-up.
    pub fn without(mut self, refuted: impl Fn(&Pose2) -> bool) -> WalkerFit {
        self.others.retain(|(_, q)| !refuted(q));
        self
    }

    /// The runner-up's walks against the best's. In a crowd a clearly different pose collects
    /// 30–60 % as many agreements as the right one, but from a moment's crossings and from
    /// one or two walks that happen to be congruent (two straight walks at one pace always
    /// are); the right pose has a walk for every person both saw.
    pub fn rival_share(&self) -> f64 {
        self.runner_up_walks as f64 / self.walks.max(1) as f64
    }

    /// Whether the fit is strong enough to place a pair by itself (`alone_*` thresholds):
    /// many simultaneous correspondences, spread over time and floor, with no rival.
    pub fn places_alone(&self, p: &WalkerParams) -> bool {
        self.places_alone_but_for_its_rival(p) && !self.has_rival(p)
    }

    /// Whether a clearly different pose has too many walks of its own for the fit to place
    /// a pair alone (`alone_max_ambiguity`).
    pub fn has_rival(&self, p: &WalkerParams) -> bool {
        self.rival_share() >= p.alone_max_ambiguity
    }

    /// [`places_alone`](Self::places_alone) but for the rival: where something else (the
    /// walls' free space, walkers seen through) rules the rival out, the fit stands alone.
    pub fn places_alone_but_for_its_rival(&self, p: &WalkerParams) -> bool {
        let (sigma_m, sigma_rad) = pose_sigmas(&self.covariance);
        self.decisive(p)
            && self.inliers >= p.alone_min_inliers
            && self.span_s >= p.alone_min_span_s
            && self.spread_m >= p.alone_min_spread_m
            && sigma_m <= self.alone_max_sigma_m(p)
            && sigma_rad <= p.alone_max_sigma_rad
    }

    /// The σ (m) a fit may have to place a pair alone: `alone_max_sigma_measured_m` where the
    /// torsos' area was measured, `alone_max_sigma_m` where a body was chosen.
    fn alone_max_sigma_m(&self, p: &WalkerParams) -> f64 {
        match self.torso_area_m2 {
            Some(_) => p.alone_max_sigma_measured_m,
            None => p.alone_max_sigma_m,
        }
    }

    /// How far (m) its centres may sit off the bodies' own, whatever its σ: `measured_bias_m`
    /// where the torsos' area was measured, `alone_bias_m` where a body was chosen.
    pub fn bias_m(&self, p: &WalkerParams) -> f64 {
        match self.torso_area_m2 {
            Some(_) => p.measured_bias_m,
            None => p.alone_bias_m,
        }
    }

    /// The covariance the pose the walkers give has: the fit's, its position widened by the
    /// bias a body's shape and time leave (`alone_bias_m`, or `measured_bias_m` where the
    /// torsos' area was measured).
    pub fn biased_covariance(&self, p: &WalkerParams) -> Matrix3<f64> {
        let bias = self.bias_m(p);
        let mut c = self.covariance;
        c[(0, 0)] += bias * bias;
        c[(1, 1)] += bias * bias;
        c
    }

    /// Whether `pose` is one the walkers can live with: within their basin widened by three
    /// of the fit's own σ. A decisive fit from a few seconds of walkers may be a few degrees
    /// off (σ 1.5°), and a walls' pose within that is not one they contradict.
    pub fn agrees(&self, pose: &Pose2, p: &WalkerParams) -> bool {
        let (sigma_m, sigma_rad) = pose_sigmas(&self.covariance);
        let (dt, dyaw) = pose_error(pose, &self.a_from_b);
        dt < p.same_m + 3.0 * sigma_m && dyaw < p.same_rad + 3.0 * sigma_rad
    }

    /// Whether `pose` lies in the walkers' basin: the walls refine within it what the walkers,
    /// biased by a body's shape and by time, only locate.
    pub fn near(&self, pose: &Pose2, p: &WalkerParams) -> bool {
        let (dt, dyaw) = pose_error(pose, &self.a_from_b);
        dt < p.same_m && dyaw < p.same_rad
    }
}

/// What placed a pair, in the vocabulary of `register --json` and the status socket:
/// `"walls"`, `"walls+walkers"` (walkers chose among the walls' candidates) or `"walkers"`
/// (people alone).
pub fn evidence(fit: Option<&WalkerFit>) -> &'static str {
    match fit {
        None => "walls",
        Some(f) if f.alone => "walkers",
        Some(_) => "walls+walkers",
    }
}

/// The candidates left once decisive walkers chose one (`fit`): only those in their basin.
/// The others are poses the walls liked and the people both sensors saw walk ruled out (a
/// pilaster pitch off, the corridor turned end for end); left in, the site would weigh them
/// by the walls alone and prefer the look-alike the walkers refused. Without a fit, all stay.
pub fn walkers_keep<T>(
    candidates: Vec<T>,
    fit: Option<&WalkerFit>,
    pose: impl Fn(&T) -> &Pose2,
    p: &WalkerParams,
) -> Vec<T> {
    match fit {
        Some(f) => candidates
            .into_iter()
            .filter(|c| f.near(pose(c), p))
            .collect(),
        None => candidates,
    }
}

/// Agreeing sightings: A's centre, B's, and when (s).
type Matched = Vec<(Point2<f64>, Point2<f64>, f64)>;

/// Walker centres both sensors had at one tick.
struct Tick {
    t_s: f64,
    a: Vec<Point2<f64>>,
    b: Vec<Point2<f64>>,
}

/// What a hypothesis explains.
#[derive(Default)]
struct Agreement {
    count: usize,
    pairs: Vec<(Point2<f64>, Point2<f64>, f64)>,
}

/// Pairs each of B's walkers (mapped into A) with the nearest unused one of A's within reach.
fn agree(ticks: &[&Tick], a_from_b: &Pose2, reach_m: f64, keep: bool) -> Agreement {
    let mut out = Agreement::default();
    let mut used: Vec<bool> = Vec::new();
    for tick in ticks {
        used.clear();
        used.resize(tick.a.len(), false);
        for b in &tick.b {
            let q = a_from_b * b;
            let nearest = tick
                .a
                .iter()
                .enumerate()
                .filter(|(i, _)| !used.get(*i).copied().unwrap_or(true))
                .map(|(i, a)| (i, (a - q).norm()))
                .min_by(|x, y| x.1.total_cmp(&y.1));
            if let Some((i, _)) = nearest.filter(|(_, d)| *d <= reach_m) {
                if let Some(u) = used.get_mut(i) {
                    *u = true;
                }
                out.count += 1;
                if keep && let Some(a) = tick.a.get(i) {
                    out.pairs.push((*a, *b, tick.t_s));
                }
            }
        }
    }
    out
}

/// The rigid pose taking b1→a1 and b2→a2 best (rotation from the two directions).
fn from_two(a1: Point2<f64>, a2: Point2<f64>, b1: Point2<f64>, b2: Point2<f64>) -> Pose2 {
    let (da, db) = (a2 - a1, b2 - b1);
    let yaw = da.y.atan2(da.x) - db.y.atan2(db.x);
    let rot = Rotation2::new(yaw);
    let t = nalgebra::center(&a1, &a2) - rot * nalgebra::center(&b1, &b2);
    Pose2::new(t, yaw)
}

/// Least-squares rigid pose over the pairs (a, b): a ≈ pose · b.
fn least_squares(pairs: &[(Point2<f64>, Point2<f64>, f64)]) -> Option<Pose2> {
    if pairs.len() < 2 {
        return None;
    }
    let n = pairs.len() as f64;
    let ca = pairs.iter().map(|(a, _, _)| a.coords).sum::<Vector2<f64>>() / n;
    let cb = pairs.iter().map(|(_, b, _)| b.coords).sum::<Vector2<f64>>() / n;
    let (mut s_cross, mut s_dot) = (0.0, 0.0);
    for (a, b, _) in pairs {
        let (u, v) = (a.coords - ca, b.coords - cb);
        s_cross += v.x * u.y - v.y * u.x;
        s_dot += v.x * u.x + v.y * u.y;
    }
    let yaw = s_cross.atan2(s_dot);
    let t = ca - Rotation2::new(yaw) * cb;
    Some(Pose2::new(t, yaw))
}

/// σ² (JᵀJ)⁻¹ of the fit, σ² the residual variance inflated for correlated sightings.
fn covariance(
    pose: &Pose2,
    pairs: &[(Point2<f64>, Point2<f64>, f64)],
    rms_m: f64,
    p: &WalkerParams,
) -> Matrix3<f64> {
    let yaw = pose.rotation.angle();
    let (s, c) = yaw.sin_cos();
    let mut jtj = Matrix3::zeros();
    for (_, b, _) in pairs {
        let rows = [
            nalgebra::RowVector3::new(1.0, 0.0, -s * b.x - c * b.y),
            nalgebra::RowVector3::new(0.0, 1.0, c * b.x - s * b.y),
        ];
        for r in rows {
            jtj += r.transpose() * r;
        }
    }
    let variance = (rms_m * rms_m).max(0.03f64.powi(2)) * p.correlation;
    jtj.try_inverse()
        .map_or(Matrix3::identity() * 1e6, |inv| inv * variance)
}

/// The pose most simultaneous walkers agree on, `None` without two sensors watching walkers
/// at the same ticks. Deterministic.
pub fn fit_walkers(
    a: &MotionTrack,
    b: &MotionTrack,
    p: &WalkerParams,
    motion: &MotionParams,
) -> Option<WalkerFit> {
    let ticks_of = |body: Body| -> Vec<Tick> {
        a.centres_with(b, p.max_skew_s, body)
            .into_iter()
            .map(|(t_s, a, b)| Tick { t_s, a, b })
            .collect()
    };
    let ticks = ticks_of(Body::Round);
    // Candidate correspondences: every (A walker, B walker) of a tick.
    let candidates: Vec<(usize, Point2<f64>, Point2<f64>)> = ticks
        .iter()
        .enumerate()
        .flat_map(|(k, t)| {
            t.a.iter()
                .flat_map(move |a| t.b.iter().map(move |b| (k, *a, *b)))
        })
        .collect();
    if candidates.len() < 2 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0x57a1_4e25);
    let scored: Vec<&Tick> = if ticks.len() <= p.ticks_scored {
        ticks.iter().collect()
    } else {
        let step = ticks.len() as f64 / p.ticks_scored as f64;
        (0..p.ticks_scored)
            .filter_map(|i| ticks.get((i as f64 * step) as usize))
            .collect()
    };
    // Distinct hypotheses with their agreement on the scored ticks, best first.
    let mut best: Vec<(usize, Pose2)> = Vec::new();
    let same = |x: &Pose2, y: &Pose2| {
        let (dt, dyaw) = pose_error(x, y);
        dt < p.same_m && dyaw < p.same_rad
    };
    let mut consider = |pose: Pose2| {
        let count = agree(&scored, &pose, p.inlier_m, false).count;
        match best.iter_mut().find(|(_, q)| same(q, &pose)) {
            Some(entry) if entry.0 >= count => {}
            Some(entry) => *entry = (count, pose),
            None => best.push((count, pose)),
        }
        best.sort_by_key(|x| std::cmp::Reverse(x.0));
        best.truncate(8);
    };
    // In a crowd two random sightings are seldom the same two people in both sensors; a
    // walker followed for a second or two is. Paths first, then random pairs.
    for pose in path_hypotheses(&ticks, p) {
        consider(pose);
    }
    for _ in 0..p.iterations {
        let (Some(&(_, a1, b1)), Some(&(_, a2, b2))) = (
            candidates.get(rng.random_range(0..candidates.len())),
            candidates.get(rng.random_range(0..candidates.len())),
        ) else {
            continue;
        };
        let (da, db) = ((a2 - a1).norm(), (b2 - b1).norm());
        if da < p.min_apart_m || (da - db).abs() > p.pair_tol_m {
            continue;
        }
        consider(from_two(a1, a2, b1, b2));
    }
    // Refine the leaders on every tick; the best refined one is the fit.
    let all: Vec<&Tick> = ticks.iter().collect();
    let mut refined: Vec<(usize, Pose2, Matched)> = best
        .iter()
        .filter_map(|(_, pose)| {
            let (pose, agreement) = refine_on(&all, *pose, p.inlier_m)?;
            Some((agreement.count, pose, agreement.pairs))
        })
        .collect();
    // In a crowd a wrong pose that lays one sensor's busy floor over the other's matches
    // many sightings by chance; it also puts walkers where the other saw through at that
    // moment. Those are out before any counting decides.
    refined.retain(|(_, pose, _)| !co_motion(a, b, pose, motion).refutes(motion));
    refined.sort_by_key(|x| std::cmp::Reverse(x.0));
    let (inliers, pose, pairs) = refined.first()?.clone();
    // The people's shape, refined again with it. Only where both planes cut people level
    // across the torso (elsewhere legs, heads, or a mix down a pitched plane: round is the
    // safer guess). There, the torsos' area as their silhouettes show it against the way
    // they walk (`detect::torso_area`, both units' walkers); where too few were seen from in
    // front and from the side to measure it, the body of `body_areas_m2` (or round) whose
    // centres agree best at the winner. The choice is the weaker: the agreement is nearly
    // flat in the area, and an area 0.02 m² off moves every centre 2–4 cm along its beam,
    // which left walker poses 4–12 cm off where the measured area leaves 1–3.
    let refit = |area: f64| {
        let ticks = ticks_of(Body::Area(area));
        let all: Vec<&Tick> = ticks.iter().collect();
        let (pose, agreement) = refine_on(&all, pose, p.inlier_m)?;
        Some((agreement.count, pose, agreement.pairs))
    };
    let torsos = a.sees_torsos() && b.sees_torsos();
    let measured = torsos
        .then(|| {
            let mut seen = a.silhouettes();
            seen.extend(b.silhouettes());
            torso_area(&seen, p.min_silhouettes)
        })
        .flatten()
        .and_then(|area| Some((area, refit(area)?)));
    let chosen = || {
        let areas: &[f64] = if torsos { &p.body_areas_m2 } else { &[] };
        areas
            .iter()
            .filter_map(|&area| refit(area))
            .chain(std::iter::once((inliers, pose, pairs)))
            .max_by(|x, y| {
                let (sx, sy) = (
                    support(&x.2, &x.1, p.inlier_m),
                    support(&y.2, &y.1, p.inlier_m),
                );
                sx.total_cmp(&sy)
            })
    };
    let (torso_area_m2, (inliers, pose, pairs)) = match measured {
        Some((area, fit)) => (Some(area), fit),
        None => (None, chosen()?),
    };
    // Leaders that refine to the winner were the same pose seen through noise. The rival:
    // the most sightings, and the most walks of one person in both views, of any other.
    let others: Vec<&(usize, Pose2, Matched)> = refined
        .iter()
        .skip(1)
        .filter(|(_, q, _)| !same(q, &pose))
        .collect();
    // A rival's walks count only where the winner does not explain them too: a pose a few
    // degrees off, refined from a subset of the same walkers (a corridor's walkers all far
    // along one line leave such subsets), is the winner's evidence again, not another place.
    let (runner_up_walks, rival) = others
        .iter()
        .map(|(_, q, matched)| (rival_walks(&pose, matched, p.inlier_m), *q))
        .max_by_key(|(walks, _)| *walks)
        .map_or((0, None), |(walks, q)| (walks, Some(q)));
    let rms_m = (pairs
        .iter()
        .map(|(a, b, _)| (a - pose * b).norm_squared())
        .sum::<f64>()
        / pairs.len().max(1) as f64)
        .sqrt();
    let (t0, t1) = pairs
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), (_, _, t)| {
            (lo.min(*t), hi.max(*t))
        });
    let spread_m = spread(pairs.iter().map(|(a, _, _)| *a));
    Some(WalkerFit {
        a_from_b: pose,
        inliers,
        span_s: (t1 - t0).max(0.0),
        spread_m,
        rms_m,
        others: others.iter().map(|(n, q, _)| (*n, *q)).collect(),
        walks: walked_together(&pairs).walks,
        runner_up_walks,
        rival,
        covariance: covariance(&pose, &pairs, rms_m, p),
        alone: false,
        torso_area_m2,
    })
}

/// `pose` refined on the ticks: three rounds of agreeing sightings and least squares.
fn refine_on(ticks: &[&Tick], mut pose: Pose2, reach_m: f64) -> Option<(Pose2, Agreement)> {
    let mut agreement = agree(ticks, &pose, reach_m, true);
    for _ in 0..3 {
        pose = least_squares(&agreement.pairs)?;
        agreement = agree(ticks, &pose, reach_m, true);
    }
    Some((pose, agreement))
}

/// How well sightings agree with a pose, counting both how many and how close: each
/// agreeing sighting adds what is left of the reach once its residual is taken
/// (`reach² − d²`), so a body that brings more sightings in, or the same ones closer, wins.
fn support(pairs: &Matched, pose: &Pose2, reach_m: f64) -> f64 {
    pairs
        .iter()
        .map(|(a, b, _)| (reach_m * reach_m - (a - pose * b).norm_squared()).max(0.0))
        .sum()
}

/// A rival's walks (`matched`: the sightings it agrees on) among the sightings the best pose
/// does not explain too (within `inlier_m`).
fn rival_walks(best: &Pose2, matched: &[(Point2<f64>, Point2<f64>, f64)], inlier_m: f64) -> usize {
    let own: Matched = matched
        .iter()
        .filter(|(a, b, _)| (a - best * b).norm() > inlier_m)
        .copied()
        .collect();
    walked_together(&own).walks
}

/// Agreements count as one person walking in both views only in runs that follow the same
/// walker in both, tick after tick, for at least this long (s) and this far (m): two
/// people crossing where a wrong pose lays them over each other agree for a moment, and
/// people standing in a queue agree where they stand; the same person walking agrees along.
const TOGETHER_S: f64 = 1.0;
const TOGETHER_M: f64 = 1.0;
/// A walk lost for up to this long (s) and found again within what a walker covers at
/// `WALK_SPEED_M_S` is the same walk.
const WALK_GAP_S: f64 = 1.0;
const WALK_SPEED_M_S: f64 = 2.0;

/// What one person followed walking in both views says of a pose.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
struct Together {
    /// Agreeing sightings in such runs.
    sightings: usize,
    /// The runs: walks, each a person (one long walk interrupted counts more than once).
    walks: usize,
}

/// Of the agreeing sightings `pairs` (in tick order), the runs of one walker followed in
/// both sensors for [`TOGETHER_S`] over [`TOGETHER_M`] (see there).
fn walked_together(pairs: &[(Point2<f64>, Point2<f64>, f64)]) -> Together {
    // A run: its first time and place in A, its last sighting in both, its length.
    struct Run {
        t0: f64,
        a0: Point2<f64>,
        a: Point2<f64>,
        b: Point2<f64>,
        t: f64,
        n: usize,
        far_m: f64,
    }
    let counted = |r: &Run| r.t - r.t0 >= TOGETHER_S && r.far_m >= TOGETHER_M;
    let mut out = Together::default();
    let mut close = |runs: &[Run]| {
        for r in runs.iter().filter(|r| counted(r)) {
            out.sightings += r.n;
            out.walks += 1;
        }
    };
    let mut open: Vec<Run> = Vec::new();
    let mut k = 0;
    while let Some(&(_, _, t)) = pairs.get(k) {
        let tick: Vec<&(Point2<f64>, Point2<f64>, f64)> =
            pairs[k..].iter().take_while(|x| x.2 == t).collect();
        k += tick.len();
        let mut next: Vec<Run> = Vec::new();
        for (a, b, _) in tick {
            let continued = open.iter().position(|r| {
                let reach_m = PATH_STEP_M + WALK_SPEED_M_S * (t - r.t);
                t - r.t <= WALK_GAP_S && (r.a - a).norm() <= reach_m && (r.b - b).norm() <= reach_m
            });
            next.push(match continued {
                Some(i) => {
                    let r = open.swap_remove(i);
                    Run {
                        a: *a,
                        b: *b,
                        t,
                        n: r.n + 1,
                        far_m: r.far_m.max((a - r.a0).norm()),
                        ..r
                    }
                }
                None => Run {
                    t0: t,
                    a0: *a,
                    a: *a,
                    b: *b,
                    t,
                    n: 1,
                    far_m: 0.0,
                },
            });
        }
        // Runs not seen for `WALK_GAP_S` end; a walk seen again sooner is the same walk
        // (one walk counted twice would make a chance rival look like two people).
        let (ended, waiting): (Vec<Run>, Vec<Run>) =
            open.into_iter().partition(|r| t - r.t > WALK_GAP_S);
        close(&ended);
        next.extend(waiting);
        open = next;
    }
    close(&open);
    out
}

/// How far one sensor's clock reads from another's, found from their walkers.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockOffset {
    /// B's stamp minus A's for one moment (s).
    pub offset_s: f64,
    /// The walker fit at that offset.
    pub fit: WalkerFit,
}

/// Offsets tried first (s apart), and around the best of them.
const CLOCK_COARSE_S: f64 = 0.05;
const CLOCK_FINE_S: f64 = 0.01;

/// The offset of B's clock against A's, within ±`max_s`, that best aligns the walkers both
/// saw: walkers moving every which way put a skew into the fit that no rigid pose absorbs.
/// First the offset whose decisive fit agrees with the most sightings, then, around it, the
/// one with the smallest residual, interpolated. `None` when no offset gives a decisive fit
/// (then B's walkers cannot be compared with A's, and must not be).
pub fn clock_offset(
    a: &MotionTrack,
    b: &MotionTrack,
    p: &WalkerParams,
    motion: &MotionParams,
    max_s: f64,
) -> Option<ClockOffset> {
    // B's stamps read `offset` more than A's: its frames go back by that much.
    let fit_at = |offset_s: f64| {
        fit_walkers(a, &b.shifted(-offset_s, motion), p, motion)
            .filter(|f| f.decisive(p))
            .map(|fit| (offset_s, fit))
    };
    let steps = (max_s / CLOCK_COARSE_S).ceil() as i64;
    let coarse: Vec<(f64, WalkerFit)> = (-steps..=steps)
        .collect::<Vec<i64>>()
        .into_par_iter()
        .filter_map(|k| fit_at(k as f64 * CLOCK_COARSE_S))
        .collect();
    let (centre, _) = coarse.iter().max_by_key(|(_, f)| f.inliers)?;
    let span = (CLOCK_COARSE_S / CLOCK_FINE_S).round() as i64;
    let mut fine: Vec<(f64, WalkerFit)> = (-span..=span)
        .collect::<Vec<i64>>()
        .into_par_iter()
        .filter_map(|k| fit_at(centre + k as f64 * CLOCK_FINE_S))
        .collect();
    fine.sort_by(|x, y| x.0.total_cmp(&y.0));
    let most = fine.iter().map(|(_, f)| f.inliers).max()?;
    let k = fine
        .iter()
        .enumerate()
        .filter(|(_, (_, f))| f.inliers as f64 >= 0.8 * most as f64)
        .min_by(|x, y| x.1.1.rms_m.total_cmp(&y.1.1.rms_m))
        .map(|(k, _)| k)?;
    let (offset_s, fit) = fine.get(k)?.clone();
    // A parabola through the residuals of the neighbours places the minimum between steps.
    let offset_s = match (k.checked_sub(1).and_then(|j| fine.get(j)), fine.get(k + 1)) {
        (Some((o0, f0)), Some((o2, f2))) if (o2 - o0 - 2.0 * CLOCK_FINE_S).abs() < 1e-9 => {
            let (r0, r1, r2) = (f0.rms_m, fit.rms_m, f2.rms_m);
            let curve = r0 - 2.0 * r1 + r2;
            if curve > 1e-12 {
                offset_s + 0.5 * CLOCK_FINE_S * (r0 - r2) / curve
            } else {
                offset_s
            }
        }
        _ => offset_s,
    };
    Some(ClockOffset { offset_s, fit })
}

/// One walker's centres over consecutive ticks: (tick index, centre).
type Path = Vec<(usize, Point2<f64>)>;

/// A walker moves at most this far between two ticks 0.1 s apart (m), and ticks further
/// apart than `PATH_GAP_S` end a path.
const PATH_STEP_M: f64 = 0.35;
const PATH_GAP_S: f64 = 0.15;
/// A path pair proposes a pose over at least this many shared ticks, with residuals under
/// `PATH_RMS_M`.
const PATH_MIN_TICKS: usize = 8;
const PATH_RMS_M: f64 = 0.2;

/// Each sensor's walkers linked into paths: a centre continues the path of the previous
/// tick's centre when each is the other's nearest within [`PATH_STEP_M`]; anything else
/// starts a new path (two people passing close break theirs, which is safe).
fn paths(ticks: &[Tick], side: impl Fn(&Tick) -> &[Point2<f64>]) -> Vec<Path> {
    let mut done: Vec<Path> = Vec::new();
    let mut open: Vec<Path> = Vec::new();
    let nearest = |q: &Point2<f64>, among: &[Point2<f64>]| {
        among
            .iter()
            .enumerate()
            .map(|(i, c)| (i, (c - q).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .filter(|(_, d)| *d <= PATH_STEP_M)
            .map(|(i, _)| i)
    };
    for (k, tick) in ticks.iter().enumerate() {
        let now = side(tick);
        let previous: Option<&Tick> = k.checked_sub(1).and_then(|j| ticks.get(j));
        let close = previous.is_some_and(|t| tick.t_s - t.t_s <= PATH_GAP_S);
        let before: Vec<Point2<f64>> = open.iter().filter_map(|p| p.last().map(|x| x.1)).collect();
        let mut next: Vec<Path> = Vec::new();
        let mut taken = vec![false; open.len()];
        for c in now {
            let link = close.then(|| nearest(c, &before)).flatten().filter(|&i| {
                nearest(before.get(i).unwrap_or(c), now) == now.iter().position(|x| x == c)
            });
            match link.filter(|&i| !taken.get(i).copied().unwrap_or(true)) {
                Some(i) => {
                    taken[i] = true;
                    let mut path = std::mem::take(&mut open[i]);
                    path.push((k, *c));
                    next.push(path);
                }
                None => next.push(vec![(k, *c)]),
            }
        }
        done.extend(open.into_iter().filter(|p| p.len() >= PATH_MIN_TICKS));
        open = next;
    }
    done.extend(open.into_iter().filter(|p| p.len() >= PATH_MIN_TICKS));
    done
}

/// Poses from pairs of paths, one in each sensor, over the ticks they share: a walker
/// followed over a metre or more fixes a pose by itself when it is the same person in both.
fn path_hypotheses(ticks: &[Tick], p: &WalkerParams) -> Vec<Pose2> {
    let (pa, pb) = (paths(ticks, |t| &t.a), paths(ticks, |t| &t.b));
    let mut out = Vec::new();
    for a in &pa {
        let (Some(a0), Some(a1)) = (a.first(), a.last()) else {
            continue;
        };
        for b in &pb {
            let (Some(b0), Some(b1)) = (b.first(), b.last()) else {
                continue;
            };
            if a1.0.min(b1.0) < a0.0.max(b0.0) + PATH_MIN_TICKS - 1 {
                continue;
            }
            let mut j = 0;
            let mut matched: Matched = Vec::new();
            for &(k, qa) in a {
                while b.get(j).is_some_and(|x| x.0 < k) {
                    j += 1;
                }
                if let Some(&(kb, qb)) = b.get(j).filter(|x| x.0 == k) {
                    let t_s = ticks.get(kb).map_or(0.0, |t| t.t_s);
                    matched.push((qa, qb, t_s));
                }
            }
            if matched.len() < PATH_MIN_TICKS {
                continue;
            }
            let spread_a = spread(matched.iter().map(|m| m.0));
            let spread_b = spread(matched.iter().map(|m| m.1));
            if spread_a < p.min_apart_m || (spread_a - spread_b).abs() > p.pair_tol_m {
                continue;
            }
            let Some(pose) = least_squares(&matched) else {
                continue;
            };
            let sq = matched
                .iter()
                .map(|(qa, qb, _)| (qa - pose * qb).norm_squared())
                .sum::<f64>();
            if (sq / matched.len() as f64).sqrt() <= PATH_RMS_M {
                out.push(pose);
            }
        }
    }
    out
}

/// The largest distance between two of the points (an extreme pair of a bounding box is
/// enough here).
fn spread(points: impl Iterator<Item = Point2<f64>>) -> f64 {
    let (mut lo, mut hi) = (Vector2::repeat(f64::MAX), Vector2::repeat(f64::MIN));
    let mut any = false;
    for q in points {
        lo = lo.inf(&q.coords);
        hi = hi.sup(&q.coords);
        any = true;
    }
    if any { (hi - lo).norm() } else { 0.0 }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::pose2;
    use crate::geometry::raycast::{Wall, polygon, scan_270};
    use crate::geometry::{Mount, ProjectParams};
    use crate::register::motion::MotionParams;
    use crate::scan::Scan;

    /// A 270° scan at 0.25° steps of `walls` plus `people` (0.2 m radius discs, as squares)
    /// from `site_from_sensor`.
    pub(crate) fn scan(
        walls: &[Wall],
        people: &[[f64; 2]],
        site_from_sensor: &Pose2,
        t_ns: u64,
    ) -> Scan {
        let mut seen = walls.to_vec();
        for [x, y] in people {
            let r = 0.2;
            seen.extend(polygon(&[
                (x - r, y - r),
                (x + r, y - r),
                (x + r, y + r),
                (x - r, y + r),
            ]));
        }
        scan_270(&seen, site_from_sensor, 0.25, t_ns)
    }

    /// People walking straight lines back and forth across an open floor for `seconds`.
    fn people_at(t_s: f64) -> Vec<[f64; 2]> {
        let bounce = |from: f64, to: f64, period_s: f64| {
            let s = (t_s / period_s).fract();
            let s = if s < 0.5 { 2.0 * s } else { 2.0 - 2.0 * s };
            from + s * (to - from)
        };
        vec![
            [bounce(2.0, 12.0, 14.0), 3.0 + bounce(0.0, 4.0, 9.0)],
            [8.0 + bounce(-3.0, 3.0, 7.0), bounce(1.0, 9.0, 11.0)],
            [bounce(12.0, 3.0, 10.0), 8.0],
        ]
    }

    fn track(walls: &[Wall], pose: &Pose2, seconds: f64) -> MotionTrack {
        track_on_clock(walls, pose, seconds, 0)
    }

    /// As [`track`], its scans stamped by a clock that reads `ahead_ns` more than the other's.
    fn track_on_clock(walls: &[Wall], pose: &Pose2, seconds: f64, ahead_ns: u64) -> MotionTrack {
        let p = MotionParams::default();
        let frames = (seconds * 40.0) as u64;
        let scans: Vec<Scan> = (0..frames)
            .map(|k| {
                let t_s = k as f64 / 40.0;
                scan(walls, &people_at(t_s), pose, ahead_ns + k * 25_000_000)
            })
            .collect();
        let still = scan(walls, &[], pose, 0);
        MotionTrack::new(
            &scans,
            &still,
            None,
            &Mount::default(),
            &ProjectParams::default(),
            &p,
        )
        .expect("a track")
    }

    /// A crowd: fourteen people crossing the floor back and forth on lines of their own.
    fn crowd_at(t_s: f64) -> Vec<[f64; 2]> {
        (0..14)
            .map(|i| {
                let k = i as f64;
                let period_s = 7.0 + (k * 1.7) % 6.0;
                let s = ((t_s + k * 0.9) / period_s).fract();
                let s = if s < 0.5 { 2.0 * s } else { 2.0 - 2.0 * s };
                let (x0, y0) = (1.0 + (k * 3.1) % 12.0, 1.0 + (k * 2.3) % 8.0);
                let (x1, y1) = (13.0 - (k * 1.9) % 11.0, 9.0 - (k * 4.1) % 8.0);
                [x0 + s * (x1 - x0), y0 + s * (y1 - y0)]
            })
            .collect()
    }

    /// A torso 0.45 m across its walking direction (`heading`) and 0.28 m along it, as a
    /// 24-sided outline.
    fn torso(centre: Point2<f64>, heading: f64) -> Vec<Wall> {
        let (a, b) = (0.14, 0.225);
        let corners: Vec<(f64, f64)> = (0..24)
            .map(|k| {
                let t = k as f64 * std::f64::consts::TAU / 24.0;
                let (x, y) = (a * t.cos(), b * t.sin());
                let (s, c) = heading.sin_cos();
                (centre.x + c * x - s * y, centre.y + s * x + c * y)
            })
            .collect();
        polygon(&corners)
    }

    /// People walking lanes along x between two units that face each other down them, as
    /// torsos: each unit sees every one of them from in front or behind. Level at 1 m.
    fn torso_track(pose: &Pose2, seconds: f64) -> MotionTrack {
        let room = polygon(&[(-1.0, -1.0), (15.0, -1.0), (15.0, 11.0), (-1.0, 11.0)]);
        let people = |t_s: f64| -> Vec<(Point2<f64>, f64)> {
            (0..4)
                .map(|i| {
                    let period_s = 9.0 + 1.3 * i as f64;
                    let s = ((t_s + 2.1 * i as f64) / period_s).fract();
                    let (s, heading) = if s < 0.5 {
                        (2.0 * s, 0.0)
                    } else {
                        (2.0 - 2.0 * s, std::f64::consts::PI)
                    };
                    (Point2::new(3.0 + 8.0 * s, 1.5 + 2.3 * i as f64), heading)
                })
                .collect()
        };
        // One scan a tick of the track (0.1 s): it keeps no more.
        let scans: Vec<Scan> = (0..(seconds * 10.0) as u64)
            .map(|k| {
                let mut seen = room.clone();
                for (c, heading) in people(k as f64 / 10.0) {
                    seen.extend(torso(c, heading));
                }
                scan_270(&seen, pose, 0.25, k * 100_000_000)
            })
            .collect();
        let mount = Mount {
            height_m: Some(1.0),
            pitch_rad: 0.0,
        };
        let still = scan_270(&room, pose, 0.25, 0);
        let p = MotionParams::default();
        MotionTrack::new(&scans, &still, None, &mount, &ProjectParams::default(), &p)
            .expect("a track")
    }

    #[test]
    fn torsos_walking_towards_and_away_from_both_units_are_centred_as_torsos() {
        let (pa, pb) = (pose2(0.5, 5.0, 0.0), pose2(13.5, 5.2, std::f64::consts::PI));
        let (ta, tb) = (torso_track(&pa, 20.0), torso_track(&pb, 20.0));
        let truth = pa.inverse() * pb;
        let motion = MotionParams::default();
        let error = |p: &WalkerParams| {
            let fit = fit_walkers(&ta, &tb, p, &motion).expect("a fit");
            pose_error(&fit.a_from_b, &truth).0
        };
        // Seen from in front, a round body's rule pushes each centre up to 7 cm too far from
        // its unit: the two units come out several cm too close together.
        let round = WalkerParams {
            body_areas_m2: Vec::new(),
            min_silhouettes: usize::MAX,
            ..WalkerParams::default()
        };
        let (as_torsos, as_round) = (error(&WalkerParams::default()), error(&round));
        println!("as torsos {as_torsos:.3} m off, as round bodies {as_round:.3} m");
        assert!(as_torsos < 0.03, "as torsos {as_torsos:.3} m off");
        assert!(as_round > 0.06, "as round bodies {as_round:.3} m off");
    }

    #[test]
    fn the_torsos_area_is_measured_from_a_unit_in_front_and_one_beside_them() {
        let front = torso_track(&pose2(0.5, 5.0, 0.0), 20.0);
        let side = torso_track(&pose2(7.0, -0.8, std::f64::consts::FRAC_PI_2), 20.0);
        let truth = std::f64::consts::PI * 0.14 * 0.225;
        let min = WalkerParams::default().min_silhouettes;
        // From in front alone the depth is unknown; with the side view it is measured.
        assert_eq!(torso_area(&front.silhouettes(), min), None);
        let mut seen = front.silhouettes();
        seen.extend(side.silhouettes());
        let area = torso_area(&seen, min).expect("seen from in front and beside");
        println!(
            "{} silhouettes: {area:.4} m² against {truth:.4}",
            seen.len()
        );
        assert!(
            (area - truth).abs() < 0.1 * truth,
            "{area:.4} m² against {truth:.4}"
        );
    }

    #[test]
    fn in_a_crowd_a_walker_followed_in_both_sensors_proposes_the_pose() {
        // Fourteen people at once, listed in no particular order by each sensor: a random
        // pair of sightings is seldom the same two people in both; one path is.
        let (pa, pb) = (pose2(0.0, 0.0, 0.6), pose2(14.0, 10.0, -2.4));
        let ticks: Vec<Tick> = (0..100)
            .map(|k| {
                let t_s = k as f64 * 0.1;
                let site: Vec<Point2<f64>> = crowd_at(t_s)
                    .iter()
                    .map(|[x, y]| Point2::new(*x, *y))
                    .collect();
                let mut b: Vec<Point2<f64>> = site.iter().map(|q| pb.inverse() * q).collect();
                b.rotate_left(k % 5);
                Tick {
                    t_s,
                    a: site.iter().map(|q| pa.inverse() * q).collect(),
                    b,
                }
            })
            .collect();
        let truth = pa.inverse() * pb;
        let hypotheses = path_hypotheses(&ticks, &WalkerParams::default());
        let near = hypotheses.iter().filter(|h| {
            let (dt, dyaw) = pose_error(h, &truth);
            dt < 0.05 && dyaw < 0.5f64.to_radians()
        });
        // Every person's path pairs with its own in the other sensor.
        assert!(near.count() >= 14, "{} hypotheses", hypotheses.len());
    }

    #[test]
    fn a_skewed_clock_is_found_from_the_walkers_within_20_ms() {
        let walls = polygon(&[(-1.0, -1.0), (-0.8, -1.0), (-0.8, -0.8), (-1.0, -0.8)]);
        let (pa, pb) = (pose2(0.0, 0.0, 0.6), pose2(14.0, 10.0, -2.4));
        let p = (WalkerParams::default(), MotionParams::default());
        let ta = track_on_clock(&walls, &pa, 10.0, 1_000_000_000);
        let tb = track_on_clock(&walls, &pb, 10.0, 1_230_000_000);
        // B reads 230 ms ahead of A, so A reads 230 ms behind B.
        for (x, y, ahead_s, truth) in [
            (&ta, &tb, 0.23, pa.inverse() * pb),
            (&tb, &ta, -0.23, pb.inverse() * pa),
        ] {
            let found = clock_offset(x, y, &p.0, &p.1, 0.5).expect("an offset");
            let error_s = (found.offset_s - ahead_s).abs();
            assert!(
                error_s <= 0.02,
                "{ahead_s} s: found {:.3} s",
                found.offset_s
            );
            let (dt, _) = pose_error(&found.fit.a_from_b, &truth);
            assert!(dt < 0.1, "{dt} m");
        }
        // Walkers nobody else saw give no offset.
        let alone = track_on_clock(&walls, &pose2(40.0, 40.0, 0.0), 10.0, 0);
        assert!(clock_offset(&ta, &alone, &p.0, &p.1, 0.5).is_none());
    }

    /// Open floor: the only structure is a short post near each sensor, out of the other's
    /// sight lines; they share nothing static, only the people. Two sensors' models over 20 s
    /// of `people_at`, built once for the tests that use them.
    fn no_wall_pair() -> &'static (
        Pose2,
        crate::register::ScanModel,
        crate::register::ScanModel,
    ) {
        static PAIR: std::sync::OnceLock<(
            Pose2,
            crate::register::ScanModel,
            crate::register::ScanModel,
        )> = std::sync::OnceLock::new();
        PAIR.get_or_init(|| {
            let mut walls = polygon(&[(-1.0, -1.0), (-0.8, -1.0), (-0.8, -0.8), (-1.0, -0.8)]);
            walls.extend(polygon(&[
                (15.0, 11.0),
                (15.2, 11.0),
                (15.2, 11.2),
                (15.0, 11.2),
            ]));
            let (pa, pb) = (pose2(0.0, 0.0, 0.6), pose2(14.0, 10.0, -2.4));
            (
                pa.inverse() * pb,
                model_with_people(&walls, &pa, 20.0),
                model_with_people(&walls, &pb, 20.0),
            )
        })
    }

    /// A sensor's registration model of `walls` from `pose`, with the people of `people_at`
    /// it saw over `seconds`.
    fn model_with_people(walls: &[Wall], pose: &Pose2, seconds: f64) -> crate::register::ScanModel {
        model_with(walls, pose, seconds, people_at)
    }

    /// As [`model_with_people`], the people where `people` puts them at each second.
    fn model_with(
        walls: &[Wall],
        pose: &Pose2,
        seconds: f64,
        people: fn(f64) -> Vec<[f64; 2]>,
    ) -> crate::register::ScanModel {
        let p = crate::register::RegisterParams::default();
        let frames = (seconds * 40.0) as u64;
        let scans: Vec<Scan> = (0..frames)
            .map(|k| scan(walls, &people(k as f64 / 40.0), pose, k * 25_000_000))
            .collect();
        let still = scan(walls, &[], pose, 0);
        crate::register::ScanModel::from_scan(&still, None, &Mount::default(), &p).with_motion(
            &scans,
            &still,
            None,
            &Mount::default(),
            &p,
        )
    }

    #[test]
    fn people_alone_fix_the_pose_of_two_sensors_that_share_no_wall() {
        let (truth, a, b) = no_wall_pair();
        let (ta, tb) = (a.motion.as_ref().unwrap(), b.motion.as_ref().unwrap());
        let p = WalkerParams::default();
        let fit = fit_walkers(ta, tb, &p, &MotionParams::default()).expect("a fit");
        let (dt, dyaw) = pose_error(&fit.a_from_b, truth);
        assert!(
            dt < 0.10 && dyaw.to_degrees() < 1.0,
            "{dt:.3} m {:.2}°: {fit:?}",
            dyaw.to_degrees()
        );
        assert!(fit.decisive(&p), "{fit:?}");
        let sigma_m = fit.covariance[(0, 0)].max(fit.covariance[(1, 1)]).sqrt();
        assert!(sigma_m < 0.1, "σ {sigma_m:.3} m");
    }

    #[test]
    fn a_rival_with_as_many_walks_stops_people_placing_a_pair_alone_unless_it_is_refuted() {
        use crate::register::pair::placed_by_walkers;
        let (truth, a, b) = no_wall_pair();
        let p = crate::register::RegisterParams::default();
        let fit = crate::register::register_pair(a, b, &p)
            .walkers
            .expect("the walkers' fit");
        let rivalled = |rival: Pose2| WalkerFit {
            runner_up_walks: fit.walks,
            rival: Some(rival),
            alone: false,
            torso_area_m2: None,
            ..fit.clone()
        };
        // A rival where the people walk as well (here the truth itself): nothing is placed.
        assert!(rivalled(*truth).has_rival(&p.walkers));
        assert!(placed_by_walkers(a, b, &rivalled(*truth), 0, &p).is_none());
        // One where the other sensor sees through the people it would lay over its view:
        // placed, at the fit.
        let far = truth * pose2(3.0, 1.0, 0.7);
        let placed = placed_by_walkers(a, b, &rivalled(far), 0, &p).expect("placed");
        let (dt, _) = pose_error(&placed.a_from_b, truth);
        assert!(dt < 0.10, "{dt:.3} m");
    }

    #[test]
    fn a_pair_that_shares_no_wall_is_placed_by_people_alone_and_says_so() {
        let (truth, a, b) = no_wall_pair();
        let p = crate::register::RegisterParams::default();
        let r = crate::register::register_pair(a, b, &p);
        assert!(r.registered(), "{:?}", r.verdict);
        let (dt, dyaw) = pose_error(&r.a_from_b, truth);
        assert!(
            dt < 0.10 && dyaw.to_degrees() < 1.0,
            "{dt:.3} m {:.2}°",
            dyaw.to_degrees()
        );
        let fit = r.walkers.as_ref().expect("the walkers' fit");
        assert!(fit.alone && fit.places_alone(&p.walkers), "{fit:?}");
        assert_eq!(evidence(r.walkers.as_ref()), "walkers");
        // Its σ includes the bias a body's shape and time leave, so the site weighs it as it is.
        assert!(r.covariance[(0, 0)].sqrt() >= fit.bias_m(&p.walkers));
        // The same walkers held to a stricter count than they reach: not placed alone, and
        // with no wall to place it, not registered.
        let strict = crate::register::RegisterParams {
            walkers: WalkerParams {
                alone_min_inliers: fit.inliers + 1,
                ..WalkerParams::default()
            },
            ..p.clone()
        };
        let r = crate::register::register_pair(a, b, &strict);
        assert!(!r.registered(), "placed: {:?}", r.walkers);
    }

    /// A fit past every `alone_*` count, with the covariance given.
    fn strong_fit(covariance: Matrix3<f64>) -> WalkerFit {
        WalkerFit {
            a_from_b: pose2(3.0, 1.0, 0.5),
            inliers: 400,
            span_s: 20.0,
            spread_m: 8.0,
            rms_m: 0.05,
            others: Vec::new(),
            walks: 40,
            runner_up_walks: 0,
            rival: None,
            covariance,
            alone: false,
            torso_area_m2: None,
        }
    }

    #[test]
    fn walkers_fix_where_along_a_corridor_the_walls_cannot() {
        // A 4 m corridor far longer than the units reach along it: its two walls fix the
        // heading and the distance across, nothing fixes the distance along.
        let walls = vec![
            Wall::new(-80.0, 0.0, 80.0, 0.0),
            Wall::new(-80.0, 4.0, 80.0, 4.0),
        ];
        let (pa, pb) = (pose2(0.0, 1.5, 0.05), pose2(7.0, 2.5, 3.1));
        let truth = pa.inverse() * pb;
        let p = crate::register::RegisterParams::default();
        let still = |pose: &Pose2| {
            crate::register::ScanModel::from_scan(
                &scan(&walls, &[], pose, 0),
                None,
                &Mount::default(),
                &p,
            )
        };
        let r = crate::register::register_pair(&still(&pa), &still(&pb), &p);
        assert!(
            matches!(
                r.verdict,
                Err(crate::register::pair::Abstain::Degenerate { .. })
            ),
            "walls alone: {:?}",
            r.verdict
        );
        // People walking up and down it between the two, on three lanes.
        fn lanes(t_s: f64) -> Vec<[f64; 2]> {
            let bounce = |from: f64, to: f64, period_s: f64, y: f64| {
                let s = (t_s / period_s).fract();
                let s = if s < 0.5 { 2.0 * s } else { 2.0 - 2.0 * s };
                [from + s * (to - from), y]
            };
            vec![
                bounce(1.5, 6.0, 7.0, 0.9),
                bounce(5.5, 1.0, 9.0, 2.1),
                bounce(2.0, 6.5, 11.0, 3.2),
            ]
        }
        let (a, b) = (
            model_with(&walls, &pa, 20.0, lanes),
            model_with(&walls, &pb, 20.0, lanes),
        );
        let r = crate::register::register_pair(&a, &b, &p);
        assert!(r.registered(), "{:?}", r.verdict);
        assert_eq!(evidence(r.walkers.as_ref()), "walls+walkers");
        let (dt, dyaw) = pose_error(&r.a_from_b, &truth);
        assert!(
            dt < 0.10 && dyaw.to_degrees() < 1.0,
            "{dt:.3} m {:.2}°",
            dyaw.to_degrees()
        );
        // Along the corridor the σ is the walkers' (theirs and their bias), not the walls',
        // and the candidate the site weighs has it once, not twice.
        assert_eq!(r.candidates[0].covariance, r.covariance);
        let (sigma_m, _) = crate::register::pair::pose_sigmas(&r.covariance);
        assert!(sigma_m < p.max_sigma_m, "σ {sigma_m:.3} m");
        assert!(
            sigma_m >= 0.5 * p.walkers.measured_bias_m,
            "σ {sigma_m:.3} m"
        );
    }

    #[test]
    fn a_walk_is_one_person_followed_in_both_views_and_a_crossing_or_a_queue_is_none() {
        let mut pairs: Matched = Vec::new();
        let at = |x: f64, y: f64| Point2::new(x, y);
        for k in 0..120 {
            let t = k as f64 / 40.0;
            // One person walking 1.3 m/s for 3 s, lost for half a second in the middle.
            if !(50..70).contains(&k) {
                pairs.push((at(1.3 * t, 0.0), at(5.0, 1.3 * t), t));
            }
            // Someone standing in a queue, in both views, all along.
            pairs.push((at(8.0, 8.0), at(-3.0, 2.0), t));
            // Crossings: a different spot every tick (people laid over each other a moment).
            let (ka, kb) = ((k % 7) as f64, (k % 3) as f64);
            let (ja, jb) = ((k % 5) as f64, (k % 4) as f64);
            pairs.push((
                at(20.0 + 3.0 * ka, 4.0 * ja),
                at(-20.0 - 3.0 * kb, 4.0 * jb),
                t,
            ));
        }
        let together = walked_together(&pairs);
        assert_eq!(together.walks, 1, "{together:?}");
        assert_eq!(together.sightings, 100, "{together:?}");
        // A walk shorter than a second is no walk.
        let brief: Matched = pairs.iter().filter(|x| x.2 < 0.9).copied().collect();
        assert_eq!(walked_together(&brief).walks, 0);
    }

    #[test]
    fn a_runner_up_of_many_sightings_but_one_walk_does_not_block_placing_alone() {
        let p = WalkerParams::default();
        let plain = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-6));
        // A crowd: the rival pose collects 40 % as many sightings as the right one, all of
        // them from one walk congruent with another by chance.
        let crowd = WalkerFit {
            others: vec![(160, pose2(-4.0, 2.0, 1.0))],
            runner_up_walks: 1,
            rival: None,
            walks: 12,
            ..strong_fit(plain)
        };
        assert!(crowd.runner_up() as f64 > p.alone_max_ambiguity * crowd.inliers as f64);
        assert!(crowd.places_alone(&p) && crowd.decisive(&p), "{crowd:?}");
        // Four people walking as the rival says are a rival.
        let rival = WalkerFit {
            runner_up_walks: 4,
            rival: None,
            ..crowd.clone()
        };
        assert!(!rival.places_alone(&p), "{rival:?}");
        // The same against a best of few walks.
        let few = WalkerFit { walks: 3, ..crowd };
        assert!(!few.places_alone(&p), "{few:?}");
    }

    #[test]
    fn a_runner_up_that_is_ruled_out_leaves_the_next_one_as_the_rival() {
        let p = WalkerParams::default();
        let plain = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-6));
        // Along a corridor: a pose turned 9° agrees with 63 % as many sightings, another far
        // off with 30 %.
        let (turned, far) = (pose2(3.2, 1.1, 0.66), pose2(-20.0, 4.0, 3.0));
        let fit = WalkerFit {
            inliers: 250,
            others: vec![(158, turned), (75, far)],
            ..strong_fit(plain)
        };
        assert!(!fit.decisive(&p), "{fit:?}");
        let ruled_out = fit.clone().without(|q| *q == turned);
        assert_eq!(ruled_out.runner_up(), 75);
        assert!(ruled_out.decisive(&p), "{ruled_out:?}");
        // Ruling out one that is not the runner-up changes nothing.
        let same = fit.without(|q| *q == far);
        assert_eq!(same.runner_up(), 158);
        assert!(!same.decisive(&p), "{same:?}");
    }

    #[test]
    fn a_corridor_seen_from_both_ends_places_alone_by_the_residual_any_deciding_fit_may_have() {
        let p = WalkerParams::default();
        let plain = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-6));
        // Fronts to one unit, backs to the other: a residual of 10-11 cm with σ 1 cm (as
        // corridor-cross's west arm, 1 cm from the truth) places the pair ...
        let both_ends = WalkerFit {
            rms_m: 0.11,
            ..strong_fit(plain)
        };
        assert!(both_ends.places_alone(&p), "{both_ends:?}");
        // ... where a residual past a deciding fit's own does not even decide.
        let loose = WalkerFit {
            rms_m: p.max_rms_m + 0.01,
            ..both_ends
        };
        assert!(!loose.decisive(&p) && !loose.places_alone(&p), "{loose:?}");
    }

    #[test]
    fn a_fit_places_alone_by_its_worst_direction_not_its_axes() {
        let p = WalkerParams::default();
        let s2 = (0.8 * p.alone_max_sigma_m).powi(2);
        let yaw2 = (0.5 * p.alone_max_sigma_rad).powi(2);
        let plain = Matrix3::from_diagonal(&nalgebra::Vector3::new(s2, s2, yaw2));
        assert!(strong_fit(plain).places_alone(&p));
        // The same σ along x and y, correlated 0.9: along the diagonal 1.1× the limit.
        let mut tilted = plain;
        tilted[(0, 1)] = 0.9 * s2;
        tilted[(1, 0)] = 0.9 * s2;
        assert!(!strong_fit(tilted).places_alone(&p));
    }

    #[test]
    fn walkers_disagree_only_beyond_their_basin_widened_by_their_own_sigma() {
        let p = WalkerParams::default();
        // A fit whose heading is known to 1.5° (a few seconds of walkers).
        let loose = Matrix3::from_diagonal(&nalgebra::Vector3::new(
            0.03f64.powi(2),
            0.03f64.powi(2),
            1.5f64.to_radians().powi(2),
        ));
        let fit = strong_fit(loose);
        let turned = |deg: f64| fit.a_from_b * pose2(0.0, 0.0, deg.to_radians());
        // 5° off: out of the basin (3°) the walkers choose in, within what they can tell.
        assert!(!fit.near(&turned(5.0), &p) && fit.agrees(&turned(5.0), &p));
        // 8°: beyond 3° + 3σ, they contradict it.
        assert!(!fit.agrees(&turned(8.0), &p));
        // A tight fit contradicts the 5° pose.
        let tight = Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-6));
        assert!(!strong_fit(tight).agrees(&turned(5.0), &p));
        // Position: 0.3 m + 3 × 3 cm.
        let moved = fit.a_from_b * pose2(0.35, 0.0, 0.0);
        assert!(fit.agrees(&moved, &p) && !fit.near(&moved, &p));
        assert!(!fit.agrees(&(fit.a_from_b * pose2(0.45, 0.0, 0.0)), &p));
    }

    #[test]
    fn the_walls_refined_from_the_walkers_pose_replace_a_candidate_that_stopped_short() {
        use crate::register::pair::{Candidate, propose_from_walkers};
        use crate::register::score::score;
        // A 12 × 8 m room with a pillar and a box both sensors see; people walk through it.
        let mut walls = polygon(&[(-1.0, -1.0), (14.0, -1.0), (14.0, 11.0), (-1.0, 11.0)]);
        walls.extend(polygon(&[(5.0, 5.0), (5.4, 5.0), (5.4, 5.4), (5.0, 5.4)]));
        walls.extend(polygon(&[(9.0, 1.0), (11.0, 1.0), (11.0, 1.6), (9.0, 1.6)]));
        let (pa, pb) = (pose2(0.0, 0.0, 0.6), pose2(13.0, 10.0, -2.4));
        let (a, b) = (
            model_with_people(&walls, &pa, 3.0),
            model_with_people(&walls, &pb, 3.0),
        );
        let truth = pa.inverse() * pb;
        let p = crate::register::RegisterParams::default();
        // The walls' candidate in the walkers' basin, 0.2 m off the truth.
        let short = truth * pose2(0.2, 0.0, 0.0);
        let candidate = Candidate {
            a_from_b: short,
            score: score(&a, &b, &short, &p),
            covariance: Matrix3::zeros(),
        };
        let icp = crate::register::icp::IcpResult {
            a_from_b: short,
            iterations: 1,
            hessian: Matrix3::identity(),
            rms_m: 0.05,
            correspondences: 100,
        };
        let (ma, mb) = (a.motion.as_ref().unwrap(), b.motion.as_ref().unwrap());
        let mut distinct = vec![(candidate, icp)];
        let mut evidence = vec![co_motion(ma, mb, &short, &p.motion)];
        let fit = WalkerFit {
            a_from_b: truth * pose2(0.05, -0.05, 0.01),
            ..strong_fit(Matrix3::identity() * 1e-4)
        };
        assert!(fit.near(&short, &p.walkers));
        propose_from_walkers(&a, &b, &fit, &mut distinct, &mut evidence, &p);
        assert_eq!((distinct.len(), evidence.len()), (1, 1));
        let (dt, dyaw) = pose_error(&distinct[0].0.a_from_b, &truth);
        assert!(
            dt < 0.05 && dyaw.to_degrees() < 0.5,
            "{dt:.3} m {:.2}°",
            dyaw.to_degrees()
        );
        assert!(distinct[0].0.score.value > score(&a, &b, &short, &p).value);
    }

    /// A rival refined from a subset of the best's own walkers (a pose a degree or two off,
    /// as a corridor's far walkers leave) has no walks of its own; one that lays other
    /// sightings over each other (a mirror image) keeps its walks.
    #[test]
    fn a_rival_walks_only_where_the_best_does_not() {
        let best = pose2(4.0, -1.0, 0.7);
        // One person walking 5 m along x at 1 m/s, seen by both at 10 Hz.
        let walk = |at: &dyn Fn(f64) -> Point2<f64>, b_of: &dyn Fn(Point2<f64>) -> Point2<f64>| {
            (0..50)
                .map(|k| {
                    let t = k as f64 * 0.1;
                    let a = at(t);
                    (a, b_of(a), t)
                })
                .collect::<Vec<_>>()
        };
        let along = |t: f64| Point2::new(t, 0.0);
        let same = walk(&along, &|a| best.inverse() * a);
        assert!(walked_together(&same).walks >= 1);
        assert_eq!(rival_walks(&best, &same, 0.25), 0);
        // The B sightings of another person: the best puts them 3 m off.
        let mirror = walk(&along, &|a| {
            best.inverse() * (a + nalgebra::Vector2::new(0.0, 3.0))
        });
        assert_eq!(
            rival_walks(&best, &mirror, 0.25),
            walked_together(&mirror).walks
        );
        assert!(rival_walks(&best, &mirror, 0.25) >= 1);
    }

    #[test]
    fn without_people_in_common_there_is_no_fit_or_no_decision() {
        let walls = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 5.0), (0.0, 5.0)]);
        // b looks away from everyone, into a corner.
        let (pa, pb) = (pose2(1.0, 1.0, 0.3), pose2(7.9, 4.9, 0.8));
        let (ta, tb) = (track(&walls, &pa, 5.0), track(&walls, &pb, 5.0));
        let p = WalkerParams::default();
        let fit = fit_walkers(&ta, &tb, &p, &MotionParams::default());
        assert!(fit.as_ref().is_none_or(|f| !f.decisive(&p)), "{fit:?}");
    }
}
