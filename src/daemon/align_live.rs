//! The live site aligned to the building drawing (`[site] drawing`): once the placed sensors
//! have settled, their latest scans are aligned to the drawing as `scanfuse align` aligns a
//! recording's (`drawing::align`: from `[site] drawing_pairs` when given, else automatically),
//! and `building_from_site` is set, announced and saved (an abstention is shown with its
//! reason, not saved). Tried again whenever the set of
//! placed sensors changes, until it is aligned; an alignment loaded from `poses.toml` or found
//! once stays (the building's frame does not jump under zones and lines drawn in it).

use std::sync::Arc;
use std::time::Duration;

use super::pipeline::{Pipeline, PosedScan};
use super::protocol::EventKind;
use crate::drawing::align::{AlignSensor, PointPair, align};
use crate::drawing::{BuildingFromSite, Drawing};
use crate::register::{RegisterParams, ScanModel};

/// How often the placed sensors are looked at.
const TICK: Duration = Duration::from_secs(1);

/// When to try: the placed sensors unchanged for `settle` looks in a row, and not the set
/// last tried.
#[derive(Debug, Default)]
pub struct Trigger {
    seen: Vec<String>,
    looks: u32,
    tried: Option<Vec<String>>,
}

impl Trigger {
    /// `placed` (sorted ids) now; whether to align them. Alone, the anchor is enough only
    /// with point pairs (`alone_ok`): one unit's view of a building is rarely unique.
    pub fn due(&mut self, placed: Vec<String>, settle: u32, alone_ok: bool) -> bool {
        if placed == self.seen {
            self.looks += 1;
        } else {
            self.seen = placed;
            self.looks = 1;
        }
        let enough = self.seen.len() >= 2 || (alone_ok && !self.seen.is_empty());
        let due = enough && self.looks >= settle && self.tried.as_ref() != Some(&self.seen);
        if due {
            self.tried = Some(self.seen.clone());
        }
        due
    }
}

/// Aligns the posed sensors' latest scans to `drawing`.
pub fn align_scans(
    drawing: &Drawing,
    scans: &[PosedScan],
    pairs: &[PointPair],
    p: &RegisterParams,
) -> BuildingFromSite {
    let models: Vec<ScanModel> = scans
        .iter()
        .map(|s| ScanModel::from_scan(&s.scan, s.geometry.as_ref(), &s.mount, p))
        .collect();
    let sensors: Vec<AlignSensor<'_>> = scans
        .iter()
        .zip(&models)
        .map(|(s, model)| AlignSensor {
            id: &s.id,
            model,
            site_from_sensor: s.site_from_sensor.planar(),
        })
        .collect();
    BuildingFromSite::from_alignment(&align(drawing, &sensors, pairs, false, p))
}

/// Runs until `stop` resolves: aligns the site to its drawing (as it stands: a reload may set,
/// change or remove it) whenever that is due.
pub async fn run(pipeline: Arc<Pipeline>, stop: impl std::future::Future<Output = ()>) {
    let mut trigger = Trigger::default();
    let mut tried_on: Option<Arc<Drawing>> = None;
    let mut tick = tokio::time::interval(TICK);
    tokio::pin!(stop);
    loop {
        tokio::select! {
            _ = &mut stop => return,
            _ = tick.tick() => {}
        }
        let aligned = pipeline.building_from_site().is_some_and(|b| b.aligned);
        let Some(drawing) = pipeline.drawing().filter(|_| !aligned) else {
            continue;
        };
        // Another drawing: the placed sensors are worth a try again.
        if !tried_on.as_ref().is_some_and(|d| Arc::ptr_eq(d, &drawing)) {
            trigger = Trigger::default();
            tried_on = Some(Arc::clone(&drawing));
        }
        let pairs = pipeline.drawing_pairs();
        let scans = pipeline.posed_scans();
        let mut placed: Vec<String> = scans.iter().map(|s| s.id.clone()).collect();
        placed.sort();
        if !trigger.due(placed, 3, !pairs.is_empty()) {
            continue;
        }
        let on = Arc::clone(&drawing);
        let found = tokio::task::spawn_blocking(move || {
            align_scans(&on, &scans, &pairs, &RegisterParams::default())
        })
        .await;
        // A reload may have changed the drawing while this one was aligned to.
        let current = pipeline.drawing();
        if !current.is_some_and(|d| Arc::ptr_eq(&d, &drawing)) {
            continue;
        }
        match found {
            Ok(b) => publish(&pipeline, b),
            Err(e) => tracing::warn!("aligning to the drawing failed: {e}"),
        }
    }
}

/// Announces the alignment (or why there is none), shows it on the socket and saves it.
pub(super) fn publish(pipeline: &Pipeline, b: BuildingFromSite) {
    let source = pipeline
        .drawing()
        .map_or_else(String::new, |d| d.source.clone());
    if b.aligned {
        let sigma = match (b.sigma_x_m, b.sigma_y_m, b.sigma_yaw_deg) {
            (Some(x), Some(y), Some(yaw)) => {
                format!(", σ {:.1} / {:.1} cm, {yaw:.2}°", x * 100.0, y * 100.0)
            }
            _ => String::new(),
        };
        pipeline.announce(
            EventKind::Aligned,
            None,
            format!(
                "aligned to the drawing {source}: building_from_site x {:.3} m, y {:.3} m, yaw {:.2}° ({}{sigma})",
                b.x_m, b.y_m, b.yaw_deg, b.method
            ),
        );
    } else {
        pipeline.announce(
            EventKind::Error,
            None,
            format!(
                "not aligned to the drawing {source} yet ({}): {}; tried again when another sensor is placed, or give [site] drawing_pairs = \"site_x,site_y=drawing_x,drawing_y; …\" (two or more)",
                b.method,
                b.reason.as_deref().unwrap_or("no reason given")
            ),
        );
    }
    let aligned = b.aligned;
    pipeline.set_building_from_site(Some(b));
    // Saved with the poses (and the map files in the building's frame), under the one lock
    // every save takes: a save racing this one cannot write the file without it.
    if aligned && let Err(e) = pipeline.save_now() {
        pipeline.announce(EventKind::Error, None, format!("cannot save poses: {e}"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn the_trigger_waits_for_the_placed_set_to_settle_and_tries_each_set_once() {
        let mut t = Trigger::default();
        // The anchor alone is no building without point pairs.
        assert!(!t.due(ids(&["a"]), 1, false));
        assert!(!t.due(ids(&["a", "b"]), 2, false));
        assert!(t.due(ids(&["a", "b"]), 2, false));
        assert!(
            !t.due(ids(&["a", "b"]), 2, false),
            "the same set is tried once"
        );
        assert!(!t.due(ids(&["a", "b", "c"]), 2, false));
        assert!(
            t.due(ids(&["a", "b", "c"]), 2, false),
            "a new sensor: again"
        );
        let mut t = Trigger::default();
        assert!(
            t.due(ids(&["a"]), 1, true),
            "with pairs the anchor is enough"
        );
    }
}
