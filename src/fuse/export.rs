//! Map files real tools open: `map.pgm` + `map.yaml` in ROS map_server conventions, and a
//! `map.ply` point cloud. Pure: these build bytes; the caller writes them atomically.

use std::fmt::Write as _;

use nalgebra::Point3;

use super::grid::{Cell, OccupancyGrid};

/// map_server's trinary values.
pub const PGM_FREE: u8 = 254;
pub const PGM_OCCUPIED: u8 = 0;
pub const PGM_UNKNOWN: u8 = 205;

/// Binary PGM (P5), top row first as image viewers expect, so the grid's bottom row is last.
pub fn pgm(grid: &OccupancyGrid) -> Vec<u8> {
    let (w, h) = grid.size();
    let mut out = format!(
        "P5\n# scanfuse occupancy map, {} m/cell\n{w} {h}\n255\n",
        grid.params().cell_m
    )
    .into_bytes();
    out.reserve(w * h);
    for y in (0..h as i64).rev() {
        for x in 0..w as i64 {
            out.push(match grid.cell(x, y) {
                Cell::Free => PGM_FREE,
                Cell::Occupied => PGM_OCCUPIED,
                Cell::Unknown => PGM_UNKNOWN,
            });
        }
    }
    out
}

/// The map_server YAML beside the PGM: `origin` is the site-frame pose of the lower-left pixel.
pub fn map_yaml(grid: &OccupancyGrid, image_file: &str) -> String {
    let p = grid.params();
    let o = grid.origin();
    let mut s = String::new();
    let _ = writeln!(s, "image: {image_file}");
    let _ = writeln!(s, "mode: trinary");
    let _ = writeln!(s, "resolution: {}", p.cell_m);
    let _ = writeln!(s, "origin: [{}, {}, 0.0]", o.x, o.y);
    let _ = writeln!(s, "negate: 0");
    let _ = writeln!(s, "occupied_thresh: {}", p.occupied_above);
    let _ = writeln!(s, "free_thresh: {}", p.free_below);
    s
}

/// `map.yaml` with the map placed in the building's frame: the grid is the site's, so its
/// origin (lower-left cell) is moved and turned by `building_from_site` (x, y, yaw; scale
/// multiplies the resolution, for a drawing not in metres).
pub fn map_yaml_in_building(
    grid: &OccupancyGrid,
    image_file: &str,
    building_from_site: &crate::drawing::align::Similarity,
) -> String {
    let p = grid.params();
    let o = grid.origin();
    let b = building_from_site.apply(&nalgebra::Point2::new(o.x, o.y));
    let mut s = String::new();
    let _ = writeln!(s, "# frame: building (building_from_site from poses.toml)");
    let _ = writeln!(s, "image: {image_file}");
    let _ = writeln!(s, "mode: trinary");
    let _ = writeln!(s, "resolution: {}", p.cell_m * building_from_site.scale);
    let _ = writeln!(
        s,
        "origin: [{}, {}, {}]",
        b.x, b.y, building_from_site.yaw_rad
    );
    let _ = writeln!(s, "negate: 0");
    let _ = writeln!(s, "occupied_thresh: {}", p.occupied_above);
    let _ = writeln!(s, "free_thresh: {}", p.free_below);
    s
}

/// One point of the fused cloud: where, and which sensor saw it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaggedPoint {
    pub site: Point3<f64>,
    /// Index into the sensor list the caller keeps.
    pub sensor: u16,
}

/// Binary little-endian PLY with float x, y, z, a colour per sensor (so every viewer shows
/// who saw what) and the sensor index as a `ushort` property.
pub fn ply(points: &[TaggedPoint]) -> Vec<u8> {
    ply_framed(points, "site frame")
}

/// [`ply`] with the frame the points are in named in the header comment.
pub fn ply_framed(points: &[TaggedPoint], frame: &str) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment scanfuse fused scan, {frame}, metres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nproperty ushort sensor\n\
         end_header\n",
        points.len()
    )
    .into_bytes();
    out.reserve(points.len() * 17);
    for p in points {
        for v in [p.site.x, p.site.y, p.site.z] {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
        out.extend_from_slice(&sensor_colour(p.sensor));
        out.extend_from_slice(&p.sensor.to_le_bytes());
    }
    out
}

/// Well-separated colours for the first sensors, then a cycle.
fn sensor_colour(sensor: u16) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 10] = [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [0, 128, 128],
        [170, 110, 40],
    ];
    PALETTE[usize::from(sensor) % PALETTE.len()]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuse::grid::GridParams;
    use nalgebra::Point2;

    /// A 4 × 3 m room seen from its centre, a ray every half degree, a few times over.
    fn room() -> OccupancyGrid {
        let mut g = OccupancyGrid::new(GridParams::default());
        let c = Point2::new(2.0, 1.5);
        for _ in 0..4 {
            for k in 0..720 {
                let a = (k as f64 * 0.5).to_radians();
                let (dx, dy) = (a.cos(), a.sin());
                // Distance to the first wall of [0,4]×[0,3] along (dx, dy).
                let tx = if dx > 0.0 {
                    (4.0 - c.x) / dx
                } else {
                    -c.x / dx
                };
                let ty = if dy > 0.0 {
                    (3.0 - c.y) / dy
                } else {
                    -c.y / dy
                };
                let t = tx.min(ty) - 0.01;
                g.insert_ray(c, Point2::new(c.x + t * dx, c.y + t * dy), true);
            }
        }
        g
    }

    #[test]
    fn pgm_is_top_row_first_with_map_server_values() {
        let g = room();
        let bytes = pgm(&g);
        let (w, h) = g.size();
        let header_end = bytes.len() - w * h;
        let header = String::from_utf8_lossy(&bytes[..header_end]);
        assert!(header.starts_with("P5\n") && header.ends_with(&format!("{w} {h}\n255\n")));
        let px = |x: f64, y: f64| {
            let o = g.origin();
            let c = g.params().cell_m;
            let col = ((x - o.x) / c).floor() as usize;
            let row_from_bottom = ((y - o.y) / c).floor() as usize;
            bytes[header_end + (h - 1 - row_from_bottom) * w + col]
        };
        assert_eq!(px(2.0, 1.0), PGM_FREE);
        assert_eq!(px(3.98, 1.5), PGM_OCCUPIED);
        assert_eq!(px(2.0, 2.98), PGM_OCCUPIED);
        assert_eq!(px(5.5, 1.5), PGM_UNKNOWN);
    }

    #[test]
    fn yaml_origin_is_the_lower_left_pixel() {
        let g = room();
        let y = map_yaml(&g, "map.pgm");
        let o = g.origin();
        assert!(
            y.contains(&format!("origin: [{}, {}, 0.0]", o.x, o.y)),
            "{y}"
        );
        assert!(y.contains("resolution: 0.05") && y.contains("image: map.pgm"));
        assert!(
            o.x <= 0.0 && o.y <= 0.0,
            "the room's corner is inside the map: {o:?}"
        );
    }

    #[test]
    fn ply_header_matches_the_body() {
        let pts = [
            TaggedPoint {
                site: Point3::new(1.0, 2.0, 0.5),
                sensor: 0,
            },
            TaggedPoint {
                site: Point3::new(-1.0, 0.0, 1.0),
                sensor: 3,
            },
        ];
        let bytes = ply(&pts);
        let text = String::from_utf8_lossy(&bytes);
        let end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.contains("element vertex 2"));
        assert_eq!(bytes.len() - end, 2 * (12 + 3 + 2));
        let body = &bytes[end..];
        assert_eq!(f32::from_le_bytes(body[0..4].try_into().unwrap()), 1.0);
        assert_eq!(u16::from_le_bytes(body[32..34].try_into().unwrap()), 3);
    }
}
