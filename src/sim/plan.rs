//! Floor plans: the TOML a person writes, parsed and checked into a [`Plan`].
//!
//! A plan is a 2D floor plan whose shapes are extruded vertically, plus the sensors that look at
//! it, the people who walk through it and the moves that happen to sensors during a recording.
//! Coordinates are the site frame, metres, x/y on the floor, z up from the floor; angles in the
//! file are degrees, counter-clockwise from +x.
//!
//! # Keys (every table rejects keys it does not know)
//!
//! Top level:
//! - `name` (string, required): the plan's name; sensors report `connect = "sim:<name>"`.
//! - `start_unix_s` (integer, default 1767225600 = 2026-01-01T00:00:00Z): recording start time,
//!   fixed by default so that output is deterministic.
//! - `ceiling_m` (number, optional): height of a flat ceiling; absent means open sky.
//! - `floor_reflectivity` (default 0.3), `ceiling_reflectivity` (default 0.7).
//!
//! Shapes (all have `height_m`, the top above the floor, `z_min_m`, the bottom, default 0 —
//! set it for a table top or a shelf board that a beam can pass under — and `reflectivity`,
//! a diffuse albedo in (0, 1], up to 10 for retro-reflective tape):
//! - `[[wall]]`: `points = [[x, y], …]` (at least 2), `closed` (default false; true joins the
//!   last point back to the first), `height_m` (default 3.0), `z_min_m`, `reflectivity` (0.7).
//!   Walls have no thickness.
//! - `[[box]]`: furniture, shelves, desks: `center = [x, y]`, `size = [length, width]` (along
//!   the box's own x and y), `yaw_deg` (default 0), `height_m` (default 1.0), `z_min_m`,
//!   `reflectivity` (0.5).
//! - `[[circle]]`: pillars, bins: `center`, `radius_m`, `height_m` (default 3.0), `z_min_m`,
//!   `reflectivity` (0.6).
//! - `[[door]]`: an opening cut into the nearest wall segment: `at = [x, y]` (within
//!   0.5 m of that segment), `width_m` (default 0.9). The gap is centred on the foot of `at`
//!   on the segment and must fit inside it; beams pass through it to whatever lies beyond.
//!
//! Sensors, `[[sensor]]`: `id` (required, unique, letters, digits, `-`, `_`), `model`
//! (`"UTM-30LX-EW"`, `"UXM-30LX-E"` or `"URG-04LX"`), `x`, `y` (m), `yaw_deg` (default 0),
//! `height_m` (optical centre above the floor, default 1.0), `pitch_deg` (scan plane tilt about
//! the sensor's y axis, positive up, default 0, at most 60 either way), `intensities` (default
//! true for the UTM, false for the UXM; the URG-04LX has none to send, so `true` is refused).
//!
//! People, `[[person]]`: discs that walk a closed loop through `waypoints = [[x, y], …]` (at least
//! 2) at `speed_m_s` (default 1.2), `radius_m` (default 0.25), `height_m` (default 1.75),
//! starting `phase` of the way round the loop (0 ≤ phase < 1, default 0).
//!
//! Moves, `[[move]]`: at `at_s` seconds after the start the sensor `sensor` is shifted by `dx`,
//! `dy` (site frame, m) and turned by `dyaw_deg`. Several moves of one sensor add up.
//!
//! Crowds, `[[crowd]]`: people who come in, walk to random destinations, some stop and stand,
//! some walk in pairs or groups side by side, and leave through a door. They walk round walls,
//! boxes and pillars (a path on a 0.2 m occupancy grid of the plan, 0.25 m clear of anything
//! lower than 1.8 m), and through each other. Each body is seen as a scanner at that height
//! would see it: legs (two 0.12 m discs that swing with the gait) up to 0.46 × the person's
//! height, a torso ellipse 0.45 × 0.28 m turned to the walking direction up to 0.82 × it, a
//! head above. Keys:
//! - `people` (0–100, default 10): how many are inside at the start, each at a destination
//!   partway through a visit.
//! - `max_people` (`people`..=100, default `people`): the cap; nobody of this crowd enters while
//!   this many of it are inside.
//! - `rate_per_min` (≥ 0, default 30): arrivals per minute (a Poisson stream), each a person or a
//!   group; an arrival that would pass the cap stays away.
//! - `entrances` (`[[x, y], …]`, default every `[[door]]`): where people come in: a door's
//!   centre (they appear 1 m outside it and walk in) or a point in free space (they appear there).
//! - `exits` (`[[x, y], …]`, default the entrances): where they leave, the same way out.
//! - `destinations` (`[[x, y], …]`) and `areas` (`[[x0, y0, x1, y1], …]`, rectangles): where they
//!   walk to, a point or a random spot in an area; with neither, random free points of the plan
//!   (inside its walls).
//! - `visits` (`[min, max]`, default `[1, 4]`): destinations per visit.
//! - `speed_m_s` (`[min, max]` within 0.5–1.8, default `[0.5, 1.8]`): walking speeds, drawn
//!   per person (a group walks at one speed).
//! - `stop_share` (0–1, default 0.3): share of destinations where a person stops and stands;
//!   `stop_s` (`[min, max]`, default `[5, 30]`): for how long.
//! - `group_share` (0–1, default 0.3): share of arrivals (and of the people inside at the start)
//!   that are groups; `group_size` (`[min, max]` within 2–6, default `[2, 3]`); `spacing_m`
//!   (default 0.7): between neighbours walking side by side (where the way is too narrow they
//!   fall in behind).
//! - `height_m` (`[min, max]`, default `[1.55, 1.95]`): body heights.
//!
//! Queues, `[[queue]]`: people standing still in a line, served one at a time. `head = [x, y]`
//! (the front), `tail = [x, y]` (the line runs from the head towards it), `people` (1–100,
//! default 6), `spacing_m` (default 0.7), `serve_s` (default 30; 0 = nobody is ever served, the
//! line stands still all run): every `serve_s` the front person walks to an exit, the rest step
//! up one place, and a newcomer walks in from an entrance to the back. `entrances`, `exits` and
//! `speed_m_s` as for a crowd. Every place of the line must be free.
//!
//! People's truth: `truth_people` (top level, default true when the plan has a crowd or a
//! queue): the recording gets a `/truth/people` channel, every 0.1 s every simulated body's
//! centre (crowd and queue people `p1`, `p2`, … in order of appearance, never reused;
//! `[[person]]` walkers `w1`, `w2`, … in plan order).

use std::collections::BTreeSet;
use std::ops::Range;
use std::path::Path;

use serde::{Deserialize, Serialize};
use toml::Spanned;

use super::PlanError;
use crate::scan::ScanGeometry;

/// Recording start when the plan does not say: 2026-01-01T00:00:00Z.
pub const DEFAULT_START_UNIX_S: u64 = 1_767_225_600;
/// How far a door's `at` may lie from the wall it cuts, m.
pub const DOOR_SNAP_M: f64 = 0.5;
/// Largest tilt a sensor may have, degrees.
pub const MAX_PITCH_DEG: f64 = 60.0;
/// Shortest segment a shape may have, m.
const MIN_LENGTH_M: f64 = 0.001;

/// Which sensor a plan places.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
pub enum Model {
    #[serde(rename = "UTM-30LX-EW")]
    Utm30lxEw,
    #[serde(rename = "UXM-30LX-E")]
    Uxm30lxE,
    #[serde(rename = "URG-04LX")]
    Urg04lx,
}

impl Model {
    /// Every model, in declaration order.
    pub const ALL: [Model; 3] = [Model::Utm30lxEw, Model::Uxm30lxE, Model::Urg04lx];

    /// The model name as Hokuyo writes it.
    pub fn name(self) -> &'static str {
        match self {
            Model::Utm30lxEw => "UTM-30LX-EW",
            Model::Uxm30lxE => "UXM-30LX-E",
            Model::Urg04lx => "URG-04LX",
        }
    }

    /// Its layout, as its PP reply states it.
    pub fn geometry(self) -> ScanGeometry {
        match self {
            Model::Utm30lxEw => ScanGeometry::UTM_30LX_EW,
            Model::Uxm30lxE => ScanGeometry::UXM_30LX_E,
            Model::Urg04lx => ScanGeometry::URG_04LX,
        }
    }

    /// Whether it can send intensities at all: the URG-04LX speaks MD/GD only, no ME.
    pub fn can_send_intensities(self) -> bool {
        !matches!(self, Model::Urg04lx)
    }
}

/// A model by name, ignoring case: the full name (`URG-04LX`) or its family's three letters
/// (`urg`), as command lines take it.
impl std::str::FromStr for Model {
    type Err = String;

    fn from_str(text: &str) -> Result<Model, String> {
        let text = text.trim();
        Model::ALL
            .into_iter()
            .find(|m| {
                let name = m.name();
                text.eq_ignore_ascii_case(name)
                    || name
                        .get(..3)
                        .is_some_and(|short| text.eq_ignore_ascii_case(short))
            })
            .ok_or_else(|| {
                let names: Vec<&str> = Model::ALL.iter().map(|m| m.name()).collect();
                format!(
                    "unknown model {text:?}; use {} (or utm, uxm, urg), any case",
                    names.join(", ")
                )
            })
    }
}

/// A checked floor plan. Build it with [`Plan::load`] or [`Plan::from_toml`]; a plan built by
/// hand is checked again by [`Plan::validate`] (which `Simulation::new` calls).
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Where the plan came from (file name), for messages.
    pub origin: String,
    pub name: String,
    /// Recording start, s since the Unix epoch.
    pub start_unix_s: u64,
    /// Height of a flat ceiling, m; `None` for open sky.
    pub ceiling_m: Option<f64>,
    pub floor_reflectivity: f64,
    pub ceiling_reflectivity: f64,
    pub walls: Vec<Wall>,
    pub boxes: Vec<BoxShape>,
    pub circles: Vec<Circle>,
    pub doors: Vec<Door>,
    pub sensors: Vec<SensorPlan>,
    pub people: Vec<Person>,
    pub moves: Vec<Move>,
    pub crowds: Vec<Crowd>,
    pub queues: Vec<Queue>,
    /// Whether recordings carry `/truth/people`; `None` means "when there is a crowd or queue".
    pub truth_people: Option<bool>,
}

/// A wall polyline, extruded from `z_min_m` to `height_m`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Wall {
    #[serde(skip)]
    pub line: Option<usize>,
    pub points: Vec<[f64; 2]>,
    #[serde(default)]
    pub closed: bool,
    #[serde(default = "default_wall_height")]
    pub height_m: f64,
    #[serde(default)]
    pub z_min_m: f64,
    #[serde(default = "default_wall_reflectivity")]
    pub reflectivity: f64,
}

impl Wall {
    /// Its straight pieces, end to end (and back to the start when `closed`).
    pub fn segments(&self) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + '_ {
        let n = self.points.len();
        let count = if self.closed { n } else { n.saturating_sub(1) };
        (0..count).map(move |i| (self.points[i], self.points[(i + 1) % n]))
    }
}

/// A rectangular block: a desk, a shelf, a cabinet.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoxShape {
    #[serde(skip)]
    pub line: Option<usize>,
    pub center: [f64; 2],
    pub size: [f64; 2],
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default = "default_box_height")]
    pub height_m: f64,
    #[serde(default)]
    pub z_min_m: f64,
    #[serde(default = "default_box_reflectivity")]
    pub reflectivity: f64,
}

/// A vertical cylinder: a pillar, a bin.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Circle {
    #[serde(skip)]
    pub line: Option<usize>,
    pub center: [f64; 2],
    pub radius_m: f64,
    #[serde(default = "default_wall_height")]
    pub height_m: f64,
    #[serde(default)]
    pub z_min_m: f64,
    #[serde(default = "default_circle_reflectivity")]
    pub reflectivity: f64,
}

/// An opening cut into the nearest wall segment.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Door {
    #[serde(skip)]
    pub line: Option<usize>,
    pub at: [f64; 2],
    #[serde(default = "default_door_width")]
    pub width_m: f64,
}

/// A sensor placed in the plan.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SensorPlan {
    #[serde(skip)]
    pub line: Option<usize>,
    pub id: String,
    pub model: Model,
    pub x: f64,
    pub y: f64,
    #[serde(default)]
    pub yaw_deg: f64,
    #[serde(default = "default_sensor_height")]
    pub height_m: f64,
    #[serde(default)]
    pub pitch_deg: f64,
    /// `None` means the model's default (on for the UTM, off for the UXM and the URG).
    pub intensities: Option<bool>,
}

impl SensorPlan {
    /// Whether scans carry intensities.
    pub fn has_intensities(&self) -> bool {
        self.intensities
            .unwrap_or(matches!(self.model, Model::Utm30lxEw))
    }
}

/// A person: a disc that walks a closed loop through its waypoints.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Person {
    #[serde(skip)]
    pub line: Option<usize>,
    pub waypoints: Vec<[f64; 2]>,
    #[serde(default = "default_speed")]
    pub speed_m_s: f64,
    #[serde(default = "default_person_radius")]
    pub radius_m: f64,
    #[serde(default = "default_person_height")]
    pub height_m: f64,
    #[serde(default)]
    pub phase: f64,
}

/// People who come and go: see the module docs for every key.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Crowd {
    #[serde(skip)]
    pub line: Option<usize>,
    #[serde(default = "default_crowd_people")]
    pub people: u32,
    pub max_people: Option<u32>,
    #[serde(default = "default_rate")]
    pub rate_per_min: f64,
    #[serde(default)]
    pub entrances: Vec<[f64; 2]>,
    #[serde(default)]
    pub exits: Vec<[f64; 2]>,
    #[serde(default)]
    pub destinations: Vec<[f64; 2]>,
    #[serde(default)]
    pub areas: Vec<[f64; 4]>,
    #[serde(default = "default_visits")]
    pub visits: [u32; 2],
    #[serde(default = "default_speeds")]
    pub speed_m_s: [f64; 2],
    #[serde(default = "default_stop_share")]
    pub stop_share: f64,
    #[serde(default = "default_stop_s")]
    pub stop_s: [f64; 2],
    #[serde(default = "default_group_share")]
    pub group_share: f64,
    #[serde(default = "default_group_size")]
    pub group_size: [u32; 2],
    #[serde(default = "default_spacing")]
    pub spacing_m: f64,
    #[serde(default = "default_heights")]
    pub height_m: [f64; 2],
}

/// A crowd with every key at its documented default (10 people, 30 a minute, doors as
/// entrances and exits), for plans made by a program.
impl Default for Crowd {
    fn default() -> Self {
        Crowd {
            line: None,
            people: default_crowd_people(),
            max_people: None,
            rate_per_min: default_rate(),
            entrances: Vec::new(),
            exits: Vec::new(),
            destinations: Vec::new(),
            areas: Vec::new(),
            visits: default_visits(),
            speed_m_s: default_speeds(),
            stop_share: default_stop_share(),
            stop_s: default_stop_s(),
            group_share: default_group_share(),
            group_size: default_group_size(),
            spacing_m: default_spacing(),
            height_m: default_heights(),
        }
    }
}

impl Crowd {
    /// The cap on how many of this crowd are inside at once.
    pub fn cap(&self) -> u32 {
        self.max_people.unwrap_or(self.people)
    }
}

/// People standing in a line, served one at a time.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Queue {
    #[serde(skip)]
    pub line: Option<usize>,
    pub head: [f64; 2],
    pub tail: [f64; 2],
    #[serde(default = "default_queue_people")]
    pub people: u32,
    #[serde(default = "default_spacing")]
    pub spacing_m: f64,
    #[serde(default = "default_serve_s")]
    pub serve_s: f64,
    #[serde(default)]
    pub entrances: Vec<[f64; 2]>,
    #[serde(default)]
    pub exits: Vec<[f64; 2]>,
    #[serde(default = "default_speeds")]
    pub speed_m_s: [f64; 2],
}

impl Queue {
    /// Where the `k`-th person of the line stands (0 = the front).
    pub fn place(&self, k: u32) -> [f64; 2] {
        let (dx, dy) = (self.tail[0] - self.head[0], self.tail[1] - self.head[1]);
        let len = dx.hypot(dy).max(1e-9);
        let d = f64::from(k) * self.spacing_m;
        [self.head[0] + dx / len * d, self.head[1] + dy / len * d]
    }
}

/// Most people a crowd or queue may hold at once.
pub const MAX_CROWD: u32 = 100;
/// Slowest and fastest walking speeds a crowd may be given, m/s.
pub const CROWD_SPEEDS_M_S: [f64; 2] = [0.5, 1.8];

/// A sensor being moved during the recording.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Move {
    #[serde(skip)]
    pub line: Option<usize>,
    pub sensor: String,
    pub at_s: f64,
    #[serde(default)]
    pub dx: f64,
    #[serde(default)]
    pub dy: f64,
    #[serde(default)]
    pub dyaw_deg: f64,
}

fn default_crowd_people() -> u32 {
    10
}
fn default_queue_people() -> u32 {
    6
}
fn default_rate() -> f64 {
    30.0
}
fn default_visits() -> [u32; 2] {
    [1, 4]
}
fn default_speeds() -> [f64; 2] {
    CROWD_SPEEDS_M_S
}
fn default_stop_share() -> f64 {
    0.3
}
fn default_stop_s() -> [f64; 2] {
    [5.0, 30.0]
}
fn default_group_share() -> f64 {
    0.3
}
fn default_group_size() -> [u32; 2] {
    [2, 3]
}
fn default_spacing() -> f64 {
    0.7
}
fn default_heights() -> [f64; 2] {
    [1.55, 1.95]
}
fn default_serve_s() -> f64 {
    30.0
}
fn default_start() -> u64 {
    DEFAULT_START_UNIX_S
}
fn default_floor_reflectivity() -> f64 {
    0.3
}
fn default_ceiling_reflectivity() -> f64 {
    0.7
}
fn default_wall_height() -> f64 {
    3.0
}
fn default_wall_reflectivity() -> f64 {
    0.7
}
fn default_box_height() -> f64 {
    1.0
}
fn default_box_reflectivity() -> f64 {
    0.5
}
fn default_circle_reflectivity() -> f64 {
    0.6
}
fn default_door_width() -> f64 {
    0.9
}
fn default_sensor_height() -> f64 {
    1.0
}
fn default_speed() -> f64 {
    1.2
}
fn default_person_radius() -> f64 {
    0.25
}
fn default_person_height() -> f64 {
    1.75
}

/// The file as written: the same tables, with where each one starts.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanFile {
    name: String,
    #[serde(default = "default_start")]
    start_unix_s: u64,
    ceiling_m: Option<f64>,
    #[serde(default = "default_floor_reflectivity")]
    floor_reflectivity: f64,
    #[serde(default = "default_ceiling_reflectivity")]
    ceiling_reflectivity: f64,
    #[serde(default)]
    wall: Vec<Spanned<Wall>>,
    #[serde(default, rename = "box")]
    boxes: Vec<Spanned<BoxShape>>,
    #[serde(default)]
    circle: Vec<Spanned<Circle>>,
    #[serde(default)]
    door: Vec<Spanned<Door>>,
    #[serde(default)]
    sensor: Vec<Spanned<SensorPlan>>,
    #[serde(default)]
    person: Vec<Spanned<Person>>,
    #[serde(default, rename = "move")]
    moves: Vec<Spanned<Move>>,
    #[serde(default)]
    crowd: Vec<Spanned<Crowd>>,
    #[serde(default)]
    queue: Vec<Spanned<Queue>>,
    truth_people: Option<bool>,
}

/// The file as [`Plan::to_toml`] writes it: plain keys first, then the tables.
#[derive(Serialize)]
struct PlanOut<'a> {
    name: &'a str,
    start_unix_s: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    ceiling_m: Option<f64>,
    floor_reflectivity: f64,
    ceiling_reflectivity: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    truth_people: Option<bool>,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    wall: &'a [Wall],
    #[serde(rename = "box")]
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    boxes: &'a [BoxShape],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    circle: &'a [Circle],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    door: &'a [Door],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    sensor: &'a [SensorPlan],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    person: &'a [Person],
    #[serde(rename = "move")]
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    moves: &'a [Move],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    crowd: &'a [Crowd],
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    queue: &'a [Queue],
}

/// 1-based line of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text.bytes().take(offset).filter(|&b| b == b'\n').count() + 1
}

/// Unwraps spanned tables, remembering the line each starts on.
fn located<T>(text: &str, items: Vec<Spanned<T>>, set: impl Fn(&mut T, usize)) -> Vec<T> {
    items
        .into_iter()
        .map(|item| {
            let line = line_of(text, item.span().start);
            let mut value = item.into_inner();
            set(&mut value, line);
            value
        })
        .collect()
}

/// The key written on the line a parser error points at, if any.
fn key_at(text: &str, span: &Range<usize>) -> Option<String> {
    let before = text.get(..span.start)?;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text.get(start..)?.lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    (!key.is_empty() && !key.starts_with('[')).then(|| key.to_string())
}

/// Moves an error from its table's header to the line that sets the key, when there is one.
fn refine_line(text: &str, mut err: PlanError) -> PlanError {
    let (Some(line), Some(key)) = (err.line, err.key.as_deref()) else {
        return err;
    };
    let name = key.rsplit('.').next().unwrap_or(key);
    let found = text
        .lines()
        .enumerate()
        .skip(line)
        .take_while(|(_, l)| !l.trim_start().starts_with('['))
        .find(|(_, l)| {
            l.split_once('=')
                .is_some_and(|(k, _)| name.split('/').any(|n| k.trim() == n))
        });
    if let Some((i, _)) = found {
        err.line = Some(i + 1);
    }
    err
}

impl Plan {
    /// Reads and checks the plan in `path`.
    pub fn load(path: &Path) -> Result<Plan, PlanError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| PlanError::new(&origin, None, None, format!("cannot read: {e}")))?;
        Plan::from_toml(&text, &origin)
    }

    /// Parses and checks a plan; `origin` names it in messages (usually the file name).
    pub fn from_toml(text: &str, origin: &str) -> Result<Plan, PlanError> {
        let file: PlanFile = toml::from_str(text).map_err(|e| {
            let span = e.span();
            let line = span.as_ref().map(|s| line_of(text, s.start));
            let key = span.as_ref().and_then(|s| key_at(text, s));
            PlanError::new(origin, line, key.as_deref(), e.message().trim().to_string())
        })?;
        let plan = Plan {
            origin: origin.to_string(),
            name: file.name,
            start_unix_s: file.start_unix_s,
            ceiling_m: file.ceiling_m,
            floor_reflectivity: file.floor_reflectivity,
            ceiling_reflectivity: file.ceiling_reflectivity,
            walls: located(text, file.wall, |w, l| w.line = Some(l)),
            boxes: located(text, file.boxes, |b, l| b.line = Some(l)),
            circles: located(text, file.circle, |c, l| c.line = Some(l)),
            doors: located(text, file.door, |d, l| d.line = Some(l)),
            sensors: located(text, file.sensor, |s, l| s.line = Some(l)),
            people: located(text, file.person, |p, l| p.line = Some(l)),
            moves: located(text, file.moves, |m, l| m.line = Some(l)),
            crowds: located(text, file.crowd, |c, l| c.line = Some(l)),
            queues: located(text, file.queue, |q, l| q.line = Some(l)),
            truth_people: file.truth_people,
        };
        plan.validate().map_err(|e| refine_line(text, e))?;
        Ok(plan)
    }

    /// The plan as the TOML [`Plan::from_toml`] reads (every key written out), for plans made
    /// by a program (`sim::generate`) that a person opens, edits or simulates again.
    pub fn to_toml(&self) -> Result<String, PlanError> {
        let out = PlanOut {
            name: &self.name,
            start_unix_s: self.start_unix_s,
            ceiling_m: self.ceiling_m,
            floor_reflectivity: self.floor_reflectivity,
            ceiling_reflectivity: self.ceiling_reflectivity,
            truth_people: self.truth_people,
            wall: &self.walls,
            boxes: &self.boxes,
            circle: &self.circles,
            door: &self.doors,
            sensor: &self.sensors,
            person: &self.people,
            moves: &self.moves,
            crowd: &self.crowds,
            queue: &self.queues,
        };
        toml::to_string(&out).map_err(|e| {
            PlanError::new(
                &self.origin,
                None,
                None,
                format!("cannot write as TOML: {e}"),
            )
        })
    }

    /// Whether recordings of this plan carry `/truth/people`.
    pub fn writes_people_truth(&self) -> bool {
        self.truth_people
            .unwrap_or(!self.crowds.is_empty() || !self.queues.is_empty())
    }

    /// The sensor with this id.
    pub fn sensor(&self, id: &str) -> Option<&SensorPlan> {
        self.sensors.iter().find(|s| s.id == id)
    }

    /// The box or circle (described with its line) that holds the point at `height_m`, if any.
    fn solid_at(&self, p: [f64; 2], height_m: f64) -> Option<String> {
        let at = |line: Option<usize>| line.map_or(String::new(), |l| format!(" at line {l}"));
        for b in &self.boxes {
            let (sin, cos) = b.yaw_deg.to_radians().sin_cos();
            let (dx, dy) = (p[0] - b.center[0], p[1] - b.center[1]);
            let (u, v) = (cos * dx + sin * dy, -sin * dx + cos * dy);
            if u.abs() < b.size[0] / 2.0
                && v.abs() < b.size[1] / 2.0
                && (b.z_min_m..=b.height_m).contains(&height_m)
            {
                return Some(format!("[[box]]{}", at(b.line)));
            }
        }
        for c in &self.circles {
            let d = (p[0] - c.center[0]).hypot(p[1] - c.center[1]);
            if d < c.radius_m && (c.z_min_m..=c.height_m).contains(&height_m) {
                return Some(format!("[[circle]]{}", at(c.line)));
            }
        }
        None
    }

    /// Checks everything a simulation relies on; the error names the table, key and what is valid.
    pub fn validate(&self) -> Result<(), PlanError> {
        let err = |line: Option<usize>, key: &str, problem: String| {
            Err(PlanError::new(&self.origin, line, Some(key), problem))
        };
        if self.name.trim().is_empty() {
            return err(None, "name", "must not be empty".into());
        }
        check_reflectivity(self, None, "floor_reflectivity", self.floor_reflectivity)?;
        check_reflectivity(
            self,
            None,
            "ceiling_reflectivity",
            self.ceiling_reflectivity,
        )?;
        if let Some(ceiling_m) = self.ceiling_m {
            if !(ceiling_m.is_finite() && ceiling_m > 0.0) {
                return err(
                    None,
                    "ceiling_m",
                    format!("is {ceiling_m}; use a height > 0 m, or leave it out for no ceiling"),
                );
            }
            if let Some(s) = self.sensors.iter().find(|s| s.height_m >= ceiling_m) {
                return err(
                    s.line,
                    "height_m",
                    format!(
                        "sensor `{}` at {} m is not below the ceiling at {ceiling_m} m",
                        s.id, s.height_m
                    ),
                );
            }
        }
        for w in &self.walls {
            check_points(self, w.line, "wall.points", &w.points, 2)?;
            if w.closed && w.points.len() < 3 {
                return err(
                    w.line,
                    "wall.closed",
                    "a closed wall needs at least 3 points".into(),
                );
            }
            check_extent(self, w.line, "wall", w.z_min_m, w.height_m)?;
            check_reflectivity(self, w.line, "wall.reflectivity", w.reflectivity)?;
        }
        for b in &self.boxes {
            check_points(self, b.line, "box.center", &[b.center], 1)?;
            check_finite(self, b.line, "box.yaw_deg", b.yaw_deg)?;
            if !b.size.iter().all(|s| s.is_finite() && *s >= MIN_LENGTH_M) {
                return err(
                    b.line,
                    "box.size",
                    format!(
                        "is {:?}; both sides must be at least {MIN_LENGTH_M} m",
                        b.size
                    ),
                );
            }
            check_extent(self, b.line, "box", b.z_min_m, b.height_m)?;
            check_reflectivity(self, b.line, "box.reflectivity", b.reflectivity)?;
        }
        for c in &self.circles {
            check_points(self, c.line, "circle.center", &[c.center], 1)?;
            if !(c.radius_m.is_finite() && c.radius_m >= MIN_LENGTH_M) {
                return err(
                    c.line,
                    "circle.radius_m",
                    format!(
                        "is {}; use a radius of at least {MIN_LENGTH_M} m",
                        c.radius_m
                    ),
                );
            }
            check_extent(self, c.line, "circle", c.z_min_m, c.height_m)?;
            check_reflectivity(self, c.line, "circle.reflectivity", c.reflectivity)?;
        }
        for d in &self.doors {
            check_points(self, d.line, "door.at", &[d.at], 1)?;
            if !(d.width_m.is_finite() && d.width_m >= MIN_LENGTH_M) {
                return err(
                    d.line,
                    "door.width_m",
                    format!("is {}; use a width > 0 m", d.width_m),
                );
            }
        }
        // Doors must find their wall; the scene builder reports which one failed.
        super::scene::Scene::build(self)?;
        let mut ids = BTreeSet::new();
        for s in &self.sensors {
            let valid_id = !s.id.is_empty()
                && s.id
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
            if !valid_id {
                return err(
                    s.line,
                    "sensor.id",
                    format!(
                        "{:?} is not usable; use letters, digits, `-` and `_` only",
                        s.id
                    ),
                );
            }
            if !ids.insert(s.id.as_str()) {
                return err(
                    s.line,
                    "sensor.id",
                    format!("`{}` is used twice; every sensor needs its own id", s.id),
                );
            }
            check_points(self, s.line, "sensor.x/y", &[[s.x, s.y]], 1)?;
            if let Some(inside) = self.solid_at([s.x, s.y], s.height_m) {
                return err(
                    s.line,
                    "sensor.x/y",
                    format!(
                        "sensor `{}` is inside the {inside}; place it in free space",
                        s.id
                    ),
                );
            }
            check_finite(self, s.line, "sensor.yaw_deg", s.yaw_deg)?;
            if !(s.height_m.is_finite() && s.height_m > 0.0) {
                return err(
                    s.line,
                    "sensor.height_m",
                    format!("is {}; use a height above the floor, > 0 m", s.height_m),
                );
            }
            if s.intensities == Some(true) && !s.model.can_send_intensities() {
                return err(
                    s.line,
                    "sensor.intensities",
                    format!(
                        "sensor `{}` is a {}, which sends no intensities (MD/GD only); \
                         leave `intensities` out or set it to false",
                        s.id,
                        s.model.name()
                    ),
                );
            }
            if !(s.pitch_deg.is_finite() && s.pitch_deg.abs() <= MAX_PITCH_DEG) {
                return err(
                    s.line,
                    "sensor.pitch_deg",
                    format!(
                        "is {}; use a tilt between -{MAX_PITCH_DEG} and {MAX_PITCH_DEG} degrees",
                        s.pitch_deg
                    ),
                );
            }
        }
        for p in &self.people {
            check_points(self, p.line, "person.waypoints", &p.waypoints, 2)?;
            for (key, value) in [
                ("person.speed_m_s", p.speed_m_s),
                ("person.radius_m", p.radius_m),
                ("person.height_m", p.height_m),
            ] {
                if !(value.is_finite() && value > 0.0) {
                    return err(p.line, key, format!("is {value}; use a number > 0"));
                }
            }
            if !(p.phase.is_finite() && (0.0..1.0).contains(&p.phase)) {
                return err(
                    p.line,
                    "person.phase",
                    format!("is {}; use a fraction of the loop, 0 <= phase < 1", p.phase),
                );
            }
        }
        for c in &self.crowds {
            check_crowd(self, c)?;
        }
        for q in &self.queues {
            check_queue(self, q)?;
        }
        for m in &self.moves {
            if self.sensor(&m.sensor).is_none() {
                let known: Vec<&str> = self.sensors.iter().map(|s| s.id.as_str()).collect();
                return err(
                    m.line,
                    "move.sensor",
                    format!(
                        "`{}` is not a sensor of this plan; known: {}",
                        m.sensor,
                        known.join(", ")
                    ),
                );
            }
            if !(m.at_s.is_finite() && m.at_s >= 0.0) {
                return err(
                    m.line,
                    "move.at_s",
                    format!("is {}; use seconds after the start, >= 0", m.at_s),
                );
            }
            for (key, value) in [
                ("move.dx", m.dx),
                ("move.dy", m.dy),
                ("move.dyaw_deg", m.dyaw_deg),
            ] {
                check_finite(self, m.line, key, value)?;
            }
        }
        Ok(())
    }
}

/// `[min, max]` with min ≤ max, both within `range`.
fn check_span(
    plan: &Plan,
    line: Option<usize>,
    key: &str,
    span: [f64; 2],
    range: (f64, f64),
) -> Result<(), PlanError> {
    let ok = span
        .iter()
        .all(|v| v.is_finite() && *v >= range.0 && *v <= range.1)
        && span[0] <= span[1];
    if ok {
        return Ok(());
    }
    Err(PlanError::new(
        &plan.origin,
        line,
        Some(key),
        format!(
            "is {span:?}; give [min, max] with {} <= min <= max <= {}",
            range.0, range.1
        ),
    ))
}

fn check_share(plan: &Plan, line: Option<usize>, key: &str, v: f64) -> Result<(), PlanError> {
    if v.is_finite() && (0.0..=1.0).contains(&v) {
        return Ok(());
    }
    Err(PlanError::new(
        &plan.origin,
        line,
        Some(key),
        format!("is {v}; use a share between 0 and 1"),
    ))
}

/// Entrances and exits: given points, or the plan's doors.
fn check_ways(
    plan: &Plan,
    line: Option<usize>,
    table: &str,
    entrances: &[[f64; 2]],
    exits: &[[f64; 2]],
) -> Result<(), PlanError> {
    check_points(plan, line, &format!("{table}.entrances"), entrances, 0)?;
    check_points(plan, line, &format!("{table}.exits"), exits, 0)?;
    if entrances.is_empty() && plan.doors.is_empty() {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(&format!("{table}.entrances")),
            "the plan has no [[door]]; add one, or give entrances = [[x, y], …]".into(),
        ));
    }
    Ok(())
}

fn check_crowd(plan: &Plan, c: &Crowd) -> Result<(), PlanError> {
    let err =
        |key: &str, problem: String| Err(PlanError::new(&plan.origin, c.line, Some(key), problem));
    if c.people > MAX_CROWD {
        return err(
            "crowd.people",
            format!("is {}; use 0 to {MAX_CROWD}", c.people),
        );
    }
    if c.cap() > MAX_CROWD || c.cap() < c.people {
        return err(
            "crowd.max_people",
            format!("is {}; use {} (people) to {MAX_CROWD}", c.cap(), c.people),
        );
    }
    if !(c.rate_per_min.is_finite() && c.rate_per_min >= 0.0) {
        return err(
            "crowd.rate_per_min",
            format!("is {}; use arrivals per minute >= 0", c.rate_per_min),
        );
    }
    check_ways(plan, c.line, "crowd", &c.entrances, &c.exits)?;
    check_points(plan, c.line, "crowd.destinations", &c.destinations, 0)?;
    if let Some(a) = c
        .areas
        .iter()
        .find(|a| !(a.iter().all(|v| v.is_finite()) && a[0] < a[2] && a[1] < a[3]))
    {
        return err(
            "crowd.areas",
            format!("{a:?} is not a rectangle [x0, y0, x1, y1] with x0 < x1 and y0 < y1"),
        );
    }
    if !(c.visits[0] >= 1 && c.visits[0] <= c.visits[1] && c.visits[1] <= 100) {
        return err(
            "crowd.visits",
            format!(
                "is {:?}; give [min, max] with 1 <= min <= max <= 100",
                c.visits
            ),
        );
    }
    check_span(
        plan,
        c.line,
        "crowd.speed_m_s",
        c.speed_m_s,
        (CROWD_SPEEDS_M_S[0], CROWD_SPEEDS_M_S[1]),
    )?;
    check_share(plan, c.line, "crowd.stop_share", c.stop_share)?;
    check_span(plan, c.line, "crowd.stop_s", c.stop_s, (0.0, 3600.0))?;
    check_share(plan, c.line, "crowd.group_share", c.group_share)?;
    if !(c.group_size[0] >= 2 && c.group_size[0] <= c.group_size[1] && c.group_size[1] <= 6) {
        return err(
            "crowd.group_size",
            format!(
                "is {:?}; give [min, max] with 2 <= min <= max <= 6",
                c.group_size
            ),
        );
    }
    check_span(
        plan,
        c.line,
        "crowd.spacing_m",
        [c.spacing_m; 2],
        (0.3, 3.0),
    )?;
    check_span(plan, c.line, "crowd.height_m", c.height_m, (0.5, 2.5))?;
    Ok(())
}

fn check_queue(plan: &Plan, q: &Queue) -> Result<(), PlanError> {
    let err =
        |key: &str, problem: String| Err(PlanError::new(&plan.origin, q.line, Some(key), problem));
    check_points(plan, q.line, "queue.head", &[q.head, q.tail], 2)?;
    if !(1..=MAX_CROWD).contains(&q.people) {
        return err(
            "queue.people",
            format!("is {}; use 1 to {MAX_CROWD}", q.people),
        );
    }
    check_span(
        plan,
        q.line,
        "queue.spacing_m",
        [q.spacing_m; 2],
        (0.3, 3.0),
    )?;
    if !(q.serve_s.is_finite() && q.serve_s >= 0.0) {
        return err(
            "queue.serve_s",
            format!("is {}; use seconds >= 0 (0: never served)", q.serve_s),
        );
    }
    check_ways(plan, q.line, "queue", &q.entrances, &q.exits)?;
    check_span(
        plan,
        q.line,
        "queue.speed_m_s",
        q.speed_m_s,
        (CROWD_SPEEDS_M_S[0], CROWD_SPEEDS_M_S[1]),
    )?;
    Ok(())
}

fn check_finite(plan: &Plan, line: Option<usize>, key: &str, value: f64) -> Result<(), PlanError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(PlanError::new(
            &plan.origin,
            line,
            Some(key),
            format!("is {value}; use a finite number"),
        ))
    }
}

fn check_points(
    plan: &Plan,
    line: Option<usize>,
    key: &str,
    points: &[[f64; 2]],
    min: usize,
) -> Result<(), PlanError> {
    if points.len() < min {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(key),
            format!("has {} point(s); give at least {min}", points.len()),
        ));
    }
    if let Some(p) = points
        .iter()
        .find(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(key),
            format!("point {p:?} is not finite; use finite numbers (m)"),
        ));
    }
    if let Some(w) = points.windows(2).find(|w| {
        let (a, b) = (w[0], w[1]);
        (a[0] - b[0]).hypot(a[1] - b[1]) < MIN_LENGTH_M
    }) {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(key),
            format!(
                "points {:?} and {:?} coincide; consecutive points must be at least {MIN_LENGTH_M} m apart",
                w[0], w[1]
            ),
        ));
    }
    Ok(())
}

fn check_extent(
    plan: &Plan,
    line: Option<usize>,
    shape: &str,
    z_min_m: f64,
    height_m: f64,
) -> Result<(), PlanError> {
    if !(z_min_m.is_finite() && z_min_m >= 0.0) {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(&format!("{shape}.z_min_m")),
            format!("is {z_min_m}; use a height >= 0 m"),
        ));
    }
    if !(height_m.is_finite() && height_m > z_min_m) {
        return Err(PlanError::new(
            &plan.origin,
            line,
            Some(&format!("{shape}.height_m")),
            format!("is {height_m}; the top must be above z_min_m = {z_min_m} m"),
        ));
    }
    Ok(())
}

fn check_reflectivity(
    plan: &Plan,
    line: Option<usize>,
    key: &str,
    value: f64,
) -> Result<(), PlanError> {
    if value.is_finite() && value > 0.0 && value <= 10.0 {
        Ok(())
    } else {
        Err(PlanError::new(
            &plan.origin,
            line,
            Some(key),
            format!("is {value}; use an albedo in (0, 1], or up to 10 for retro-reflectors"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "t"
[[wall]]
points = [[0, 0], [10, 0], [10, 6], [0, 6]]
closed = true

[[sensor]]
id = "a"
model = "UTM-30LX-EW"
x = 2.0
y = 3.0

[[sensor]]
id = "b"
model = "UXM-30LX-E"
x = 8.0
y = 3.0
yaw_deg = 180
"#;

    fn error_of(text: &str) -> PlanError {
        match Plan::from_toml(text, "plan.toml") {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e,
        }
    }

    /// Line (1-based) of the first line of `text` that contains `needle`.
    fn line_with(text: &str, needle: &str) -> usize {
        text.lines()
            .position(|l| l.contains(needle))
            .map(|i| i + 1)
            .unwrap_or(0)
    }

    #[test]
    fn good_plan_parses_with_defaults_and_lines() {
        let plan = Plan::from_toml(GOOD, "plan.toml").unwrap();
        assert_eq!(plan.start_unix_s, DEFAULT_START_UNIX_S);
        assert_eq!(plan.sensors.len(), 2);
        assert_eq!(plan.sensors[0].line, Some(line_with(GOOD, "[[sensor]]")));
        assert!(plan.sensors[0].has_intensities());
        assert!(!plan.sensors[1].has_intensities());
        assert_eq!(plan.sensors[1].height_m, 1.0);
    }

    #[test]
    fn unknown_key_names_file_line_key_and_the_valid_keys() {
        let text = GOOD.replace("yaw_deg = 180", "yaw_dg = 180");
        let err = error_of(&text);
        assert_eq!(err.file, "plan.toml");
        assert_eq!(err.line, Some(line_with(&text, "yaw_dg")));
        assert_eq!(err.key.as_deref(), Some("yaw_dg"));
        let shown = err.to_string();
        assert!(
            shown.starts_with(&format!("plan.toml:{}: `yaw_dg`", err.line.unwrap())),
            "{shown}"
        );
        assert!(shown.contains("yaw_deg"), "should list valid keys: {shown}");
    }

    #[test]
    fn unknown_model_lists_the_models() {
        let err = error_of(&GOOD.replace("\"UXM-30LX-E\"", "\"URG-04LXX\""));
        assert_eq!(err.key.as_deref(), Some("model"));
        for model in Model::ALL {
            assert!(err.problem.contains(model.name()), "{err}");
        }
    }

    #[test]
    fn models_parse_by_name_or_family_in_any_case() {
        for (text, model) in [
            ("UTM-30LX-EW", Model::Utm30lxEw),
            ("uxm-30lx-e", Model::Uxm30lxE),
            ("URG-04LX", Model::Urg04lx),
            ("utm", Model::Utm30lxEw),
            ("UXM", Model::Uxm30lxE),
            (" urg ", Model::Urg04lx),
        ] {
            assert_eq!(text.parse::<Model>(), Ok(model), "{text:?}");
        }
        for bad in ["", "ur", "urg-04", "UTM-30LX", "lms"] {
            let err = bad.parse::<Model>().unwrap_err();
            assert!(err.contains(&format!("{:?}", bad.trim())), "{err}");
            assert!(
                err.contains("UTM-30LX-EW") && err.contains("URG-04LX"),
                "{err}"
            );
        }
    }

    #[test]
    fn urg_parses_without_intensities_and_refuses_them() {
        let text = GOOD.replace("\"UXM-30LX-E\"", "\"URG-04LX\"");
        let plan = Plan::from_toml(&text, "plan.toml").unwrap();
        assert_eq!(plan.sensors[1].model, Model::Urg04lx);
        assert_eq!(plan.sensors[1].model.name(), "URG-04LX");
        assert_eq!(plan.sensors[1].model.geometry(), ScanGeometry::URG_04LX);
        assert!(!plan.sensors[1].has_intensities());
        let asked = text.replace("yaw_deg = 180", "yaw_deg = 180\nintensities = true");
        let err = error_of(&asked);
        assert_eq!(err.key.as_deref(), Some("sensor.intensities"));
        assert_eq!(err.line, Some(line_with(&asked, "intensities = true")));
        assert!(err.problem.contains("URG-04LX"), "{err}");
        let off = text.replace("yaw_deg = 180", "yaw_deg = 180\nintensities = false");
        assert!(Plan::from_toml(&off, "plan.toml").is_ok());
    }

    #[test]
    fn move_of_an_unknown_sensor_is_refused_with_the_known_ones() {
        let text = format!("{GOOD}\n[[move]]\nsensor = \"c\"\nat_s = 1.0\ndx = 0.5\n");
        let err = error_of(&text);
        assert_eq!(err.key.as_deref(), Some("move.sensor"));
        assert_eq!(err.line, Some(line_with(&text, "sensor = \"c\"")));
        assert!(err.problem.contains("known: a, b"), "{err}");
    }

    #[test]
    fn duplicate_sensor_id_is_refused_at_the_second() {
        let text = GOOD.replace("id = \"b\"", "id = \"a\"");
        let err = error_of(&text);
        assert_eq!(err.key.as_deref(), Some("sensor.id"));
        let second = text
            .lines()
            .enumerate()
            .filter(|(_, l)| l.contains("id = \"a\""))
            .nth(1)
            .unwrap()
            .0
            + 1;
        assert_eq!(err.line, Some(second));
    }

    #[test]
    fn degenerate_shapes_are_refused() {
        let one_point = GOOD.replace("[[0, 0], [10, 0], [10, 6], [0, 6]]", "[[0, 0]]");
        assert_eq!(error_of(&one_point).key.as_deref(), Some("wall.points"));
        let repeated = GOOD.replace(
            "[[0, 0], [10, 0], [10, 6], [0, 6]]",
            "[[0, 0], [0, 0], [3, 3]]",
        );
        assert!(error_of(&repeated).problem.contains("coincide"));
        let flat_box = format!("{GOOD}\n[[box]]\ncenter = [1, 1]\nsize = [0, 1]\n");
        assert_eq!(error_of(&flat_box).key.as_deref(), Some("box.size"));
        let low_top = format!(
            "{GOOD}\n[[circle]]\ncenter = [1, 1]\nradius_m = 0.2\nz_min_m = 1.0\nheight_m = 0.5\n"
        );
        assert_eq!(error_of(&low_top).key.as_deref(), Some("circle.height_m"));
        let still = format!("{GOOD}\n[[person]]\nwaypoints = [[1, 1], [2, 2]]\nspeed_m_s = 0\n");
        assert_eq!(error_of(&still).key.as_deref(), Some("person.speed_m_s"));
    }

    #[test]
    fn non_finite_numbers_are_refused() {
        let err = error_of(&GOOD.replace("x = 2.0", "x = nan"));
        assert_eq!(err.key.as_deref(), Some("sensor.x/y"));
        assert_eq!(err.line, Some(line_with(GOOD, "x = 2.0")));
        assert!(err.problem.contains("finite"));
        let err = error_of(&GOOD.replace("yaw_deg = 180", "yaw_deg = inf"));
        assert_eq!(err.key.as_deref(), Some("sensor.yaw_deg"));
        assert_eq!(err.line, Some(line_with(GOOD, "yaw_deg = 180")));
    }

    #[test]
    fn out_of_range_pitch_and_bad_ids_are_refused() {
        let err = error_of(&GOOD.replace("yaw_deg = 180", "pitch_deg = 80"));
        assert_eq!(err.key.as_deref(), Some("sensor.pitch_deg"));
        assert!(err.problem.contains("between -60 and 60"));
        let err = error_of(&GOOD.replace("id = \"b\"", "id = \"b/2\""));
        assert_eq!(err.key.as_deref(), Some("sensor.id"));
    }

    #[test]
    fn sensor_inside_a_pillar_is_refused() {
        let text = format!("{GOOD}\n[[circle]]\ncenter = [2.1, 3.0]\nradius_m = 0.3\n");
        let err = error_of(&text);
        assert_eq!(err.key.as_deref(), Some("sensor.x/y"));
        let pillar = line_with(&text, "[[circle]]");
        assert!(
            err.problem
                .contains(&format!("[[circle]] at line {pillar}")),
            "{err}"
        );
        // Above a low box is fine: a unit standing on a cabinet.
        let on_top = format!("{GOOD}\n[[box]]\ncenter = [2, 3]\nsize = [1, 1]\nheight_m = 0.8\n");
        assert!(Plan::from_toml(&on_top, "plan.toml").is_ok());
    }

    #[test]
    fn crowd_and_queue_keys_parse_with_defaults_and_bad_values_are_refused() {
        let doors = format!("{GOOD}\n[[door]]\nat = [5, 0]\n");
        let plan = Plan::from_toml(&format!("{doors}\n[[crowd]]\npeople = 12\n"), "p").unwrap();
        let c = &plan.crowds[0];
        assert_eq!((c.people, c.cap(), c.rate_per_min), (12, 12, 30.0));
        assert_eq!(
            (c.visits, c.speed_m_s, c.group_size),
            ([1, 4], [0.5, 1.8], [2, 3])
        );
        assert!(plan.writes_people_truth());
        assert!(!Plan::from_toml(GOOD, "p").unwrap().writes_people_truth());
        for (extra, key) in [
            ("[[crowd]]\npeople = 101\n", "crowd.people"),
            (
                "[[crowd]]\npeople = 5\nmax_people = 4\n",
                "crowd.max_people",
            ),
            ("[[crowd]]\nspeed_m_s = [0.4, 1.2]\n", "crowd.speed_m_s"),
            ("[[crowd]]\nstop_share = 1.5\n", "crowd.stop_share"),
            ("[[crowd]]\ngroup_size = [1, 3]\n", "crowd.group_size"),
            ("[[crowd]]\nareas = [[3, 3, 1, 1]]\n", "crowd.areas"),
            ("[[crowd]]\nrate_per_min = -1\n", "crowd.rate_per_min"),
            ("[[queue]]\nhead = [1, 1]\ntail = [1, 1]\n", "queue.head"),
            (
                "[[queue]]\nhead = [1, 1]\ntail = [3, 1]\nserve_s = -2\n",
                "queue.serve_s",
            ),
        ] {
            let text = format!("{doors}\n{extra}");
            let err = error_of(&text);
            assert_eq!(err.key.as_deref(), Some(key), "{extra}: {err}");
            // The line that sets the key (the table's, for keys left at their defaults).
            let name = key.rsplit('.').next().unwrap();
            let table = text.lines().count() - extra.lines().count() + 1;
            let expected = text
                .lines()
                .enumerate()
                .skip(table)
                .find(|(_, l)| l.starts_with(&format!("{name} =")))
                .map_or(table, |(i, _)| i + 1);
            assert_eq!(err.line, Some(expected), "{err}");
        }
        // No doors and no entrances: nowhere to come in.
        let err = error_of(&format!("{GOOD}\n[[crowd]]\n"));
        assert_eq!(err.key.as_deref(), Some("crowd.entrances"));
        assert!(err.problem.contains("[[door]]"), "{err}");
        let given = format!("{GOOD}\n[[crowd]]\nentrances = [[5, 3]]\n");
        assert!(Plan::from_toml(&given, "p").is_ok());
        let err = error_of(&format!("{doors}\n[[crowd]]\npepole = 3\n"));
        assert_eq!(err.key.as_deref(), Some("pepole"));
    }

    #[test]
    fn missing_file_names_the_file() {
        let err = Plan::load(Path::new("/nonexistent/plan.toml")).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("/nonexistent/plan.toml: cannot read"),
            "{err}"
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]

        /// Any value of any key of the lab (or moved) plan replaced by nonsense: an error naming the file,
        /// or a plan that simulates without panicking.
        #[test]
        fn mangled_values_are_refused_or_simulated_never_a_panic(
            pick in 0usize..10_000,
            moved in proptest::bool::ANY,
            value in proptest::sample::select(vec![
                "nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "\"x\"", "[]", "[[0, 0]]",
                "true", "{}", "0.0001", "1e-300",
            ]),
        ) {
            let lab = if moved {
                include_str!("../../fixtures/plans/moved.toml")
            } else {
                include_str!("../../fixtures/plans/lab.toml")
            };
            let keyed: Vec<usize> = lab
                .lines()
                .enumerate()
                .filter(|(_, l)| !l.starts_with('#') && l.contains(" = "))
                .map(|(i, _)| i)
                .collect();
            let target = keyed[pick % keyed.len()];
            let text: String = lab
                .lines()
                .enumerate()
                .map(|(i, l)| match l.split_once(" = ") {
                    Some((key, _)) if i == target => format!("{key} = {value}\n"),
                    _ => format!("{l}\n"),
                })
                .collect();
            match Plan::from_toml(&text, "lab.toml") {
                Err(e) => proptest::prop_assert!(e.to_string().starts_with("lab.toml"), "{e}"),
                Ok(plan) => {
                    if let Ok(mut sim) = crate::sim::Simulation::new(&plan, 1) {
                        sim.run(0.03, |_, _| Ok::<(), ()>(())).ok();
                    }
                }
            }
        }

        #[test]
        fn arbitrary_text_is_refused_with_the_file_named(text in "\\PC{0,200}") {
            if let Err(e) = Plan::from_toml(&text, "any.toml") {
                proptest::prop_assert!(e.to_string().starts_with("any.toml"));
            }
        }
    }
}
