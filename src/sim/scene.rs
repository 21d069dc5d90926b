//! The static scene as ray-castable geometry: wall segments (doors cut out), boxes and
//! cylinders extruded between two heights, the floor and an optional ceiling.
//!
//! Rays are 3D beams from a sensor; a shape is hit only where the beam's height at the hit lies
//! within the shape's extent, and boxes and cylinders have top and bottom faces, so a tilted
//! beam can land on a desk top or pass over it.

use super::PlanError;
use super::plan::{DOOR_SNAP_M, Plan};

/// Beams closer than this to their origin do not count as hits (the sensor's own window).
const MIN_HIT_M: f64 = 1e-6;

/// One beam: origin (x, y, z) in the site frame and a unit direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Ray {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
}

impl Ray {
    /// The beam of a sensor at (x, y, height) with heading `yaw_rad` and tilt `pitch_rad`, at
    /// angle `theta_rad` in its scan plane: METHOD.md §1, (cosθ cosφ, sinθ, cosθ sinφ) rotated by yaw.
    pub fn from_sensor(pose: [f64; 3], height_m: f64, pitch_rad: f64, theta_rad: f64) -> Ray {
        let [x, y, yaw] = pose;
        let (sin_t, cos_t) = theta_rad.sin_cos();
        let (sin_p, cos_p) = pitch_rad.sin_cos();
        let (sin_y, cos_y) = yaw.sin_cos();
        let fx = cos_t * cos_p;
        let fy = sin_t;
        Ray {
            origin: [x, y, height_m],
            dir: [
                cos_y * fx - sin_y * fy,
                sin_y * fx + cos_y * fy,
                cos_t * sin_p,
            ],
        }
    }

    /// Horizontal position at range `d`.
    pub fn xy_at(&self, range_m: f64) -> [f64; 2] {
        [
            self.origin[0] + range_m * self.dir[0],
            self.origin[1] + range_m * self.dir[1],
        ]
    }
}

/// What a ray struck.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Hit {
    pub range_m: f64,
    /// |cos| of the angle between the beam and the surface normal.
    pub cos_incidence: f64,
    pub reflectivity: f64,
    pub surface: Surface,
}

/// Which surface a hit lies on; two hits on the same surface are not a depth edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Surface {
    Shape(u32),
    Floor,
    Ceiling,
    Person(u32),
}

/// A vertical extent, m above the floor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Extent {
    pub z_min_m: f64,
    pub z_max_m: f64,
}

impl Extent {
    /// The range interval over which the ray's height lies within the extent.
    fn range_interval(&self, ray: &Ray) -> Option<(f64, f64)> {
        let (z0, uz) = (ray.origin[2], ray.dir[2]);
        if uz.abs() < 1e-12 {
            return (self.z_min_m..=self.z_max_m)
                .contains(&z0)
                .then_some((f64::NEG_INFINITY, f64::INFINITY));
        }
        let a = (self.z_min_m - z0) / uz;
        let b = (self.z_max_m - z0) / uz;
        Some((a.min(b), a.max(b)))
    }

    fn contains(&self, z: f64) -> bool {
        z >= self.z_min_m && z <= self.z_max_m
    }
}

#[derive(Debug, Clone)]
struct Segment {
    a: [f64; 2],
    b: [f64; 2],
    extent: Extent,
    reflectivity: f64,
}

#[derive(Debug, Clone)]
struct Block {
    center: [f64; 2],
    /// Unit vector of the box's own x axis.
    axis: [f64; 2],
    half: [f64; 2],
    extent: Extent,
    reflectivity: f64,
}

/// A vertical cylinder (pillars, bins, people).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cylinder {
    pub center: [f64; 2],
    pub radius_m: f64,
    pub extent: Extent,
    pub reflectivity: f64,
}

/// The static geometry of a plan.
#[derive(Debug, Clone)]
pub(crate) struct Scene {
    segments: Vec<Segment>,
    blocks: Vec<Block>,
    cylinders: Vec<Cylinder>,
    floor_reflectivity: f64,
    ceiling: Option<(f64, f64)>,
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

fn lerp(a: [f64; 2], b: [f64; 2], t: f64) -> [f64; 2] {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t]
}

impl Scene {
    /// The wall pieces (end points, m) left between the doors: what a drawing of the
    /// building shows as walls.
    pub(crate) fn wall_pieces(&self) -> Vec<super::WallPiece> {
        self.segments.iter().map(|s| (s.a, s.b)).collect()
    }

    /// Builds the geometry, cutting each door into the wall segment nearest to it.
    pub fn build(plan: &Plan) -> Result<Scene, PlanError> {
        // Every wall segment with the gaps (arc-length intervals) doors cut into it.
        let mut raw: Vec<(Segment, Vec<(f64, f64)>)> = Vec::new();
        for wall in &plan.walls {
            let extent = Extent {
                z_min_m: wall.z_min_m,
                z_max_m: wall.height_m,
            };
            for (a, b) in wall.segments() {
                raw.push((
                    Segment {
                        a,
                        b,
                        extent,
                        reflectivity: wall.reflectivity,
                    },
                    Vec::new(),
                ));
            }
        }
        for door in &plan.doors {
            let nearest = raw
                .iter_mut()
                .map(|(seg, gaps)| {
                    let e = sub(seg.b, seg.a);
                    let len = dot(e, e).sqrt();
                    let t = (dot(sub(door.at, seg.a), e) / (len * len)).clamp(0.0, 1.0);
                    let foot = lerp(seg.a, seg.b, t);
                    let d = sub(door.at, foot);
                    (dot(d, d).sqrt(), t * len, len, seg, gaps)
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let problem = match nearest {
                None => "there is no wall to cut it into; add a [[wall]]".to_string(),
                Some((dist, ..)) if dist > DOOR_SNAP_M => format!(
                    "{:?} is {dist:.2} m from the nearest wall; put it within {DOOR_SNAP_M} m of the wall it opens",
                    door.at
                ),
                Some((_, along, len, seg, gaps)) => {
                    let (from, to) = (along - door.width_m / 2.0, along + door.width_m / 2.0);
                    if from >= -1e-9 && to <= len + 1e-9 {
                        gaps.push((from.max(0.0), to.min(len)));
                        continue;
                    }
                    format!(
                        "a {} m door at {:?} does not fit in the wall from {:?} to {:?} ({len:.2} m); move it along the wall or narrow it",
                        door.width_m, door.at, seg.a, seg.b
                    )
                }
            };
            return Err(PlanError::new(
                &plan.origin,
                door.line,
                Some("door.at"),
                problem,
            ));
        }
        let mut segments = Vec::new();
        for (seg, mut gaps) in raw {
            let len = dot(sub(seg.b, seg.a), sub(seg.b, seg.a)).sqrt();
            gaps.sort_by(|x, y| x.0.total_cmp(&y.0));
            let mut from = 0.0;
            for (g0, g1) in gaps.into_iter().chain(std::iter::once((len, len))) {
                if g0 - from > 1e-6 {
                    segments.push(Segment {
                        a: lerp(seg.a, seg.b, from / len),
                        b: lerp(seg.a, seg.b, g0 / len),
                        ..seg.clone()
                    });
                }
                from = f64::max(from, g1);
            }
        }
        let blocks = plan
            .boxes
            .iter()
            .map(|b| {
                let (s, c) = b.yaw_deg.to_radians().sin_cos();
                Block {
                    center: b.center,
                    axis: [c, s],
                    half: [b.size[0] / 2.0, b.size[1] / 2.0],
                    extent: Extent {
                        z_min_m: b.z_min_m,
                        z_max_m: b.height_m,
                    },
                    reflectivity: b.reflectivity,
                }
            })
            .collect();
        let cylinders = plan
            .circles
            .iter()
            .map(|c| Cylinder {
                center: c.center,
                radius_m: c.radius_m,
                extent: Extent {
                    z_min_m: c.z_min_m,
                    z_max_m: c.height_m,
                },
                reflectivity: c.reflectivity,
            })
            .collect();
        Ok(Scene {
            segments,
            blocks,
            cylinders,
            floor_reflectivity: plan.floor_reflectivity,
            ceiling: plan.ceiling_m.map(|h| (h, plan.ceiling_reflectivity)),
        })
    }

    /// The nearest hit of `ray` on the static scene, if any.
    pub fn cast(&self, ray: &Ray) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut keep = |hit: Option<Hit>| {
            if let Some(h) = hit
                && best.is_none_or(|b| h.range_m < b.range_m)
            {
                best = Some(h);
            }
        };
        let uz = ray.dir[2];
        if uz < -1e-12 {
            keep(Some(Hit {
                range_m: ray.origin[2] / -uz,
                cos_incidence: -uz,
                reflectivity: self.floor_reflectivity,
                surface: Surface::Floor,
            }));
        }
        if let Some((height_m, reflectivity)) = self.ceiling
            && uz > 1e-12
        {
            keep(Some(Hit {
                range_m: (height_m - ray.origin[2]) / uz,
                cos_incidence: uz,
                reflectivity,
                surface: Surface::Ceiling,
            }));
        }
        let mut id = 0u32;
        for seg in &self.segments {
            keep(hit_segment(ray, seg, Surface::Shape(id)));
            id += 1;
        }
        for block in &self.blocks {
            keep(hit_block(ray, block, Surface::Shape(id)));
            id += 1;
        }
        for cyl in &self.cylinders {
            keep(hit_cylinder(ray, cyl, Surface::Shape(id)));
            id += 1;
        }
        best
    }
}

/// Anything a person cannot pass: it reaches below this height.
pub(crate) const WALK_CLEAR_BELOW_M: f64 = 1.8;

impl Scene {
    /// Whether a person standing at `p` would be within `clearance_m` of a wall, box or pillar
    /// that reaches below [`WALK_CLEAR_BELOW_M`] (doors are gaps, so they are free).
    pub fn blocks_walking(&self, p: [f64; 2], clearance_m: f64) -> bool {
        let low = |e: &Extent| e.z_min_m < WALK_CLEAR_BELOW_M && e.z_max_m > 0.05;
        self.segments
            .iter()
            .any(|s| low(&s.extent) && distance_to_segment(p, s.a, s.b) < clearance_m)
            || self.blocks.iter().any(|b| {
                let rel = sub(p, b.center);
                let u = dot(rel, b.axis).abs() - b.half[0];
                let v = dot(rel, [-b.axis[1], b.axis[0]]).abs() - b.half[1];
                let outside = u.max(0.0).hypot(v.max(0.0));
                low(&b.extent) && (outside < clearance_m)
            })
            || self.cylinders.iter().any(|c| {
                low(&c.extent)
                    && dot(sub(p, c.center), sub(p, c.center)).sqrt() < c.radius_m + clearance_m
            })
    }

    /// Whether the straight step from `a` to `b` crosses a wall (outside its doors) or enters a
    /// box or pillar that a person could not pass: for checking walkers.
    #[cfg(test)]
    pub fn step_crosses_solid(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let low = |e: &Extent| e.z_min_m < WALK_CLEAR_BELOW_M && e.z_max_m > 0.05;
        let d = sub(b, a);
        let crosses = |p: [f64; 2], q: [f64; 2]| {
            let e = sub(q, p);
            let denom = cross(d, e);
            if denom.abs() < 1e-15 {
                return false;
            }
            let w = sub(p, a);
            let t = cross(w, e) / denom;
            let s = cross(w, d) / denom;
            (0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&s)
        };
        self.segments
            .iter()
            .any(|s| low(&s.extent) && crosses(s.a, s.b))
            || [a, b].iter().any(|&p| {
                self.blocks.iter().any(|blk| {
                    let rel = sub(p, blk.center);
                    low(&blk.extent)
                        && dot(rel, blk.axis).abs() < blk.half[0]
                        && dot(rel, [-blk.axis[1], blk.axis[0]]).abs() < blk.half[1]
                }) || self.cylinders.iter().any(|c| {
                    low(&c.extent) && dot(sub(p, c.center), sub(p, c.center)).sqrt() < c.radius_m
                })
            })
    }
}

fn distance_to_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let e = sub(b, a);
    let len2 = dot(e, e);
    let t = if len2 > 0.0 {
        (dot(sub(p, a), e) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let d = sub(p, lerp(a, b, t));
    dot(d, d).sqrt()
}

fn hit_segment(ray: &Ray, seg: &Segment, surface: Surface) -> Option<Hit> {
    let u = [ray.dir[0], ray.dir[1]];
    let e = sub(seg.b, seg.a);
    let denom = cross(u, e);
    if denom.abs() < 1e-12 {
        return None;
    }
    let w = sub(seg.a, [ray.origin[0], ray.origin[1]]);
    let range_m = cross(w, e) / denom;
    let s = cross(w, u) / denom;
    if range_m <= MIN_HIT_M || !(0.0..=1.0).contains(&s) {
        return None;
    }
    if !seg.extent.contains(ray.origin[2] + range_m * ray.dir[2]) {
        return None;
    }
    let len = dot(e, e).sqrt();
    Some(Hit {
        range_m,
        cos_incidence: (cross(u, e) / len).abs(),
        reflectivity: seg.reflectivity,
        surface,
    })
}

/// Entry into a convex prism whose footprint the ray is inside for ranges `inside`
/// (entry normal `side_cos`), clipped by its vertical extent: a side or a cap.
fn enter_prism(
    ray: &Ray,
    inside: (f64, f64),
    side_cos: f64,
    extent: &Extent,
    reflectivity: f64,
    surface: Surface,
) -> Option<Hit> {
    let (z0, z1) = extent.range_interval(ray)?;
    let start = inside.0.max(z0);
    let end = inside.1.min(z1);
    if start > end || start <= MIN_HIT_M {
        return None;
    }
    let cos_incidence = if inside.0 >= z0 {
        side_cos
    } else {
        ray.dir[2].abs()
    };
    Some(Hit {
        range_m: start,
        cos_incidence,
        reflectivity,
        surface,
    })
}

fn hit_block(ray: &Ray, block: &Block, surface: Surface) -> Option<Hit> {
    // Slab test in the box's own frame.
    let rel = sub([ray.origin[0], ray.origin[1]], block.center);
    let ax = block.axis;
    let ay = [-ax[1], ax[0]];
    let o = [dot(rel, ax), dot(rel, ay)];
    let u = [
        ray.dir[0] * ax[0] + ray.dir[1] * ax[1],
        ray.dir[0] * ay[0] + ray.dir[1] * ay[1],
    ];
    let (mut t_in, mut t_out, mut cos_in) = (f64::NEG_INFINITY, f64::INFINITY, 0.0);
    for k in 0..2 {
        if u[k].abs() < 1e-12 {
            if o[k].abs() > block.half[k] {
                return None;
            }
            continue;
        }
        let a = (-block.half[k] - o[k]) / u[k];
        let b = (block.half[k] - o[k]) / u[k];
        let (near, far) = (a.min(b), a.max(b));
        if near > t_in {
            t_in = near;
            cos_in = u[k].abs();
        }
        t_out = t_out.min(far);
    }
    if t_in > t_out {
        return None;
    }
    enter_prism(
        ray,
        (t_in, t_out),
        cos_in,
        &block.extent,
        block.reflectivity,
        surface,
    )
}

/// A ray against a vertical cylinder (also used for people).
pub(crate) fn hit_cylinder(ray: &Ray, cyl: &Cylinder, surface: Surface) -> Option<Hit> {
    let f = sub([ray.origin[0], ray.origin[1]], cyl.center);
    let u = [ray.dir[0], ray.dir[1]];
    let a = dot(u, u);
    if a < 1e-12 {
        return None;
    }
    let b = dot(f, u);
    let c = dot(f, f) - cyl.radius_m * cyl.radius_m;
    let disc = b * b - a * c;
    if disc <= 0.0 {
        return None;
    }
    let root = disc.sqrt();
    let t_in = (-b - root) / a;
    let t_out = (-b + root) / a;
    let p = [f[0] + t_in * u[0], f[1] + t_in * u[1]];
    let side_cos = (dot(p, u) / cyl.radius_m).abs();
    enter_prism(
        ray,
        (t_in, t_out),
        side_cos,
        &cyl.extent,
        cyl.reflectivity,
        surface,
    )
}

/// A vertical elliptic cylinder: a torso. `axis` is the unit direction of the `half_along_m`
/// semi-axis (the walking direction); `half_across_m` lies across it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ellipse {
    pub center: [f64; 2],
    pub axis: [f64; 2],
    pub half_along_m: f64,
    pub half_across_m: f64,
    pub extent: Extent,
    pub reflectivity: f64,
}

/// A ray against a vertical elliptic cylinder.
pub(crate) fn hit_ellipse(ray: &Ray, e: &Ellipse, surface: Surface) -> Option<Hit> {
    let rel = sub([ray.origin[0], ray.origin[1]], e.center);
    let across = [-e.axis[1], e.axis[0]];
    // In the ellipse's frame scaled to a unit circle; the ray parameter stays the range.
    let f = [
        dot(rel, e.axis) / e.half_along_m,
        dot(rel, across) / e.half_across_m,
    ];
    let u_local = [
        ray.dir[0] * e.axis[0] + ray.dir[1] * e.axis[1],
        ray.dir[0] * across[0] + ray.dir[1] * across[1],
    ];
    let u = [u_local[0] / e.half_along_m, u_local[1] / e.half_across_m];
    let a = dot(u, u);
    if a < 1e-12 {
        return None;
    }
    let b = dot(f, u);
    let c = dot(f, f) - 1.0;
    let disc = b * b - a * c;
    if disc <= 0.0 {
        return None;
    }
    let root = disc.sqrt();
    let t_in = (-b - root) / a;
    let t_out = (-b + root) / a;
    // Normal at the entry point: (x / a², y / b²) in the ellipse's frame.
    let p = [f[0] + t_in * u[0], f[1] + t_in * u[1]];
    let normal = [p[0] / e.half_along_m, p[1] / e.half_across_m];
    let n_len = dot(normal, normal).sqrt().max(1e-12);
    let h_len = dot(u_local, u_local).sqrt().max(1e-12);
    let side_cos = (dot(normal, u_local) / (n_len * h_len)).abs();
    enter_prism(
        ray,
        (t_in, t_out),
        side_cos,
        &e.extent,
        e.reflectivity,
        surface,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(text: &str) -> Plan {
        match Plan::from_toml(text, "test.toml") {
            Ok(p) => p,
            Err(e) => panic!("{e}"),
        }
    }

    const ROOM: &str = r#"
name = "room"
[[wall]]
points = [[0, 0], [10, 0], [10, 6], [0, 6]]
closed = true
[[door]]
at = [10, 3]
width_m = 1.0
[[box]]
center = [5, 1.5]
size = [2, 1]
height_m = 0.75
[[circle]]
center = [3, 4]
radius_m = 0.3
"#;

    #[test]
    fn level_beam_hits_wall_square_at_its_distance() {
        let scene = Scene::build(&plan(ROOM)).unwrap();
        // From (7, 5) looking +y: wall y = 6 at 1 m, square on.
        let ray = Ray::from_sensor([7.0, 5.0, std::f64::consts::FRAC_PI_2], 1.0, 0.0, 0.0);
        let hit = scene.cast(&ray).unwrap();
        assert!((hit.range_m - 1.0).abs() < 1e-9);
        assert!((hit.cos_incidence - 1.0).abs() < 1e-9);
    }

    #[test]
    fn door_lets_the_beam_through_and_wall_beside_it_does_not() {
        let scene = Scene::build(&plan(ROOM)).unwrap();
        let through = Ray::from_sensor([8.0, 3.0, 0.0], 1.0, 0.0, 0.0);
        assert!(scene.cast(&through).is_none());
        let beside = Ray::from_sensor([8.0, 3.7, 0.0], 1.0, 0.0, 0.0);
        assert!((scene.cast(&beside).unwrap().range_m - 2.0).abs() < 1e-9);
    }

    #[test]
    fn level_beam_passes_over_a_desk_and_tilted_beam_lands_on_its_top() {
        let scene = Scene::build(&plan(ROOM)).unwrap();
        // Looking -y from (5, 4) at 1 m: the desk top is at 0.75 m, so the beam reaches y = 0.
        let level = Ray::from_sensor([5.0, 4.0, -std::f64::consts::FRAC_PI_2], 1.0, 0.0, 0.0);
        assert!((scene.cast(&level).unwrap().range_m - 4.0).abs() < 1e-9);
        // At 0.5 m it hits the desk's side at y = 2.
        let low = Ray::from_sensor([5.0, 4.0, -std::f64::consts::FRAC_PI_2], 0.5, 0.0, 0.0);
        assert!((scene.cast(&low).unwrap().range_m - 2.0).abs() < 1e-9);
        // Tilted down 10° from 1.2 m: z = 0.75 at horizontal distance 0.45/tan 10° = 2.55 m,
        // which is over the desk (y = 1.45), so it lands on the top with vertical normal.
        let pitch = (-10.0f64).to_radians();
        let tilted = Ray::from_sensor([5.0, 4.0, -std::f64::consts::FRAC_PI_2], 1.2, pitch, 0.0);
        let hit = scene.cast(&tilted).unwrap();
        assert!(
            (hit.range_m - 0.45 / pitch.sin().abs()).abs() < 1e-9,
            "{hit:?}"
        );
        assert!((hit.cos_incidence - pitch.sin().abs()).abs() < 1e-9);
    }

    #[test]
    fn pillar_is_hit_on_its_near_side() {
        let scene = Scene::build(&plan(ROOM)).unwrap();
        let ray = Ray::from_sensor([1.0, 4.0, 0.0], 1.0, 0.0, 0.0);
        let hit = scene.cast(&ray).unwrap();
        assert!((hit.range_m - 1.7).abs() < 1e-9);
        assert!((hit.cos_incidence - 1.0).abs() < 1e-9);
    }

    #[test]
    fn downward_beam_meets_the_floor_at_height_over_sine_of_pitch() {
        let scene = Scene::build(&plan(ROOM)).unwrap();
        let pitch = (-20.0f64).to_radians();
        let ray = Ray::from_sensor([1.0, 3.0, 0.0], 2.5, pitch, 0.0);
        let hit = scene.cast(&ray).unwrap();
        assert_eq!(hit.surface, Surface::Floor);
        assert!((hit.range_m - 2.5 / 20f64.to_radians().sin()).abs() < 1e-9);
    }

    #[test]
    fn door_far_from_any_wall_is_refused_with_its_line() {
        let text = format!("{ROOM}\n[[door]]\nat = [5, 3]\n");
        let err = Plan::from_toml(&text, "room.toml").unwrap_err();
        assert_eq!(err.key.as_deref(), Some("door.at"));
        let at_line = text.lines().position(|l| l == "at = [5, 3]").map(|i| i + 1);
        assert_eq!(err.line, at_line);
        assert!(err.to_string().contains("within 0.5 m"), "{err}");
    }

    /// A box as four walls of the same extent and reflectivity.
    fn box_as_walls(cx: f64, cy: f64, len: f64, wid: f64, yaw_deg: f64) -> Scene {
        let (sin, cos) = yaw_deg.to_radians().sin_cos();
        let corner = |u: f64, v: f64| [cx + cos * u - sin * v, cy + sin * u + cos * v];
        let (hl, hw) = (len / 2.0, wid / 2.0);
        let pts = [
            corner(-hl, -hw),
            corner(hl, -hw),
            corner(hl, hw),
            corner(-hl, hw),
        ];
        let extent = Extent {
            z_min_m: 0.0,
            z_max_m: 1.0,
        };
        Scene {
            segments: (0..4)
                .map(|i| Segment {
                    a: pts[i],
                    b: pts[(i + 1) % 4],
                    extent,
                    reflectivity: 0.5,
                })
                .collect(),
            blocks: Vec::new(),
            cylinders: Vec::new(),
            floor_reflectivity: 0.3,
            ceiling: None,
        }
    }

    proptest::proptest! {
        #[test]
        fn level_beam_from_inside_a_room_lands_on_its_boundary_at_the_nearest_wall(
            x in 0.1f64..9.9, y in 0.1f64..5.9, yaw in -3.2f64..3.2, theta in -2.4f64..2.4,
        ) {
            let scene = Scene::build(&plan(
                "name = \"r\"\n[[wall]]\npoints = [[0, 0], [10, 0], [10, 6], [0, 6]]\nclosed = true\n",
            ))
            .unwrap();
            let ray = Ray::from_sensor([x, y, yaw], 1.0, 0.0, theta);
            let hit = scene.cast(&ray).unwrap();
            let [ux, uy, _] = ray.dir;
            // Distance to each wall line along the beam; the nearest positive one is the hit.
            let candidates = [(0.0 - x) / ux, (10.0 - x) / ux, (0.0 - y) / uy, (6.0 - y) / uy];
            let expected = candidates.iter().copied().filter(|t| *t > 0.0).fold(f64::INFINITY, f64::min);
            proptest::prop_assert!((hit.range_m - expected).abs() < 1e-9);
            let [hx, hy] = ray.xy_at(hit.range_m);
            let on_edge = hx.abs() < 1e-9 || (hx - 10.0).abs() < 1e-9 || hy.abs() < 1e-9 || (hy - 6.0).abs() < 1e-9;
            proptest::prop_assert!(on_edge);
            proptest::prop_assert!((0.0..=1.0 + 1e-12).contains(&hit.cos_incidence));
        }

        #[test]
        fn box_hits_like_its_four_walls_from_outside(
            cx in -2.0f64..2.0, cy in -2.0f64..2.0, len in 0.2f64..3.0, wid in 0.2f64..3.0,
            box_yaw in -180.0f64..180.0, bearing in -3.2f64..3.2, theta in -0.1f64..0.1, aim in -0.4f64..0.4,
        ) {
            // The sensor stands 6 m from the box centre, outside it, looking roughly at it.
            let (x, y) = (cx + 6.0 * bearing.cos(), cy + 6.0 * bearing.sin());
            let walls = box_as_walls(cx, cy, len, wid, box_yaw);
            let block = Scene {
                blocks: vec![Block {
                    center: [cx, cy],
                    axis: [box_yaw.to_radians().cos(), box_yaw.to_radians().sin()],
                    half: [len / 2.0, wid / 2.0],
                    extent: Extent { z_min_m: 0.0, z_max_m: 1.0 },
                    reflectivity: 0.5,
                }],
                segments: Vec::new(),
                ..walls.clone()
            };
            let yaw = bearing + std::f64::consts::PI + aim;
            let ray = Ray::from_sensor([x, y, yaw], 0.5, 0.0, theta);
            match (walls.cast(&ray), block.cast(&ray)) {
                (None, None) => {}
                (Some(a), Some(b)) => {
                    proptest::prop_assert!((a.range_m - b.range_m).abs() < 1e-9);
                    proptest::prop_assert!((a.cos_incidence - b.cos_incidence).abs() < 1e-9);
                }
                (a, b) => proptest::prop_assert!(false, "walls {:?} vs box {:?}", a, b),
            }
        }

        #[test]
        fn beam_directions_are_unit_and_tilt_follows_method_section_1(
            pitch_deg in -60.0f64..60.0, theta in -2.4f64..2.4, yaw in -3.2f64..3.2, d in 0.1f64..30.0,
        ) {
            let pitch = pitch_deg.to_radians();
            let ray = Ray::from_sensor([1.0, 2.0, yaw], 1.5, pitch, theta);
            let [ux, uy, uz] = ray.dir;
            proptest::prop_assert!(((ux * ux + uy * uy + uz * uz) - 1.0).abs() < 1e-12);
            // z = h + d cosθ sinφ; horizontal distance = d √(cos²θ cos²φ + sin²θ).
            proptest::prop_assert!((ray.origin[2] + d * uz - (1.5 + d * theta.cos() * pitch.sin())).abs() < 1e-9);
            let [hx, hy] = ray.xy_at(d);
            let horizontal = (hx - 1.0).hypot(hy - 2.0);
            let expected = d * ((theta.cos() * pitch.cos()).powi(2) + theta.sin().powi(2)).sqrt();
            proptest::prop_assert!((horizontal - expected).abs() < 1e-9);
        }
    }
}
