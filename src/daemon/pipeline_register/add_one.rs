//! One sensor appearing on a placed site (or moved beyond local refinement) is placed against
//! its neighbours alone ([`add_sensor`]: work in proportion to them, not to the site), the
//! others' poses standing.
//! When that refuses, the site registration runs as before, so nothing it could place is lost.

use std::time::{Instant, SystemTime};

use super::{Method, Need, Outcome, Registrar};
use crate::daemon::pipeline::PoseEntry;
use crate::geometry::{Pose2, Pose3};
use crate::register::site::{SensorInput, add_sensor};

/// The sensor to add, and every input's site pose (None for it) and σ.
type Newcomer = (usize, Vec<Option<Pose2>>, Vec<[f64; 3]>);

impl Registrar {
    /// The one input to add to a placed site, when this registration is that: every other
    /// input placed, and it pending and not surveyed (the site solve weighs a survey). The
    /// anchor too, when units placed from the scans hold the site frame ([`Self::stand_in`]:
    /// it was knocked, or lost its pose before a restart). A moved sensor whose local
    /// refinement was refused is one too: the others' poses stand, and registering the whole
    /// site again for it took 15.6 s at 100 sensors (`cargo bench --bench moved_site`). The
    /// placed sensors' site poses are what [`add_sensor`] places against.
    fn newcomer(&self, inputs: &[SensorInput]) -> Option<Newcomer> {
        let anchor = inputs.iter().position(|s| s.id == self.anchor)?;
        let frame_held = self.stand_in(inputs, anchor).is_some();
        let mut newcomer = None;
        let (mut placed, mut sigma) = (Vec::new(), Vec::new());
        for (i, input) in inputs.iter().enumerate() {
            let t = self.tracks.get(&input.id)?;
            let pose = match (t.need, t.pose) {
                (Need::Nothing, Some(pose)) => Some(pose.planar()),
                (
                    Need::Pose {
                        refine_from: None, ..
                    },
                    _,
                ) if newcomer.is_none() && t.survey.is_none() && (i != anchor || frame_held) => {
                    newcomer = Some(i);
                    None
                }
                _ => return None,
            };
            placed.push(pose);
            sigma.push(t.sigma.unwrap_or([0.0; 3]));
        }
        Some((newcomer?, placed, sigma))
    }

    /// Places the newcomer, if there is one, against the placed inputs; None when there is
    /// none or adding refuses (said at debug level), for the site registration to try.
    pub(super) fn add_newcomer(
        &mut self,
        inputs: &[SensorInput],
        anchor: usize,
        now: SystemTime,
    ) -> Option<Outcome> {
        let (new, placed, sigma) = self.newcomer(inputs)?;
        let started = Instant::now();
        let added = add_sensor(
            inputs,
            &placed,
            &sigma,
            new,
            &self.params,
            &self.site_params,
        );
        let input = inputs.get(new)?;
        let took = format!(
            "{} pairs of {} placed sensors, {:.2} s",
            added.pairs.len(),
            added.placed,
            started.elapsed().as_secs_f64()
        );
        let at = match added.pose {
            Ok(at) => at,
            Err(why) => {
                tracing::debug!(
                    "adding {} to the placed site refused ({took}): {why}; registering the site",
                    input.id
                );
                return None;
            }
        };
        tracing::debug!("{} added to the placed site ({took})", input.id);
        let track = self.tracks.get_mut(&input.id)?;
        let Need::Pose { source, .. } = track.need else {
            return None;
        };
        // z and pitch as the site registration gives them: the mount's, pitch the anchor's.
        let anchor_pitch = inputs.get(anchor).map_or(0.0, |a| a.mount.pitch_rad);
        let [sigma_x, sigma_y, sigma_yaw] = added.sigma;
        let entry = PoseEntry {
            site_from_sensor: Pose3::from_planar(
                &at,
                input.mount.height_m.unwrap_or(0.0),
                input.mount.pitch_rad - anchor_pitch,
            ),
            sigma_x_m: Some(sigma_x),
            sigma_y_m: Some(sigma_y),
            sigma_yaw_rad: Some(sigma_yaw),
            source,
            loaded: false,
            caveat: added.caveat,
            evidence: added.evidence,
            updated: now,
        };
        track.take(&entry);
        Some(Outcome {
            id: input.id.clone(),
            pose: Ok(entry),
            method: Method::Added,
            local_refused: track.local_refused.take(),
            retry_in_s: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::Command;
    use super::super::walker_tests::simulate;
    use super::*;
    use crate::geometry::{pose_error, pose2};
    use crate::sim::plan::Plan;

    /// The lab, and 60 m east of it a closed room of its own with sensor `far`, which shares
    /// no view with the lab's.
    fn lab_and_far_room() -> Plan {
        let far = r#"
[[wall]]
points = [[80, 0], [92, 0], [92, 7], [87, 7], [87, 5], [80, 5]]
closed = true

[[box]]
center = [84, 1]
size = [1.5, 0.8]

[[sensor]]
id = "far"
model = "UTM-30LX-EW"
x = 82.0
y = 3.0
yaw_deg = -20
"#;
        let lab = include_str!("../../../fixtures/plans/lab.toml");
        Plan::from_toml(&format!("{lab}\n{far}"), "lab").expect("plan")
    }

    /// Site poses (the anchor `entrance`'s frame) from the plan's truth.
    fn truth(plan: &Plan, ids: &[&str]) -> Vec<Pose2> {
        let sim = crate::sim::Simulation::new(plan, 3).expect("simulates");
        let at = |id: &str| {
            let t = sim
                .sensors()
                .iter()
                .find(|s| s.id == id)
                .and_then(|s| s.truth)
                .expect("truth");
            pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
        };
        ids.iter()
            .map(|id| at("entrance").inverse() * at(id))
            .collect()
    }

    #[test]
    fn a_sensor_appearing_on_a_placed_site_is_added_at_its_truth_from_its_neighbours() {
        let plan = lab_and_far_room();
        let ids = ["entrance", "north", "east", "bench"];
        let site = truth(&plan, &ids);
        let sensors: Vec<(&str, Option<Pose2>)> = ids
            .iter()
            .zip(&site)
            .map(|(&id, &pose)| (id, (id != "bench").then_some(pose)))
            .collect();
        let (r, seen) = simulate(&plan, &sensors, 1.5);
        let [(_, bench)] = seen.outcomes.as_slice() else {
            panic!("one outcome, bench's: {:?}", seen.outcomes);
        };
        println!("bench placed in {:.2} s", seen.register_s[0]);
        assert_eq!((bench.id.as_str(), bench.method), ("bench", Method::Added));
        let entry = bench.pose.as_ref().expect("bench placed");
        let (dt, dyaw) = pose_error(&entry.site_from_sensor.planar(), &site[3]);
        assert!(
            dt < 0.05 && dyaw < 0.5f64.to_radians(),
            "{dt} m, {dyaw} rad"
        );
        assert_eq!(entry.site_from_sensor.z_m, 1.2, "its mount's height");
        // σ from its pairs, of the order of what it is off by; the walls placed it, on three
        // pairs: nothing to check but that people did not confirm it yet.
        let sigma = entry.sigma().expect("σ");
        println!(
            "bench off by {dt:.3} m, {:.2}°; σ {sigma:?}",
            dyaw.to_degrees()
        );
        assert!(sigma.iter().all(|&s| s > 0.0) && sigma[0] < 0.05 && sigma[1] < 0.05);
        assert!(entry.evidence.is_some_and(|e| e.contains("walls")));
        assert!(
            !entry
                .caveat
                .as_ref()
                .is_some_and(|c| c.contains("rests on"))
        );
        // It needs nothing more, and the others stand where they were.
        assert!(r.pending().is_empty());
        for (id, pose) in ids.iter().zip(&site).take(3) {
            let stands = r.tracks[*id].pose.map(|p| pose_error(&p.planar(), pose));
            assert!(
                stands.is_some_and(|(dt, dyaw)| dt < 1e-9 && dyaw < 1e-9),
                "{id}"
            );
        }
    }

    /// Only one pending sensor among placed ones is added: not a second, not a surveyed one; a
    /// moved one whose local refinement was refused is, and so is the anchor.
    #[test]
    fn only_a_lone_unsurveyed_newcomer_on_a_placed_site_is_added() {
        let model = crate::register::ScanModel::new(&[], 0.01, &Default::default());
        let inputs: Vec<SensorInput> = ["a", "b", "c"]
            .map(|id| SensorInput {
                id: id.into(),
                model: model.clone(),
                mount: Default::default(),
                prior: None,
            })
            .into();
        let registrar = |pending: &[&str]| {
            let mut r = Registrar::new("a", &Default::default());
            for id in ["a", "b", "c"] {
                let pose = (!pending.contains(&id))
                    .then(|| Pose3::from_planar(&Pose2::identity(), 0.0, 0.0));
                let (mount, survey) = (Default::default(), None);
                let sigma = Some([0.01, 0.02, 0.003]);
                let add = Command::Add {
                    id: id.into(),
                    mount,
                    survey,
                    pose,
                    sigma,
                };
                r.command(add, 0);
            }
            r
        };
        let chosen = |r: &Registrar| {
            r.newcomer(&inputs).map(|(new, placed, sigma)| {
                assert_eq!(placed.iter().filter(|p| p.is_none()).count(), 1);
                assert_eq!(
                    sigma[(new + 1) % 3],
                    [0.01, 0.02, 0.003],
                    "placed σ carried"
                );
                new
            })
        };
        assert_eq!(chosen(&registrar(&["c"])), Some(2));
        assert_eq!(chosen(&registrar(&["b", "c"])), None, "two pending");
        assert_eq!(chosen(&registrar(&["a"])), Some(0), "the anchor pending");
        // Units placed by hand do not hold the frame (their surveys are in it).
        let mut by_hand = registrar(&["a"]);
        for id in ["b", "c"] {
            by_hand.tracks.get_mut(id).expect("placed").survey =
                Some(crate::daemon::config::Survey {
                    x_m: 1.0,
                    y_m: 2.0,
                    yaw_rad: 0.3,
                    sigma_xy_m: 0.05,
                    sigma_yaw_rad: 0.02,
                });
        }
        assert_eq!(chosen(&by_hand), None, "the others placed by hand");
        assert_eq!(
            by_hand.stand_in(&inputs, 0),
            None,
            "the others placed by hand"
        );
        let mut surveyed = registrar(&["c"]);
        surveyed.tracks.get_mut("c").expect("c").survey = Some(crate::daemon::config::Survey {
            x_m: 1.0,
            y_m: 2.0,
            yaw_rad: 0.3,
            sigma_xy_m: 0.05,
            sigma_yaw_rad: 0.02,
        });
        assert_eq!(chosen(&surveyed), None, "surveyed");
        let mut moved = registrar(&["c"]);
        moved.tracks.get_mut("c").expect("c").local_refused = Some("too far".into());
        assert_eq!(chosen(&moved), Some(2), "moved, local refinement refused");
        // The anchor knocked (pending with the pose it had) is added; with another unit
        // pending too, the site solve stands in the first placed unit for it.
        let knocked = |also: &[&str]| {
            let mut r = registrar(also);
            let a = r.tracks.get_mut("a").expect("a");
            a.need = Need::Pose {
                since_ns: 0,
                source: crate::daemon::protocol::PoseSource::ReRegistered,
                refine_from: None,
            };
            r
        };
        assert_eq!(chosen(&knocked(&[])), Some(0), "the anchor knocked");
        assert_eq!(chosen(&knocked(&["c"])), None, "two pending");
        let b = Some((1, Pose3::from_planar(&Pose2::identity(), 0.0, 0.0)));
        assert_eq!(knocked(&["c"]).stand_in(&inputs, 0), b);
        assert_eq!(
            registrar(&["c"]).stand_in(&inputs, 0),
            None,
            "the anchor stands"
        );
        assert_eq!(
            registrar(&["a", "b", "c"]).stand_in(&inputs, 0),
            None,
            "none placed"
        );
    }

    /// Where a unit at `p` (plan frame) stands once knocked by `dx`, `dy`, `dyaw_deg`.
    fn knocked(p: &Pose2, (dx, dy, dyaw_deg): (f64, f64, f64)) -> Pose2 {
        let (x, y) = (p.translation.x + dx, p.translation.y + dy);
        pose2(x, y, p.rotation.angle() + dyaw_deg.to_radians())
    }

    /// The lab with its anchor, `bench`, knocked at 3 s by `knock` (and `north` by
    /// `north_knock` at the same moment, if given): found moved and placed again against the
    /// others, whose poses stand, in the frame where it stood (not at 0, 0, 0°, where its
    /// new view would put the site). Returns how bench was placed, and how far off.
    fn knock_the_anchor(
        knock: (f64, f64, f64),
        north_knock: Option<(f64, f64, f64)>,
    ) -> (Method, f64, f64) {
        let lab = include_str!("../../../fixtures/plans/lab.toml");
        let mv = |id: &str, (dx, dy, dyaw): (f64, f64, f64)| {
            format!(
                "[[move]]\nsensor = \"{id}\"\nat_s = 3.0\ndx = {dx:?}\ndy = {dy:?}\ndyaw_deg = {dyaw:?}\n"
            )
        };
        let moves = mv("bench", knock) + &north_knock.map(|k| mv("north", k)).unwrap_or_default();
        let plan = Plan::from_toml(&format!("{lab}\n{moves}"), "lab").expect("plan");
        let ids = ["bench", "entrance", "north", "east"];
        // In the plan's frame (the knocks are in it): the entrance's, carried by its truth.
        let world: Vec<Pose2> = {
            let sim = crate::sim::Simulation::new(&plan, 3).expect("simulates");
            let t = sim.sensors().iter().find(|s| s.id == "entrance");
            let e = t.and_then(|s| s.truth).expect("truth");
            let world_from_entrance = pose2(e.x_m, e.y_m, e.yaw_deg.to_radians());
            truth(&plan, &ids)
                .into_iter()
                .map(|p| world_from_entrance * p)
                .collect()
        };
        // The site frame: where bench stood.
        let site: Vec<Pose2> = world.iter().map(|p| world[0].inverse() * p).collect();
        let sensors: Vec<(&str, Option<Pose2>)> = ids
            .iter()
            .zip(&site)
            .map(|(&id, &p)| (id, Some(p)))
            .collect();
        let (r, seen) = simulate(&plan, &sensors, 7.0);
        let placed = |id: &str, now: Pose2| {
            let Some((t_s, o)) = seen.outcomes.iter().rev().find(|(_, o)| o.id == id) else {
                panic!("no outcome for {id}: {:?}", seen.outcomes);
            };
            let entry = o.pose.as_ref().expect("placed again");
            let (dt, dyaw) = pose_error(&entry.site_from_sensor.planar(), &now);
            println!(
                "{id} knocked: placed again ({:?}) at {t_s:.1} s, {:.1} cm / {:.2}° from the truth",
                o.method,
                dt * 100.0,
                dyaw.to_degrees()
            );
            (o.method, dt, dyaw)
        };
        let now = |i: usize, k| world[0].inverse() * knocked(&world[i], k);
        if let Some(k) = north_knock {
            let (_, dt, dyaw) = placed("north", now(2, k));
            assert!(
                dt < 0.05 && dyaw < 0.5f64.to_radians(),
                "north {dt} m, {dyaw} rad"
            );
        }
        for (id, pose) in ids.iter().zip(&site).skip(1) {
            if north_knock.is_some() && *id == "north" {
                continue;
            }
            let stands = r.tracks[*id].pose.map(|p| pose_error(&p.planar(), pose));
            assert!(
                stands.is_some_and(|(dt, dyaw)| dt < 1e-9 && dyaw < 1e-9),
                "{id} moved"
            );
        }
        placed("bench", now(0, knock))
    }

    #[test]
    fn a_knocked_anchor_is_placed_again_where_it_now_stands_in_the_frame_it_held() {
        // Refined locally; beyond that, added against the others; with another unit knocked
        // too, by the site solve from a placed unit standing in for it.
        for (knock, north_knock, method) in [
            ((0.3, -0.4, 10.0), None, Method::Local),
            ((1.2, 0.9, -25.0), None, Method::Added),
            ((1.2, 0.9, -25.0), Some((-1.0, 0.8, 20.0)), Method::Global),
        ] {
            let (how, dt, dyaw) = knock_the_anchor(knock, north_knock);
            assert_eq!(how, method, "{knock:?}");
            assert!(
                dt < 0.05 && dyaw < 0.5f64.to_radians(),
                "{knock:?}: {dt} m, {dyaw} rad"
            );
        }
    }

    #[test]
    fn a_sensor_adding_refuses_goes_to_the_site_registration() {
        let plan = lab_and_far_room();
        let ids = ["entrance", "north", "far"];
        let site = truth(&plan, &ids);
        let sensors = [
            ("entrance", Some(site[0])),
            ("north", Some(site[1])),
            ("far", None),
        ];
        let (_, seen) = simulate(&plan, &sensors, 1.5);
        let [(_, far)] = seen.outcomes.as_slice() else {
            panic!("one outcome, far's: {:?}", seen.outcomes);
        };
        // Refused by adding, then by the site registration, which says why.
        assert_eq!((far.id.as_str(), far.method), ("far", Method::Global));
        let why = far.pose.as_ref().expect_err("far shares no view");
        assert!(why.contains("survey it"), "{why}");
    }
}
