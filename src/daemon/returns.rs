//! How much a sensor sees: the share of its beams that return, per sensor, so that a unit
//! whose lens is covered, that points at the sky or that is broken is named as such instead
//! of streaming at 40 Hz with "too few walls" as its only symptom. Pure: scans in, verdicts out.

/// Below this share of returning beams a sensor is said to see almost nothing.
pub const BLIND_BELOW: f64 = 0.05;
/// It sees again once the share is back above this (hysteresis: no flapping at the line).
pub const SEEING_ABOVE: f64 = 0.10;
/// Scans before any verdict: the first few of a connection may be partial.
const JUDGE_AFTER_SCANS: u32 = 20;
/// Weight of each new scan in the running share (about a second of a 40 Hz unit).
const WEIGHT: f64 = 1.0 / 40.0;

/// A change of verdict, to be announced once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Verdict {
    /// The share fell below [`BLIND_BELOW`].
    Blind { share: f64 },
    /// It rose back above [`SEEING_ABOVE`].
    Seeing { share: f64 },
}

/// The running share of returning beams of one sensor.
#[derive(Debug, Clone, Default)]
pub struct Returns {
    share: Option<f64>,
    scans: u32,
    blind: bool,
}

/// Share of `ranges_m` that are returns (finite and above zero; 0 and NaN are "no return").
pub fn share_of(ranges_m: &[f32]) -> Option<f64> {
    if ranges_m.is_empty() {
        return None;
    }
    let hits = ranges_m
        .iter()
        .filter(|r| r.is_finite() && **r > 0.0)
        .count();
    Some(hits as f64 / ranges_m.len() as f64)
}

impl Returns {
    /// Takes one scan's ranges; `Some` when the verdict changes.
    pub fn observe(&mut self, ranges_m: &[f32]) -> Option<Verdict> {
        let now = share_of(ranges_m)?;
        let share = match self.share {
            Some(s) => s + WEIGHT * (now - s),
            None => now,
        };
        self.share = Some(share);
        self.scans = self.scans.saturating_add(1);
        if self.scans < JUDGE_AFTER_SCANS {
            return None;
        }
        if !self.blind && share < BLIND_BELOW {
            self.blind = true;
            return Some(Verdict::Blind { share });
        }
        if self.blind && share > SEEING_ABOVE {
            self.blind = false;
            return Some(Verdict::Seeing { share });
        }
        None
    }

    /// The running share, once a scan has come.
    pub fn share(&self) -> Option<f64> {
        self.share
    }

    /// The sentence for a sensor that sees almost nothing, while it does.
    pub fn blind_reason(&self) -> Option<String> {
        let share = self.share.filter(|_| self.blind)?;
        Some(format!(
            "it sees almost nothing: {:.0} % of its beams return (below {:.0} %); check that its lens is clean and uncovered and that it faces the room, not the sky or the floor, or replace it",
            share * 100.0,
            BLIND_BELOW * 100.0
        ))
    }

    /// A new connection: judge it afresh.
    pub fn reset(&mut self) {
        *self = Returns::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(hits: usize, of: usize) -> Vec<f32> {
        (0..of)
            .map(|i| {
                if i < hits {
                    5.0
                } else if i % 2 == 0 {
                    0.0
                } else {
                    f32::NAN
                }
            })
            .collect()
    }

    #[test]
    fn a_unit_that_sees_nothing_is_named_once_and_again_when_it_sees() {
        let mut r = Returns::default();
        let mut verdicts = Vec::new();
        for _ in 0..60 {
            verdicts.extend(r.observe(&scan(0, 1081)));
        }
        assert_eq!(
            verdicts,
            [Verdict::Blind { share: 0.0 }],
            "once, after 20 scans"
        );
        assert!(
            r.blind_reason()
                .is_some_and(|s| s.contains("0 % of its beams"))
        );
        verdicts.clear();
        for _ in 0..200 {
            verdicts.extend(r.observe(&scan(800, 1081)));
        }
        assert!(
            matches!(verdicts.as_slice(), [Verdict::Seeing { share }] if *share > SEEING_ABOVE),
            "{verdicts:?}"
        );
        assert_eq!(r.blind_reason(), None);
    }

    #[test]
    fn a_room_with_few_returns_is_not_called_blind_nor_does_it_flap() {
        let mut r = Returns::default();
        for i in 0..400 {
            // Between the two lines: 6–9 % of beams return.
            let hits = 65 + (i % 4) * 10;
            assert_eq!(r.observe(&scan(hits, 1081)), None, "scan {i}");
        }
        assert!(r.share().is_some_and(|s| (0.05..0.1).contains(&s)));
        assert_eq!(share_of(&[]), None);
    }
}
