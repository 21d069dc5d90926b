//! The tracker task: posed scans in (a bounded queue that drops the oldest, off the scan
//! path: a slow tracker never stalls a sensor), `TRACKS` out on the people stream
//! ([`Publisher::people`]) at the fused rate. The core is [`crate::track`]; this is its thread.
//!
//! Across machines the same thread serves both ends: a zone daemon's also hands what each
//! scan saw ([`Sightings`]) to its Zenoh side, and the site daemon's takes the zones'
//! sightings, moved into the site frame, instead of scans: one tracker over every zone, so a
//! person walking from one zone into another keeps one id.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use crossbeam_channel::RecvTimeoutError;
use serde::{Deserialize, Serialize};

use super::pipeline::PosedScan;
use super::protocol::Message;
use super::queue::{DropOldestSender, drop_oldest};
use super::socket::Publisher;
use crate::track::{SensorScan, TrackParams, Tracker};

/// Items queued for the tracker at most: a quarter second of `sensors` at 40 Hz (of 8 at
/// least).
pub fn track_queue_len(sensors: usize) -> usize {
    sensors.max(8) * 10
}

/// The people one sensor's scan saw, as a zone sends them to the site daemon: one point per
/// person, in the zone's frame (the site frame once the site daemon has moved them).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sightings {
    pub sensor: String,
    /// The scan's stamp (UNIX ns, the zone's clock).
    pub t_ns: u64,
    /// Body centres `[x, y]` (m); empty when the sensor saw no one (it still looked).
    pub people: Vec<[f64; 2]>,
}

impl Sightings {
    /// The body centres as points, for the tracker.
    pub fn points(&self) -> Vec<nalgebra::Point2<f64>> {
        self.people
            .iter()
            .map(|&[x, y]| nalgebra::Point2::new(x, y))
            .collect()
    }
}

/// What the tracker takes.
#[derive(Debug, Clone)]
pub enum TrackIn {
    /// A scan of one of this daemon's placed sensors.
    Scan(PosedScan),
    /// What a sensor of another daemon (a zone's, at the site daemon) saw, site frame.
    Sighted(Sightings),
    /// A sensor's pose was withdrawn or replaced (found moved, placed again): what the
    /// tracker learnt of its view (its background) no longer holds, and its next posed scan
    /// starts it afresh.
    Forget(String),
}

/// The running tracker: stop it with [`TrackerTask::stop`]; dropped, it stops too (within
/// one queue poll) without being waited for.
pub struct TrackerTask {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for TrackerTask {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl TrackerTask {
    /// Starts the tracker thread; what is pushed into the returned queue is tracked and
    /// every fused step is published on `publisher`'s people stream. With `sightings`, what
    /// each scan saw goes there too (dropping the oldest when nobody takes it).
    pub fn start(
        publisher: Publisher,
        params: TrackParams,
        sightings: Option<DropOldestSender<Sightings>>,
        queue_len: usize,
    ) -> std::io::Result<(DropOldestSender<TrackIn>, TrackerTask)> {
        let (tx, rx) = drop_oldest::<TrackIn>(queue_len);
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("tracker".into())
            .spawn(move || {
                let mut tracker = Tracker::new(params);
                while !stopped.load(Ordering::Relaxed) {
                    let item = match rx.recv_timeout(Duration::from_millis(100)) {
                        Ok(p) => p,
                        Err(RecvTimeoutError::Timeout) => continue,
                        Err(RecvTimeoutError::Disconnected) => break,
                    };
                    let step = match item {
                        TrackIn::Scan(posed) => {
                            let step = tracker.push(SensorScan {
                                id: &posed.id,
                                scan: &posed.scan,
                                geometry: posed.geometry.as_ref(),
                                mount: posed.mount,
                                site_from_sensor: Some(posed.site_from_sensor.planar()),
                            });
                            if let (Some(out), Some(seen)) =
                                (&sightings, tracker.sightings(&posed.id))
                            {
                                let _ = out.push(Sightings {
                                    sensor: posed.id.clone(),
                                    t_ns: posed.scan.stamp_ns,
                                    people: seen.iter().map(|p| [p.x, p.y]).collect(),
                                });
                            }
                            step
                        }
                        TrackIn::Sighted(s) => {
                            tracker.push_detections(&s.sensor, s.t_ns, &s.points())
                        }
                        TrackIn::Forget(id) => {
                            tracker.forget_sensor(&id);
                            None
                        }
                    };
                    if let Some(tracks) = step {
                        publisher.people(Message::Tracks(tracks));
                    }
                }
            })?;
        Ok((
            tx,
            TrackerTask {
                stop,
                thread: Some(thread),
            },
        ))
    }

    /// Stops the thread and waits for it (at most one queue poll, 0.1 s).
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raycast::{polygon, scan_270};
    use crate::geometry::{Mount, Pose2, Pose3, pose2};
    use crate::scan::Scan;

    /// A 270° scan at 0.5° steps from the origin, facing +x, of a 10 × 8 m room with a 0.4 m
    /// square person at `(x, y)`.
    fn scan(x: f64, y: f64, t_ns: u64) -> Scan {
        let mut walls = polygon(&[(-1.0, -4.0), (9.0, -4.0), (9.0, 4.0), (-1.0, 4.0)]);
        walls.extend(polygon(&[
            (x - 0.2, y - 0.2),
            (x + 0.2, y - 0.2),
            (x + 0.2, y + 0.2),
            (x - 0.2, y + 0.2),
        ]));
        scan_270(&walls, &Pose2::identity(), 0.5, t_ns)
    }

    #[test]
    fn posed_scans_in_make_tracks_out_on_the_people_stream() {
        let publisher = Publisher::new(256);
        let mut people = publisher.subscribe_people();
        let (seen_tx, seen_rx) = drop_oldest::<Sightings>(1000);
        let (queue, task) = TrackerTask::start(
            publisher.clone(),
            TrackParams::default(),
            Some(seen_tx),
            track_queue_len(1),
        )
        .expect("starts");
        // The sensor stands at (2, 1) facing +y in the site frame.
        let site = Pose3::from_planar(&pose2(2.0, 1.0, std::f64::consts::FRAC_PI_2), 1.0, 0.0);
        for k in 0..60u64 {
            // First scan: the empty room (the background); then someone walks along +x.
            let s = if k == 0 {
                scan(20.0, 20.0, 0)
            } else {
                scan(2.0 + 0.03 * k as f64, 0.5, k * 25_000_000)
            };
            queue
                .push(TrackIn::Scan(PosedScan {
                    index: 0,
                    id: "a".into(),
                    scan: s,
                    geometry: None,
                    mount: Mount::default(),
                    site_from_sensor: site,
                }))
                .expect("the tracker takes scans");
        }
        // The last walker position in the sensor frame is (3.77, 0.5): site (1.5, 4.77).
        let mut last = None;
        let deadline = std::time::Instant::now() + Duration::from_secs(20);
        while std::time::Instant::now() < deadline {
            match people.try_recv() {
                Ok(m) => {
                    if let Message::Tracks(t) = &*m
                        && !t.tracks.is_empty()
                    {
                        last = Some(t.clone());
                        if t.t_ns >= 58 * 25_000_000 {
                            break;
                        }
                    }
                }
                Err(_) => std::thread::sleep(Duration::from_millis(10)),
            }
        }
        task.stop();
        let last = last.expect("a TRACKS message with a track");
        let t = &last.tracks[0];
        assert_eq!(last.tracks.len(), 1, "{last:?}");
        assert!(
            (t.x_m - 1.5).abs() < 0.15 && (t.y_m - 4.7).abs() < 0.2,
            "{last:?}"
        );
        assert_eq!(t.sensors, vec!["a".to_string()]);
        // What each scan saw went out too, for a zone's site daemon: the first scan (the
        // background) saw nobody, the last the walker where the track is.
        let seen: Vec<Sightings> = std::iter::from_fn(|| seen_rx.try_recv().ok()).collect();
        assert_eq!(seen.len(), 60, "one per scan");
        assert!(seen[0].people.is_empty() && seen[0].t_ns == 0);
        let last = seen.last().unwrap();
        assert_eq!((last.sensor.as_str(), last.t_ns), ("a", 59 * 25_000_000));
        assert!(
            matches!(last.people[..], [[x, y]] if (x - 1.5).abs() < 0.15 && (y - 4.77).abs() < 0.2),
            "{last:?}"
        );
    }
}
