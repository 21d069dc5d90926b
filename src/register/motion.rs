//! People as evidence. A site's scanners look at the same floor at the same time, so wherever
//! one sees someone walk, another that looks at that spot at that moment sees them too, or has
//! its view blocked before it. A pose under which one sensor's walkers stand where the other
//! saw straight through at that moment is refuted: the look-alike office next door, the
//! corridor turned end for end, which walls alone cannot tell from the truth. Nothing moving,
//! nothing shared, or no common time: no evidence either way.

use super::model::ScanPlane;
use crate::geometry::{Mount, Pose2, ProjectParams, ScanPoint, beam_angles_rad, project_scan};
use crate::scan::{Scan, ScanGeometry};
use crate::track::detect;
use nalgebra::Point2;

/// One tick both tracks saw walkers at: seconds since the first frame, and each sensor's
/// walker centres in its own frame.
pub type SharedTick = (f64, Vec<Point2<f64>>, Vec<Point2<f64>>);

/// How far a walker goes between two kept frames (0.1 s apart) at most (m).
const STRIDE_M: f64 = 0.3;
/// Where a still beam got nothing back, its free space is taken to reach this far (m): the
/// longest range of the units scanfuse drives.
const OPEN_M: f64 = 30.0;

/// Of the walker centres of the frame before, the one nearest `c` within a stride: where the
/// walker at `c` stood then.
fn one_stride_before<'a>(then: &'a [Point2<f64>], c: &Point2<f64>) -> Option<&'a Point2<f64>> {
    then.iter()
        .map(|q| (q, (c - q).norm()))
        .filter(|(_, d)| *d <= STRIDE_M)
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .map(|(q, _)| q)
}

/// Thresholds of the motion check.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionParams {
    /// A return this much (plus `margin_frac` of its range) short of the still view is
    /// something that walked in; a spot the other sensor saw within the same margin is seen,
    /// and beyond it, seen through (m). People are about 0.5 m across.
    pub moved_m: f64,
    pub margin_frac: f64,
    /// One frame is kept per tick of the common clock (s), the scan nearest the tick, so two
    /// sensors' frames of one tick are at most a scan period apart; at most `max_frames`.
    pub tick_s: f64,
    pub max_frames: usize,
    /// Frames of one tick further apart than this are not compared (s): a walker moves
    /// ~0.1 m in 0.06 s.
    pub max_skew_s: f64,
    /// A walker: neighbouring moved returns no further apart than `gap_m`, at least
    /// `min_points` of them, no wider than `max_width_m` (a door swinging is wider).
    pub gap_m: f64,
    pub min_points: usize,
    pub max_width_m: f64,
    /// Heights a standing person blocks (m): a beam that crosses the spot above or below them
    /// may pass.
    pub body_z_m: [f64; 2],
    /// A walker counts as seen when this share of its returns the other sensor could look at
    /// is seen; as seen through when this share is seen through.
    pub seen_share: f64,
    pub through_share: f64,
    /// A pose is refuted by at least `refute_min` walkers seen through, more than
    /// `refute_ratio` times the walkers both saw.
    pub refute_min: usize,
    pub refute_ratio: f64,
    /// Once both sensors have watched together this long (s), a pose needs at least one walker
    /// both saw; over a shorter common stretch walkers only refute. Over eval's simulated pairs
    /// (10 s, seeds 1–6, both plan sets) every confident-wrong pose but one had no walker to
    /// check, against 218 of 1854 right ones.
    pub confirm_after_s: f64,
    /// People confirm a pose, so that a rival they never saw at is no rival, once this many
    /// walkers both sensors saw stand there (and at most `WalkerParams::max_through_share`
    /// of them are seen through).
    pub settle_min_seen: usize,
}

impl Default for MotionParams {
    fn default() -> Self {
        MotionParams {
            moved_m: 0.3,
            margin_frac: 0.03,
            tick_s: 0.1,
            max_frames: 300,
            max_skew_s: 0.06,
            gap_m: 0.3,
            min_points: 3,
            max_width_m: 1.2,
            body_z_m: [0.1, 1.6],
            seen_share: 0.3,
            through_share: 0.75,
            refute_min: 4,
            refute_ratio: 0.5,
            confirm_after_s: 5.0,
            settle_min_seen: 10,
        }
    }
}

impl MotionParams {
    /// The walker detector's thresholds.
    pub fn blob(&self) -> detect::BlobParams {
        detect::BlobParams {
            moved_m: self.moved_m,
            margin_frac: self.margin_frac,
            gap_m: self.gap_m,
            min_points: self.min_points,
            max_width_m: self.max_width_m,
            far_body_m: 0.0,
        }
    }
}

/// What a sensor saw over time: per kept frame its horizontal ranges and the walkers in it.
#[derive(Debug, Clone)]
pub struct MotionTrack {
    frames: Vec<Frame>,
    /// Horizontal range per beam of the still view (m); NaN where nothing came back.
    still_m: Vec<f32>,
    first_rad: f64,
    step_rad: f64,
    beams: usize,
    cos_pitch: f64,
    plane: Option<ScanPlane>,
}

#[derive(Debug, Clone)]
struct Frame {
    tick: i64,
    t_ns: u64,
    /// Horizontal range per beam (m); NaN where nothing usable came back.
    ranges_m: Vec<f32>,
    /// Returns of each walker, sensor frame.
    walkers: Vec<Vec<Point2<f64>>>,
}

/// Walkers one sensor saw that the other, at the same moment, saw too, or saw through.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MotionEvidence {
    pub seen: usize,
    pub seen_through: usize,
}

impl MotionEvidence {
    pub fn refutes(&self, p: &MotionParams) -> bool {
        self.seen_through >= p.refute_min
            && self.seen_through as f64 > p.refute_ratio * self.seen as f64
    }

    /// Enough walkers both saw here (`MotionParams::settle_min_seen`), few of them seen
    /// through (`WalkerParams::max_through_share`), to confirm the pose.
    pub fn confirms(&self, p: &super::RegisterParams) -> bool {
        self.seen >= p.motion.settle_min_seen
            && self.seen_through as f64 <= p.walkers.max_through_share * self.seen as f64
    }
}

enum Look {
    Seen,
    Through,
    Nothing,
}

impl MotionTrack {
    /// The walkers in `scans` (stamp order) against `still`, the sensor's static view. `None`
    /// when the scans do not share the still view's beam layout.
    pub fn new(
        scans: &[Scan],
        still: &Scan,
        geometry: Option<&ScanGeometry>,
        mount: &Mount,
        project: &ProjectParams,
        p: &MotionParams,
    ) -> Option<MotionTrack> {
        let angles = beam_angles_rad(still, geometry);
        let beams = angles.len();
        let (&first_rad, &last_rad) = (angles.first()?, angles.last()?);
        if beams < 2 {
            return None;
        }
        let horizontal = |points: &[ScanPoint]| {
            let mut ranges = vec![f32::NAN; beams];
            for sp in points {
                if let Some(r) = ranges.get_mut(sp.beam) {
                    *r = sp.p.coords.norm() as f32;
                }
            }
            ranges
        };
        let still_m = horizontal(&project_scan(still, geometry, mount, project));
        let tick_ns = (p.tick_s * 1e9).max(1.0);
        let mut frames: Vec<Frame> = Vec::new();
        for scan in scans.iter().filter(|s| s.ranges_m.len() == beams) {
            let tick = (scan.stamp_ns as f64 / tick_ns).round() as i64;
            let off = |t: u64| (t as f64 - tick as f64 * tick_ns).abs();
            match frames.last() {
                Some(f) if f.tick == tick && off(f.t_ns) <= off(scan.stamp_ns) => continue,
                Some(f) if f.tick == tick => {
                    frames.pop();
                }
                _ if frames.len() >= p.max_frames => break,
                _ => {}
            }
            let points = project_scan(scan, geometry, mount, project);
            let ranges_m = horizontal(&points);
            let walkers = walkers(&points, &ranges_m, &still_m, p);
            frames.push(Frame {
                tick,
                t_ns: scan.stamp_ns,
                ranges_m,
                walkers,
            });
        }
        Some(MotionTrack {
            frames,
            still_m,
            first_rad,
            step_rad: (last_rad - first_rad) / (beams - 1) as f64,
            beams,
            cos_pitch: mount.pitch_rad.cos().max(1e-3),
            plane: ScanPlane::of(mount),
        })
    }

    /// The same track read on another clock: every stamp moved by `dt_s`, frames given the
    /// tick of their new stamp (one per tick; a frame landing on a tick already taken goes).
    pub fn shifted(&self, dt_s: f64, p: &MotionParams) -> MotionTrack {
        let tick_ns = (p.tick_s * 1e9).max(1.0);
        let mut out = self.clone();
        out.frames.clear();
        for f in &self.frames {
            let t_ns = (f.t_ns as f64 + dt_s * 1e9).max(0.0);
            let tick = (t_ns / tick_ns).round() as i64;
            if out.frames.last().is_some_and(|g| g.tick >= tick) {
                continue;
            }
            out.frames.push(Frame {
                tick,
                t_ns: t_ns as u64,
                ..f.clone()
            });
        }
        out
    }

    /// Whether its plane cuts people across the torso ([`detect::cuts_torsos`]). Not with the
    /// mount unknown.
    pub fn sees_torsos(&self) -> bool {
        self.plane
            .is_some_and(|p| detect::cuts_torsos(p.height_m, p.slope.atan()))
    }

    /// How wide its walkers looked against the way they walked ([`detect::Silhouette`]):
    /// each walker of a frame that, one frame before, stood within a stride of where it is,
    /// and has moved at least [`detect::WALKING_M_S`] since (a heading to measure against).
    pub fn silhouettes(&self) -> Vec<detect::Silhouette> {
        let centre = |w: &Vec<Point2<f64>>| detect::centre(w, detect::Body::Round);
        let mut out = Vec::new();
        for pair in self.frames.windows(2) {
            let [before, now] = pair else { continue };
            let dt_s = (now.t_ns as f64 - before.t_ns as f64) * 1e-9;
            if now.tick != before.tick + 1 || dt_s <= 1e-3 {
                continue;
            }
            let then: Vec<Point2<f64>> = before.walkers.iter().filter_map(centre).collect();
            for w in &now.walkers {
                let Some(c) = centre(w) else { continue };
                let Some(q) = one_stride_before(&then, &c) else {
                    continue;
                };
                let step = c - q;
                if step.norm() < detect::WALKING_M_S * dt_s {
                    continue;
                }
                out.extend(detect::silhouette(w, &c, &step));
            }
        }
        out
    }

    /// Walkers seen over the whole track.
    pub fn walkers(&self) -> usize {
        self.frames.iter().map(|f| f.walkers.len()).sum()
    }

    /// How long both tracks watched at the same time (s).
    pub fn watched_with(&self, other: &MotionTrack) -> f64 {
        let span = |t: &MotionTrack| Some((t.frames.first()?.t_ns, t.frames.last()?.t_ns));
        match (span(self), span(other)) {
            (Some((a0, a1)), Some((b0, b1))) => a1.min(b1).saturating_sub(a0.max(b0)) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// For each tick at which both tracks saw walkers: the time (s since this track's first
    /// frame) and the walkers' centres in each sensor's frame, each blob taken as the near
    /// side of `body` (`detect::centre`). Without a previous frame to carry the other's
    /// walkers to this one's time, frames further apart than `max_skew_s` are not paired.
    pub fn centres_with(
        &self,
        other: &MotionTrack,
        max_skew_s: f64,
        body: detect::Body,
    ) -> Vec<SharedTick> {
        let centres = |f: &Frame| -> Vec<Point2<f64>> {
            f.walkers
                .iter()
                .filter_map(|w| detect::centre(w, body))
                .collect()
        };
        // The other's walkers moved between its scan and this one's: carried forward along the
        // velocity from its previous frame (the nearest walker there within a stride), so that
        // sensors with scans far apart in time can still be paired.
        let carried = |k: usize, to_ns: u64| -> Option<Vec<Point2<f64>>> {
            let g = other.frames.get(k)?;
            let now = centres(g);
            let dt_s = (to_ns as f64 - g.t_ns as f64) * 1e-9;
            let before = k
                .checked_sub(1)
                .and_then(|j| other.frames.get(j))
                .filter(|h| h.tick + 1 == g.tick);
            let Some(h) = before else {
                return (dt_s.abs() <= max_skew_s).then_some(now);
            };
            let span_s = (g.t_ns as f64 - h.t_ns as f64) * 1e-9;
            let then = centres(h);
            Some(
                now.iter()
                    .map(|c| match one_stride_before(&then, c) {
                        Some(q) if span_s > 1e-3 => c + (c - q) * (dt_s / span_s),
                        _ => *c,
                    })
                    .collect(),
            )
        };
        let t0 = self.frames.first().map_or(0, |f| f.t_ns);
        self.frames
            .iter()
            .filter(|f| !f.walkers.is_empty())
            .filter_map(|f| {
                let k = other
                    .frames
                    .binary_search_by_key(&f.tick, |g| g.tick)
                    .ok()?;
                let g = other.frames.get(k)?;
                if g.walkers.is_empty() {
                    return None;
                }
                Some((
                    f.t_ns.saturating_sub(t0) as f64 * 1e-9,
                    centres(f),
                    carried(k, f.t_ns)?,
                ))
            })
            .collect()
    }

    /// Whether the two still views' free space (up to each beam's still return, or [`OPEN_M`]
    /// where nothing came back) can hold a common spot under `self_from_other`. Where it cannot,
    /// [`co_motion`] finds nothing: a walker lies in its own sensor's free space, and the other
    /// sees it, or sees through it, only in its own. Sampled every ~2° and 1 m along the other's
    /// beams, so a sliver of shared view can be missed. The daemon's walker check weighs only
    /// the pairs whose views meet (issue 20: 100 sensors are 4950 pairs, most of them apart).
    pub fn views_meet(&self, other: &MotionTrack, self_from_other: &Pose2) -> bool {
        if self_from_other.translation.vector.norm() > self.reach_m() + other.reach_m() {
            return false;
        }
        let every = ((2f64.to_radians() / other.step_rad.abs().max(1e-6)) as usize).max(1);
        (0..other.beams).step_by(every).any(|k| {
            let theta = other.first_rad + k as f64 * other.step_rad;
            let dir = nalgebra::Vector2::new(theta.cos() * other.cos_pitch, theta.sin());
            let dir = dir / dir.norm().max(1e-9);
            let still = other.still_m[k];
            let free = if still.is_nan() {
                OPEN_M
            } else {
                f64::from(still)
            };
            (1..=free as usize)
                .any(|d| self.free_at(&(self_from_other * Point2::from(dir * d as f64))))
        })
    }

    /// Farthest the still view's free space reaches (m).
    fn reach_m(&self) -> f64 {
        self.still_m.iter().fold(0.0, |far, &r| {
            far.max(if r.is_nan() { OPEN_M } else { f64::from(r) })
        })
    }

    /// Whether `q` (this sensor's frame) lies in the still view's free space.
    fn free_at(&self, q: &Point2<f64>) -> bool {
        let theta = q.y.atan2(q.x / self.cos_pitch);
        let k = ((theta - self.first_rad) / self.step_rad).round();
        if !(0.0..self.beams as f64).contains(&k) {
            return false;
        }
        let d = q.coords.norm();
        match self.still_m[k as usize] {
            r if r.is_nan() => d <= OPEN_M,
            r => f64::from(r) > d,
        }
    }

    fn frame_at(&self, tick: i64, t_ns: u64, p: &MotionParams) -> Option<&Frame> {
        let k = self.frames.binary_search_by_key(&tick, |f| f.tick).ok()?;
        let f = self.frames.get(k)?;
        let skew_s = f.t_ns.abs_diff(t_ns) as f64 * 1e-9;
        (skew_s <= p.max_skew_s).then_some(f)
    }

    /// What this sensor saw at `q` (its frame) in `frame`.
    fn look(&self, frame: &Frame, q: &Point2<f64>, p: &MotionParams) -> Look {
        if let Some(plane) = &self.plane {
            let z = plane.z_at(q);
            if z < p.body_z_m[0] || z > p.body_z_m[1] {
                return Look::Nothing;
            }
        }
        // A tilted beam at angle θ lands at (d cosθ cosφ, d sinθ).
        let theta = q.y.atan2(q.x / self.cos_pitch);
        let k = ((theta - self.first_rad) / self.step_rad).round();
        if !(1.0..(self.beams - 1) as f64).contains(&k) {
            return Look::Nothing;
        }
        let k = k as usize;
        let d = q.coords.norm();
        let margin = p.moved_m + p.margin_frac * d;
        let beyond = |r: f32| r as f64 > d + margin;
        let now = |i: usize| frame.ranges_m.get(i).copied().unwrap_or(f32::NAN);
        let still = |i: usize| self.still_m.get(i).copied().unwrap_or(f32::NAN);
        // Seen: something is at the spot now where the still view sees past it (a walker
        // beside a wall cannot be told from the wall).
        let seen = (k - 1..=k + 1).any(|i| {
            let (r, s) = (now(i), still(i));
            (r as f64 - d).abs() <= margin && (s.is_nan() || beyond(s))
        });
        if seen {
            Look::Seen
        } else if (k - 1..=k + 1).all(|i| beyond(now(i))) {
            Look::Through
        } else {
            Look::Nothing
        }
    }
}

/// Runs of moved returns among a scan's `points` (its horizontal `ranges_m` per beam), each
/// one walker: the shared detector of [`crate::track::detect`].
fn walkers(
    points: &[ScanPoint],
    ranges_m: &[f32],
    still_m: &[f32],
    p: &MotionParams,
) -> Vec<Vec<Point2<f64>>> {
    detect::blobs(points, ranges_m, still_m, &p.blob())
}

/// Walkers each sensor saw, checked in the other's frame at the same tick, under `a_from_b`.
pub fn co_motion(
    a: &MotionTrack,
    b: &MotionTrack,
    a_from_b: &Pose2,
    p: &MotionParams,
) -> MotionEvidence {
    let mut e = MotionEvidence::default();
    tally(a, b, &a_from_b.inverse(), p, &mut e);
    tally(b, a, a_from_b, p, &mut e);
    e
}

fn tally(
    from: &MotionTrack,
    into: &MotionTrack,
    into_from_from: &Pose2,
    p: &MotionParams,
    e: &mut MotionEvidence,
) {
    for f in from.frames.iter().filter(|f| !f.walkers.is_empty()) {
        let Some(g) = into.frame_at(f.tick, f.t_ns, p) else {
            continue;
        };
        for w in &f.walkers {
            let (mut seen, mut through) = (0usize, 0usize);
            for q in w {
                match into.look(g, &(into_from_from * q), p) {
                    Look::Seen => seen += 1,
                    Look::Through => through += 1,
                    Look::Nothing => {}
                }
            }
            let looked = seen + through;
            if looked < p.min_points {
                continue;
            }
            if seen as f64 >= p.seen_share * looked as f64 {
                e.seen += 1;
            } else if through as f64 >= p.through_share * looked as f64 {
                e.seen_through += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose2;
    use crate::geometry::raycast::{Wall, polygon, scan_270};

    /// A 270° scan at 0.5° steps of `walls` from `site_from_sensor`, stamped `t_ns`.
    fn scan(walls: &[Wall], site_from_sensor: &Pose2, t_ns: u64) -> Scan {
        scan_270(walls, site_from_sensor, 0.5, t_ns)
    }

    /// Each sensor's track over 3 s at 40 Hz while a 0.4 m person walks from `from` to `to`.
    fn tracks(walls: &[Wall], poses: &[Pose2], from: [f64; 2], to: [f64; 2]) -> Vec<MotionTrack> {
        let p = MotionParams::default();
        let frames = 120u64;
        poses
            .iter()
            .map(|pose| {
                let scans: Vec<Scan> = (0..frames)
                    .map(|k| {
                        let s = k as f64 / (frames - 1) as f64;
                        let (x, y) = (
                            from[0] + s * (to[0] - from[0]),
                            from[1] + s * (to[1] - from[1]),
                        );
                        let mut seen = walls.to_vec();
                        seen.extend(polygon(&[
                            (x - 0.2, y - 0.2),
                            (x + 0.2, y - 0.2),
                            (x + 0.2, y + 0.2),
                            (x - 0.2, y + 0.2),
                        ]));
                        scan(&seen, pose, k * 25_000_000)
                    })
                    .collect();
                let still = scan(walls, pose, 0);
                let (mount, project) = (Mount::default(), ProjectParams::default());
                MotionTrack::new(&scans, &still, None, &mount, &project, &p).expect("a track")
            })
            .collect()
    }

    #[test]
    fn a_walker_seen_in_one_room_refutes_the_look_alike_room_next_door() {
        // Two identical 6 × 4 m rooms side by side; a and b stand at the same spot in each.
        let mut walls = polygon(&[(0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0)]);
        walls.extend(polygon(&[(6.0, 0.0), (12.0, 0.0), (12.0, 4.0), (6.0, 4.0)]));
        let poses = [pose2(1.0, 1.0, 0.5), pose2(7.0, 1.0, 0.5)];
        let t = tracks(&walls, &poses, [2.0, 3.0], [5.0, 2.0]);
        let p = MotionParams::default();
        // One frame per 0.1 s tick is kept: 30 over the walk.
        assert!(
            t[0].walkers() >= 25 && t[1].walkers() == 0,
            "{} {}",
            t[0].walkers(),
            t[1].walkers()
        );
        // The walls cannot tell b from a sensor at a's own spot; the walker can: b saw its room
        // empty where a's walker would stand.
        let look_alike = co_motion(&t[0], &t[1], &Pose2::identity(), &p);
        assert!(
            look_alike.refutes(&p) && look_alike.seen == 0,
            "{look_alike:?}"
        );
        // At the truth the wall hides the walker from b: no evidence either way.
        let truth = poses[0].inverse() * poses[1];
        let at_truth = co_motion(&t[0], &t[1], &truth, &p);
        assert_eq!(at_truth, MotionEvidence::default());
    }

    #[test]
    fn views_meet_in_one_room_and_not_across_a_wall_or_far_apart() {
        // Two 6 × 4 m rooms side by side, closed between them; a third far down a corridor.
        let mut walls = polygon(&[(0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0)]);
        walls.extend(polygon(&[(6.0, 0.0), (12.0, 0.0), (12.0, 4.0), (6.0, 4.0)]));
        walls.extend(polygon(&[
            (70.0, 0.0),
            (74.0, 0.0),
            (74.0, 4.0),
            (70.0, 4.0),
        ]));
        let poses = [
            pose2(1.0, 1.0, 0.5),
            pose2(5.0, 3.0, 3.5),
            pose2(7.0, 1.0, 0.5),
            pose2(72.0, 2.0, 0.0),
        ];
        let t = tracks(&walls, &poses, [2.0, 3.0], [5.0, 2.0]);
        let meet = |i: usize, j: usize| t[i].views_meet(&t[j], &(poses[i].inverse() * poses[j]));
        assert!(meet(0, 1) && meet(1, 0), "the same room");
        assert!(
            !meet(0, 2) && !meet(2, 0),
            "the room next door, behind a wall"
        );
        assert!(!meet(0, 3) && !meet(3, 2), "66 m apart");
        // Under a wrong pose that lays b's room over a's, they would meet: the test is the
        // poses', not the walls'.
        assert!(t[0].views_meet(&t[2], &pose2(0.0, 0.0, 0.0)));
    }

    #[test]
    fn a_walker_both_sensors_see_confirms_the_true_pose() {
        let walls = polygon(&[(0.0, 0.0), (8.0, 0.0), (8.0, 5.0), (0.0, 5.0)]);
        let poses = [pose2(1.0, 1.0, 0.3), pose2(7.0, 4.0, 3.5)];
        let t = tracks(&walls, &poses, [2.0, 4.0], [6.0, 1.5]);
        let p = MotionParams::default();
        let truth = poses[0].inverse() * poses[1];
        let e = co_motion(&t[0], &t[1], &truth, &p);
        assert!(
            e.seen >= 40 && e.seen_through <= 2 && !e.refutes(&p),
            "{e:?}"
        );
        // Half a metre off, the walkers stand where the other saw through.
        let off = truth * pose2(0.0, 0.8, 0.0);
        let e = co_motion(&t[0], &t[1], &off, &p);
        assert!(e.refutes(&p), "{e:?}");
    }
}
