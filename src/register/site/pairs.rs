//! Pair selection: which pairs of sensors are registered (today every pair, in parallel).

use super::SensorInput;
use crate::register::{PairResult, RegisterParams, register_pair};
use rayon::prelude::*;

/// Every pair (a < b) and its registration.
#[allow(clippy::type_complexity)]
pub(super) fn register_all(
    sensors: &[SensorInput],
    p: &RegisterParams,
) -> (Vec<(usize, usize)>, Vec<PairResult>) {
    let n = sensors.len();
    let pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
        .collect();
    let results: Vec<PairResult> = pairs
        .par_iter()
        .map(|&(a, b)| register_pair(&sensors[a].model, &sensors[b].model, p))
        .collect();
    (pairs, results)
}
