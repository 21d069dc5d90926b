//! DXF → wall segments. The `dxf` crate reads the file; here LINE, LWPOLYLINE, POLYLINE
//! (with bulges), ARC and CIRCLE (as chords of at most 10°) and INSERT of blocks become
//! segments. Inserts are honoured as AutoCAD draws them: nested, rotated, unevenly scaled,
//! arrayed, with the block's base point; an entity of a block on layer `0` takes the layer of
//! the INSERT that places it. Model space only. `$INSUNITS` gives metres; unitless needs a
//! scale from the user.

use super::{DrawingError, Raw, ReadOptions, WallSegment, arc_points, check_scale};
use dxf::entities::{Entity, EntityType};
use dxf::enums::{AcadVersion, Units};
use nalgebra::{Matrix3, Point2, Vector2};
use std::collections::HashMap;
use std::io::Cursor;

/// Blocks nested deeper than this are refused (a block that inserts itself would never end).
const MAX_DEPTH: usize = 16;
/// An arrayed INSERT of more copies than this is refused.
const MAX_ARRAY: usize = 10_000;
/// Entities visited through inserts, at most: nested arrays of empty blocks emit no segment,
/// yet could take forever.
const MAX_VISITS: usize = 2_000_000;

/// Metres per drawing unit of `$INSUNITS`, or `None` when unitless.
pub fn metres_per_unit(units: Units) -> Option<(f64, &'static str)> {
    Some(match units {
        Units::Unitless => return None,
        Units::Inches => (0.0254, "in"),
        Units::Feet => (0.3048, "ft"),
        Units::Miles => (1609.344, "mi"),
        Units::Millimeters => (0.001, "mm"),
        Units::Centimeters => (0.01, "cm"),
        Units::Meters => (1.0, "m"),
        Units::Kilometers => (1000.0, "km"),
        Units::Microinches => (0.0254e-6, "µin"),
        Units::Mils => (0.0254e-3, "mil"),
        Units::Yards => (0.9144, "yd"),
        Units::Angstroms => (1e-10, "Å"),
        Units::Nanometers => (1e-9, "nm"),
        Units::Microns => (1e-6, "µm"),
        Units::Decimeters => (0.1, "dm"),
        Units::Decameters => (10.0, "dam"),
        Units::Hectometers => (100.0, "hm"),
        Units::Gigameters => (1e9, "Gm"),
        Units::AstronomicalUnits => (1.495_978_707e11, "au"),
        Units::LightYears => (9.460_730_472_580_8e15, "ly"),
        Units::Parsecs => (3.085_677_581e16, "pc"),
        Units::USSurveyFeet => (1200.0 / 3937.0, "US survey ft"),
        Units::USSurveyInch => (100.0 / 3937.0, "US survey in"),
        Units::USSurveyYard => (3600.0 / 3937.0, "US survey yd"),
        Units::USSurveyMile => (6_336_000.0 / 3937.0, "US survey mi"),
    })
}

pub(crate) fn segments(file: &str, data: &[u8], opts: &ReadOptions) -> Result<Raw, DrawingError> {
    let err = |message: String| DrawingError::Dxf {
        file: file.to_string(),
        message,
    };
    if data.starts_with(b"AC10") {
        return Err(err("this is a DWG file; export it as DXF".into()));
    }
    let drawing = dxf::Drawing::load(&mut Cursor::new(data)).map_err(|e| err(e.to_string()))?;
    if drawing.header.version < AcadVersion::R12 {
        return Err(err(format!(
            "version {:?} is older than R12, which is not supported; save it as R12 or newer",
            drawing.header.version
        )));
    }
    let (scale, units) = match (
        opts.scale_m_per_unit,
        metres_per_unit(drawing.header.default_drawing_units),
    ) {
        (Some(s), _) => (check_scale(file, s)?, format!("{s} m per unit (given)")),
        (None, Some((s, name))) => (s, name.to_string()),
        (None, None) => {
            return Err(DrawingError::Units {
                file: file.to_string(),
                message: "$INSUNITS is unset (unitless); give the scale in metres per drawing unit (--scale)".into(),
            });
        }
    };
    let blocks: HashMap<String, &dxf::Block> = drawing
        .blocks()
        .map(|b| (b.name.to_ascii_uppercase(), b))
        .collect();
    // Refuse what would expand past the budget before walking it (nested arrays of blocks
    // multiply; the walk's own count is a second guard).
    let mut memo = HashMap::new();
    let expanded = drawing
        .entities()
        .filter(|e| !e.common.is_in_paper_space)
        .fold(0u64, |sum, e| {
            sum.saturating_add(expansion(e, &blocks, &mut memo, 0))
        });
    if expanded > MAX_VISITS as u64 {
        return Err(DrawingError::Dxf {
            file: file.to_string(),
            message: format!(
                "its blocks expand to over {MAX_VISITS} entities (nested arrays?); not a floor plan"
            ),
        });
    }
    let mut w = Walker {
        visits: 0,
        blocks: &blocks,
        out: Vec::new(),
        layers: Vec::new(),
        file,
    };
    let root = Matrix3::new_scaling(scale);
    for e in drawing.entities() {
        if e.common.is_in_paper_space {
            continue;
        }
        w.entity(e, &root, None, 0)?;
    }
    for (_, b) in blocks.iter() {
        w.layers.push(b.layer.clone());
    }
    Ok(Raw {
        segments: w.out,
        layers: w.layers,
        units,
    })
}

/// How many entities `e` stands for once its inserts are expanded (saturating). Blocks
/// nested too deep count as nothing here: the walk reports them.
fn expansion(
    e: &Entity,
    blocks: &HashMap<String, &dxf::Block>,
    memo: &mut HashMap<String, u64>,
    depth: usize,
) -> u64 {
    let EntityType::Insert(ins) = &e.specific else {
        return 1;
    };
    if depth >= MAX_DEPTH {
        return 1;
    }
    let key = ins.name.to_ascii_uppercase();
    let inner = match memo.get(&key) {
        Some(&n) => n,
        None => {
            let n = blocks.get(&key).map_or(0, |b| {
                b.entities.iter().fold(0u64, |sum, be| {
                    sum.saturating_add(expansion(be, blocks, memo, depth + 1))
                })
            });
            memo.insert(key, n);
            n
        }
    };
    let copies = (ins.column_count.max(1) as u64).saturating_mul(ins.row_count.max(1) as u64);
    copies.saturating_mul(inner.max(1)).saturating_add(1)
}

struct Walker<'a> {
    visits: usize,
    blocks: &'a HashMap<String, &'a dxf::Block>,
    out: Vec<WallSegment>,
    layers: Vec<String>,
    file: &'a str,
}

fn apply(m: &Matrix3<f64>, x: f64, y: f64) -> Point2<f64> {
    let v = m * nalgebra::Vector3::new(x, y, 1.0);
    Point2::new(v.x, v.y)
}

/// The object coordinate system of a planar entity seen from +z: an extrusion of (0, 0, −1)
/// (a mirrored entity, common in exports) flips x; other tilted extrusions are not on the
/// floor plan and are skipped.
fn ocs(normal: &dxf::Vector) -> Option<Matrix3<f64>> {
    if normal.x.abs() > 1e-6 || normal.y.abs() > 1e-6 {
        return None;
    }
    if normal.z < 0.0 {
        Some(Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
    } else {
        Some(Matrix3::identity())
    }
}

/// Polyline vertices (x, y, bulge) to points, arcs for bulges.
fn polyline_points(v: &[(f64, f64, f64)], closed: bool) -> Vec<Point2<f64>> {
    let n = v.len();
    let mut pts = Vec::with_capacity(n);
    let count = if closed { n } else { n.saturating_sub(1) };
    if let Some(first) = v.first() {
        pts.push(Point2::new(first.0, first.1));
    }
    for i in 0..count {
        let (x0, y0, bulge) = v[i];
        let (x1, y1, _) = v[(i + 1) % n];
        let p0 = Point2::new(x0, y0);
        let p1 = Point2::new(x1, y1);
        if bulge.abs() > 1e-9 && bulge.is_finite() && (p1 - p0).norm() > 1e-12 {
            // bulge = tan(θ/4), θ the included angle, positive counter-clockwise.
            let theta = 4.0 * bulge.atan();
            let chord = p1 - p0;
            let c = chord.norm();
            let r = c / (2.0 * (theta / 2.0).sin());
            let mid = nalgebra::center(&p0, &p1);
            let h = r * (theta / 2.0).cos();
            let perp = Vector2::new(-chord.y, chord.x) / c;
            let centre = mid + perp * h;
            let start = (p0 - centre).y.atan2((p0 - centre).x);
            let arc = arc_points(centre, r.abs(), start, theta);
            pts.extend(arc.into_iter().skip(1));
        } else {
            pts.push(p1);
        }
    }
    pts
}

impl Walker<'_> {
    /// Counts one entity or block copy visited; too many is an error.
    fn tick(&mut self) -> Result<(), DrawingError> {
        self.visits += 1;
        if self.visits > MAX_VISITS {
            return Err(DrawingError::Dxf {
                file: self.file.to_string(),
                message: format!(
                    "its blocks expand to over {MAX_VISITS} entities (nested arrays?); not a floor plan"
                ),
            });
        }
        Ok(())
    }

    fn chain(
        &mut self,
        pts: &[Point2<f64>],
        m: &Matrix3<f64>,
        layer: &str,
    ) -> Result<(), DrawingError> {
        if self.out.len() + pts.len() > super::MAX_SEGMENTS {
            return Err(DrawingError::TooManySegments {
                file: self.file.to_string(),
                limit: super::MAX_SEGMENTS,
            });
        }
        for w in pts.windows(2) {
            self.out.push(WallSegment {
                a: apply(m, w[0].x, w[0].y),
                b: apply(m, w[1].x, w[1].y),
                layer: layer.to_string(),
            });
        }
        Ok(())
    }

    fn entity(
        &mut self,
        e: &Entity,
        m: &Matrix3<f64>,
        insert_layer: Option<&str>,
        depth: usize,
    ) -> Result<(), DrawingError> {
        self.tick()?;
        let own = e.common.layer.as_str();
        let layer = match insert_layer {
            Some(l) if own == "0" || own.is_empty() => l.to_string(),
            _ => own.to_string(),
        };
        if !self.layers.contains(&layer) {
            self.layers.push(layer.clone());
        }
        match &e.specific {
            EntityType::Line(l) => {
                let pts = [Point2::new(l.p1.x, l.p1.y), Point2::new(l.p2.x, l.p2.y)];
                self.chain(&pts, m, &layer)?;
            }
            EntityType::LwPolyline(p) => {
                let Some(o) = ocs(&p.extrusion_direction) else {
                    return Ok(());
                };
                let v: Vec<(f64, f64, f64)> =
                    p.vertices.iter().map(|v| (v.x, v.y, v.bulge)).collect();
                let pts = polyline_points(&v, p.is_closed());
                self.chain(&pts, &(m * o), &layer)?;
            }
            EntityType::Polyline(p) => {
                if p.is_polyface_mesh() || p.is_3d_polygon_mesh() {
                    return Ok(());
                }
                let o = if p.is_3d_polyline() {
                    Matrix3::identity()
                } else {
                    match ocs(&p.normal) {
                        Some(o) => o,
                        None => return Ok(()),
                    }
                };
                let v: Vec<(f64, f64, f64)> = p
                    .vertices()
                    .map(|v| (v.location.x, v.location.y, v.bulge))
                    .collect();
                let pts = polyline_points(&v, p.is_closed());
                self.chain(&pts, &(m * o), &layer)?;
            }
            EntityType::Arc(a) => {
                let Some(o) = ocs(&a.normal) else {
                    return Ok(());
                };
                let start = a.start_angle.to_radians();
                let mut sweep = (a.end_angle - a.start_angle).rem_euclid(360.0).to_radians();
                if sweep < 1e-9 {
                    sweep = std::f64::consts::TAU;
                }
                let c = Point2::new(a.center.x, a.center.y);
                let pts = arc_points(c, a.radius.abs(), start, sweep);
                self.chain(&pts, &(m * o), &layer)?;
            }
            EntityType::Circle(c) => {
                let Some(o) = ocs(&c.normal) else {
                    return Ok(());
                };
                let centre = Point2::new(c.center.x, c.center.y);
                let pts = arc_points(centre, c.radius.abs(), 0.0, std::f64::consts::TAU);
                self.chain(&pts, &(m * o), &layer)?;
            }
            EntityType::Insert(ins) => {
                if depth >= MAX_DEPTH {
                    return Err(DrawingError::Dxf {
                        file: self.file.to_string(),
                        message: format!(
                            "block {:?} nests deeper than {MAX_DEPTH} levels (does it insert itself?)",
                            ins.name
                        ),
                    });
                }
                let Some(block) = self.blocks.get(&ins.name.to_ascii_uppercase()).copied() else {
                    // A missing block draws nothing, as in AutoCAD; not fatal.
                    return Ok(());
                };
                let Some(o) = ocs(&ins.extrusion_direction) else {
                    return Ok(());
                };
                let cols = ins.column_count.max(1) as usize;
                let rows = ins.row_count.max(1) as usize;
                if cols.saturating_mul(rows) > MAX_ARRAY {
                    return Err(DrawingError::Dxf {
                        file: self.file.to_string(),
                        message: format!("INSERT of {:?} arrays {cols}×{rows} copies", ins.name),
                    });
                }
                let rot = ins.rotation.to_radians();
                let (s, c) = rot.sin_cos();
                let r = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
                let scale = Matrix3::new(
                    ins.x_scale_factor,
                    0.0,
                    0.0,
                    0.0,
                    ins.y_scale_factor,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                );
                let base = Matrix3::new_translation(&Vector2::new(
                    -block.base_point.x,
                    -block.base_point.y,
                ));
                for row in 0..rows {
                    for col in 0..cols {
                        self.tick()?;
                        // Array offsets run along the insert's rotated axes, unscaled.
                        let off = Vector2::new(
                            col as f64 * ins.column_spacing,
                            row as f64 * ins.row_spacing,
                        );
                        let at =
                            Matrix3::new_translation(&Vector2::new(ins.location.x, ins.location.y));
                        let shift = Matrix3::new_translation(&off);
                        let child = m * o * at * r * shift * scale * base;
                        for be in &block.entities {
                            self.entity(be, &child, Some(&layer), depth + 1)?;
                        }
                    }
                }
            }
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Format, ReadOptions, parse};
    use dxf::entities::{Entity, EntityType, Insert, Line, LwPolyline};
    use dxf::{Block, LwPolylineVertex, Point};

    fn line(x0: f64, y0: f64, x1: f64, y1: f64, layer: &str) -> Entity {
        let mut e = Entity::new(EntityType::Line(Line::new(
            Point::new(x0, y0, 0.0),
            Point::new(x1, y1, 0.0),
        )));
        e.common.layer = layer.into();
        e
    }

    fn bytes(d: &dxf::Drawing) -> Vec<u8> {
        let mut out = Vec::new();
        d.save(&mut out).unwrap();
        out
    }

    fn base(units: dxf::enums::Units) -> dxf::Drawing {
        let mut d = dxf::Drawing::new();
        d.header.version = dxf::enums::AcadVersion::R2013;
        d.header.default_drawing_units = units;
        d
    }

    #[test]
    fn millimetre_lines_become_metres_and_layers_filter() {
        let mut d = base(dxf::enums::Units::Millimeters);
        d.add_entity(line(0.0, 0.0, 10_000.0, 0.0, "A-WALL"));
        d.add_entity(line(0.0, 500.0, 1000.0, 500.0, "FURNITURE"));
        let opts = ReadOptions {
            layers: Some(vec!["a-wall".into()]),
            ..ReadOptions::default()
        };
        let got = parse("t.dxf", &bytes(&d), Format::Dxf, &opts).unwrap();
        assert_eq!(got.segments.len(), 1);
        assert!((got.segments[0].b.x - 10.0).abs() < 1e-9);
        assert_eq!(got.segments[0].layer, "A-WALL");
        assert!(got.layers.contains(&"FURNITURE".to_string()));
        assert_eq!(got.units, "mm");
    }

    #[test]
    fn unitless_without_a_scale_is_an_error_naming_the_file() {
        let mut d = base(dxf::enums::Units::Unitless);
        d.add_entity(line(0.0, 0.0, 10.0, 0.0, "0"));
        let err = parse("plan.dxf", &bytes(&d), Format::Dxf, &ReadOptions::default()).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("plan.dxf") && msg.contains("INSUNITS"),
            "{msg}"
        );
        let opts = ReadOptions {
            scale_m_per_unit: Some(0.5),
            ..ReadOptions::default()
        };
        let got = parse("plan.dxf", &bytes(&d), Format::Dxf, &opts).unwrap();
        assert!((got.segments[0].b.x - 5.0).abs() < 1e-9);
    }

    #[test]
    fn nested_rotated_unevenly_scaled_inserts_with_base_points_and_layer_zero() {
        let mut d = base(dxf::enums::Units::Meters);
        // Inner block: a unit line on layer 0 from its base point (1, 1) to (2, 1).
        let mut inner = Block {
            name: "INNER".into(),
            base_point: Point::new(1.0, 1.0, 0.0),
            ..Default::default()
        };
        inner.entities.push(line(1.0, 1.0, 2.0, 1.0, "0"));
        // Outer block inserts INNER at (0, 0), rotated 90°, scaled (2, 3).
        let mut outer = Block {
            name: "OUTER".into(),
            ..Default::default()
        };
        let mut ins = Insert {
            name: "INNER".into(),
            rotation: 90.0,
            x_scale_factor: 2.0,
            y_scale_factor: 3.0,
            ..Default::default()
        };
        ins.location = Point::new(0.0, 0.0, 0.0);
        let mut ie = Entity::new(EntityType::Insert(ins));
        ie.common.layer = "0".into();
        outer.entities.push(ie);
        // A line on its own layer inside the block keeps it.
        outer.entities.push(line(0.0, 0.0, 0.0, 1.0, "DOORS"));
        d.add_block(inner);
        d.add_block(outer);
        let mut top = Insert {
            name: "OUTER".into(),
            ..Default::default()
        };
        top.location = Point::new(10.0, 5.0, 0.0);
        let mut te = Entity::new(EntityType::Insert(top));
        te.common.layer = "A-WALL".into();
        d.add_entity(te);
        let got = parse("b.dxf", &bytes(&d), Format::Dxf, &ReadOptions::default()).unwrap();
        let wall: Vec<_> = got
            .segments
            .iter()
            .filter(|s| s.layer == "A-WALL")
            .collect();
        assert_eq!(wall.len(), 1, "{:?}", got.segments);
        // (1,1)→(2,1) less base = (0,0)→(1,0); ×(2,3) = (0,0)→(2,0); rotated 90° = (0,0)→(0,2);
        // at (10, 5): (10,5)→(10,7).
        let s = wall[0];
        assert!(
            (s.a - nalgebra::Point2::new(10.0, 5.0)).norm() < 1e-9,
            "{s:?}"
        );
        assert!(
            (s.b - nalgebra::Point2::new(10.0, 7.0)).norm() < 1e-9,
            "{s:?}"
        );
        assert!(got.segments.iter().any(|s| s.layer == "DOORS"));
    }

    #[test]
    fn closed_lwpolyline_with_a_bulge_is_a_half_circle() {
        let mut d = base(dxf::enums::Units::Meters);
        let mut p = LwPolyline::default();
        p.set_is_closed(true);
        let v = |x: f64, y: f64, bulge: f64| LwPolylineVertex {
            x,
            y,
            bulge,
            ..Default::default()
        };
        // (0,0)→(4,0) straight, (4,0)→(0,0) a half circle (bulge 1) through (2, −2)... closed.
        p.vertices = vec![v(0.0, 0.0, 0.0), v(4.0, 0.0, 1.0)];
        d.add_entity(Entity::new(EntityType::LwPolyline(p)));
        let got = parse("p.dxf", &bytes(&d), Format::Dxf, &ReadOptions::default()).unwrap();
        assert!(got.segments.len() > 10, "{}", got.segments.len());
        let lowest = got
            .segments
            .iter()
            .map(|s| s.a.y.min(s.b.y))
            .fold(f64::INFINITY, f64::min);
        let highest = got
            .segments
            .iter()
            .map(|s| s.a.y.max(s.b.y))
            .fold(f64::NEG_INFINITY, f64::max);
        // Counter-clockwise from (4,0) to (0,0) passes above: y up to 2.
        assert!(
            (highest - 2.0).abs() < 0.05 && lowest.abs() < 1e-9,
            "{lowest} {highest}"
        );
    }

    #[test]
    fn garbage_and_empty_files_are_errors_not_panics() {
        for data in [
            &b""[..],
            b"0\nSECTION\n2\nENTITIES\n0\nENDSEC\n0\nEOF\n",
            b"\xff\xfe garbage",
        ] {
            let r = parse("g.dxf", data, Format::Dxf, &ReadOptions::default());
            let msg = r.unwrap_err().to_string();
            assert!(msg.contains("g.dxf"), "{msg}");
        }
    }

    #[test]
    fn nested_arrays_of_empty_blocks_end_with_an_error_not_a_hang() {
        let mut d = base(dxf::enums::Units::Meters);
        // L0 arrays 100 × 1 copies of L1, … L9 is empty: 100^9 visits unchecked.
        for level in 0..10 {
            let mut b = Block {
                name: format!("L{level}"),
                ..Default::default()
            };
            if level < 9 {
                b.entities.push(Entity::new(EntityType::Insert(Insert {
                    name: format!("L{}", level + 1),
                    column_count: 100,
                    column_spacing: 1.0,
                    ..Default::default()
                })));
            }
            d.add_block(b);
        }
        d.add_entity(line(0.0, 0.0, 10.0, 0.0, "A-WALL"));
        d.add_entity(Entity::new(EntityType::Insert(Insert {
            name: "L0".into(),
            ..Default::default()
        })));
        let err = parse("n.dxf", &bytes(&d), Format::Dxf, &ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("expand"), "{err}");
    }

    #[test]
    fn a_block_that_inserts_itself_is_refused() {
        let mut d = base(dxf::enums::Units::Meters);
        let mut b = Block {
            name: "LOOP".into(),
            ..Default::default()
        };
        b.entities.push(Entity::new(EntityType::Insert(Insert {
            name: "LOOP".into(),
            ..Default::default()
        })));
        d.add_block(b);
        d.add_entity(Entity::new(EntityType::Insert(Insert {
            name: "LOOP".into(),
            ..Default::default()
        })));
        let err = parse("l.dxf", &bytes(&d), Format::Dxf, &ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("deeper"), "{err}");
    }
}
