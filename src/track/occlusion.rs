//! What one sensor's latest scan says of a spot: in its clear view, hidden behind people
//! nearer, or out of its reach (beyond its range or field of view, or behind the static
//! scene). A track whose person no sensor saw, where every sensor that reaches the spot has
//! people in the way, is hidden (as one of a group walking down a corridor), not gone: the
//! tracker carries it on. Behind a wall or a shelf it is out of view, and ends as usual.

use nalgebra::Point2;

use crate::geometry::ScanPoint;

/// What a sensor's scan says of one spot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sight {
    /// A beam reaches the spot (or passes it, or strikes a body there).
    Clear,
    /// Something stands in front of it on every beam that points there, people among them.
    Hidden,
    /// Out of the scan's field of view or range, or behind its background.
    Outside,
}

/// One scan's returns, sensor frame, by bearing.
#[derive(Debug, Clone, Default)]
pub struct View {
    /// (bearing rad, horizontal range m, short of the background) of each return, bearing
    /// ascending.
    returns: Vec<(f64, f64, bool)>,
    /// Bearings a beam is taken to cover either side of its own (rad).
    half_beam_rad: f64,
    /// The bearings of its first and last return: its field of view (rad).
    fov: (f64, f64),
}

impl View {
    /// The view of a scan's projected returns (sensor frame); `beam_rad` is its angular step
    /// and `moved` says which beams are short of the background. A sensor's blind sector
    /// lies behind it, where atan2 wraps, so its returns' bearings run from the first beam's
    /// to the last's.
    pub fn of(points: &[ScanPoint], beam_rad: f64, moved: impl Fn(usize) -> bool) -> View {
        let mut returns: Vec<(f64, f64, bool)> = points
            .iter()
            .map(|sp| (sp.p.y.atan2(sp.p.x), sp.p.coords.norm(), moved(sp.beam)))
            .collect();
        returns.sort_by(|a, b| a.0.total_cmp(&b.0));
        let fov = match (returns.first(), returns.last()) {
            (Some(a), Some(b)) => (a.0, b.0),
            _ => (0.0, -1.0),
        };
        View {
            returns,
            half_beam_rad: 1.5 * beam_rad.abs(),
            fov,
        }
    }

    /// What the scan says of `at` (sensor frame): clear when a return within a beam and a
    /// half of its bearing reaches it (is no more than `body_m` short of it), or none came
    /// back there (nothing in the way up to `range_m`); else hidden when one of those in
    /// front is short of the background (a person), out of view when all are background.
    pub fn sight(&self, at: &Point2<f64>, range_m: f64, body_m: f64) -> Sight {
        let d = at.coords.norm();
        let bearing = at.y.atan2(at.x);
        if d > range_m || bearing < self.fov.0 || bearing > self.fov.1 {
            return Sight::Outside;
        }
        let from = self
            .returns
            .partition_point(|r| r.0 < bearing - self.half_beam_rad);
        let near = self.returns[from..]
            .iter()
            .take_while(|r| r.0 <= bearing + self.half_beam_rad);
        let (mut any, mut people) = (false, false);
        for &(_, r, moved) in near {
            if r >= d - body_m {
                return Sight::Clear;
            }
            any = true;
            people |= moved;
        }
        match (any, people) {
            (false, _) => Sight::Clear,
            (true, true) => Sight::Hidden,
            (true, false) => Sight::Outside,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(beam: usize, bearing_deg: f64, r: f64) -> ScanPoint {
        let a = bearing_deg.to_radians();
        ScanPoint {
            p: Point2::new(r * a.cos(), r * a.sin()),
            beam,
            z_m: None,
        }
    }

    #[test]
    fn a_spot_behind_a_nearer_return_is_hidden_one_the_beams_reach_is_clear() {
        let step = 0.25f64;
        // A wall at 10 m; someone at 3 m on bearings 9.5°..10.5°, a pillar (background) at 4 m
        // on 29.5°..30.5°.
        let points: Vec<ScanPoint> = (0..=400)
            .map(|k| {
                let deg = -50.0 + k as f64 * step;
                let r = if (9.5..=10.5).contains(&deg) {
                    3.0
                } else if (29.5..=30.5).contains(&deg) {
                    4.0
                } else {
                    10.0
                };
                point(k, deg, r)
            })
            .collect();
        let person = |beam: usize| points.get(beam).is_some_and(|p| p.p.coords.norm() < 3.5);
        let view = View::of(&points, step.to_radians(), person);
        let at = |deg: f64, r: f64| {
            let a = deg.to_radians();
            Point2::new(r * a.cos(), r * a.sin())
        };
        assert_eq!(view.sight(&at(10.0, 6.0), 25.0, 0.3), Sight::Hidden);
        assert_eq!(view.sight(&at(20.0, 6.0), 25.0, 0.3), Sight::Clear);
        assert_eq!(view.sight(&at(30.0, 6.0), 25.0, 0.3), Sight::Outside);
        // The body the beams strike is in clear view.
        assert_eq!(view.sight(&at(10.0, 3.2), 25.0, 0.3), Sight::Clear);
        assert_eq!(view.sight(&at(80.0, 6.0), 25.0, 0.3), Sight::Outside);
        assert_eq!(view.sight(&at(20.0, 30.0), 25.0, 0.3), Sight::Outside);
        // No return at all there: nothing in the way.
        let gap: Vec<ScanPoint> = points.into_iter().filter(|p| p.beam % 100 > 20).collect();
        let view = View::of(&gap, step.to_radians(), |_| false);
        assert_eq!(view.sight(&at(-23.0, 6.0), 25.0, 0.3), Sight::Clear);
    }
}
