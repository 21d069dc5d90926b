//! Zones and counting lines (`[[zone]]`, `[[line]]` in the site config): how many people stand
//! in each zone, and who crossed which line which way. Pure: [`Counter::update`] takes one
//! [`Tracks`] and returns the [`Zones`] and [`Crossing`] messages it causes.
//!
//! A crossing is a track whose path between two consecutive positions crosses the line's
//! segment. Its side is the sign of the cross product of `from → to` with `from → position`
//! (positive: left). Hysteresis: a track has a side only once it is at least `hysteresis_m`
//! from the line; a crossing counts when the side changes and the path crossed the segment on
//! the way, so a person standing on the line and swaying is counted once, not at every sway.

use std::collections::{BTreeMap, BTreeSet};

use crate::daemon::protocol::{Crossing, Message, Side, Tracks, ZoneCount, Zones};

/// A track must be this far from a line before it counts as being on one side, m.
pub const DEFAULT_HYSTERESIS_M: f64 = 0.2;

/// A point in the site frame, m.
pub type Xy = [f64; 2];

/// One `[[zone]]`: a simple polygon in the site frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Zone {
    pub id: String,
    /// Corners in order (either way round); closed implicitly.
    pub polygon: Vec<Xy>,
}

/// One `[[line]]`: a directed segment in the site frame.
#[derive(Debug, Clone, PartialEq)]
pub struct CountLine {
    pub id: String,
    pub from: Xy,
    pub to: Xy,
    /// See the module doc.
    pub hysteresis_m: f64,
}

fn sub(a: Xy, b: Xy) -> Xy {
    [a[0] - b[0], a[1] - b[1]]
}

fn cross(a: Xy, b: Xy) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

/// Orientation of `c` relative to `a → b`: > 0 left, < 0 right, 0 on the line.
fn orient(a: Xy, b: Xy, c: Xy) -> f64 {
    cross(sub(b, a), sub(c, a))
}

fn within_box(a: Xy, b: Xy, p: Xy) -> bool {
    p[0] >= a[0].min(b[0])
        && p[0] <= a[0].max(b[0])
        && p[1] >= a[1].min(b[1])
        && p[1] <= a[1].max(b[1])
}

/// True when segments `a–b` and `c–d` share at least one point (touching counts).
pub fn segments_meet(a: Xy, b: Xy, c: Xy, d: Xy) -> bool {
    let (o1, o2) = (orient(a, b, c), orient(a, b, d));
    let (o3, o4) = (orient(c, d, a), orient(c, d, b));
    if ((o1 > 0.0 && o2 < 0.0) || (o1 < 0.0 && o2 > 0.0))
        && ((o3 > 0.0 && o4 < 0.0) || (o3 < 0.0 && o4 > 0.0))
    {
        return true;
    }
    (o1 == 0.0 && within_box(a, b, c))
        || (o2 == 0.0 && within_box(a, b, d))
        || (o3 == 0.0 && within_box(c, d, a))
        || (o4 == 0.0 && within_box(c, d, b))
}

/// True when `p` is inside `polygon` (even–odd rule; a point on an edge may go either way).
pub fn inside(polygon: &[Xy], p: Xy) -> bool {
    let mut inside = false;
    let n = polygon.len();
    for i in 0..n {
        let (Some(&a), Some(&b)) = (polygon.get(i), polygon.get((i + 1) % n)) else {
            continue;
        };
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// Checks a zone's polygon: at least 3 finite corners, no repeated corner, edges that do not
/// cross or touch each other, and an area. The error is a sentence for the config's author.
pub fn check_polygon(polygon: &[Xy]) -> Result<(), String> {
    let n = polygon.len();
    if n < 3 {
        return Err(format!(
            "has {n} point{}; a zone needs at least 3 corners, e.g. [[0, 0], [4, 0], [4, 3], [0, 3]]",
            if n == 1 { "" } else { "s" }
        ));
    }
    if polygon.iter().flatten().any(|v| !v.is_finite()) {
        return Err("has a coordinate that is not a finite number".into());
    }
    let at = |i: usize| polygon.get(i % n).copied().unwrap_or([0.0, 0.0]);
    for i in 0..n {
        for j in i + 1..n {
            if at(i) == at(j) {
                return Err(format!(
                    "repeats the point [{}, {}] (points {} and {}); list each corner once, without closing the ring",
                    at(i)[0],
                    at(i)[1],
                    i + 1,
                    j + 1
                ));
            }
        }
    }
    for i in 0..n {
        for j in i + 1..n {
            let adjacent = j == i + 1 || (i == 0 && j == n - 1);
            let (a, b, c, d) = (at(i), at(i + 1), at(j), at(j + 1));
            let meet = if adjacent {
                // Neighbours share a corner; they must not fold back onto each other.
                let (shared, p, q) = if j == i + 1 { (b, a, d) } else { (a, b, c) };
                orient(shared, p, q) == 0.0
                    && (within_box(shared, p, q) || within_box(shared, q, p))
            } else {
                segments_meet(a, b, c, d)
            };
            if meet {
                return Err(format!(
                    "crosses itself: the edge from point {} to {} meets the edge from point {} to {}; list the corners in order around the zone",
                    i + 1,
                    (i + 1) % n + 1,
                    j + 1,
                    (j + 1) % n + 1
                ));
            }
        }
    }
    let twice_area: f64 = (0..n).map(|i| cross(at(i), at(i + 1))).sum();
    if twice_area.abs() < 1e-9 {
        return Err("has no area (all its points lie on one line)".into());
    }
    Ok(())
}

/// Checks a counting line: finite ends that are apart.
pub fn check_line(from: Xy, to: Xy) -> Result<(), String> {
    if from.iter().chain(&to).any(|v| !v.is_finite()) {
        return Err("has a coordinate that is not a finite number".into());
    }
    let d = sub(to, from);
    if d[0].hypot(d[1]) < 1e-3 {
        return Err(format!(
            "from and to are the same point [{}, {}]; a counting line needs two ends apart, e.g. from = [0, 0], to = [2, 0]",
            from[0], from[1]
        ));
    }
    Ok(())
}

/// What a line remembers of one track.
#[derive(Debug, Clone, Copy, Default)]
struct LineState {
    /// The side the track was last clearly on.
    side: Option<Side>,
    /// The track's path met the segment since it was last clearly on `side`.
    crossed: bool,
}

#[derive(Debug, Clone, Default)]
struct LineTotals {
    left: u64,
    right: u64,
    tracks: BTreeMap<u64, LineState>,
}

/// Counts occupancy and crossings from a stream of [`Tracks`]. State is per track: tracks not
/// listed in an update are forgotten; an id listed again (its person seen again after hiding)
/// starts afresh, so a jump over a line while unseen is not counted.
#[derive(Debug, Clone)]
pub struct Counter {
    zones: Vec<Zone>,
    lines: Vec<CountLine>,
    totals: Vec<LineTotals>,
    last_position: BTreeMap<u64, Xy>,
    last_zones: Option<Vec<ZoneCount>>,
}

impl Counter {
    pub fn new(zones: Vec<Zone>, lines: Vec<CountLine>) -> Counter {
        let totals = vec![LineTotals::default(); lines.len()];
        Counter {
            zones,
            lines,
            totals,
            last_position: BTreeMap::new(),
            last_zones: None,
        }
    }

    /// True when there is nothing to count (no zones, no lines).
    pub fn is_empty(&self) -> bool {
        self.zones.is_empty() && self.lines.is_empty()
    }

    /// The messages `tracks` causes: a [`Zones`] on the first update and whenever a zone's
    /// occupants change (not sent without zones), then one [`Crossing`] per line crossed.
    pub fn update(&mut self, tracks: &Tracks) -> Vec<Message> {
        let mut out = Vec::new();
        if !self.zones.is_empty() {
            let counts: Vec<ZoneCount> = self
                .zones
                .iter()
                .map(|z| {
                    let mut ids: Vec<u64> = tracks
                        .tracks
                        .iter()
                        .filter(|t| inside(&z.polygon, [t.x_m, t.y_m]))
                        .map(|t| t.id)
                        .collect();
                    ids.sort_unstable();
                    ids.dedup();
                    ZoneCount {
                        id: z.id.clone(),
                        count: u32::try_from(ids.len()).unwrap_or(u32::MAX),
                        tracks: ids,
                    }
                })
                .collect();
            if self.last_zones.as_ref() != Some(&counts) {
                self.last_zones = Some(counts.clone());
                out.push(Message::Zones(Zones {
                    t_ns: tracks.t_ns,
                    zones: counts,
                }));
            }
        }
        for (line, totals) in self.lines.iter().zip(self.totals.iter_mut()) {
            let dir = sub(line.to, line.from);
            let length = dir[0].hypot(dir[1]);
            for t in &tracks.tracks {
                let p = [t.x_m, t.y_m];
                if !p.iter().all(|v| v.is_finite()) {
                    continue;
                }
                let state = totals.tracks.entry(t.id).or_default();
                if let Some(&prev) = self.last_position.get(&t.id)
                    && segments_meet(prev, p, line.from, line.to)
                {
                    state.crossed = true;
                }
                let distance_m = cross(dir, sub(p, line.from)) / length;
                if distance_m.abs() < line.hysteresis_m {
                    continue;
                }
                let side = if distance_m > 0.0 {
                    Side::Left
                } else {
                    Side::Right
                };
                match state.side {
                    Some(was) if was != side && state.crossed => {
                        match side {
                            Side::Left => totals.left += 1,
                            Side::Right => totals.right += 1,
                        }
                        out.push(Message::Crossing(Crossing {
                            t_ns: tracks.t_ns,
                            line: line.id.clone(),
                            track: t.id,
                            to: side,
                            left_total: totals.left,
                            right_total: totals.right,
                        }));
                    }
                    // Same side again (swayed back), round the line's end, or first seen.
                    _ => {}
                }
                state.side = Some(side);
                state.crossed = false;
            }
            let listed: BTreeSet<u64> = tracks.tracks.iter().map(|t| t.id).collect();
            totals.tracks.retain(|id, _| listed.contains(id));
        }
        self.last_position = tracks
            .tracks
            .iter()
            .filter(|t| t.x_m.is_finite() && t.y_m.is_finite())
            .map(|t| (t.id, [t.x_m, t.y_m]))
            .collect();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::Track;

    fn track(id: u64, x_m: f64, y_m: f64) -> Track {
        Track {
            id,
            x_m,
            y_m,
            vx_m_s: 0.0,
            vy_m_s: 0.0,
            sigma_m: 0.05,
            age_s: 1.0,
            sensors: vec!["a".into()],
        }
    }

    fn at(t_ns: u64, tracks: Vec<Track>) -> Tracks {
        Tracks { t_ns, tracks }
    }

    /// A door from (0, 0) to (2, 0): going up (+y) is to its left.
    fn door() -> CountLine {
        CountLine {
            id: "door".into(),
            from: [0.0, 0.0],
            to: [2.0, 0.0],
            hysteresis_m: DEFAULT_HYSTERESIS_M,
        }
    }

    fn crossings(messages: &[Message]) -> Vec<Crossing> {
        messages
            .iter()
            .filter_map(|m| match m {
                Message::Crossing(c) => Some(c.clone()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn polygons_are_checked() {
        assert!(check_polygon(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]).is_ok());
        assert!(check_polygon(&[[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]).is_ok());
        let e = check_polygon(&[[0.0, 0.0], [1.0, 0.0]]).unwrap_err();
        assert!(e.contains("has 2 points"), "{e}");
        // A bow tie: the edges 1→2 and 3→4 cross.
        let e = check_polygon(&[[0.0, 0.0], [2.0, 2.0], [2.0, 0.0], [0.0, 2.0]]).unwrap_err();
        assert!(e.contains("crosses itself"), "{e}");
        assert!(
            e.contains("point 1 to 2") && e.contains("point 3 to 4"),
            "{e}"
        );
        let e = check_polygon(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 0.0]]).unwrap_err();
        assert!(e.contains("repeats the point [0, 0]"), "{e}");
        // Folds back along itself.
        let e = check_polygon(&[[0.0, 0.0], [2.0, 0.0], [1.0, 0.0], [1.0, 1.0]]).unwrap_err();
        assert!(e.contains("crosses itself"), "{e}");
        let e = check_polygon(&[[0.0, 0.0], [f64::NAN, 0.0], [1.0, 1.0]]).unwrap_err();
        assert!(e.contains("finite"), "{e}");
    }

    #[test]
    fn lines_are_checked() {
        assert!(check_line([0.0, 0.0], [1.0, 0.0]).is_ok());
        let e = check_line([1.0, 2.0], [1.0, 2.0]).unwrap_err();
        assert!(e.contains("same point [1, 2]"), "{e}");
    }

    #[test]
    fn inside_a_polygon() {
        // An L shape.
        let l = [
            [0.0, 0.0],
            [3.0, 0.0],
            [3.0, 1.0],
            [1.0, 1.0],
            [1.0, 3.0],
            [0.0, 3.0],
        ];
        assert!(inside(&l, [0.5, 0.5]));
        assert!(inside(&l, [0.5, 2.5]));
        assert!(inside(&l, [2.5, 0.5]));
        assert!(!inside(&l, [2.0, 2.0]));
        assert!(!inside(&l, [-1.0, 0.5]));
    }

    #[test]
    fn zones_are_sent_at_start_and_when_occupants_change() {
        let zone = Zone {
            id: "desk".into(),
            polygon: vec![[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]],
        };
        let mut c = Counter::new(vec![zone], vec![]);
        let first = c.update(&at(1, vec![track(7, 5.0, 5.0)]));
        assert_eq!(
            first,
            vec![Message::Zones(Zones {
                t_ns: 1,
                zones: vec![ZoneCount {
                    id: "desk".into(),
                    count: 0,
                    tracks: vec![]
                }]
            })],
            "once at start, even when empty"
        );
        assert!(c.update(&at(2, vec![track(7, 4.0, 5.0)])).is_empty());
        let m = c.update(&at(3, vec![track(7, 1.0, 1.0), track(9, 1.5, 0.5)]));
        let Some(Message::Zones(z)) = m.first() else {
            panic!("{m:?}")
        };
        assert_eq!(z.t_ns, 3);
        assert_eq!(z.zones[0].count, 2);
        assert_eq!(z.zones[0].tracks, vec![7, 9]);
        assert!(
            c.update(&at(4, vec![track(7, 1.1, 1.0), track(9, 1.5, 0.6)]))
                .is_empty()
        );
        let m = c.update(&at(5, vec![track(9, 1.5, 0.6)]));
        assert_eq!(m.len(), 1, "7 left (its track ended): {m:?}");
        // No zones: never a ZONES message.
        let mut none = Counter::new(vec![], vec![door()]);
        assert!(none.update(&at(1, vec![track(1, 1.0, 1.0)])).is_empty());
    }

    #[test]
    fn a_walk_through_the_door_counts_once_each_way_with_totals() {
        let mut c = Counter::new(vec![], vec![door()]);
        let walk = |c: &mut Counter, t0: u64, ys: &[f64]| -> Vec<Crossing> {
            let mut out = Vec::new();
            for (i, y) in ys.iter().enumerate() {
                out.extend(crossings(
                    &c.update(&at(t0 + i as u64, vec![track(1, 1.0, *y)])),
                ));
            }
            out
        };
        let up = walk(&mut c, 0, &[-1.0, -0.5, -0.1, 0.1, 0.5, 1.0]);
        assert_eq!(up.len(), 1, "{up:?}");
        assert_eq!(up[0].to, Side::Left);
        assert_eq!(up[0].t_ns, 4, "counted when clear of the line (0.5 m)");
        assert_eq!((up[0].left_total, up[0].right_total), (1, 0));
        let down = walk(&mut c, 10, &[0.5, -0.5]);
        assert_eq!(down.len(), 1);
        assert_eq!(down[0].to, Side::Right);
        assert_eq!((down[0].left_total, down[0].right_total), (1, 1));
        assert_eq!(down[0].line, "door");
        assert_eq!(down[0].track, 1);
    }

    #[test]
    fn swaying_on_the_line_is_not_counted_twice() {
        let mut c = Counter::new(vec![], vec![door()]);
        let mut all = Vec::new();
        // From below, onto the line, sways across it ±5 cm for a while, then goes on up.
        let mut ys = vec![-1.0, -0.3];
        for i in 0..40 {
            ys.push(if i % 2 == 0 { 0.05 } else { -0.05 });
        }
        ys.extend([0.1, 0.6, 1.2]);
        for (i, y) in ys.iter().enumerate() {
            all.extend(crossings(&c.update(&at(i as u64, vec![track(3, 1.0, *y)]))));
        }
        assert_eq!(all.len(), 1, "{all:?}");
        assert_eq!(all[0].to, Side::Left);
        // Sways and steps back: nothing.
        let mut back = Vec::new();
        for (i, y) in [0.6, 0.05, -0.05, 0.05, 0.7].iter().enumerate() {
            back.extend(crossings(
                &c.update(&at(100 + i as u64, vec![track(3, 1.0, *y)])),
            ));
        }
        assert!(back.is_empty(), "{back:?}");
    }

    #[test]
    fn passing_round_the_end_of_the_line_is_not_a_crossing() {
        let mut c = Counter::new(vec![], vec![door()]);
        let mut all = Vec::new();
        // Crosses the line's extension at x = 3, beyond its end at x = 2.
        for (i, y) in [-1.0, -0.4, 0.4, 1.0].iter().enumerate() {
            all.extend(crossings(&c.update(&at(i as u64, vec![track(5, 3.0, *y)]))));
        }
        assert!(all.is_empty(), "{all:?}");
        // A fast walker that jumps over the line between two updates is counted.
        for (i, y) in [-1.0, 1.0].iter().enumerate() {
            all.extend(crossings(
                &c.update(&at(10 + i as u64, vec![track(6, 1.0, *y)])),
            ));
        }
        assert_eq!(all.len(), 1, "{all:?}");
        // A track born on the far side is not a crossing.
        assert!(crossings(&c.update(&at(20, vec![track(8, 1.0, 1.0)]))).is_empty());
    }
}
