//! People: discs walking a closed loop through their waypoints at constant speed.

use super::plan::Person;

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
        let i = self
            .at_m
            .partition_point(|&a| a <= s)
            .clamp(1, self.corners.len() - 1);
        let (a, b) = (self.corners[i - 1], self.corners[i]);
        let leg_m = self.at_m[i] - self.at_m[i - 1];
        let f = if leg_m > 0.0 {
            (s - self.at_m[i - 1]) / leg_m
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
