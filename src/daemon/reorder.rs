//! Puts the scans of several sensors back into the order they were measured in, so the
//! registration worker's decisions (when a static view is complete, when a move has lasted)
//! depend on the stamps alone, not on which sensor's scan happened to arrive first. Each
//! sensor's own scans arrive in order; a scan is released once every sensor still streaming
//! has sent one at least as new. A sensor more than `hold` behind the newest stamp holds
//! nobody up (it is unplugged, or its recording ended). Pure: stamps in, items out.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};

/// The reorder buffer.
#[derive(Debug)]
pub struct Reorder<T> {
    hold_ns: u64,
    /// Newest stamp seen per sensor.
    newest: BTreeMap<String, u64>,
    /// Waiting items by (stamp, arrival number).
    waiting: BinaryHeap<Reverse<(u64, u64, Slot<T>)>>,
    arrivals: u64,
}

/// Keeps the heap's order on the key alone.
#[derive(Debug)]
struct Slot<T>(T);

impl<T> PartialEq for Slot<T> {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}
impl<T> Eq for Slot<T> {}
impl<T> PartialOrd for Slot<T> {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl<T> Ord for Slot<T> {
    fn cmp(&self, _: &Self) -> std::cmp::Ordering {
        std::cmp::Ordering::Equal
    }
}

impl<T> Reorder<T> {
    pub fn new(hold_ns: u64) -> Self {
        Reorder {
            hold_ns,
            newest: BTreeMap::new(),
            waiting: BinaryHeap::new(),
            arrivals: 0,
        }
    }

    /// Takes sensor `sensor`'s item stamped `stamp_ns`.
    pub fn push(&mut self, sensor: &str, stamp_ns: u64, item: T) {
        let newest = self.newest.entry(sensor.to_string()).or_insert(stamp_ns);
        *newest = (*newest).max(stamp_ns);
        self.arrivals += 1;
        self.waiting
            .push(Reverse((stamp_ns, self.arrivals, Slot(item))));
    }

    /// Up to where every sensor still streaming has sent its scans.
    fn watermark(&self) -> u64 {
        let newest = self.newest.values().copied().max().unwrap_or(0);
        self.newest
            .values()
            .copied()
            .filter(|&n| n.saturating_add(self.hold_ns) >= newest)
            .min()
            .unwrap_or(newest)
    }

    /// The oldest item, once nothing older can still come.
    pub fn pop(&mut self) -> Option<T> {
        let watermark = self.watermark();
        let Reverse((stamp_ns, _, _)) = self.waiting.peek()?;
        if *stamp_ns > watermark {
            return None;
        }
        self.waiting.pop().map(|Reverse((_, _, Slot(item)))| item)
    }

    /// The oldest item, whatever may still come (the scans have ended).
    pub fn pop_any(&mut self) -> Option<T> {
        self.waiting.pop().map(|Reverse((_, _, Slot(item)))| item)
    }

    /// Forgets a sensor that has gone (it no longer holds the others).
    pub fn forget(&mut self, sensor: &str) {
        self.newest.remove(sensor);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drain(r: &mut Reorder<&'static str>) -> Vec<&'static str> {
        std::iter::from_fn(|| r.pop()).collect()
    }

    #[test]
    fn scans_come_out_in_stamp_order_once_every_sensor_has_passed_them() {
        let mut r = Reorder::new(500);
        r.push("a", 10, "a10");
        r.push("a", 20, "a20");
        assert_eq!(
            drain(&mut r),
            ["a10", "a20"],
            "one sensor: nothing to wait for"
        );
        r.push("b", 15, "b15");
        r.push("a", 30, "a30");
        assert_eq!(drain(&mut r), ["b15"], "a30 waits for b to pass 30");
        r.push("b", 25, "b25");
        assert_eq!(drain(&mut r), ["b25"]);
        r.push("b", 35, "b35");
        assert_eq!(drain(&mut r), ["a30"]);
        assert_eq!(r.pop_any(), Some("b35"));
        assert_eq!(r.pop_any(), None);
    }

    #[test]
    fn a_sensor_far_behind_holds_nobody_up() {
        let mut r = Reorder::new(100);
        r.push("a", 0, "a0");
        r.push("b", 0, "b0");
        assert_eq!(drain(&mut r), ["a0", "b0"]);
        r.push("a", 50, "a50");
        assert!(drain(&mut r).is_empty(), "b is 50 behind: within the hold");
        r.push("a", 150, "a150");
        assert_eq!(drain(&mut r), ["a50", "a150"], "b is 150 behind: left out");
        r.forget("a");
        r.push("b", 10, "b10");
        assert_eq!(drain(&mut r), ["b10"]);
    }
}
