//! Recordings made on different machines stamp their scans by different clocks, and walkers
//! are compared by time. Before walkers of two recordings are weighed together, the offset
//! between their clocks is found from the walkers themselves ([`clock_offset`]) and taken out;
//! where it cannot be found, that recording's walkers are not used (its units register from
//! walls alone) rather than compared at skewed times.

use std::sync::Arc;

use super::RegisterParams;
use super::site::SensorInput;
use super::walkers::clock_offset;

/// Clocks further apart than this are not searched (s): beyond it, say so and use walls.
pub const MAX_CLOCK_OFFSET_S: f64 = 1.0;
/// Pairs of units tried per recording before giving up.
const PAIRS_TRIED: usize = 6;

/// What was done about one recording's clock.
#[derive(Debug, Clone, PartialEq)]
pub enum Clock {
    /// Its stamps read `offset_s` more than the reference recording's, found from walkers
    /// both `reference_unit` and `unit` saw; taken out.
    Aligned {
        offset_s: f64,
        reference_unit: String,
        unit: String,
    },
    /// No offset within ±[`MAX_CLOCK_OFFSET_S`] aligned any walkers: its units' walkers are
    /// left out.
    Unknown,
}

/// Aligns every recording's walkers to the clock of recording `reference`: `sources[i]` is the
/// recording input `i` came from. Returns what was done per recording other than the
/// reference. Inputs without motion are left as they are.
pub fn align_clocks(
    inputs: &mut [SensorInput],
    sources: &[usize],
    reference: usize,
    p: &RegisterParams,
) -> Vec<(usize, Clock)> {
    let mut recordings: Vec<usize> = sources.to_vec();
    recordings.sort_unstable();
    recordings.dedup();
    let mut out = Vec::new();
    for r in recordings.into_iter().filter(|&r| r != reference) {
        let of = |want: usize| -> Vec<usize> {
            (0..inputs.len())
                .filter(|&i| sources.get(i) == Some(&want))
                .filter(|&i| inputs.get(i).is_some_and(|s| s.model.motion.is_some()))
                .collect()
        };
        let (mine, theirs) = (of(r), of(reference));
        let found = theirs
            .iter()
            .flat_map(|&a| mine.iter().map(move |&b| (a, b)))
            .take(PAIRS_TRIED)
            .find_map(|(a, b)| {
                let ma = inputs.get(a)?.model.motion.as_ref()?;
                let mb = inputs.get(b)?.model.motion.as_ref()?;
                let off = clock_offset(ma, mb, &p.walkers, &p.motion, MAX_CLOCK_OFFSET_S)?;
                Some((a, b, off.offset_s))
            });
        let clock = match found {
            Some((a, b, offset_s)) => Clock::Aligned {
                offset_s,
                reference_unit: inputs.get(a).map(|s| s.id.clone()).unwrap_or_default(),
                unit: inputs.get(b).map(|s| s.id.clone()).unwrap_or_default(),
            },
            None => Clock::Unknown,
        };
        for &i in &mine {
            let Some(input) = inputs.get_mut(i) else {
                continue;
            };
            input.model.motion = match &clock {
                Clock::Aligned { offset_s, .. } => input
                    .model
                    .motion
                    .as_ref()
                    .map(|m| Arc::new(m.shifted(-offset_s, &p.motion))),
                Clock::Unknown => None,
            };
        }
        out.push((r, clock));
    }
    out
}
