//! Crowds and queues (`[[crowd]]`, `[[queue]]`): people who come in at entrances, walk to
//! destinations round walls and boxes, stand for a while, walk side by side in groups, and leave
//! through a door — stepped every [`TICK_S`] from one random stream, so a seed fixes them.
//!
//! [`CrowdPlan`] is the static part (the walkable grid, the ways in and out); [`CrowdRun`]
//! steps it forward on demand and answers where everyone is at any time already stepped to,
//! keeping only the last few seconds.

use std::collections::VecDeque;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::PlanError;
use super::plan::{Crowd, Plan, Queue};
use super::scene::Scene;
use super::walkable::Walkable;

/// Step of the crowd simulation, s.
pub(crate) const TICK_S: f64 = 0.05;
/// How far outside a door people appear and vanish, m.
const OUTSIDE_M: f64 = 1.0;
/// How far inside a door its inner end lies, m.
const INSIDE_M: f64 = 0.6;
/// Walking speed for stepping up in a queue, m/s.
const SHUFFLE_M_S: f64 = 0.6;
/// How far a group member turns in one tick, rad (60° a second).
const MAX_TURN_RAD: f64 = std::f64::consts::FRAC_PI_3 * TICK_S;
/// Seconds of frames kept behind the latest asked for.
const KEEP_S: f64 = 5.0;
/// Strangers pass no nearer than this, centre to centre (m): a torso is 0.45 m across.
const PASS_M: f64 = 0.55;
/// How far ahead a walker looks for someone in the way, to step round them early (m).
const LOOK_M: f64 = 0.9;
/// Turns tried to step round someone, either way (rad: 25°, 50°, 75°, and a sidestep of
/// 100° that parts two already face to face).
const DODGE_RAD: [f64; 4] = [0.436, 0.873, 1.309, 1.745];
/// How far from where a way in or out meets the floor a doorway reaches (m).
const DOORWAY_M: f64 = 1.5;
/// Ticks a walker waits, with no way round, before walking on regardless (a crowd never
/// locks up for good).
const MAX_WAIT_TICKS: u32 = 30;

/// One body at one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BodyState {
    /// `p<id>` in the truth; never reused.
    pub id: u32,
    pub pos: [f64; 2],
    /// Unit walking direction (where the torso faces).
    pub heading: [f64; 2],
    /// Distance walked so far: the gait's phase.
    pub gait_m: f64,
    pub height_m: f64,
    pub reflectivity: f64,
}

/// A body at a moment: its state and velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BodyNow {
    pub state: BodyState,
    pub vel: [f64; 2],
}

/// A way in or out: people appear at `outer` (1 m beyond a door, or the given point itself)
/// and walk straight to `inner`, or the reverse when leaving.
#[derive(Debug, Clone, Copy)]
struct Way {
    inner: [f64; 2],
    outer: [f64; 2],
    /// The furthest a body's centre may keep from the door's centre line, along the door,
    /// to the right of someone coming in (0 for a given point).
    room: [f64; 2],
}

/// Of a way's room to the side, the least share a passer keeps right by.
const KEEP_RIGHT_MIN: f64 = 0.25;

impl Way {
    /// The lane of one passage: people keep right, at `share` (in [`KEEP_RIGHT_MIN`], 1) of
    /// the room, so those coming in and those going out pass each other rather than
    /// walk through one another at the door's centre.
    fn lane(self, coming_in: bool, share: f64) -> Way {
        let k = if coming_in { share } else { -share };
        let shift = |p: [f64; 2]| [p[0] + self.room[0] * k, p[1] + self.room[1] * k];
        Way {
            inner: shift(self.inner),
            outer: shift(self.outer),
            ..self
        }
    }
}

#[derive(Debug, Clone)]
struct CrowdSpec {
    crowd: Crowd,
    entrances: Vec<Way>,
    exits: Vec<Way>,
    /// Named destinations, snapped to free space.
    destinations: Vec<[f64; 2]>,
}

#[derive(Debug, Clone)]
struct QueueSpec {
    queue: Queue,
    entrances: Vec<Way>,
    exits: Vec<Way>,
}

/// The static part of every crowd and queue of a plan.
#[derive(Debug, Clone)]
pub(crate) struct CrowdPlan {
    grid: Walkable,
    crowds: Vec<CrowdSpec>,
    queues: Vec<QueueSpec>,
}

impl CrowdPlan {
    /// Whether `p` is in a doorway (within [`DOORWAY_M`] of where a way in or out meets the
    /// floor): people squeeze past one another there rather than give way.
    fn in_doorway(&self, p: [f64; 2]) -> bool {
        let ways = self
            .crowds
            .iter()
            .flat_map(|c| c.entrances.iter().chain(&c.exits));
        let mut ways = ways.chain(
            self.queues
                .iter()
                .flat_map(|q| q.entrances.iter().chain(&q.exits)),
        );
        ways.any(|w| norm(sub(w.inner, p)) < DOORWAY_M)
    }
}

/// Whether someone now at `from` keeps clear of `strangers` at `p`: no nearer than
/// [`PASS_M`] to any, or at least no nearer than now (one already close may step away).
fn keeps_clear(strangers: &[[f64; 2]], from: [f64; 2], p: [f64; 2]) -> bool {
    strangers.iter().all(|o| {
        let d = norm(sub(*o, p));
        d >= PASS_M || d >= norm(sub(*o, from)) - 1e-6
    })
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}
fn norm(a: [f64; 2]) -> f64 {
    a[0].hypot(a[1])
}
fn unit(a: [f64; 2]) -> [f64; 2] {
    let n = norm(a).max(1e-12);
    [a[0] / n, a[1] / n]
}

/// The ways of a crowd or queue: its points, or else the plan's doors.
fn ways_of(
    plan: &Plan,
    grid: &Walkable,
    points: &[[f64; 2]],
    line: Option<usize>,
    key: &str,
) -> Result<Vec<Way>, PlanError> {
    let err = |problem: String| PlanError::new(&plan.origin, line, Some(key), problem);
    if !points.is_empty() {
        return points
            .iter()
            .map(|&p| {
                let inner = grid.nearest_free(p, 1.0).ok_or_else(|| {
                    err(format!(
                        "{p:?} is not in free space people can reach; move it off walls and boxes"
                    ))
                })?;
                Ok(Way {
                    inner,
                    outer: p,
                    room: [0.0, 0.0],
                })
            })
            .collect();
    }
    plan.doors
        .iter()
        .map(|d| {
            // The wall segment the door is cut into: the nearest one.
            let seg = plan
                .walls
                .iter()
                .flat_map(|w| w.segments())
                .map(|(a, b)| {
                    let e = sub(b, a);
                    let t = ((d.at[0] - a[0]) * e[0] + (d.at[1] - a[1]) * e[1])
                        / (e[0] * e[0] + e[1] * e[1]).max(1e-12);
                    let t = t.clamp(0.0, 1.0);
                    let foot = [a[0] + e[0] * t, a[1] + e[1] * t];
                    (norm(sub(d.at, foot)), foot, unit(e))
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            let Some((_, foot, along)) = seg else {
                return Err(err("the plan has no walls for its doors".into()));
            };
            let normal = [-along[1], along[0]];
            // Inside is the side where the inner end is free; prefer a side that is not.
            let side = |s: f64| [foot[0] + normal[0] * s, foot[1] + normal[1] * s];
            let (inner, outer, inward) =
                if grid.is_free(side(INSIDE_M)) && !grid.is_free(side(-INSIDE_M)) {
                    (side(INSIDE_M), side(-OUTSIDE_M), normal)
                } else if grid.is_free(side(-INSIDE_M)) {
                    (side(-INSIDE_M), side(OUTSIDE_M), [-normal[0], -normal[1]])
                } else {
                return Err(PlanError::new(
                    &plan.origin,
                    d.line,
                    Some("door.at"),
                    format!(
                        "people of a [[{}]] cannot walk through the door at {:?}: it is too narrow or blocked (widen it to 0.9 m or more)",
                        key.split('.').next().unwrap_or("crowd"),
                        d.at
                    ),
                ));
            };
            // A body's half width (and a little) clear of each jamb; the inner end must
            // stay walkable across the lane.
            let right = [inward[1], -inward[0]];
            let mut half = (d.width_m / 2.0 - 0.3).max(0.0);
            let at = |k: f64| [inner[0] + right[0] * k, inner[1] + right[1] * k];
            while half > 0.0 && !(grid.is_free(at(half)) && grid.is_free(at(-half))) {
                half -= 0.05;
            }
            let half = half.max(0.0);
            Ok(Way {
                inner,
                outer,
                room: [right[0] * half, right[1] * half],
            })
        })
        .collect()
}

impl CrowdPlan {
    /// `None` when the plan has no crowd and no queue.
    pub fn build(plan: &Plan, scene: &Scene) -> Result<Option<CrowdPlan>, PlanError> {
        if plan.crowds.is_empty() && plan.queues.is_empty() {
            return Ok(None);
        }
        let grid = Walkable::build(plan, scene);
        let mut crowds = Vec::new();
        for c in &plan.crowds {
            let entrances = ways_of(plan, &grid, &c.entrances, c.line, "crowd.entrances")?;
            let exits = if c.exits.is_empty() {
                entrances.clone()
            } else {
                ways_of(plan, &grid, &c.exits, c.line, "crowd.exits")?
            };
            let destinations = c
                .destinations
                .iter()
                .map(|&p| {
                    grid.nearest_free(p, 1.0).ok_or_else(|| {
                        PlanError::new(
                            &plan.origin,
                            c.line,
                            Some("crowd.destinations"),
                            format!("{p:?} is not in free space people can reach"),
                        )
                    })
                })
                .collect::<Result<_, _>>()?;
            crowds.push(CrowdSpec {
                crowd: c.clone(),
                entrances,
                exits,
                destinations,
            });
        }
        let mut queues = Vec::new();
        for q in &plan.queues {
            for k in 0..q.people {
                let place = q.place(k);
                if !grid.is_free(place) || !grid.line_free(q.place(0), place) {
                    return Err(PlanError::new(
                        &plan.origin,
                        q.line,
                        Some("queue.head"),
                        format!(
                            "place {} of the queue, {place:?}, is not free space people can stand in (0.25 m clear of walls and boxes); move or shorten the line",
                            k + 1
                        ),
                    ));
                }
            }
            let entrances = ways_of(plan, &grid, &q.entrances, q.line, "queue.entrances")?;
            let exits = if q.exits.is_empty() {
                entrances.clone()
            } else {
                ways_of(plan, &grid, &q.exits, q.line, "queue.exits")?
            };
            queues.push(QueueSpec {
                queue: q.clone(),
                entrances,
                exits,
            });
        }
        Ok(Some(CrowdPlan {
            grid,
            crowds,
            queues,
        }))
    }

    /// A fresh run from time 0 (every call starts the same way for the same stream).
    pub fn start(&self, rng: ChaCha8Rng) -> CrowdRun<'_> {
        let mut run = CrowdRun {
            plan: self,
            rng,
            agents: Vec::new(),
            next_id: 1,
            tick: 0,
            next_arrival_s: Vec::new(),
            lines: self.queues.iter().map(|_| Vec::new()).collect(),
            next_serve_s: self.queues.iter().map(|q| q.queue.serve_s).collect(),
            frames: VecDeque::new(),
            first_frame: 0,
        };
        run.populate();
        for i in 0..run.agents.len() {
            if run.agents[i].follow.is_some() {
                run.step_member(i);
            }
        }
        run.record_frame();
        run
    }
}

#[derive(Debug, Clone)]
enum Goal {
    /// Walk there, round whatever is in the way.
    Point([f64; 2]),
    /// Walk straight there (through a door).
    Straight([f64; 2]),
    Stand(f64),
    /// Stand in line `q` until served.
    InLine(usize),
    Vanish,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Source {
    Crowd(usize),
    Queue(usize),
}

#[derive(Debug, Clone)]
struct Agent {
    body: BodyState,
    source: Source,
    speed_m_s: f64,
    goals: VecDeque<Goal>,
    route: Vec<[f64; 2]>,
    route_next: usize,
    stand_until_s: Option<f64>,
    /// (leader id, rank 1.., side ±1, lateral share 0..1) for a group member.
    follow: Option<(u32, u32, f64, f64)>,
    /// Where the body was over the last seconds (leaders only; members fall in behind).
    trail: VecDeque<[f64; 2]>,
    spacing_m: f64,
    /// Ticks in a row it waited for someone in its way.
    waited: u32,
    gone: bool,
}

impl Agent {
    /// Its group's leader's id (its own when alone or leading): a group walks close together.
    fn group(&self) -> u32 {
        self.follow.map_or(self.body.id, |f| f.0)
    }
}

/// A crowd being stepped forward.
pub(crate) struct CrowdRun<'a> {
    plan: &'a CrowdPlan,
    rng: ChaCha8Rng,
    agents: Vec<Agent>,
    next_id: u32,
    tick: u64,
    next_arrival_s: Vec<f64>,
    /// Per queue, the ids in line, front first.
    lines: Vec<Vec<u32>>,
    next_serve_s: Vec<f64>,
    /// Bodies at ticks `first_frame..`, each sorted by id.
    frames: VecDeque<Vec<BodyState>>,
    first_frame: u64,
}

/// Uniform in `[lo, hi]` (just `lo` when they are equal).
fn uniform(rng: &mut impl Rng, span: [f64; 2]) -> f64 {
    if span[1] > span[0] {
        rng.random_range(span[0]..=span[1])
    } else {
        span[0]
    }
}

fn exp_wait(rng: &mut impl Rng, rate_per_min: f64) -> f64 {
    if rate_per_min <= 0.0 {
        return f64::INFINITY;
    }
    -(1.0 - rng.random::<f64>()).ln() * 60.0 / rate_per_min
}

impl CrowdRun<'_> {
    fn new_agent(
        &mut self,
        source: Source,
        pos: [f64; 2],
        speed_m_s: f64,
        heights: [f64; 2],
    ) -> Agent {
        let id = self.next_id;
        self.next_id += 1;
        let height_m = uniform(&mut self.rng, heights);
        let reflectivity = 0.15 + 0.6 * self.rng.random::<f64>();
        let angle = self.rng.random::<f64>() * std::f64::consts::TAU;
        Agent {
            body: BodyState {
                id,
                pos,
                heading: [angle.cos(), angle.sin()],
                gait_m: self.rng.random::<f64>() * 1.4,
                height_m,
                reflectivity,
            },
            source,
            speed_m_s,
            goals: VecDeque::new(),
            route: Vec::new(),
            route_next: 0,
            stand_until_s: None,
            follow: None,
            trail: VecDeque::new(),
            spacing_m: 0.7,
            waited: 0,
            gone: false,
        }
    }

    /// A destination of crowd `c`.
    fn destination(&mut self, c: usize) -> Option<[f64; 2]> {
        let spec = &self.plan.crowds[c];
        let (points, areas) = (spec.destinations.len(), spec.crowd.areas.len());
        if points + areas == 0 {
            return self.plan.grid.random_free(&mut self.rng);
        }
        let pick = self.rng.random_range(0..points + areas);
        if pick < points {
            return spec.destinations.get(pick).copied();
        }
        let a = spec.crowd.areas[pick - points];
        for _ in 0..20 {
            let p = [
                self.rng.random_range(a[0]..a[2]),
                self.rng.random_range(a[1]..a[3]),
            ];
            if let Some(q) = self.plan.grid.nearest_free(p, 1.0) {
                return Some(q);
            }
        }
        self.plan.grid.random_free(&mut self.rng)
    }

    /// Goals for a visit of crowd `c`: `visits` destinations, stops, then out.
    fn visit_goals(&mut self, c: usize, visits: u32) -> VecDeque<Goal> {
        let crowd = self.plan.crowds[c].crowd.clone();
        let mut goals = VecDeque::new();
        for _ in 0..visits {
            if let Some(p) = self.destination(c) {
                goals.push_back(Goal::Point(p));
                if self.rng.random::<f64>() < crowd.stop_share {
                    goals.push_back(Goal::Stand(uniform(&mut self.rng, crowd.stop_s)));
                }
            }
        }
        let exits = &self.plan.crowds[c].exits;
        let way = exits[self.rng.random_range(0..exits.len())];
        let share = self.rng.random_range(KEEP_RIGHT_MIN..=1.0);
        goals.extend(leave_by(way.lane(false, share)));
        goals
    }

    /// Group size for an arrival of crowd `c` (1 = alone).
    fn group_size(&mut self, c: usize) -> u32 {
        let crowd = &self.plan.crowds[c].crowd;
        let (share, [lo, hi]) = (crowd.group_share, crowd.group_size);
        if self.rng.random::<f64>() < share {
            self.rng.random_range(lo..=hi)
        } else {
            1
        }
    }

    /// Adds a leader and its group members; returns how many.
    fn spawn_group(&mut self, c: usize, size: u32, pos: [f64; 2], goals: VecDeque<Goal>) -> u32 {
        let crowd = self.plan.crowds[c].crowd.clone();
        // A group walks at one pace: the slowest of its members'.
        let speed = (0..size)
            .map(|_| uniform(&mut self.rng, crowd.speed_m_s))
            .fold(f64::INFINITY, f64::min);
        let mut leader = self.new_agent(Source::Crowd(c), pos, speed, crowd.height_m);
        leader.goals = goals;
        leader.spacing_m = crowd.spacing_m;
        let leader_id = leader.body.id;
        let heading = leader.body.heading;
        self.agents.push(leader);
        for k in 1..size {
            let mut member = self.new_agent(Source::Crowd(c), pos, speed, crowd.height_m);
            let rank = k.div_ceil(2);
            let side = if k % 2 == 1 { 1.0 } else { -1.0 };
            member.follow = Some((leader_id, rank, side, 1.0));
            member.spacing_m = crowd.spacing_m;
            member.body.heading = heading;
            self.agents.push(member);
        }
        size
    }

    /// The people inside at the start, each at one of its crowd's destinations.
    fn populate(&mut self) {
        for c in 0..self.plan.crowds.len() {
            let crowd = self.plan.crowds[c].crowd.clone();
            let mut placed = 0;
            while placed < crowd.people {
                let size = self.group_size(c).min(crowd.people - placed);
                // Not on top of someone already there (a few tries; a packed floor takes
                // what it gets).
                let mut pos = None;
                for _ in 0..20 {
                    pos = self.destination(c);
                    let Some(p) = pos else { break };
                    if !self.someone_at(p) {
                        break;
                    }
                }
                let Some(pos) = pos else {
                    break;
                };
                let visits = self.rng.random_range(0..crowd.visits[1]);
                let mut goals = self.visit_goals(c, visits);
                if self.rng.random::<f64>() < crowd.stop_share {
                    goals.push_front(Goal::Stand(self.rng.random::<f64>() * crowd.stop_s[1]));
                }
                placed += self.spawn_group(c, size, pos, goals);
            }
            let wait = exp_wait(&mut self.rng, crowd.rate_per_min);
            self.next_arrival_s.push(wait);
        }
        for q in 0..self.plan.queues.len() {
            let spec = self.plan.queues[q].queue.clone();
            let facing = unit(sub(spec.head, spec.tail));
            for k in 0..spec.people {
                let speed = uniform(&mut self.rng, spec.speed_m_s);
                let mut agent =
                    self.new_agent(Source::Queue(q), spec.place(k), speed, [1.55, 1.95]);
                agent.body.heading = facing;
                agent.goals.push_back(Goal::InLine(q));
                self.lines[q].push(agent.body.id);
                self.agents.push(agent);
            }
        }
    }

    fn now_s(&self) -> f64 {
        self.tick as f64 * TICK_S
    }

    /// New arrivals and queue service due at this tick.
    fn arrivals(&mut self) {
        let now = self.now_s();
        for c in 0..self.plan.crowds.len() {
            while self.next_arrival_s[c] <= now {
                let crowd = self.plan.crowds[c].crowd.clone();
                let wait = exp_wait(&mut self.rng, crowd.rate_per_min);
                self.next_arrival_s[c] += wait;
                let size = self.group_size(c);
                let inside = self
                    .agents
                    .iter()
                    .filter(|a| a.source == Source::Crowd(c) && !a.gone)
                    .count() as u32;
                let entrances = &self.plan.crowds[c].entrances;
                let way = entrances[self.rng.random_range(0..entrances.len())]
                    .lane(true, self.rng.random_range(KEEP_RIGHT_MIN..=1.0));
                let visits = self.rng.random_range(crowd.visits[0]..=crowd.visits[1]);
                let mut goals = self.visit_goals(c, visits);
                if inside + size > crowd.cap() {
                    continue;
                }
                goals.push_front(Goal::Straight(way.inner));
                // Behind whoever is still coming in at a door, not on top of them (an
                // entrance given as a point has no behind: they appear there).
                let out = sub(way.outer, way.inner);
                let out = (norm(out) > 1e-6).then(|| unit(out));
                let mut at = way.outer;
                for _ in 0..100 {
                    let Some(out) = out.filter(|_| self.someone_at(at)) else {
                        break;
                    };
                    at = [at[0] + out[0] * PASS_M, at[1] + out[1] * PASS_M];
                }
                self.spawn_group(c, size, at, goals);
            }
        }
        for q in 0..self.plan.queues.len() {
            let spec = self.plan.queues[q].clone();
            if spec.queue.serve_s <= 0.0 || self.next_serve_s[q] > now {
                continue;
            }
            self.next_serve_s[q] += spec.queue.serve_s;
            let Some(&front) = self.lines[q].first() else {
                continue;
            };
            let ready = self
                .agents
                .iter()
                .find(|a| a.body.id == front)
                .is_some_and(|a| norm(sub(a.body.pos, spec.queue.place(0))) < 0.1);
            if !ready {
                continue;
            }
            self.lines[q].remove(0);
            let way = spec.exits[self.rng.random_range(0..spec.exits.len())]
                .lane(false, self.rng.random_range(KEEP_RIGHT_MIN..=1.0));
            if let Some(a) = self.agents.iter_mut().find(|a| a.body.id == front) {
                a.goals = leave_by(way);
                a.route.clear();
            }
            let way = spec.entrances[self.rng.random_range(0..spec.entrances.len())]
                .lane(true, self.rng.random_range(KEEP_RIGHT_MIN..=1.0));
            let speed = uniform(&mut self.rng, spec.queue.speed_m_s);
            let mut agent = self.new_agent(Source::Queue(q), way.outer, speed, [1.55, 1.95]);
            agent.goals = VecDeque::from([Goal::Straight(way.inner), Goal::InLine(q)]);
            self.lines[q].push(agent.body.id);
            self.agents.push(agent);
        }
    }

    /// Moves a leader (or anyone alone) one tick along its goals.
    fn step_leader(&mut self, index: usize) {
        let now = self.now_s();
        let grid = &self.plan.grid;
        let Some(agent) = self.agents.get_mut(index) else {
            return;
        };
        let mut budget_m = agent.speed_m_s * TICK_S;
        for _ in 0..6 {
            if let Some(&target) = agent.route.get(agent.route_next) {
                let to = sub(target, agent.body.pos);
                let d = norm(to);
                if d > 1e-9 {
                    agent.body.heading = unit(to);
                }
                if d <= budget_m {
                    agent.body.pos = target;
                    agent.body.gait_m += d;
                    budget_m -= d;
                    agent.route_next += 1;
                    continue;
                }
                let u = unit(to);
                agent.body.pos = [
                    agent.body.pos[0] + u[0] * budget_m,
                    agent.body.pos[1] + u[1] * budget_m,
                ];
                agent.body.gait_m += budget_m;
                break;
            }
            if let Some(until) = agent.stand_until_s {
                if now < until {
                    break;
                }
                agent.stand_until_s = None;
            }
            let Some(goal) = agent.goals.front().cloned() else {
                agent.gone = true;
                break;
            };
            match goal {
                Goal::InLine(q) => {
                    let Some(k) = self
                        .lines
                        .get(q)
                        .and_then(|l| l.iter().position(|id| *id == agent.body.id))
                    else {
                        agent.goals.pop_front();
                        continue;
                    };
                    let Some(spec) = self.plan.queues.get(q) else {
                        break;
                    };
                    let place = spec.queue.place(k as u32);
                    let d = norm(sub(place, agent.body.pos));
                    if d < 0.02 {
                        agent.body.heading = unit(sub(spec.queue.head, spec.queue.tail));
                        break;
                    }
                    // Stepping up along the line is a shuffle; joining it is a walk.
                    agent.route = if d < 1.5 * spec.queue.spacing_m {
                        budget_m = budget_m.min(SHUFFLE_M_S * TICK_S);
                        vec![place]
                    } else {
                        grid.path(agent.body.pos, place)
                            .unwrap_or_else(|| vec![place])
                    };
                    agent.route_next = 0;
                    if agent.route.first() == Some(&agent.body.pos) {
                        agent.route_next = 1;
                    }
                }
                Goal::Point(p) => {
                    agent.goals.pop_front();
                    if let Some(route) = grid.path(agent.body.pos, p) {
                        agent.route = route;
                        agent.route_next = 1;
                    }
                }
                Goal::Straight(p) => {
                    agent.goals.pop_front();
                    agent.route = vec![p];
                    agent.route_next = 0;
                }
                Goal::Stand(s) => {
                    agent.goals.pop_front();
                    agent.stand_until_s = Some(now + s);
                }
                Goal::Vanish => {
                    agent.gone = true;
                    break;
                }
            }
        }
        agent.trail.push_front(agent.body.pos);
        agent.trail.truncate(80);
    }

    /// Whether someone stands where a newcomer at `p` would be on top of them (both bodies
    /// and room to pass: within twice [`PASS_M`]).
    fn someone_at(&self, p: [f64; 2]) -> bool {
        self.agents
            .iter()
            .any(|a| !a.gone && norm(sub(a.body.pos, p)) < 2.0 * PASS_M)
    }

    /// Where strangers to agent `i` stand that a step from `from` of up to `reach_m` could
    /// come near.
    fn strangers_near(&self, i: usize, from: [f64; 2], reach_m: f64) -> Vec<[f64; 2]> {
        let group = self.agents[i].group();
        self.agents
            .iter()
            .enumerate()
            .filter(|(j, o)| *j != i && !o.gone && o.group() != group)
            .map(|(_, o)| o.body.pos)
            .filter(|q| norm(sub(*q, from)) < reach_m + PASS_M)
            .collect()
    }

    /// Leader `i` just stepped from `before`: where that step walks into a stranger (nearer
    /// than [`PASS_M`] and closing), it steps round them instead, turning away from the
    /// side they are on (to the right when dead ahead), preferring a way clear for
    /// [`LOOK_M`]; with no way round it waits (for [`MAX_WAIT_TICKS`] at most). People do
    /// not walk through one another, and two bodies in one place are no test of a tracker.
    /// Off the walkable floor and in doorways no one gives way.
    fn give_way(&mut self, i: usize, before: BodyState) {
        let grid = &self.plan.grid;
        let (from, to) = (before.pos, self.agents[i].body.pos);
        let step = norm(sub(to, from));
        if step < 1e-9
            || self.agents[i].gone
            || !grid.is_free(from)
            || !grid.is_free(to)
            || self.plan.in_doorway(from)
        {
            self.agents[i].waited = 0;
            return;
        }
        if self.agents[i].waited >= MAX_WAIT_TICKS {
            self.agents[i].waited = 0;
            return;
        }
        let others = self.strangers_near(i, from, LOOK_M.max(step));
        let clear = |p: [f64; 2]| keeps_clear(&others, from, p);
        let u = unit(sub(to, from));
        let ahead = [from[0] + u[0] * LOOK_M, from[1] + u[1] * LOOK_M];
        if clear(to) && clear(ahead) {
            self.agents[i].waited = 0;
            return;
        }
        let target = {
            let a = &self.agents[i];
            a.route.get(a.route_next).copied()
        };
        // Going out through a doorway (the next waypoint beyond the floor): no room to step
        // round anyone there.
        if target.is_some_and(|t| !grid.line_free(to, t)) {
            self.agents[i].waited = 0;
            return;
        }
        // The stranger nearest the way ahead: turn away from their side.
        let side = others
            .iter()
            .min_by(|a, b| norm(sub(**a, ahead)).total_cmp(&norm(sub(**b, ahead))))
            .map(|o| {
                let cross = u[0] * (o[1] - from[1]) - u[1] * (o[0] - from[0]);
                if cross > 1e-3 { -1.0 } else { 1.0 }
            })
            .unwrap_or(1.0);
        let turned = |rad: f64| {
            let (sin, cos) = rad.sin_cos();
            [u[0] * cos - u[1] * sin, u[0] * sin + u[1] * cos]
        };
        // A turn to the right is negative; `side` 1.0 means the stranger is not on the left.
        let mut ways = vec![u];
        for rad in DODGE_RAD {
            ways.push(turned(-side * rad));
            ways.push(turned(side * rad));
        }
        let mut first_clear = None;
        let mut chosen = None;
        for v in ways {
            let p = [from[0] + v[0] * step, from[1] + v[1] * step];
            // A way round that leaves the next waypoint in sight (a doorway's is narrow).
            let sight = target.is_none_or(|t| grid.line_free(p, t));
            if !grid.is_free(p) || !grid.line_free(from, p) || !sight || !clear(p) {
                continue;
            }
            let look = [from[0] + v[0] * LOOK_M, from[1] + v[1] * LOOK_M];
            if clear(look) {
                chosen = Some((p, v));
                break;
            }
            first_clear.get_or_insert((p, v));
        }
        let agent = &mut self.agents[i];
        match chosen.or(first_clear) {
            Some((p, v)) => {
                agent.body.pos = p;
                agent.body.heading = v;
                agent.body.gait_m = before.gait_m + step;
                agent.waited = 0;
            }
            None => {
                agent.body.pos = from;
                agent.body.gait_m = before.gait_m;
                agent.waited += 1;
                // Someone stands where it was going (a spot to visit, not a way out): it
                // stops short, there.
                let end = agent.route.last().copied().unwrap_or(from);
                let visiting = matches!(
                    agent.goals.front(),
                    None | Some(Goal::Stand(_) | Goal::Point(_))
                );
                if visiting && norm(sub(end, from)) < PASS_M + LOOK_M {
                    agent.route_next = agent.route.len();
                }
            }
        }
        // The trail its group follows: where it went, not where it waited.
        if agent.body.pos == from {
            agent.trail.pop_front();
        } else if let Some(last) = agent.trail.front_mut() {
            *last = agent.body.pos;
        }
    }

    /// Moves a group member beside its leader: as far to the side as the way is clear,
    /// falling in behind on the leader's trail where it is not.
    fn step_member(&mut self, index: usize) {
        let grid = &self.plan.grid;
        let Some((leader_id, rank, side, share)) = self.agents.get(index).and_then(|a| a.follow)
        else {
            return;
        };
        let Some(leader) = self.agents.iter().find(|a| a.body.id == leader_id) else {
            if let Some(a) = self.agents.get_mut(index) {
                a.gone = true;
            }
            return;
        };
        if leader.gone {
            // The leader went out: the member follows its trail out on its own.
            let mut back = f64::from(rank) * self.agents[index].spacing_m * (1.0 - share);
            let mut route = Vec::new();
            let mut at = leader.body.pos;
            route.push(at);
            for &p in leader.trail.iter() {
                back -= norm(sub(p, at));
                if back <= 0.0 {
                    break;
                }
                route.push(p);
                at = p;
            }
            route.reverse();
            if let Some(a) = self.agents.get_mut(index) {
                a.follow = None;
                a.route = route;
                a.route_next = 0;
                a.goals = VecDeque::from([Goal::Vanish]);
            }
            return;
        }
        let spacing = self.agents[index].spacing_m;
        // The member turns with its leader at a walker's pace, not at once.
        let own = self.agents[index].body.heading;
        let target = leader.body.heading;
        let turn = (own[0] * target[1] - own[1] * target[0])
            .atan2(own[0] * target[0] + own[1] * target[1]);
        let turn = turn.clamp(-MAX_TURN_RAD, MAX_TURN_RAD);
        let (sin, cos) = turn.sin_cos();
        let heading = unit([own[0] * cos - own[1] * sin, own[0] * sin + own[1] * cos]);
        let lateral = [-heading[1] * side, heading[0] * side];
        let offset_m = f64::from(rank) * spacing;
        // The point `back_m` behind the leader along its trail.
        let behind = |back_m: f64| {
            let mut left = back_m;
            let mut at = leader.body.pos;
            for &p in leader.trail.iter() {
                let d = norm(sub(p, at));
                if d >= left && d > 0.0 {
                    let f = left / d;
                    return [at[0] + (p[0] - at[0]) * f, at[1] + (p[1] - at[1]) * f];
                }
                left -= d;
                at = p;
            }
            at
        };
        let place = |s: f64| {
            let anchor = behind((1.0 - s) * offset_m);
            let p = [
                anchor[0] + lateral[0] * s * offset_m,
                anchor[1] + lateral[1] * s * offset_m,
            ];
            (anchor, p)
        };
        // Beside the leader only where no stranger is in the way.
        let own_pos = self.agents[index].body.pos;
        let strangers = self.strangers_near(index, own_pos, 2.0 * offset_m);
        let fits = |s: f64| {
            let (anchor, p) = place(s);
            s == 0.0 || (grid.is_free(p) && grid.line_free(anchor, p))
        };
        // Strangers in the way close the group in gradually, as a narrows ahead does.
        let clear_of_strangers = |s: f64| {
            let (_, p) = place(s);
            s == 0.0 || keeps_clear(&strangers, own_pos, p)
        };
        // Look along the leader's way for narrows coming up, to close in gradually.
        let mut ahead: Vec<([f64; 2], [f64; 2])> = Vec::new();
        let mut at = leader.body.pos;
        let mut walked = 0.0;
        for &next in leader.route.iter().skip(leader.route_next) {
            let d = norm(sub(next, at));
            if d < 1e-9 {
                continue;
            }
            let u = unit(sub(next, at));
            for look in [0.5, 1.0, 1.5] {
                if look > walked && look <= walked + d {
                    let f = look - walked;
                    ahead.push(([at[0] + u[0] * f, at[1] + u[1] * f], u));
                }
            }
            walked += d;
            at = next;
            if walked >= 1.5 {
                break;
            }
        }
        let fits_ahead = |s: f64| {
            ahead.iter().all(|(c, u)| {
                let lat = [-u[1] * side, u[0] * side];
                let p = [c[0] + lat[0] * s * offset_m, c[1] + lat[1] * s * offset_m];
                grid.is_free(p) && grid.line_free(*c, p)
            })
        };
        let mut wanted = 1.0;
        while wanted > 0.0 && !(fits(wanted) && fits_ahead(wanted) && clear_of_strangers(wanted)) {
            wanted = (wanted - 0.1f64).max(0.0);
        }
        // Widen and narrow gradually; narrow at once only where there is no room now.
        let mut s = if share >= 1.0 && wanted >= 1.0 {
            1.0
        } else {
            wanted.clamp(share - 0.05, share + 0.04).clamp(0.0, 1.0)
        };
        while s > 0.0 && !fits(s) {
            s = (s - 0.05).max(0.0);
        }
        let (_, p) = place(s);
        let Some(agent) = self.agents.get_mut(index) else {
            return;
        };
        agent.body.gait_m += norm(sub(p, agent.body.pos));
        agent.body.pos = p;
        agent.body.heading = heading;
        agent.follow = Some((leader_id, rank, side, s));
    }

    fn record_frame(&mut self) {
        let mut frame: Vec<BodyState> = self
            .agents
            .iter()
            .filter(|a| !a.gone)
            .map(|a| a.body)
            .collect();
        frame.sort_by_key(|b| b.id);
        self.frames.push_back(frame);
    }

    /// One tick forward.
    fn step(&mut self) {
        self.tick += 1;
        self.arrivals();
        for i in 0..self.agents.len() {
            if self.agents[i].follow.is_none() {
                let before = self.agents[i].body;
                self.step_leader(i);
                self.give_way(i, before);
            }
        }
        for i in 0..self.agents.len() {
            if self.agents[i].follow.is_some() {
                self.step_member(i);
            }
        }
        self.agents.retain(|a| !a.gone);
        self.record_frame();
    }

    /// Everyone at `t_s` after the start: positions between ticks are interpolated and the
    /// velocity is that of the tick. Times must not go back more than a few seconds.
    pub fn bodies_at(&mut self, t_s: f64) -> Vec<BodyNow> {
        let t_s = t_s.max(0.0);
        let k = (t_s / TICK_S).floor() as u64;
        while self.first_frame + self.frames.len() as u64 <= k + 1 {
            self.step();
        }
        let keep_from = k.saturating_sub((KEEP_S / TICK_S) as u64);
        while self.first_frame < keep_from && self.frames.len() > 2 {
            self.frames.pop_front();
            self.first_frame += 1;
        }
        let k = k.max(self.first_frame);
        let index = (k - self.first_frame) as usize;
        let (Some(a), Some(b)) = (self.frames.get(index), self.frames.get(index + 1)) else {
            return Vec::new();
        };
        let f = (t_s / TICK_S - k as f64).clamp(0.0, 1.0);
        a.iter()
            .map(|s| match b.binary_search_by_key(&s.id, |n| n.id) {
                Ok(j) => {
                    let n = &b[j];
                    let vel = [
                        (n.pos[0] - s.pos[0]) / TICK_S,
                        (n.pos[1] - s.pos[1]) / TICK_S,
                    ];
                    BodyNow {
                        state: BodyState {
                            pos: [
                                s.pos[0] + vel[0] * f * TICK_S,
                                s.pos[1] + vel[1] * f * TICK_S,
                            ],
                            gait_m: s.gait_m + (n.gait_m - s.gait_m) * f,
                            heading: n.heading,
                            ..*s
                        },
                        vel,
                    }
                }
                Err(_) => BodyNow {
                    state: *s,
                    vel: [0.0, 0.0],
                },
            })
            .collect()
    }
}

/// Goals that take someone out through `way`.
fn leave_by(way: Way) -> VecDeque<Goal> {
    VecDeque::from([
        Goal::Point(way.inner),
        Goal::Straight(way.outer),
        Goal::Vanish,
    ])
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, BTreeSet};

    use rand::SeedableRng;

    use super::*;

    /// A 16 × 10 m room with a partition, a box and a pillar, doors south and east.
    const ROOM: &str = r#"
name = "room"
[[wall]]
points = [[0, 0], [16, 0], [16, 10], [0, 10]]
closed = true
[[wall]]
points = [[8, 0], [8, 6]]
[[door]]
at = [4, 0]
width_m = 1.2
[[door]]
at = [16, 7]
width_m = 1.0
[[box]]
center = [4, 6]
size = [2, 1]
height_m = 1.2
[[circle]]
center = [12, 4]
radius_m = 0.4
"#;

    fn plan_with(extra: &str) -> (Plan, Scene) {
        let plan = Plan::from_toml(&format!("{ROOM}\n{extra}"), "room.toml").unwrap();
        let scene = Scene::build(&plan).unwrap();
        (plan, scene)
    }

    fn rng(seed: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(seed)
    }

    /// Every tick's bodies for `seconds`.
    fn frames(crowd: &CrowdPlan, seed: u64, seconds: f64) -> Vec<Vec<BodyState>> {
        let mut run = crowd.start(rng(seed));
        let ticks = (seconds / TICK_S) as u64;
        let mut out = vec![run.frames[0].clone()];
        for _ in 0..ticks {
            run.step();
            out.push(run.frames.back().cloned().unwrap_or_default());
        }
        out
    }

    fn crowd_of(extra: &str) -> (Plan, Scene, CrowdPlan) {
        let (plan, scene) = plan_with(extra);
        let crowd = CrowdPlan::build(&plan, &scene).unwrap().unwrap();
        (plan, scene, crowd)
    }

    /// Each id's positions, in time order.
    fn tracks(frames: &[Vec<BodyState>]) -> BTreeMap<u32, Vec<[f64; 2]>> {
        let mut out: BTreeMap<u32, Vec<[f64; 2]>> = BTreeMap::new();
        for frame in frames {
            for b in frame {
                out.entry(b.id).or_default().push(b.pos);
            }
        }
        out
    }

    #[test]
    fn arrivals_come_at_the_rate() {
        // Nobody leaves within the window: many far destinations, long stops.
        let (_, _, crowd) = crowd_of(
            "[[crowd]]\npeople = 0\nmax_people = 100\nrate_per_min = 60\ngroup_share = 0\n\
             visits = [20, 20]\nstop_share = 1\nstop_s = [100, 100]\n",
        );
        let all = frames(&crowd, 3, 40.0);
        let spawned = tracks(&all).len();
        // Poisson, 40 expected (σ ≈ 6.3).
        assert!((22..=58).contains(&spawned), "{spawned} arrivals in 40 s");
        assert!(all[0].is_empty());
    }

    #[test]
    fn everyone_leaves_through_a_door_and_nobody_walks_through_a_wall() {
        let (plan, scene, crowd) = crowd_of(
            "[[crowd]]\npeople = 12\nrate_per_min = 20\nmax_people = 14\nvisits = [1, 2]\n\
             stop_s = [1, 3]\ngroup_share = 0.5\n",
        );
        for seed in [5, 6, 7] {
            check_walks(&plan, &scene, &frames(&crowd, seed, 90.0), 12);
        }
    }

    /// Nobody jumps or steps through anything solid, and whoever is gone by the end left
    /// from outside a door (at least `min_left` of them).
    fn check_walks(plan: &Plan, scene: &Scene, all: &[Vec<BodyState>], min_left: usize) {
        let tracks = tracks(all);
        let last = all
            .last()
            .map(|f| f.iter().map(|b| b.id).collect::<BTreeSet<_>>());
        let mut left = 0;
        for (id, track) in &tracks {
            for w in track.windows(2) {
                let step = norm(sub(w[1], w[0]));
                if step >= 0.2 {
                    let i = track.iter().position(|p| p == &w[1]).unwrap();
                    panic!(
                        "p{id} jumps {step} m in one tick: {:?}",
                        &track[i.saturating_sub(5)..(i + 3).min(track.len())]
                    );
                }
                assert!(
                    !scene.step_crosses_solid(w[0], w[1]),
                    "p{id} steps through something solid from {:?} to {:?}",
                    w[0],
                    w[1]
                );
            }
            if last.as_ref().is_some_and(|l| l.contains(id)) {
                continue;
            }
            left += 1;
            // Gone from outside a door: 1 m beyond it, in its width.
            let end = track[track.len() - 1];
            let given = plan
                .crowds
                .iter()
                .flat_map(|c| c.entrances.iter().chain(&c.exits))
                .chain(
                    plan.queues
                        .iter()
                        .flat_map(|q| q.entrances.iter().chain(&q.exits)),
                );
            let near_door = plan
                .doors
                .iter()
                .map(|d| (d.at, d.width_m / 2.0))
                .chain(given.map(|&at| (at, 0.0)))
                .any(|(at, half)| norm(sub(end, at)) < OUTSIDE_M.hypot(half) + 0.15);
            assert!(near_door, "p{id} vanished at {end:?}, not at a way out");
        }
        assert!(left >= min_left, "only {left} of {} left", tracks.len());
    }

    /// The crowd plans of fixtures/plans-crowd: everyone walks clear of walls and boxes.
    #[test]
    fn crowd_plans_walk_clear_of_walls() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans-crowd");
        let mut names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        names.sort();
        assert!(names.len() >= 6, "{names:?}");
        for path in names {
            let plan = Plan::load(&path).unwrap();
            let scene = Scene::build(&plan).unwrap();
            let crowd = CrowdPlan::build(&plan, &scene).unwrap().unwrap();
            let all = frames(&crowd, 1, 40.0);
            let most = all.iter().map(Vec::len).max().unwrap_or(0);
            let cap: u32 = plan.crowds.iter().map(|c| c.cap()).sum::<u32>()
                + plan.queues.iter().map(|q| q.people + 1).sum::<u32>();
            assert!(most as u32 <= cap, "{}: {most} people", path.display());
            assert!(!all[0].is_empty(), "{}", path.display());
            check_walks(&plan, &scene, &all, 1);
        }
    }

    /// The crowd plans (fixtures/plans-crowd), 40 s at seeds 1–3: on the floor (doorways
    /// apart, where people squeeze past one another), people of different groups come
    /// nearer than 0.3 m (bodies through one another) in under 0.2 % of the person-ticks.
    /// In corridor-cross: 1.4 % before people gave way, 0 after.
    #[test]
    fn strangers_do_not_walk_through_one_another() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/plans-crowd");
        for name in ["corridor-cross", "shop20", "hall40"] {
            let plan = Plan::load(&dir.join(format!("{name}.toml"))).unwrap();
            let scene = Scene::build(&plan).unwrap();
            let crowd = CrowdPlan::build(&plan, &scene).unwrap().unwrap();
            let (mut ticks, mut through) = (0usize, 0usize);
            for seed in 1..=3 {
                let mut run = crowd.start(rng(seed));
                for _ in 0..(40.0 / TICK_S) as usize {
                    run.step();
                    let on_floor: Vec<&Agent> = run
                        .agents
                        .iter()
                        .filter(|a| crowd.grid.is_free(a.body.pos) && !crowd.in_doorway(a.body.pos))
                        .collect();
                    ticks += on_floor.len();
                    for (i, a) in on_floor.iter().enumerate() {
                        through += on_floor[i + 1..]
                            .iter()
                            .filter(|b| b.group() != a.group())
                            .filter(|b| norm(sub(a.body.pos, b.body.pos)) < 0.3)
                            .count();
                    }
                }
            }
            let share = through as f64 / ticks as f64;
            assert!(
                share < 0.002,
                "{name}: {through} of {ticks} person-ticks ({:.2} %) through a stranger",
                share * 100.0
            );
        }
    }

    #[test]
    fn the_cap_is_honoured_and_reached() {
        let (_, _, crowd) = crowd_of(
            "[[crowd]]\npeople = 2\nmax_people = 7\nrate_per_min = 600\ngroup_share = 0.5\n",
        );
        let all = frames(&crowd, 9, 30.0);
        let most = all.iter().map(Vec::len).max().unwrap_or(0);
        assert_eq!(most, 7);
    }

    #[test]
    fn the_same_seed_gives_the_same_crowd_and_another_does_not() {
        let (_, _, crowd) = crowd_of("[[crowd]]\npeople = 8\n");
        let a = frames(&crowd, 1, 10.0);
        assert_eq!(a, frames(&crowd, 1, 10.0));
        assert_ne!(a, frames(&crowd, 2, 10.0));
        // Asking for times out of step order gives the same bodies.
        let mut run = crowd.start(rng(1));
        let late = run.bodies_at(7.0);
        let mut again = crowd.start(rng(1));
        again.bodies_at(3.0);
        assert_eq!(late, again.bodies_at(7.0));
    }

    #[test]
    fn groups_walk_side_by_side() {
        // A big empty hall, everyone in pairs.
        let text = r#"
name = "open"
[[wall]]
points = [[0, 0], [40, 0], [40, 30], [0, 30]]
closed = true
[[door]]
at = [20, 0]
width_m = 2
[[crowd]]
people = 10
group_share = 1
group_size = [2, 2]
stop_share = 0
spacing_m = 0.7
"#;
        let plan = Plan::from_toml(text, "open.toml").unwrap();
        let scene = Scene::build(&plan).unwrap();
        let crowd = CrowdPlan::build(&plan, &scene).unwrap().unwrap();
        let mut run = crowd.start(rng(4));
        let (mut beside, mut walking) = (0, 0);
        for _ in 0..400 {
            run.step();
            for m in run.agents.iter() {
                let Some((leader, ..)) = m.follow else {
                    continue;
                };
                let Some(l) = run.agents.iter().find(|a| a.body.id == leader) else {
                    continue;
                };
                // Only while the leader walks in the open, well inside.
                let p = l.body.pos;
                if l.route.get(l.route_next).is_none()
                    || !(2.0..38.0).contains(&p[0])
                    || !(2.0..28.0).contains(&p[1])
                {
                    continue;
                }
                walking += 1;
                let d = sub(m.body.pos, p);
                let along = d[0] * l.body.heading[0] + d[1] * l.body.heading[1];
                if (norm(d) - 0.7).abs() < 0.1 && along.abs() < 0.15 {
                    beside += 1;
                }
            }
        }
        assert!(walking > 1000, "{walking} member-ticks walking");
        assert!(
            beside as f64 > 0.8 * walking as f64,
            "{beside} of {walking} member-ticks side by side"
        );
    }

    #[test]
    fn a_queue_stands_still_and_steps_up_when_served() {
        let (_, _, still) =
            crowd_of("[[queue]]\nhead = [12, 8]\ntail = [12, 4.8]\npeople = 4\nserve_s = 0\n");
        let all = frames(&still, 1, 60.0);
        assert_eq!(all.first(), all.last(), "a queue never served never moves");
        assert_eq!(all[0].len(), 4);

        let (_, _, served) = crowd_of(
            "[[queue]]\nhead = [3, 3]\ntail = [6, 3]\npeople = 4\nserve_s = 20\nspacing_m = 0.7\n",
        );
        let all = frames(&served, 1, 25.0);
        let first = &all[0];
        // Still for the first 20 s.
        assert_eq!(first, &all[(19.9 / TICK_S) as usize]);
        let end = all.last().unwrap();
        // The front one has gone towards the door; the second stands at the front.
        let front = end.iter().find(|b| b.id == first[0].id);
        assert!(
            front.is_none_or(|f| norm(sub(f.pos, [3.0, 3.0])) > 2.0),
            "{front:?}"
        );
        let second = end.iter().find(|b| b.id == first[1].id).unwrap();
        assert!(norm(sub(second.pos, [3.0, 3.0])) < 0.05, "{:?}", second.pos);
        // A newcomer came in.
        assert!(
            end.iter().any(|b| first.iter().all(|f| f.id != b.id)),
            "{end:?}"
        );
    }

    #[test]
    fn a_queue_place_in_a_box_is_refused() {
        let (plan, scene) = plan_with("[[queue]]\nhead = [2, 6]\ntail = [6, 6]\npeople = 3\n");
        let err = CrowdPlan::build(&plan, &scene).unwrap_err();
        assert_eq!(err.key.as_deref(), Some("queue.head"));
    }
}
