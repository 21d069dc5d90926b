//! Real-data pairs and sites for `scanfuse eval`: single 180° scans from the CARMEN logs with
//! their SLAM-corrected poses as the truth.

use super::sim::INSTALLED_OVERLAP;
use super::site::{SiteTotals, solve_site};
use super::{Args, BINS, Case, bin_of};
use anyhow::{Result, bail};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use scanfuse::geometry::{Mount, Pose2};
use scanfuse::record::carmen;
use scanfuse::register::model::shared_view;
use scanfuse::register::site::SensorInput;
use scanfuse::register::{RegisterParams, ScanModel};
use std::collections::BTreeMap;
use std::sync::Arc;

/// The CARMEN logs, each scan's model built once: pair and site draws try many scans, often the
/// same ones.
pub(super) struct Logs<'a> {
    pub logs: Vec<(&'static str, Vec<carmen::LogScan>)>,
    params: &'a RegisterParams,
    models: BTreeMap<(usize, usize), Arc<ScanModel>>,
}

impl<'a> Logs<'a> {
    pub fn new(
        logs: Vec<(&'static str, Vec<carmen::LogScan>)>,
        params: &'a RegisterParams,
    ) -> Self {
        Logs {
            logs,
            params,
            models: BTreeMap::new(),
        }
    }

    /// The model of scan `k` of log `l`.
    fn model(&mut self, l: usize, k: usize) -> Arc<ScanModel> {
        let (logs, params) = (&self.logs, self.params);
        self.models
            .entry((l, k))
            .or_insert_with(|| {
                let scan = &logs[l].1[k].scan;
                Arc::new(ScanModel::from_scan(scan, None, &Mount::default(), params))
            })
            .clone()
    }
}

/// The CARMEN logs the real-data tables draw from, those present in `--real-data`.
pub(super) fn load_logs(args: &Args) -> Result<Vec<(&'static str, Vec<carmen::LogScan>)>> {
    let mut per_log = Vec::new();
    for name in ["intel", "aces", "freiburg-079", "csail"] {
        let path = args.real_data.join(format!("{name}-corrected.log.gz"));
        if !path.is_file() {
            continue;
        }
        let scans = carmen::load(&path)?;
        eprintln!("real data: {} scans from {}", scans.len(), path.display());
        per_log.push((name, scans));
    }
    if per_log.is_empty() {
        bail!("no CARMEN logs found in {}", args.real_data.display());
    }
    Ok(per_log)
}

/// Sites of `--site-sensors` real scans of one log, drawn as `SiteDraw::Installed` draws
/// sensors: each 1–10 m from one drawn before it and sharing at least `INSTALLED_OVERLAP` of its
/// view with it (and at least 1 m from every other, so no two are near-copies of one robot stop).
pub(super) fn real_sites(args: &Args, logs: &mut Logs) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0x5ea1_5173);
    SiteTotals::header("≤15cm/1.5°");
    let mut totals = SiteTotals::default();
    let mut attempts = 0;
    while totals.sites < args.sites && attempts < args.sites * 50 {
        attempts += 1;
        let l = rng.random_range(0..logs.logs.len());
        let count = logs.logs[l].1.len();
        let first = rng.random_range(0..count);
        let mut picked: Vec<(usize, Arc<ScanModel>)> = vec![(first, logs.model(l, first))];
        for _ in 1..args.site_sensors {
            let found = (0..200).find_map(|_| {
                let (parent, parent_model) = picked[rng.random_range(0..picked.len())].clone();
                let j = rng.random_range(0..count);
                let scans = &logs.logs[l].1;
                let at = |k: usize| scans[k].site_from_laser.translation.vector;
                let from_parent = (at(j) - at(parent)).norm();
                let apart = picked.iter().all(|(k, _)| (at(j) - at(*k)).norm() >= 1.0);
                if !(1.0..=10.0).contains(&from_parent) || !apart {
                    return None;
                }
                let truth = scans[parent].site_from_laser.inverse() * scans[j].site_from_laser;
                let m = logs.model(l, j);
                (shared_view(&parent_model, &m, &truth) >= INSTALLED_OVERLAP).then_some((j, m))
            });
            match found {
                Some(p) => picked.push(p),
                None => break,
            }
        }
        if picked.len() < usize::from(args.site_sensors) {
            continue;
        }
        let (name, scans) = &logs.logs[l];
        let truths: Vec<Pose2> = picked
            .iter()
            .map(|(k, _)| scans[*k].site_from_laser)
            .collect();
        let inputs: Vec<SensorInput> = picked
            .into_iter()
            .map(|(k, model)| SensorInput {
                id: format!("{name}#{k}"),
                model: (*model).clone(),
                mount: Mount::default(),
                prior: None,
            })
            .collect();
        let outcome = solve_site(
            &inputs,
            &truths,
            logs.params,
            (0.15, 1.5f64.to_radians()),
            args.site_compare,
            args.partners,
        );
        outcome.print(totals.sites + 1, name);
        totals.add(&outcome);
    }
    totals.print("15 cm / 1.5°");
    Ok(())
}

/// Draws real pairs from the CARMEN logs, spread over the overlap bins.
pub(super) fn real_cases(args: &Args, logs: &mut Logs) -> Result<Vec<Case>> {
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0x5ea1);
    let quota = args.real_pairs.div_ceil(BINS.len());
    let mut filled = [0usize; BINS.len()];
    let mut cases = Vec::new();
    let mut attempts = 0;
    while cases.len() < args.real_pairs && attempts < args.real_pairs * 200 {
        attempts += 1;
        let l = rng.random_range(0..logs.logs.len());
        let count = logs.logs[l].1.len();
        let (i, j) = (rng.random_range(0..count), rng.random_range(0..count));
        let scans = &logs.logs[l].1;
        let a_from_b = scans[i].site_from_laser.inverse() * scans[j].site_from_laser;
        let dist = a_from_b.translation.vector.norm();
        if !(1.0..=10.0).contains(&dist) {
            continue;
        }
        let (a, b) = (logs.model(l, i), logs.model(l, j));
        let overlap = shared_view(&a, &b, &a_from_b);
        let bin = bin_of(overlap);
        if filled[bin] >= quota {
            continue;
        }
        filled[bin] += 1;
        cases.push(Case {
            label: format!("{} {i}→{j}", logs.logs[l].0),
            a: (*a).clone(),
            b: (*b).clone(),
            a_from_b,
            overlap,
        });
    }
    Ok(cases)
}
