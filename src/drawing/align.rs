//! `building_from_site`: where the site frame (the anchor sensor's) lies in the drawing's.
//! Pure: segments and scan models in, a transform and its residuals out. Three ways, each
//! with residuals:
//!
//! 1. [`fit_pairs`]: two or more point pairs (site ↔ drawing), least squares, rigid or
//!    similarity, with each pair's residual;
//! 2. [`refine`]: the map's wall points fitted to the nearest drawing lines (seed 003's line
//!    fit, robust and iterated), with each line's offset, so a wall moved since the drawing
//!    was made shows by name;
//! 3. [`automatic`]: each sensor's scan registered against the drawing with the sensors' own
//!    hypothesis and free-space scoring (`register::hypotheses`, `register::score`: the
//!    drawing is one more map of walls), the candidates of all sensors pooled into site-wide
//!    alignments, each refined and scored against every sensor; a runner-up that fits nearly
//!    as well (a symmetric hall) means abstaining, with the reason.

use super::{Drawing, WallSegment};
use crate::features::{EdgeKind, EdgePoint, Features, PointClass, Segment};
use crate::geometry::{Pose2, pose_error, pose2};
use crate::register::model::{NearestGrid, PolarRanges};
use crate::register::pair::pose_sigmas;
use crate::register::score::{score, score_coarse};
use crate::register::{RegisterParams, ScanModel, hypotheses::hypotheses};
use nalgebra::{Matrix3, Point2, Rotation2, Vector2, Vector3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// A similarity transform `p_b = scale · R(yaw) · p_s + t` (scale 1: rigid).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_rad: f64,
    pub scale: f64,
}

impl Similarity {
    pub fn rigid(p: &Pose2) -> Similarity {
        Similarity {
            x_m: p.translation.x,
            y_m: p.translation.y,
            yaw_rad: p.rotation.angle(),
            scale: 1.0,
        }
    }

    pub fn apply(&self, p: &Point2<f64>) -> Point2<f64> {
        let r = Rotation2::new(self.yaw_rad);
        Point2::from(r * p.coords * self.scale + Vector2::new(self.x_m, self.y_m))
    }

    /// The inverse: the site point at building point `p` (`R(−yaw) (p − t) / scale`).
    pub fn to_site(&self, p: &Point2<f64>) -> Point2<f64> {
        let back = Rotation2::new(-self.yaw_rad);
        Point2::from(back * (p.coords - Vector2::new(self.x_m, self.y_m)) / self.scale)
    }

    /// The rigid part (as a pose; the scale left out).
    pub fn pose(&self) -> Pose2 {
        pose2(self.x_m, self.y_m, self.yaw_rad)
    }

    /// Where a sensor at `site_from_sensor` stands in the building: position mapped, heading
    /// turned.
    pub fn sensor(&self, site_from_sensor: &Pose2) -> Pose2 {
        let p = self.apply(&Point2::from(site_from_sensor.translation.vector));
        pose2(p.x, p.y, self.yaw_rad + site_from_sensor.rotation.angle())
    }
}

/// Why an alignment could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    #[error("need two or more point pairs (\"sx,sy=dx,dy; sx,sy=dx,dy\", m), got {0}")]
    TooFewPairs(usize),
    #[error("the site points of the pairs coincide; pick points at least a metre apart")]
    CoincidentPairs,
    #[error("bad point pairs {0:?}: use \"sx,sy=dx,dy;sx,sy=dx,dy\"")]
    BadPairs(String),
}

/// A pair fit: the transform and each pair's residual (m, in the drawing).
#[derive(Debug, Clone, PartialEq)]
pub struct PairFit {
    pub transform: Similarity,
    pub residuals_m: Vec<f64>,
    /// Of (x, y, yaw) of the transform, from the clicks' σ (`CLICK_SIGMA_M`, or their RMS
    /// residual when larger).
    pub covariance: Matrix3<f64>,
}

/// σ of a clicked point on each axis (m): a corner clicked on a drawing, or measured on
/// site, is good to a couple of decimetres, not centimetres.
pub const CLICK_SIGMA_M: f64 = 0.1;

/// Parses `"sx,sy=dx,dy;sx,sy=dx,dy"` (site point = drawing point, metres).
pub fn parse_pairs(text: &str) -> Result<Vec<PointPair>, AlignError> {
    let bad = || AlignError::BadPairs(text.to_string());
    text.split(';')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|pair| {
            let (s, d) = pair.split_once('=').ok_or_else(bad)?;
            let point = |t: &str| -> Result<Point2<f64>, AlignError> {
                let (x, y) = t.split_once(',').ok_or_else(bad)?;
                let x: f64 = x.trim().parse().map_err(|_| bad())?;
                let y: f64 = y.trim().parse().map_err(|_| bad())?;
                if x.is_finite() && y.is_finite() {
                    Ok(Point2::new(x, y))
                } else {
                    Err(bad())
                }
            };
            Ok((point(s)?, point(d)?))
        })
        .collect()
}

/// Parses point pairs to align from (`--pairs`, `[site] drawing_pairs`, the socket's
/// `align`): as [`parse_pairs`], and two or more of them.
pub fn parse_pairs_to_fit(text: &str) -> Result<Vec<PointPair>, AlignError> {
    let pairs = parse_pairs(text)?;
    if pairs.len() < 2 {
        return Err(AlignError::TooFewPairs(pairs.len()));
    }
    Ok(pairs)
}

/// A point pair: a site point and the drawing point it lies at (m).
pub type PointPair = (Point2<f64>, Point2<f64>);

/// Least-squares rigid (or, with `similarity`, similarity) fit of `pairs` (site, drawing):
/// Umeyama's closed form in 2D.
pub fn fit_pairs(pairs: &[PointPair], similarity: bool) -> Result<PairFit, AlignError> {
    if pairs.len() < 2 {
        return Err(AlignError::TooFewPairs(pairs.len()));
    }
    let n = pairs.len() as f64;
    let cs = pairs
        .iter()
        .fold(Vector2::zeros(), |s, (a, _)| s + a.coords)
        / n;
    let cd = pairs
        .iter()
        .fold(Vector2::zeros(), |s, (_, b)| s + b.coords)
        / n;
    let (mut dot, mut cross, mut var_s) = (0.0, 0.0, 0.0);
    for (s, d) in pairs {
        let (u, v) = (s.coords - cs, d.coords - cd);
        dot += u.dot(&v);
        cross += u.perp(&v);
        var_s += u.norm_squared();
    }
    if var_s < 1e-6 {
        return Err(AlignError::CoincidentPairs);
    }
    let yaw_rad = cross.atan2(dot);
    let scale = if similarity {
        (dot * dot + cross * cross).sqrt() / var_s
    } else {
        1.0
    };
    let t = cd - Rotation2::new(yaw_rad) * cs * scale;
    let transform = Similarity {
        x_m: t.x,
        y_m: t.y,
        yaw_rad,
        scale,
    };
    let residuals_m: Vec<f64> = pairs
        .iter()
        .map(|(s, d)| (transform.apply(s) - d).norm())
        .collect();
    let rms = (residuals_m.iter().map(|r| r * r).sum::<f64>() / n).sqrt();
    let var = rms.max(CLICK_SIGMA_M).powi(2);
    // q = R p + t at each drawing point: ∂q/∂t = I, ∂q/∂yaw = perp(q − t).
    let mut info = Matrix3::zeros();
    for (_, d) in pairs {
        let lever = d.coords - t;
        for j in [
            Vector3::new(1.0, 0.0, -lever.y),
            Vector3::new(0.0, 1.0, lever.x),
        ] {
            info += j * j.transpose() / var;
        }
    }
    let covariance = info
        .try_inverse()
        .unwrap_or_else(|| Matrix3::identity() * UNKNOWN_SIGMA.powi(2));
    Ok(PairFit {
        transform,
        residuals_m,
        covariance,
    })
}

/// A wall point of the fused map, in the site frame, with its normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    pub p: Point2<f64>,
    pub n: Vector2<f64>,
}

/// The wall points of a sensor's scan model in the site frame.
pub fn map_points(model: &ScanModel, site_from_sensor: &Pose2) -> Vec<MapPoint> {
    let pts = model.points();
    model
        .features
        .segments
        .iter()
        .flat_map(|s| s.points.iter())
        .filter_map(|&i| {
            let p = pts.get(i)?;
            let n = model.normals.get(i)?;
            Some(MapPoint {
                p: site_from_sensor * p,
                n: site_from_sensor.rotation * n,
            })
        })
        .collect()
}

/// Drawing segments bucketed by cell, for nearest-line queries within a gate.
pub struct LineIndex<'a> {
    lines: &'a [WallSegment],
    min: Point2<f64>,
    cell_m: f64,
    width: usize,
    height: usize,
    cells: Vec<Vec<u32>>,
}

/// Nearest-line queries reach this far at most (m).
const MAX_GATE_M: f64 = 0.6;

impl<'a> LineIndex<'a> {
    pub fn new(drawing: &'a Drawing) -> Self {
        let cell_m = 1.0;
        let (lo, hi) = drawing.bounds;
        let min = lo - Vector2::repeat(MAX_GATE_M + cell_m);
        let width = ((hi.x - min.x + MAX_GATE_M) / cell_m).ceil() as usize + 2;
        let height = ((hi.y - min.y + MAX_GATE_M) / cell_m).ceil() as usize + 2;
        let mut cells = vec![Vec::new(); width * height];
        for (k, s) in drawing.segments.iter().enumerate() {
            let steps = (s.length_m() / (0.5 * cell_m)).ceil().max(1.0) as usize;
            for i in 0..=steps {
                let q = s.a + (s.b - s.a) * (i as f64 / steps as f64);
                let (cx, cy) = (
                    ((q.x - min.x) / cell_m) as i64,
                    ((q.y - min.y) / cell_m) as i64,
                );
                for y in cy - 1..=cy + 1 {
                    for x in cx - 1..=cx + 1 {
                        if x < 0 || y < 0 || x as usize >= width || y as usize >= height {
                            continue;
                        }
                        let c = y as usize * width + x as usize;
                        if cells[c].last() != Some(&(k as u32)) {
                            cells[c].push(k as u32);
                        }
                    }
                }
            }
        }
        LineIndex {
            lines: &drawing.segments,
            min,
            cell_m,
            width,
            height,
            cells,
        }
    }

    /// The nearest line to `q` within `gate_m` roughly parallel to a surface of normal `n`
    /// (|cos| ≥ 0.8): its index and the signed distance along its normal.
    fn nearest(
        &self,
        q: &Point2<f64>,
        n: &Vector2<f64>,
        gate_m: f64,
    ) -> Option<(usize, f64, Vector2<f64>)> {
        let x = ((q.x - self.min.x) / self.cell_m).floor();
        let y = ((q.y - self.min.y) / self.cell_m).floor();
        if x < 0.0 || y < 0.0 || x >= self.width as f64 || y >= self.height as f64 {
            return None;
        }
        let cell = self.cells.get(y as usize * self.width + x as usize)?;
        let mut best: Option<(usize, f64, Vector2<f64>, f64)> = None;
        for &k in cell {
            let s = &self.lines[k as usize];
            let d = s.b - s.a;
            let len = d.norm();
            if len < 1e-9 {
                continue;
            }
            let u = d / len;
            let normal = Vector2::new(-u.y, u.x);
            if normal.dot(n).abs() < 0.8 {
                continue;
            }
            let along = u.dot(&(q - s.a));
            let outside = (-along).max(along - len).max(0.0);
            let signed = normal.dot(&(q - s.a));
            let dist = (signed * signed + outside * outside).sqrt();
            if dist <= gate_m && best.is_none_or(|b| dist < b.3) {
                best = Some((k as usize, signed, normal, dist));
            }
        }
        best.map(|(k, s, n, _)| (k, s, n))
    }
}

/// One drawing line the map's walls were fitted to.
#[derive(Debug, Clone, PartialEq)]
pub struct LineResidual {
    pub a: Point2<f64>,
    pub b: Point2<f64>,
    pub layer: String,
    /// Median signed distance of the map's wall points from the line (m; + along its left
    /// normal).
    pub offset_m: f64,
    pub points: usize,
    /// The map's wall stands this far off the drawing's: moved since the drawing was made,
    /// or drawn wrong.
    pub moved: bool,
}

/// A refined alignment with its residuals.
#[derive(Debug, Clone, PartialEq)]
pub struct Refined {
    pub transform: Similarity,
    /// RMS of the inlier residuals (m).
    pub rms_m: f64,
    /// Map points within 5 cm of a drawing line / map points.
    pub inlier_share: f64,
    /// σ of x, y (m) and yaw (rad) of the alignment (of the site origin's place in the
    /// building and the turn), from [`Refined::covariance`].
    pub sigma: (f64, f64, f64),
    /// Covariance of (x, y, yaw) of the transform: each fitted line once (see
    /// `line_covariance`), not each of its thousands of points.
    pub covariance: Matrix3<f64>,
    /// Drawing lines the covariance rests on: with enough support, not reported moved.
    pub fitted_lines: usize,
    /// Lines with enough support, the moved ones first, then by offset.
    pub lines: Vec<LineResidual>,
}

impl Refined {
    /// σ of x and y (m) of where the site point `p_site` lands in the building.
    pub fn sigma_at(&self, p_site: &Point2<f64>) -> (f64, f64) {
        sigma_at(&self.transform, &self.covariance, p_site)
    }
}

/// σ of x and y (m) of where the site point `p_site` lands in the building under `t` with
/// covariance `c` of its (x, y, yaw): its translation and, over the lever arm from the site
/// origin, its turn.
pub fn sigma_at(t: &Similarity, c: &Matrix3<f64>, p_site: &Point2<f64>) -> (f64, f64) {
    let l = t.apply(p_site).coords - Vector2::new(t.x_m, t.y_m);
    let j = nalgebra::Matrix2x3::new(1.0, 0.0, -l.y, 0.0, 1.0, l.x);
    let c = j * c * j.transpose();
    (c[(0, 0)].max(0.0).sqrt(), c[(1, 1)].max(0.0).sqrt())
}

/// A wall this far (m) off its drawing line is reported moved.
pub const MOVED_M: f64 = 0.08;
/// Points on a line before its offset is reported.
const MIN_LINE_POINTS: usize = 15;
/// Robust scale of the fit (Cauchy weights): walls 20 cm off barely pull.
const ROBUST_M: f64 = 0.04;
/// The robust scale of the first iterations, narrowing to [`ROBUST_M`]: wide at first, so
/// that every wall pulls and the fit settles where most walls agree, not on whichever wall
/// (perhaps one moved since the drawing) the start happened to lie nearest.
const ROBUST_SCHEDULE_M: [f64; 7] = [0.3, 0.3, 0.2, 0.15, 0.1, 0.07, 0.05];
/// A line with this many points or more weighs as one line; fewer, proportionally less.
const LINE_FULL_POINTS: f64 = 20.0;

/// Fits the map's wall points to the nearest drawing lines, from `init` (scale kept): Gauss-
/// Newton on point-to-line distances with Cauchy weights, the gate narrowing from `gate_m`.
pub fn refine(map: &[MapPoint], index: &LineIndex<'_>, init: &Similarity, gate_m: f64) -> Refined {
    refine_n(map, index, init, gate_m, 40)
}

fn refine_n(
    map: &[MapPoint],
    index: &LineIndex<'_>,
    init: &Similarity,
    gate_m: f64,
    max_iter: usize,
) -> Refined {
    let mut t = *init;
    let gates = [gate_m, gate_m, 0.75 * gate_m, 0.5 * gate_m, 0.3, 0.25, 0.2];
    let mut hits: Vec<(usize, f64, Vector3<f64>)> = Vec::with_capacity(map.len());
    let mut per_line = vec![0u32; index.lines.len()];
    for iter in 0..max_iter {
        let gate = gates
            .get(iter)
            .copied()
            .unwrap_or(0.2)
            .clamp(0.15, MAX_GATE_M);
        let robust = ROBUST_SCHEDULE_M.get(iter).copied().unwrap_or(ROBUST_M);
        let r = Rotation2::new(t.yaw_rad);
        hits.clear();
        for m in map {
            let q = t.apply(&m.p);
            let n = r * m.n;
            let Some((k, res, ln)) = index.nearest(&q, &n, gate) else {
                continue;
            };
            per_line[k] += 1;
            hits.push((
                k,
                res,
                Vector3::new(ln.x, ln.y, ln.dot(&Vector2::new(-q.y, q.x))),
            ));
        }
        // Each line counts once (its points share its error): a long wall moved since the
        // drawing, seen by every sensor, must not outvote the many walls that were not.
        let (mut hh, mut g) = (Matrix3::zeros(), Vector3::zeros());
        for (k, res, j) in &hits {
            let share = 1.0 / f64::from(per_line[*k]).max(LINE_FULL_POINTS);
            let w = share / (1.0 + (res / robust).powi(2));
            hh += j * j.transpose() * w;
            g += j * (w * res);
        }
        for (k, _, _) in &hits {
            per_line[*k] = 0;
        }
        let Some(inv) = (hh + Matrix3::identity() * 1e-9).try_inverse() else {
            break;
        };
        let d = -(inv * g);
        // Left-multiply the increment: q' = R(dθ) q + dt.
        let dr = Rotation2::new(d.z);
        let tv = dr * Vector2::new(t.x_m, t.y_m) + Vector2::new(d.x, d.y);
        t = Similarity {
            x_m: tv.x,
            y_m: tv.y,
            yaw_rad: t.yaw_rad + d.z,
            scale: t.scale,
        };
        if iter >= gates.len() && d.xy().norm() < 1e-5 && d.z.abs() < 1e-6 {
            break;
        }
    }
    residuals(map, index, t)
}

fn residuals(map: &[MapPoint], index: &LineIndex<'_>, t: Similarity) -> Refined {
    let r = Rotation2::new(t.yaw_rad);
    // Each line's residuals and how far along it its points reach (the seen extent).
    let mut per_line: Vec<(Vec<f64>, f64, f64)> =
        vec![(Vec::new(), f64::INFINITY, f64::NEG_INFINITY); index.lines.len()];
    let (mut sq, mut inliers) = (0.0, 0usize);
    for m in map {
        let q = t.apply(&m.p);
        if let Some((k, res, _)) = index.nearest(&q, &(r * m.n), 0.5) {
            let s = &index.lines[k];
            let along = (s.b - s.a).normalize().dot(&(q - s.a));
            let l = &mut per_line[k];
            l.0.push(res);
            l.1 = l.1.min(along);
            l.2 = l.2.max(along);
            if res.abs() <= 0.05 {
                sq += res * res;
                inliers += 1;
            }
        }
    }
    let rms_m = if inliers > 0 {
        (sq / inliers as f64).sqrt()
    } else {
        f64::INFINITY
    };
    let mut lines = Vec::new();
    let mut extents = Vec::new();
    for (k, (mut v, lo, hi)) in per_line.into_iter().enumerate() {
        if v.len() < MIN_LINE_POINTS {
            continue;
        }
        v.sort_by(f64::total_cmp);
        let offset_m = v[v.len() / 2];
        let s = &index.lines[k];
        let moved = offset_m.abs() > MOVED_M;
        if !moved {
            let u = (s.b - s.a).normalize();
            extents.push((s.a + u * lo, s.a + u * hi, offset_m));
        }
        lines.push(LineResidual {
            a: s.a,
            b: s.b,
            layer: s.layer.clone(),
            offset_m,
            points: v.len(),
            moved,
        });
    }
    lines.sort_by(|x, y| {
        y.moved
            .cmp(&x.moved)
            .then(y.offset_m.abs().total_cmp(&x.offset_m.abs()))
    });
    let covariance = line_covariance(&extents, &t);
    Refined {
        transform: t,
        rms_m,
        inlier_share: inliers as f64 / map.len().max(1) as f64,
        sigma: (
            covariance[(0, 0)].sqrt(),
            covariance[(1, 1)].sqrt(),
            covariance[(2, 2)].sqrt(),
        ),
        covariance,
        fitted_lines: extents.len(),
        lines,
    }
}

/// Smallest σ of a line's offset (m): neither a drawing nor a wall's face is truer than this.
const MIN_LINE_SIGMA_M: f64 = 0.01;
/// σ (m, m, rad) given when the lines do not pin the alignment down at all.
const UNKNOWN_SIGMA: f64 = 1e3;

/// The covariance of (x, y, yaw) of `building_from_site` from the lines fitted (seed 003's
/// line fit): the points along one wall share its error (its thickness, the drawing's
/// accuracy), so each line counts once, as its seen extent's two ends, with the spread of the
/// lines' offsets as their σ; walls reported moved are left out (the robust fit ignored them).
/// Parallel walls only leave the slide along them unknown, and that shows. A line no other
/// line checks along its normal (the one wall seen across a room, or the partner of one
/// found moved) would not show as moved if it were: it counts as known to
/// `UNCHECKED_LINE_SIGMA_M` only.
fn line_covariance(extents: &[(Point2<f64>, Point2<f64>, f64)], t: &Similarity) -> Matrix3<f64> {
    let unknown = Matrix3::identity() * UNKNOWN_SIGMA.powi(2);
    if extents.len() < 3 {
        return unknown;
    }
    // Offsets' spread, with three degrees of freedom taken by the fit.
    let var = (extents.iter().map(|e| e.2 * e.2).sum::<f64>() / (extents.len() - 3).max(1) as f64)
        .max(MIN_LINE_SIGMA_M.powi(2));
    let origin = Vector2::new(t.x_m, t.y_m);
    // Each line's information at unit variance, and its normal.
    let lines: Vec<(Matrix3<f64>, Vector2<f64>)> = extents
        .iter()
        .filter_map(|(a, b, _)| {
            let d = b - a;
            let len = d.norm();
            (len > 1e-9).then(|| {
                let n = Vector2::new(-d.y, d.x) / len;
                let mut info = Matrix3::zeros();
                for e in [a, b] {
                    // q = R p + t: ∂q/∂t = I, ∂q/∂yaw = perp(q − t).
                    let lever = e.coords - origin;
                    let j = Vector3::new(n.x, n.y, n.dot(&Vector2::new(-lever.y, lever.x)));
                    info += j * j.transpose();
                }
                (info, n)
            })
        })
        .collect();
    let total: Matrix3<f64> = lines.iter().map(|(i, _)| i).sum();
    let along = |info: &Matrix3<f64>, n: &Vector2<f64>| {
        (n.transpose() * info.fixed_view::<2, 2>(0, 0) * n)[(0, 0)]
    };
    let mut info = Matrix3::zeros();
    for (own, n) in &lines {
        let checked = along(&(total - own), n) >= along(own, n) * CHECKED_SHARE;
        let v = if checked {
            var
        } else {
            var.max(UNCHECKED_LINE_SIGMA_M.powi(2))
        };
        info += own / v;
    }
    match info.try_inverse() {
        Some(c) if c.iter().all(|v| v.is_finite()) && c[(0, 0)] >= 0.0 => c,
        _ => unknown,
    }
}

/// σ of a line no other checks (m): it may be a wall moved since the drawing, by anything
/// the refinement's gate lets through; known as well as a click (`CLICK_SIGMA_M`).
const UNCHECKED_LINE_SIGMA_M: f64 = CLICK_SIGMA_M;
/// A line is checked when the other lines hold at least this share of its own information
/// along its normal (one parallel wall that agrees is a check).
const CHECKED_SHARE: f64 = 0.9;

/// The drawing as a scan model for `register::hypotheses` and `register::score`: its lines
/// sampled every 4 cm, each point and segment twice with opposite normals (a drawn wall is
/// seen from either side), corners of both kinds, and no free space of its own (a drawing was
/// not seen from anywhere; the sensors' free space still tests it).
pub fn drawing_model(drawing: &Drawing, p: &RegisterParams) -> ScanModel {
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let mut segments = Vec::new();
    for s in &drawing.segments {
        let len = s.length_m();
        let u = (s.b - s.a) / len;
        let n = Vector2::new(-u.y, u.x);
        let steps = (len / 0.04).ceil().max(1.0) as usize;
        for sign in [1.0, -1.0] {
            let first = points.len();
            for i in 0..=steps {
                points.push(s.a + (s.b - s.a) * (i as f64 / steps as f64));
                normals.push(n * sign);
            }
            segments.push(Segment {
                a: s.a,
                b: s.b,
                normal: n * sign,
                points: (first..points.len()).collect(),
            });
        }
    }
    segments.sort_by(|a, b| b.length_m().total_cmp(&a.length_m()));
    // Corners: where two non-parallel lines meet end to end.
    let mut edges = Vec::new();
    let ends: Vec<(Point2<f64>, Vector2<f64>)> = drawing
        .segments
        .iter()
        .flat_map(|s| {
            let u = (s.b - s.a).normalize();
            [(s.a, u), (s.b, u)]
        })
        .collect();
    // Scoring looks no further than the coarse hit distance (0.24 m): a smaller reach than the
    // scans' keeps a large drawing's grid quick to build.
    let reach_m = (p.hit_m + p.coarse_slack_m + 0.01).min(p.grid_radius_m);
    let grid = NearestGrid::new(&points, p.grid_res_m, reach_m);
    if ends.len() <= 20_000 {
        for (i, (e, u)) in ends.iter().enumerate() {
            let corner = ends[i + 1..]
                .iter()
                .any(|(f, v)| (f - e).norm() < 0.02 && u.perp(v).abs() > 0.5);
            if corner && let Some(k) = grid.nearest(e) {
                for kind in [EdgeKind::Convex, EdgeKind::Concave] {
                    edges.push(EdgePoint {
                        index: k,
                        p: *e,
                        kind,
                    });
                }
            }
        }
    }
    let spread = |count: usize| -> Vec<usize> {
        let step = (points.len() / count.max(1)).max(1);
        (0..points.len()).step_by(step).collect()
    };
    let score_sample = spread(2 * p.score_points.max(1000));
    let icp_sample = spread(p.icp_points);
    let classes = vec![PointClass::Wall; points.len()];
    let groups = std::iter::once(0..points.len()).collect();
    let surface = vec![true; points.len()];
    ScanModel {
        features: Features {
            points,
            groups,
            segments,
            edges,
            classes,
        },
        normals,
        surface,
        score_sample,
        icp_sample,
        grid,
        polar: PolarRanges::new(&[], 1f64.to_radians()),
        plane: None,
        motion: None,
    }
}

/// A sensor taking part in the automatic alignment: its scan model and where it stands in
/// the site.
pub struct AlignSensor<'a> {
    pub id: &'a str,
    pub model: &'a ScanModel,
    pub site_from_sensor: Pose2,
}

/// A site-wide candidate and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct AutoCandidate {
    pub refined: Refined,
    /// Mean of the sensors' free-space scores against the drawing.
    pub score: f64,
}

/// The automatic alignment: the best candidate, or why none is trusted, with the candidates.
#[derive(Debug, Clone, PartialEq)]
pub struct AutoResult {
    pub verdict: Result<(), String>,
    pub candidates: Vec<AutoCandidate>,
}

/// Mean per-sensor score below which the map does not fit the drawing anywhere.
pub const MIN_AUTO_SCORE: f64 = 0.15;
/// A clearly different candidate scoring this share of the best makes the answer ambiguous.
pub const MAX_AUTO_AMBIGUITY: f64 = 0.9;

/// How well the site fits the drawing at `building_from_site`: the mean of the sensors'
/// free-space scores against it (the drawing as one more scan model, [`drawing_model`]).
pub fn site_score(
    dmodel: &ScanModel,
    sensors: &[AlignSensor<'_>],
    building_from_site: &Pose2,
    p: &RegisterParams,
) -> f64 {
    sensors
        .iter()
        .map(|s| {
            score(
                dmodel,
                s.model,
                &(building_from_site * s.site_from_sensor),
                p,
            )
            .value
        })
        .sum::<f64>()
        / sensors.len().max(1) as f64
}

/// Registers the sensors' scans against the drawing (see the module doc).
pub fn automatic(
    dmodel: &ScanModel,
    index: &LineIndex<'_>,
    sensors: &[AlignSensor<'_>],
    p: &RegisterParams,
) -> AutoResult {
    if sensors.is_empty() {
        return AutoResult {
            verdict: Err("no placed sensor to align".into()),
            candidates: Vec::new(),
        };
    }
    // More translation peaks per heading than between two scans: a drawing has many more
    // places that look alike locally.
    let pp = RegisterParams {
        peaks_per_rotation: 24,
        ..p.clone()
    };
    let per_sensor: Vec<Vec<Pose2>> = sensors
        .par_iter()
        .map(|s| {
            let mut coarse: Vec<(f64, Pose2)> = hypotheses(dmodel, s.model, &pp)
                .into_iter()
                .map(|(_, h)| (score_coarse(dmodel, s.model, &h, &pp).value, h))
                .collect();
            coarse.sort_by(|x, y| y.0.total_cmp(&x.0));
            let mut seeds: Vec<Pose2> = Vec::new();
            for (_, h) in coarse {
                if seeds.len() >= 6 {
                    break;
                }
                if seeds.iter().all(|x| {
                    let (dt, dr) = pose_error(x, &h);
                    dt > 0.5 || dr > 5f64.to_radians()
                }) {
                    seeds.push(h * s.site_from_sensor.inverse());
                }
            }
            seeds
        })
        .collect();
    let mut pooled: Vec<Pose2> = Vec::new();
    for h in per_sensor.into_iter().flatten() {
        if pooled.iter().all(|x| {
            let (dt, dr) = pose_error(x, &h);
            dt > 0.3 || dr > 3f64.to_radians()
        }) {
            pooled.push(h);
        }
    }
    let map: Vec<MapPoint> = thin(
        sensors
            .iter()
            .flat_map(|s| map_points(s.model, &s.site_from_sensor))
            .collect(),
        2500,
    );
    let mut candidates: Vec<AutoCandidate> = pooled
        .par_iter()
        .map(|h| {
            // A short refinement to rank by; the winner is refined fully on every point.
            let refined = refine_n(&map, index, &Similarity::rigid(h), 0.5, 12);
            let score = site_score(dmodel, sensors, &refined.transform.pose(), p);
            AutoCandidate { refined, score }
        })
        .collect();
    candidates.sort_by(|x, y| y.score.total_cmp(&x.score));
    // Refined candidates that converged to the same place are one.
    let mut distinct: Vec<AutoCandidate> = Vec::new();
    for c in candidates {
        if distinct.iter().all(|d| {
            let (dt, dr) = pose_error(&d.refined.transform.pose(), &c.refined.transform.pose());
            dt > 0.5 || dr > 5f64.to_radians()
        }) {
            distinct.push(c);
        }
    }
    distinct.truncate(8);
    let verdict = match distinct.as_slice() {
        [] => Err("no hypothesis: too few walls in the map or the drawing".to_string()),
        [best, ..] if best.score < MIN_AUTO_SCORE => Err(format!(
            "the map fits the drawing nowhere well (best score {:.2}); check the layers and the scale, or give two point pairs (--pairs)",
            best.score
        )),
        [best, second, ..] if second.score > MAX_AUTO_AMBIGUITY * best.score => {
            let rel = best.refined.transform.pose().inverse() * second.refined.transform.pose();
            Err(format!(
                "ambiguous: an alignment {:.2} m / {:.0}° away fits {:.0} % as well (a symmetric building?); ask for two points: give two point pairs with --pairs",
                rel.translation.vector.norm(),
                rel.rotation.angle().to_degrees().abs(),
                100.0 * second.score / best.score
            ))
        }
        _ => Ok(()),
    };
    AutoResult {
        verdict,
        candidates: distinct,
    }
}

/// Every k-th point, so at most `max` remain.
fn thin<T>(points: Vec<T>, max: usize) -> Vec<T> {
    let step = points.len().div_ceil(max.max(1)).max(1);
    points.into_iter().step_by(step).collect()
}

/// The whole alignment.
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// `None` when no alignment was found (see `reason`).
    pub building_from_site: Option<Similarity>,
    /// "pairs+lines", "automatic+lines".
    pub method: String,
    pub reason: Option<String>,
    /// Residual of each given point pair under the final transform (m).
    pub pair_residuals_m: Vec<f64>,
    pub refined: Option<Refined>,
    /// Of (x, y, yaw) of `building_from_site`, from the fit it came from: the lines'; with
    /// clicks, theirs and the lines' combined, or theirs alone where the walls fit poorly.
    /// `None` when not aligned.
    pub covariance: Option<Matrix3<f64>>,
}

impl Alignment {
    /// σ of x, y (m) and yaw (rad) of the alignment.
    pub fn sigma(&self) -> Option<(f64, f64, f64)> {
        self.covariance.map(|c| {
            (
                c[(0, 0)].max(0.0).sqrt(),
                c[(1, 1)].max(0.0).sqrt(),
                c[(2, 2)].max(0.0).sqrt(),
            )
        })
    }

    /// σ of x and y (m) of where the site point `p_site` lands in the building; (0, 0)
    /// when not aligned.
    pub fn sigma_at(&self, p_site: &Point2<f64>) -> (f64, f64) {
        match (&self.building_from_site, &self.covariance) {
            (Some(t), Some(c)) => sigma_at(t, c, p_site),
            _ => (0.0, 0.0),
        }
    }
}

/// Aligns the site to the drawing: from `pairs` when given (then refined on the lines),
/// else automatically.
pub fn align(
    drawing: &Drawing,
    sensors: &[AlignSensor<'_>],
    pairs: &[PointPair],
    similarity: bool,
    p: &RegisterParams,
) -> Alignment {
    let index = LineIndex::new(drawing);
    // Each wall point with the sensor it came from, thinned alike.
    let owned: Vec<(MapPoint, usize)> = thin(
        sensors
            .iter()
            .enumerate()
            .flat_map(|(k, s)| {
                map_points(s.model, &s.site_from_sensor)
                    .into_iter()
                    .map(move |m| (m, k))
            })
            .collect(),
        20_000,
    );
    let map: Vec<MapPoint> = owned.iter().map(|(m, _)| *m).collect();
    let first = if pairs.is_empty() {
        automatically(drawing, &index, &map, sensors, p)
    } else {
        from_pairs(&map, &index, pairs, similarity)
    };
    // A sensor whose walls do not fit the drawing where the others put it (surveyed or
    // dragged to the wrong place, knocked and not yet noticed) would pull the line fit: it
    // is left out and named, and the lines fitted again without it.
    let Some(t) = first.building_from_site.filter(|_| first.refined.is_some()) else {
        return first;
    };
    let misfits = misfits(&owned, &index, &t, sensors.len());
    if misfits.is_empty() {
        return first;
    }
    let kept: Vec<MapPoint> = owned
        .iter()
        .filter(|(_, k)| !misfits.iter().any(|(m, _)| m == k))
        .map(|(m, _)| *m)
        .collect();
    let mut again = if pairs.is_empty() {
        let refined = refine(&kept, &index, &t, 0.2);
        Alignment {
            building_from_site: Some(refined.transform),
            covariance: Some(refined.covariance),
            refined: Some(refined),
            ..first.clone()
        }
    } else {
        from_pairs(&kept, &index, pairs, similarity)
    };
    let named: Vec<String> = misfits
        .iter()
        .map(|(k, share)| format!("{} ({:.0} % of its walls)", sensors[*k].id, share * 100.0))
        .collect();
    let note = format!(
        "left out of the line fit: {} within 5 cm of the drawing's lines where the site puts it, against most of the others': placed wrong (a survey, a drag, a knock), or seeing what the drawing leaves out",
        named.join(", ")
    );
    again.reason = Some(match again.reason.take() {
        Some(r) => format!("{r}; {note}"),
        None => note,
    });
    again
}

/// A sensor fits the drawing poorly when this share of its wall points or fewer lie within
/// 5 cm of a drawing line, against the median sensor's.
const MISFIT_SHARE: f64 = 0.4;

/// The sensors (index, share within 5 cm) whose walls fit the drawing under `t` at most
/// `MISFIT_SHARE` as well as the median sensor's do; none unless two others fit.
fn misfits(
    owned: &[(MapPoint, usize)],
    index: &LineIndex<'_>,
    t: &Similarity,
    sensors: usize,
) -> Vec<(usize, f64)> {
    let r = Rotation2::new(t.yaw_rad);
    let mut hit = vec![(0usize, 0usize); sensors];
    for (m, k) in owned {
        hit[*k].1 += 1;
        if index.nearest(&t.apply(&m.p), &(r * m.n), 0.05).is_some() {
            hit[*k].0 += 1;
        }
    }
    let shares: Vec<(usize, f64)> = hit
        .iter()
        .enumerate()
        .filter(|(_, h)| h.1 >= MIN_LINE_POINTS)
        .map(|(k, h)| (k, h.0 as f64 / h.1 as f64))
        .collect();
    let mut sorted: Vec<f64> = shares.iter().map(|s| s.1).collect();
    sorted.sort_by(f64::total_cmp);
    let Some(&median) = sorted.get(sorted.len() / 2) else {
        return Vec::new();
    };
    let poor: Vec<(usize, f64)> = shares
        .into_iter()
        .filter(|s| s.1 <= MISFIT_SHARE * median)
        .collect();
    if sorted.len() - poor.len() < 2 {
        return Vec::new();
    }
    poor
}

/// The automatic alignment, refined on every wall point (not the thinned set the search
/// used).
fn automatically(
    drawing: &Drawing,
    index: &LineIndex<'_>,
    map: &[MapPoint],
    sensors: &[AlignSensor<'_>],
    p: &RegisterParams,
) -> Alignment {
    let dmodel = drawing_model(drawing, p);
    let auto = automatic(&dmodel, index, sensors, p);
    let best = auto.candidates.first().cloned();
    match (auto.verdict, best) {
        (Ok(()), Some(best)) => {
            let refined = refine(map, index, &best.refined.transform, 0.2);
            Alignment {
                building_from_site: Some(refined.transform),
                method: "automatic+lines".into(),
                reason: None,
                pair_residuals_m: Vec::new(),
                covariance: Some(refined.covariance),
                refined: Some(refined),
            }
        }
        (verdict, _) => Alignment {
            building_from_site: None,
            method: "automatic".into(),
            reason: Some(verdict.err().unwrap_or_else(|| "no candidate".into())),
            pair_residuals_m: Vec::new(),
            refined: None,
            covariance: None,
        },
    }
}

/// Aligns from clicked `pairs`, refined on the lines: the clicks' fit and the lines' fit
/// from it, each with its covariance, combined. Where the walls seen pin the alignment, the
/// lines decide; where they do not (one or two walls seen, perhaps one moved since the
/// drawing, with nothing to check it by), the clicks keep their say.
fn from_pairs(
    map: &[MapPoint],
    index: &LineIndex<'_>,
    pairs: &[PointPair],
    similarity: bool,
) -> Alignment {
    let fit = match fit_pairs(pairs, similarity) {
        Ok(fit) => fit,
        Err(e) => {
            return Alignment {
                building_from_site: None,
                method: "pairs".into(),
                reason: Some(e.to_string()),
                pair_residuals_m: Vec::new(),
                refined: None,
                covariance: None,
            };
        }
    };
    let refined = refine(map, index, &fit.transform, 0.5);
    let (t, covariance, method, reason) = if refined.inlier_share <= 0.2 {
        let why = format!(
            "the walls fit the drawing's lines poorly near the pairs' alignment ({:.0} % within 5 cm); kept the pairs' fit",
            refined.inlier_share * 100.0
        );
        (fit.transform, fit.covariance, "pairs", Some(why))
    } else {
        let (t, c) = combine(
            (&fit.transform, &fit.covariance),
            (&refined.transform, &refined.covariance),
        );
        let (lines_m, lines_yaw) = pose_sigmas(&refined.covariance);
        let (clicks_m, clicks_yaw) = pose_sigmas(&fit.covariance);
        let weak = lines_m > clicks_m || lines_yaw > clicks_yaw;
        let why = weak.then(|| {
            format!(
                "the walls seen ({} of the drawing's lines fitted) pin the alignment less well than the clicks: it leans on the clicks; give a third pair, or place a sensor that sees more walls",
                refined.fitted_lines
            )
        });
        (t, c, "pairs+lines", why)
    };
    Alignment {
        building_from_site: Some(t),
        method: method.into(),
        reason,
        pair_residuals_m: pairs.iter().map(|(s, d)| (t.apply(s) - d).norm()).collect(),
        refined: Some(refined),
        covariance: Some(covariance),
    }
}

/// Two independent estimates of one transform (x, y, yaw), each with its covariance, combined
/// by their information (the scale is the second's).
fn combine(
    a: (&Similarity, &Matrix3<f64>),
    b: (&Similarity, &Matrix3<f64>),
) -> (Similarity, Matrix3<f64>) {
    let (Some(ia), Some(ib)) = (a.1.try_inverse(), b.1.try_inverse()) else {
        return (*b.0, *b.1);
    };
    let va = Vector3::new(a.0.x_m, a.0.y_m, a.0.yaw_rad);
    // b's yaw taken next to a's.
    let vb = Vector3::new(
        b.0.x_m,
        b.0.y_m,
        a.0.yaw_rad + angle_diff(b.0.yaw_rad, a.0.yaw_rad),
    );
    let Some(c) = (ia + ib).try_inverse() else {
        return (*b.0, *b.1);
    };
    let v = c * (ia * va + ib * vb);
    (
        Similarity {
            x_m: v.x,
            y_m: v.y,
            yaw_rad: v.z,
            scale: b.0.scale,
        },
        c,
    )
}

/// Angle difference wrapped to (−π, π].
pub fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(2.0 * PI);
    if d > PI { d - 2.0 * PI } else { d }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Line = ((f64, f64), (f64, f64));

    fn drawing(segs: &[Line]) -> Drawing {
        let segments: Vec<WallSegment> = segs
            .iter()
            .map(|&((ax, ay), (bx, by))| WallSegment {
                a: Point2::new(ax, ay),
                b: Point2::new(bx, by),
                layer: "A-WALL".into(),
            })
            .collect();
        let mut lo = Point2::new(f64::INFINITY, f64::INFINITY);
        let mut hi = -lo;
        for s in &segments {
            lo = lo.inf(&s.a).inf(&s.b);
            hi = hi.sup(&s.a).sup(&s.b);
        }
        Drawing {
            source: "t".into(),
            segments,
            units: "m".into(),
            bounds: (lo, hi),
            layers: vec!["A-WALL".into()],
        }
    }

    /// Wall points every 2 cm along `segs` (building frame), seen in the site frame through
    /// `building_from_site`, with normals.
    fn map_of(segs: &[Line], t: &Similarity) -> Vec<MapPoint> {
        let inv = t.pose().inverse();
        let mut out = Vec::new();
        for &((ax, ay), (bx, by)) in segs {
            let (a, b) = (Point2::new(ax, ay), Point2::new(bx, by));
            let u = (b - a).normalize();
            let n = Vector2::new(-u.y, u.x);
            let steps = ((b - a).norm() / 0.02) as usize;
            for i in 0..=steps {
                let p = a + (b - a) * (i as f64 / steps as f64);
                out.push(MapPoint {
                    p: inv * p,
                    n: inv.rotation * n,
                });
            }
        }
        out
    }

    #[test]
    fn pairs_fit_rigid_and_similarity_with_residuals() {
        let t = Similarity {
            x_m: 10.0,
            y_m: -4.0,
            yaw_rad: 0.4,
            scale: 1.0,
        };
        let site = [
            Point2::new(0.0, 0.0),
            Point2::new(5.0, 1.0),
            Point2::new(2.0, 7.0),
        ];
        let pairs: Vec<_> = site.iter().map(|p| (*p, t.apply(p))).collect();
        let fit = fit_pairs(&pairs, false).unwrap();
        assert!(
            (fit.transform.x_m - 10.0).abs() < 1e-9 && (fit.transform.yaw_rad - 0.4).abs() < 1e-9
        );
        assert!(fit.residuals_m.iter().all(|r| *r < 1e-9));
        // A drawing at 1:2 needs the similarity; the rigid fit shows it in the residuals.
        let scaled: Vec<_> = pairs
            .iter()
            .map(|(s, d)| (*s, Point2::from(d.coords * 2.0)))
            .collect();
        let sim = fit_pairs(&scaled, true).unwrap();
        assert!((sim.transform.scale - 2.0).abs() < 1e-9, "{sim:?}");
        assert!(
            fit_pairs(&scaled, false)
                .unwrap()
                .residuals_m
                .iter()
                .any(|r| *r > 1.0)
        );
        // One pair off by 20 cm shows in its residual.
        let mut off = pairs.clone();
        off[1].1.x += 0.2;
        let fit = fit_pairs(&off, false).unwrap();
        assert!(fit.residuals_m[1] > 0.1, "{fit:?}");
        assert_eq!(
            fit_pairs(&pairs[..1], false),
            Err(AlignError::TooFewPairs(1))
        );
        assert_eq!(
            fit_pairs(&[(site[0], site[0]), (site[0], site[1])], false),
            Err(AlignError::CoincidentPairs)
        );
    }

    #[test]
    fn pairs_parse_and_bad_text_is_named() {
        let p = parse_pairs("0,0=1.5,2; 3,-1=4,5").unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[1].0, Point2::new(3.0, -1.0));
        assert!(
            parse_pairs("0,0=1")
                .unwrap_err()
                .to_string()
                .contains("0,0=1")
        );
        assert!(parse_pairs("a,b=1,2").is_err());
    }

    #[test]
    fn sigma_counts_each_wall_once_and_an_unpinned_slide_shows() {
        // A 20 × 10 room whose walls stand up to 3 cm off their drawn lines (wall faces vs
        // drawing), with an inner partition: thousands of points, but only five lines.
        let drawn = [
            ((0.0, 0.0), (20.0, 0.0)),
            ((20.0, 0.0), (20.0, 10.0)),
            ((20.0, 10.0), (0.0, 10.0)),
            ((0.0, 10.0), (0.0, 0.0)),
            ((8.0, 0.0), (8.0, 6.0)),
        ];
        let offsets = [0.03, -0.02, 0.01, 0.025, -0.03];
        let seen: Vec<Line> = drawn
            .iter()
            .zip(offsets)
            .map(|(&((ax, ay), (bx, by)), o)| {
                let (dx, dy) = (bx - ax, by - ay);
                let l = f64::hypot(dx, dy);
                let (nx, ny) = (-dy / l * o, dx / l * o);
                ((ax + nx, ay + ny), (bx + nx, by + ny))
            })
            .collect();
        let truth = Similarity {
            x_m: 5.0,
            y_m: 2.0,
            yaw_rad: 0.2,
            scale: 1.0,
        };
        let d = drawing(&drawn);
        let index = LineIndex::new(&d);
        let r = refine(&map_of(&seen, &truth), &index, &truth, 0.5);
        let (sx, sy, syaw) = r.sigma;
        // Points alone would claim well under a millimetre; the lines' spread says centimetres.
        assert!(
            sx > 0.008 && sy > 0.008 && sx < 0.1 && sy < 0.1,
            "{:?}",
            r.sigma
        );
        assert!(
            syaw > 0.01f64.to_radians() && syaw < 1f64.to_radians(),
            "{syaw}"
        );
        // The error made is within 3 σ.
        let (dt, dr) = pose_error(&r.transform.pose(), &truth.pose());
        assert!(
            dt < 3.0 * sx.hypot(sy) && dr < 3.0 * syaw,
            "{dt} {dr} {:?}",
            r.sigma
        );
        // σ at a site point 20 m away grows with the lever arm of the turn.
        let (fx, fy) = r.sigma_at(&Point2::new(20.0, 20.0));
        assert!(fx.hypot(fy) > sx.hypot(sy), "{fx} {fy}");

        // A corridor of parallel walls pins the across and the turn, not the along.
        let corridor = [
            ((0.0, 0.0), (30.0, 0.0)),
            ((0.0, 1.5), (30.0, 1.5)),
            ((0.0, 3.0), (30.0, 3.0)),
        ];
        let d = drawing(&corridor);
        let index = LineIndex::new(&d);
        let c = refine(&map_of(&corridor, &truth), &index, &truth, 0.5);
        assert!(c.sigma.0.max(c.sigma.1) > 10.0, "{:?}", c.sigma);
    }

    #[test]
    fn a_wall_no_other_checks_counts_as_known_to_a_click_only() {
        // A corridor's two long walls check each other across it; its one end wall is all
        // that fixes the along, and would not show as moved if it were.
        let mut walls = vec![
            ((0.0, 0.0), (20.0, 0.0)),
            ((20.0, 4.0), (0.0, 4.0)),
            ((0.0, 4.0), (0.0, 0.0)),
        ];
        let truth = Similarity {
            x_m: 3.0,
            y_m: -1.0,
            yaw_rad: 0.3,
            scale: 1.0,
        };
        let along = |walls: &[Line]| {
            let d = drawing(walls);
            let r = refine(&map_of(walls, &truth), &LineIndex::new(&d), &truth, 0.5);
            // σ in the building's axes: x along the corridor, y across.
            (r.sigma_at(&Point2::new(0.0, 0.0)), r.fitted_lines)
        };
        let ((ax, ay), lines) = along(&walls);
        assert_eq!(lines, 3);
        assert!(ax > 0.05 && ay < 0.02, "σ {ax:.3} {ay:.3}");
        // A second end wall checks the first: both are known to the lines' spread again.
        walls.push(((20.0, 0.0), (20.0, 4.0)));
        let ((bx, by), _) = along(&walls);
        assert!(bx < 0.02 && by < 0.02, "σ {bx:.3} {by:.3}");
    }

    #[test]
    fn a_sensor_whose_walls_miss_the_drawing_where_the_others_fit_is_named() {
        let room: [Line; 5] = [
            ((0.0, 0.0), (20.0, 0.0)),
            ((20.0, 0.0), (20.0, 10.0)),
            ((20.0, 10.0), (0.0, 10.0)),
            ((0.0, 10.0), (0.0, 0.0)),
            ((8.0, 0.0), (8.0, 6.0)),
        ];
        let truth = Similarity {
            x_m: 1.0,
            y_m: 2.0,
            yaw_rad: 0.4,
            scale: 1.0,
        };
        let d = drawing(&room);
        let index = LineIndex::new(&d);
        // Sensors 0 and 1 see the room where it is; sensor 2 was dragged 2.5 m off, so its
        // walls land in the site 2.5 m from where they stand.
        let dragged = Similarity {
            x_m: truth.x_m + 2.0,
            y_m: truth.y_m - 1.5,
            ..truth
        };
        let mut owned: Vec<(MapPoint, usize)> = Vec::new();
        for (k, (walls, t)) in [
            (&room[..2], &truth),
            (&room[2..4], &truth),
            (&room[3..], &dragged),
        ]
        .into_iter()
        .enumerate()
        {
            owned.extend(map_of(walls, t).into_iter().map(|m| (m, k)));
        }
        let poor = misfits(&owned, &index, &truth, 3);
        assert_eq!(
            poor.iter().map(|p| p.0).collect::<Vec<_>>(),
            [2],
            "{poor:?}"
        );
        // Without two others that fit, nobody is blamed.
        let two: Vec<(MapPoint, usize)> = owned.iter().filter(|(_, k)| *k != 1).cloned().collect();
        assert!(misfits(&two, &index, &truth, 3).is_empty());
    }

    #[test]
    fn clicks_keep_their_say_where_the_one_wall_seen_would_carry_them_onto_a_moved_line() {
        let room = [
            ((0.0, 0.0), (20.0, 0.0)),
            ((20.0, 0.0), (20.0, 10.0)),
            ((20.0, 10.0), (0.0, 10.0)),
            ((0.0, 10.0), (0.0, 0.0)),
        ];
        let truth = Similarity {
            x_m: 5.0,
            y_m: 2.0,
            yaw_rad: -0.7,
            scale: 1.0,
        };
        // The sensors see only the south wall, which stands 20 cm north of its drawn line.
        let seen = [((2.0, 0.2), (18.0, 0.2))];
        let d = drawing(&room);
        let index = LineIndex::new(&d);
        let site = |p: (f64, f64)| truth.to_site(&Point2::new(p.0, p.1));
        let pairs = [
            (site((0.0, 0.0)), Point2::new(0.0, 0.0)),
            (site((20.0, 10.0)), Point2::new(20.0, 10.0)),
        ];
        let a = from_pairs(&map_of(&seen, &truth), &index, &pairs, false);
        let t = a.building_from_site.expect("aligned");
        let (dt, dr) = pose_error(&t.pose(), &truth.pose());
        assert!(dt < 0.01 && dr < 0.001, "{dt} m {dr} rad off: {a:?}");
        assert!(
            a.reason
                .as_deref()
                .is_some_and(|r| r.contains("third pair")),
            "{a:?}"
        );
        // Its σ is the clicks' (each good to 10 cm), not a line fit's centimetre.
        let (sx, sy, _) = a.sigma().expect("σ");
        assert!(sx.min(sy) > 0.04 && sx.max(sy) < 0.2, "σ {sx:.3} {sy:.3}");
        // With the whole room seen, the lines decide: a click 15 cm off is corrected.
        let mut rough = pairs;
        rough[0].1.x += 0.15;
        let a = from_pairs(&map_of(&room, &truth), &index, &rough, false);
        let (dt, _) = pose_error(
            &a.building_from_site.expect("aligned").pose(),
            &truth.pose(),
        );
        assert!(dt < 0.01 && a.reason.is_none(), "{dt} m off: {a:?}");
    }

    #[test]
    fn refinement_recovers_the_alignment_and_names_the_moved_wall() {
        // A 12 × 8 room with an inner partition; the map sees the partition 20 cm east.
        let drawn = [
            ((0.0, 0.0), (12.0, 0.0)),
            ((12.0, 0.0), (12.0, 8.0)),
            ((12.0, 8.0), (0.0, 8.0)),
            ((0.0, 8.0), (0.0, 0.0)),
            ((6.0, 0.0), (6.0, 5.0)),
        ];
        let mut seen = drawn;
        seen[4] = ((6.2, 0.0), (6.2, 5.0));
        let truth = Similarity {
            x_m: 3.0,
            y_m: 1.0,
            yaw_rad: 0.3,
            scale: 1.0,
        };
        let d = drawing(&drawn);
        let index = LineIndex::new(&d);
        let map = map_of(&seen, &truth);
        // Start 15 cm and 1° off, as two clicked points would leave it.
        let init = Similarity {
            x_m: 3.12,
            y_m: 0.9,
            yaw_rad: 0.3 + 1f64.to_radians(),
            scale: 1.0,
        };
        let r = refine(&map, &index, &init, 0.5);
        let (dt, dr) = pose_error(&r.transform.pose(), &truth.pose());
        assert!(
            dt < 0.01 && dr < 0.05f64.to_radians(),
            "{dt} {dr} {:?}",
            r.transform
        );
        let moved: Vec<_> = r.lines.iter().filter(|l| l.moved).collect();
        assert_eq!(moved.len(), 1, "{:?}", r.lines);
        assert_eq!(moved[0].a, Point2::new(6.0, 0.0));
        assert!(
            (moved[0].offset_m.abs() - 0.2).abs() < 0.01,
            "{:?}",
            moved[0]
        );
        assert!(
            r.lines
                .iter()
                .filter(|l| !l.moved)
                .all(|l| l.offset_m.abs() < 0.01)
        );
    }
}
