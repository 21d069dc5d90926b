//! The fuser: the latest scan of each posed sensor × its current pose → one fused frame of
//! site-frame points (streamed to `watch` clients), the fused cloud (`map.ply`) and the
//! log-odds occupancy grid (`map.pgm` + `map.yaml`); and the atomic writing of those files.

use std::path::Path;
use std::time::SystemTime;

use nalgebra::Point3;

use super::config::PublishConfig;
use super::pipeline::PosedScan;
use super::protocol::{Frame, FrameScan, PoseSource, SensorPose};
use super::state::{POSES_FILE, PosesFile, SavedPose, StateError, write_atomic};
use crate::fuse::{GridParams, OccupancyGrid, TaggedPoint, map_yaml, pgm, ply};
use crate::geometry::{ProjectParams, project_scan};

/// Rays enter the grid at most this often per sensor: a static map needs no 40 Hz updates,
/// and a ray costs one cell per 5 cm of range.
pub const GRID_UPDATE_S: f64 = 0.5;

pub const MAP_PGM: &str = "map.pgm";
pub const MAP_YAML: &str = "map.yaml";
pub const MAP_PLY: &str = "map.ply";

/// The fused map state.
pub struct Fuser {
    grid: OccupancyGrid,
    /// The latest fused cloud, every posed sensor's latest scan.
    points: Vec<TaggedPoint>,
    /// Last scan stamp that entered the grid, per sensor.
    grid_stamps_ns: std::collections::BTreeMap<String, u64>,
    project: ProjectParams,
}

impl Fuser {
    pub fn new(publish: &PublishConfig) -> Fuser {
        Fuser {
            grid: OccupancyGrid::new(GridParams {
                cell_m: publish.map_cell_m,
                occupied_above: publish.occupied_thresh,
                free_below: publish.free_thresh,
                ..GridParams::default()
            }),
            points: Vec::new(),
            grid_stamps_ns: Default::default(),
            project: ProjectParams::default(),
        }
    }

    pub fn grid(&self) -> &OccupancyGrid {
        &self.grid
    }

    pub fn points(&self) -> &[TaggedPoint] {
        &self.points
    }

    /// Fuses the latest scans: returns the frame and updates the cloud and (at most every
    /// [`GRID_UPDATE_S`] per sensor) the grid.
    pub fn fuse(&mut self, scans: &[PosedScan]) -> Frame {
        let mut frame = Frame {
            stamp_ns: 0,
            scans: Vec::with_capacity(scans.len()),
        };
        self.points.clear();
        for s in scans {
            let site_from_sensor = s.site_from_sensor.planar();
            let origin = site_from_sensor.translation.vector.into();
            let points = project_scan(&s.scan, s.geometry.as_ref(), &s.mount, &self.project);
            let due = self
                .grid_stamps_ns
                .get(&s.id)
                .is_none_or(|&t| s.scan.stamp_ns.saturating_sub(t) as f64 >= GRID_UPDATE_S * 1e9);
            if due {
                self.grid_stamps_ns.insert(s.id.clone(), s.scan.stamp_ns);
            }
            let mut xy_m = Vec::with_capacity(points.len() * 2);
            for p in &points {
                let site = site_from_sensor * p.p;
                if !(site.x.is_finite() && site.y.is_finite()) {
                    continue;
                }
                xy_m.push(site.x as f32);
                xy_m.push(site.y as f32);
                let z_m = p.z_m.or(s.mount.height_m).unwrap_or(0.0);
                self.points.push(TaggedPoint {
                    site: Point3::new(site.x, site.y, z_m),
                    sensor: s.index,
                });
                if due {
                    self.grid.insert_ray(origin, site, true);
                }
            }
            frame.stamp_ns = frame.stamp_ns.max(s.scan.stamp_ns);
            frame.scans.push(FrameScan {
                sensor: s.id.clone(),
                stamp_ns: s.scan.stamp_ns,
                xy_m,
            });
        }
        frame
    }
}

/// Writes `poses.toml` (when any sensor is known) and the map files into `dir`, each
/// atomically; returns the names written.
pub fn save_files(
    dir: &Path,
    anchor: &str,
    poses: &[(SensorPose, PoseSource, SystemTime)],
    grid: &OccupancyGrid,
    points: &[TaggedPoint],
) -> Result<Vec<String>, StateError> {
    let mut files = Vec::new();
    std::fs::create_dir_all(dir).map_err(|source| StateError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    if poses.iter().any(|(p, _, _)| p.id == anchor) {
        let file = PosesFile {
            anchor: anchor.to_string(),
            sensors: poses
                .iter()
                .map(|(pose, source, updated)| SavedPose::from_pose(pose, *source, *updated))
                .collect(),
        };
        file.save(dir)?;
        files.push(POSES_FILE.to_string());
    }
    let (w, h) = grid.size();
    if w > 0 && h > 0 {
        write_atomic(&dir.join(MAP_PGM), &pgm(grid))?;
        write_atomic(&dir.join(MAP_YAML), map_yaml(grid, MAP_PGM).as_bytes())?;
        files.push(MAP_PGM.into());
        files.push(MAP_YAML.into());
    }
    if !points.is_empty() {
        write_atomic(&dir.join(MAP_PLY), &ply(points))?;
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
        let frame = fuser.fuse(&[PosedScan {
            index: 0,
            id: "a".into(),
            scan: wall_scan(),
            geometry: None,
            mount: Mount {
                height_m: Some(1.0),
                pitch_rad: 0.0,
            },
            site_from_sensor: pose,
        }]);
        let xy = &frame.scans[0].xy_m;
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
    fn saved_files_are_complete_and_parse() {
        let dir = tempfile::tempdir().unwrap();
        let mut fuser = Fuser::new(&PublishConfig::default());
        fuser.fuse(&[PosedScan {
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
        let files = save_files(
            dir.path(),
            "a",
            &[(pose, PoseSource::Registered, SystemTime::now())],
            fuser.grid(),
            fuser.points(),
        )
        .unwrap();
        assert_eq!(files, ["poses.toml", "map.pgm", "map.yaml", "map.ply"]);
        let loaded = PosesFile::load(dir.path()).unwrap().unwrap();
        assert_eq!(loaded.anchor, "a");
        assert!(
            std::fs::read(dir.path().join(MAP_PGM))
                .unwrap()
                .starts_with(b"P5\n")
        );
    }
}
