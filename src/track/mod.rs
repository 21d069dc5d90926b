//! People tracking, pure (no I/O, no clock: the scans' stamps are the time).
//!
//! - [`detect`]: the one walker detector (foreground against a background, person-sized
//!   blobs, a blob's centre), shared with registration's `register::motion`.
//! - [`background`]: one sensor's background, learnt slowly from its scans.
//! - [`filter`]: the constant-velocity Kalman filter of one track.
//! - [`assign`]: global assignment of detections to tracks (Hungarian, gated).
//! - [`occlusion`]: whether a sensor's scan has a spot in view or behind something nearer.
//! - [`tracker`]: all of it together: scans of placed sensors in, confirmed [`Tracks`] out.
//! - [`zones`]: occupancy of configured zones and crossings of counting lines, from tracks.
//!
//! [`Tracks`]: crate::daemon::protocol::Tracks

pub mod assign;
pub mod background;
pub mod detect;
pub mod filter;
pub mod mot;
pub mod occlusion;
pub mod score;
pub mod tracker;
pub mod zones;

pub use tracker::{SensorScan, Tracker};

use crate::geometry::ProjectParams;
use background::BackgroundParams;
use detect::BlobParams;

/// Every setting of the tracker, with its default.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackParams {
    /// Foreground and blobs: a return 0.2 m (+ 2 % of range) short of the background is
    /// foreground; returns ≤ 0.2 m apart (one beam may be skipped) form a blob of ≥ 3 returns,
    /// at most 1.6 m wide (wider: a door or a wall that moved, not people); of ≥ 2 where
    /// fewer than 3 beams fall across 0.3 m (past 23 m at 0.25°): a person far off, some of
    /// whose returns drop out, was seen in about a third of the scans and never tracked
    /// (glass-shop's far end, `eval --only tracking --seed 2`: misses 385 → 237).
    pub blob: BlobParams,
    /// The background: what stands still for 90 s (`absorb_s`) becomes background.
    pub background: BackgroundParams,
    pub project: ProjectParams,
    /// A blob wider than 0.75 m is several people side by side, about 0.5 m each.
    pub max_person_m: f64,
    pub person_m: f64,
    /// A level unit's blob in which two or more confirmed tracks stand (their bearings within
    /// it, their range within 0.5 m of its nearest return) is cut between them, each part of
    /// at least 2 returns (`detect::split_by_centres`): two walking close, one partly behind
    /// the other, show one run no wider than a person, whose centre lay between them. Against
    /// no such cut (`eval --only tracking`, seeds 1–6, every all-sensor row): id switches
    /// 354 → 340 (14 rows fewer, 11 more), mean MOTA 0.9796 → 0.9802; 120 s, seed 1: 183 →
    /// 176. Within 0.3 m instead: 2.51 → 2.55 switches per 5 person-minutes at seeds 1–3
    /// (0.5 m: 2.23; 0.8 m: 2.29).
    pub split_behind_m: f64,
    pub split_min_points: usize,
    /// Two centres one sensor sees closer than 0.3 m are one person.
    pub same_person_m: f64,
    /// Units mounted at most 0.4 m high see legs: blobs ≤ 0.3 m wide of ≥ 2 returns, paired
    /// when ≤ 0.6 m apart.
    pub leg_height_m: f64,
    pub leg_max_width_m: f64,
    pub leg_min_points: usize,
    pub leg_pair_m: f64,
    /// A low unit's leg goes to the confirmed track it lies nearest within 0.6 m (a leg
    /// mid-stride, plus where the track expects its person), two legs at most a track; the
    /// legs no track takes are paired as above, and any within 0.6 m of a track's leg would
    /// make a second track on that person. Against pairing every leg closest first (0), in
    /// hall20-legs (`eval --only tracking --track-seconds 120`, seeds 1–2): MOTA 0.972 → 0.984
    /// and 0.949 → 0.969, id switches per 5 person-minutes 6.2 → 4.7 and 16.9 → 9.3 (0.5 m:
    /// 0.976, 0.961; 4.8, 9.6; at 30 s, 0.35 m and 0.4 m made hundreds of false track-frames).
    pub leg_track_m: f64,
    /// A level unit at torso height places its people as torsos of the area it measures from
    /// how wide they look against the way their tracks go (`detect::torso_area`), once it has
    /// 20 such sightings from in front and 20 from the side; round bodies until then.
    pub min_silhouettes: usize,
    /// Returns farther than 25 m from their sensor make no detection.
    pub max_range_m: f64,
    /// Detections of different sensors within 0.45 m are one person.
    pub merge_m: f64,
    /// One fused step per 25 ms of scan time (the scanners' 40 Hz).
    pub step_s: f64,
    /// A merged detection's position noise, 1σ (m).
    pub sigma_meas_m: f64,
    /// The filter's white acceleration (m²/s³): people walk smoothly; a looser filter follows
    /// a passer-by's blob onto a neighbour (0.5 against 2.0: id switches per 5 person-minutes
    /// 3.1 → 2.7 in hall20, 9.7 → 7.4 with 50 people, `eval --only tracking`, seeds 1–2).
    /// With [`filter::Kalman::cost`], seeds 1–6, all sensors: 0.2, 0.3, 0.5, 1.0 gave 246,
    /// 223, 219, 247 id switches, mean MOTA 0.9768, 0.9770, 0.9761, 0.9745.
    pub accel_psd: f64,
    /// A detection may go to a track at this cost ([`filter::Kalman::cost`]: the squared
    /// Mahalanobis distance plus how much less sure the track is than one just seen) and no
    /// further than `gate_max_m` (1 m); the assignment minimises the summed cost. With a
    /// coasting track giving way to one seen (`step`), against the distance alone and the
    /// younger giving way (`eval --only tracking`, all sensors, seeds 1–6): id switches 258
    /// → 219 (hall20 ×50: 72 → 59), mean MOTA 0.9758 → 0.9761; gated at 20 or 45 instead:
    /// 245 and 214, MOTA 0.9758 and 0.9752. 30, far past the 99.9 % of 2 dof (13.8): the
    /// filter is stiff (`accel_psd`), so a person turning at a door or stopping short leaves
    /// a tight gate, coasts unseen and comes back as a new track (by the distance alone,
    /// 13.8 → 30: id switches per 5 person-minutes 2.2 → 1.9 in hall20, 22.8 → 14.2 with
    /// legs, `eval --only tracking`, seeds 1–2; 240 s of hall20 ×20: 2.5 → 1.8).
    pub gate_chi2: f64,
    pub gate_max_m: f64,
    /// A sighting at most 0.15 m nearer one confirmed track than another within the gate
    /// is not taken as the nearer's: two people close together that one sensor saw as one
    /// body (a centre between them) would pull one track onto the other. The other sensors
    /// place them.
    pub ambiguous_m: f64,
    /// Where no other sensor does, such a sighting moves the track as if it saw it offset by
    /// half the pair's spacing, a measurement this loose (m), without counting as seen: both
    /// keep up with the blob, each on its side, until the scans part them (0.3 against none:
    /// id switches per 5 person-minutes 2.7 → 2.2 in hall20, 20.9 → 22.8 with legs).
    pub shared_sigma_m: f64,
    /// A new track's speed uncertainty (m/s).
    pub birth_sigma_v_m_s: f64,
    /// No track is born within 0.45 m of another: less than the 0.5–0.7 m between people
    /// walking abreast, whose middle one is otherwise never tracked ...
    pub birth_clear_m: f64,
    /// ... or within 0.6 m when a low unit saw it: a leg left unpaired mid-stride lies up to
    /// that far from its person's track.
    pub leg_birth_clear_m: f64,
    /// Two confirmed tracks within 0.3 m for 0.5 s are one person (the younger ends): people
    /// crossing are that close only for a moment.
    pub same_track_m: f64,
    pub same_track_s: f64,
    /// A track is confirmed (gets its id) at its 5th detection ...
    pub confirm_hits: u32,
    /// ... when seen in at least this share of the steps since it was born: a person in view
    /// is seen nearly every step, stray returns (a low unit grazing the floor far off) only
    /// now and then. A tentative track unseen for 0.2 s is dropped, a confirmed one unseen
    /// for 1.5 s ends.
    pub confirm_rate: f64,
    pub tentative_death_s: f64,
    pub death_s: f64,
    /// A confirmed track hidden behind others from every sensor that reaches its spot is
    /// neither dropped nor unlisted (it walks on as last seen) for up to 4 s unseen.
    pub hidden_s: f64,
    /// A confirmed track is listed while seen within the last 0.5 s; unseen longer (hidden
    /// behind others) it is kept, to take its person back, but not listed.
    pub shown_unseen_s: f64,
    /// A track lost (ended unseen, ended on another track's person, or hidden past
    /// `shown_unseen_s`) gives its id to a new
    /// track confirmed within 4 s (`reid_s`) where its last velocity carries it, within
    /// 0.5 m (`reid_m`) + 0.5 m (`reid_m_per_s`) for every second unseen: a person hidden
    /// behind others keeps their id.
    pub reid_s: f64,
    pub reid_m: f64,
    pub reid_m_per_s: f64,
    /// No one walks faster than 2.5 m/s: a faster estimate is capped.
    pub max_speed_m_s: f64,
    /// A sensor whose pose changes by more than 0.1 m or 1° was moved: its background
    /// starts again.
    pub repose_m: f64,
    pub repose_rad: f64,
}

impl Default for TrackParams {
    fn default() -> Self {
        TrackParams {
            blob: BlobParams {
                moved_m: 0.2,
                margin_frac: 0.02,
                gap_m: 0.2,
                min_points: 3,
                max_width_m: 1.6,
                far_body_m: 0.3,
            },
            background: BackgroundParams::default(),
            project: ProjectParams::default(),
            max_person_m: 0.75,
            person_m: 0.5,
            same_person_m: 0.3,
            split_behind_m: 0.5,
            split_min_points: 2,
            leg_height_m: 0.4,
            leg_max_width_m: 0.3,
            leg_min_points: 2,
            leg_pair_m: 0.6,
            leg_track_m: 0.6,
            min_silhouettes: 20,
            max_range_m: 25.0,
            merge_m: 0.45,
            step_s: 0.025,
            sigma_meas_m: 0.05,
            accel_psd: 0.5,
            gate_chi2: 30.0,
            gate_max_m: 1.0,
            ambiguous_m: 0.15,
            shared_sigma_m: 0.3,
            birth_sigma_v_m_s: 1.0,
            birth_clear_m: 0.45,
            leg_birth_clear_m: 0.6,
            same_track_m: 0.3,
            same_track_s: 0.5,
            confirm_hits: 5,
            confirm_rate: 0.5,
            tentative_death_s: 0.2,
            death_s: 1.5,
            hidden_s: 4.0,
            shown_unseen_s: 0.5,
            reid_s: 4.0,
            reid_m: 0.5,
            reid_m_per_s: 0.5,
            max_speed_m_s: 2.5,
            repose_m: 0.1,
            repose_rad: 1f64.to_radians(),
        }
    }
}
