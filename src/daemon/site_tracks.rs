//! People across zones, at the site daemon (no I/O): the zones' sightings (`zone_net`'s
//! `detections`) moved into the site frame and put back into stamp order across zones, for
//! the one tracker (`pipeline_track`) that follows everyone on the site. A person walking
//! from one zone into another is then one track with one id: the zones' sensors are simply
//! more sensors of one tracker.
//!
//! A zone not placed in the site frame contributes nothing (its people would be in the wrong
//! place), as a sensor not placed contributes nothing inside a zone.

use super::pipeline_track::Sightings;
use super::reorder::Reorder;
use crate::geometry::Pose2;

/// A zone more than this far (ns) behind the newest stamp holds nobody up: it stopped
/// sending, or its link stalls. Zones send every 0.1 s, so on a LAN each is within a few
/// tenths of the newest.
const HOLD_NS: u64 = 1_000_000_000;

/// A scan with more people than this is not a scan of people.
const MAX_PEOPLE: usize = 500;
/// A scan stamped further than this from when its batch was sent is not of that batch.
const MAX_AGE_NS: u64 = 5_000_000_000;
/// No site is wider than this (m).
const MAX_COORD_M: f64 = 100_000.0;

/// Checks a zone's batch sent at `sent_ns` (its clock) before anything of it is tracked:
/// stamps near when it was sent (a stamp far ahead would hold every other zone's back),
/// sensor ids, a person-sized number of people at sane coordinates. Why not, when not.
pub fn check(scans: &[Sightings], sent_ns: u64) -> Result<(), String> {
    for s in scans {
        if s.sensor.is_empty() || s.sensor.len() > 64 {
            return Err(format!("a scan names sensor {:?}", s.sensor));
        }
        if s.t_ns.abs_diff(sent_ns) > MAX_AGE_NS {
            return Err(format!(
                "{}'s scan is stamped {:.1} s from when the batch was sent",
                s.sensor,
                (s.t_ns as f64 - sent_ns as f64) * 1e-9
            ));
        }
        if s.people.len() > MAX_PEOPLE {
            return Err(format!(
                "{}'s scan lists {} people (at most {MAX_PEOPLE})",
                s.sensor,
                s.people.len()
            ));
        }
        if let Some(p) = s
            .people
            .iter()
            .find(|p| p.iter().any(|c| c.abs() > MAX_COORD_M))
        {
            return Err(format!("{}'s scan has a person at {p:?} m", s.sensor));
        }
    }
    Ok(())
}

/// The zones' sightings on their way to the tracker.
#[derive(Debug)]
pub struct CrossZone {
    reorder: Reorder<Sightings>,
}

impl Default for CrossZone {
    fn default() -> Self {
        CrossZone {
            reorder: Reorder::new(HOLD_NS),
        }
    }
}

impl CrossZone {
    /// Takes what zone `zone` sent, in its own frame; `site_from_zone` is where the zone
    /// stands in the site frame, `None` when it is not placed (or its clock cannot be
    /// trusted): then its sightings are dropped and it holds nobody up. Returns what may go
    /// to the tracker now, site frame, in stamp order across zones.
    pub fn take(
        &mut self,
        zone: &str,
        site_from_zone: Option<&Pose2>,
        scans: Vec<Sightings>,
    ) -> Vec<Sightings> {
        match site_from_zone {
            Some(pose) => {
                for mut s in scans {
                    for p in &mut s.people {
                        let q = pose * nalgebra::Point2::new(p[0], p[1]);
                        *p = [q.x, q.y];
                    }
                    self.reorder.push(zone, s.t_ns, s);
                }
            }
            None => self.reorder.forget(zone),
        }
        std::iter::from_fn(|| self.reorder.pop()).collect()
    }

    /// Zone `zone` is lost: it holds nobody up.
    pub fn lost(&mut self, zone: &str) {
        self.reorder.forget(zone);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;
    use crate::track::{TrackParams, Tracker};
    use std::collections::BTreeSet;

    /// One person walks east along y = 1 from x = 0 to 12 m at 1.2 m/s. Zone west's sensor
    /// sees x < 7, zone east's x > 5; east's frame is turned 90° and shifted from the site's.
    /// The zones send every 0.1 s, east a little later than west. Through `CrossZone` and
    /// the tracker the person is one track with one id from end to end, seen by west, then
    /// both, then east, where the site has them.
    #[test]
    fn a_person_walking_from_one_zone_into_another_keeps_one_id() {
        let site_from_east = pose2(20.0, -3.0, std::f64::consts::FRAC_PI_2);
        let east_from_site = site_from_east.inverse();
        let mut cross = CrossZone::default();
        let mut tracker = Tracker::new(TrackParams::default());
        let (step_ns, batch) = (25_000_000u64, 4);
        let mut ids = BTreeSet::new();
        let mut seen_by = Vec::new();
        let mut last = None;
        let at = |k: u64| 1.2 * (k * step_ns) as f64 * 1e-9;
        let sightings = |sensor: &str, k: u64, p: Option<[f64; 2]>| Sightings {
            sensor: sensor.into(),
            t_ns: 1_000_000_000_000 + k * step_ns,
            people: p.into_iter().collect(),
        };
        let scans = 400u64;
        for b in 0..scans / batch {
            let ks = b * batch..(b + 1) * batch;
            let west: Vec<Sightings> = ks
                .clone()
                .map(|k| sightings("w", k, (at(k) < 7.0).then_some([at(k), 1.0])))
                .collect();
            let east: Vec<Sightings> = ks
                .map(|k| {
                    let q = east_from_site * nalgebra::Point2::new(at(k), 1.0);
                    sightings("e", k, (at(k) > 5.0).then_some([q.x, q.y]))
                })
                .collect();
            let mut ready = cross.take("west", Some(&Pose2::identity()), west);
            ready.extend(cross.take("east", Some(&site_from_east), east));
            for s in ready {
                if let Some(tracks) = tracker.push_detections(&s.sensor, s.t_ns, &s.points()) {
                    assert!(tracks.tracks.len() <= 1, "{tracks:?}");
                    for t in &tracks.tracks {
                        ids.insert(t.id);
                        if seen_by.last() != Some(&t.sensors) {
                            seen_by.push(t.sensors.clone());
                        }
                        last = Some(t.clone());
                    }
                }
            }
        }
        assert_eq!(ids.len(), 1, "one id from end to end: {ids:?}");
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            seen_by,
            [names(&["w"]), names(&["e", "w"]), names(&["e"])],
            "seen by west, then both, then east"
        );
        let last = last.expect("a track");
        let end = at(scans - 1);
        assert!(
            (last.x_m - end).abs() < 0.1 && (last.y_m - 1.0).abs() < 0.05,
            "{last:?} against ({end:.2}, 1.00)"
        );
    }

    #[test]
    fn a_batch_that_cannot_be_people_is_refused_with_why() {
        let t = 1_000_000_000_000u64;
        let ok = Sightings {
            sensor: "w".into(),
            t_ns: t,
            people: vec![[1.0, 2.0]],
        };
        assert_eq!(check(std::slice::from_ref(&ok), t + 100_000_000), Ok(()));
        for (bad, says) in [
            (
                Sightings {
                    t_ns: t + 60_000_000_000,
                    ..ok.clone()
                },
                "stamped 60.0 s",
            ),
            (
                Sightings {
                    sensor: String::new(),
                    ..ok.clone()
                },
                "names sensor",
            ),
            (
                Sightings {
                    people: vec![[0.0, 0.0]; MAX_PEOPLE + 1],
                    ..ok.clone()
                },
                "501 people",
            ),
            (
                Sightings {
                    people: vec![[1e9, 0.0]],
                    ..ok.clone()
                },
                "a person at",
            ),
        ] {
            let why = check(&[ok.clone(), bad], t).unwrap_err();
            assert!(why.contains(says), "{why}");
        }
    }

    #[test]
    fn a_zone_not_placed_adds_no_one_and_holds_nobody_up() {
        let mut cross = CrossZone::default();
        let s = |t_ns: u64| Sightings {
            sensor: "w".into(),
            t_ns,
            people: vec![[1.0, 2.0]],
        };
        let east = |t_ns| Sightings {
            sensor: "e".into(),
            ..s(t_ns)
        };
        // East placed and behind: west waits for it.
        assert_eq!(
            cross
                .take("east", Some(&Pose2::identity()), vec![east(0)])
                .len(),
            1
        );
        assert!(
            cross
                .take("west", Some(&Pose2::identity()), vec![s(10)])
                .is_empty()
        );
        // East no longer placed: what it sends is dropped, and west goes on.
        assert!(
            cross
                .take("east", None, vec![east(20)])
                .iter()
                .all(|x| x.sensor == "w")
        );
        assert_eq!(
            cross
                .take("west", Some(&Pose2::identity()), vec![s(30)])
                .len(),
            1
        );
        // Moved into the site frame.
        let moved = cross.take("west", Some(&pose2(1.0, 0.0, 0.0)), vec![s(40)]);
        assert_eq!(moved[0].people, vec![[2.0, 2.0]]);
    }
}
