//! Where people can walk: a coarse occupancy grid of the plan (inside its walls, clear of
//! walls, boxes and pillars by a body's half-width) and A* paths on it, pulled straight where
//! the way is clear.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

use rand::Rng;

use super::plan::Plan;
use super::scene::{Scene, WALK_CLEAR_BELOW_M};

/// Grid cell side, m (grown for very large plans to keep the grid under `MAX_CELLS`).
const CELL_M: f64 = 0.2;
const MAX_CELLS: f64 = 400_000.0;
/// How far a walker's centre keeps from anything solid, m.
pub(crate) const CLEARANCE_M: f64 = 0.25;
/// A cell this close to a door's centre counts as inside, m.
const DOOR_REACH_M: f64 = 0.8;

#[derive(Debug, Clone)]
pub(crate) struct Walkable {
    origin: [f64; 2],
    cell_m: f64,
    nx: usize,
    ny: usize,
    free: Vec<bool>,
    /// The largest connected set of free cells, where destinations are drawn.
    main: Vec<u32>,
    in_main: Vec<bool>,
}

/// Whether `p` lies inside the plan's walls: an axis ray in each of the four directions meets
/// a wall (doors count as closed here).
fn enclosed(p: [f64; 2], walls: &[([f64; 2], [f64; 2])]) -> bool {
    let mut hit = [false; 4];
    for &(a, b) in walls {
        // Crossing of x = p.x (vertical ray) and y = p.y (horizontal ray).
        if (a[0] - p[0]) * (b[0] - p[0]) <= 0.0 && (a[0] - b[0]).abs() > 1e-12 {
            let y = a[1] + (b[1] - a[1]) * (p[0] - a[0]) / (b[0] - a[0]);
            hit[if y >= p[1] { 0 } else { 1 }] = true;
        }
        if (a[1] - p[1]) * (b[1] - p[1]) <= 0.0 && (a[1] - b[1]).abs() > 1e-12 {
            let x = a[0] + (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]);
            hit[if x >= p[0] { 2 } else { 3 }] = true;
        }
        if hit.iter().all(|h| *h) {
            return true;
        }
    }
    false
}

impl Walkable {
    pub fn build(plan: &Plan, scene: &Scene) -> Walkable {
        let walls: Vec<([f64; 2], [f64; 2])> = plan
            .walls
            .iter()
            .filter(|w| w.z_min_m < WALK_CLEAR_BELOW_M)
            .flat_map(|w| w.segments())
            .collect();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in walls.iter().flat_map(|(a, b)| [*a, *b]) {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if !(lo[0].is_finite() && hi[0].is_finite()) {
            lo = [0.0, 0.0];
            hi = [1.0, 1.0];
        }
        let area = (hi[0] - lo[0] + 1.0) * (hi[1] - lo[1] + 1.0);
        let cell_m = CELL_M.max((area / MAX_CELLS).sqrt());
        let origin = [lo[0] - 0.5, lo[1] - 0.5];
        let nx = ((hi[0] - lo[0] + 1.0) / cell_m).ceil() as usize + 1;
        let ny = ((hi[1] - lo[1] + 1.0) / cell_m).ceil() as usize + 1;
        let mut free = vec![false; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let p = [
                    origin[0] + (i as f64 + 0.5) * cell_m,
                    origin[1] + (j as f64 + 0.5) * cell_m,
                ];
                let near_door = plan
                    .doors
                    .iter()
                    .any(|d| (p[0] - d.at[0]).hypot(p[1] - d.at[1]) < DOOR_REACH_M);
                free[j * nx + i] =
                    (near_door || enclosed(p, &walls)) && !scene.blocks_walking(p, CLEARANCE_M);
            }
        }
        let mut grid = Walkable {
            origin,
            cell_m,
            nx,
            ny,
            free,
            main: Vec::new(),
            in_main: Vec::new(),
        };
        grid.find_main();
        grid
    }

    fn find_main(&mut self) {
        let mut label = vec![u32::MAX; self.free.len()];
        let mut best: Vec<u32> = Vec::new();
        for start in 0..self.free.len() {
            if !self.free[start] || label[start] != u32::MAX {
                continue;
            }
            let mut members = vec![start as u32];
            label[start] = start as u32;
            let mut queue = VecDeque::from([start]);
            while let Some(c) = queue.pop_front() {
                for (n, _) in self.neighbours(c) {
                    if label[n] == u32::MAX {
                        label[n] = start as u32;
                        members.push(n as u32);
                        queue.push_back(n);
                    }
                }
            }
            if members.len() > best.len() {
                best = members;
            }
        }
        let mut in_main = vec![false; self.free.len()];
        for &c in &best {
            in_main[c as usize] = true;
        }
        self.main = best;
        self.in_main = in_main;
    }

    fn cell_of(&self, p: [f64; 2]) -> Option<usize> {
        let i = ((p[0] - self.origin[0]) / self.cell_m).floor();
        let j = ((p[1] - self.origin[1]) / self.cell_m).floor();
        if !(i >= 0.0 && j >= 0.0 && (i as usize) < self.nx && (j as usize) < self.ny) {
            return None;
        }
        Some(j as usize * self.nx + i as usize)
    }

    fn centre(&self, c: usize) -> [f64; 2] {
        [
            self.origin[0] + ((c % self.nx) as f64 + 0.5) * self.cell_m,
            self.origin[1] + ((c / self.nx) as f64 + 0.5) * self.cell_m,
        ]
    }

    /// Free 8-neighbours of a cell with the step's length in cells; no cutting corners.
    fn neighbours(&self, c: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let (i, j) = ((c % self.nx) as i64, (c / self.nx) as i64);
        let free = move |i: i64, j: i64| {
            i >= 0
                && j >= 0
                && (i as usize) < self.nx
                && (j as usize) < self.ny
                && self.free[j as usize * self.nx + i as usize]
        };
        [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (1, -1),
            (-1, 1),
            (-1, -1),
        ]
        .into_iter()
        .filter(move |&(di, dj)| {
            free(i + di, j + dj) && (di == 0 || dj == 0 || (free(i + di, j) && free(i, j + dj)))
        })
        .map(move |(di, dj)| {
            let n = (j + dj) as usize * self.nx + (i + di) as usize;
            (n, if di != 0 && dj != 0 { 2f64.sqrt() } else { 1.0 })
        })
    }

    /// Whether a walker may stand at `p`.
    pub fn is_free(&self, p: [f64; 2]) -> bool {
        self.cell_of(p).is_some_and(|c| self.free[c])
    }

    /// Whether every point of the straight way from `a` to `b` is free.
    pub fn line_free(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let steps = (len / (self.cell_m / 3.0)).ceil().max(1.0) as usize;
        (0..=steps).all(|k| {
            let f = k as f64 / steps as f64;
            self.is_free([a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f])
        })
    }

    /// The free cell of the main area nearest to `p` within `max_m`, as a point.
    pub fn nearest_free(&self, p: [f64; 2], max_m: f64) -> Option<[f64; 2]> {
        if self.cell_of(p).is_some_and(|c| self.in_main[c]) {
            return Some(p);
        }
        let reach = (max_m / self.cell_m).ceil() as i64;
        let (ci, cj) = (
            ((p[0] - self.origin[0]) / self.cell_m).floor() as i64,
            ((p[1] - self.origin[1]) / self.cell_m).floor() as i64,
        );
        let mut best: Option<(f64, usize)> = None;
        for dj in -reach..=reach {
            for di in -reach..=reach {
                let (i, j) = (ci + di, cj + dj);
                if i < 0 || j < 0 || i as usize >= self.nx || j as usize >= self.ny {
                    continue;
                }
                let c = j as usize * self.nx + i as usize;
                if !self.in_main[c] {
                    continue;
                }
                let q = self.centre(c);
                let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                if d <= max_m && best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, c));
                }
            }
        }
        best.map(|(_, c)| self.centre(c))
    }

    /// A random free point of the main area.
    pub fn random_free(&self, rng: &mut impl Rng) -> Option<[f64; 2]> {
        if self.main.is_empty() {
            return None;
        }
        let c = self.main[rng.random_range(0..self.main.len())] as usize;
        let q = self.centre(c);
        let jitter = self.cell_m * 0.45;
        Some([
            q[0] + rng.random_range(-jitter..jitter),
            q[1] + rng.random_range(-jitter..jitter),
        ])
    }

    /// A walkable way from `a` to `b` (both included), straightened where clear; `None` when
    /// there is none.
    pub fn path(&self, a: [f64; 2], b: [f64; 2]) -> Option<Vec<[f64; 2]>> {
        if self.line_free(a, b) {
            return Some(vec![a, b]);
        }
        let start = self.cell_of(self.nearest_free(a, 2.0)?)?;
        let goal = self.cell_of(self.nearest_free(b, 2.0)?)?;
        let g_centre = self.centre(goal);
        let h = |c: usize| {
            let p = self.centre(c);
            let (dx, dy) = (
                ((p[0] - g_centre[0]) / self.cell_m).abs(),
                ((p[1] - g_centre[1]) / self.cell_m).abs(),
            );
            dx.max(dy) + (2f64.sqrt() - 1.0) * dx.min(dy)
        };
        let scale = 1000.0;
        let mut cost = vec![f64::INFINITY; self.free.len()];
        let mut came = vec![u32::MAX; self.free.len()];
        let mut open = BinaryHeap::new();
        cost[start] = 0.0;
        open.push(Reverse(((h(start) * scale) as u64, start)));
        while let Some(Reverse((_, c))) = open.pop() {
            if c == goal {
                break;
            }
            let here = cost[c];
            for (n, step) in self.neighbours(c) {
                let through = here + step;
                if through < cost[n] {
                    cost[n] = through;
                    came[n] = c as u32;
                    open.push(Reverse((((through + h(n)) * scale) as u64, n)));
                }
            }
        }
        if !cost[goal].is_finite() {
            return None;
        }
        let mut cells = vec![goal];
        let mut c = goal;
        while c != start {
            c = came[c] as usize;
            cells.push(c);
        }
        cells.reverse();
        let mut points: Vec<[f64; 2]> = Vec::with_capacity(cells.len() + 2);
        points.push(a);
        points.extend(cells.iter().map(|&c| self.centre(c)));
        points.push(b);
        // Pull the string: from each kept point, go as far along as the way is clear.
        let mut out = vec![a];
        let mut anchor = 0;
        while anchor + 1 < points.len() {
            let mut next = anchor + 1;
            while next + 1 < points.len() && self.line_free(points[anchor], points[next + 1]) {
                next += 1;
            }
            out.push(points[next]);
            anchor = next;
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_goes_round_a_wall_through_its_gap_and_stays_clear() {
        let text = r#"
name = "t"
[[wall]]
points = [[0, 0], [10, 0], [10, 6], [0, 6]]
closed = true
[[wall]]
points = [[5, 0], [5, 5]]
[[box]]
center = [2.5, 3]
size = [1, 1]
"#;
        let plan = Plan::from_toml(text, "t.toml").unwrap();
        let scene = Scene::build(&plan).unwrap();
        let grid = Walkable::build(&plan, &scene);
        assert!(!grid.is_free([-1.0, 3.0]), "outside the walls");
        assert!(!grid.is_free([2.5, 3.0]), "inside the box");
        assert!(grid.is_free([1.0, 1.0]));
        let path = grid.path([2.0, 1.0], [8.0, 1.0]).unwrap();
        assert!(path.len() >= 3, "{path:?}");
        // Goes through the 1 m gap at the top of the partition.
        assert!(path.iter().any(|p| p[1] > 5.0), "{path:?}");
        for w in path.windows(2) {
            assert!(grid.line_free(w[0], w[1]), "{path:?}");
            assert!(!scene.step_crosses_solid(w[0], w[1]), "{path:?}");
        }
    }
}
