//! SVG → wall segments. `usvg` parses the file and resolves its shapes (path, line, polyline,
//! polygon, rect, circle…) and transforms into absolute paths; here they are flattened into
//! segments (curves as 8 chords). The layer of a shape is the id of the nearest group around it
//! that has one (`<g id="A-WALL">`, as CAD and Inkscape exports name layers). SVG has no
//! units a building could use, so the user gives metres per SVG unit; y is flipped (SVG runs
//! down the page). A file referring to anything outside itself is refused before parsing.

use super::{DrawingError, Raw, ReadOptions, WallSegment, check_scale};
use nalgebra::Point2;

/// Curves are flattened into this many chords.
const CURVE_CHORDS: usize = 8;

pub(crate) fn segments(file: &str, data: &[u8], opts: &ReadOptions) -> Result<Raw, DrawingError> {
    let Some(scale) = opts.scale_m_per_unit else {
        return Err(DrawingError::Units {
            file: file.to_string(),
            message: "an SVG has no real-world units; give metres per SVG unit (--scale)".into(),
        });
    };
    let scale = check_scale(file, scale)?;
    if data.starts_with(&[0x1f, 0x8b]) {
        return Err(DrawingError::Svg {
            file: file.to_string(),
            message: "compressed SVG (svgz); decompress it first".into(),
        });
    }
    let text = std::str::from_utf8(data).map_err(|_| DrawingError::Svg {
        file: file.to_string(),
        message: "not UTF-8 text".into(),
    })?;
    if let Some(href) = external_reference(text) {
        return Err(DrawingError::ExternalReference {
            file: file.to_string(),
            href,
        });
    }
    let options = usvg::Options {
        resources_dir: None,
        ..usvg::Options::default()
    };
    let tree = usvg::Tree::from_str(text, &options).map_err(|e| DrawingError::Svg {
        file: file.to_string(),
        message: e.to_string(),
    })?;
    let mut out = Raw {
        segments: Vec::new(),
        layers: Vec::new(),
        units: format!("{scale} m per SVG unit"),
    };
    walk(file, tree.root(), "", scale, &mut out)?;
    Ok(out)
}

/// The first reference to anything but the file itself: an `href` or `url(…)` that is not a
/// fragment (`#id`) or inline data, or a CSS `@import`. usvg would try to load such files
/// relative to the working directory; a drawing must not make the daemon read other files.
fn external_reference(text: &str) -> Option<String> {
    let lower = text.to_ascii_lowercase();
    if let Some(at) = lower.find("@import") {
        return Some(text[at..].chars().take(60).collect());
    }
    let local = |v: &str| {
        let v = v.trim().trim_matches(|c| c == '\'' || c == '"').trim();
        v.is_empty() || v.starts_with('#') || v.to_ascii_lowercase().starts_with("data:")
    };
    // href="…" / xlink:href='…'
    let mut from = 0;
    while let Some(k) = lower[from..].find("href") {
        let start = from + k + 4;
        from = start;
        let rest = &text[start..];
        let rest = rest.trim_start();
        let Some(rest) = rest.strip_prefix('=') else {
            continue;
        };
        let rest = rest.trim_start();
        let Some(q) = rest.chars().next().filter(|c| *c == '"' || *c == '\'') else {
            continue;
        };
        let body = &rest[1..];
        let value = body.split(q).next().unwrap_or("");
        if !local(value) {
            return Some(value.to_string());
        }
    }
    // url(…) in attributes and style sheets.
    let mut from = 0;
    while let Some(k) = lower[from..].find("url(") {
        let start = from + k + 4;
        from = start;
        let value = text[start..].split(')').next().unwrap_or("");
        if !local(value) {
            return Some(value.to_string());
        }
    }
    None
}

fn walk(
    file: &str,
    group: &usvg::Group,
    layer: &str,
    scale: f64,
    out: &mut Raw,
) -> Result<(), DrawingError> {
    let layer = if group.id().is_empty() {
        layer.to_string()
    } else {
        group.id().to_string()
    };
    if !out.layers.contains(&layer) {
        out.layers.push(layer.clone());
    }
    for node in group.children() {
        match node {
            usvg::Node::Group(g) => walk(file, g, &layer, scale, out)?,
            usvg::Node::Path(p) => path_segments(file, p, &layer, scale, out)?,
            _ => {}
        }
    }
    Ok(())
}

fn path_segments(
    file: &str,
    path: &usvg::Path,
    layer: &str,
    scale: f64,
    out: &mut Raw,
) -> Result<(), DrawingError> {
    use usvg::tiny_skia_path::PathSegment;
    let t = path.abs_transform();
    let map = |x: f32, y: f32| {
        let mut p = usvg::tiny_skia_path::Point::from_xy(x, y);
        t.map_point(&mut p);
        // y down the page → y up.
        Point2::new(p.x as f64 * scale, -(p.y as f64) * scale)
    };
    let mut pts: Vec<Point2<f64>> = Vec::new();
    let mut start: Option<Point2<f64>> = None;
    let mut last: Option<(f32, f32)> = None;
    let flush = |pts: &mut Vec<Point2<f64>>, out: &mut Raw| -> Result<(), DrawingError> {
        if out.segments.len() + pts.len() > super::MAX_SEGMENTS {
            return Err(DrawingError::TooManySegments {
                file: file.to_string(),
                limit: super::MAX_SEGMENTS,
            });
        }
        for w in pts.windows(2) {
            out.segments.push(WallSegment {
                a: w[0],
                b: w[1],
                layer: layer.to_string(),
            });
        }
        pts.clear();
        Ok(())
    };
    for seg in path.data().segments() {
        match seg {
            PathSegment::MoveTo(p) => {
                flush(&mut pts, out)?;
                let q = map(p.x, p.y);
                pts.push(q);
                start = Some(q);
                last = Some((p.x, p.y));
            }
            PathSegment::LineTo(p) => {
                pts.push(map(p.x, p.y));
                last = Some((p.x, p.y));
            }
            PathSegment::QuadTo(c, p) => {
                let (x0, y0) = last.unwrap_or((p.x, p.y));
                for k in 1..=CURVE_CHORDS {
                    let s = k as f32 / CURVE_CHORDS as f32;
                    let u = 1.0 - s;
                    let x = u * u * x0 + 2.0 * u * s * c.x + s * s * p.x;
                    let y = u * u * y0 + 2.0 * u * s * c.y + s * s * p.y;
                    pts.push(map(x, y));
                }
                last = Some((p.x, p.y));
            }
            PathSegment::CubicTo(c1, c2, p) => {
                let (x0, y0) = last.unwrap_or((p.x, p.y));
                for k in 1..=CURVE_CHORDS {
                    let s = k as f32 / CURVE_CHORDS as f32;
                    let u = 1.0 - s;
                    let x = u * u * u * x0
                        + 3.0 * u * u * s * c1.x
                        + 3.0 * u * s * s * c2.x
                        + s * s * s * p.x;
                    let y = u * u * u * y0
                        + 3.0 * u * u * s * c1.y
                        + 3.0 * u * s * s * c2.y
                        + s * s * s * p.y;
                    pts.push(map(x, y));
                }
                last = Some((p.x, p.y));
            }
            PathSegment::Close => {
                if let Some(s) = start {
                    pts.push(s);
                }
                flush(&mut pts, out)?;
                // A path may go on from the start point after a close.
                if let Some(s) = start {
                    pts.push(s);
                }
            }
        }
    }
    flush(&mut pts, out)
}

#[cfg(test)]
mod tests {
    use super::super::{Format, ReadOptions, parse};
    use super::external_reference;

    fn opts(scale: f64, layers: Option<&[&str]>) -> ReadOptions {
        ReadOptions {
            scale_m_per_unit: Some(scale),
            layers: layers.map(|l| l.iter().map(|s| s.to_string()).collect()),
            ..ReadOptions::default()
        }
    }

    #[test]
    fn shapes_and_transforms_become_segments_in_metres_y_up() {
        let svg = r#"<svg xmlns="http://www.w3.org/2000/svg" width="1000" height="1000">
          <g id="A-WALL" transform="translate(100,0)">
            <line x1="0" y1="0" x2="500" y2="0" stroke="black"/>
            <rect x="0" y="100" width="200" height="100" fill="none" stroke="black"/>
            <g transform="rotate(90)"><polyline points="0,0 300,0" fill="none" stroke="black"/></g>
          </g>
          <g id="FURNITURE"><path d="M 0 0 L 50 50" stroke="black"/></g>
        </svg>"#;
        let d = parse(
            "s.svg",
            svg.as_bytes(),
            Format::Svg,
            &opts(0.01, Some(&["A-WALL"])),
        )
        .unwrap();
        assert!(
            d.segments.iter().all(|s| s.layer == "A-WALL"),
            "{:?}",
            d.segments
        );
        // The line: (100,0)→(600,0) SVG units = (1,0)→(6,0) m.
        assert!(d.segments.iter().any(|s| (s.a.x - 1.0).abs() < 1e-6
            && (s.b.x - 6.0).abs() < 1e-6
            && s.a.y.abs() < 1e-6));
        // The rect: 4 sides, from y = −1 to −2 m (flipped).
        let rect = d
            .segments
            .iter()
            .filter(|s| s.a.y < -0.5 || s.b.y < -0.5)
            .filter(|s| s.a.x < 3.5 && s.b.x < 3.5 && s.a.x > 0.5)
            .count();
        assert!(rect >= 4, "{:?}", d.segments);
        // rotate(90) turns +x into +y (down the page) → −y in metres: (1,0)→(1,−3).
        assert!(
            d.segments
                .iter()
                .any(|s| (s.b.y + 3.0).abs() < 1e-4 && (s.b.x - 1.0).abs() < 1e-4)
        );
        assert!(d.layers.contains(&"FURNITURE".to_string()));
    }

    #[test]
    fn external_references_are_refused_and_internal_ones_kept() {
        let bad = r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink">
          <image xlink:href="/etc/passwd" width="10" height="10"/>
          <line x1="0" y1="0" x2="500" y2="0" stroke="black"/></svg>"#;
        let err = parse("x.svg", bad.as_bytes(), Format::Svg, &opts(0.01, None)).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("x.svg") && msg.contains("/etc/passwd"),
            "{msg}"
        );
        assert!(external_reference(r##"<use href="#a"/><rect fill="url(#g)"/>"##).is_none());
        assert!(external_reference(r#"<rect style="fill:url(other.svg#g)"/>"#).is_some());
    }

    #[test]
    fn no_scale_or_not_svg_is_an_error_naming_the_file() {
        let svg = r#"<svg xmlns="http://www.w3.org/2000/svg"><line x1="0" y1="0" x2="5" y2="0" stroke="black"/></svg>"#;
        let err = parse(
            "n.svg",
            svg.as_bytes(),
            Format::Svg,
            &ReadOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("n.svg"), "{err}");
        for data in [
            &b""[..],
            b"<svg",
            b"\xff\xff",
            b"<svg xmlns=\"http://www.w3.org/2000/svg\"/>",
        ] {
            let err = parse("n.svg", data, Format::Svg, &opts(1.0, None)).unwrap_err();
            assert!(err.to_string().contains("n.svg"), "{err}");
        }
    }
}
