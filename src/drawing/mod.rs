//! Building drawings (DXF, SVG, PNG/PGM rasters) turned into wall segments in metres, and the
//! alignment of the fused map to them (`align`: `building_from_site`).
//!
//! The crates read the formats (`dxf`, `usvg`, `image`); here only their entities become
//! segments. Every reader is pure over bytes ([`parse`]); [`read`] is the file edge, which
//! checks the size before reading anything. Drawings are y-up: SVG and raster y (down the
//! page) is flipped, so the building frame is right-handed like the site frame.

pub mod align;
pub mod dxf;
pub mod raster;
pub mod svg;

use nalgebra::Point2;
use std::path::Path;

/// Files larger than this are refused before they are read (a plan of a whole campus is a few
/// tens of MB; a 200 MB file is a mistake or an attack).
pub const MAX_FILE_BYTES: u64 = 100 * 1024 * 1024;

/// More segments than this is not a floor plan (a ~5,000-entity drawing gives ~50,000).
pub const MAX_SEGMENTS: usize = 2_000_000;

/// A straight piece of wall in the drawing, in metres, with the layer it was drawn on.
#[derive(Debug, Clone, PartialEq)]
pub struct WallSegment {
    pub a: Point2<f64>,
    pub b: Point2<f64>,
    pub layer: String,
}

impl WallSegment {
    pub fn length_m(&self) -> f64 {
        (self.b - self.a).norm()
    }
}

/// A drawing reduced to what a scanner can see: wall segments in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Drawing {
    /// The file (for messages).
    pub source: String,
    pub segments: Vec<WallSegment>,
    /// The units the file was drawn in ("mm", "m", "px at 0.05 m", …), for reports.
    pub units: String,
    /// Bounding box of the segments (min, max), m.
    pub bounds: (Point2<f64>, Point2<f64>),
    /// Every layer the file holds (before selection), sorted.
    pub layers: Vec<String>,
}

/// `building_from_site` as files, the socket and `align --json` carry it: where the site
/// frame (the anchor's) lies in the drawing's, kept beside the poses, never folded into them.
/// `p_building = scale · R(yaw) · p_site + (x, y)`. When `aligned` is false the numbers are
/// the identity and `reason` says why.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildingFromSite {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_deg: f64,
    pub scale: f64,
    pub aligned: bool,
    /// How it was found: `automatic+lines`, `pairs+lines`, `pairs`, `automatic`.
    pub method: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// σ of x, y (m) and yaw (degrees), as the poses carry theirs: from the line fit, each
    /// drawing line counted once (`align::Refined::covariance`), or from the clicks where
    /// their fit was kept (`align::CLICK_SIGMA_M`); absent when not aligned.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_x_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_y_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_yaw_deg: Option<f64>,
}

impl Default for BuildingFromSite {
    /// The identity, not aligned.
    fn default() -> Self {
        BuildingFromSite {
            x_m: 0.0,
            y_m: 0.0,
            yaw_deg: 0.0,
            scale: 1.0,
            aligned: false,
            method: String::new(),
            reason: None,
            sigma_x_m: None,
            sigma_y_m: None,
            sigma_yaw_deg: None,
        }
    }
}

impl BuildingFromSite {
    pub fn from_alignment(a: &align::Alignment) -> BuildingFromSite {
        let t = a.building_from_site.unwrap_or(align::Similarity {
            x_m: 0.0,
            y_m: 0.0,
            yaw_rad: 0.0,
            scale: 1.0,
        });
        let sigma = a.sigma();
        BuildingFromSite {
            x_m: t.x_m,
            y_m: t.y_m,
            yaw_deg: t.yaw_rad.to_degrees(),
            scale: t.scale,
            aligned: a.building_from_site.is_some(),
            method: a.method.clone(),
            reason: a.reason.clone(),
            sigma_x_m: sigma.map(|s| s.0),
            sigma_y_m: sigma.map(|s| s.1),
            sigma_yaw_deg: sigma.map(|s| s.2.to_degrees()),
        }
    }

    /// The transform, when aligned.
    pub fn similarity(&self) -> Option<align::Similarity> {
        self.aligned.then_some(align::Similarity {
            x_m: self.x_m,
            y_m: self.y_m,
            yaw_rad: self.yaw_deg.to_radians(),
            scale: self.scale,
        })
    }
}

/// The formats read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Dxf,
    Svg,
    Png,
    Pgm,
}

impl Format {
    /// From the file name's extension.
    pub fn of(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "dxf" => Some(Format::Dxf),
            "svg" => Some(Format::Svg),
            "png" => Some(Format::Png),
            "pgm" | "pnm" => Some(Format::Pgm),
            _ => None,
        }
    }
}

/// How to read a drawing.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOptions {
    /// Layers to keep (case-insensitive); `None` keeps all.
    pub layers: Option<Vec<String>>,
    /// Metres per drawing unit: required for SVG and rasters (m per px), and for a DXF whose
    /// `$INSUNITS` is unset; overrides `$INSUNITS` when given.
    pub scale_m_per_unit: Option<f64>,
    /// Files larger than this are refused unread.
    pub max_bytes: u64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            layers: None,
            scale_m_per_unit: None,
            max_bytes: MAX_FILE_BYTES,
        }
    }
}

/// Why a drawing could not be used. Each names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DrawingError {
    #[error("{file}: cannot read: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error(
        "{file}: {bytes} bytes is over the {limit} byte limit for a drawing; export only the floor needed"
    )]
    TooLarge {
        file: String,
        bytes: u64,
        limit: u64,
    },
    #[error("{file}: unknown drawing format (use .dxf, .svg, .png or .pgm)")]
    UnknownFormat { file: String },
    #[error("{file}: not a readable DXF: {message}")]
    Dxf { file: String, message: String },
    #[error("{file}: not a readable SVG: {message}")]
    Svg { file: String, message: String },
    #[error("{file}: refers to an outside file {href:?}; drawings must be self-contained")]
    ExternalReference { file: String, href: String },
    #[error("{file}: not a readable image: {message}")]
    Raster { file: String, message: String },
    #[error("{file}: units: {message}")]
    Units { file: String, message: String },
    #[error("{file}: no wall segments{}", layers_note(.layers, .selected))]
    Empty {
        file: String,
        layers: Vec<String>,
        selected: Option<Vec<String>>,
    },
    #[error("{file}: over {limit} segments; not a floor plan")]
    TooManySegments { file: String, limit: usize },
}

fn layers_note(layers: &[String], selected: &Option<Vec<String>>) -> String {
    match selected {
        Some(sel) => format!(
            " on layers {} (the file has: {})",
            sel.join(", "),
            if layers.is_empty() {
                "none".to_string()
            } else {
                layers.join(", ")
            }
        ),
        None => String::new(),
    }
}

/// Reads a drawing file: the size is checked before a byte is read.
pub fn read(path: &Path, opts: &ReadOptions) -> Result<Drawing, DrawingError> {
    let file = path.display().to_string();
    let format =
        Format::of(path).ok_or_else(|| DrawingError::UnknownFormat { file: file.clone() })?;
    let io = |source| DrawingError::Io {
        file: file.clone(),
        source,
    };
    let bytes = std::fs::metadata(path).map_err(io)?.len();
    if bytes > opts.max_bytes {
        return Err(DrawingError::TooLarge {
            file,
            bytes,
            limit: opts.max_bytes,
        });
    }
    let data = std::fs::read(path).map_err(io)?;
    parse(&file, &data, format, opts)
}

/// Turns a drawing's bytes into wall segments (pure; `file` is for messages).
pub fn parse(
    file: &str,
    data: &[u8],
    format: Format,
    opts: &ReadOptions,
) -> Result<Drawing, DrawingError> {
    if data.len() as u64 > opts.max_bytes {
        return Err(DrawingError::TooLarge {
            file: file.to_string(),
            bytes: data.len() as u64,
            limit: opts.max_bytes,
        });
    }
    let raw = match format {
        Format::Dxf => dxf::segments(file, data, opts)?,
        Format::Svg => svg::segments(file, data, opts)?,
        Format::Png | Format::Pgm => raster::segments(file, data, format, opts)?,
    };
    finish(file, raw, opts)
}

impl Drawing {
    /// A drawing made in code (eval, tests) from segments in metres, checked as a file's are.
    pub fn from_segments(
        source: &str,
        segments: Vec<WallSegment>,
        units: &str,
    ) -> Result<Drawing, DrawingError> {
        let mut layers: Vec<String> = segments.iter().map(|s| s.layer.clone()).collect();
        layers.dedup();
        let raw = Raw {
            segments,
            layers,
            units: units.to_string(),
        };
        finish(source, raw, &ReadOptions::default())
    }
}

/// What a reader hands back: segments in metres (all layers), the layers seen, the units.
pub(crate) struct Raw {
    pub segments: Vec<WallSegment>,
    pub layers: Vec<String>,
    pub units: String,
}

/// A positive, finite scale or an error naming it.
pub(crate) fn check_scale(file: &str, scale: f64) -> Result<f64, DrawingError> {
    if scale.is_finite() && scale > 0.0 {
        Ok(scale)
    } else {
        Err(DrawingError::Units {
            file: file.to_string(),
            message: format!("scale {scale} m per unit is not a positive number"),
        })
    }
}

/// Smallest and largest span (m) of a building drawing; outside, the units are wrong.
const MIN_SPAN_M: f64 = 0.5;
const MAX_SPAN_M: f64 = 5_000.0;

fn finish(file: &str, raw: Raw, opts: &ReadOptions) -> Result<Drawing, DrawingError> {
    let Raw {
        mut segments,
        mut layers,
        units,
    } = raw;
    layers.sort();
    layers.dedup();
    if let Some(keep) = &opts.layers {
        segments.retain(|s| keep.iter().any(|k| k.eq_ignore_ascii_case(&s.layer)));
    }
    segments.retain(|s| {
        s.a.coords
            .iter()
            .chain(s.b.coords.iter())
            .all(|v| v.is_finite())
            && s.length_m() > 1e-4
    });
    if segments.is_empty() {
        return Err(DrawingError::Empty {
            file: file.to_string(),
            layers,
            selected: opts.layers.clone(),
        });
    }
    let mut lo = Point2::new(f64::INFINITY, f64::INFINITY);
    let mut hi = Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    for s in &segments {
        lo = lo.inf(&s.a).inf(&s.b);
        hi = hi.sup(&s.a).sup(&s.b);
    }
    let span = (hi - lo).amax();
    if !(MIN_SPAN_M..=MAX_SPAN_M).contains(&span) {
        return Err(DrawingError::Units {
            file: file.to_string(),
            message: format!(
                "the walls span {span:.3} m in {units}, not a building ({MIN_SPAN_M}–{MAX_SPAN_M} m); wrong units or scale?"
            ),
        });
    }
    Ok(Drawing {
        source: file.to_string(),
        segments,
        units,
        bounds: (lo, hi),
        layers,
    })
}

/// Chord points of a circular arc from `start_rad` sweeping `sweep_rad` (signed), at most
/// 10° per chord: start and end included.
pub(crate) fn arc_points(
    centre: Point2<f64>,
    radius: f64,
    start_rad: f64,
    sweep_rad: f64,
) -> Vec<Point2<f64>> {
    let steps = ((sweep_rad.abs() / 10f64.to_radians()).ceil() as usize).clamp(1, 72);
    (0..=steps)
        .map(|k| {
            let a = start_rad + sweep_rad * k as f64 / steps as f64;
            centre + nalgebra::Vector2::new(a.cos(), a.sin()) * radius
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_over_the_limit_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.dxf");
        let f = std::fs::File::create(&path).unwrap();
        // Sparse: 300 MB that take no disk and would take a while to read.
        f.set_len(300 * 1024 * 1024).unwrap();
        let err = read(&path, &ReadOptions::default()).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, DrawingError::TooLarge { .. }), "{msg}");
        assert!(msg.contains("big.dxf") && msg.contains("limit"), "{msg}");
    }

    #[test]
    fn an_unknown_extension_is_named() {
        let err = read(Path::new("plan.dwg"), &ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("plan.dwg"), "{err}");
    }

    #[test]
    fn units_that_make_a_building_tiny_are_refused() {
        let raw = Raw {
            segments: vec![WallSegment {
                a: Point2::new(0.0, 0.0),
                b: Point2::new(0.01, 0.0),
                layer: "0".into(),
            }],
            layers: vec!["0".into()],
            units: "m".into(),
        };
        let err = finish("x.dxf", raw, &ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("wrong units"), "{err}");
    }
}
