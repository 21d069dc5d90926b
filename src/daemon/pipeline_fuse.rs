//! The fuser. The `watch` stream is event-driven: each scan of a posed sensor becomes a frame
//! of site-frame points the moment it arrives ([`scan_frame`], called on the driver's task).
//! The fused cloud (`map.ply`) and the log-odds occupancy grid (`map.pgm` + `map.yaml`) are
//! integrated in batches by [`Fuser`], one grid per sensor so that what a sensor saw under a
//! pose it no longer has can be dropped without touching the others'. Also the atomic
//! writing of those files.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::SystemTime;

use nalgebra::Point3;

use super::config::PublishConfig;
use super::pipeline::PosedScan;
use super::protocol::{FrameScan, PoseSource, SensorPose};
use super::state::{POSES_FILE, PosesFile, SavedPose, StateError, write_atomic};
use crate::fuse::{GridParams, OccupancyGrid, TaggedPoint, map_yaml, pgm, ply};
use crate::geometry::{Pose3, ProjectParams, pose_error, project_scan};

/// Rays enter the grid once per this period per sensor: a static map needs no 40 Hz updates,
/// and a ray costs one cell per 5 cm of range.
pub const GRID_UPDATE_S: f64 = 0.5;
/// A pose that changes by more than this (half a default cell, a fifth of a degree) makes
/// the sensor's grid start again: its old cells were drawn from where it no longer is.
pub const REPOSE_M: f64 = 0.025;
pub const REPOSE_RAD: f64 = 0.2 * std::f64::consts::PI / 180.0;

pub const MAP_PGM: &str = "map.pgm";
pub const MAP_YAML: &str = "map.yaml";
pub const MAP_PLY: &str = "map.ply";

/// Frame points are rounded to the millimetre: far below a scanner's noise (±30 mm), and the
/// JSON of a rounded coordinate (`12.346`) is about half as long as an unrounded one's
/// (`12.345678`), which is most of what a `watch` client or a page receives.
pub const FRAME_RESOLUTION_M: f64 = 0.001;

fn frame_coordinate(v: f64) -> f32 {
    ((v / FRAME_RESOLUTION_M).round() * FRAME_RESOLUTION_M) as f32
}

/// One posed sensor's scan as a `watch` frame entry: its points in the site frame, to the
/// millimetre.
pub fn scan_frame(s: &PosedScan, project: &ProjectParams) -> FrameScan {
    let site_from_sensor = s.site_from_sensor.planar();
    let points = project_scan(&s.scan, s.geometry.as_ref(), &s.mount, project);
    let mut xy_m = Vec::with_capacity(points.len() * 2);
    for p in &points {
        let site = site_from_sensor * p.p;
        if site.x.is_finite() && site.y.is_finite() {
            xy_m.push(frame_coordinate(site.x));
            xy_m.push(frame_coordinate(site.y));
        }
    }
    FrameScan {
        sensor: s.id.clone(),
        stamp_ns: s.scan.stamp_ns,
        xy_m,
    }
}

/// The [`GRID_UPDATE_S`] window a scan's stamp falls in for sensor `index`: a sensor's rays
/// enter the grid once per window. Each sensor's windows are shifted by its own phase so that
/// a hundred sensors' rays (most of the fuser's work) are spread over the period instead of
/// all landing on one pass.
fn grid_window(stamp_ns: u64, index: u16) -> u64 {
    const GOLDEN: f64 = 0.618_033_988_749_895;
    let period_ns = (GRID_UPDATE_S * 1e9) as u64;
    let phase_ns = ((index as f64 * GOLDEN).fract() * period_ns as f64) as u64;
    (stamp_ns + phase_ns) / period_ns
}

/// What one sensor contributed to the map, under the pose it had.
struct SensorMap {
    site_from_sensor: Pose3,
    grid: OccupancyGrid,
    /// The update window ([`grid_window`]) of the last scan whose rays entered `grid`.
    grid_window: Option<u64>,
    /// Its latest scan's points (the sensor's part of the fused cloud).
    points: Vec<TaggedPoint>,
}

/// The fused map state: per-sensor grids and clouds, combined when asked.
pub struct Fuser {
    params: GridParams,
    sensors: BTreeMap<String, SensorMap>,
    project: ProjectParams,
}

impl Fuser {
    pub fn new(publish: &PublishConfig) -> Fuser {
        Fuser {
            params: GridParams {
                cell_m: publish.map_cell_m,
                occupied_above: publish.occupied_thresh,
                free_below: publish.free_thresh,
                ..GridParams::default()
            },
            sensors: BTreeMap::new(),
            project: ProjectParams::default(),
        }
    }

    pub fn project_params(&self) -> &ProjectParams {
        &self.project
    }

    /// The occupancy grid of every sensor's rays.
    pub fn grid(&self) -> OccupancyGrid {
        OccupancyGrid::combined(self.params, self.sensors.values().map(|m| &m.grid))
    }

    /// The fused cloud: every posed sensor's latest scan.
    pub fn points(&self) -> Vec<TaggedPoint> {
        self.sensors
            .values()
            .flat_map(|m| m.points.iter().copied())
            .collect()
    }

    /// Takes the latest scan of every posed sensor: refreshes the cloud and (at most every
    /// [`GRID_UPDATE_S`] per sensor) the grid. A sensor whose pose changed starts a new grid;
    /// a sensor absent from `scans` (removed, or no longer posed) leaves the map.
    pub fn integrate(&mut self, scans: &[PosedScan]) {
        self.sensors
            .retain(|id, _| scans.iter().any(|s| &s.id == id));
        for s in scans {
            let map = match self.sensors.get_mut(&s.id) {
                Some(map) => {
                    let (moved_m, moved_rad) =
                        pose_error(&s.site_from_sensor.planar(), &map.site_from_sensor.planar());
                    if moved_m > REPOSE_M || moved_rad > REPOSE_RAD {
                        tracing::debug!(sensor = %s.id, moved_m, "new pose: its grid starts again");
                        map.site_from_sensor = s.site_from_sensor;
                        map.grid = OccupancyGrid::new(self.params);
                        map.grid_window = None;
                    }
                    map
                }
                None => self.sensors.entry(s.id.clone()).or_insert(SensorMap {
                    site_from_sensor: s.site_from_sensor,
                    grid: OccupancyGrid::new(self.params),
                    grid_window: None,
                    points: Vec::new(),
                }),
            };
            let window = grid_window(s.scan.stamp_ns, s.index);
            let due = map.grid_window != Some(window);
            if due {
                map.grid_window = Some(window);
            }
            let site_from_sensor = map.site_from_sensor.planar();
            let origin = site_from_sensor.translation.vector.into();
            map.points.clear();
            for p in project_scan(&s.scan, s.geometry.as_ref(), &s.mount, &self.project) {
                let site = site_from_sensor * p.p;
                if !(site.x.is_finite() && site.y.is_finite()) {
                    continue;
                }
                let z_m = p.z_m.or(s.mount.height_m).unwrap_or(0.0);
                map.points.push(TaggedPoint {
                    site: Point3::new(site.x, site.y, z_m),
                    sensor: s.index,
                });
                if due {
                    map.grid.insert_ray(origin, site, true);
                }
            }
        }
    }
}

/// Writes `poses.toml` (when any sensor is known) and the map files into `dir`, each
/// atomically; returns the names written. `held`: the site's alignment to the drawing the
/// daemon holds (found live, or asked for on the socket); without one, what `poses.toml`
/// has is kept.
pub fn save_files(
    dir: &Path,
    anchor: &str,
    poses: &[(SensorPose, PoseSource, SystemTime)],
    held: Option<&crate::drawing::BuildingFromSite>,
    grid: &OccupancyGrid,
    points: &[TaggedPoint],
) -> Result<Vec<String>, StateError> {
    let mut files = Vec::new();
    std::fs::create_dir_all(dir).map_err(|source| StateError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    // The map files are in the building's frame once the site is aligned. One set by
    // `scanfuse align --save` while the daemon runs is kept until the daemon finds its own.
    let building = match held {
        Some(b) => Some(b.clone()),
        None => PosesFile::load(dir)
            .ok()
            .flatten()
            .filter(|f| f.anchor == anchor)
            .and_then(|f| f.building_from_site),
    };
    let to_building = building.as_ref().and_then(|b| b.similarity());
    if poses.iter().any(|(p, _, _)| p.id == anchor) {
        let file = PosesFile {
            anchor: anchor.to_string(),
            sensors: poses
                .iter()
                .map(|(pose, source, updated)| SavedPose::from_pose(pose, *source, *updated))
                .collect(),
            // An alignment to the drawing (`scanfuse align --save`) is kept across saves.
            building_from_site: building.clone(),
        };
        file.save(dir)?;
        files.push(POSES_FILE.to_string());
    }
    let (w, h) = grid.size();
    if w > 0 && h > 0 {
        write_atomic(&dir.join(MAP_PGM), &pgm(grid))?;
        let yaml = match &to_building {
            Some(t) => crate::fuse::export::map_yaml_in_building(grid, MAP_PGM, t),
            None => map_yaml(grid, MAP_PGM),
        };
        write_atomic(&dir.join(MAP_YAML), yaml.as_bytes())?;
        files.push(MAP_PGM.into());
        files.push(MAP_YAML.into());
    }
    if !points.is_empty() {
        let bytes = match &to_building {
            Some(t) => {
                let moved: Vec<TaggedPoint> = points
                    .iter()
                    .map(|p| {
                        let b = t.apply(&nalgebra::Point2::new(p.site.x, p.site.y));
                        TaggedPoint {
                            site: Point3::new(b.x, b.y, p.site.z),
                            ..*p
                        }
                    })
                    .collect();
                crate::fuse::export::ply_framed(&moved, "building frame")
            }
            None => ply(points),
        };
        write_atomic(&dir.join(MAP_PLY), &bytes)?;
        files.push(MAP_PLY.into());
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Mount, Pose3, pose2};
    use crate::scan::Scan;

    fn wall_scan() -> Scan {
        // Three beams at -0.1, 0, 0.1 rad, all 2 m.
        Scan {
            stamp_ns: 1_000_000_000,
            sensor_stamp_ms: None,
            start_angle_rad: -0.1,
            end_angle_rad: 0.1,
            ranges_m: vec![2.0, 2.0, 2.0],
            intensities: Vec::new(),
        }
    }

    #[test]
    fn points_land_where_the_pose_puts_them() {
        let mut fuser = Fuser::new(&PublishConfig::default());
        let pose = Pose3::from_planar(&pose2(1.0, 2.0, std::f64::consts::FRAC_PI_2), 1.0, 0.0);
        let posed = PosedScan {
            index: 0,
            id: "a".into(),
            scan: wall_scan(),
            geometry: None,
            mount: Mount {
                height_m: Some(1.0),
                pitch_rad: 0.0,
            },
            site_from_sensor: pose,
        };
        let frame = scan_frame(&posed, &ProjectParams::default());
        assert_eq!(frame.sensor, "a");
        assert_eq!(frame.stamp_ns, 1_000_000_000);
        fuser.integrate(&[posed]);
        let xy = &frame.xy_m;
        assert_eq!(xy.len(), 6);
        // The middle beam looks along the sensor's +x, which is the site's +y.
        assert!(
            (xy[2] - 1.0).abs() < 1e-4 && (xy[3] - 4.0).abs() < 1e-4,
            "{xy:?}"
        );
        assert_eq!(fuser.points().len(), 3);
        assert!(fuser.grid().size().0 > 0, "the rays entered the grid");
    }

    #[test]
    fn frame_points_are_rounded_to_the_millimetre_and_written_short() {
        let mut posed = posed("a", 0, 2.0, 1.0, 0.123_456_7, -3.987_654_3);
        posed.scan.ranges_m = vec![2.345_678_9; 3];
        let frame = scan_frame(&posed, &ProjectParams::default());
        for &v in &frame.xy_m {
            let mm = f64::from(v) * 1000.0;
            assert!(
                (mm - mm.round()).abs() < 1e-3,
                "{v} is not whole millimetres"
            );
        }
        let json = serde_json::to_string(&frame.xy_m).unwrap();
        // Every number has at most three decimals.
        for n in json.trim_matches(|c| c == '[' || c == ']').split(',') {
            let decimals = n.split_once('.').map_or(0, |(_, d)| d.len());
            assert!(decimals <= 3, "{n} in {json}");
        }
    }

    fn posed(id: &str, index: u16, range_m: f32, stamp_s: f64, x_m: f64, y_m: f64) -> PosedScan {
        let mut scan = wall_scan();
        scan.ranges_m = vec![range_m; 3];
        scan.stamp_ns = (stamp_s * 1e9) as u64;
        PosedScan {
            index,
            id: id.into(),
            scan,
            geometry: None,
            mount: Mount::default(),
            site_from_sensor: Pose3::from_planar(&pose2(x_m, y_m, 0.0), 0.0, 0.0),
        }
    }

    #[test]
    fn a_sensor_with_a_new_pose_takes_its_old_cells_out_of_the_map() {
        use crate::fuse::Cell;
        use nalgebra::Point2;
        let mut fuser = Fuser::new(&PublishConfig::default());
        for k in 0..6 {
            let t = k as f64 * GRID_UPDATE_S;
            fuser.integrate(&[
                posed("a", 0, 2.0, t, 0.0, 0.0),
                posed("b", 1, 3.0, t, 0.0, 5.0),
            ]);
        }
        let before = fuser.grid();
        assert_eq!(before.cell_at(Point2::new(2.0, 0.0)), Cell::Occupied);
        assert_eq!(before.cell_at(Point2::new(3.0, 5.0)), Cell::Occupied);
        // b moved 3 m north and was re-registered there; it still sees a wall 3 m ahead.
        for k in 6..12 {
            let t = k as f64 * GRID_UPDATE_S;
            fuser.integrate(&[
                posed("a", 0, 2.0, t, 0.0, 0.0),
                posed("b", 1, 3.0, t, 0.0, 8.0),
            ]);
        }
        let after = fuser.grid();
        assert_eq!(after.cell_at(Point2::new(3.0, 8.0)), Cell::Occupied);
        assert_eq!(
            after.cell_at(Point2::new(3.0, 5.0)),
            Cell::Unknown,
            "only b's old pose explained this cell"
        );
        assert_eq!(after.cell_at(Point2::new(1.5, 5.0)), Cell::Unknown);
        assert_eq!(
            after.cell_at(Point2::new(2.0, 0.0)),
            Cell::Occupied,
            "a keeps its cells"
        );
        // A pose refined by less than half a cell keeps what the sensor drew.
        fuser.integrate(&[
            posed("a", 0, 2.0, 6.5, 0.01, 0.0),
            posed("b", 1, 3.0, 6.5, 0.0, 8.0),
        ]);
        assert_eq!(fuser.grid().cell_at(Point2::new(2.0, 0.0)), Cell::Occupied);
        // A sensor no longer posed (or removed) leaves the map and the cloud.
        fuser.integrate(&[posed("a", 0, 2.0, 7.0, 0.0, 0.0)]);
        assert_eq!(fuser.grid().cell_at(Point2::new(3.0, 8.0)), Cell::Unknown);
        assert!(fuser.points().iter().all(|p| p.sensor == 0));
    }

    #[test]
    fn a_hundred_sensors_rays_enter_the_grid_spread_over_the_period() {
        let mut fuser = Fuser::new(&PublishConfig::default());
        let scans = |t: f64| -> Vec<PosedScan> {
            (0..100)
                .map(|i| posed(&format!("s{i}"), i, 2.0, t, 0.0, i as f64))
                .collect()
        };
        let windows =
            |f: &Fuser| -> Vec<Option<u64>> { f.sensors.values().map(|m| m.grid_window).collect() };
        fuser.integrate(&scans(10.0));
        let mut before = windows(&fuser);
        // Passes at 10 Hz: each takes about a fifth of the sensors' rays, not all or none.
        for k in 1..=10 {
            fuser.integrate(&scans(10.0 + 0.1 * k as f64));
            let now = windows(&fuser);
            let updated = before.iter().zip(&now).filter(|(a, b)| a != b).count();
            assert!(
                (12..=28).contains(&updated),
                "{updated} grids took rays on pass {k}"
            );
            before = now;
        }
    }

    #[test]
    fn saved_files_are_complete_and_parse() {
        let dir = tempfile::tempdir().unwrap();
        let mut fuser = Fuser::new(&PublishConfig::default());
        fuser.integrate(&[PosedScan {
            index: 0,
            id: "a".into(),
            scan: wall_scan(),
            geometry: None,
            mount: Mount {
                height_m: None,
                pitch_rad: 0.0,
            },
            site_from_sensor: Pose3::from_planar(&pose2(0.0, 0.0, 0.0), 0.0, 0.0),
        }]);
        let mut pose = SensorPose::unregistered("a", "");
        pose.registered = true;
        pose.reason = None;
        pose.x_m = Some(0.0);
        pose.y_m = Some(0.0);
        pose.yaw_deg = Some(0.0);
        let pose_b = pose.clone();
        let files = save_files(
            dir.path(),
            "a",
            &[(pose, PoseSource::Registered, SystemTime::now())],
            None,
            &fuser.grid(),
            &fuser.points(),
        )
        .unwrap();
        assert_eq!(files, ["poses.toml", "map.pgm", "map.yaml", "map.ply"]);
        let loaded = PosesFile::load(dir.path()).unwrap().unwrap();
        assert_eq!(loaded.anchor, "a");
        let site_yaml = std::fs::read_to_string(dir.path().join(MAP_YAML)).unwrap();
        assert!(!site_yaml.contains("building"), "{site_yaml}");

        // Once aligned to a drawing (`scanfuse align --save`), the next save keeps the
        // alignment and writes the map files in the building's frame.
        let mut aligned = loaded.clone();
        aligned.building_from_site = Some(crate::drawing::BuildingFromSite {
            x_m: 100.0,
            y_m: 50.0,
            yaw_deg: 90.0,
            scale: 1.0,
            aligned: true,
            method: "pairs+lines".into(),
            reason: None,
            ..Default::default()
        });
        aligned.save(dir.path()).unwrap();
        save_files(
            dir.path(),
            "a",
            &[(pose_b, PoseSource::Registered, SystemTime::now())],
            None,
            &fuser.grid(),
            &fuser.points(),
        )
        .unwrap();
        let kept = PosesFile::load(dir.path()).unwrap().unwrap();
        assert_eq!(kept.building_from_site, aligned.building_from_site);
        assert_eq!(
            kept.sensors[0].x_m,
            Some(0.0),
            "poses stay in the site frame"
        );
        let yaml = std::fs::read_to_string(dir.path().join(MAP_YAML)).unwrap();
        let o = fuser.grid().origin();
        // (x, y) turned 90° and moved: (100 − y, 50 + x).
        let want = format!(
            "origin: [{}, {}, {}]",
            100.0 - o.y,
            50.0 + o.x,
            90f64.to_radians()
        );
        assert!(
            yaml.contains("frame: building") && yaml.contains(&want),
            "{yaml}\nwant {want}"
        );
        let ply = std::fs::read(dir.path().join(MAP_PLY)).unwrap();
        let header_end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert!(String::from_utf8_lossy(&ply[..header_end]).contains("building frame"));
        let x = f32::from_le_bytes(ply[header_end..header_end + 4].try_into().unwrap()) as f64;
        let site_x = fuser.points()[0].site.x;
        let site_y = fuser.points()[0].site.y;
        assert!(
            (x - (100.0 - site_y)).abs() < 1e-3,
            "{x} vs site ({site_x}, {site_y})"
        );
        assert!(
            std::fs::read(dir.path().join(MAP_PGM))
                .unwrap()
                .starts_with(b"P5\n")
        );
    }
}
