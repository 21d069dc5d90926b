//! Local refinement of a moved sensor: its new static view aligned (ICP) against the other
//! posed sensors' static views, starting from where it stood. Cheap next to a global search,
//! and most knocks are small; when the fit is not clearly good, the caller falls back to the
//! global search. Pure: models and poses in, a pose or the reason it was refused out.
//!
//! Accepted when
//! - at least `min(2, others)` neighbours fit: the ICP result passes the pair gates of
//!   [`RegisterParams`] (`min_overlap`, `min_score`, `max_violation`), as a global pair
//!   registration would require;
//! - every fitting neighbour agrees with the best one within [`SiteParams`]' `confirm_m` /
//!   `confirm_rad` (one neighbour's local minimum cannot pass alone when others see it);
//! - the pose lies within `radius_m` / `yaw_rad` of the old pose, plus one step of the seed
//!   grid (else it was no local move).

use nalgebra::{Matrix2, Matrix3};

use crate::geometry::{Pose2, pose_error, pose2, yaw_rad};
use crate::register::icp::refine_scored;
use rayon::prelude::*;

use crate::register::score::{PoseScore, score_coarse};
use crate::register::site::SiteParams;
use crate::register::{RegisterParams, ScanModel};

/// Spacing of the local search's seed grid: the true pose is at most 18 cm and 1.25° from
/// some seed, within ICP's capture range (its first correspondence gate is 40 cm).
const SEED_STEP_M: f64 = 0.25;
const SEED_STEP_RAD: f64 = 2.5 * std::f64::consts::PI / 180.0;
/// Distinct best seeds refined by ICP per neighbour.
const REFINED_SEEDS: usize = 4;

/// Another posed sensor, as the moved one is aligned against it.
pub struct Neighbour<'a> {
    pub id: &'a str,
    pub site_from_sensor: Pose2,
    pub model: &'a ScanModel,
}

/// A local fit that was accepted.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalFit {
    pub site_from_sensor: Pose2,
    pub sigma_x_m: f64,
    pub sigma_y_m: f64,
    pub sigma_yaw_rad: f64,
    /// The neighbours whose fits agreed.
    pub agreeing: Vec<String>,
    /// Distance and heading change from the old pose.
    pub shift_m: f64,
    pub turn_rad: f64,
}

/// The best fit against one neighbour.
struct Fit {
    id: String,
    site_from_sensor: Pose2,
    score: PoseScore,
    /// Covariance of (x, y, yaw) in the site frame.
    covariance: Matrix3<f64>,
}

/// Bounds of the local search.
#[derive(Debug, Clone, Copy)]
pub struct LocalBounds {
    pub radius_m: f64,
    pub yaw_rad: f64,
}

/// Aligns `moved` (its new static view, sensor frame) from `old` (its site pose before the
/// move) against `others`; see the module doc for when the result is accepted.
pub fn refine_locally(
    moved: &ScanModel,
    old: &Pose2,
    others: &[Neighbour<'_>],
    bounds: LocalBounds,
    p: &RegisterParams,
    site: &SiteParams,
) -> Result<LocalFit, String> {
    if others.is_empty() {
        return Err("no other posed sensor to align against".into());
    }
    let mut fits: Vec<Fit> = others
        .iter()
        .filter_map(|n| best_fit(moved, old, n, bounds, p))
        .filter(|f| passes(&f.score, p))
        .collect();
    let needed = others.len().min(2);
    if fits.len() < needed {
        return Err(format!(
            "{} of {} neighbours fit near the old pose ({needed} needed)",
            fits.len(),
            others.len()
        ));
    }
    fits.sort_by(|a, b| b.score.overlap().total_cmp(&a.score.overlap()));
    let best = &fits[0];
    if let Some(off) = fits.iter().find(|f| {
        let (dt, dyaw) = pose_error(&f.site_from_sensor, &best.site_from_sensor);
        dt > site.confirm_m || dyaw > site.confirm_rad
    }) {
        let (dt, dyaw) = pose_error(&off.site_from_sensor, &best.site_from_sensor);
        return Err(format!(
            "the fits against {} and {} disagree by {dt:.2} m, {:.1}°",
            best.id,
            off.id,
            dyaw.to_degrees()
        ));
    }
    let (shift_m, turn_rad) = pose_error(&best.site_from_sensor, old);
    // ICP from a seed on the edge of the search may end up to a seed step beyond it.
    if shift_m > bounds.radius_m + SEED_STEP_M || turn_rad > bounds.yaw_rad + SEED_STEP_RAD {
        return Err(format!(
            "the fit is {shift_m:.2} m, {:.1}° from the old pose, beyond the local search",
            turn_rad.to_degrees()
        ));
    }
    let c = &best.covariance;
    Ok(LocalFit {
        site_from_sensor: best.site_from_sensor,
        sigma_x_m: c[(0, 0)].max(0.0).sqrt().max(site.min_sigma_m),
        sigma_y_m: c[(1, 1)].max(0.0).sqrt().max(site.min_sigma_m),
        sigma_yaw_rad: c[(2, 2)].max(0.0).sqrt().max(site.min_sigma_rad),
        agreeing: fits.iter().map(|f| f.id.clone()).collect(),
        shift_m,
        turn_rad,
    })
}

/// The pair gates a global registration applies to its best pose.
fn passes(s: &PoseScore, p: &RegisterParams) -> bool {
    s.overlap() >= p.min_overlap && s.value >= p.min_score && s.violation() <= p.max_violation
}

/// The local search against one neighbour: every pose on a grid around the old one (within
/// the bounds) scored coarsely, the best few distinct ones refined by guarded ICP; the
/// best-scoring result. ICP alone captures a few centimetres and degrees; a knock is more.
fn best_fit(
    moved: &ScanModel,
    old: &Pose2,
    n: &Neighbour<'_>,
    bounds: LocalBounds,
    p: &RegisterParams,
) -> Option<Fit> {
    let a = n.model;
    let site_from_a = n.site_from_sensor;
    let a_from_site = site_from_a.inverse();
    let steps_xy = (bounds.radius_m / SEED_STEP_M).ceil() as i32;
    let steps_yaw = (bounds.yaw_rad / SEED_STEP_RAD).ceil() as i32;
    let old_yaw = yaw_rad(old);
    let mut seeds: Vec<Pose2> = Vec::new();
    for ix in -steps_xy..=steps_xy {
        for iy in -steps_xy..=steps_xy {
            let (dx, dy) = (f64::from(ix) * SEED_STEP_M, f64::from(iy) * SEED_STEP_M);
            if dx.hypot(dy) > bounds.radius_m + 1e-9 {
                continue;
            }
            for k in -steps_yaw..=steps_yaw {
                let dyaw = (f64::from(k) * SEED_STEP_RAD).clamp(-bounds.yaw_rad, bounds.yaw_rad);
                let seed = pose2(
                    old.translation.x + dx,
                    old.translation.y + dy,
                    old_yaw + dyaw,
                );
                seeds.push(a_from_site * seed);
            }
        }
    }
    let mut coarse: Vec<(f64, Pose2)> = seeds
        .into_par_iter()
        .map(|init| (score_coarse(a, moved, &init, p).value, init))
        .collect();
    coarse.sort_by(|x, y| y.0.total_cmp(&x.0));
    let mut best_seeds: Vec<Pose2> = Vec::new();
    for (_, pose) in coarse {
        if best_seeds.len() >= REFINED_SEEDS {
            break;
        }
        let apart = |s: &Pose2| {
            let (dt, dyaw) = pose_error(s, &pose);
            dt >= p.seed_gap_m || dyaw >= p.seed_gap_rad
        };
        if best_seeds.iter().all(apart) {
            best_seeds.push(pose);
        }
    }
    best_seeds
        .par_iter()
        .map(|init| {
            let (icp, s) = refine_scored(a, moved, init, p, p.class_aware);
            (s, icp)
        })
        .max_by(|x, y| x.0.value.total_cmp(&y.0.value))
        .map(|(s, icp)| {
            let sigma = icp.rms_m.clamp(0.01, 1.0);
            let in_a = icp
                .hessian
                .try_inverse()
                .map_or(Matrix3::identity() * 1e6, |inv| {
                    inv * sigma * sigma * p.covariance_inflation
                });
            // Translation covariance turned from A's frame into the site frame.
            let r = site_from_a.rotation.to_rotation_matrix().into_inner();
            let tt: Matrix2<f64> = r * in_a.fixed_view::<2, 2>(0, 0) * r.transpose();
            let mut covariance = in_a;
            covariance.fixed_view_mut::<2, 2>(0, 0).copy_from(&tt);
            Fit {
                id: n.id.to_string(),
                site_from_sensor: site_from_a * icp.a_from_b,
                score: s,
                covariance,
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::static_view;
    use crate::record::{self, Recording};

    fn lab() -> Recording {
        record::read(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/lab.mcap"))
            .unwrap()
    }

    /// Every lab sensor's static view as a model, with its true pose in the entrance frame.
    fn models(rec: &Recording, p: &RegisterParams) -> Vec<(String, Pose2, ScanModel)> {
        let truth = |id: &str| {
            let t = rec.sensor(id).and_then(|s| s.truth).unwrap();
            pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
        };
        let world_from_anchor = truth("entrance");
        rec.sensors
            .iter()
            .map(|info| {
                let scans: Vec<_> = rec.scans_of(&info.id).to_vec();
                let view = static_view(&scans, 1.0).unwrap();
                let mount = info.mount();
                let model = ScanModel::from_scan(&view, info.geometry.as_ref(), &mount, p);
                (
                    info.id.clone(),
                    world_from_anchor.inverse() * truth(&info.id),
                    model,
                )
            })
            .collect()
    }

    fn run(old_offset: Pose2) -> (Result<LocalFit, String>, Pose2) {
        let rec = lab();
        let p = RegisterParams::default();
        let all = models(&rec, &p);
        let (_, truth, model) = all.iter().find(|(id, _, _)| id == "bench").unwrap();
        let others: Vec<Neighbour<'_>> = all
            .iter()
            .filter(|(id, _, _)| id != "bench")
            .map(|(id, pose, model)| Neighbour {
                id,
                site_from_sensor: *pose,
                model,
            })
            .collect();
        let old = truth * old_offset;
        let bounds = LocalBounds {
            radius_m: 0.5,
            yaw_rad: 10f64.to_radians(),
        };
        let fit = refine_locally(model, &old, &others, bounds, &p, &SiteParams::default());
        (fit, *truth)
    }

    #[test]
    fn a_knock_is_found_from_the_old_pose() {
        // The sensor stood 0.25 m and 6° from where its new view puts it.
        let (fit, truth) = run(pose2(0.2, -0.15, 6f64.to_radians()));
        let fit = fit.expect("a small knock is refined locally");
        let (err_m, err_rad) = pose_error(&fit.site_from_sensor, &truth);
        assert!(
            err_m < 0.05 && err_rad.to_degrees() < 0.5,
            "{err_m:.3} m, {:.2}°",
            err_rad.to_degrees()
        );
        assert!(fit.agreeing.len() >= 2, "{:?}", fit.agreeing);
        assert!(fit.sigma_x_m > 0.0 && fit.sigma_x_m < 0.1);
    }

    #[test]
    fn a_move_beyond_the_local_search_is_refused() {
        // 3 m and 60° away: no neighbour fits near the old pose, the global search must.
        let (fit, _) = run(pose2(2.0, 2.2, 60f64.to_radians()));
        let reason = fit.expect_err("far from the old pose");
        assert!(!reason.is_empty());
    }

    #[test]
    fn nobody_to_align_against_is_a_refusal() {
        let rec = lab();
        let p = RegisterParams::default();
        let all = models(&rec, &p);
        let bounds = LocalBounds {
            radius_m: 0.5,
            yaw_rad: 0.2,
        };
        let r = refine_locally(
            &all[0].2,
            &all[0].1,
            &[],
            bounds,
            &p,
            &SiteParams::default(),
        );
        assert!(r.is_err());
    }
}
