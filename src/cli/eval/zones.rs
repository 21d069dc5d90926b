//! `eval --only zones`: generated concourses split along their length into zones, each zone
//! registered on its own (as a zone daemon does) and the zones joined into one site frame
//! (`register::zones`, as the site daemon does), scored against the simulator's truth. The
//! same join as `cargo bench --bench zones_site`, without the processes and the network: a
//! seed in 20 s, where the bench takes five minutes. With `--site-compare`, each concourse is
//! also registered whole, as one daemon would, and the two compared unit by unit.

use anyhow::{Context, Result};
use scanfuse::geometry::{Pose2, pose_error, within_sigma};
use scanfuse::register::site::{Prior, SiteParams, register_site};
use scanfuse::register::zones::{ZoneInput, ZoneParams, ZoneSensor, ZonesResult, join_zones};
use scanfuse::register::{RegisterParams, ScanModel};
use scanfuse::scan::SensorInfo;
use scanfuse::sim::generate::{FloorSpec, concourse};
use std::time::Instant;

use super::Args;
use super::sim::{simulate_models, site_inputs, truth_pose};

/// A zone counts as right within this of the truth (m, °), or within 3σ of it: a zone at the
/// end of a chain of links carries the error of every link and zone before it, and says so.
const RIGHT_M: f64 = 0.10;
const RIGHT_DEG: f64 = 1.0;

/// Concourses of `--site-sensors` scanners (seeds from `--seed`), in `--zones` zones.
pub(super) fn run(args: &Args, params: &RegisterParams) -> Result<()> {
    let n = usize::from(args.site_sensors);
    let zones = args.zones.max(1);
    println!(
        "\n== Concourses of {n} scanners in {zones} zones, each zone registered alone and the zones joined (register::zones){}: every zone within {:.0} cm / {RIGHT_DEG}° of the truth, or within 3σ? ==",
        if args.zone_survey {
            ", the last zone's first unit surveyed (2 cm, 0.2°)"
        } else {
            ""
        },
        RIGHT_M * 100.0
    );
    println!(
        "{:>5} {:>6} {:>7} {:>6} {:>7} {:>7} {:>6} {:>9} {:>8} {:>7}  wrong and unplaced zones",
        "seed",
        "units",
        "placed",
        "zones",
        "≤10cm",
        "≤3σ",
        "wrong",
        "worst cm",
        "worst °",
        "join s"
    );
    let (mut all, mut placed, mut right, mut sigma_right) = (0, 0, 0, 0);
    for k in 0..args.sites {
        let seed = args.seed.wrapping_add(k as u64);
        let plan = concourse(FloorSpec { sensors: n }, seed, 0)
            .with_context(|| format!("--floor concourse --site-sensors {n}"))?;
        let models = match simulate_models(&plan, seed, 0.0, params)? {
            Ok(models) => models,
            Err(why) => {
                println!("{seed:>5} refused: {why}");
                continue;
            }
        };
        // Along the concourse: the generator names its units by bay, as the bench splits them.
        let mut models = models;
        models.sort_by(|a, b| a.0.id.cmp(&b.0.id));
        let per = models.len().div_ceil(zones);
        let mut inputs: Vec<ZoneInput> = Vec::new();
        let mut truths: Vec<Pose2> = Vec::new();
        let mut units_placed = 0;
        for (z, chunk) in models.chunks(per).enumerate() {
            let chunk = chunk.to_vec();
            let truth: Vec<Option<Pose2>> = chunk.iter().map(|(i, _)| truth_pose(i)).collect();
            let site = register_site(
                &site_inputs(chunk.clone()),
                0,
                params,
                &SiteParams::default(),
            );
            let sensors: Vec<ZoneSensor> = site
                .sensors
                .iter()
                .zip(chunk)
                .filter_map(|(placement, (info, model))| {
                    let p = placement.pose.as_ref().ok()?;
                    Some(ZoneSensor {
                        id: info.id.clone(),
                        model,
                        zone_from_sensor: p.pose.planar(),
                        sigma: [p.sigma_x_m, p.sigma_y_m, p.sigma_yaw_rad],
                        surveyed: None,
                    })
                })
                .collect();
            units_placed += sensors.len();
            truths.push(truth[0].unwrap_or_else(Pose2::identity));
            inputs.push(ZoneInput {
                id: format!("z{z:02}"),
                sensors,
            });
        }
        if args.zone_survey {
            survey_last_unit(&mut inputs, &models, truths[0]);
        }
        let t0 = Instant::now();
        let p = ZoneParams {
            register: params.clone(),
            ..ZoneParams::default()
        };
        let joined = join_zones(&inputs, 0, &p);
        let join_s = t0.elapsed().as_secs_f64();
        let (mut worst_m, mut worst_deg, mut ok, mut here) = (0f64, 0f64, 0, 0);
        let mut by_sigma = 0;
        let mut notes: Vec<String> = Vec::new();
        // Each zone's error (cm) down the chain from the anchor zone: where drift builds.
        let mut per_zone: Vec<String> = Vec::new();
        for (z, zone) in joined.zones.iter().enumerate() {
            match &zone.site_from_zone {
                Ok((pose, sigma)) => {
                    here += 1;
                    let (m, rad) = pose_error(pose, &(truths[0].inverse() * truths[z]));
                    let deg = rad.to_degrees();
                    worst_m = worst_m.max(m);
                    worst_deg = worst_deg.max(deg);
                    per_zone.push(format!("{} {:.1}", zone.id, m * 100.0));
                    let sigma_m = sigma[0].hypot(sigma[1]);
                    if m <= RIGHT_M && deg <= RIGHT_DEG {
                        ok += 1;
                    } else if within_sigma((m, rad), [sigma[0], sigma[1]], sigma[2], 3.0) {
                        ok += 1;
                        by_sigma += 1;
                    } else {
                        notes.push(format!(
                            "{} off {m:.2} m {deg:.1}° (σ {:.2} m {:.2}°)",
                            zone.id,
                            sigma_m,
                            sigma[2].to_degrees()
                        ));
                    }
                }
                Err(_) => notes.push(format!("{} unplaced", zone.id)),
            }
        }
        println!(
            "{seed:>5} {n:>6} {units_placed:>7} {here:>6} {:>7} {by_sigma:>7} {:>6} {:>9.1} {worst_deg:>8.2} {join_s:>7.1}  {}",
            ok - by_sigma,
            here - ok,
            worst_m * 100.0,
            notes.join(", ")
        );
        println!("      each zone's error, cm: {}", per_zone.join(", "));
        for zone in joined.zones.iter().filter(|z| z.site_from_zone.is_err()) {
            if let Err(why) = &zone.site_from_zone {
                println!("      {}: {why}", zone.id);
            }
        }
        if args.site_compare {
            println!(
                "      {}",
                against_one_daemon(&models, &inputs, &joined, params)
            );
        }
        all += inputs.len();
        placed += here;
        right += ok;
        sigma_right += by_sigma;
    }
    println!(
        "zones placed {placed} of {all}: within 10 cm / 1° {}, farther but within 3σ {sigma_right}, wrong {} (must be 0)",
        right - sigma_right,
        placed - right
    );
    Ok(())
}

/// `--zone-survey`: the last zone's first unit surveyed where it truly stands in the site
/// frame (`truth_from_site`: the site's frame in the truth's), σ 2 cm and 0.2°.
fn survey_last_unit(
    inputs: &mut [ZoneInput],
    models: &[(SensorInfo, ScanModel)],
    truth_from_site: Pose2,
) {
    let Some(unit) = inputs.last_mut().and_then(|z| z.sensors.first_mut()) else {
        return;
    };
    let truth = models
        .iter()
        .find(|(info, _)| info.id == unit.id)
        .and_then(|(info, _)| truth_pose(info));
    unit.surveyed =
        truth.map(|t| Prior::new(truth_from_site.inverse() * t, 0.02, 0.2f64.to_radians()));
}

/// The units the zones placed in the site frame against one daemon's: every unit registered
/// as one site (`register_site`, anchored at the first zone's first unit, whose frame is the
/// site's), units placed by both compared (`--site-compare`).
fn against_one_daemon(
    models: &[(SensorInfo, ScanModel)],
    zones: &[ZoneInput],
    joined: &ZonesResult,
    params: &RegisterParams,
) -> String {
    let t0 = Instant::now();
    let whole = register_site(
        &site_inputs(models.to_vec()),
        0,
        params,
        &SiteParams::default(),
    );
    let whole_s = t0.elapsed().as_secs_f64();
    let truth = |id: &str| {
        let first = truth_pose(&models.first()?.0)?;
        let info = &models.iter().find(|(i, _)| i.id == id)?.0;
        Some(first.inverse() * truth_pose(info)?)
    };
    let mut apart: Vec<(f64, f64)> = Vec::new();
    // Each unit's distance from the truth: placed by the zones, by one daemon (m).
    let (mut zones_off, mut one_off): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    for (zone, placed) in zones.iter().zip(&joined.zones) {
        let Ok((site_from_zone, _)) = &placed.site_from_zone else {
            continue;
        };
        for s in &zone.sensors {
            let one = whole
                .sensors
                .iter()
                .find(|w| w.id == s.id)
                .and_then(|w| w.pose.as_ref().ok());
            if let Some(one) = one {
                let (by_zones, by_one) = (site_from_zone * s.zone_from_sensor, one.pose.planar());
                apart.push(pose_error(&by_zones, &by_one));
                if let Some(t) = truth(&s.id) {
                    zones_off.push(pose_error(&by_zones, &t).0);
                    one_off.push(pose_error(&by_one, &t).0);
                }
            }
        }
    }
    let unplaced = whole.sensors.iter().filter(|w| w.pose.is_err()).count();
    if apart.is_empty() {
        return format!("one daemon: no unit placed by both ({unplaced} unplaced by it)");
    }
    // Sorts `v` (its last is then the worst).
    let median_mm = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).map_or(f64::NAN, |m| m * 1e3)
    };
    let mut m: Vec<f64> = apart.iter().map(|a| a.0).collect();
    let median_apart_mm = median_mm(&mut m);
    let worst_deg = apart.iter().map(|a| a.1).fold(0.0, f64::max).to_degrees();
    let within = apart
        .iter()
        .filter(|a| a.0 <= 0.01 && a.1 <= 0.1f64.to_radians())
        .count();
    format!(
        "against one daemon ({} units placed by both; it left {unplaced} unplaced, took {whole_s:.0} s): median {:.1} mm, worst {:.1} mm / {worst_deg:.2}°; {within} within 1 cm / 0.1°; to the truth, median {:.1} mm by the zones, {:.1} mm by one daemon",
        apart.len(),
        median_apart_mm,
        m.last().map_or(f64::NAN, |w| w * 1e3),
        median_mm(&mut zones_off),
        median_mm(&mut one_off)
    )
}
