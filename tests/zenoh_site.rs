//! One site across several machines: the site daemon (`[site] role = "site"`, hosting the Zenoh
//! router) joins three zone daemons into one frame, all real `scanfuse run` processes on
//! 127.0.0.1. The hall's five units, three in west, the dock in east and tough in north, come
//! out in the site frame as each zone places them relative to one another (to the millimetre:
//! zones stay authoritative), and where one daemon holding all five puts them, within 5 cm and
//! 0.3° once the site daemon has averaged five moments' joins (8 cm at the first join: one
//! moment's views, through the hall's people): a zone solves its units from its own pairs only,
//! so its poses differ from one daemon's by up to a few cm, and that carries into the links.
//! The table prints each unit's Δ to one daemon and both against the recording's truth, with σ,
//! at both moments. A zone killed is lost within 2 s, its poses kept and marked stale, and
//! started again it rejoins with nothing else restarted; the site daemon restarted rebuilds the
//! site from the zones. The zones send what their trackers see (`[zenoh] detections = true`),
//! west its scans too (`scans_hz`): the site daemon tracks the hall's people across zones (one
//! person seen by units of two zones is one track, one id), streams west's scans in the site
//! frame to `map` watchers and saves the fused map. East's bytes a second are printed with its
//! detections and, back after the kill without them, without. Every zone replays the hall
//! anchored to one wall-clock time (`--replay-since`), so the zones are in step, as live units
//! are, also east once restarted.
#![cfg(feature = "zenoh")]

use crate::daemon_run_common;

use std::path::Path;
use std::time::{Duration, Instant};

use daemon_run_common::{
    Client, HALL, Proc, check_map_files, fixture, replay_sensors, start_daemon, start_daemon_with,
    wait_for, write_config,
};
use scanfuse::daemon::protocol::{Message, Poses, SensorPose};

/// How long any one expected thing may take before the test gives up (not a timing assert).
const PATIENCE: Duration = Duration::from_secs(90);

/// The site daemon's config: the router on `endpoint`, its page on 127.0.0.1 at a port of
/// its choosing (read back from `status`: one picked free here and released could be taken
/// by a replay emulator before the daemon binds it), a counting zone `hall` over the whole site frame, and tough (north's only unit) surveyed in
/// the site frame where it truly stands (σ 3 mm, 0.05°): a second anchor.
fn site_config(dir: &Path, endpoint: &str) -> std::path::PathBuf {
    let (x, y, yaw) = truth_from("gate")["tough"];
    let text = format!(
        "[site]\nname = \"test\"\nrole = \"site\"\nanchor = \"west\"\nstate_dir = \"{}\"\nsocket = \"{}\"\n\n[web]\nlisten = \"127.0.0.1:0\"\n\n[zenoh]\nlisten = [\"{endpoint}\"]\n\n[[zone]]\nid = \"hall\"\npolygon = [[-60, -60], [60, -60], [60, 60], [-60, 60]]\n\n[[survey]]\nsensor = \"tough\"\nx_m = {x}\ny_m = {y}\nyaw_deg = {yaw}\nsigma_xy_m = 0.003\nsigma_yaw_deg = 0.05\n",
        dir.join("state").display(),
        dir.join("s.sock").display()
    );
    let path = dir.join("site.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// A zone daemon holding `units` of the hall, its first the zone's anchor; `more` lines in
/// its `[zenoh]` (the opt-in streams). Its replay is anchored to the wall clock at `since`
/// (`--replay-since`), as every zone's: restarted, it replays in step with the others.
fn zone(
    dir: &Path,
    zone: &str,
    units: &[(&'static str, &'static str)],
    endpoint: &str,
    more: &str,
    since: &str,
) -> Proc {
    let sensors = replay_sensors(&fixture("hall.mcap"), units);
    let config = write_config(
        dir,
        units[0].0,
        &sensors,
        &format!("\n[zenoh]\nzone = \"{zone}\"\nconnect = [\"{endpoint}\"]\n{more}\n"),
    );
    start_daemon_with(&config, dir, &["--replay-since", since])
}

fn sensor<'a>(poses: &'a Poses, id: &str) -> Option<&'a SensorPose> {
    poses.sensors.iter().find(|s| s.id == id)
}

/// Waits for every one of `ids` placed in the site frame; on timeout, says what the site
/// daemon showed last.
fn wait_all_placed(client: &mut Client, ids: &[&str], what: &str) -> Poses {
    let start = Instant::now();
    loop {
        if let Some(p) = all_placed(client, ids) {
            return p;
        }
        if start.elapsed() > PATIENCE {
            panic!(
                "timed out waiting for {what}; the site daemon shows {:?}\n{:?}",
                client.status().zones,
                client.poses().sensors
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Poses with every one of `ids` placed (and live).
fn all_placed(client: &mut Client, ids: &[&str]) -> Option<Poses> {
    let poses = client.poses();
    ids.iter()
        .all(|id| sensor(&poses, id).is_some_and(|s| s.registered && !s.stale))
        .then_some(poses)
}

#[test]
fn zones_join_into_the_frame_one_daemon_would_give_and_survive_losing_one() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // The site daemon's, west's, east's, the one daemon's and north's.
    let dirs: Vec<tempfile::TempDir> = (0..5).map(|_| tempfile::tempdir().unwrap()).collect();
    let ids = ["gate", "dock", "mezz", "tough", "tilt"];
    // West holds three units, east the dock, north tough; pairs across them register (the
    // dock with mezz and with tough, tough with mezz). The hall's units share too little for
    // a zone of two far units to place both in good time: its own registration, not the
    // join, would set the pace.
    let west_units = [HALL[0], HALL[4], HALL[2]];
    let east_units = [HALL[1]];
    let north_units = [HALL[3]];

    // The site daemon first, to bind the router's port before any replay emulator starts
    // (they listen on ports the system chooses, the one picked above among them).
    let started = Instant::now();
    let mut site_daemon = start_daemon(&site_config(dirs[0].path(), &endpoint), dirs[0].path());
    // One daemon holding all five: the frame the site must reproduce.
    let whole = write_config(
        dirs[3].path(),
        "gate",
        &replay_sensors(&fixture("hall.mcap"), &HALL),
        "",
    );
    let _whole = start_daemon(&whole, dirs[3].path());
    // West sends what its tracker sees and its scans twice a second; east and north what
    // their trackers see. Anchored to one wall-clock time, their replays of the hall run in
    // step, as live units would, whenever each was started (east again, below).
    let since = format!(
        "{:.3}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64()
    );
    let _west = zone(
        dirs[1].path(),
        "west",
        &west_units,
        &endpoint,
        "detections = true\nscans_hz = 2",
        &since,
    );
    let mut east = zone(
        dirs[2].path(),
        "east",
        &east_units,
        &endpoint,
        "detections = true",
        &since,
    );
    let _north = zone(
        dirs[4].path(),
        "north",
        &north_units,
        &endpoint,
        "detections = true",
        &since,
    );

    let mut site = Client::connect(&dirs[0].path().join("s.sock"), PATIENCE);
    let line = wait_for(PATIENCE, "the site daemon on Zenoh", || {
        site.status()
            .zenoh
            .filter(|z| z.contains("the site daemon"))
    });
    assert!(
        line.contains(&endpoint) && line.contains("anchor zone west"),
        "{line}"
    );
    let joined = wait_all_placed(
        &mut site,
        &ids,
        "every unit of the three zones in the site frame",
    );
    println!(
        "the three zones in the site frame {:?} after start",
        started.elapsed()
    );
    // Surveyed, tough stands where the survey says, to its σ, not where the links alone
    // would put it (5–13 mm off before it was surveyed).
    let (t, yaw) = apart(
        xyyaw(sensor(&joined, "tough").unwrap()),
        truth_from("gate")["tough"],
    );
    println!(
        "tough, surveyed: {:.1} mm, {yaw:.3}° from its truth",
        t * 1e3
    );
    assert!(t < 0.004 && yaw < 0.06, "{t:.4} m, {yaw:.3}°");
    let mut reference = Client::connect(&dirs[3].path().join("s.sock"), PATIENCE);
    let whole = wait_for(PATIENCE, "the one daemon to place all five", || {
        all_placed(&mut reference, &ids)
    });
    let placed_at = Instant::now();
    check_site("first join", ONE_MOMENT_M, &joined, &whole, &dirs);
    let status = site.status();
    for z in &status.zones {
        println!(
            "zone {} sends the site daemon {:.0} bytes/s (poses and status of {} unit(s){})",
            z.zone,
            z.bytes_per_s.unwrap_or(0.0),
            z.sensors,
            if z.zone == "west" {
                ", what its tracker sees, and its scans twice a second"
            } else {
                ", and what its tracker sees"
            }
        );
        assert!(z.bytes_per_s.is_some_and(|b| b > 0.0), "{z:?}");
    }
    // The zones' drivers, as each zone says.
    for id in ids {
        assert!(
            status.sensors.iter().any(|s| s.id == id),
            "{id} has no driver status"
        );
    }
    site_map(
        &dirs[0].path().join("s.sock"),
        &dirs[0].path().join("state"),
    );
    people_across_zones(&dirs[0].path().join("s.sock"));
    let page = site.status().web.expect("the site daemon serves its page");
    site_page(&page, &ids);
    let east_status = status.zones.iter().find(|z| z.zone == "east").unwrap();
    let frame = east_status.site_from_zone.expect("east is placed");
    assert!(frame.pairs >= 1 && frame.sigma_x_m > 0.0, "{frame:?}");
    // Joined again every 5 s on later moments' views, four times: each link averages them.
    std::thread::sleep(Duration::from_secs(23).saturating_sub(placed_at.elapsed()));
    let refined = wait_all_placed(&mut site, &ids, "every unit still placed");
    check_site("five joins averaged", 0.05, &refined, &whole, &dirs);
    zones_report_the_site_frame(&mut site, &dirs);

    // East killed: lost within the lease, its poses kept, marked stale.
    let killed = Instant::now();
    east.0.kill().unwrap();
    let _ = east.0.wait();
    wait_for(PATIENCE, "east lost", || {
        site.status()
            .zones
            .iter()
            .find(|z| z.zone == "east" && !z.alive)
            .map(|_| ())
    });
    let lost = killed.elapsed();
    println!("east killed → lost to the site daemon in {lost:?}");
    assert!(lost < Duration::from_secs(2), "{lost:?}");
    // Past the next join (which no longer sees east), east's poses still stand, stale.
    std::thread::sleep(Duration::from_secs(4));
    let poses = site.poses();
    let dock = sensor(&poses, "dock").expect("dock's last pose kept");
    assert!(dock.stale && dock.registered, "{dock:?}");
    assert!(!sensor(&poses, "gate").unwrap().stale);

    // Started again, it rejoins; nothing else was restarted.
    // Back, it sends neither stream: its bytes a second without them.
    let _east = zone(dirs[2].path(), "east", &east_units, &endpoint, "", &since);
    wait_all_placed(&mut site, &ids, "east back and placed");
    std::thread::sleep(Duration::from_secs(10));
    let east_status = site.status().zones.into_iter().find(|z| z.zone == "east");
    println!(
        "zone east, back without its detections, sends the site daemon {:.0} bytes/s",
        east_status.and_then(|z| z.bytes_per_s).unwrap_or(0.0)
    );

    // The site daemon gone, a zone's line no longer says where the site put it: it says
    // when the site daemon was last heard.
    let mut west = Client::connect(&dirs[1].path().join("s.sock"), PATIENCE);
    let placed_line = west.status().zenoh.unwrap_or_default();
    assert!(placed_line.contains("anchor zone"), "{placed_line}");
    drop(site);
    site_daemon.signal("TERM");
    site_daemon.wait_exit(PATIENCE);
    let silent = wait_for(PATIENCE, "west to say the site daemon is silent", || {
        west.status()
            .zenoh
            .filter(|z| z.contains("the site daemon has not been heard"))
    });
    println!("west, the site daemon gone: {silent}");
    // The site daemon restarted rebuilds the site from the zones.
    let restarted = Instant::now();
    let _site_daemon = start_daemon(&site_config(dirs[0].path(), &endpoint), dirs[0].path());
    let mut site = Client::connect(&dirs[0].path().join("s.sock"), PATIENCE);
    let again = wait_all_placed(
        &mut site,
        &ids,
        "the restarted site daemon to place every unit",
    );
    println!(
        "site daemon restarted → all placed in {:?}",
        restarted.elapsed()
    );
    check_site(
        "the restarted site daemon's first join",
        ONE_MOMENT_M,
        &again,
        &whole,
        &dirs,
    );
    wait_for(PATIENCE, "west to hear the site daemon again", || {
        west.status()
            .zenoh
            .filter(|z| !z.contains("has not been heard"))
    });
}

/// West's scans reach the site daemon's `map` watchers in the site frame, and its `save`
/// writes the fused map's files.
fn site_map(socket: &Path, state: &Path) {
    let mut watcher = Client::connect(socket, PATIENCE);
    match watcher.request(r#"{"cmd":"watch","status":false,"map":true}"#) {
        Message::Watch(w) => assert!(w.map, "{w:?}"),
        other => panic!("watch answered {other:?}"),
    }
    let frame = loop {
        if let Message::Frame(f) = watcher.read() {
            break f;
        }
    };
    let scan = &frame.scans[0];
    assert!(
        scan.sensor != "dock" && scan.xy_m.len() > 200,
        "{} with {} coordinates",
        scan.sensor,
        scan.xy_m.len()
    );
    let mut site = Client::connect(socket, PATIENCE);
    // Saved once each of west's units has been fused (a second, at the site daemon's pace).
    std::thread::sleep(Duration::from_secs(2));
    match site.request(r#"{"cmd":"save"}"#) {
        Message::Saved(s) => {
            println!("the site daemon saved {:?} in {}", s.files, s.dir);
            assert!(s.files.contains(&"map.pgm".to_string()), "{s:?}");
        }
        other => panic!("save answered {other:?}"),
    }
    check_map_files(state);
}

/// The site daemon's page, over its WebSocket (tokio-tungstenite, another codebase's
/// client): every unit of every zone with its zone, west's scans, and the map they make.
fn site_page(web: &str, ids: &[&str]) {
    // "page at http://127.0.0.1:PORT/"
    let url = web
        .strip_prefix("page at http://")
        .map(|at| format!("ws://{at}ws"))
        .unwrap_or_else(|| panic!("status' web: {web:?}"));
    use futures_util::StreamExt;
    let runtime = tokio::runtime::Runtime::new().unwrap();
    runtime.block_on(async {
        let (mut socket, _) = tokio_tungstenite::connect_async(url)
            .await
            .expect("the site daemon's page opens");
        let (mut zoned, mut map, mut frame) = (false, false, false);
        let mut classes = std::collections::BTreeSet::new();
        let start = Instant::now();
        while !(zoned && map && frame) {
            assert!(
                start.elapsed() < PATIENCE,
                "the page showed {classes:?}: zoned units {zoned}, map {map}, scans {frame}"
            );
            let next = tokio::time::timeout(Duration::from_secs(30), socket.next()).await;
            let Ok(Some(Ok(tokio_tungstenite::tungstenite::Message::Text(text)))) = next else {
                panic!("the page's WebSocket ended or went quiet: {next:?}");
            };
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            let class = v["class"].as_str().unwrap_or("").to_string();
            match class.as_str() {
                "POSES" => {
                    let zone_of = |id: &str| {
                        v["sensors"]
                            .as_array()
                            .and_then(|a| a.iter().find(|s| s["id"] == id))
                            .and_then(|s| s["zone"].as_str().map(str::to_string))
                    };
                    zoned = ids.iter().all(|id| zone_of(id).is_some())
                        && zone_of("dock").as_deref() == Some("east");
                }
                "MAP" => map |= v["width"].as_u64().is_some_and(|w| w > 10),
                "FRAME" => {
                    frame |= v["scans"][0]["sensor"]
                        .as_str()
                        .is_some_and(|s| s != "dock")
                }
                _ => {}
            }
            classes.insert(class);
        }
        println!(
            "the site daemon's page showed {classes:?} in {:?}",
            start.elapsed()
        );
    });
}

/// Watches the site daemon's tracks until one track (one id) has been seen by units of east
/// and west, at once or one after the other (the dock is east's; gate, mezz and tilt west's):
/// a person the zones share is one person. Says what it saw when that does not come.
fn people_across_zones(socket: &Path) {
    let mut watcher = Client::connect(socket, PATIENCE);
    match watcher.request(r#"{"cmd":"watch","status":false,"tracks":true}"#) {
        Message::Watch(w) => assert!(w.tracks, "{w:?}"),
        other => panic!("watch answered {other:?}"),
    }
    let start = Instant::now();
    let (mut lines, mut tracked) = (0, 0);
    // Each id's units over its life.
    let mut by: std::collections::BTreeMap<u64, std::collections::BTreeSet<String>> =
        Default::default();
    let (mut across, mut counted) = (false, None);
    while !across || counted.is_none() {
        // A hang guard. Before the zones' replays were anchored to one time they could start
        // out of step on a loaded machine, and then only someone standing still where two
        // zones see merged (57 s, once); in step, it takes under a second.
        assert!(
            start.elapsed() < PATIENCE,
            "no track seen by east and west ({across}) or no one counted in zone hall ({counted:?}): {lines} TRACKS lines, {tracked} tracks, by id {by:?}"
        );
        let t = match watcher.read() {
            Message::Tracks(t) => t,
            // The site file's zone counts the site's tracks, as a zone daemon's counts its own.
            Message::Zones(z) => {
                if let Some(hall) = z.zones.iter().find(|z| z.id == "hall" && z.count > 0) {
                    counted.get_or_insert(hall.count);
                }
                continue;
            }
            _ => continue,
        };
        lines += 1;
        for track in &t.tracks {
            tracked += 1;
            let units = by.entry(track.id).or_default();
            units.extend(track.sensors.iter().cloned());
            let east = units.iter().any(|s| s == "dock");
            let west = units
                .iter()
                .any(|s| ["gate", "mezz", "tilt"].contains(&s.as_str()));
            if east && west && !across {
                across = true;
                println!(
                    "track {} (now at ({:.2}, {:.2}) m, seen by {:?}) has been seen by {units:?}, across east and west, {:?} after the watch began ({} TRACKS lines)",
                    track.id,
                    track.x_m,
                    track.y_m,
                    track.sensors,
                    start.elapsed(),
                    lines
                );
            }
        }
    }
    println!("zone hall of the site file counted {counted:?} people");
}

/// How far a first join may put a unit (m): one moment's views through the hall's people
/// have put the dock up to 40 mm off, within 1.5 σ of what the site says of it (28 mm).
const ONE_MOMENT_M: f64 = 0.08;

/// The site's poses against one daemon's (printed; within `limit_m` and 0.3°), both against
/// the recording's truth in the anchor unit's frame (printed; the site's within `limit_m` and
/// 0.3°), and against each zone's own (to the millimetre: the site frame moves each zone
/// whole).
fn check_site(what: &str, limit_m: f64, site: &Poses, whole: &Poses, dirs: &[tempfile::TempDir]) {
    let truth = truth_from("gate");
    println!("{what}:");
    println!(
        "unit   zone   site frame (m, °)            one daemon                 Δ (mm, °)       to truth: site (mm, °)   one daemon (mm, °)   σ site, one daemon (mm, mm, °)"
    );
    for a in &site.sensors {
        let b = sensor(whole, &a.id).unwrap();
        let (dt, dyaw) = apart(xyyaw(a), xyyaw(b));
        let (site_t, site_yaw) = apart(xyyaw(a), truth[&a.id]);
        let (whole_t, whole_yaw) = apart(xyyaw(b), truth[&a.id]);
        println!(
            "{:<6} {:<6} ({:7.3}, {:7.3}, {:7.2})  ({:7.3}, {:7.3}, {:7.2})  {:5.1}, {:5.3}    {:5.1}, {:5.3}             {:5.1}, {:5.3}        {}  {}",
            a.id,
            a.zone.as_deref().unwrap_or("?"),
            a.x_m.unwrap(),
            a.y_m.unwrap(),
            a.yaw_deg.unwrap(),
            b.x_m.unwrap(),
            b.y_m.unwrap(),
            b.yaw_deg.unwrap(),
            dt * 1e3,
            dyaw,
            site_t * 1e3,
            site_yaw,
            whole_t * 1e3,
            whole_yaw,
            sigmas(a),
            sigmas(b)
        );
        let zone = match a.id.as_str() {
            "dock" => "east",
            "tough" => "north",
            _ => "west",
        };
        assert_eq!(a.zone.as_deref(), Some(zone), "{}", a.id);
        assert!(
            dt < limit_m && dyaw < 0.3,
            "{}: {dt:.4} m, {dyaw:.3}°",
            a.id
        );
        assert!(
            site_t < limit_m && site_yaw < 0.3,
            "{}: {site_t:.4} m, {site_yaw:.3}° from the truth",
            a.id
        );
    }
    for (zone, dir) in [("west", &dirs[1]), ("east", &dirs[2]), ("north", &dirs[4])] {
        let own = Client::connect(&dir.path().join("s.sock"), PATIENCE).poses();
        let units: Vec<&SensorPose> = own.sensors.iter().filter(|s| s.registered).collect();
        for pair in units.windows(2) {
            let (p, q) = (pair[0], pair[1]);
            let apart = |p: &SensorPose, q: &SensorPose| {
                (p.x_m.unwrap() - q.x_m.unwrap()).hypot(p.y_m.unwrap() - q.y_m.unwrap())
            };
            let in_zone = apart(p, q);
            let in_site = apart(sensor(site, &p.id).unwrap(), sensor(site, &q.id).unwrap());
            assert!(
                (in_zone - in_site).abs() < 1e-3,
                "zone {zone}: {} to {} is {in_zone:.4} m in the zone, {in_site:.4} m in the site",
                p.id,
                q.id
            );
        }
    }
}

/// Each zone's own `poses` says where the site daemon put its frame (`site_from_zone`): its
/// units composed with it are where the site daemon has them (to the millimetre; asked again
/// while a join moves a frame between the two questions).
fn zones_report_the_site_frame(site: &mut Client, dirs: &[tempfile::TempDir]) {
    for (zone, dir) in [("west", &dirs[1]), ("east", &dirs[2]), ("north", &dirs[4])] {
        let mut own = Client::connect(&dir.path().join("s.sock"), PATIENCE);
        let start = Instant::now();
        let said = loop {
            let (mine, theirs) = (own.poses(), site.poses());
            let said = match mine.site_from_zone {
                None => Err("no site_from_zone in the zone's poses".to_string()),
                Some(f) => {
                    let (sin, cos) = f.yaw_deg.to_radians().sin_cos();
                    let off: Vec<String> = mine
                        .sensors
                        .iter()
                        .filter(|p| p.registered)
                        .filter_map(|p| {
                            let (x, y, yaw) = xyyaw(p);
                            let composed = (
                                f.x_m + cos * x - sin * y,
                                f.y_m + sin * x + cos * y,
                                f.yaw_deg + yaw,
                            );
                            let (dt, dyaw) = match sensor(&theirs, &p.id) {
                                Some(q) => apart(composed, xyyaw(q)),
                                None => (f64::INFINITY, f64::INFINITY),
                            };
                            (dt >= 1e-3 || dyaw >= 0.01)
                                .then(|| format!("{} {:.4} m, {dyaw:.4}° off", p.id, dt))
                        })
                        .collect();
                    if off.is_empty() {
                        Ok(format!("{f:?}"))
                    } else {
                        Err(format!("{} ({f:?})", off.join(", ")))
                    }
                }
            };
            match said {
                Ok(said) => break said,
                Err(why) if start.elapsed() > Duration::from_secs(10) => {
                    panic!("zone {zone}: {why}")
                }
                Err(_) => std::thread::sleep(Duration::from_millis(200)),
            }
        };
        println!("zone {zone}'s poses say where its frame stands in the site's: {said}");
    }
}

/// A placed unit's σ as the socket gives it: x, y (mm), yaw (°).
fn sigmas(p: &SensorPose) -> String {
    let mm = |v: Option<f64>| v.map_or("?".into(), |v| format!("{:.0}", v * 1e3));
    let deg = p.sigma_yaw_deg.map_or("?".into(), |v| format!("{v:.2}"));
    format!("({}, {}, {deg})", mm(p.sigma_x_m), mm(p.sigma_y_m))
}

/// A placed unit's pose: x, y (m), yaw (°).
fn xyyaw(p: &SensorPose) -> (f64, f64, f64) {
    (p.x_m.unwrap(), p.y_m.unwrap(), p.yaw_deg.unwrap())
}

/// How far apart two poses of one unit are: m, and ° (absolute).
fn apart(a: (f64, f64, f64), b: (f64, f64, f64)) -> (f64, f64) {
    let dyaw = (a.2 - b.2 + 540.0).rem_euclid(360.0) - 180.0;
    ((a.0 - b.0).hypot(a.1 - b.1), dyaw.abs())
}

/// The hall recording's true pose of each unit in `anchor`'s frame: x, y (m), yaw (°).
fn truth_from(anchor: &str) -> std::collections::BTreeMap<String, (f64, f64, f64)> {
    use scanfuse::geometry::pose2;
    let rec = scanfuse::record::read(&fixture("hall.mcap")).expect("the hall recording");
    let pose = |id: &str| {
        let s = rec.sensors.iter().find(|s| s.id == id).expect(id);
        let t = s.truth.expect("the simulator's truth");
        pose2(t.x_m, t.y_m, t.yaw_deg.to_radians())
    };
    let site_from_anchor = pose(anchor);
    rec.sensors
        .iter()
        .map(|s| {
            let p = site_from_anchor.inverse() * pose(&s.id);
            let at = (
                p.translation.x,
                p.translation.y,
                p.rotation.angle().to_degrees(),
            );
            (s.id.clone(), at)
        })
        .collect()
}
