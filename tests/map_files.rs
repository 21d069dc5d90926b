//! The fused map of a simulated site: walls where the floor plan has them, and files that
//! Pillow, plyfile and PyYAML open.

use crate::common;

use nalgebra::{Isometry2, Point2, Point3, Vector2};
use scanfuse::fuse::{self, Cell, GridParams, OccupancyGrid, TaggedPoint};
use scanfuse::record;

/// Half a second of the lab fixture into one grid and one cloud, placed by the true poses.
fn lab_map() -> (OccupancyGrid, Vec<TaggedPoint>) {
    let rec = record::read(&common::repo().join("fixtures/lab.mcap")).unwrap();
    let mut grid = OccupancyGrid::new(GridParams::default());
    let mut cloud = Vec::new();
    for (index, sensor) in rec.sensors.iter().enumerate() {
        let truth = sensor.truth.unwrap();
        let site_from_sensor = Isometry2::new(
            Vector2::new(truth.x_m, truth.y_m),
            truth.yaw_deg.to_radians(),
        );
        let origin = site_from_sensor * Point2::origin();
        for scan in rec.scans_of(&sensor.id).iter().take(20) {
            for (i, r) in scan.ranges_m.iter().enumerate() {
                if !scan.is_return(i) {
                    continue;
                }
                let a = scan.angle_of_index_rad(i);
                let p = site_from_sensor
                    * Point2::new(f64::from(*r) * a.cos(), f64::from(*r) * a.sin());
                grid.insert_ray(origin, p, true);
                cloud.push(TaggedPoint {
                    site: Point3::new(p.x, p.y, sensor.height_m.unwrap_or(0.0)),
                    sensor: index as u16,
                });
            }
        }
    }
    (grid, cloud)
}

#[test]
fn walls_of_the_plan_are_occupied_and_the_room_is_free() {
    let (grid, _) = lab_map();
    // lab.toml: outer walls along y = 0 (x 0..20, with a door at x 2.5..3.5) and x = 20.
    let occupied_near = |x: f64, y: f64| {
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                grid.cell_at(Point2::new(x + dx as f64 * 0.05, y + dy as f64 * 0.05))
                    == Cell::Occupied
            })
        })
    };
    // Cabinets and people hide some of each wall from every sensor.
    let wall_cells = (0..40)
        .filter(|k| occupied_near(5.0 + *k as f64 * 0.2, 0.0))
        .count();
    assert!(
        wall_cells >= 30,
        "south wall seen in {wall_cells} of 40 places"
    );
    let east_cells = (0..25)
        .filter(|k| occupied_near(20.0, 1.5 + *k as f64 * 0.2))
        .count();
    assert!(
        east_cells >= 18,
        "east wall seen in {east_cells} of 25 places"
    );
    assert_eq!(grid.cell_at(Point2::new(4.0, 3.0)), Cell::Free);
    assert_eq!(grid.cell_at(Point2::new(10.0, 20.0)), Cell::Unknown);
}

#[test]
fn map_files_open_in_common_tools() {
    let Some(python) = common::test_python("map_files_open_in_common_tools") else {
        return;
    };
    let (grid, cloud) = lab_map();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("map.pgm"), fuse::pgm(&grid)).unwrap();
    std::fs::write(
        dir.path().join("map.yaml"),
        fuse::map_yaml(&grid, "map.pgm"),
    )
    .unwrap();
    std::fs::write(dir.path().join("map.ply"), fuse::ply(&cloud)).unwrap();
    let out = common::succeeded(
        std::process::Command::new(python)
            .arg(common::repo().join("tests/python/read_map_files.py"))
            .arg(dir.path()),
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (w, h) = grid.size();
    assert_eq!(v["mode"], "L");
    assert_eq!(v["size"], serde_json::json!([w, h]));
    let count = |k: &str| v["pixels"][k].as_u64().unwrap_or(0);
    assert_eq!(count("0") + count("205") + count("254"), (w * h) as u64);
    assert!(
        count("0") > 1000 && count("254") > 10_000,
        "{}",
        v["pixels"]
    );
    assert_eq!(v["yaml"]["resolution"], 0.05);
    assert_eq!(v["yaml"]["origin"][0].as_f64().unwrap(), grid.origin().x);
    assert_eq!(v["yaml"]["mode"], "trinary");
    assert_eq!(v["ply_vertices"], cloud.len());
    assert_eq!(
        v["ply_properties"],
        serde_json::json!(["x", "y", "z", "red", "green", "blue", "sensor"])
    );
    assert!((v["ply_first"][0].as_f64().unwrap() - cloud[0].site.x).abs() < 1e-5);
}
