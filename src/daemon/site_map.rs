//! The site daemon's fused map (no I/O but the save): the zones' decimated scans
//! (`zone_net`'s `scan/<sensor>`, opt-in with `[zenoh] scans_hz`), each placed by its zone's
//! pose of the unit and the zone's `site_from_zone`, fused as a zone daemon fuses its own
//! (`pipeline_fuse::Fuser`): streamed to `watch` clients with `map` as they come, and written
//! as map files on `save` and at stop; the site daemon's page draws it.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};

use super::config::PublishConfig;
use super::pipeline::PosedScan;
use super::pipeline_fuse::{Fuser, save_files, scan_frame};
use super::protocol::Frame;
use super::state::StateError;
use super::zone_net::ViewPayload;
use crate::geometry::{Pose2, Pose3, ProjectParams};

/// Every zone's latest scan of each unit, and the map fused from them. The fusing has a
/// lock of its own, so that a large site's map is fused while its zones' scans come in.
pub struct SiteMap {
    fuser: Arc<Mutex<Fuser>>,
    project: ProjectParams,
    latest: BTreeMap<String, PosedScan>,
    /// A unit's number in the map's cloud (its PLY `sensor`), in the order first heard.
    index: BTreeMap<String, u16>,
}

impl SiteMap {
    pub fn new(publish: &PublishConfig) -> SiteMap {
        let fuser = Fuser::new(publish);
        SiteMap {
            project: *fuser.project_params(),
            fuser: Arc::new(Mutex::new(fuser)),
            latest: BTreeMap::new(),
            index: BTreeMap::new(),
        }
    }

    /// Takes a zone's scan of one unit, which stands at `site_from_sensor` (planar) in the
    /// site frame; returns it as a `watch` frame.
    pub fn take(&mut self, scan: ViewPayload, site_from_sensor: &Pose2) -> Frame {
        let next = self.index.len() as u16;
        let index = *self.index.entry(scan.sensor.clone()).or_insert(next);
        let view = scan.into_view();
        let posed = PosedScan {
            index,
            id: view.id.clone(),
            site_from_sensor: Pose3::from_planar(
                site_from_sensor,
                view.mount.height_m.unwrap_or(0.0),
                view.mount.pitch_rad,
            ),
            scan: view.view,
            geometry: view.geometry,
            mount: view.mount,
        };
        let frame = Frame {
            stamp_ns: posed.scan.stamp_ns,
            scans: vec![scan_frame(&posed, &self.project)],
        };
        self.latest.insert(posed.id.clone(), posed);
        frame
    }

    /// A unit no longer placed in the site frame leaves the map.
    pub fn forget(&mut self, sensor: &str) {
        self.latest.remove(sensor);
    }

    /// The latest scans to fuse, and the fuser to fuse them with: fuse with
    /// `fuser.lock().integrate(&scans)` once this map's own lock is let go (each unit's rays
    /// go in at most every half second).
    pub fn to_fuse(&self) -> (Arc<Mutex<Fuser>>, Vec<PosedScan>) {
        (self.fuser.clone(), self.latest.values().cloned().collect())
    }

    /// Fuses the latest scans into the map, here and now.
    #[cfg(test)]
    fn fuse(&self) {
        let (fuser, scans) = self.to_fuse();
        lock(&fuser).integrate(&scans);
    }

    /// Units in the map.
    pub fn units(&self) -> usize {
        self.latest.len()
    }

    /// The occupancy grid of every unit's rays.
    pub fn grid(&self) -> crate::fuse::OccupancyGrid {
        lock(&self.fuser).grid()
    }

    /// Each unit's field of view from its latest scan: id, first and last beam angle (rad,
    /// the unit's frame), for the page.
    pub fn fields_of_view(&self) -> Vec<(String, f64, f64)> {
        self.latest
            .values()
            .map(|p| (p.id.clone(), p.scan.start_angle_rad, p.scan.end_angle_rad))
            .collect()
    }

    /// Writes the map files (`map.pgm`, `map.yaml`, `map.ply`, site frame) into `dir`, each
    /// atomically; the site daemon writes no `poses.toml` (the zones save their own).
    pub fn save(&self, dir: &Path, anchor_zone: &str) -> Result<Vec<String>, StateError> {
        let fuser = lock(&self.fuser);
        save_files(dir, anchor_zone, &[], None, &fuser.grid(), &fuser.points())
    }
}

/// The fuser, even if a thread panicked while it fused (the map is then at worst a fuse
/// behind).
pub fn lock(fuser: &Mutex<Fuser>) -> MutexGuard<'_, Fuser> {
    fuser.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::zone_net::{SCAN_SCHEMA, ViewPayload};
    use crate::geometry::Mount;
    use crate::geometry::pose2;
    use crate::geometry::raycast::{polygon, scan_270};

    /// A unit of a 10 × 8 m room, scanned from its centre facing +x.
    fn scan(t_ns: u64) -> ViewPayload {
        let walls = polygon(&[(-5.0, -4.0), (5.0, -4.0), (5.0, 4.0), (-5.0, 4.0)]);
        let s = scan_270(&walls, &Pose2::identity(), 0.5, t_ns);
        ViewPayload::of(
            SCAN_SCHEMA,
            "hall",
            "east",
            "a",
            &s,
            &Mount::default(),
            None,
        )
    }

    #[test]
    fn a_zones_scans_land_where_the_site_puts_the_unit_and_save_as_map_files() {
        let mut map = SiteMap::new(&PublishConfig::default());
        // The unit stands at (20, 0) in the site frame, turned 90°: the room's east wall
        // (5 m ahead of it) is at y = 5 in the site.
        let at = pose2(20.0, 0.0, std::f64::consts::FRAC_PI_2);
        let frame = map.take(scan(1_000_000_000), &at);
        let xy = &frame.scans[0].xy_m;
        let ahead = xy
            .chunks(2)
            .filter(|p| (p[0] - 20.0).abs() < 0.05)
            .map(|p| p[1])
            .collect::<Vec<_>>();
        assert!(ahead.iter().any(|y| (y - 5.0).abs() < 0.02), "{ahead:?}");
        map.fuse();
        assert_eq!(map.units(), 1);
        let (w, h) = map.grid().size();
        assert!(
            w > 100 && h > 100,
            "{w}×{h} cells of 5 cm over a 10 × 8 m room"
        );
        let fov = &map.fields_of_view()[0];
        assert_eq!(fov.0, "a");
        assert!(
            (fov.2 - fov.1 - 270f64.to_radians()).abs() < 0.01,
            "{fov:?}"
        );
        let dir = tempfile::tempdir().unwrap();
        let files = map.save(dir.path(), "west").unwrap();
        assert_eq!(files, ["map.pgm", "map.yaml", "map.ply"]);
        assert!(!dir.path().join("poses.toml").exists());
        map.forget("a");
        map.fuse();
        assert_eq!(map.units(), 0);
    }
}
