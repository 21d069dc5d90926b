//! One site across many machines (issue 21), on this one: a simulated concourse of
//! `SCANFUSE_BENCH_SENSORS` scanners (default 200, seed 1, no crowd; recorded once,
//! `SCANFUSE_BENCH_REC_S` s, cached under `target/bench-data/`) split along its length into
//! `SCANFUSE_BENCH_ZONES` zones (default 10), each a release `scanfuse run` process replaying
//! its own scanners (`replay:`, at ×1), and one site daemon (`role = "site"`, hosting the Zenoh
//! router) on loopback. It prints, until every zone is placed in the site frame or
//! `SCANFUSE_BENCH_S` s (default 600) pass: when each zone's own units were placed and when the
//! zone was placed in the site frame (from the zones' start), each placed unit's error in the
//! site frame against the recording's truth (median and worst per zone), and per process its CPU (share of one core over
//! the run), RSS and peak RSS, and the bytes a second each zone sends the site daemon. Then,
//! `SCANFUSE_BENCH_REFINE_S` s later (default 40; 0 skips), each zone's errors when every zone
//! was first placed and now, once the site daemon has joined the zones on later moments'
//! views and averaged its links, and its CPU meanwhile.
//!
//! Run: `cargo bench --bench zones_site` (`SCANFUSE_BIN` picks the binary; default the one
//! cargo built for the bench). 11 processes share the machine's cores: the times are this
//! machine's with everything at once, not one zone's alone.

mod common;

use std::io::BufReader;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use scanfuse::daemon::protocol::{Message, Poses, Status};
use scanfuse::geometry::{pose_error, pose2, within_sigma};

type Error = Box<dyn std::error::Error>;

/// `status` and `poses` of a daemon.
fn ask(socket: &Path) -> Result<(Status, Poses), Error> {
    let mut stream = BufReader::new(common::connect_when_up(socket)?);
    let status = match common::ask(&mut stream, "{\"cmd\":\"status\"}\n")? {
        Message::Status(s) => s,
        other => return Err(format!("status answered {other:?}").into()),
    };
    let poses = match common::ask(&mut stream, "{\"cmd\":\"poses\"}\n")? {
        Message::Poses(p) => p,
        other => return Err(format!("poses answered {other:?}").into()),
    };
    Ok((status, poses))
}

/// (VmRSS, VmHWM) of a process, MiB.
fn rss_mib(pid: u32) -> (f64, f64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
            .map_or(f64::NAN, |kb| kb / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

fn main() -> Result<(), Error> {
    let n = common::env_f64("SCANFUSE_BENCH_SENSORS", 200.0) as usize;
    let zones = common::env_f64("SCANFUSE_BENCH_ZONES", 10.0) as usize;
    let patience = Duration::from_secs_f64(common::env_f64("SCANFUSE_BENCH_S", 600.0));
    let rec_s = common::env_f64("SCANFUSE_BENCH_REC_S", 10.0);
    let bin = std::env::var("SCANFUSE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_scanfuse").to_string());
    println!("zones_site: {bin}, a concourse of {n} scanners in {zones} zones, looped at ×1");
    let file = common::concourse(&bin, n, rec_s, 0)?;
    let rec = scanfuse::record::read(&file)?;
    let mut ids: Vec<&scanfuse::scan::SensorInfo> = rec.sensors.iter().collect();
    // Along the concourse: its units are named by bay, so their ids sort by place.
    ids.sort_by(|a, b| a.id.cmp(&b.id));
    let per = ids.len().div_ceil(zones.max(1));
    let dir = tempfile::tempdir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");

    let site_dir = dir.path().join("site");
    std::fs::create_dir_all(&site_dir)?;
    let site_socket = site_dir.join("s.sock");
    std::fs::write(
        site_dir.join("site.toml"),
        format!(
            "[site]\nname = \"concourse\"\nrole = \"site\"\nanchor = \"z00\"\nstate_dir = \"{}\"\nsocket = \"{}\"\n\n[web]\nlisten = \"\"\n\n[zenoh]\nlisten = [\"{endpoint}\"]\n",
            site_dir.join("state").display(),
            site_socket.display()
        ),
    )?;
    let start = |config: &Path, log: &Path| -> Result<common::Daemon, Error> {
        Ok(common::Daemon(
            Command::new(&bin)
                .args(["run", "--config"])
                .arg(config)
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(log)?)
                .spawn()?,
        ))
    };
    let site = start(&site_dir.join("site.toml"), &site_dir.join("log"))?;
    common::connect_when_up(&site_socket)?;

    let mut daemons = Vec::new();
    let mut zone_of = std::collections::BTreeMap::new();
    for (z, units) in ids.chunks(per).enumerate() {
        let zone = format!("z{z:02}");
        let zdir = dir.path().join(&zone);
        std::fs::create_dir_all(&zdir)?;
        let mut text = format!(
            "[site]\nname = \"concourse\"\nanchor = \"{}\"\nstate_dir = \"{}\"\nsocket = \"{}\"\n",
            units[0].id,
            zdir.join("state").display(),
            zdir.join("s.sock").display()
        );
        for u in units {
            zone_of.insert(u.id.clone(), zone.clone());
            text.push_str(&format!(
                "\n[[sensor]]\nid = \"{}\"\nconnect = \"replay:{}#{}\"\nmode = \"MD\"\nheight_m = {:?}\npitch_deg = {:?}\n",
                u.id,
                file.display(),
                u.id,
                u.height_m.unwrap_or(1.0),
                u.pitch_deg.unwrap_or(0.0)
            ));
        }
        text.push_str(&format!(
            "\n[web]\nlisten = \"\"\n\n[zenoh]\nzone = \"{zone}\"\nconnect = [\"{endpoint}\"]\n"
        ));
        std::fs::write(zdir.join("site.toml"), text)?;
        daemons.push((
            zone,
            zdir.clone(),
            start(&zdir.join("site.toml"), &zdir.join("log"))?,
        ));
    }
    let started = Instant::now();
    let ticks0: Vec<u64> = daemons
        .iter()
        .map(|(_, _, d)| common::cpu_ticks(d.0.id()).unwrap_or(0))
        .collect();
    let site_ticks0 = common::cpu_ticks(site.0.id()).unwrap_or(0);

    // Poll: when each zone placed its own units, and when the site placed the zone.
    let mut own_at: Vec<Option<f64>> = vec![None; daemons.len()];
    let mut site_at: Vec<Option<f64>> = vec![None; daemons.len()];
    let mut last = None;
    // The poses when every zone was first in the site frame (before any refine).
    let mut first: Option<Poses> = None;
    while started.elapsed() < patience {
        std::thread::sleep(Duration::from_millis(500));
        let t = started.elapsed().as_secs_f64();
        for (k, (_, zdir, _)) in daemons.iter().enumerate() {
            if own_at[k].is_none()
                && let Ok((_, poses)) = ask(&zdir.join("s.sock"))
                && poses.sensors.iter().all(|s| s.registered)
            {
                own_at[k] = Some(t);
            }
        }
        let Ok((status, poses)) = ask(&site_socket) else {
            continue;
        };
        for (k, (zone, _, _)) in daemons.iter().enumerate() {
            let placed = status
                .zones
                .iter()
                .any(|z| z.zone == *zone && z.site_from_zone.is_some());
            if placed && site_at[k].is_none() {
                site_at[k] = Some(t);
            }
        }
        // Done when every zone is in the site frame and every zone has placed all its own
        // units, or a minute after the last zone joined (a zone may leave a unit unplaced).
        let last_joined = site_at.iter().flatten().fold(0.0f64, |a, &t| a.max(t));
        let done = site_at.iter().all(Option::is_some)
            && (own_at.iter().all(Option::is_some) || t > last_joined + 60.0);
        if first.is_none() && site_at.iter().all(Option::is_some) {
            first = Some(poses.clone());
        }
        last = Some((status, poses));
        if done {
            break;
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    let tps = common::ticks_per_s();
    let (status, poses) = last.ok_or("the site daemon never answered")?;

    // Each placed unit against the truth, in the anchor zone's anchor's frame.
    let truth = |id: &str| {
        rec.sensor(id)
            .and_then(|s| s.truth)
            .map(|t| pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()))
    };
    let world_from_site = truth(&poses.anchor).ok_or("no truth for the anchor")?;
    let errors_of = |poses: &Poses| -> Vec<UnitError> {
        let mut errors = Vec::new();
        for s in poses.sensors.iter().filter(|s| s.registered && !s.stale) {
            let (Some(x), Some(y), Some(yaw), Some(t)) = (s.x_m, s.y_m, s.yaw_deg, truth(&s.id))
            else {
                continue;
            };
            let (dt, dyaw) = pose_error(
                &pose2(x, y, yaw.to_radians()),
                &(world_from_site.inverse() * t),
            );
            // Beyond 3σ of what the site daemon says of the unit: wrong, not just imprecise.
            let beyond = !within_sigma(
                (dt, dyaw),
                [s.sigma_x_m.unwrap_or(0.0), s.sigma_y_m.unwrap_or(0.0)],
                s.sigma_yaw_deg.unwrap_or(0.0).to_radians(),
                3.0,
            );
            errors.push((s.id.clone(), dt, dyaw.to_degrees(), beyond));
        }
        errors
    };
    // A zone's units' errors, cm: "median / max".
    let in_zone = |errors: &[UnitError], zone: &str| {
        let mut mine: Vec<f64> = errors
            .iter()
            .filter(|e| zone_of.get(&e.0).map(String::as_str) == Some(zone))
            .map(|e| e.1 * 100.0)
            .collect();
        mine.sort_by(f64::total_cmp);
        match (mine.get(mine.len() / 2), mine.last()) {
            (Some(mid), Some(max)) => format!("{mid:.1} / {max:.1}"),
            _ => "-".to_string(),
        }
    };
    let mut errors = errors_of(&poses);

    println!(
        "\nzone  units  own units placed at  in the site frame at  pairs  error median/max cm  sends B/s  CPU of a core  RSS MiB (peak)"
    );
    for (k, (zone, _, d)) in daemons.iter().enumerate() {
        let z = status.zones.iter().find(|z| z.zone == *zone);
        let cpu = (common::cpu_ticks(d.0.id()).unwrap_or(0) - ticks0[k]) as f64 / tps / elapsed;
        let (rss, peak) = rss_mib(d.0.id());
        let at = |v: Option<f64>| v.map_or("never".to_string(), |t| format!("{t:.1} s"));
        let error = in_zone(&errors, zone);
        println!(
            "{zone}  {:>5}  {:>19}  {:>20}  {:>5}  {error:>19}  {:>9.0}  {:>13.2}  {rss:>6.0} ({peak:.0})",
            z.map_or(0, |z| z.sensors),
            at(own_at[k]),
            at(site_at[k]),
            z.and_then(|z| z.site_from_zone).map_or(0, |f| f.pairs),
            z.and_then(|z| z.bytes_per_s).unwrap_or(0.0),
            cpu
        );
        if let Some(why) = z.and_then(|z| z.reason.clone()) {
            println!("      not placed: {why}");
        }
    }
    let site_cpu =
        (common::cpu_ticks(site.0.id()).unwrap_or(0) - site_ticks0) as f64 / tps / elapsed;
    let (rss, peak) = rss_mib(site.0.id());
    println!("site daemon: CPU {site_cpu:.2} of a core, RSS {rss:.0} MiB (peak {peak:.0})");
    let placed = site_at.iter().filter(|t| t.is_some()).count();
    let all = site_at.iter().flatten().fold(0.0f64, |a, &t| a.max(t));
    println!(
        "{placed} of {} zones in the site frame; the last at {all:.1} s after the zones started",
        daemons.len()
    );
    summary(&mut errors, &zone_of);

    // The site daemon joins the zones again on later moments' views and averages each link
    // (`site_net`'s refines): the errors once it has.
    let refine_s = common::env_f64("SCANFUSE_BENCH_REFINE_S", 40.0);
    if refine_s > 0.0 && placed == daemons.len() {
        let (ticks, from) = (common::cpu_ticks(site.0.id()).unwrap_or(0), Instant::now());
        std::thread::sleep(Duration::from_secs_f64(refine_s));
        let (_, later) = ask(&site_socket)?;
        let cpu = (common::cpu_ticks(site.0.id()).unwrap_or(0) - ticks) as f64
            / tps
            / from.elapsed().as_secs_f64();
        let mut after = errors_of(&later);
        println!();
        println!(
            "{refine_s:.0} s later, the links averaged over the moments the site daemon joined again (site daemon CPU {cpu:.2} of a core meanwhile):"
        );
        println!("zone  error median/max cm: when every zone was first placed → now");
        let at_first = first.as_ref().map(errors_of).unwrap_or_default();
        for (zone, _, _) in &daemons {
            println!(
                "{zone}  {:>19} → {}",
                in_zone(&at_first, zone),
                in_zone(&after, zone)
            );
        }
        summary(&mut after, &zone_of);
    }
    Ok(())
}

/// A unit's error against the truth: id, m, °, and whether beyond 3σ of its reported σ.
type UnitError = (String, f64, f64, bool);

/// The worst and median unit against the truth, how many are off by more than 10 cm or 1°,
/// and how many of those by more than their σ says (a look-alike, or a σ too small).
fn summary(errors: &mut [UnitError], zone_of: &std::collections::BTreeMap<String, String>) {
    errors.sort_by(|a, b| b.1.total_cmp(&a.1));
    let far = errors.iter().filter(|e| e.1 > 0.1 || e.2 > 1.0).count();
    let wrong = errors.iter().filter(|e| e.3).count();
    if let Some(worst) = errors.first() {
        let mid = errors[errors.len() / 2].1;
        println!(
            "{} units in the site frame: error vs truth median {:.1} cm, worst {:.1} cm / {:.2}° ({} in zone {}); {far} beyond 10 cm or 1°, {wrong} beyond 3σ",
            errors.len(),
            mid * 100.0,
            worst.1 * 100.0,
            worst.2,
            worst.0,
            zone_of.get(&worst.0).map_or("?", String::as_str)
        );
    }
}
