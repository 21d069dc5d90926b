//! The site solve's tests: stages on crafted scenes (a half-turn-symmetric hall, corridors).

use super::check::{certain_only, contradicts};
use super::join::{JoinContext, Refusal};
use super::second_opinion::second_opinion;
use super::*;
use crate::geometry::pose2;

fn edge(a: usize, b: usize, truth: &[Pose2], bias: Pose2) -> Edge {
    Edge {
        a,
        b,
        a_from_b: bias * truth[a].inverse() * truth[b],
        covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(1e-4, 1e-4, 1e-5)),
        strength: 1.0,
    }
}

#[test]
fn one_wrong_edge_is_dropped_and_the_rest_solve_to_truth() {
    let truth = [
        pose2(0.0, 0.0, 0.0),
        pose2(5.0, 1.0, 0.5),
        pose2(3.0, 6.0, -1.0),
        pose2(-4.0, 2.0, 2.0),
        pose2(1.0, -5.0, 3.0),
    ];
    let mut edges = Vec::new();
    for a in 0..5 {
        for b in a + 1..5 {
            // Small, different errors on every good edge; one edge is a metre and 20° off.
            let bias = if (a, b) == (1, 3) {
                pose2(1.0, -0.5, 0.35)
            } else {
                pose2(
                    0.004 * (a as f64 - b as f64),
                    0.003 * a as f64,
                    0.001 * b as f64,
                )
            };
            edges.push(edge(a, b, &truth, bias));
        }
    }
    let sp = SiteParams::default();
    let kept = consistent_edges(5, 0, &edges, &sp);
    assert_eq!(kept.len(), 9);
    assert!(kept.iter().all(|&k| (edges[k].a, edges[k].b) != (1, 3)));
    let kept_edges: Vec<Edge> = kept.iter().map(|&k| edges[k].clone()).collect();
    let sensors: Vec<SensorInput> = Vec::new();
    let solution = solve(5, 0, &kept_edges, &priors_of(&sensors), &sp);
    for (i, t) in truth.iter().enumerate() {
        let Some((pose, sigma)) = solution[i] else {
            panic!("sensor {i} unplaced")
        };
        let (dt, dyaw) = pose_error(&pose, t);
        assert!(dt < 0.03 && dyaw < 0.005, "sensor {i}: {dt} m {dyaw} rad");
        if i != 0 {
            assert!(
                sigma[0] > 0.0 && sigma[0] < 0.05 && sigma[2] > 0.0,
                "sigma {sigma:?}"
            );
        }
    }
}

/// A ring of sensors the anchor has no edge to (it joins them later, as one group): a wrong
/// edge on the ring closes no triangle, only the long cycle, and must still be dropped, as it
/// is when the anchor is on the ring. (On a 120-scanner concourse one such edge to a
/// look-alike bay 112 m away placed a sensor there: the anchor's tree checked nothing.)
#[test]
fn a_wrong_edge_on_a_cycle_away_from_the_anchor_is_dropped() {
    // 0 the anchor, far away; 1..=6 a ring 4 m apart along a concourse.
    let truth: Vec<Pose2> = std::iter::once(pose2(-50.0, 0.0, 0.0))
        .chain((0..6).map(|k| pose2(4.0 * k as f64, 3.0 * (k % 2) as f64, 0.1 * k as f64)))
        .collect();
    let ring = [(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (1, 6)];
    let edges: Vec<Edge> = ring
        .iter()
        .map(|&(a, b)| {
            // The closing edge puts 6 a period of the floor (8 m) off, and is the weakest.
            let wrong = (a, b) == (1, 6);
            let bias = if wrong {
                pose2(8.0, 0.0, 0.0)
            } else {
                Pose2::identity()
            };
            Edge {
                strength: if wrong { 0.5 } else { 1.0 },
                ..edge(a, b, &truth, bias)
            }
        })
        .collect();
    let sp = SiteParams::default();
    for anchor in [0, 1] {
        let kept = consistent_edges(7, anchor, &edges, &sp);
        let wrong = kept.iter().any(|&k| (edges[k].a, edges[k].b) == (1, 6));
        assert!(!wrong, "anchor {anchor}: the wrong edge is kept ({kept:?})");
    }
}

/// Three sensors' true poses, for the survey tests.
fn three_truths() -> [Pose2; 3] {
    [
        pose2(0.0, 0.0, 0.0),
        pose2(5.0, 1.0, 0.5),
        pose2(3.0, 6.0, -1.0),
    ]
}

/// Sensor `s{i}` with no scan (the solve and its checks see only edges and priors).
fn blank_input(i: usize, prior: Option<Prior>) -> SensorInput {
    SensorInput {
        id: format!("s{i}"),
        mount: crate::geometry::Mount::default(),
        model: ScanModel::new(&[], 0.25f64.to_radians(), &RegisterParams::default()),
        prior,
    }
}

#[test]
fn surveyed_priors_place_an_unreached_sensor_and_weigh_against_edges() {
    let truth = three_truths();
    let input = blank_input;
    // Sensor 1: its edge (σ² 1e-4 plus the 1 cm floor: 2e-4) and a survey 20 cm off along
    // x (σ² 1e-4) meet at the weighted mean, 2/3 of the way to the survey. Sensor 2: no
    // edge, only a survey; it stands where surveyed, with the survey's σ.
    let sensors = [
        input(0, None),
        input(
            1,
            Some(Prior::new(pose2(0.2, 0.0, 0.0) * truth[1], 0.01, 0.01)),
        ),
        input(2, Some(Prior::new(truth[2], 0.05, 0.02))),
    ];
    let edges = vec![edge(0, 1, &truth, Pose2::identity())];
    let solution = solve(3, 0, &edges, &priors_of(&sensors), &SiteParams::default());
    let (one, _) = solution[1].expect("sensor 1 placed");
    let (dx, dy) = (
        one.translation.x - truth[1].translation.x,
        one.translation.y - truth[1].translation.y,
    );
    assert!(
        (dx - 0.2 * 2.0 / 3.0).abs() < 0.01 && dy.abs() < 0.01,
        "weighted mean expected: {dx} {dy}"
    );
    let (two, sigma) = solution[2].expect("sensor 2 placed by its survey");
    let (dt, dyaw) = pose_error(&two, &truth[2]);
    assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
    assert!((sigma[0] - 0.05).abs() < 0.01, "σx {}", sigma[0]);
}

#[test]
fn a_survey_metres_off_the_scans_stands_alone_and_does_not_carry_the_others() {
    let truth = three_truths();
    let input = blank_input;
    // Sensor 2 dragged 2.5 m from where the scans place it, with a drag's σ (5 cm, 2°).
    let dragged = pose2(2.0, -1.5, 0.0) * truth[2];
    let sensors = [
        input(0, None),
        input(1, None),
        input(2, Some(Prior::new(dragged, 0.05, 2f64.to_radians()))),
    ];
    let edges = vec![
        edge(0, 1, &truth, Pose2::identity()),
        edge(1, 2, &truth, Pose2::identity()),
        edge(0, 2, &truth, Pose2::identity()),
    ];
    let origin = vec![(0, 0), (1, 0), (2, 0)];
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let solved = check::solve_without_conflicts(3, 0, edges.clone(), origin, &sensors, &p, &sp);
    let (one, _) = solved.solution[1].expect("sensor 1 placed");
    let (dt, dyaw) = pose_error(&one, &truth[1]);
    assert!(
        dt < 0.005 && dyaw < 0.001,
        "sensor 1 carried {dt} m {dyaw} rad"
    );
    let (two, _) = solved.solution[2].expect("sensor 2 where surveyed");
    assert!(pose_error(&two, &dragged).0 < 1e-6);
    let (apart, _) = solved.survey_conflicts[2].expect("the conflict named");
    assert!((apart - 2.5).abs() < 0.05, "{apart}");
    assert!(solved.survey_conflicts[1].is_none());
    // 20 cm off is weighed against the scans, as before (the surveyed test above).
    let near = [
        input(0, None),
        input(1, None),
        input(
            2,
            Some(Prior::new(pose2(0.2, 0.0, 0.0) * truth[2], 0.05, 0.02)),
        ),
    ];
    let solved = check::solve_without_conflicts(3, 0, edges, vec![(0, 0); 3], &near, &p, &sp);
    assert!(solved.survey_conflicts.iter().all(Option::is_none));
}

use crate::geometry::raycast::{Wall, cast, polygon};
use crate::geometry::{ScanPoint, pose_error};
use crate::register::Candidate;

/// A 12 × 6 m hall, symmetric under a half turn about its centre but for one 1.5 × 1.5 m
/// block in its north-west; the block's mirror image would stand in empty floor.
fn hall() -> Vec<Wall> {
    let mut walls = polygon(&[(-6.0, -3.0), (6.0, -3.0), (6.0, 3.0), (-6.0, 3.0)]);
    walls.extend(polygon(&[
        (-5.5, 1.0),
        (-4.0, 1.0),
        (-4.0, 2.5),
        (-5.5, 2.5),
    ]));
    walls
}

/// The scan of a sensor at `site_from_sensor` over `fov_rad` centred ahead, 0.5° steps.
pub(crate) fn sensor_at(
    walls: &[Wall],
    site_from_sensor: Pose2,
    fov_rad: f64,
    id: &str,
) -> SensorInput {
    let step = 0.5f64.to_radians();
    sensor_within(walls, site_from_sensor, fov_rad, step, f64::INFINITY, id)
}

/// A 270° sensor `s{i}` of `walls` at each of `truth`.
fn sensors_at(walls: &[Wall], truth: &[Pose2]) -> Vec<SensorInput> {
    truth
        .iter()
        .enumerate()
        .map(|(i, pose)| sensor_at(walls, *pose, 270f64.to_radians(), &format!("s{i}")))
        .collect()
}

/// `sensor_at` with beams `step` apart and returns only within `range_m`.
fn sensor_within(
    walls: &[Wall],
    site_from_sensor: Pose2,
    fov_rad: f64,
    step: f64,
    range_m: f64,
    id: &str,
) -> SensorInput {
    let beams = (fov_rad / step) as usize;
    let points: Vec<ScanPoint> = (0..beams)
        .filter_map(|k| {
            let angle = -fov_rad / 2.0 + step * k as f64;
            let dir_site =
                site_from_sensor.rotation * nalgebra::Vector2::new(angle.cos(), angle.sin());
            let origin = nalgebra::Point2::from(site_from_sensor.translation.vector);
            let range = cast(walls, origin, dir_site).filter(|r| *r <= range_m)?;
            Some(ScanPoint {
                p: nalgebra::Point2::new(range * angle.cos(), range * angle.sin()),
                beam: k,
                z_m: None,
            })
        })
        .collect();
    SensorInput {
        id: id.to_string(),
        model: ScanModel::new(&points, step, &RegisterParams::default()),
        mount: crate::geometry::Mount::default(),
        prior: None,
    }
}

#[test]
fn a_surveyed_sensor_out_of_reach_places_the_sensors_registered_to_it() {
    // Two rooms 40 m apart that share no view: s0 and s1 in the hall, s2 and s3 in an
    // L-shaped room with a pillar. Only s2 is surveyed; s3 registers with s2 alone.
    let mut room = polygon(&[
        (40.0, 0.0),
        (52.0, 0.0),
        (52.0, 5.0),
        (46.0, 5.0),
        (46.0, 10.0),
        (40.0, 10.0),
    ]);
    room.extend(polygon(&[
        (43.0, 3.0),
        (43.6, 3.0),
        (43.6, 3.6),
        (43.0, 3.6),
    ]));
    let walls: Vec<Wall> = hall().into_iter().chain(room).collect();
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(1.0, -2.0, 2.6),
        pose2(41.0, 1.5, 0.6),
        pose2(50.0, 3.5, 2.9),
    ];
    let fov = 270f64.to_radians();
    let mut sensors: Vec<SensorInput> = truth
        .iter()
        .enumerate()
        .map(|(i, t)| sensor_at(&walls, *t, fov, &format!("s{i}")))
        .collect();
    sensors[2].prior = Some(Prior::new(truth[0].inverse() * truth[2], 0.02, 0.01));
    let site = register_site(
        &sensors,
        0,
        &RegisterParams::default(),
        &SiteParams::default(),
    );
    for k in 1..4 {
        let placed = site.sensors[k].pose.as_ref();
        let pose = placed.unwrap_or_else(|why| panic!("s{k} not placed: {why}"));
        let (dt, dyaw) = pose_error(&pose.pose.planar(), &(truth[0].inverse() * truth[k]));
        assert!(
            dt < 0.05 && dyaw < 0.5f64.to_radians(),
            "s{k} off by {dt} m {} deg",
            dyaw.to_degrees()
        );
    }
    // s1 and s3 each rest on one pair: the caveat says so and names the other end. The
    // anchor and the surveyed s2 have none.
    let caveat = |k: usize| site.sensors[k].caveat.clone();
    for (k, with) in [(1, "s0"), (3, "s2")] {
        let c = caveat(k).unwrap_or_else(|| panic!("s{k} rests on one pair, no caveat"));
        assert!(c.contains("one pair") && c.contains(with), "s{k}: {c}");
    }
    assert_eq!((caveat(0), caveat(2)), (None, None));
}

/// A pair that could not decide between `poses` (best first): each is a candidate, scored
/// honestly against the two scans.
fn undecided_pair(a: &SensorInput, b: &SensorInput, poses: &[Pose2]) -> PairResult {
    let p = RegisterParams::default();
    let candidates: Vec<Candidate> = poses
        .iter()
        .map(|pose| Candidate {
            a_from_b: *pose,
            score: crate::register::score::score(&a.model, &b.model, pose, &p),
            covariance: Matrix3::identity() * 1e-4,
        })
        .collect();
    let best = candidates.first().cloned().unwrap_or(Candidate {
        a_from_b: Pose2::identity(),
        score: Default::default(),
        covariance: Matrix3::identity() * 1e-4,
    });
    PairResult {
        verdict: Err(crate::register::Abstain::Ambiguous {
            ratio: 0.9,
            other: Pose2::identity(),
        }),
        a_from_b: best.a_from_b,
        covariance: Matrix3::identity() * 1e-4,
        match_score: 0.5,
        ambiguity: 0.9,
        overlap: best.score.overlap(),
        score: best.score,
        candidates,
        hypotheses: poses.len(),
        icp_iterations: 0,
        motion: None,
        walkers: None,
        nobody_walked_s: None,
    }
}

/// s0 and s1 look only at symmetric corners of the hall, so each of their pairs with s3
/// fits s3's true pose and its half-turn mirror image equally well, and both pairs put the
/// mirror first: two neighbours agreeing on the wrong pose. The group to join is s3 alone.
struct MirrorScene {
    sensors: Vec<SensorInput>,
    pairs: Vec<(usize, usize)>,
    results: Vec<PairResult>,
    truth: Vec<Pose2>,
    mirror_of_s3: Pose2,
}

/// A join context in which the scene's first `count` sensors stand at their true poses.
fn truth_placed<'a>(
    scene: &'a MirrorScene,
    count: usize,
    p: &'a RegisterParams,
    sp: &'a SiteParams,
) -> JoinContext<'a> {
    JoinContext {
        sensors: &scene.sensors,
        placed: (0..count)
            .map(|i| (i, scene.truth[0].inverse() * scene.truth[i]))
            .collect(),
        pairs: &scene.pairs,
        results: &scene.results,
        p,
        sp,
        reach_m: &[],
        memo: None,
    }
}

fn mirror_scene() -> MirrorScene {
    let walls = hall();
    let half_turn = pose2(0.0, 0.0, std::f64::consts::PI);
    // s0 sees only the hall's north-east, s1 (its half-turn image) only its south-west;
    // s3 sees all of the hall but the block's shadow; s2 looks at the block.
    let truth = vec![
        pose2(0.0, 2.0, 45f64.to_radians()),
        half_turn * pose2(0.0, 2.0, 45f64.to_radians()),
        pose2(-2.0, 2.5, 195f64.to_radians()),
        pose2(-2.0, -0.5, 0.3),
    ];
    let fov_deg = [120.0, 120.0, 60.0, 360.0];
    let sensors: Vec<SensorInput> = truth
        .iter()
        .zip(fov_deg)
        .enumerate()
        .map(|(i, (pose, fov))| sensor_at(&walls, *pose, f64::to_radians(fov), &format!("s{i}")))
        .collect();
    let mirror_of_s3 = half_turn * truth[3];
    let pairs = vec![(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    let results = pairs
        .iter()
        .map(|&(a, b)| {
            let poses = if b == 3 && a != 2 {
                let site_from_a = truth[a];
                vec![
                    site_from_a.inverse() * mirror_of_s3,
                    site_from_a.inverse() * truth[3],
                ]
            } else {
                Vec::new()
            };
            undecided_pair(&sensors[a], &sensors[b], &poses)
        })
        .collect();
    MirrorScene {
        sensors,
        pairs,
        results,
        truth,
        mirror_of_s3,
    }
}

#[test]
fn a_mirror_image_two_neighbours_agree_on_is_refused_by_a_third_sensors_free_space() {
    let scene = mirror_scene();
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    // The premise: on their own, s0 and s1 cannot tell the mirror image from the truth.
    for pair in [2, 4] {
        let c = &scene.results[pair].candidates;
        let (mirror, truth) = (&c[0].score, &c[1].score);
        assert!(
            mirror.violation() <= p.max_violation && truth.violation() <= p.max_violation,
            "pair {pair}: both fit"
        );
        assert!(
            mirror.value >= 0.9 * truth.value,
            "pair {pair}: mirror {} vs truth {}",
            mirror.value,
            truth.value
        );
    }
    let ctx = truth_placed(&scene, 3, &p, &sp);
    let s3 = [(3, Pose2::identity())];
    // The mirror image puts s3's view of the pillar in the floor s2 sees empty.
    let at_mirror = ctx.joint(&s3, &(scene.truth[0].inverse() * scene.mirror_of_s3));
    assert!(
        at_mirror.violation > p.max_violation && at_mirror.worst == 2,
        "mirror violation {} against s{}",
        at_mirror.violation,
        at_mirror.worst
    );
    let join = ctx
        .weigh(&s3)
        .expect("the true pose is the one placement left");
    assert!(ctx.slides(&s3, &join).is_none());
    let (dt, dyaw) = pose_error(
        &join.anchor_from_root,
        &(scene.truth[0].inverse() * scene.truth[3]),
    );
    assert!(
        dt < 0.01 && dyaw < 0.001,
        "placed {dt} m {dyaw} rad from the truth"
    );
}

#[test]
fn a_second_opinion_moves_a_sensor_placed_at_a_mirror_image_to_where_the_rest_fit() {
    let scene = mirror_scene();
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let rel = |i: usize| scene.truth[0].inverse() * scene.truth[i];
    let near = |x: &Option<Pose2>, y: &Pose2| {
        let (dt, dyaw) = pose_error(&x.expect("placed"), y);
        dt < 0.01 && dyaw < 0.001
    };
    let opinion = |placed: &mut [Option<Pose2>], anchor: usize| {
        let (sensors, pairs, results) = (&scene.sensors, &scene.pairs, &scene.results);
        let memo = super::memo::ScoreMemo::default();
        second_opinion(placed, anchor, sensors, pairs, results, &p, &sp, &memo);
    };
    // s3 placed at its mirror image (as two agreeing wrong edges would put it): s2's free
    // space rules that out, and s0's and s1's pairs also propose the truth.
    let mut placed = vec![
        Some(rel(0)),
        Some(rel(1)),
        Some(rel(2)),
        Some(scene.truth[0].inverse() * scene.mirror_of_s3),
    ];
    opinion(&mut placed, 0);
    for (i, pose) in placed.iter().enumerate() {
        assert!(near(pose, &rel(i)), "s{i} at {pose:?}");
    }
    // The same with s3 as the anchor: the others were placed in its mirrored frame, and
    // they move instead.
    let m = scene.mirror_of_s3;
    let mut placed: Vec<Option<Pose2>> = (0..3)
        .map(|i| Some(m.inverse() * scene.truth[i]))
        .chain([Some(Pose2::identity())])
        .collect();
    opinion(&mut placed, 3);
    for (i, pose) in placed.iter().enumerate() {
        let truth = scene.truth[3].inverse() * scene.truth[i];
        assert!(near(pose, &truth), "s{i} at {pose:?}");
    }
}

#[test]
fn without_the_third_sensor_the_mirror_image_is_reported_not_placed() {
    let scene = mirror_scene();
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let ctx = truth_placed(&scene, 2, &p, &sp);
    let refusal = ctx.weigh(&[(3, Pose2::identity())]).err();
    let Some(Refusal::Ambiguous {
        ratio, apart_deg, ..
    }) = refusal
    else {
        panic!("expected two placements fitting equally, got {refusal:?}");
    };
    assert!(
        ratio > 0.9 && (apart_deg - 180.0).abs() < 1.0,
        "{ratio} {apart_deg}"
    );
    let why = Refusal::Ambiguous {
        ratio,
        apart_m: 9.0,
        apart_deg,
    }
    .describe(&|i| ["s0", "s1", "s2", "s3"][i]);
    assert!(
        why.contains("mirror image") && why.contains("survey it"),
        "{why}"
    );
}

/// Two 270° sensors in `walls` at `truth` (site frame) and their pair, whose only
/// candidate is the true pose (verdict: undecided).
struct TwoSensors {
    sensors: Vec<SensorInput>,
    pair: PairResult,
}

fn two_in(walls: &[Wall], truth: [Pose2; 2]) -> TwoSensors {
    let sensors = sensors_at(walls, &truth);
    let pair = undecided_pair(&sensors[0], &sensors[1], &[truth[0].inverse() * truth[1]]);
    TwoSensors { sensors, pair }
}

impl TwoSensors {
    /// `f` on a join context in which s0 is placed at the origin.
    fn context<T>(
        &self,
        p: &RegisterParams,
        sp: &SiteParams,
        f: impl FnOnce(&JoinContext<'_>) -> T,
    ) -> T {
        let (pairs, results) = ([(0, 1)], [self.pair.clone()]);
        f(&JoinContext {
            sensors: &self.sensors,
            placed: vec![(0, Pose2::identity())],
            pairs: &pairs,
            results: &results,
            p,
            sp,
            reach_m: &[],
            memo: None,
        })
    }
}

#[test]
fn a_sensor_one_placed_sensor_sees_stands_only_where_that_pair_alone_would_put_it() {
    let two = two_in(&hall(), [pose2(-1.0, 0.0, 0.0), pose2(1.5, 0.5, 0.3)]);
    let truth = two.pair.a_from_b;
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let weigh = |verdict: Result<(), crate::register::Abstain>| {
        let with = TwoSensors {
            pair: PairResult {
                verdict,
                ..two.pair.clone()
            },
            sensors: two.sensors.clone(),
        };
        with.context(&p, &sp, |ctx| ctx.weigh(&[(1, Pose2::identity())]))
    };
    // Registered alone: placed where the pair puts it.
    let join = weigh(Ok(())).expect("a registered pair places its sensor");
    let (dt, dyaw) = pose_error(&join.anchor_from_root, &truth);
    assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
    // Not registered alone (its σ too wide): nothing else checks it, so the pair's own
    // reason is the refusal, naming the one placed sensor that sees it.
    let uncertain = crate::register::Abstain::Uncertain {
        sigma_m: 0.2,
        sigma_yaw_deg: 0.1,
    };
    let refusal = weigh(Err(uncertain)).err();
    let Some(Refusal::LonePair { with: 0, why }) = &refusal else {
        panic!("expected the lone pair's refusal, got {refusal:?}");
    };
    assert!(why.contains("too uncertain"), "{why}");
    let said = refusal.map(|r| r.describe(&|k| ["s0", "s1"][k]));
    assert!(said.is_some_and(|s| s.contains("only s0")));
}

/// `group` weighed for a join with s0 placed at `s0` and `pair` (s0–s1) the only pair.
fn weigh_through(
    sensors: &[SensorInput],
    s0: Pose2,
    pair: PairResult,
    group: &[(usize, Pose2)],
    p: &RegisterParams,
    sp: &SiteParams,
) -> Result<super::join::Join, Refusal> {
    let (pairs, results) = ([(0, 1)], [pair]);
    JoinContext {
        sensors,
        placed: vec![(0, s0)],
        pairs: &pairs,
        results: &results,
        p,
        sp,
        reach_m: &[],
        memo: None,
    }
    .weigh(group)
}

/// A group of two (s1 in the hall, s2 in a room 40 m off) that only s0 sees, through one
/// pair: people walking without confirming that pair leave the group unplaced as they would
/// the pair, while a walls reason the group's own joint score weighs again does not.
#[test]
fn a_group_one_unconfirmed_pair_witnesses_is_not_joined() {
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(2.0, 0.5, 2.8),
        pose2(45.0, 2.5, 0.0),
    ];
    let sensors = in_hall_and_far_room(&truth);
    let group = [(1, Pose2::identity()), (2, truth[1].inverse() * truth[2])];
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let weigh = |verdict: Result<(), crate::register::Abstain>| {
        let pair = PairResult {
            verdict,
            ..undecided_pair(&sensors[0], &sensors[1], &[truth[0].inverse() * truth[1]])
        };
        weigh_through(&sensors, truth[0], pair, &group, &p, &sp)
    };
    let join = weigh(Ok(())).expect("a registered pair joins its group");
    let (dt, dyaw) = pose_error(&join.anchor_from_root, &truth[1]);
    assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
    assert_eq!(join.score.witnesses, [(0, 1)], "s2 shares nothing with s0");
    let refusal = weigh(Err(crate::register::Abstain::Unconfirmed {
        watched_s: 30.0,
    }))
    .err();
    let Some(Refusal::LonePair { with: 0, why }) = &refusal else {
        panic!("expected the lone pair's refusal, got {refusal:?}");
    };
    assert!(why.contains("not confirmed"), "{why}");
    let uncertain = crate::register::Abstain::Uncertain {
        sigma_m: 0.2,
        sigma_yaw_deg: 0.1,
    };
    let weighed_again = weigh(Err(uncertain));
    assert!(
        !matches!(weighed_again, Err(Refusal::LonePair { .. })),
        "{weighed_again:?}"
    );
}

#[test]
fn a_weak_join_names_the_rival_only_when_there_is_one() {
    let id = |i: usize| ["s0", "s1"][i];
    let alone = Refusal::Weak {
        overlap: 0.22,
        ambiguity: 0.0,
    }
    .describe(&id);
    assert!(
        alone.contains("only 22 %") && !alone.contains("as well"),
        "{alone}"
    );
    let rivalled = Refusal::Weak {
        overlap: 0.45,
        ambiguity: 0.4,
    }
    .describe(&id);
    assert!(rivalled.contains("40 % as well"), "{rivalled}");
}

#[test]
fn a_sensor_seen_only_along_a_corridor_is_not_placed() {
    // Two 60 m walls 3 m apart and no end in sight: sliding along them changes nothing.
    let walls = vec![
        Wall::new(-30.0, -1.5, 30.0, -1.5),
        Wall::new(-30.0, 1.5, 30.0, 1.5),
    ];
    let mut two = two_in(&walls, [pose2(0.0, 0.0, 0.0), pose2(3.0, 0.2, 0.4)]);
    // Registered alone (the pair's own slide check is not what this tests).
    two.pair.verdict = Ok(());
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let s1 = [(1, Pose2::identity())];
    // One proposal, no rival: only the slide test can refuse it.
    let slid = two.context(&p, &sp, |ctx| {
        let join = ctx.weigh(&s1).expect("a lone proposal that fits");
        ctx.slides(&s1, &join)
    });
    let Some(Refusal::Slides { axis_deg }) = slid else {
        panic!("a placement free to slide along the corridor was accepted");
    };
    assert!(
        !(20.0..=160.0).contains(&axis_deg),
        "slides along {axis_deg}°, not along the corridor"
    );
}

/// What a walker fit that placed a pair alone at `a_from_b` looks like (`walkers.rs`' limits
/// passed: many walks, no rival).
fn walked_alone(a_from_b: Pose2) -> crate::register::walkers::WalkerFit {
    crate::register::walkers::WalkerFit {
        a_from_b,
        inliers: 600,
        span_s: 28.0,
        spread_m: 9.0,
        rms_m: 0.06,
        others: vec![(20, pose2(-20.0, 4.0, 1.0))],
        walks: 25,
        runner_up_walks: 1,
        rival: None,
        covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(4e-4, 4e-4, 1e-5)),
        alone: true,
        torso_area_m2: None,
    }
}

#[test]
fn a_pair_people_placed_joins_where_walls_alone_would_slide_or_share_too_little() {
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let s1 = [(1, Pose2::identity())];
    // Along a corridor with no end in sight: walls leave the position free along it.
    let corridor = vec![
        Wall::new(-30.0, -1.5, 30.0, -1.5),
        Wall::new(-30.0, 1.5, 30.0, 1.5),
    ];
    let mut two = two_in(&corridor, [pose2(0.0, 0.0, 0.0), pose2(3.0, 0.2, 0.4)]);
    two.pair.verdict = Ok(());
    two.pair.walkers = Some(walked_alone(two.pair.a_from_b));
    let slid = two.context(&p, &sp, |ctx| {
        let join = ctx.weigh(&s1).expect("a pair people placed joins");
        assert!(join.walked);
        ctx.slides(&s1, &join)
    });
    assert!(slid.is_none(), "people's walks fix the slide: {slid:?}");
    // In the hall, 90° views back to back: the two share no wall (people walked between).
    let truth = [pose2(-1.0, 0.0, std::f64::consts::PI), pose2(1.0, 0.3, 0.1)];
    let sensors: Vec<SensorInput> = truth
        .iter()
        .enumerate()
        .map(|(i, pose)| sensor_at(&hall(), *pose, 90f64.to_radians(), &format!("s{i}")))
        .collect();
    let pair = undecided_pair(&sensors[0], &sensors[1], &[truth[0].inverse() * truth[1]]);
    let mut two = TwoSensors { sensors, pair };
    two.pair.verdict = Ok(());
    let overlap = two.pair.candidates[0].score.overlap();
    assert!(overlap < p.min_overlap, "the scene shares {overlap}");
    let by_walls = two.context(&p, &sp, |ctx| ctx.weigh(&s1).err());
    assert!(
        by_walls.is_some(),
        "walls alone placed a pair sharing {overlap} of its view"
    );
    two.pair.walkers = Some(walked_alone(two.pair.a_from_b));
    let join = two
        .context(&p, &sp, |ctx| ctx.weigh(&s1))
        .expect("people placed the pair: it joins");
    let (dt, dyaw) = pose_error(&join.anchor_from_root, &two.pair.a_from_b);
    assert!(dt < 1e-6 && dyaw < 1e-6, "{dt} {dyaw}");
    // People that merely agree with an undecided pair are not enough.
    two.pair.verdict = Err(crate::register::Abstain::Uncertain {
        sigma_m: 0.2,
        sigma_yaw_deg: 0.1,
    });
    assert!(two.context(&p, &sp, |ctx| ctx.weigh(&s1)).is_err());
}

#[test]
fn candidates_people_refuted_propose_nothing_and_speak_for_nothing() {
    let two = two_in(&hall(), [pose2(-1.0, 0.0, 0.0), pose2(1.5, 0.5, 0.3)]);
    let truth = two.pair.a_from_b;
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let s1 = [(1, Pose2::identity())];
    // The walls' candidate alone, registered: it places s1 and supports it there.
    let mut with = TwoSensors {
        pair: PairResult {
            verdict: Ok(()),
            ..two.pair.clone()
        },
        sensors: two.sensors.clone(),
    };
    assert!(with.context(&p, &sp, |ctx| ctx.weigh(&s1)).is_ok());
    assert_eq!(with.context(&p, &sp, |ctx| ctx.support(1, truth)), 1);
    // People saw walkers through it: the same candidate proposes nothing.
    with.pair.verdict = Err(crate::register::Abstain::PeopleDisagree {
        seen_through: 35,
        seen: 40,
        left: None,
    });
    let refused = with.context(&p, &sp, |ctx| ctx.weigh(&s1)).err();
    assert!(
        matches!(refused, Some(Refusal::NoProposal)),
        "a refuted candidate proposed: {refused:?}"
    );
    assert_eq!(with.context(&p, &sp, |ctx| ctx.support(1, truth)), 0);
}

/// A 270° sensor of `walls` at `site_from_sensor`, level at 1 m (across people's torsos), as
/// `register` prepares it: its still view and the people of `people_at` (0.4 m squares) it
/// saw walk over `seconds` at 40 Hz.
fn sensor_seeing_people(
    walls: &[Wall],
    site_from_sensor: Pose2,
    id: &str,
    seconds: f64,
    people_at: impl Fn(f64) -> Vec<[f64; 2]>,
) -> SensorInput {
    use crate::register::walkers::tests::scan;
    let p = RegisterParams::default();
    let mount = Mount {
        height_m: Some(1.0),
        pitch_rad: 0.0,
    };
    let scans: Vec<crate::scan::Scan> = (0..(seconds * 40.0) as u64)
        .map(|k| {
            scan(
                walls,
                &people_at(k as f64 / 40.0),
                &site_from_sensor,
                k * 25_000_000,
            )
        })
        .collect();
    let still = scan(walls, &[], &site_from_sensor, 0);
    SensorInput {
        id: id.to_string(),
        model: ScanModel::from_scan(&still, None, &mount, &p)
            .with_motion(&scans, &still, None, &mount, &p),
        mount,
        prior: None,
    }
}

/// A bare room turned half round is itself: the walls cannot tell a sensor's pose from its
/// mirror image. Two people walking (across it, and along one side) can: at the mirror image
/// the one sensor's walkers stand where the other saw the floor empty. A pair that proposes
/// only the mirror image joined the placed sensor there by walls alone; the join now asks
/// the people too, whatever pair proposed it (session 35: three units of the held-out random
/// sites joined 8–17 m off through such a look-alike).
#[test]
fn a_placement_people_saw_through_does_not_join_though_the_walls_fit_it() {
    let walls = polygon(&[(-6.0, -3.0), (6.0, -3.0), (6.0, 3.0), (-6.0, 3.0)]);
    let bounce = |t_s: f64, from: f64, to: f64, period_s: f64| {
        let s = (t_s / period_s).fract();
        from + (to - from) * if s < 0.5 { 2.0 * s } else { 2.0 - 2.0 * s }
    };
    let people = |t_s: f64| {
        vec![
            [bounce(t_s, -4.0, 4.0, 8.0), 1.5],
            [3.5, bounce(t_s, -2.4, 2.4, 6.0)],
        ]
    };
    let truth = [pose2(-2.0, -1.0, 0.2), pose2(2.5, 0.8, 2.8)];
    let mirror = pose2(0.0, 0.0, std::f64::consts::PI) * truth[1];
    let sensors: Vec<SensorInput> = truth
        .iter()
        .enumerate()
        .map(|(i, pose)| sensor_seeing_people(&walls, *pose, &format!("s{i}"), 10.0, people))
        .collect();
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let s1 = [(1, Pose2::identity())];
    let weigh = |sensors: &[SensorInput], at: Pose2| {
        let pair = PairResult {
            verdict: Ok(()),
            ..undecided_pair(&sensors[0], &sensors[1], &[truth[0].inverse() * at])
        };
        weigh_through(sensors, Pose2::identity(), pair, &s1, &p, &sp)
    };
    // The premise: by the walls alone, the mirror image joins.
    let walls_only: Vec<SensorInput> = sensors
        .iter()
        .map(|s| {
            let mut s = s.clone();
            s.model.motion = None;
            s
        })
        .collect();
    let join = weigh(&walls_only, mirror).expect("the walls alone take the mirror image");
    let (dt, _) = pose_error(&join.anchor_from_root, &(truth[0].inverse() * mirror));
    assert!(dt < 1e-6, "joined {dt} m from the mirror image");
    // With the people they saw: refused, naming the sensor that saw through them.
    let refused = weigh(&sensors, mirror).err();
    let Some(Refusal::PeopleSawThrough { with: 0 }) = &refused else {
        panic!("expected people to refuse the mirror image, got {refused:?}");
    };
    let said = refused.map(|r| r.describe(&|k| ["s0", "s1"][k]));
    assert!(said.is_some_and(|s| s.contains("s0 saw straight through")));
    // And at the truth the same people are no objection.
    let join = weigh(&sensors, truth[1]).expect("the true pose joins");
    let (dt, _) = pose_error(&join.anchor_from_root, &(truth[0].inverse() * truth[1]));
    assert!(dt < 1e-6, "joined {dt} m from the truth");
}

#[test]
fn a_sensor_reached_by_no_edge_stays_unplaced() {
    let truth = [
        pose2(0.0, 0.0, 0.0),
        pose2(5.0, 1.0, 0.5),
        pose2(3.0, 6.0, -1.0),
    ];
    let edges = vec![edge(0, 1, &truth, Pose2::identity())];
    let solution = solve(3, 0, &edges, &[], &SiteParams::default());
    assert!(solution[1].is_some());
    assert!(solution[2].is_none());
}

/// Found in a shop with a glass front: two units outside joined the two inside through one
/// pair that saw one wall, and were reported placed with σ 482 m. A pose the solve cannot
/// say it is sure of is not given, and a sensor resting on it loses it too.
#[test]
fn a_sensor_the_pairs_leave_loose_is_not_placed_and_says_why() {
    let truth = [
        pose2(0.0, 0.0, 0.0),
        pose2(5.0, 1.0, 0.5),
        pose2(3.0, 6.0, -1.0),
        pose2(6.0, 7.0, 0.2),
    ];
    let sp = SiteParams::default();
    // 0–1 tight; 1–2 fixes 2 across a wall but not along it (σ 30 m along x); 2–3 tight.
    let along_wall = Edge {
        covariance: Matrix3::from_diagonal(&nalgebra::Vector3::new(900.0, 1e-4, 1e-5)),
        ..edge(1, 2, &truth, Pose2::identity())
    };
    let edges = vec![
        edge(0, 1, &truth, Pose2::identity()),
        along_wall,
        edge(2, 3, &truth, Pose2::identity()),
    ];
    let origin = vec![(0, 0), (1, 0), (2, 0)];
    let sensors: Vec<SensorInput> = (0..4).map(|i| blank_input(i, None)).collect();
    let p = RegisterParams::default();
    let solved = super::check::solve_without_conflicts(4, 0, edges, origin, &sensors, &p, &sp);
    assert!(solved.solution[1].is_some() && solved.loose[1].is_none());
    for i in [2, 3] {
        assert!(solved.solution[i].is_none(), "sensor {i} placed");
        let Some(Refusal::Loose { sigma_m, .. }) = solved.loose[i] else {
            panic!("sensor {i}: {:?}", solved.loose[i]);
        };
        assert!(sigma_m > 10.0, "{sigma_m}");
    }
    // Their edges no longer count as used.
    assert_eq!(solved.origin, vec![(0, 0)]);
    let why = solved.loose[2].as_ref().unwrap().describe(&|_| "s");
    assert!(
        why.contains("only loosely") && why.contains("survey it"),
        "{why}"
    );
    // Within the limits, the same chain is placed.
    let tight: Vec<Edge> = (0..3)
        .map(|k| edge(k, k + 1, &truth, Pose2::identity()))
        .collect();
    let origin = vec![(0, 0), (1, 0), (2, 0)];
    let solved = super::check::solve_without_conflicts(4, 0, tight, origin, &sensors, &p, &sp);
    assert!(solved.solution.iter().all(Option::is_some));
    // Placed by hand as loosely as the page lets a person (σ 0.1 m, 3°), and reached by no
    // edge: it stands as surveyed, with the σ it was given (and the check ends).
    let mut sensors = sensors;
    sensors[3].prior = Some(Prior::new(truth[3], 0.1, 3f64.to_radians()));
    let edges = vec![edge(0, 1, &truth, Pose2::identity())];
    let solved =
        super::check::solve_without_conflicts(4, 0, edges, vec![(0, 0)], &sensors, &p, &sp);
    let (_, sigma) = solved.solution[3].expect("placed by hand");
    assert!(sigma[2] > sp.placed_max_sigma_rad, "{sigma:?}");
}

#[test]
fn the_last_check_drops_a_sensor_only_for_contradictions_it_is_sure_of() {
    use crate::register::score::tests::facing;
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let same = Pose2::identity();
    // Side by side, the low unit (0.8 m) hits a counter 3 m out; the high one (1.1 m) sees
    // over it to the wall at 6 m. Pair scoring counts that against the pose (0.3 m above is
    // within its 0.5 m), the last check does not: the counter may stand under 1.1 m.
    let (low, high) = (facing(3.0, Some(0.8)), facing(6.0, Some(1.1)));
    assert!(crate::register::score::score(&high, &low, &same, &p).violation() > 0.9);
    let certain = certain_only(&p, &sp);
    assert!(!contradicts(&high, &low, &same, &certain));
    // A low beam that passed where the high unit saw something would have hit it.
    let (low_far, high_near) = (facing(6.0, Some(0.8)), facing(3.0, Some(1.1)));
    assert!(contradicts(&low_far, &high_near, &same, &certain));
    // Mounts unknown: one plane, and the counter contradicts.
    let (far, near) = (facing(6.0, None), facing(3.0, None));
    assert!(contradicts(&far, &near, &same, &certain));
}

/// 270° sensors `s0`, `s1`, … at `truth` in the hall and a 12 × 5 m room 40 m off it.
fn in_hall_and_far_room(truth: &[Pose2]) -> Vec<SensorInput> {
    let mut walls = hall();
    walls.extend(polygon(&[
        (40.0, 0.0),
        (52.0, 0.0),
        (52.0, 5.0),
        (40.0, 5.0),
    ]));
    sensors_at(&walls, truth)
}

/// Two sensors in the hall and two in a room 40 m off it, placed at the truth: pair selection
/// registers the pairs that share view where the site puts them, and skips the rest.
#[test]
fn placed_sensors_are_paired_where_their_views_meet_and_not_across_the_site() {
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(1.0, -2.0, 2.6),
        pose2(41.0, 1.5, 0.6),
        pose2(50.0, 3.5, 2.9),
    ];
    let sensors = in_hall_and_far_room(&truth);
    let p = RegisterParams::default();
    let mut selection = pairs::PairSelection::new(&sensors, &p, 1);
    let frame: Vec<Option<(usize, Pose2)>> = truth
        .iter()
        .map(|t| Some((0, truth[0].inverse() * t)))
        .collect();
    assert_eq!(selection.widen(&frame, &[true; 4]), vec![(0, 1), (2, 3)]);
    let skipped = selection.skipped(&frame);
    assert_eq!(skipped.len(), 6, "nothing registered yet: {skipped:?}");
    let across = |k: &SkippedPair| (k.a < 2) != (k.b < 2);
    for k in skipped.iter().filter(|k| across(k)) {
        assert_eq!(k.why, Skip::NoSharedView { predicted: 0.0 }, "{k:?}");
    }
    // An unplaced sensor with no registered pair goes down its ranking: one partner, then two
    // more, then the last.
    let mut placed = [true; 4];
    placed[3] = false;
    let mut frame = frame;
    frame[3] = None;
    let first = selection.widen(&frame, &placed);
    assert!(first.contains(&(0, 1)) && first.iter().filter(|k| k.1 == 3).count() == 1);
    selection.register(&first);
    let more: Vec<_> = selection.widen(&frame, &placed);
    assert!(
        more.iter().all(|k| k.1 == 3) && !more.is_empty(),
        "{more:?}"
    );
}

/// Two pairs registered through one sensor propose the third side of their triangle, where
/// the two registrations put its ends in view of each other; a pair that did not register
/// (across the site) proposes nothing, and a closed triangle nothing more.
#[test]
fn two_registered_pairs_through_one_sensor_propose_the_pair_that_closes_their_triangle() {
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(1.0, -2.0, 2.6),
        pose2(-1.0, 1.5, -0.8),
        pose2(50.0, 3.5, 2.9),
    ];
    let sensors = in_hall_and_far_room(&truth);
    let p = RegisterParams::default();
    let mut selection = pairs::PairSelection::new(&sensors, &p, 1);
    selection.register(&[(0, 1), (0, 2), (0, 3)]);
    let (_, results) = selection.registered();
    let verdicts: Vec<_> = results.iter().map(|r| r.verdict.clone()).collect();
    assert!(
        results[0].registered() && results[1].registered() && !results[2].registered(),
        "{verdicts:?}"
    );
    assert_eq!(selection.close_triangles(), vec![(1, 2)]);
    selection.register(&[(1, 2)]);
    assert_eq!(selection.close_triangles(), Vec::new());
}

/// Three sensors placed in the hall and one in a room 40 m off it; a fourth hall sensor
/// added alone lands at its truth after registering only the placed sensors it shares view
/// with, and a sensor in the far room, which shares no view with any placed one, is refused
/// after trying them all.
#[test]
fn a_sensor_added_to_a_placed_site_lands_at_its_truth_from_its_neighbours_alone() {
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(1.0, -2.0, 2.6),
        pose2(4.0, 1.5, -2.5),
        pose2(50.0, 3.5, 2.9),
        pose2(-1.0, 1.5, -0.8),
        pose2(42.0, 1.0, 0.6),
    ];
    let sensors = in_hall_and_far_room(&truth);
    let placed: Vec<Option<Pose2>> = truth
        .iter()
        .enumerate()
        .map(|(i, t)| (i < 4).then(|| truth[0].inverse() * t))
        .collect();
    let p = RegisterParams::default();
    let sp = SiteParams {
        partners: 1,
        ..SiteParams::default()
    };
    let added = add_sensor(&sensors, &placed, &[], 4, &p, &sp);
    let at = added.pose.expect("the hall sensor is placed");
    let (dt, dyaw) = pose_error(&at, &(truth[0].inverse() * truth[4]));
    assert!(dt < 0.05 && dyaw < 0.5f64.to_radians(), "{dt} m {dyaw} rad");
    // Its σ comes from the pairs that placed it: above the solve's floor shared among them,
    // and well within what it is off by (a few cm); the walls alone placed it, on enough pairs.
    let [sx, sy, syaw] = added.sigma;
    assert!(sx > 0.001 && sy > 0.001 && syaw > 0.0, "{:?}", added.sigma);
    assert!(
        sx < 0.05 && sy < 0.05 && syaw < 1f64.to_radians(),
        "{:?}",
        added.sigma
    );
    assert_eq!(added.evidence, Some("walls"));
    // Partners placed less surely make it less sure.
    let unsure = add_sensor(&sensors, &placed, &[[0.1, 0.1, 0.02]; 4], 4, &p, &sp);
    assert!(
        unsure.sigma[0] > sx + 0.02,
        "{:?} vs {:?}",
        unsure.sigma,
        added.sigma
    );
    assert_eq!(added.placed, 4);
    // Its hall neighbours only: the sensor in the far room was never tried.
    let keys: Vec<(usize, usize)> = added.pairs.iter().map(|(k, _)| *k).collect();
    assert!(!keys.contains(&(3, 4)), "{keys:?}");
    assert!(keys.contains(&(0, 4)) && keys.contains(&(1, 4)), "{keys:?}");
    // With s3 unplaced, a second sensor in the far room shares view with no placed sensor:
    // refused, with a reason, after trying every placed one.
    let mut without_s3 = placed.clone();
    without_s3[3] = None;
    let far = add_sensor(&sensors, &without_s3, &[], 5, &p, &sp);
    let why = far.pose.expect_err("nothing placed sees the far room");
    assert!(why.contains("survey it"), "{why}");
    let keys: Vec<(usize, usize)> = far.pairs.iter().map(|(k, _)| *k).collect();
    assert_eq!(keys, vec![(0, 5), (1, 5), (2, 5)]);
}

#[test]
fn joins_that_take_minutes_are_said_with_how_far_they_got() {
    use super::join::slow_joins;
    assert_eq!(slow_joins(2.0, (8, 36, 20_906), 100, 100), None);
    let said = slow_joins(690.0, (3, 106, 174_448), 41, 200).expect("said");
    for part in [
        "took 690 s",
        "106 groups weighed at 174448 placements, 3 joined",
        "41 of 200 units placed",
        "surveyed poses",
    ] {
        assert!(said.contains(part), "{part}: {said}");
    }
}

/// A registered pair on no cycle (a bridge) only proposes where its sensor joins, unless
/// people both sensors saw walk confirmed it: their walks check it as a cycle would, so it
/// binds its sensors into a group. Walls alone, or too few walkers, do not.
#[test]
fn a_bridge_people_confirmed_binds_its_sensors_and_a_walls_only_one_does_not() {
    let truth = [
        pose2(-3.0, -1.0, 0.3),
        pose2(1.0, -2.0, 2.6),
        pose2(-1.0, 1.5, -0.8),
    ];
    let sensors = sensors_at(&hall(), &truth);
    let (p, sp) = (RegisterParams::default(), SiteParams::default());
    let registered = |a: usize, b: usize, seen: usize| {
        let mut r = undecided_pair(&sensors[a], &sensors[b], &[truth[a].inverse() * truth[b]]);
        r.verdict = Ok(());
        r.motion = Some(crate::register::motion::MotionEvidence {
            seen,
            seen_through: 0,
        });
        r
    };
    let pairs = [(0, 1), (1, 2)];
    let checked = |seen: [usize; 2]| {
        let results = [registered(0, 1, seen[0]), registered(1, 2, seen[1])];
        let memo = super::memo::ScoreMemo::default();
        let c = groups::checked_edges(3, 0, &pairs, &results, &sensors, &p, &sp, &memo);
        c.edges.iter().map(|e| (e.a, e.b)).collect::<Vec<_>>()
    };
    let many = p.motion.settle_min_seen;
    assert_eq!(checked([0, many]), vec![(1, 2)]);
    assert_eq!(checked([many, many]), vec![(0, 1), (1, 2)]);
    assert_eq!(checked([0, many - 1]), Vec::<(usize, usize)>::new());
}
