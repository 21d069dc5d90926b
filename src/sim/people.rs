//! People: discs walking a closed loop through their waypoints at constant speed
//! (`[[person]]`), and crowd bodies as a scanner sees them at its height: two legs that swing
//! with the gait, a torso ellipse turned to the walking direction, a head.

use super::crowd::BodyNow;
use super::plan::Person;
use super::scene::{Cylinder, Ellipse, Extent, Hit, Ray, Surface, hit_cylinder, hit_ellipse};

/// Torso: 0.45 m across the walking direction, 0.28 m along it.
pub(crate) const TORSO_HALF_ACROSS_M: f64 = 0.225;
pub(crate) const TORSO_HALF_ALONG_M: f64 = 0.14;
/// Legs: 0.12 m discs, hips 0.2 m apart.
pub(crate) const LEG_RADIUS_M: f64 = 0.06;
const HIP_HALF_M: f64 = 0.1;
const HEAD_RADIUS_M: f64 = 0.09;
/// Legs reach this share of the height, the torso the next part up to `SHOULDER`.
const HIP: f64 = 0.46;
const SHOULDER: f64 = 0.82;
/// One gait cycle (two steps), m walked.
pub(crate) const STRIDE_M: f64 = 1.4;
/// Farthest any part of a body lies from its centre, m.
pub(crate) const BODY_REACH_M: f64 = 0.45;

/// How far a foot swings ahead of (or behind) the hip at speed `v`, m.
fn swing_m(v: f64) -> f64 {
    ((0.12 + 0.1 * v) * (v / 0.3).min(1.0)).clamp(0.0, 0.32)
}

/// A crowd body `dt_s` after its state, ready to be ray-cast.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Body {
    torso: Ellipse,
    legs: [Cylinder; 2],
    head: Cylinder,
}

impl Body {
    pub fn at(now: &BodyNow, dt_s: f64) -> Body {
        let s = &now.state;
        let center = [s.pos[0] + now.vel[0] * dt_s, s.pos[1] + now.vel[1] * dt_s];
        let speed = now.vel[0].hypot(now.vel[1]);
        let along = s.heading;
        let across = [-along[1], along[0]];
        let phase = (s.gait_m + speed * dt_s) / STRIDE_M * std::f64::consts::TAU;
        let swing = swing_m(speed) * phase.sin();
        let hip_m = HIP * s.height_m;
        let leg = |side: f64| Cylinder {
            center: [
                center[0] + across[0] * side * HIP_HALF_M + along[0] * side * swing,
                center[1] + across[1] * side * HIP_HALF_M + along[1] * side * swing,
            ],
            radius_m: LEG_RADIUS_M,
            extent: Extent {
                z_min_m: 0.0,
                z_max_m: hip_m,
            },
            reflectivity: s.reflectivity * 0.8,
        };
        Body {
            torso: Ellipse {
                center,
                axis: along,
                half_along_m: TORSO_HALF_ALONG_M,
                half_across_m: TORSO_HALF_ACROSS_M,
                extent: Extent {
                    z_min_m: hip_m,
                    z_max_m: SHOULDER * s.height_m,
                },
                reflectivity: s.reflectivity,
            },
            legs: [leg(1.0), leg(-1.0)],
            head: Cylinder {
                center,
                radius_m: HEAD_RADIUS_M,
                extent: Extent {
                    z_min_m: SHOULDER * s.height_m,
                    z_max_m: s.height_m,
                },
                reflectivity: s.reflectivity * 0.5,
            },
        }
    }

    /// Where the legs stand (centres), for tests.
    #[cfg(test)]
    pub fn leg_centres(&self) -> [[f64; 2]; 2] {
        [self.legs[0].center, self.legs[1].center]
    }

    /// The nearest hit of `ray` on the body.
    pub fn hit(&self, ray: &Ray, surface: Surface) -> Option<Hit> {
        let mut best = hit_ellipse(ray, &self.torso, surface);
        for cyl in self.legs.iter().chain(std::iter::once(&self.head)) {
            if let Some(h) = hit_cylinder(ray, cyl, surface)
                && best.is_none_or(|b| h.range_m < b.range_m)
            {
                best = Some(h);
            }
        }
        best
    }
}

/// A person's path, ready to answer "where at time t".
#[derive(Debug, Clone)]
pub(crate) struct Walker {
    /// Loop corners, the first repeated at the end.
    corners: Vec<[f64; 2]>,
    /// Path length from the start to each corner.
    at_m: Vec<f64>,
    loop_m: f64,
    start_m: f64,
    speed_m_s: f64,
    pub radius_m: f64,
    pub height_m: f64,
}

impl Walker {
    pub fn new(person: &Person) -> Walker {
        let mut corners = person.waypoints.clone();
        if let Some(&first) = corners.first() {
            corners.push(first);
        }
        let mut at_m = vec![0.0];
        for w in corners.windows(2) {
            let last = at_m.last().copied().unwrap_or(0.0);
            at_m.push(last + (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]));
        }
        let loop_m = at_m.last().copied().unwrap_or(0.0);
        Walker {
            corners,
            at_m,
            loop_m,
            start_m: person.phase * loop_m,
            speed_m_s: person.speed_m_s,
            radius_m: person.radius_m,
            height_m: person.height_m,
        }
    }

    /// Position and velocity at `t_s` seconds after the start.
    pub fn state_at(&self, t_s: f64) -> ([f64; 2], [f64; 2]) {
        if self.loop_m <= 0.0 {
            return (
                self.corners.first().copied().unwrap_or([0.0, 0.0]),
                [0.0, 0.0],
            );
        }
        let s = (self.start_m + self.speed_m_s * t_s).rem_euclid(self.loop_m);
        // First corner beyond s; the leg before it holds s.
        let i = self.at_m.partition_point(|&a| a <= s).max(1);
        let (Some(&a), Some(&b), Some(&from_m), Some(&to_m)) = (
            self.corners.get(i - 1),
            self.corners.get(i),
            self.at_m.get(i - 1),
            self.at_m.get(i),
        ) else {
            return (
                self.corners.first().copied().unwrap_or([0.0, 0.0]),
                [0.0, 0.0],
            );
        };
        let leg_m = to_m - from_m;
        let f = if leg_m > 0.0 {
            (s - from_m) / leg_m
        } else {
            0.0
        };
        let dir = if leg_m > 0.0 {
            [(b[0] - a[0]) / leg_m, (b[1] - a[1]) / leg_m]
        } else {
            [0.0, 0.0]
        };
        (
            [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f],
            [dir[0] * self.speed_m_s, dir[1] * self.speed_m_s],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walker(phase: f64) -> Walker {
        Walker::new(&Person {
            line: None,
            waypoints: vec![[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]],
            speed_m_s: 1.0,
            radius_m: 0.25,
            height_m: 1.75,
            phase,
        })
    }

    use crate::sim::crowd::{BodyNow, BodyState};

    fn body(heading: [f64; 2], speed: f64, gait_m: f64) -> Body {
        Body::at(
            &BodyNow {
                state: BodyState {
                    id: 1,
                    pos: [3.0, 0.0],
                    heading,
                    gait_m,
                    height_m: 1.75,
                    reflectivity: 0.5,
                },
                vel: [heading[0] * speed, heading[1] * speed],
            },
            0.0,
        )
    }

    fn range_at(b: &Body, height_m: f64, y: f64) -> Option<f64> {
        let ray = Ray {
            origin: [0.0, y, height_m],
            dir: [1.0, 0.0, 0.0],
        };
        b.hit(&ray, Surface::Person(0)).map(|h| h.range_m)
    }

    #[test]
    fn torso_is_an_ellipse_turned_to_the_walking_direction() {
        // Walking across the beam: the shoulders' 0.45 m face it.
        let across = body([0.0, 1.0], 1.2, 0.0);
        let r = range_at(&across, 1.0, 0.0).unwrap();
        assert!((r - (3.0 - TORSO_HALF_ACROSS_M)).abs() < 1e-9, "{r}");
        assert!(range_at(&across, 1.0, 0.0).is_some());
        // Seen 0.2 m off centre: within the width (0.225) but not the depth (0.14).
        assert!(
            range_at(&across, 1.0, 0.2).is_none(),
            "the torso is 0.28 m deep"
        );
        // Walking away along the beam: its 0.28 m depth.
        let away = body([1.0, 0.0], 1.2, 0.0);
        let r = range_at(&away, 1.0, 0.0).unwrap();
        assert!((r - (3.0 - TORSO_HALF_ALONG_M)).abs() < 1e-9, "{r}");
        assert!(
            range_at(&away, 1.0, 0.2).is_some(),
            "the torso is 0.45 m wide"
        );
        assert!(range_at(&away, 1.0, 0.24).is_none());
    }

    #[test]
    fn at_ankle_height_two_legs_swing_with_the_gait() {
        // Standing, facing along the beam: the beam passes between the legs (0.2 m apart).
        let still = body([1.0, 0.0], 0.0, 0.0);
        assert!(range_at(&still, 0.3, 0.0).is_none(), "between the legs");
        let r = range_at(&still, 0.3, 0.1).unwrap();
        assert!((r - (3.0 - LEG_RADIUS_M)).abs() < 1e-9, "{r}");
        // Walking along the beam: a quarter stride on, one foot is ahead, the other behind.
        let quarter = body([1.0, 0.0], 1.2, STRIDE_M / 4.0);
        let [left, right] = quarter.leg_centres();
        let swing = left[0] - 3.0;
        assert!((0.15..0.35).contains(&swing), "swing {swing}");
        assert!((right[0] - 3.0 + swing).abs() < 1e-9);
        let near = range_at(&quarter, 0.3, -0.1).unwrap();
        let far = range_at(&quarter, 0.3, 0.1).unwrap();
        assert!((far - near - 2.0 * swing).abs() < 1e-9, "{near} {far}");
        // Half a stride on, they have swapped.
        let half = body([1.0, 0.0], 1.2, STRIDE_M * 0.75);
        assert!(range_at(&half, 0.3, 0.1).unwrap() < range_at(&half, 0.3, -0.1).unwrap());
        // Above the hips, the torso; the legs are not seen at 1 m.
        assert!(
            (range_at(&quarter, 1.0, 0.1).unwrap()
                - (3.0 - 0.14 * (1.0f64 - (0.1f64 / 0.225).powi(2)).sqrt()))
            .abs()
                < 1e-6
        );
    }

    #[test]
    fn walks_the_loop_back_to_the_start() {
        let w = walker(0.0);
        // Loop: 4 + 3 + 5 = 12 m.
        let close = |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) < 1e-9;
        assert!(close(w.state_at(0.0).0, [0.0, 0.0]));
        assert!(close(w.state_at(2.0).0, [2.0, 0.0]));
        assert!(close(w.state_at(5.0).0, [4.0, 1.0]));
        assert!(close(w.state_at(9.5).0, [2.0, 1.5]));
        assert!(close(w.state_at(12.0).0, [0.0, 0.0]));
        let (_, v) = w.state_at(9.5);
        assert!(close(v, [-0.8, -0.6]));
        // Phase 0.5 starts 6 m round the loop.
        assert!(close(walker(0.5).state_at(0.0).0, [4.0, 2.0]));
    }
}
