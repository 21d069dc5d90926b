//! Scoring a candidate pose against the lookup tables, in both directions: hits (points that
//! land near the other scan's points) minus weighted free-space violations (points that land
//! where the other sensor saw empty space). Violations are counted, not fatal: at the true
//! pose a few per cent of real points violate (clutter, people, grazing walls).

use super::{RegisterParams, ScanModel};
use crate::geometry::Pose2;
use nalgebra::Point2;

/// Hit and violation fractions of one direction.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DirScore {
    /// Soft hit count / points: 1 − (d/hit)² per hit.
    pub hit: f64,
    /// Points within the hit distance / points.
    pub overlap: f64,
    /// Points in the other sensor's free space / points.
    pub violation: f64,
}

/// The score of a pose: both directions and the combined value.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PoseScore {
    pub a_in_b: DirScore,
    pub b_in_a: DirScore,
    pub value: f64,
}

impl PoseScore {
    /// Estimated shared view: the smaller of the two hit shares.
    pub fn overlap(&self) -> f64 {
        self.a_in_b.overlap.min(self.b_in_a.overlap)
    }
    /// The worse direction's violation share: one sensor contradicting the other suffices.
    pub fn violation(&self) -> f64 {
        self.a_in_b.violation.max(self.b_in_a.violation)
    }
}

/// How two sets of views agree with one set standing at a given pose in the other's frame:
/// every pair of their sensors within reach of each other scored at the pose it implies (both
/// directions), the points that land on the other's points and those that land in its free
/// space summed over all of them. A look-alike that one pair of views matches rarely extends
/// to the views around them: zone links and the edges that bind a site's groups are both
/// checked by it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WholeView {
    pub hits: f64,
    pub violations: f64,
}

impl WholeView {
    /// The share of the points that meet the other set's views which contradict them.
    pub fn violation(&self) -> f64 {
        self.violations / (self.hits + self.violations).max(1.0)
    }

    /// Adds the score `s` of `b`'s view at some pose in `a`'s, each direction by its points.
    pub fn add(&mut self, s: &PoseScore, a: &ScanModel, b: &ScanModel) {
        let (na, nb) = (a.score_sample.len() as f64, b.score_sample.len() as f64);
        self.hits += s.b_in_a.overlap * nb + s.a_in_b.overlap * na;
        self.violations += s.b_in_a.violation * nb + s.a_in_b.violation * na;
    }

    pub fn merged(self, other: Self) -> Self {
        WholeView {
            hits: self.hits + other.hits,
            violations: self.violations + other.violations,
        }
    }
}

/// Scores `from`'s sample moved by `into_from_from` against `into`'s tables.
fn score_dir(
    from: &ScanModel,
    into: &ScanModel,
    into_from_from: &Pose2,
    p: &Tolerance,
) -> DirScore {
    let (mut hit, mut overlap, mut violation) = (0.0, 0usize, 0usize);
    let pts = from.points();
    let into_pts = into.points();
    for &i in &from.score_sample {
        let q = into_from_from * pts[i];
        if let Some(j) = into.grid.nearest(&q) {
            let d = (q - into_pts[j]).norm();
            if d < p.hit_m {
                let x = d / p.hit_m;
                hit += 1.0 - x * x;
                overlap += 1;
            }
        }
        // The grazing walk is the dearest test: asked last, of points that violate.
        if crosses(from, into, &pts[i], &q, p)
            && into.polar.violates(&q, p.free_margin_m, p.free_margin_frac)
            && !grazes(from, into, i, into_from_from, &q, p)
        {
            violation += 1;
        }
    }
    let n = from.score_sample.len().max(1) as f64;
    DirScore {
        hit: hit / n,
        overlap: overlap as f64 / n,
        violation: violation as f64 / n,
    }
}

/// Whether `into`'s beam towards `q` (its frame; `p_from`, the same point in `from`'s frame)
/// would have hit what `from` saw there: only then does a return short of it in `into`'s scan
/// contradict it. A beam passing well above it may clear a box or partition; one passing below
/// would hit it too, since objects stand on the floor (unless `free_space_dz_below_m` says
/// otherwise). With a mount unknown the two planes are taken as one.
#[inline]
fn crosses(
    from: &ScanModel,
    into: &ScanModel,
    p_from: &Point2<f64>,
    q: &Point2<f64>,
    p: &Tolerance,
) -> bool {
    match (from.plane, into.plane) {
        (Some(f), Some(i)) => {
            let above = i.z_at(q) - f.z_at(p_from);
            above <= p.free_space_dz_m && -above <= p.free_space_dz_below_m
        }
        _ => true,
    }
}

/// Whether `into`'s beam towards `q` (its frame; `from`'s point `i`) runs along the surface
/// `from` saw the point on, past `Tolerance::grazing_cos`, and `into` itself saw that surface
/// nearer, where its beams met it less obliquely: its beam can then have passed beside the
/// surface (a stronger target behind outshining the grazed wall) without contradicting it.
/// Without the nearer sighting a wrong pose could lay any radial wall along `into`'s beams.
/// Points on no fitted surface never graze.
#[inline]
fn grazes(
    from: &ScanModel,
    into: &ScanModel,
    i: usize,
    into_from_from: &Pose2,
    q: &Point2<f64>,
    p: &Tolerance,
) -> bool {
    let (Some(true), Some(n)) = (from.surface.get(i), from.normals.get(i)) else {
        return false;
    };
    let r = q.coords.norm();
    let n = into_from_from.rotation * n;
    let off = n.dot(&q.coords);
    if r < 1e-9 || off.abs() >= p.grazing_cos * r {
        return false;
    }
    // Walk the surface's line from q towards its foot nearest `into`.
    let along = q.coords - n * off;
    let length_m = along.norm();
    let step = along * (GRAZE_STEP_M / length_m);
    let steps = (length_m / GRAZE_STEP_M) as usize;
    let into_pts = into.points();
    (1..steps).any(|k| {
        let s = q - step * k as f64;
        into.grid.nearest(&s).is_some_and(|j| {
            let seen = into_pts[j];
            (seen - s).norm() < p.hit_m && n.dot(&(seen - q)).abs() < p.hit_m
        })
    })
}

/// Step of the walk along a grazed surface looking for `into`'s own sighting of it, m.
const GRAZE_STEP_M: f64 = 0.25;

/// Hit distance and free-space margins of one scoring pass.
#[derive(Debug, Clone, Copy)]
struct Tolerance {
    hit_m: f64,
    free_margin_m: f64,
    free_margin_frac: f64,
    free_space_dz_m: f64,
    free_space_dz_below_m: f64,
    grazing_cos: f64,
    violation_weight: f64,
}

impl Tolerance {
    /// A refined pose's tolerances, as `p` sets them.
    fn of(p: &RegisterParams) -> Self {
        Tolerance {
            hit_m: p.hit_m,
            free_margin_m: p.free_margin_m,
            free_margin_frac: p.free_margin_frac,
            free_space_dz_m: p.free_space_dz_m,
            free_space_dz_below_m: p.free_space_dz_below_m,
            grazing_cos: p.free_space_grazing_deg.to_radians().cos(),
            violation_weight: p.violation_weight,
        }
    }
}

/// Scores the pose `a_from_b` of B in A's frame.
pub fn score(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2, p: &RegisterParams) -> PoseScore {
    score_with(a, b, a_from_b, &Tolerance::of(p))
}

/// Scores an unrefined hypothesis: its heading may be a degree off, so hits and free-space
/// margins are widened by `coarse_slack_m`.
pub fn score_coarse(
    a: &ScanModel,
    b: &ScanModel,
    a_from_b: &Pose2,
    p: &RegisterParams,
) -> PoseScore {
    let t = Tolerance {
        hit_m: p.hit_m + p.coarse_slack_m,
        free_margin_m: p.free_margin_m + p.coarse_slack_m,
        ..Tolerance::of(p)
    };
    score_with(a, b, a_from_b, &t)
}

fn score_with(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2, p: &Tolerance) -> PoseScore {
    let b_in_a = score_dir(b, a, a_from_b, p);
    let a_in_b = score_dir(a, b, &a_from_b.inverse(), p);
    let value = 0.5 * (a_in_b.hit + b_in_a.hit)
        - p.violation_weight * (a_in_b.violation + b_in_a.violation);
    PoseScore {
        a_in_b,
        b_in_a,
        value,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::ScanPoint;
    use crate::register::model::ScanPlane;

    /// A level sensor at the origin, facing +x, that saw a straight surface across its view
    /// at `range_m` (±40°, 0.25° steps), mounted at `height_m` (None: mount unknown).
    pub(crate) fn facing(range_m: f64, height_m: Option<f64>) -> ScanModel {
        let step = 0.25f64.to_radians();
        let points: Vec<ScanPoint> = (-160..=160)
            .enumerate()
            .map(|(beam, k)| {
                let a = k as f64 * step;
                ScanPoint {
                    p: Point2::new(range_m, range_m * a.tan()),
                    beam,
                    z_m: height_m,
                }
            })
            .collect();
        let model = ScanModel::new(&points, step, &RegisterParams::default());
        ScanModel {
            plane: height_m.map(|height_m| ScanPlane {
                height_m,
                slope: 0.0,
            }),
            ..model
        }
    }

    /// Two units of the corridor crossing (`fixtures/plans-crowd/corridor-cross.toml`, no
    /// crowd): x stands 0.2 m from the wall of the south arm and looks along it, s sees that
    /// wall from 2–6 m. At the true pose x's beams, grazing the wall, must not contradict
    /// what s saw on it.
    #[test]
    fn a_beam_running_along_a_wall_does_not_contradict_what_another_unit_saw_on_it() {
        use crate::sim::{Plan, Simulation};
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures/plans-crowd/corridor-cross.toml");
        let mut plan = Plan::load(&path).expect("the plan");
        plan.crowds.clear();
        let mut sim = Simulation::new(&plan, 1).expect("a simulation");
        let infos = sim.sensors().to_vec();
        let mut first: Vec<Option<crate::scan::Scan>> = vec![None; infos.len()];
        sim.run(0.2, |i, scan| {
            if let Some(slot) = first.get_mut(i) {
                slot.get_or_insert(scan);
            }
            Ok::<(), std::convert::Infallible>(())
        })
        .ok();
        let p = RegisterParams::default();
        let unit = |id: &str| {
            let k = infos.iter().position(|s| s.id == id).expect(id);
            let info = &infos[k];
            let scan = first[k].as_ref().expect("a scan");
            let model = ScanModel::from_scan(scan, info.geometry.as_ref(), &info.mount(), &p);
            let t = info.truth.expect("truth");
            (
                model,
                crate::geometry::pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()),
            )
        };
        let ((s, site_s), (x, site_x)) = (unit("s"), unit("x"));
        let truth = site_x.inverse() * site_s;
        let along = score(&x, &s, &truth, &p).violation();
        assert!(along < p.max_violation, "violation {along:.2} at the truth");
        let strict = RegisterParams {
            free_space_grazing_deg: 90.0,
            ..p.clone()
        };
        let counted = score(&x, &s, &truth, &strict).violation();
        println!("violation at the truth {along:.2}, with grazing beams counted {counted:.2}");
        assert!(counted > along + 0.1, "{counted:.2} against {along:.2}");
    }

    #[test]
    fn a_beam_passing_over_what_a_lower_unit_saw_does_not_contradict_it() {
        let p = RegisterParams::default();
        let same = Pose2::identity();
        // Both at one spot: the low unit (0.8 m) hits a 1 m box 3 m out, the high one (1.5 m)
        // sees over it to the wall at 6 m.
        let (low, high) = (facing(3.0, Some(0.8)), facing(6.0, Some(1.5)));
        let s = score(&high, &low, &same, &p);
        assert!(s.a_in_b.violation < 0.01, "{s:?}");
        assert!(s.b_in_a.violation < 0.01, "{s:?}");
        // Mounts unknown: the scans are taken to sweep one plane, and the box contradicts.
        let s = score(&facing(6.0, None), &facing(3.0, None), &same, &p);
        assert!(s.b_in_a.violation > 0.9, "{s:?}");
        // Objects stand on the floor: a low beam that passed where the high unit saw something
        // would have hit it too, so that still contradicts.
        let (low_far, high_near) = (facing(6.0, Some(0.8)), facing(3.0, Some(1.5)));
        let s = score(&low_far, &high_near, &same, &p);
        assert!(s.b_in_a.violation > 0.9, "{s:?}");
    }
}
