//! How much two sensors see of the same things: the fixture plans are tuned with this.

use std::collections::HashMap;

use super::PlanError;
use super::plan::Plan;
use super::scene::{Scene, Surface};
use super::simulation::beam_rays;

/// Fraction of B's static returns (noise-free, no people, initial poses) that lie within `tol_m`
/// of a return of A seen from the same side, and the same the other way; returns the smaller.
///
/// Plan walls have no thickness, so a sensor outside a wall (or behind a partition) sees points
/// that coincide with the other face's: those are not shared view (a real wall's faces lie its
/// thickness apart, and the two sensors see different surfaces), so a pair of returns counts
/// only when both beams strike the surface from the same side.
///
/// Returns are the centre rays' hits within [DMIN, DMAX], as horizontal points in the site
/// frame. Floor and ceiling hits are left out: registration drops them (METHOD.md §1), so they
/// are not shared view.
pub fn view_overlap(plan: &Plan, a_id: &str, b_id: &str, tol_m: f64) -> Result<f64, PlanError> {
    let scene = Scene::build(plan)?;
    let points = |id: &str| -> Result<Vec<Return>, PlanError> {
        let sensor = plan.sensor(id).ok_or_else(|| {
            let known: Vec<&str> = plan.sensors.iter().map(|s| s.id.as_str()).collect();
            PlanError::new(
                &plan.origin,
                None,
                Some("sensor.id"),
                format!(
                    "`{id}` is not a sensor of this plan; known: {}",
                    known.join(", ")
                ),
            )
        })?;
        let geometry = sensor.model.geometry();
        let (dmin_m, dmax_m) = (
            geometry.dmin_mm as f64 / 1000.0,
            geometry.dmax_mm as f64 / 1000.0,
        );
        let pose = [sensor.x, sensor.y, sensor.yaw_deg.to_radians()];
        let hits: Vec<([f64; 2], [f64; 2])> = beam_rays(sensor, &geometry, pose)
            .iter()
            .filter_map(|[_, centre, _]| {
                let hit = scene.cast(centre)?;
                let wall = matches!(hit.surface, Surface::Shape(_));
                (wall && (dmin_m..=dmax_m).contains(&hit.range_m))
                    .then(|| (centre.xy_at(hit.range_m), [centre.dir[0], centre.dir[1]]))
            })
            .collect();
        Ok(with_normals(&hits))
    };
    if !(tol_m.is_finite() && tol_m > 0.0) {
        return Err(PlanError::new(
            &plan.origin,
            None,
            Some("tol_m"),
            format!("is {tol_m}; use a distance > 0 m"),
        ));
    }
    let a = points(a_id)?;
    let b = points(b_id)?;
    Ok(covered(&a, &b, tol_m).min(covered(&b, &a, tol_m)))
}

/// One static return: where it lies, the beam's direction and the surface's normal there
/// (from the neighbouring returns; `None` where they are too far to tell).
#[derive(Debug, Clone, Copy)]
struct Return {
    at: [f64; 2],
    dir: [f64; 2],
    normal: Option<[f64; 2]>,
}

/// Surface normals from each return's neighbours along the scan (within 0.3 m).
fn with_normals(hits: &[([f64; 2], [f64; 2])]) -> Vec<Return> {
    let dist = |p: &[f64; 2], q: &[f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]);
    (0..hits.len())
        .map(|i| {
            let (at, dir) = hits[i];
            let near = |j: usize| hits.get(j).map(|h| h.0).filter(|q| dist(q, &at) <= 0.3);
            let before = i.checked_sub(1).and_then(near).unwrap_or(at);
            let after = near(i + 1).unwrap_or(at);
            let t = [after[0] - before[0], after[1] - before[1]];
            let len = t[0].hypot(t[1]);
            let normal = (len > 1e-6).then(|| [-t[1] / len, t[0] / len]);
            Return { at, dir, normal }
        })
        .collect()
}

/// Fraction of `of` within `tol_m` of some return of `by` that struck the surface from the same
/// side.
fn covered(by: &[Return], of: &[Return], tol_m: f64) -> f64 {
    if of.is_empty() {
        return 0.0;
    }
    let cell = |p: &[f64; 2]| ((p[0] / tol_m).floor() as i64, (p[1] / tol_m).floor() as i64);
    let mut grid: HashMap<(i64, i64), Vec<Return>> = HashMap::new();
    for r in by {
        grid.entry(cell(&r.at)).or_default().push(*r);
    }
    let same_side = |p: &Return, q: &Return| {
        let dot = |n: &[f64; 2], d: &[f64; 2]| n[0] * d[0] + n[1] * d[1];
        q.normal
            .or(p.normal)
            .is_none_or(|n| dot(&n, &p.dir) * dot(&n, &q.dir) > 0.0)
    };
    let near = |p: &Return| {
        let (cx, cy) = cell(&p.at);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                grid.get(&(cx + dx, cy + dy)).is_some_and(|qs| {
                    qs.iter().any(|q| {
                        (p.at[0] - q.at[0]).hypot(p.at[1] - q.at[1]) <= tol_m && same_side(p, q)
                    })
                })
            })
        })
    };
    of.iter().filter(|p| near(p)).count() as f64 / of.len() as f64
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    /// Pairwise overlaps of a fixture plan at 0.10 m, printed (`cargo test fixture -- --nocapture`).
    fn overlaps(file: &str) -> Vec<(String, String, f64)> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(if file.contains('/') {
                "fixtures"
            } else {
                "fixtures/plans"
            })
            .join(file);
        let plan = Plan::load(&path).unwrap();
        let mut out = Vec::new();
        for (i, a) in plan.sensors.iter().enumerate() {
            for b in &plan.sensors[i + 1..] {
                let o = view_overlap(&plan, &a.id, &b.id, 0.10).unwrap();
                println!("{file}: {} – {}: {:.0} %", a.id, b.id, o * 100.0);
                out.push((a.id.clone(), b.id.clone(), o));
            }
        }
        out
    }

    #[test]
    fn lab_pairs_overlap_30_to_70_percent() {
        for (a, b, o) in overlaps("lab.toml") {
            assert!((0.30..=0.70).contains(&o), "{a}–{b}: {o}");
        }
    }

    #[test]
    fn hall_has_one_pair_sharing_about_a_fifth_and_level_pairs_a_quarter_or_more() {
        for (a, b, o) in overlaps("hall.toml") {
            if (a.as_str(), b.as_str()) == ("gate", "tough") {
                assert!((0.15..=0.25).contains(&o), "{a}–{b}: {o}");
            } else if a != "tilt" && b != "tilt" {
                assert!((0.25..=0.70).contains(&o), "{a}–{b}: {o}");
            }
        }
    }

    /// The crowd plans (fixtures/plans-crowd): neighbours in the halls and the shop share a
    /// good part of their views; the open hall's, the glass shop's and the corridor crossing's
    /// pairs include some that share floor but little static view.
    #[test]
    fn crowd_plans_share_views_as_their_headers_say() {
        for plan in ["hall20", "shop20"] {
            let all = overlaps(&format!("plans-crowd/{plan}.toml"));
            let ids: std::collections::BTreeSet<&str> = all
                .iter()
                .flat_map(|(a, b, _)| [a.as_str(), b.as_str()])
                .collect();
            for id in ids {
                let good = all
                    .iter()
                    .filter(|(a, b, o)| (a == id || b == id) && *o >= 0.30)
                    .count();
                assert!(good >= 2, "{plan}: {id} shares ≥ 30 % with {good} others");
            }
        }
        for plan in ["open-hall", "glass-shop", "corridor-cross"] {
            let all = overlaps(&format!("plans-crowd/{plan}.toml"));
            assert!(
                all.iter().any(|(_, _, o)| *o < 0.10),
                "{plan}: no pair with little shared view"
            );
        }
    }

    #[test]
    fn the_two_faces_of_a_wall_are_not_shared_view() {
        // One free-standing 10 m wall (no thickness): `north` and `also_north` see its north
        // face, `south` its south face at the very same points.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wall.toml");
        let sensor = |id: &str, x: f64, y: f64, yaw: f64| {
            format!(
                "[[sensor]]\nid = \"{id}\"\nmodel = \"UTM-30LX-EW\"\nx = {x}\ny = {y}\nyaw_deg = {yaw}\n"
            )
        };
        let text = format!(
            "name = \"wall\"\n[[wall]]\npoints = [[0, 0], [10, 0]]\n{}{}{}",
            sensor("north", 5.0, 3.0, -90.0),
            sensor("also_north", 3.5, 2.5, -90.0),
            sensor("south", 5.0, -3.0, 90.0)
        );
        std::fs::write(&path, text).unwrap();
        let plan = Plan::load(&path).unwrap();
        let across = view_overlap(&plan, "north", "south", 0.10).unwrap();
        let along = view_overlap(&plan, "north", "also_north", 0.10).unwrap();
        assert!(across < 0.02, "opposite faces counted as shared: {across}");
        assert!(along > 0.5, "the same face from nearby: {along}");
    }

    /// A plan without what locates it in its file, to compare plans across files.
    fn placeless(mut plan: Plan) -> Plan {
        plan.origin.clear();
        plan.name.clear();
        plan.moves.clear();
        plan.walls.iter_mut().for_each(|x| x.line = None);
        plan.boxes.iter_mut().for_each(|x| x.line = None);
        plan.circles.iter_mut().for_each(|x| x.line = None);
        plan.doors.iter_mut().for_each(|x| x.line = None);
        plan.sensors.iter_mut().for_each(|x| x.line = None);
        plan.people.iter_mut().for_each(|x| x.line = None);
        plan
    }

    #[test]
    fn moved_is_the_lab_with_bench_shifted_half_a_metre_and_turned_ten_degrees_at_one_second() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans");
        let lab = Plan::load(&dir.join("lab.toml")).unwrap();
        let moved = Plan::load(&dir.join("moved.toml")).unwrap();
        assert_eq!(moved.name, "moved");
        let moves = moved.moves.clone();
        let [m] = moves.as_slice() else {
            panic!("moved.toml should have exactly one move");
        };
        assert_eq!((m.sensor.as_str(), m.at_s), ("bench", 1.0));
        assert!((m.dx.hypot(m.dy) - 0.5).abs() < 1e-9 && m.dyaw_deg == 10.0);
        assert_eq!(placeless(lab), placeless(moved.clone()));
        // After the move, bench still shares 30–70 % with every other sensor.
        let mut after = moved;
        if let Some(s) = after.sensors.iter_mut().find(|s| s.id == "bench") {
            s.x += m.dx;
            s.y += m.dy;
            s.yaw_deg += m.dyaw_deg;
        }
        for other in ["entrance", "north", "east"] {
            let o = view_overlap(&after, "bench", other, 0.10).unwrap();
            println!(
                "moved.toml after the move: bench – {other}: {:.0} %",
                o * 100.0
            );
            assert!(
                (0.30..=0.70).contains(&o),
                "bench–{other} after the move: {o}"
            );
        }
    }
}
