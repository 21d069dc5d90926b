//! A log-odds occupancy grid of static structure, fed by rays from sensor origins to hits.
//!
//! Cells along a ray become more likely free, the cell at its end more likely occupied; people
//! walking through leave few marks because the cells they cross are seen free far more often.
//! The grid grows to fit what it is given, up to a bound, so a site needs no extent up front.

use nalgebra::Point2;

/// Update and classification parameters; the defaults are ROS map_server's thresholds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridParams {
    /// Cell side, m.
    pub cell_m: f64,
    /// Log-odds added to a cell a ray ends in.
    pub hit_log_odds: f32,
    /// Log-odds added (negative) to a cell a ray passes through.
    pub miss_log_odds: f32,
    /// Log-odds are clamped to ±this, so a cell can change its mind.
    pub clamp_log_odds: f32,
    /// Probability above which a cell is occupied.
    pub occupied_above: f64,
    /// Probability below which a cell is free.
    pub free_below: f64,
    /// Largest grid side in cells; rays reaching further are cut at the border.
    pub max_side_cells: usize,
}

impl Default for GridParams {
    fn default() -> Self {
        GridParams {
            cell_m: 0.05,
            hit_log_odds: 0.85,  // p = 0.70
            miss_log_odds: -0.4, // p = 0.40
            clamp_log_odds: 3.5,
            occupied_above: 0.65,
            free_below: 0.196,
            max_side_cells: 4096,
        }
    }
}

/// What a cell is believed to be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cell {
    Unknown,
    Free,
    Occupied,
}

#[derive(Debug, Clone)]
pub struct OccupancyGrid {
    params: GridParams,
    /// Site-frame position of the lower-left corner of cell (0, 0), m.
    origin: Point2<f64>,
    width: usize,
    height: usize,
    /// Row-major from the bottom row (y = origin.y) up; 0 = never observed.
    log_odds: Vec<f32>,
    /// Rays that were cut because they left the largest allowed grid.
    clipped_rays: u64,
}

impl OccupancyGrid {
    pub fn new(params: GridParams) -> Self {
        OccupancyGrid {
            params,
            origin: Point2::origin(),
            width: 0,
            height: 0,
            log_odds: Vec::new(),
            clipped_rays: 0,
        }
    }

    pub fn params(&self) -> &GridParams {
        &self.params
    }

    /// Lower-left corner of the grid in the site frame, m.
    pub fn origin(&self) -> Point2<f64> {
        self.origin
    }

    /// (width, height) in cells.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    pub fn clipped_rays(&self) -> u64 {
        self.clipped_rays
    }

    /// Adds one beam: free space from `from` to `to`, and an obstacle at `to` when `hit`
    /// (a beam that returned nothing within range clears space but marks nothing).
    pub fn insert_ray(&mut self, from: Point2<f64>, to: Point2<f64>, hit: bool) {
        if !(from.x.is_finite() && from.y.is_finite() && to.x.is_finite() && to.y.is_finite()) {
            return;
        }
        if !self.fit(&[from, to]) {
            self.clipped_rays += 1;
            return;
        }
        let (x0, y0) = self.cell_of(from);
        let (x1, y1) = self.cell_of(to);
        let (miss, hit_lo, clamp) = (
            self.params.miss_log_odds,
            self.params.hit_log_odds,
            self.params.clamp_log_odds,
        );
        // Bresenham over cells; the end cell is the obstacle and is never marked free.
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = ((x1 - x0).signum(), (y1 - y0).signum());
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        while (x, y) != (x1, y1) {
            self.add(x, y, miss, clamp);
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
        if hit {
            self.add(x1, y1, hit_lo, clamp);
        }
    }

    /// The belief about the cell containing `p`.
    pub fn cell_at(&self, p: Point2<f64>) -> Cell {
        let (x, y) = self.cell_of(p);
        self.cell(x, y)
    }

    /// The belief about cell (x, y), counted from the lower-left.
    pub fn cell(&self, x: i64, y: i64) -> Cell {
        let Some(&l) = self.index(x, y).and_then(|i| self.log_odds.get(i)) else {
            return Cell::Unknown;
        };
        if l == 0.0 {
            return Cell::Unknown;
        }
        let p = 1.0 - 1.0 / (1.0 + f64::from(l).exp());
        if p > self.params.occupied_above {
            Cell::Occupied
        } else if p < self.params.free_below {
            Cell::Free
        } else {
            Cell::Unknown
        }
    }

    /// The grids combined into one: every observed cell's log-odds summed over the grids
    /// (clamped), as if their rays had gone into one grid. Lets each sensor keep its own
    /// grid, so one sensor's cells can be dropped (it moved) without touching the others'.
    /// Grids with another cell size than `params.cell_m` are skipped.
    pub fn combined<'a>(
        params: GridParams,
        grids: impl IntoIterator<Item = &'a OccupancyGrid>,
    ) -> OccupancyGrid {
        let mut out = OccupancyGrid::new(params);
        let c = params.cell_m;
        let grids: Vec<&OccupancyGrid> = grids
            .into_iter()
            .filter(|g| g.width > 0 && (g.params.cell_m - c).abs() < 1e-12)
            .collect();
        let corners: Vec<Point2<f64>> = grids
            .iter()
            .flat_map(|g| {
                // Cell centres of the corner cells, so rounding cannot push a corner outside.
                let lo = Point2::new(g.origin.x + 0.5 * c, g.origin.y + 0.5 * c);
                let hi = Point2::new(
                    g.origin.x + (g.width as f64 - 0.5) * c,
                    g.origin.y + (g.height as f64 - 0.5) * c,
                );
                [lo, hi]
            })
            .collect();
        if corners.is_empty() || !out.fit(&corners) {
            return out;
        }
        let clamp = params.clamp_log_odds;
        for g in grids {
            for y in 0..g.height {
                for x in 0..g.width {
                    let Some(&l) = g.log_odds.get(y * g.width + x) else {
                        continue;
                    };
                    if l == 0.0 {
                        continue;
                    }
                    let centre = Point2::new(
                        g.origin.x + (x as f64 + 0.5) * c,
                        g.origin.y + (y as f64 + 0.5) * c,
                    );
                    let (tx, ty) = out.cell_of(centre);
                    out.add(tx, ty, l, clamp);
                }
            }
        }
        out
    }

    fn add(&mut self, x: i64, y: i64, delta: f32, clamp: f32) {
        if let Some(l) = self.index(x, y).and_then(|i| self.log_odds.get_mut(i)) {
            *l = (*l + delta).clamp(-clamp, clamp);
            if *l == 0.0 {
                // 0 means "never seen"; a seen cell that lands exactly on 0 stays seen.
                *l = f32::EPSILON.copysign(delta);
            }
        }
    }

    fn cell_of(&self, p: Point2<f64>) -> (i64, i64) {
        let c = self.params.cell_m;
        (
            ((p.x - self.origin.x) / c).floor() as i64,
            ((p.y - self.origin.y) / c).floor() as i64,
        )
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        let (x, y) = (usize::try_from(x).ok()?, usize::try_from(y).ok()?);
        (x < self.width && y < self.height).then(|| y * self.width + x)
    }

    /// Grows the grid (with a margin) so every point lies inside; false when that would pass
    /// `max_side_cells`.
    fn fit(&mut self, points: &[Point2<f64>]) -> bool {
        let c = self.params.cell_m;
        let inside = |g: &Self, p: &Point2<f64>| {
            let (x, y) = g.cell_of(*p);
            g.index(x, y).is_some()
        };
        if points.iter().all(|p| inside(self, p)) {
            return true;
        }
        let margin = 2.0; // m, so a growing site does not reallocate every scan
        let (mut lo_x, mut lo_y, mut hi_x, mut hi_y) = if self.width == 0 {
            (f64::MAX, f64::MAX, f64::MIN, f64::MIN)
        } else {
            (
                self.origin.x,
                self.origin.y,
                self.origin.x + self.width as f64 * c,
                self.origin.y + self.height as f64 * c,
            )
        };
        for p in points {
            lo_x = lo_x.min(p.x - margin);
            lo_y = lo_y.min(p.y - margin);
            hi_x = hi_x.max(p.x + margin);
            hi_y = hi_y.max(p.y + margin);
        }
        // Keep cell boundaries where they were, so old cells map onto new ones exactly.
        let shift_x = ((self.origin.x - lo_x) / c).ceil().max(0.0) as usize;
        let shift_y = ((self.origin.y - lo_y) / c).ceil().max(0.0) as usize;
        let new_origin = if self.width == 0 {
            Point2::new((lo_x / c).floor() * c, (lo_y / c).floor() * c)
        } else {
            Point2::new(
                self.origin.x - shift_x as f64 * c,
                self.origin.y - shift_y as f64 * c,
            )
        };
        let width = ((hi_x - new_origin.x) / c).ceil() as usize;
        let height = ((hi_y - new_origin.y) / c).ceil() as usize;
        if width > self.params.max_side_cells || height > self.params.max_side_cells {
            return false;
        }
        let mut grown = vec![0.0f32; width * height];
        let (ox, oy) = if self.width == 0 {
            (0, 0)
        } else {
            (shift_x, shift_y)
        };
        for row in 0..self.height {
            let src = &self.log_odds[row * self.width..(row + 1) * self.width];
            let start = (row + oy) * width + ox;
            grown[start..start + self.width].copy_from_slice(src);
        }
        self.log_odds = grown;
        self.origin = new_origin;
        self.width = width;
        self.height = height;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64) -> Point2<f64> {
        Point2::new(x, y)
    }

    #[test]
    fn repeated_rays_make_the_end_occupied_and_the_way_free() {
        let mut g = OccupancyGrid::new(GridParams::default());
        for _ in 0..5 {
            g.insert_ray(p(0.0, 0.0), p(3.0, 1.0), true);
        }
        assert_eq!(g.cell_at(p(3.0, 1.0)), Cell::Occupied);
        assert_eq!(g.cell_at(p(1.5, 0.5)), Cell::Free);
        assert_eq!(g.cell_at(p(1.5, 2.5)), Cell::Unknown);
        assert_eq!(g.cell_at(p(500.0, 0.0)), Cell::Unknown);
    }

    #[test]
    fn a_person_seen_once_is_cleared_by_later_rays_through_the_spot() {
        let mut g = OccupancyGrid::new(GridParams::default());
        g.insert_ray(p(0.0, 0.0), p(2.0, 0.0), true);
        assert_eq!(g.cell_at(p(2.0, 0.0)), Cell::Occupied);
        for _ in 0..6 {
            g.insert_ray(p(0.0, 0.0), p(5.0, 0.0), true);
        }
        assert_eq!(g.cell_at(p(2.0, 0.0)), Cell::Free);
        assert_eq!(g.cell_at(p(5.0, 0.0)), Cell::Occupied);
    }

    #[test]
    fn growing_keeps_what_was_seen_in_place() {
        let mut g = OccupancyGrid::new(GridParams::default());
        for _ in 0..5 {
            g.insert_ray(p(0.0, 0.0), p(1.0, 1.0), true);
        }
        let before = g.size();
        for _ in 0..3 {
            g.insert_ray(p(0.0, 0.0), p(-20.0, -15.0), true);
            g.insert_ray(p(0.0, 0.0), p(30.0, 12.0), true);
        }
        assert!(g.size().0 > before.0 && g.size().1 > before.1);
        assert_eq!(g.cell_at(p(1.0, 1.0)), Cell::Occupied);
        assert_eq!(g.cell_at(p(-20.0, -15.0)), Cell::Occupied);
        assert_eq!(g.cell_at(p(30.0, 12.0)), Cell::Occupied);
        assert_eq!(g.cell_at(p(0.5, 0.5)), Cell::Free);
    }

    #[test]
    fn combined_grids_sum_what_each_saw_wherever_their_origins_are() {
        let mut a = OccupancyGrid::new(GridParams::default());
        let mut b = OccupancyGrid::new(GridParams::default());
        for _ in 0..5 {
            a.insert_ray(p(0.0, 0.0), p(3.0, 1.0), true);
            b.insert_ray(p(10.0, -4.0), p(12.0, -4.0), true);
        }
        // A cell both saw free twice: each alone is undecided, together they call it free.
        for _ in 0..2 {
            a.insert_ray(p(0.0, 0.0), p(0.0, 8.0), false);
            b.insert_ray(p(-4.0, 6.0), p(4.0, 6.0), false);
        }
        assert_eq!(a.cell_at(p(0.0, 6.0)), Cell::Unknown);
        assert_eq!(b.cell_at(p(0.0, 6.0)), Cell::Unknown);
        let both = OccupancyGrid::combined(GridParams::default(), [&a, &b]);
        assert_eq!(both.cell_at(p(3.0, 1.0)), Cell::Occupied);
        assert_eq!(both.cell_at(p(12.0, -4.0)), Cell::Occupied);
        assert_eq!(both.cell_at(p(1.5, 0.5)), Cell::Free);
        assert_eq!(both.cell_at(p(11.0, -4.0)), Cell::Free);
        assert_eq!(both.cell_at(p(1.5, 2.5)), Cell::Unknown);
        assert_eq!(both.cell_at(p(0.0, 6.0)), Cell::Free);
        let only_a = OccupancyGrid::combined(GridParams::default(), [&a]);
        assert_eq!(
            only_a.cell_at(p(12.0, -4.0)),
            Cell::Unknown,
            "b's cells went with b"
        );
        assert_eq!(only_a.cell_at(p(3.0, 1.0)), Cell::Occupied);
        let none = OccupancyGrid::combined(GridParams::default(), []);
        assert_eq!(none.size(), (0, 0));
    }

    #[test]
    fn rays_beyond_the_largest_grid_are_counted_not_stored() {
        let params = GridParams {
            max_side_cells: 200,
            ..GridParams::default()
        };
        let mut g = OccupancyGrid::new(params);
        g.insert_ray(p(0.0, 0.0), p(100.0, 0.0), true);
        g.insert_ray(p(0.0, 0.0), p(f64::NAN, 0.0), true);
        assert_eq!(g.clipped_rays(), 1);
        assert_eq!(g.size(), (0, 0));
    }
}
