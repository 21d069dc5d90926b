//! Pairwise registration on ray-cast scenes: truth recovered, a crafted false match rejected by
//! free space, a symmetric corridor reported as not registered, determinism.

use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::geometry::raycast::{Wall, polygon, scan_ranges};
use scanfuse::geometry::{Mount, Pose2, pose_error, pose2, project_scan};
use scanfuse::register::{RegisterParams, ScanModel, register_pair};
use scanfuse::scan::{Scan, ScanGeometry};

/// Ranges ray-cast at `angles` with uniform noise of ±`noise_m`.
fn noisy_scan(
    walls: &[Wall],
    site_from_sensor: &Pose2,
    angles: &[f64],
    noise_m: f32,
    seed: u64,
) -> Scan {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ranges_m = scan_ranges(walls, site_from_sensor, angles, 30.0)
        .into_iter()
        .map(|r| {
            if r > 0.0 {
                r + rng.random_range(-noise_m..noise_m)
            } else {
                0.0
            }
        })
        .collect();
    Scan {
        stamp_ns: 0,
        sensor_stamp_ms: None,
        start_angle_rad: angles.first().copied().unwrap_or(0.0),
        end_angle_rad: angles.last().copied().unwrap_or(0.0),
        ranges_m,
        intensities: vec![],
    }
}

/// A UTM-30LX-EW scan (0.25°, 270°, ±1 cm).
fn model(walls: &[Wall], site_from_sensor: &Pose2, seed: u64, p: &RegisterParams) -> ScanModel {
    let g = ScanGeometry::UTM_30LX_EW;
    let angles: Vec<f64> = (g.amin..=g.amax).map(|s| g.angle_of_step_rad(s)).collect();
    let scan = noisy_scan(walls, site_from_sensor, &angles, 0.01, seed);
    let points = project_scan(&scan, Some(&g), &Mount::default(), &p.project);
    ScanModel::new(&points, g.step_rad(), p)
}

/// A 180° scan at 1° steps with ±3 cm noise, like the SICK units of the CARMEN logs (no PP
/// geometry).
fn sparse_model(
    walls: &[Wall],
    site_from_sensor: &Pose2,
    seed: u64,
    p: &RegisterParams,
) -> ScanModel {
    let angles: Vec<f64> = (0..180).map(|k| (-90.0 + k as f64).to_radians()).collect();
    let scan = noisy_scan(walls, site_from_sensor, &angles, 0.03, seed);
    ScanModel::from_scan(&scan, None, &Mount::default(), p)
}

/// Registers B against A and checks the verdict and the error against the truth.
fn assert_registered_within(
    a: &ScanModel,
    b: &ScanModel,
    truth: &Pose2,
    tol_m: f64,
    tol_deg: f64,
    p: &RegisterParams,
) -> scanfuse::register::PairResult {
    let r = register_pair(a, b, p);
    let (dt, dyaw) = pose_error(&r.a_from_b, truth);
    assert!(r.registered(), "{:?}", r.verdict);
    assert!(
        dt < tol_m && dyaw < tol_deg.to_radians(),
        "error {dt} m {} deg",
        dyaw.to_degrees()
    );
    r
}

/// An L-shaped hall with a pillar, a cabinet and a door recess.
fn hall() -> Vec<Wall> {
    let mut w = polygon(&[
        (0.0, 0.0),
        (14.0, 0.0),
        (14.0, 6.0),
        (6.0, 6.0),
        (6.0, 12.0),
        (0.0, 12.0),
    ]);
    w.extend(polygon(&[(4.0, 2.5), (4.6, 2.5), (4.6, 3.1), (4.0, 3.1)]));
    w.extend(polygon(&[
        (10.0, 5.2),
        (11.5, 5.2),
        (11.5, 5.9),
        (10.0, 5.9),
    ]));
    w.extend(polygon(&[(0.0, 8.0), (0.8, 8.6), (0.0, 9.2)]));
    w
}

#[test]
fn pair_in_hall_is_registered_within_tolerance() {
    let p = RegisterParams::default();
    let walls = hall();
    let site_from_a = pose2(2.0, 1.5, 0.4);
    let site_from_b = pose2(9.0, 3.0, 2.5);
    let a = model(&walls, &site_from_a, 1, &p);
    let b = model(&walls, &site_from_b, 2, &p);
    let truth = site_from_a.inverse() * site_from_b;
    let r = assert_registered_within(&a, &b, &truth, 0.05, 0.5, &p);
    assert!(r.overlap > 0.3 && r.ambiguity < 0.8 && r.match_score > 0.0);
    assert!(r.covariance[(0, 0)] > 0.0 && r.covariance[(0, 0)].sqrt() < 0.05);
    // Every candidate carries the covariance linearised at its own pose (the site solve
    // weighs an edge made from a runner-up by it); the best's is the pair's.
    assert_eq!(r.candidates[0].covariance, r.covariance);
    for c in &r.candidates {
        assert!((0..3).all(|k| c.covariance[(k, k)].is_finite() && c.covariance[(k, k)] > 0.0));
    }
}

#[test]
fn crafted_false_match_is_rejected_by_free_space() {
    let p = RegisterParams::default();
    // Two rooms back to back: A in the north one (0 < y < 6), B in the shallow south one
    // (−3.2 < y < −0.2). They share no view at all.
    let mut walls = polygon(&[(0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)]);
    walls.extend(polygon(&[
        (0.0, -0.2),
        (10.0, -0.2),
        (10.0, -3.2),
        (0.0, -3.2),
    ]));
    let site_from_a = pose2(3.0, 2.0, 0.3);
    let site_from_b = pose2(6.0, -1.5, -0.5);
    let a = model(&walls, &site_from_a, 1, &p);
    let b = model(&walls, &site_from_b, 2, &p);
    // The classic false match: B turned about the dividing wall, so its view of that wall
    // lands exactly on A's view of it (many hits) while its far wall lands at y = 3, in the
    // middle of the room A saw empty.
    let turn_about_wall =
        pose2(5.0, -0.1, 0.0) * pose2(0.0, 0.0, std::f64::consts::PI) * pose2(-5.0, 0.1, 0.0);
    let false_pose = site_from_a.inverse() * turn_about_wall * site_from_b;
    let s_false = scanfuse::register::score::score(&a, &b, &false_pose, &p);
    assert!(
        s_false.b_in_a.overlap > 0.15,
        "hits alone would like it: {s_false:?}"
    );
    assert!(s_false.violation() > p.max_violation, "{s_false:?}");
    assert!(s_false.value < 0.0, "{s_false:?}");
    let r = register_pair(&a, &b, &p);
    assert!(
        !r.registered(),
        "rooms that share no view must not register: {r:?}"
    );
}

#[test]
fn symmetric_corridor_is_not_registered() {
    let p = RegisterParams::default();
    // A long featureless corridor: every position along it looks the same.
    let walls = polygon(&[(0.0, 0.0), (80.0, 0.0), (80.0, 2.4), (0.0, 2.4)]);
    let a = model(&walls, &pose2(30.0, 1.2, 0.0), 3, &p);
    let b = model(&walls, &pose2(36.0, 1.0, 0.1), 4, &p);
    let r = register_pair(&a, &b, &p);
    assert!(
        !r.registered(),
        "a corridor seen lengthwise cannot be registered: {r:?}"
    );
}

#[test]
fn registration_is_deterministic() {
    let p = RegisterParams::default();
    let walls = hall();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let _ = rng.random::<u8>();
    let a = model(&walls, &pose2(3.0, 9.0, -1.0), 5, &p);
    let b = model(&walls, &pose2(4.0, 2.0, 1.0), 6, &p);
    let r1 = register_pair(&a, &b, &p);
    let r2 = register_pair(&a, &b, &p);
    assert_eq!(r1.a_from_b, r2.a_from_b);
    assert_eq!(r1.verdict, r2.verdict);
    let _ = Point2::<f64>::origin();
}

#[test]
fn noisy_sparse_180_degree_scans_are_registered_within_5_cm_and_half_a_degree() {
    // The CARMEN-like case: few points per wall, ±3 cm range noise, no PP geometry.
    let p = RegisterParams::default();
    let walls = hall();
    let site_from_a = pose2(1.5, 4.0, -0.3);
    let site_from_b = pose2(12.0, 1.5, 2.6);
    let a = sparse_model(&walls, &site_from_a, 1, &p);
    let b = sparse_model(&walls, &site_from_b, 2, &p);
    assert_registered_within(
        &a,
        &b,
        &(site_from_a.inverse() * site_from_b),
        0.05,
        0.5,
        &p,
    );
}

#[test]
fn a_sensor_standing_far_behind_the_other_is_found() {
    // A looks down a hall; B stands 6 m behind A's back, where A sees nothing, facing the same
    // way. The translation vote must reach that far beyond A's outline.
    let p = RegisterParams::default();
    let mut walls = polygon(&[
        (0.0, 0.0),
        (20.0, 0.0),
        (20.0, 5.0),
        (17.0, 5.0),
        (17.0, 8.0),
        (0.0, 8.0),
    ]);
    walls.extend(polygon(&[
        (15.0, 2.0),
        (16.0, 2.0),
        (16.0, 3.0),
        (15.0, 3.0),
    ]));
    walls.extend(polygon(&[
        (12.5, 5.5),
        (13.2, 5.5),
        (13.2, 6.2),
        (12.5, 6.2),
    ]));
    walls.extend(polygon(&[(10.0, 0.0), (11.0, 1.2), (12.0, 0.0)]));
    walls.extend(polygon(&[(4.0, 8.0), (5.5, 7.0), (7.0, 8.0)]));
    let site_from_a = pose2(9.0, 4.0, 0.05);
    let site_from_b = pose2(3.0, 3.5, -0.1);
    let a = sparse_model(&walls, &site_from_a, 1, &p);
    let b = sparse_model(&walls, &site_from_b, 2, &p);
    let leftmost = a.points().iter().map(|q| q.x).fold(f64::INFINITY, f64::min);
    let truth = site_from_a.inverse() * site_from_b;
    assert!(
        leftmost - truth.translation.x > 4.0,
        "B must stand well outside A's outline"
    );
    assert_registered_within(&a, &b, &truth, 0.05, 0.5, &p);
}
