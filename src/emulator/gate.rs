//! The shared clock of a replay: when recorded scans fall due, for every emulator of one run.
//!
//! Stream time is the recordings' own clock, counted from the earliest first scan of all of
//! them (`origin`). It starts once every emulator's client has asked for scans (or after
//! [`START_ANYWAY_AFTER`], so a unit that never connects holds nobody up), runs at `speed`
//! times the wall clock (or as fast as it may, at `--max`), and never more than `lead` ahead of
//! the sensor the pipeline has taken in least of: a slow pipeline holds the replay back instead
//! of dropping scans, and the sensors stay in step, so whatever the speed the pipeline sees
//! every scan, stamped with its recorded time, in nearly the order it was recorded.
//!
//! A gate anchored to the wall clock ([`ReplayGate::anchored`]) instead starts at once, at the
//! offset the wall clock gives: daemons started (or restarted) at different times, each with
//! its own gate on the same anchor, play their recordings in step, as live units would be.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::Notify;
use tokio::time::Instant;

/// A unit that never asks for scans holds the others back this long, no longer.
pub const START_ANYWAY_AFTER: Duration = Duration::from_secs(5);
/// A sensor whose scans stop reaching the pipeline (its link is down) stops holding the
/// others back after this long; it is in step again from its next scan.
pub const LEFT_BEHIND_AFTER: Duration = Duration::from_secs(2);

#[derive(Debug)]
struct Progress {
    /// Newest stream offset of this sensor the pipeline has taken in, ns.
    consumed_ns: u64,
    /// Wall time of its last progress.
    advanced: Instant,
    /// Played to its end: it holds nobody back.
    finished: bool,
}

#[derive(Debug)]
struct State {
    sensors: BTreeMap<String, Progress>,
    first_join: Option<Instant>,
    /// Wall time at stream offset `start_offset_ns`.
    start: Option<Instant>,
    /// The stream offset at `start`: 0, unless anchored to the wall clock after its anchor.
    start_offset_ns: u64,
}

#[derive(Debug)]
struct Inner {
    /// `None`: as fast as the pipeline takes the scans.
    speed: Option<f64>,
    lead_ns: u64,
    expected: usize,
    /// Started by the wall clock, not by its units joining ([`ReplayGate::anchored`]).
    anchored: bool,
    state: Mutex<State>,
    changed: Notify,
}

/// Cheap to clone; one per replay, shared by its emulators and the pipeline.
#[derive(Debug, Clone)]
pub struct ReplayGate {
    inner: Arc<Inner>,
}

fn lock(m: &Mutex<State>) -> MutexGuard<'_, State> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl ReplayGate {
    /// A gate for `expected` emulators at `speed` (`None`: as fast as possible), letting the
    /// replay run at most `lead` ahead of the pipeline (keep it above a scan period); with no
    /// `lead` the pipeline never holds it, as live units do not wait (then give a speed).
    pub fn new(expected: usize, speed: Option<f64>, lead: Option<Duration>) -> Self {
        let speed = speed.filter(|s| s.is_finite() && *s > 0.0);
        let lead_ns = lead.map_or(u64::MAX, |l| l.as_nanos().clamp(1, u64::MAX as u128) as u64);
        Self::with(expected, speed, lead_ns, None)
    }

    /// A gate on the wall clock: stream offset 0 was `since_s` seconds ago (is in `-since_s`
    /// seconds, if negative), and the stream runs at `speed` from there, never held back by
    /// the pipeline (as live units are not). Its units start where the stream stands when
    /// they join, not at their recordings' first scans.
    pub fn anchored(expected: usize, speed: f64, since_s: f64) -> Self {
        let speed = if speed.is_finite() && speed > 0.0 {
            speed
        } else {
            1.0
        };
        let now = Instant::now();
        let start = if since_s >= 0.0 {
            (now, (since_s * speed * 1e9).min(u64::MAX as f64) as u64)
        } else {
            (now + Duration::from_secs_f64((-since_s).min(1e9)), 0)
        };
        Self::with(expected, Some(speed), u64::MAX, Some(start))
    }

    fn with(
        expected: usize,
        speed: Option<f64>,
        lead_ns: u64,
        anchor: Option<(Instant, u64)>,
    ) -> Self {
        ReplayGate {
            inner: Arc::new(Inner {
                speed,
                lead_ns,
                expected: expected.max(1),
                anchored: anchor.is_some(),
                state: Mutex::new(State {
                    sensors: BTreeMap::new(),
                    first_join: None,
                    start: anchor.map(|(at, _)| at),
                    start_offset_ns: anchor.map_or(0, |(_, offset)| offset),
                }),
                changed: Notify::new(),
            }),
        }
    }

    /// Anchored to the wall clock ([`ReplayGate::anchored`]).
    pub fn is_anchored(&self) -> bool {
        self.inner.anchored
    }

    /// Sensor `id`'s client started its first stream; its first scan is at `first_ns`.
    pub fn join(&self, id: &str, first_ns: u64) {
        let mut s = lock(&self.inner.state);
        let now = Instant::now();
        s.sensors.entry(id.to_string()).or_insert(Progress {
            consumed_ns: first_ns,
            advanced: now,
            finished: false,
        });
        s.first_join.get_or_insert(now);
        if s.start.is_none() && s.sensors.len() >= self.inner.expected {
            s.start = Some(now);
        }
        drop(s);
        self.inner.changed.notify_waiters();
    }

    /// Sensor `id` has played its recording to the end.
    pub fn finished(&self, id: &str) {
        if let Some(p) = lock(&self.inner.state).sensors.get_mut(id) {
            p.finished = true;
        }
        self.inner.changed.notify_waiters();
    }

    /// The pipeline has taken in sensor `id`'s scan at stream offset `offset_ns`.
    pub fn consumed(&self, id: &str, offset_ns: u64) {
        let mut s = lock(&self.inner.state);
        let Some(p) = s.sensors.get_mut(id) else {
            return;
        };
        p.advanced = Instant::now();
        if offset_ns > p.consumed_ns {
            p.consumed_ns = offset_ns;
            drop(s);
            self.inner.changed.notify_waiters();
        }
    }

    /// How far the pipeline lets the stream run: `lead` past the sensor it has taken in least
    /// of, among those still playing and not left behind.
    fn held_ns(&self, s: &State, now: Instant) -> u64 {
        let playing = s.sensors.values().filter(|p| !p.finished);
        let in_step = playing
            .clone()
            .filter(|p| now.duration_since(p.advanced) < LEFT_BEHIND_AFTER)
            .map(|p| p.consumed_ns)
            .min();
        let floor = in_step
            .or_else(|| playing.map(|p| p.consumed_ns).max())
            .or_else(|| s.sensors.values().map(|p| p.consumed_ns).max())
            .unwrap_or(0);
        floor.saturating_add(self.inner.lead_ns)
    }

    /// How far the stream may have run at `now`: `None` before it starts.
    fn allowed_ns(&self, s: &mut State, now: Instant) -> Option<u64> {
        if s.start.is_none()
            && s.first_join
                .is_some_and(|t| now.duration_since(t) >= START_ANYWAY_AFTER)
        {
            s.start = Some(now);
        }
        let start = s.start?;
        let held = self.held_ns(s, now);
        Some(match self.inner.speed {
            Some(speed) => {
                let paced = (now.duration_since(start).as_secs_f64() * speed * 1e9) as u64;
                s.start_offset_ns.saturating_add(paced).min(held)
            }
            None => held,
        })
    }

    /// The stream offset at this moment (0 before the start).
    pub fn now_ns(&self) -> u64 {
        let mut s = lock(&self.inner.state);
        self.allowed_ns(&mut s, Instant::now()).unwrap_or(0)
    }

    /// Waits until the stream reaches `offset_ns`.
    pub async fn wait_until(&self, offset_ns: u64) {
        loop {
            // Registered before the check, so a change between the check and the wait is seen.
            let changed = self.inner.changed.notified();
            tokio::pin!(changed);
            changed.as_mut().enable();
            let wake = {
                let mut s = lock(&self.inner.state);
                let now = Instant::now();
                match self.allowed_ns(&mut s, now) {
                    Some(allowed) if allowed >= offset_ns => return,
                    Some(_) => {
                        // Paced: the wall time it falls due. Held by the pipeline: re-check
                        // when a sensor could be left behind.
                        let paced = match (self.inner.speed, s.start) {
                            (Some(speed), Some(start)) => Some(
                                start
                                    + Duration::from_secs_f64(
                                        offset_ns.saturating_sub(s.start_offset_ns) as f64
                                            / 1e9
                                            / speed,
                                    ),
                            ),
                            _ => None,
                        };
                        let behind = s
                            .sensors
                            .values()
                            .filter(|p| !p.finished)
                            .map(|p| p.advanced + LEFT_BEHIND_AFTER)
                            .filter(|t| *t > now)
                            .min();
                        match (paced.filter(|t| *t > now), behind) {
                            (Some(a), Some(b)) => Some(a.min(b)),
                            (a, b) => a.or(b),
                        }
                    }
                    None => s.first_join.map(|t| t + START_ANYWAY_AFTER),
                }
            };
            match wake {
                Some(at) => {
                    tokio::select! {
                        _ = tokio::time::sleep_until(at) => {}
                        _ = changed => {}
                    }
                }
                None => changed.await,
            }
        }
    }
}

impl PartialEq for ReplayGate {
    /// The same gate, not an equal one.
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.inner, &other.inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn the_stream_starts_when_every_unit_has_joined_and_follows_the_speed() {
        let gate = ReplayGate::new(2, Some(4.0), None);
        gate.join("a", 0);
        tokio::time::sleep(Duration::from_secs(1)).await;
        assert_eq!(gate.now_ns(), 0, "one of two joined: not started");
        gate.join("b", 0);
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(gate.now_ns(), 2_000_000_000, "×4 for half a second");
        let before = Instant::now();
        gate.wait_until(3_000_000_000).await;
        assert_eq!(Instant::now() - before, Duration::from_millis(250));
    }

    #[tokio::test(start_paused = true)]
    async fn a_gate_on_the_wall_clock_stands_where_its_anchor_puts_it() {
        // Anchored 20 s ago at ×2: 40 s in at once, with no unit joined, and never held.
        let gate = ReplayGate::anchored(2, 2.0, 20.0);
        assert!(gate.is_anchored());
        assert_eq!(gate.now_ns(), 40_000_000_000);
        gate.join("a", 0);
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(gate.now_ns(), 41_000_000_000, "×2 for half a second");
        let before = Instant::now();
        gate.wait_until(30_000_000_000).await;
        assert_eq!(Instant::now(), before, "long due");
        gate.wait_until(42_000_000_000).await;
        assert_eq!(Instant::now() - before, Duration::from_millis(500));
        // Anchored 3 s ahead: nothing plays until then.
        let later = ReplayGate::anchored(1, 1.0, -3.0);
        tokio::time::sleep(Duration::from_secs(2)).await;
        assert_eq!(later.now_ns(), 0);
        let before = Instant::now();
        later.wait_until(1_000_000_000).await;
        assert_eq!(Instant::now() - before, Duration::from_secs(2));
        assert!(!ReplayGate::new(1, Some(1.0), None).is_anchored());
    }

    #[tokio::test(start_paused = true)]
    async fn a_unit_that_never_joins_holds_the_others_only_for_a_while() {
        let gate = ReplayGate::new(3, Some(1.0), None);
        gate.join("a", 0);
        let before = Instant::now();
        gate.wait_until(1).await;
        assert!(Instant::now() - before >= START_ANYWAY_AFTER);
    }

    #[tokio::test(start_paused = true)]
    async fn a_slow_pipeline_holds_the_replay_back_at_any_speed() {
        for speed in [Some(1.0), None] {
            let gate = ReplayGate::new(1, speed, Some(Duration::from_millis(200)));
            gate.join("a", 0);
            gate.consumed("a", 0);
            let waiting = {
                let gate = gate.clone();
                tokio::spawn(async move { gate.wait_until(1_000_000_000).await })
            };
            tokio::time::sleep(Duration::from_millis(1500)).await;
            assert_eq!(
                gate.now_ns(),
                200_000_000,
                "{speed:?}: nothing taken in yet"
            );
            assert!(!waiting.is_finished(), "{speed:?}");
            gate.consumed("a", 900_000_000);
            tokio::time::timeout(Duration::from_millis(1), waiting)
                .await
                .expect("taken in: it may go on")
                .expect("no panic");
        }
    }

    #[tokio::test(start_paused = true)]
    async fn sensors_stay_in_step_until_one_is_left_behind_or_finished() {
        let gate = ReplayGate::new(2, None, Some(Duration::from_millis(100)));
        gate.join("a", 0);
        gate.join("b", 0);
        gate.consumed("a", 500_000_000);
        gate.consumed("b", 200_000_000);
        assert_eq!(gate.now_ns(), 300_000_000, "held by b");
        tokio::time::sleep(Duration::from_millis(1000)).await;
        gate.consumed("a", 500_000_000);
        tokio::time::sleep(Duration::from_millis(1100)).await;
        assert_eq!(gate.now_ns(), 600_000_000, "b left behind after 2 s");
        gate.consumed("b", 250_000_000);
        assert_eq!(gate.now_ns(), 350_000_000, "b in step again");
        gate.finished("b");
        assert_eq!(gate.now_ns(), 600_000_000, "b finished");
    }
}
