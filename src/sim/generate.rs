//! Seeded floor plans of large sites, made as ordinary [`Plan`]s (issue 20): a station or
//! airport concourse of any length with its scanners installed, so `simulate`, `eval` and the
//! benchmarks can run sites of a hundred scanners without anyone drawing one.
//!
//! The concourse: a hall [`HALL_WIDTH_M`] wide between two lines of shops (random widths, fronts
//! set back into recesses, doors with shelves seen through them), two rows of square columns at
//! a [`BAY_M`] pitch, kiosks in the middle aisle, benches and bins by the columns, and gates
//! (three doors) in both end walls. Scanners are installed four per column bay, as an installer
//! would: one on each column of the bay (facing the nearer shop line on even bays, along the
//! hall on odd ones) and one on each shop line's front (facing into the hall, staggered a
//! quarter bay from the columns), all at about 1 m, UTM-30LX-EW and UXM-30LX-E mixed. Every
//! scanner so shares much of its view with the others of its bay and the next; the floor grows
//! one bay per four scanners. Same spec and seed, same plan, bit for bit.

use std::str::FromStr;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::PlanError;
use super::plan::{
    BoxShape, Circle, Crowd, DEFAULT_START_UNIX_S, Door, Model, Plan, SensorPlan, Wall,
};

/// Column pitch along the hall, m; also the length of floor each four scanners add.
pub const BAY_M: f64 = 8.0;
/// Between the two shop lines (where the fronts are not set back), m.
pub const HALL_WIDTH_M: f64 = 22.0;
/// Most scanners a generated floor takes.
pub const MAX_SENSORS: usize = 500;
/// Scanners installed per column bay.
const PER_BAY: usize = 4;
const HALF_HALL_M: f64 = HALL_WIDTH_M / 2.0;
/// Column rows at ±this, m.
const COLUMN_Y_M: f64 = 5.5;
const COLUMN_SIDE_M: f64 = 0.8;
/// Shops reach this far behind the hall's edge, m.
const SHOP_DEPTH_M: f64 = 6.0;
/// A shop divider stays this far along the hall from a front scanner, m.
const DIVIDER_CLEAR_M: f64 = 1.0;
/// Free floor between the gates and the first column bay, m.
const END_M: f64 = 6.0;
/// Roof height; walls of the shell reach it.
const ROOF_M: f64 = 6.0;
/// How far a scanner's optical centre stands off the face it is mounted on, m.
const STANDOFF_M: f64 = 0.12;
/// The gates' doors: across the hall at these y, this wide.
const GATE_Y_M: [f64; 3] = [-6.0, 0.0, 6.0];
const GATE_WIDTH_M: f64 = 2.4;

/// Which floor to make and how many scanners it holds: `concourse:N` on command lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FloorSpec {
    pub sensors: usize,
}

impl FromStr for FloorSpec {
    type Err = String;

    fn from_str(text: &str) -> Result<FloorSpec, String> {
        let usage = "use concourse:N, N scanners from 2 to 500, e.g. concourse:100";
        let (kind, count) = text
            .trim()
            .split_once(':')
            .ok_or_else(|| format!("{text:?} is not a generated floor; {usage}"))?;
        if !kind.eq_ignore_ascii_case("concourse") {
            return Err(format!(
                "unknown floor {kind:?}; the generator makes only a concourse: {usage}"
            ));
        }
        let sensors: usize = count
            .parse()
            .map_err(|_| format!("{count:?} is not a scanner count; {usage}"))?;
        if !(2..=MAX_SENSORS).contains(&sensors) {
            return Err(format!("{sensors} scanners is out of range; {usage}"));
        }
        Ok(FloorSpec { sensors })
    }
}

/// A concourse with `spec.sensors` scanners, drawn from `seed`; with `crowd` > 0 (at most 100)
/// that many people walk it, coming and going through the gates.
pub fn concourse(spec: FloorSpec, seed: u64, crowd: u32) -> Result<Plan, PlanError> {
    let n = spec.sensors;
    let origin = format!("concourse:{n} (seed {seed})");
    if !(2..=MAX_SENSORS).contains(&n) {
        return Err(PlanError::new(
            &origin,
            None,
            Some("sensors"),
            format!("is {n}; a concourse takes 2 to {MAX_SENSORS} scanners"),
        ));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let bays = n.div_ceil(PER_BAY);
    let length = 2.0 * END_M + bays as f64 * BAY_M;
    let back = HALF_HALL_M + SHOP_DEPTH_M;
    let mut plan = Plan {
        origin,
        name: format!("concourse-{n}"),
        start_unix_s: DEFAULT_START_UNIX_S,
        ceiling_m: Some(ROOF_M),
        floor_reflectivity: 0.3,
        ceiling_reflectivity: 0.7,
        walls: vec![wall(
            vec![[0.0, -back], [length, -back], [length, back], [0.0, back]],
            true,
            ROOF_M,
            0.7,
        )],
        boxes: Vec::new(),
        circles: Vec::new(),
        doors: Vec::new(),
        sensors: Vec::new(),
        people: Vec::new(),
        moves: Vec::new(),
        crowds: Vec::new(),
        queues: Vec::new(),
        truth_people: None,
    };
    for x in [0.0, length] {
        for y in GATE_Y_M {
            plan.doors.push(Door {
                line: None,
                at: [x, y],
                width_m: GATE_WIDTH_M,
            });
        }
    }
    // Where the wall scanners go, per side: a quarter bay either side of the columns, so the
    // two lines are staggered; an installer's tape is good to a few decimetres.
    let column_x = |bay: usize| END_M + (bay as f64 + 0.5) * BAY_M;
    let mut wall_x: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for bay in 0..bays {
        for (k, side) in [-1.0f64, 1.0].into_iter().enumerate() {
            let x = column_x(bay) - side * BAY_M / 4.0 + rng.random_range(-0.4..0.4);
            wall_x[k].push(x);
        }
    }
    let mut fronts: [Vec<(f64, f64, f64)>; 2] = [Vec::new(), Vec::new()];
    for (k, side) in [-1.0f64, 1.0].into_iter().enumerate() {
        fronts[k] = shops(&mut plan, &mut rng, side, length, &wall_x[k]);
    }
    for bay in 0..bays {
        let xc = column_x(bay);
        for side in [-1.0f64, 1.0] {
            plan.boxes.push(BoxShape {
                line: None,
                center: [xc, side * COLUMN_Y_M],
                size: [COLUMN_SIDE_M, COLUMN_SIDE_M],
                yaw_deg: 0.0,
                height_m: ROOF_M,
                z_min_m: 0.0,
                reflectivity: 0.6,
            });
            if rng.random_bool(0.5) {
                plan.boxes.push(BoxShape {
                    line: None,
                    center: [
                        xc + BAY_M / 2.0 + rng.random_range(-1.0..1.0),
                        side * COLUMN_Y_M,
                    ],
                    size: [2.0, 0.5],
                    yaw_deg: 0.0,
                    height_m: 0.45,
                    z_min_m: 0.0,
                    reflectivity: 0.4,
                });
            }
            if rng.random_bool(0.3) {
                plan.circles.push(Circle {
                    line: None,
                    center: [xc, side * (COLUMN_Y_M - 1.3)],
                    radius_m: 0.25,
                    height_m: 1.05,
                    z_min_m: 0.0,
                    reflectivity: 0.3,
                });
            }
        }
        if rng.random_bool(0.35) {
            let size = [rng.random_range(2.0..3.5), rng.random_range(1.2..2.0)];
            plan.boxes.push(BoxShape {
                line: None,
                center: [
                    xc + rng.random_range(-2.5..2.5),
                    rng.random_range(-1.5..1.5),
                ],
                size,
                yaw_deg: if rng.random_bool(0.5) { 0.0 } else { 90.0 },
                height_m: 2.4,
                z_min_m: 0.0,
                reflectivity: 0.5,
            });
        }
    }
    // The scanners, four a bay: wall south, column south, column north, wall north.
    for i in 0..n {
        let (bay, slot) = (i / PER_BAY, i % PER_BAY);
        let side = if slot < 2 { -1.0 } else { 1.0 };
        let k = usize::from(side > 0.0);
        let (x, y, yaw_deg, role) = if slot == 0 || slot == 3 {
            let x = wall_x[k][bay];
            let setback = fronts[k]
                .iter()
                .find(|(x0, x1, _)| (*x0..*x1).contains(&x))
                .map_or(0.0, |f| f.2);
            let y = side * (HALF_HALL_M + setback - STANDOFF_M);
            (x, y, -side * 90.0, "wall")
        } else {
            let to_wall = bay % 2 == 0;
            let (dx, dy) = if to_wall { (0.0, side) } else { (-side, 0.0) };
            let out = COLUMN_SIDE_M / 2.0 + STANDOFF_M;
            let yaw = dy.atan2(dx).to_degrees();
            (
                column_x(bay) + dx * out,
                side * COLUMN_Y_M + dy * out,
                yaw,
                "col",
            )
        };
        let model = if rng.random_bool(0.6) {
            Model::Utm30lxEw
        } else {
            Model::Uxm30lxE
        };
        plan.sensors.push(SensorPlan {
            line: None,
            id: format!("b{bay:03}-{role}-{}", if side < 0.0 { 's' } else { 'n' }),
            model,
            x: round_mm(x),
            y: round_mm(y),
            yaw_deg: round_mm(yaw_deg + rng.random_range(-3.0..3.0)),
            height_m: round_mm(rng.random_range(0.9..1.15)),
            pitch_deg: 0.0,
            intensities: None,
        });
    }
    if crowd > 0 {
        let gates: Vec<[f64; 2]> = plan
            .doors
            .iter()
            .take(2 * GATE_Y_M.len())
            .map(|d| d.at)
            .collect();
        plan.crowds.push(Crowd {
            people: crowd,
            rate_per_min: f64::from(crowd),
            entrances: gates,
            areas: vec![[1.0, -HALF_HALL_M + 0.5, length - 1.0, HALF_HALL_M - 0.5]],
            ..Crowd::default()
        });
    }
    plan.validate()?;
    Ok(plan)
}

/// One side's shops from x = 0 to `length`: a divider wall between neighbours, a front set back
/// 0–2 m from the hall's edge, most with a door (never where a wall scanner goes) and shelves
/// inside. Returns each shop's (x0, x1, setback).
fn shops(
    plan: &mut Plan,
    rng: &mut ChaCha8Rng,
    side: f64,
    length: f64,
    scanner_x: &[f64],
) -> Vec<(f64, f64, f64)> {
    let back = HALF_HALL_M + SHOP_DEPTH_M;
    let mut fronts = Vec::new();
    let mut x0 = 0.0;
    while x0 < length - 1e-9 {
        let mut x1 = round_mm(x0 + rng.random_range(5.0..11.0));
        // No divider beside a front scanner: one 5 cm from it stood in the corner of the
        // divider and the next front's step, most of its view within a metre.
        if let Some(s) = scanner_x.iter().find(|s| (*s - x1).abs() < DIVIDER_CLEAR_M) {
            x1 = round_mm(s + DIVIDER_CLEAR_M);
        }
        if length - x1 < 4.0 {
            x1 = length;
        }
        let setback = if rng.random_bool(0.5) {
            0.0
        } else {
            round_mm(rng.random_range(0.4..2.0))
        };
        let front_y = side * (HALF_HALL_M + setback);
        if x0 > 0.0 {
            plan.walls.push(wall(
                vec![[x0, side * HALF_HALL_M], [x0, side * back]],
                false,
                ROOF_M,
                0.7,
            ));
        }
        plan.walls.push(wall(
            vec![[x0, front_y], [x1, front_y]],
            false,
            3.5,
            rng.random_range(0.4..0.8),
        ));
        if rng.random_bool(0.7) {
            let width = round_mm(rng.random_range(1.5..3.0));
            let (lo, hi) = (x0 + 0.8 + width / 2.0, x1 - 0.8 - width / 2.0);
            let clear = |x: f64| scanner_x.iter().all(|s| (s - x).abs() > width / 2.0 + 0.6);
            if lo < hi
                && let Some(x) = (0..10)
                    .map(|_| round_mm(rng.random_range(lo..hi)))
                    .find(|x| clear(*x))
            {
                plan.doors.push(Door {
                    line: None,
                    at: [x, front_y],
                    width_m: width,
                });
            }
        }
        let inside = SHOP_DEPTH_M - setback;
        let shelves = rng.random_range(1..=2);
        for s in 0..shelves {
            let along = (x1 - x0) / f64::from(shelves);
            let size = [round_mm(along * 0.6), round_mm(rng.random_range(0.6..1.2))];
            plan.boxes.push(BoxShape {
                line: None,
                center: [
                    x0 + along * (f64::from(s) + 0.5),
                    side * (HALF_HALL_M + setback + inside * rng.random_range(0.4..0.8)),
                ],
                size,
                yaw_deg: 0.0,
                height_m: 1.8,
                z_min_m: 0.0,
                reflectivity: 0.5,
            });
        }
        fronts.push((x0, x1, setback));
        x0 = x1;
    }
    fronts
}

fn wall(points: Vec<[f64; 2]>, closed: bool, height_m: f64, reflectivity: f64) -> Wall {
    Wall {
        line: None,
        points,
        closed,
        height_m,
        z_min_m: 0.0,
        reflectivity: round_mm(reflectivity),
    }
}

/// To the millimetre, so the written TOML reads as a person would write it.
fn round_mm(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::view_overlap;

    fn spec(sensors: usize) -> FloorSpec {
        FloorSpec { sensors }
    }

    #[test]
    fn spec_parses_and_refuses_with_a_usable_message() {
        assert_eq!("concourse:100".parse(), Ok(spec(100)));
        assert_eq!(" Concourse:25".parse(), Ok(spec(25)));
        for bad in [
            "concourse",
            "hall:10",
            "concourse:x",
            "concourse:1",
            "concourse:501",
        ] {
            let err = bad.parse::<FloorSpec>().unwrap_err();
            assert!(err.contains("concourse:N"), "{bad}: {err}");
        }
    }

    #[test]
    fn sizes_validate_and_grow_one_bay_per_four_scanners() {
        for n in [2, 25, 100, 200] {
            let plan = concourse(spec(n), 3, 0).unwrap();
            assert_eq!(plan.sensors.len(), n);
            let xs = plan.walls[0].points.iter().map(|p| p[0]);
            let length = xs.fold(0.0, f64::max);
            assert_eq!(length, 2.0 * END_M + n.div_ceil(4) as f64 * BAY_M, "{n}");
            let utm = plan
                .sensors
                .iter()
                .filter(|s| s.model == Model::Utm30lxEw)
                .count();
            if n >= 25 {
                assert!(utm > 0 && utm < n, "{n} scanners, {utm} UTMs: both models");
            }
        }
        assert!(concourse(spec(1), 1, 0).is_err());
        assert!(
            concourse(spec(100), 1, 101).is_err(),
            "crowds hold at most 100"
        );
    }

    #[test]
    fn same_seed_same_plan_other_seed_other_plan() {
        let a = concourse(spec(40), 7, 20).unwrap();
        assert_eq!(a, concourse(spec(40), 7, 20).unwrap());
        assert_ne!(a, concourse(spec(40), 8, 20).unwrap());
    }

    #[test]
    fn written_toml_reads_back_as_the_same_plan() {
        let plan = concourse(spec(30), 5, 15).unwrap();
        let text = plan.to_toml().unwrap();
        let mut back = Plan::from_toml(&text, &plan.origin).unwrap();
        back.walls.iter_mut().for_each(|w| w.line = None);
        back.boxes.iter_mut().for_each(|b| b.line = None);
        back.circles.iter_mut().for_each(|c| c.line = None);
        back.doors.iter_mut().for_each(|d| d.line = None);
        back.sensors.iter_mut().for_each(|s| s.line = None);
        back.crowds.iter_mut().for_each(|c| c.line = None);
        assert_eq!(back, plan);
    }

    /// A front scanner never stands by a shop divider (the corner it and the next front's
    /// step make hides most of the hall): on long floors, where a hundred fronts make it
    /// likely, and on every seed tried.
    #[test]
    fn no_front_scanner_stands_by_a_shop_divider() {
        for seed in 1..=3 {
            let plan = concourse(spec(200), seed, 0).unwrap();
            // Dividers run across the shops' depth: x fixed, |y| from the hall's edge back.
            let dividers: Vec<(f64, f64)> = plan
                .walls
                .iter()
                .filter_map(|w| match w.points[..] {
                    [[xa, ya], [xb, yb]] if xa == xb && ya.abs() == HALF_HALL_M => {
                        Some((xa, yb.signum()))
                    }
                    _ => None,
                })
                .collect();
            assert!(dividers.len() > 20, "{} dividers", dividers.len());
            for s in plan.sensors.iter().filter(|s| s.id.contains("-wall-")) {
                let nearest = dividers
                    .iter()
                    .filter(|(_, side)| *side == s.y.signum())
                    .map(|(x, _)| (x - s.x).abs())
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    nearest >= DIVIDER_CLEAR_M - 0.01,
                    "seed {seed}: {} stands {nearest:.2} m from a divider",
                    s.id
                );
            }
        }
    }

    /// Every scanner shares ≥ 30 % of its view (eval's "installed" bar) with one of the
    /// scanners of its own or the next bay, and most pairs of a bay share much more.
    #[test]
    fn every_scanner_shares_view_with_its_neighbours() {
        let plan = concourse(spec(25), 11, 0).unwrap();
        let ids: Vec<&str> = plan.sensors.iter().map(|s| s.id.as_str()).collect();
        let mut shares = Vec::new();
        for (i, a) in ids.iter().enumerate() {
            let best = ids
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i && (i / 4).abs_diff(*j / 4) <= 1)
                .map(|(_, b)| view_overlap(&plan, a, b, 0.1).unwrap())
                .fold(0.0, f64::max);
            shares.push(best);
            assert!(
                best >= 0.3,
                "{a} shares at most {:.0} % with its neighbours",
                best * 100.0
            );
        }
        shares.sort_by(f64::total_cmp);
        eprintln!("best neighbour overlap per scanner, sorted: {shares:.2?}");
    }
}
