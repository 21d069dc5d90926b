//! One site of sensors solved and scored against its truth, and the table the sites print.

use scanfuse::geometry::{Pose2, pose_error, within_sigma};
use scanfuse::register::RegisterParams;
use scanfuse::register::model::shared_view;
use scanfuse::register::site::{
    SensorInput, SiteParams, SiteResult, ViewDescriptor, add_sensor, rank_partners, register_site,
};
use std::time::Instant;

/// How one site came out against its truth.
pub(super) struct SiteOutcome {
    placed: usize,
    ok: usize,
    reachable: usize,
    sensors: usize,
    max_m: f64,
    max_deg: f64,
    ms: f64,
    /// Placed sensors with a caveat (too few pairs), and how many of those are wrong.
    flagged: usize,
    flagged_wrong: usize,
    /// Wrong placements off by more than 3σ of their own reported σ: confidently wrong.
    confident_wrong: usize,
    /// For each sensor not placed right: why, and whether the truth was among its candidates.
    why_wrong: Vec<String>,
    /// Pairs registered, pairs in all, rounds of pair selection.
    registered: usize,
    all_pairs: usize,
    rounds: usize,
    /// Truly overlapping pairs (≥ 30 % shared view) and, per `RECALL_K`, how many of them
    /// the ranking proposes within its first k partners of either end.
    overlapping: usize,
    recalled: [usize; RECALL_K.len()],
    /// Against registering every pair (`--site-compare`): what differs, and its time.
    compared: Option<String>,
    /// Sensors taken out of the solved site and added back one at a time (`added`).
    added: Option<String>,
}

/// Sites of at least this many sensors also time adding one sensor to the placed site.
const ADD_FROM_SENSORS: usize = 16;
/// How many placed sensors are taken out and added back, spread over the site.
const ADD_SAMPLES: usize = 5;

/// The k of the pair-selection recall figure.
const RECALL_K: [usize; 5] = [2, 4, 8, 16, 32];

impl SiteOutcome {
    pub(super) fn print(&self, k: usize, name: &str) {
        let n = self.sensors;
        println!(
            "{:<6} {:<6} {:>5}/{n} {:>7}/{n} {:>11.1} {:>10.2} {:>9.0} {:>7}/{n}",
            k,
            name,
            self.placed,
            self.ok,
            self.max_m * 100.0,
            self.max_deg,
            self.ms,
            self.reachable
        );
        println!(
            "    pairs registered: {} of {} ({} rounds of pair selection)",
            self.registered, self.all_pairs, self.rounds
        );
        if let Some(c) = &self.compared {
            println!("    {c}");
        }
        if let Some(a) = &self.added {
            println!("    {a}");
        }
        for w in &self.why_wrong {
            println!("{w}");
        }
    }
}

/// Sums over sites; prints the table's header and its totals line.
#[derive(Default)]
pub(super) struct SiteTotals {
    pub(super) sites: usize,
    sensors: usize,
    placed: usize,
    ok: usize,
    reachable: usize,
    flagged: usize,
    flagged_wrong: usize,
    confident_wrong: usize,
    slowest_ms: f64,
    registered: usize,
    all_pairs: usize,
    overlapping: usize,
    recalled: [usize; RECALL_K.len()],
    /// Why the last refused draw was refused.
    last_refusal: Option<String>,
}

impl SiteTotals {
    /// A draw that could not be used, and why.
    pub(super) fn refused(&mut self, why: String) {
        self.last_refusal = Some(why);
    }

    pub(super) fn header(tol: &str) {
        println!(
            "{:<6} {:<6} {:>7} {:>9} {:>11} {:>10} {:>9} {:>9}",
            "site", "plan", "placed", tol, "max err cm", "max err °", "time ms", "reachable"
        );
        println!(
            "(reachable: sensors joined to s0 by pairs whose candidates include the truth, an upper bound on what choosing among candidates can place)"
        );
    }

    pub(super) fn add(&mut self, o: &SiteOutcome) {
        self.sites += 1;
        self.sensors += o.sensors;
        self.placed += o.placed;
        self.ok += o.ok;
        self.reachable += o.reachable;
        self.flagged += o.flagged;
        self.flagged_wrong += o.flagged_wrong;
        self.confident_wrong += o.confident_wrong;
        self.slowest_ms = self.slowest_ms.max(o.ms);
        self.registered += o.registered;
        self.all_pairs += o.all_pairs;
        self.overlapping += o.overlapping;
        for (t, r) in self.recalled.iter_mut().zip(o.recalled) {
            *t += r;
        }
    }

    pub(super) fn print(&self, tol: &str) {
        if self.sites == 0 {
            println!(
                "no site could be drawn: every draw put a sensor outside the building, inside furniture or out of view of the others (fewer sensors per site draw more easily){}",
                self.last_refusal
                    .as_ref()
                    .map_or(String::new(), |why| format!("; the last: {why}"))
            );
            return;
        }
        println!(
            "all {} sites: {}/{} sensors placed, {} within {tol}, {} placed wrong ({} beyond 3σ of their own σ), {} reachable; slowest site {:.0} ms",
            self.sites,
            self.placed,
            self.sensors,
            self.ok,
            self.placed - self.ok,
            self.confident_wrong,
            self.reachable,
            self.slowest_ms
        );
        let wrong = self.placed - self.ok;
        println!(
            "flagged \"rests on too few pairs\": {} placed, {} of them wrong; unflagged: {} placed, {} wrong",
            self.flagged,
            self.flagged_wrong,
            self.placed - self.flagged,
            wrong - self.flagged_wrong
        );
        println!(
            "pairs registered: {} of {}; pair-selection recall (of {} pairs sharing ≥ 30 % of their view, the share a sensor's first k ranked partners include): {}",
            self.registered,
            self.all_pairs,
            self.overlapping,
            RECALL_K
                .iter()
                .zip(self.recalled)
                .map(|(k, r)| format!(
                    "k={k} {:.0} %",
                    100.0 * r as f64 / self.overlapping.max(1) as f64
                ))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
}

/// Solves a site anchored at its first sensor and scores every placement against `truths`
/// (site frame) within `tol` (m, rad).
pub(super) fn solve_site(
    inputs: &[SensorInput],
    truths: &[Pose2],
    params: &RegisterParams,
    tol: (f64, f64),
    compare: bool,
    partners: Option<usize>,
) -> SiteOutcome {
    let t0 = Instant::now();
    let selected = SiteParams {
        partners: partners.unwrap_or(SiteParams::default().partners),
        ..SiteParams::default()
    };
    let site = register_site(inputs, 0, params, &selected);
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let compared = compare.then(|| {
        let t0 = Instant::now();
        let all = SiteParams {
            partners: usize::MAX,
            ..SiteParams::default()
        };
        let every = register_site(inputs, 0, params, &all);
        differences(&site, &every, t0.elapsed().as_secs_f64() * 1e3)
    });
    let added = (inputs.len() >= ADD_FROM_SENSORS)
        .then(|| added(inputs, truths, &site, params, &selected, tol));
    let (overlapping, recalled) = recall(inputs, truths);
    let within = |e: (f64, f64)| e.0 <= tol.0 && e.1 <= tol.1;
    // Each placed sensor's error against the truth, relative to the anchor (m, rad).
    let errors: Vec<Option<(f64, f64)>> = site
        .sensors
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let (Ok(p), Some(t), Some(t0)) = (&s.pose, truths.get(k), truths.first()) else {
                return None;
            };
            Some(pose_error(&p.pose.planar(), &(t0.inverse() * t)))
        })
        .collect();
    let placed = errors.iter().flatten().count();
    // Whether each placed sensor the solve flagged (too few pairs) is wrong.
    let flagged: Vec<bool> = errors
        .iter()
        .zip(&site.sensors)
        .filter(|(_, s)| s.caveat.is_some())
        .filter_map(|(e, _)| e.map(|e| !within(e)))
        .collect();
    let ok = errors.iter().flatten().filter(|e| within(**e)).count();
    // A wrong placement its own σ covers is a loose answer honestly said; one beyond 3σ is
    // confidently wrong.
    let sigma_of = |k: usize| {
        site.sensors[k]
            .pose
            .as_ref()
            .map(|p| ([p.sigma_x_m, p.sigma_y_m], p.sigma_yaw_rad))
            .ok()
    };
    let confident_wrong = errors
        .iter()
        .enumerate()
        .filter(|(k, e)| {
            e.is_some_and(|e| {
                !within(e) && sigma_of(*k).is_some_and(|(xy, yaw)| !within_sigma(e, xy, yaw, 3.0))
            })
        })
        .count();
    let max_m = errors.iter().flatten().map(|e| e.0).fold(0.0, f64::max);
    let max_deg = errors
        .iter()
        .flatten()
        .map(|e| e.1.to_degrees())
        .fold(0.0, f64::max);
    // What placed each wrong sensor: the pairs used for it, and how wrong each was.
    let mut why_wrong = Vec::new();
    for (k, s) in site.sensors.iter().enumerate() {
        if let Err(why) = &s.pose {
            why_wrong.push(format!("    {} not placed: {why}", s.id));
        }
        let Some((dt, dyaw)) = errors[k].filter(|e| !within(*e)) else {
            continue;
        };
        for pr in site
            .pairs
            .iter()
            .filter(|pr| pr.used && (pr.a == k || pr.b == k))
        {
            let (Some(ta), Some(tb)) = (truths.get(pr.a), truths.get(pr.b)) else {
                continue;
            };
            let (et, eyaw) = pose_error(&pr.result.a_from_b, &(ta.inverse() * tb));
            let (sxy, syaw) = sigma_of(k).unwrap_or_default();
            why_wrong.push(format!(
                "    {} off by {:.2} m {:.1}° (its σ {:.2} m {:.2}°): pair {}–{} {} (pair error {:.2} m {:.1}°, ambiguity {:.2}, overlap {:.2})",
                s.id,
                dt,
                dyaw.to_degrees(),
                sxy[0].hypot(sxy[1]),
                syaw.to_degrees(),
                pr.a,
                pr.b,
                match &pr.result.verdict {
                    Ok(()) => "registered".to_string(),
                    Err(w) => format!("candidate of an unregistered pair ({w})"),
                },
                et,
                eyaw.to_degrees(),
                pr.result.ambiguity,
                pr.result.overlap
            ));
        }
    }
    // For each sensor not placed right: was the truth among its pairs' candidates at all?
    // (With both ends known: "truth #c/n of pair a–b" means the site solve had it to pick.)
    for (k, s) in site.sensors.iter().enumerate() {
        if truths.get(k).is_none() || errors[k].is_some_and(within) || k == 0 {
            continue;
        }
        let found: Vec<String> = site
            .pairs
            .iter()
            .filter(|pr| pr.a == k || pr.b == k)
            .filter_map(|pr| {
                let truth = truths.get(pr.a)?.inverse() * truths.get(pr.b)?;
                let c = pr
                    .result
                    .candidates
                    .iter()
                    .position(|c| within(pose_error(&c.a_from_b, &truth)))?;
                Some(format!(
                    "{}–{} #{}/{}",
                    pr.a,
                    pr.b,
                    c,
                    pr.result.candidates.len()
                ))
            })
            .collect();
        why_wrong.push(if found.is_empty() {
            format!("    {}: the truth is no pair's candidate", s.id)
        } else {
            format!(
                "    {}: the truth is a candidate of {}",
                s.id,
                found.join(", ")
            )
        });
    }
    // Sensors joined to s0 through pairs that had the truth among their candidates.
    let mut reachable = vec![false; site.sensors.len()];
    if let Some(r) = reachable.first_mut() {
        *r = true;
    }
    loop {
        let mut grew = false;
        for pr in &site.pairs {
            let (Some(ta), Some(tb)) = (truths.get(pr.a), truths.get(pr.b)) else {
                continue;
            };
            let truth = ta.inverse() * tb;
            let has_truth = pr
                .result
                .candidates
                .iter()
                .any(|c| within(pose_error(&c.a_from_b, &truth)));
            let (ra, rb) = (reachable[pr.a], reachable[pr.b]);
            if has_truth && ra != rb {
                reachable[pr.a] = true;
                reachable[pr.b] = true;
                grew = true;
            }
        }
        if !grew {
            break;
        }
    }
    SiteOutcome {
        placed,
        ok,
        reachable: reachable.iter().filter(|r| **r).count(),
        sensors: inputs.len(),
        max_m,
        max_deg,
        ms,
        flagged: flagged.len(),
        flagged_wrong: flagged.iter().filter(|w| **w).count(),
        confident_wrong,
        why_wrong,
        registered: site.pairs.len(),
        all_pairs: site.pairs.len() + site.skipped.len(),
        rounds: site.rounds,
        overlapping,
        recalled,
        compared,
        added,
    }
}

/// Takes `ADD_SAMPLES` placed sensors (spread over the site, never the anchor) out of the
/// solved site one at a time and adds each back (`add_sensor`): its time, the pairs it
/// registered, whether it lands right (against the truth) and how far from the site's pose.
fn added(
    inputs: &[SensorInput],
    truths: &[Pose2],
    site: &SiteResult,
    params: &RegisterParams,
    sp: &SiteParams,
    tol: (f64, f64),
) -> String {
    let placed: Vec<Option<Pose2>> = site
        .sensors
        .iter()
        .map(|s| s.pose.as_ref().ok().map(|p| p.pose.planar()))
        .collect();
    let sigma: Vec<[f64; 3]> = site
        .sensors
        .iter()
        .map(|s| {
            s.pose
                .as_ref()
                .ok()
                .map_or([0.0; 3], |p| [p.sigma_x_m, p.sigma_y_m, p.sigma_yaw_rad])
        })
        .collect();
    let candidates: Vec<usize> = (0..placed.len())
        .filter(|&k| k != site.anchor && placed[k].is_some())
        .collect();
    if candidates.is_empty() {
        return "adding one sensor: no placed sensor but the anchor to take out".to_string();
    }
    let step = candidates.len().div_ceil(ADD_SAMPLES).max(1);
    let (mut ms, mut pairs, mut others) = (Vec::new(), Vec::new(), 0);
    let (mut landed, mut right, mut max_mm) = (0, 0, 0.0f64);
    let mut refused = Vec::new();
    for &k in candidates.iter().step_by(step) {
        let t0 = Instant::now();
        let a = add_sensor(inputs, &placed, &sigma, k, params, sp);
        ms.push(t0.elapsed().as_secs_f64() * 1e3);
        pairs.push(a.pairs.len());
        others = others.max(a.placed);
        match (&a.pose, placed[k], truths.get(k), truths.first()) {
            (Ok(at), Some(site_pose), Some(t), Some(t0)) => {
                landed += 1;
                let (dt, dyaw) = pose_error(at, &(t0.inverse() * t));
                right += usize::from(dt <= tol.0 && dyaw <= tol.1);
                max_mm = max_mm.max(pose_error(at, &site_pose).0 * 1e3);
            }
            (Err(why), ..) => refused.push(format!("{}: {why}", inputs[k].id)),
            _ => {}
        }
    }
    let n = ms.len();
    ms.sort_by(f64::total_cmp);
    let mut line = format!(
        "adding one sensor ({n} placed ones taken out and added back): {landed}/{n} placed, {right} within tolerance of the truth, {} not; {:.0}–{:.0} ms (median {:.0} ms); {}–{} pairs registered of {others}; ≤ {max_mm:.1} mm from the site's pose",
        landed - right,
        ms.first().copied().unwrap_or(0.0),
        ms.last().copied().unwrap_or(0.0),
        ms.get(n / 2).copied().unwrap_or(0.0),
        pairs.iter().min().copied().unwrap_or(0),
        pairs.iter().max().copied().unwrap_or(0),
    );
    for r in refused {
        line.push_str(&format!("\n      not added: {r}"));
    }
    line
}

/// How a site solved with pair selection differs from one registering every pair.
fn differences(selected: &SiteResult, every: &SiteResult, every_ms: f64) -> String {
    let mut only_selected = Vec::new();
    let mut only_every = Vec::new();
    let mut max_mm: f64 = 0.0;
    let mut max_deg: f64 = 0.0;
    for (s, e) in selected.sensors.iter().zip(&every.sensors) {
        match (&s.pose, &e.pose) {
            (Ok(a), Ok(b)) => {
                let (dt, dyaw) = pose_error(&a.pose.planar(), &b.pose.planar());
                max_mm = max_mm.max(dt * 1e3);
                max_deg = max_deg.max(dyaw.to_degrees());
            }
            (Ok(_), Err(_)) => only_selected.push(s.id.as_str()),
            (Err(_), Ok(_)) => only_every.push(s.id.as_str()),
            _ => {}
        }
    }
    format!(
        "vs all pairs ({every_ms:.0} ms): placed only with selection [{}], only with all pairs [{}]; poses of both differ by ≤ {max_mm:.2} mm / {max_deg:.4}°",
        only_selected.join(" "),
        only_every.join(" ")
    )
}

/// Pairs sharing ≥ 30 % of their view at the truth, and how many of them the ranking puts
/// within each `RECALL_K` of either end's partners.
fn recall(inputs: &[SensorInput], truths: &[Pose2]) -> (usize, [usize; RECALL_K.len()]) {
    let descriptors: Vec<ViewDescriptor> = inputs
        .iter()
        .map(|s| ViewDescriptor::of(&s.model))
        .collect();
    let ranking = rank_partners(&descriptors);
    let rank_of = |i: usize, j: usize| ranking[i].iter().position(|&x| x == j);
    let (mut overlapping, mut recalled) = (0, [0; RECALL_K.len()]);
    for a in 0..inputs.len() {
        for b in a + 1..inputs.len() {
            let (Some(ta), Some(tb)) = (truths.get(a), truths.get(b)) else {
                continue;
            };
            if shared_view(&inputs[a].model, &inputs[b].model, &(ta.inverse() * tb)) < 0.3 {
                continue;
            }
            overlapping += 1;
            let first = rank_of(a, b).into_iter().chain(rank_of(b, a)).min();
            for (r, k) in recalled.iter_mut().zip(RECALL_K) {
                if first.is_some_and(|f| f < k) {
                    *r += 1;
                }
            }
        }
    }
    (overlapping, recalled)
}
