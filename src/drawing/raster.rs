//! PNG / PGM plans → wall segments. Dark pixels (below mid-grey) are wall; the segments are
//! the borders between wall and free pixels, merged into runs along rows and columns, so a
//! wall drawn 10 px thick gives its two faces, which is what a scanner sees. The scale is the
//! user's (m per px); pixel (0, height) — the bottom-left corner — is the origin, y up.

use super::{DrawingError, Format, Raw, ReadOptions, WallSegment, check_scale};
use nalgebra::Point2;

/// Images larger than this many pixels are refused (a 10k × 10k plan at 2 cm is 200 m).
const MAX_PIXELS: u64 = 100_000_000;
/// Runs shorter than this many pixels are left out (noise, text).
const MIN_RUN_PX: usize = 3;

pub(crate) fn segments(
    file: &str,
    data: &[u8],
    format: Format,
    opts: &ReadOptions,
) -> Result<Raw, DrawingError> {
    let Some(scale) = opts.scale_m_per_unit else {
        return Err(DrawingError::Units {
            file: file.to_string(),
            message: "a raster plan needs its scale in metres per pixel (--scale)".into(),
        });
    };
    let scale = check_scale(file, scale)?;
    let fmt = match format {
        Format::Png => image::ImageFormat::Png,
        _ => image::ImageFormat::Pnm,
    };
    let err = |message: String| DrawingError::Raster {
        file: file.to_string(),
        message,
    };
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(data), fmt);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_PIXELS * 4);
    reader.limits(limits);
    let img = reader
        .decode()
        .map_err(|e| err(e.to_string()))?
        .into_luma8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    if (w as u64) * (h as u64) > MAX_PIXELS {
        return Err(err(format!("{w}×{h} pixels is too large")));
    }
    let wall = |x: i64, y: i64| {
        x >= 0
            && y >= 0
            && (x as usize) < w
            && (y as usize) < h
            && img.get_pixel(x as u32, y as u32).0[0] < 128
    };
    // Pixel corner (x, y) (image: y down) → metres, y up.
    let at = |x: usize, y: usize| Point2::new(x as f64 * scale, (h - y) as f64 * scale);
    let mut segments = Vec::new();
    let mut push = |a: Point2<f64>, b: Point2<f64>| {
        segments.push(WallSegment {
            a,
            b,
            layer: "0".into(),
        })
    };
    // Horizontal borders: between row y−1 and row y, for y in 0..=h.
    for y in 0..=h {
        let mut run: Option<(usize, bool)> = None;
        for x in 0..=w {
            let edge = if x < w {
                let (up, down) = (wall(x as i64, y as i64 - 1), wall(x as i64, y as i64));
                (up != down).then_some(up)
            } else {
                None
            };
            match (run, edge) {
                (Some((_, side)), Some(s)) if s == side => {}
                (r, e) => {
                    if let Some((x0, _)) = r
                        && x - x0 >= MIN_RUN_PX
                    {
                        push(at(x0, y), at(x, y));
                    }
                    run = e.map(|s| (x, s));
                }
            }
        }
    }
    // Vertical borders: between column x−1 and column x.
    for x in 0..=w {
        let mut run: Option<(usize, bool)> = None;
        for y in 0..=h {
            let edge = if y < h {
                let (left, right) = (wall(x as i64 - 1, y as i64), wall(x as i64, y as i64));
                (left != right).then_some(left)
            } else {
                None
            };
            match (run, edge) {
                (Some((_, side)), Some(s)) if s == side => {}
                (r, e) => {
                    if let Some((y0, _)) = r
                        && y - y0 >= MIN_RUN_PX
                    {
                        push(at(x, y0), at(x, y));
                    }
                    run = e.map(|s| (y, s));
                }
            }
        }
    }
    Ok(Raw {
        segments,
        layers: vec!["0".into()],
        units: format!("{scale} m per px"),
    })
}

#[cfg(test)]
mod tests {
    use super::super::{Format, ReadOptions, parse};

    fn pgm(w: usize, h: usize, wall: impl Fn(usize, usize) -> bool) -> Vec<u8> {
        let mut out = format!("P5\n{w} {h}\n255\n").into_bytes();
        for y in 0..h {
            for x in 0..w {
                out.push(if wall(x, y) { 0 } else { 255 });
            }
        }
        out
    }

    #[test]
    fn a_thick_wall_gives_its_two_faces_in_metres() {
        // 100 × 50 px, a wall 4 px thick along rows 20..24, from x = 10 to 90.
        let data = pgm(100, 50, |x, y| {
            (20..24).contains(&y) && (10..90).contains(&x)
        });
        let opts = ReadOptions {
            scale_m_per_unit: Some(0.1),
            ..ReadOptions::default()
        };
        let d = parse("w.pgm", &data, Format::Pgm, &opts).unwrap();
        let long: Vec<_> = d.segments.iter().filter(|s| s.length_m() > 7.0).collect();
        assert_eq!(long.len(), 2, "{:?}", d.segments);
        // Faces at image rows 20 and 24 → y = (50 − 20)·0.1 = 3.0 and 2.6 m.
        let mut ys: Vec<f64> = long.iter().map(|s| s.a.y).collect();
        ys.sort_by(f64::total_cmp);
        assert!(
            (ys[0] - 2.6).abs() < 1e-9 && (ys[1] - 3.0).abs() < 1e-9,
            "{ys:?}"
        );
        assert!((long[0].length_m() - 8.0).abs() < 1e-9);
    }

    #[test]
    fn bad_images_are_errors_naming_the_file() {
        let opts = ReadOptions {
            scale_m_per_unit: Some(0.1),
            ..ReadOptions::default()
        };
        for data in [
            &b""[..],
            b"P5\n99999999 99999999\n255\n",
            b"\x89PNG\r\n\x1a\n trunc",
        ] {
            let err = parse("bad.png", data, Format::Png, &opts).unwrap_err();
            assert!(err.to_string().contains("bad.png"), "{err}");
        }
        let blank = pgm(10, 10, |_, _| false);
        let err = parse("blank.pgm", &blank, Format::Pgm, &opts).unwrap_err();
        assert!(err.to_string().contains("no wall"), "{err}");
        let err = parse("s.pgm", &blank, Format::Pgm, &ReadOptions::default()).unwrap_err();
        assert!(err.to_string().contains("--scale"), "{err}");
    }
}
