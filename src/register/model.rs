//! A scan prepared for registration, once per sensor: features, normals, samples and the
//! lookup tables every hypothesis is scored against (nearest-point grid, polar free space).

use super::RegisterParams;
use super::motion::MotionTrack;
use crate::features::{self, Features, PointClass};
use crate::geometry::tables::Tables;
use crate::geometry::{Mount, Pose2, ScanPoint, beam_angles_rad, project_scan};
use crate::scan::{Scan, ScanGeometry};
use nalgebra::{Point2, Vector2};
use std::f64::consts::{PI, TAU};
use std::sync::{Arc, Mutex};

/// Nearest point per cell of a regular grid, for points within `radius` of a cell.
#[derive(Debug, Clone)]
pub struct NearestGrid {
    min: Point2<f64>,
    res_m: f64,
    width: usize,
    height: usize,
    cells: Vec<u32>,
}

impl NearestGrid {
    const EMPTY: u32 = u32::MAX;

    pub fn new(points: &[Point2<f64>], res_m: f64, radius_m: f64) -> Self {
        let (mut lo, mut hi) = (Point2::new(0.0, 0.0), Point2::new(0.0, 0.0));
        for p in points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        let min = lo - Vector2::repeat(radius_m + res_m);
        let width = ((hi.x - min.x + radius_m) / res_m).ceil() as usize + 2;
        let height = ((hi.y - min.y + radius_m) / res_m).ceil() as usize + 2;
        let mut cells = vec![Self::EMPTY; width * height];
        let mut dist = vec![f32::INFINITY; width * height];
        let reach = (radius_m / res_m).ceil() as i64;
        for (i, p) in points.iter().enumerate() {
            let cx = ((p.x - min.x) / res_m) as i64;
            let cy = ((p.y - min.y) / res_m) as i64;
            for y in (cy - reach).max(0)..=(cy + reach).min(height as i64 - 1) {
                for x in (cx - reach).max(0)..=(cx + reach).min(width as i64 - 1) {
                    let centre = Point2::new(
                        min.x + (x as f64 + 0.5) * res_m,
                        min.y + (y as f64 + 0.5) * res_m,
                    );
                    let d = (centre - p).norm() as f32;
                    let k = y as usize * width + x as usize;
                    if d < dist[k] {
                        dist[k] = d;
                        cells[k] = i as u32;
                    }
                }
            }
        }
        NearestGrid {
            min,
            res_m,
            width,
            height,
            cells,
        }
    }

    /// Index of the point nearest to the cell holding `q`, if one is within the radius.
    #[inline]
    pub fn nearest(&self, q: &Point2<f64>) -> Option<usize> {
        let x = (q.x - self.min.x) / self.res_m;
        let y = (q.y - self.min.y) / self.res_m;
        if x < 0.0 || y < 0.0 || x >= self.width as f64 || y >= self.height as f64 {
            return None;
        }
        match self.cells.get(y as usize * self.width + x as usize) {
            Some(&i) if i != Self::EMPTY => Some(i as usize),
            _ => None,
        }
    }
}

/// What the sensor saw in each direction: nearest return per bearing bin, for free space.
#[derive(Debug, Clone)]
pub struct PolarRanges {
    bin_rad: f64,
    /// Range per bin; infinity = no return (unknown, never free).
    ranges_m: Vec<f32>,
    /// Per `sector`, the farthest free range any point there can be tested against (−∞:
    /// none): a point beyond it violates nothing, found without an arctangent.
    sector_max_m: Vec<f64>,
    /// Per `CELLS` step of the diamond angle, the bin of every bearing in it, or `SPLIT` where
    /// the step straddles a bin's edge: most points find their bin without an arctangent.
    /// Shared by every scan of one bin width (`shared_cell_bins`).
    cell_bin: Arc<[u16]>,
}

/// Steps of the diamond angle in `PolarRanges::cell_bin`: at the finest bins (0.25°) about
/// one point in ten lands in a step that straddles two bins.
const CELLS: usize = 4 * 4096;

/// A diamond-angle step whose bearings fall in more than one bin.
const SPLIT: u16 = u16::MAX;

/// Sectors of `PolarRanges::sector_max_m`.
const SECTORS: usize = 64;

/// A point's sector: its diamond angle in `SECTORS` equal steps. Cheap, and exact enough:
/// `PolarRanges` credits every bin to the sectors either side too.
#[inline]
fn sector(q: &Point2<f64>) -> usize {
    sector_of(diamond(q))
}

#[inline]
fn sector_of(d: f64) -> usize {
    ((d * (SECTORS / 4) as f64) as usize).min(SECTORS - 1)
}

/// The "diamond angle" of a direction: monotonic in the bearing, 0–4 from +x round
/// counter-clockwise, with one division and no arctangent.
#[inline]
fn diamond(q: &Point2<f64>) -> f64 {
    let (x, y) = (q.x, q.y);
    if y >= 0.0 {
        if x >= 0.0 {
            y / (x + y)
        } else {
            1.0 - x / (y - x)
        }
    } else if x < 0.0 {
        2.0 - y / (-x - y)
    } else {
        3.0 + x / (x - y)
    }
}

/// The `CELLS` step of diamond angle `d`.
#[inline]
fn cell_of(d: f64) -> usize {
    ((d * (CELLS / 4) as f64) as usize).min(CELLS - 1)
}

/// A direction of diamond angle `d` (taken modulo 4): `diamond`'s inverse.
fn direction_of(d: f64) -> Point2<f64> {
    let d = d.rem_euclid(4.0);
    match d {
        d if d < 1.0 => Point2::new(1.0 - d, d),
        d if d < 2.0 => Point2::new(1.0 - d, 2.0 - d),
        d if d < 3.0 => Point2::new(d - 3.0, 2.0 - d),
        d => Point2::new(d - 3.0, d - 4.0),
    }
}

impl PolarRanges {
    pub fn new(points: &[Point2<f64>], bin_rad: f64) -> Self {
        let bins = (TAU / bin_rad).ceil() as usize;
        let mut ranges_m = vec![f32::INFINITY; bins];
        for p in points {
            let b = Self::bin_of(bin_rad, bins, p.y.atan2(p.x));
            let r = p.coords.norm() as f32;
            if let Some(slot) = ranges_m.get_mut(b) {
                *slot = slot.min(r);
            }
        }
        // What `violates` compares a point in bin b with is the nearest of bins b − 1..b + 1;
        // a point's bin may be one off at a bin's edge, so each bin credits b − 2..b + 2, to
        // the sectors of both its edges and the sectors either side.
        let seen = |b: usize| {
            [bins - 1, 0, 1]
                .iter()
                .map(|&d| ranges_m[(b + d) % bins])
                .fold(f32::INFINITY, f32::min)
        };
        let mut sector_max_m = vec![f64::NEG_INFINITY; SECTORS];
        for b in 0..bins {
            let far = [bins - 1, 0, 1]
                .iter()
                .map(|&d| seen((b + d) % bins))
                .filter(|r| r.is_finite())
                .fold(f32::NEG_INFINITY, f32::max);
            if far == f32::NEG_INFINITY {
                continue;
            }
            for edge in [b, b + 1] {
                let bearing = edge as f64 * bin_rad - PI;
                let s = sector(&Point2::new(bearing.cos(), bearing.sin()));
                for t in [s + SECTORS - 1, s, s + 1] {
                    let m = &mut sector_max_m[t % SECTORS];
                    *m = m.max(far as f64);
                }
            }
        }
        PolarRanges {
            bin_rad,
            ranges_m,
            sector_max_m,
            cell_bin: Self::shared_cell_bins(bin_rad, bins),
        }
    }

    /// `cell_bins` for this bin width, built once: it takes 0.5 ms, a third of a model's
    /// making, and a site has a few bin widths (one per kind of sensor; 16 are kept).
    fn shared_cell_bins(bin_rad: f64, bins: usize) -> Arc<[u16]> {
        type ByWidth = Tables<(u64, usize), Arc<[u16]>>;
        static TABLES: Mutex<ByWidth> = Mutex::new(Tables::new(16));
        let mut tables = TABLES.lock().unwrap_or_else(|e| e.into_inner());
        tables.get((bin_rad.to_bits(), bins), || {
            Self::cell_bins(bin_rad, bins).into()
        })
    }

    /// `cell_bin`: a step's bin where the bearings just outside both its ends (by far more
    /// than rounding) share one, so that every point in it does; the ±π seam always splits.
    fn cell_bins(bin_rad: f64, bins: usize) -> Vec<u16> {
        const OUTSIDE: f64 = 1e-9;
        let per = (CELLS / 4) as f64;
        let bin_at = |d: f64| {
            let q = direction_of(d);
            Self::bin_of(bin_rad, bins, q.y.atan2(q.x))
        };
        (0..CELLS)
            .map(|c| {
                let (lo, hi) = (
                    bin_at(c as f64 / per - OUTSIDE),
                    bin_at((c + 1) as f64 / per + OUTSIDE),
                );
                if lo == hi && lo < SPLIT as usize {
                    lo as u16
                } else {
                    SPLIT
                }
            })
            .collect()
    }

    /// The bearing bin of `q` (of diamond angle `d`): from its step when the step lies in one
    /// bin, else by the arctangent.
    #[inline]
    fn bin_at(&self, q: &Point2<f64>, d: f64) -> usize {
        match self.cell_bin[cell_of(d)] {
            SPLIT => Self::bin_of(self.bin_rad, self.ranges_m.len(), q.y.atan2(q.x)),
            b => b as usize,
        }
    }

    /// The bearing bin: the beam spacing, at least 0.25°.
    pub fn bin_rad(&self) -> f64 {
        self.bin_rad
    }

    fn bin_of(bin_rad: f64, bins: usize, bearing_rad: f64) -> usize {
        (((bearing_rad + PI) / bin_rad) as usize).min(bins - 1)
    }

    /// True when `q` (sensor frame) lies in space the sensor saw empty: short of the returns
    /// in its bin and both neighbours by more than the margin.
    #[inline]
    pub fn violates(&self, q: &Point2<f64>, margin_m: f64, margin_frac: f64) -> bool {
        let r = q.coords.norm();
        if r < 0.2 {
            return false;
        }
        // Beyond anything its sector saw: nothing nearer to compare with.
        let d = diamond(q);
        let far = self.sector_max_m[sector_of(d)];
        if r >= far - margin_m - margin_frac * r {
            return false;
        }
        let bins = self.ranges_m.len();
        let b = self.bin_at(q, d);
        let seen = [(b + bins - 1) % bins, b, (b + 1) % bins]
            .iter()
            .map(|&k| self.ranges_m.get(k).copied().unwrap_or(f32::INFINITY))
            .fold(f32::INFINITY, f32::min) as f64;
        seen.is_finite() && r < seen - margin_m - margin_frac * r
    }
}

/// One sensor's scan, ready to be registered against others.
#[derive(Debug, Clone)]
pub struct ScanModel {
    pub features: Features,
    /// Unit normal per point, pointing towards the sensor.
    pub normals: Vec<Vector2<f64>>,
    /// Per point: its normal is a surface's (a segment's, or fitted over its neighbours), not
    /// just the direction to the sensor (an isolated return).
    pub surface: Vec<bool>,
    /// Points used for scoring, evenly spread along the outline.
    pub score_sample: Vec<usize>,
    /// Points used by ICP.
    pub icp_sample: Vec<usize>,
    pub grid: NearestGrid,
    pub polar: PolarRanges,
    /// Where the scan plane runs in height, when the mount is known.
    pub plane: Option<ScanPlane>,
    /// People seen walking over time, when more than the still view was kept.
    pub motion: Option<Arc<MotionTrack>>,
}

/// The plane a (possibly tilted) scan sweeps: z = height + x·slope at a horizontal point
/// (x forward, sensor frame), since a beam's x is d·cos θ·cos φ and its z is h + d·cos θ·sin φ.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPlane {
    pub height_m: f64,
    /// tan of the pitch.
    pub slope: f64,
}

impl ScanPlane {
    pub fn of(mount: &Mount) -> Option<ScanPlane> {
        mount.height_m.map(|height_m| ScanPlane {
            height_m,
            slope: mount.pitch_rad.tan(),
        })
    }

    /// Height of the plane above the floor at `q` (sensor frame, m).
    #[inline]
    pub fn z_at(&self, q: &Point2<f64>) -> f64 {
        self.height_m + q.x * self.slope
    }
}

impl ScanModel {
    /// Prepares a scan; `step_rad` is its beam spacing.
    pub fn new(points: &[ScanPoint], step_rad: f64, params: &RegisterParams) -> Self {
        let features = features::extract(points, step_rad, &params.features);
        let (normals, surface) = normals_of(&features, params.normal_radius_m);
        let grouped: Vec<usize> = features.groups.iter().flat_map(|g| g.clone()).collect();
        let score_sample = spread(&features.points, &grouped, params.score_points);
        let icp_sample = spread(&features.points, &grouped, params.icp_points);
        let grid = NearestGrid::new(&features.points, params.grid_res_m, params.grid_radius_m);
        let polar = PolarRanges::new(&features.points, step_rad.abs().max(0.25f64.to_radians()));
        ScanModel {
            features,
            normals,
            surface,
            score_sample,
            icp_sample,
            grid,
            polar,
            plane: None,
            motion: None,
        }
    }

    /// Projects a scan (exact PP angles when `geometry` fits it, tilted mount, floor hits
    /// removed) and prepares it.
    pub fn from_scan(
        scan: &Scan,
        geometry: Option<&ScanGeometry>,
        mount: &Mount,
        params: &RegisterParams,
    ) -> Self {
        let points = project_scan(scan, geometry, mount, &params.project);
        let angles = beam_angles_rad(scan, geometry);
        let step_rad = match (angles.first(), angles.last()) {
            (Some(a), Some(b)) if angles.len() > 1 => ((b - a) / (angles.len() - 1) as f64).abs(),
            _ => 0.25f64.to_radians(),
        };
        ScanModel {
            plane: ScanPlane::of(mount),
            ..Self::new(&points, step_rad, params)
        }
    }

    /// The same scan with the people seen walking in `scans` (stamp order), against `still`,
    /// the static view it was prepared from.
    pub fn with_motion(
        self,
        scans: &[Scan],
        still: &Scan,
        geometry: Option<&ScanGeometry>,
        mount: &Mount,
        params: &RegisterParams,
    ) -> Self {
        let track = MotionTrack::new(
            scans,
            still,
            geometry,
            mount,
            &params.project,
            &params.motion,
        );
        ScanModel {
            motion: track.map(Arc::new),
            ..self
        }
    }

    pub fn points(&self) -> &[Point2<f64>] {
        &self.features.points
    }

    /// How far its farthest point lies from the sensor (m): two sensors farther apart than
    /// the sum of theirs (plus scoring's margins) cannot see each other's walls.
    pub fn reach_m(&self) -> f64 {
        self.points()
            .iter()
            .map(|q| q.coords.norm())
            .fold(0.0, f64::max)
    }

    pub fn class(&self, i: usize) -> PointClass {
        self.features
            .classes
            .get(i)
            .copied()
            .unwrap_or(PointClass::Other)
    }
}

/// At most `count` of `idx`, evenly spaced by arc length along the outline.
fn spread(points: &[Point2<f64>], idx: &[usize], count: usize) -> Vec<usize> {
    let arc: f64 = idx
        .windows(2)
        .map(|w| (points[w[1]] - points[w[0]]).norm().min(0.5))
        .sum();
    let spacing = (arc / count.max(1) as f64).max(0.02);
    let mut out = Vec::with_capacity(count + 1);
    let mut last: Option<Point2<f64>> = None;
    let mut travelled = 0.0;
    for &i in idx {
        let p = points[i];
        if let Some(l) = last {
            travelled += (p - l).norm().min(0.5);
        }
        if last.is_none() || travelled >= spacing {
            out.push(i);
            travelled = 0.0;
        }
        last = Some(p);
    }
    out
}

/// Normals: the segment's for wall points, else a local fit over scan neighbours, else (an
/// isolated return) the direction to the sensor; and which points have a surface's.
fn normals_of(f: &Features, neighbour_m: f64) -> (Vec<Vector2<f64>>, Vec<bool>) {
    let pts = &f.points;
    let mut normals: Vec<Vector2<f64>> = pts
        .iter()
        .map(|p| {
            let n = -p.coords;
            if n.norm() > 1e-9 {
                n.normalize()
            } else {
                Vector2::x()
            }
        })
        .collect();
    let mut surface = vec![false; pts.len()];
    for g in &f.groups {
        for i in g.clone() {
            let near = |j: &usize| (pts[*j] - pts[i]).norm() <= neighbour_m;
            let lo = (g.start..i).rev().take_while(near).last().unwrap_or(i);
            let hi = (i + 1..g.end).take_while(near).last().unwrap_or(i);
            if hi - lo < 2 {
                continue;
            }
            let n = (hi - lo + 1) as f64;
            let c = (lo..=hi).fold(Vector2::zeros(), |s, j| s + pts[j].coords) / n;
            let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
            for q in &pts[lo..=hi] {
                let d = q.coords - c;
                sxx += d.x * d.x;
                sxy += d.x * d.y;
                syy += d.y * d.y;
            }
            let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
            let mut normal = Vector2::new(-angle.sin(), angle.cos());
            if normal.dot(&pts[i].coords) > 0.0 {
                normal = -normal;
            }
            normals[i] = normal;
            surface[i] = true;
        }
    }
    for s in &f.segments {
        for &i in &s.points {
            normals[i] = s.normal;
            if let Some(on) = surface.get_mut(i) {
                *on = true;
            }
        }
    }
    (normals, surface)
}

/// How much two scans see of the same surfaces under a known pose (the truth, in evaluation):
/// the share of each scan's points within 10 cm of the other's, seen from the same side, the
/// smaller of the two. The same definition as the simulator's `view_overlap`, so "≥ 30 %
/// overlap" means the same on simulated and real scans.
pub fn shared_view(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2) -> f64 {
    share_near(a, b, a_from_b).min(share_near(b, a, &a_from_b.inverse()))
}

/// Share of `b`'s points within 10 cm of `a`'s under `a_from_b`, where both sensors face the
/// surface from the same side (their normals, which point towards each sensor, agree). `a`'s
/// own lookup grid finds the nearest point: a large site asks this of thousands of pairs.
fn share_near(a: &ScanModel, b: &ScanModel, a_from_b: &Pose2) -> f64 {
    let grid = &a.grid;
    let pts = b.points();
    if pts.is_empty() {
        return 0.0;
    }
    let near = pts
        .iter()
        .zip(&b.normals)
        .filter(|(p, n)| {
            let q = a_from_b * **p;
            grid.nearest(&q).is_some_and(|j| {
                let close = a.points().get(j).is_some_and(|r| (q - r).norm() <= 0.1);
                let facing = a
                    .normals
                    .get(j)
                    .is_some_and(|m| m.dot(&(a_from_b * **n)) > 0.0);
                close && facing
            })
        })
        .count();
    near as f64 / pts.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `violates` as it was before the sector shortcut: every point through its bin.
    fn violates_by_bin(polar: &PolarRanges, q: &Point2<f64>, margin_m: f64, frac: f64) -> bool {
        let r = q.coords.norm();
        if r < 0.2 {
            return false;
        }
        let bins = polar.ranges_m.len();
        let b = PolarRanges::bin_of(polar.bin_rad, bins, q.y.atan2(q.x));
        let seen = [(b + bins - 1) % bins, b, (b + 1) % bins]
            .iter()
            .map(|&k| polar.ranges_m[k])
            .fold(f32::INFINITY, f32::min) as f64;
        seen.is_finite() && r < seen - margin_m - frac * r
    }

    #[test]
    fn the_sector_shortcut_decides_every_point_as_its_bin_does() {
        // A 270° view of a ragged room (near on one side, far on the other, a blind cone
        // behind), tested on a dense lattice including points on the axes and diagonals.
        let step = 0.25f64.to_radians();
        let points: Vec<Point2<f64>> = (0..1081)
            .map(|k| {
                let a = -135f64.to_radians() + k as f64 * step;
                let r = 3.0 + 2.5 * (3.0 * a).sin() + if k % 97 < 5 { 20.0 } else { 0.0 };
                Point2::new(r * a.cos(), r * a.sin())
            })
            .collect();
        let polar = PolarRanges::new(&points, step);
        let mut violations = 0;
        for i in -300..=300 {
            for j in -300..=300 {
                let q = Point2::new(i as f64 * 0.1, j as f64 * 0.1);
                let fast = polar.violates(&q, 0.15, 0.02);
                assert_eq!(fast, violates_by_bin(&polar, &q, 0.15, 0.02), "{q}");
                violations += fast as usize;
            }
        }
        assert!(violations > 1000, "{violations}");
    }

    #[test]
    fn a_point_finds_the_bin_its_bearing_falls_in_without_an_arctangent() {
        // Random bearings, bearings within rounding of every bin edge and of the ±π seam, and
        // the axes: the step's bin is the arctangent's wherever the step gives one.
        use rand::{Rng, SeedableRng};
        for bin_rad in [
            0.25f64.to_radians(),
            0.3515625f64.to_radians(),
            1f64.to_radians(),
        ] {
            let polar = PolarRanges::new(&[], bin_rad);
            let bins = polar.ranges_m.len();
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
            let mut bearings: Vec<f64> = (0..200_000).map(|_| rng.random_range(-PI..=PI)).collect();
            for k in 0..=bins {
                let edge = k as f64 * bin_rad - PI;
                bearings.extend([-2e-15, -1e-16, 0.0, 1e-16, 2e-15].map(|e| edge + e));
            }
            let mut split = 0;
            for bearing in bearings {
                for r in [0.5, 7.0, 31.0] {
                    let q = Point2::new(r * bearing.cos(), r * bearing.sin());
                    let d = diamond(&q);
                    let want = PolarRanges::bin_of(bin_rad, bins, q.y.atan2(q.x));
                    assert_eq!(polar.bin_at(&q, d), want, "{q} at {bin_rad}");
                    split += (polar.cell_bin[cell_of(d)] == SPLIT) as usize;
                }
            }
            for q in [
                (1.0f64, 0.0f64),
                (0.0, 1.0),
                (-1.0, 0.0),
                (-1.0, -0.0),
                (0.0, -1.0),
                (1.0, -0.0),
            ] {
                let q = Point2::new(q.0, q.1);
                let want = PolarRanges::bin_of(bin_rad, bins, q.y.atan2(q.x));
                assert_eq!(polar.bin_at(&q, diamond(&q)), want, "{q}");
            }
            // Most points need no arctangent.
            assert!(split < 600_000 / 4, "{split}");
        }
    }
}
