//! Which floor points a plan's sensors can see past its walls, boxes and pillars: the floor
//! a tracker can be asked to cover.

use super::PlanError;
use super::plan::Plan;
use super::scene::{Ray, Scene};

/// The plan's static scene and its sensors, to ask whether a point is in a sensor's sight.
#[derive(Debug, Clone)]
pub struct Sightlines {
    scene: Scene,
    /// Each sensor's (x, y, height, yaw, half field of view).
    sensors: Vec<[f64; 5]>,
}

impl Sightlines {
    pub fn new(plan: &Plan) -> Result<Sightlines, PlanError> {
        Ok(Sightlines {
            scene: Scene::build(plan)?,
            sensors: plan
                .sensors
                .iter()
                .map(|s| {
                    let g = s.model.geometry();
                    let half = g
                        .angle_of_step_rad(g.amax)
                        .abs()
                        .max(g.angle_of_step_rad(g.amin).abs());
                    [s.x, s.y, s.height_m, s.yaw_deg.to_radians(), half]
                })
                .collect(),
        })
    }

    /// Whether some sensor within `range_m` has a clear horizontal line, at its own height and
    /// inside its field of view, to within `body_m` of `p`.
    pub fn seen(&self, p: [f64; 2], range_m: f64, body_m: f64) -> bool {
        self.sensors.iter().any(|&[x, y, z, yaw, half]| {
            let (dx, dy) = (p[0] - x, p[1] - y);
            let d = dx.hypot(dy);
            if d > range_m || d < 1e-6 {
                return d < 1e-6;
            }
            let bearing = crate::geometry::wrap_angle_rad(dy.atan2(dx) - yaw);
            if bearing.abs() > half {
                return false;
            }
            let ray = Ray {
                origin: [x, y, z],
                dir: [dx / d, dy / d, 0.0],
            };
            self.scene
                .cast(&ray)
                .is_none_or(|hit| hit.range_m >= d - body_m)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shelf_hides_the_aisle_behind_it_and_the_blind_sector_sees_nothing() {
        let plan = Plan::from_toml(
            r#"
name = "aisle"
[[wall]]
points = [[0, 0], [20, 0], [20, 10], [0, 10]]
closed = true
[[box]]
center = [10, 5]
size = [12, 0.9]
height_m = 1.8
[[sensor]]
id = "s"
model = "UTM-30LX-EW"
x = 10.0
y = 0.5
yaw_deg = 90
height_m = 1.0
"#,
            "aisle.toml",
        )
        .unwrap();
        let sight = Sightlines::new(&plan).unwrap();
        // In front of the shelf, and past its end.
        assert!(sight.seen([10.0, 3.0], 30.0, 0.3));
        assert!(sight.seen([19.0, 6.0], 30.0, 0.3));
        // Behind it.
        assert!(!sight.seen([10.0, 7.0], 30.0, 0.3));
        // Out of reach.
        assert!(!sight.seen([10.0, 3.0], 2.0, 0.3));
        // Just in front of the sensor's back, in its 90° blind sector (looking north, 270°).
        let behind = Sightlines::new(&Plan {
            sensors: vec![crate::sim::plan::SensorPlan {
                y: 5.0,
                x: 3.0,
                ..plan.sensors[0].clone()
            }],
            ..plan.clone()
        })
        .unwrap();
        assert!(!behind.seen([3.0, 3.0], 30.0, 0.3));
        assert!(behind.seen([1.0, 5.0], 30.0, 0.3));
    }
}
