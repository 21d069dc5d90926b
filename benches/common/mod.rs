//! What the daemon benchmarks share: their knobs from the environment, a daemon that is
//! killed when the bench ends, its CPU time, reaching its socket while it starts, and one
//! request's answer on it.

use scanfuse::daemon::protocol::Message;
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A bench's knob from the environment (`SCANFUSE_BENCH_…`), or `default`.
#[allow(dead_code)] // not every bench has knobs
pub fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Kills the daemon when the bench ends, however it ends.
#[allow(dead_code)] // not every bench starts a daemon process
pub struct Daemon(pub Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// utime + stime of a process, in clock ticks (`ticks_per_s` of them a second).
#[allow(dead_code)] // not every bench measures a daemon's CPU
pub fn cpu_ticks(pid: u32) -> Result<u64, String> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).map_err(|e| e.to_string())?;
    // Fields after the command name (which may hold spaces) start after the last ')'; utime
    // and stime are fields 14 and 15 of stat, 12 and 13 after the name.
    let rest = stat.rsplit_once(')').ok_or("malformed stat")?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let field = |k: usize| -> Result<u64, String> {
        f.get(k)
            .ok_or("short stat")?
            .parse::<u64>()
            .map_err(|e| e.to_string())
    };
    Ok(field(11)? + field(12)?)
}

/// Clock ticks per second (`getconf CLK_TCK`; 100 where it cannot say).
#[allow(dead_code)]
pub fn ticks_per_s() -> f64 {
    Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(100.0)
}

/// Connects to the daemon's socket, retrying while it starts (up to 10 s).
#[allow(dead_code)] // not every bench talks to a daemon
pub fn connect_when_up(socket: &Path) -> Result<UnixStream, Box<dyn std::error::Error>> {
    let started = Instant::now();
    loop {
        match UnixStream::connect(socket) {
            Ok(s) => return Ok(s),
            Err(_) if started.elapsed() < Duration::from_secs(10) => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => return Err(format!("no socket at {}: {e}", socket.display()).into()),
        }
    }
}

/// A site file's `[site]` and `[[sensor]]` tables for a recording's sensors (each reached at
/// `connect(id)`), and the `poses.toml` of their true poses in the anchor's frame, written to
/// `state`, so that the daemon fuses from its first scan. Returns the config text; a bench
/// appends its own tables.
#[allow(dead_code)] // not every bench starts a site of true poses
pub fn site_of_true_poses(
    rec: &scanfuse::record::Recording,
    name: &str,
    anchor: &str,
    state: &Path,
    socket: &Path,
    connect: impl Fn(&str) -> String,
) -> Result<String, Box<dyn std::error::Error>> {
    use scanfuse::daemon::protocol::{PoseSource, SensorPose};
    use scanfuse::daemon::state::{PosesFile, SavedPose};
    use scanfuse::geometry::{pose2, yaw_rad};

    let mut text = format!(
        "[site]\nname = \"{name}\"\nstate_dir = \"{}\"\nsocket = \"{}\"\nanchor = \"{anchor}\"\n",
        state.display(),
        socket.display()
    );
    let truth = |id: &str| -> Result<_, Box<dyn std::error::Error>> {
        let t = rec
            .sensor(id)
            .and_then(|s| s.truth)
            .ok_or_else(|| format!("the recording has no truth for {id}"))?;
        Ok(pose2(t.x_m, t.y_m, t.yaw_deg.to_radians()))
    };
    let world_from_anchor = truth(anchor)?;
    let mut saved = Vec::new();
    for info in &rec.sensors {
        let (height_m, pitch_deg) = (info.height_m.unwrap_or(1.0), info.pitch_deg.unwrap_or(0.0));
        text.push_str(&format!(
            "\n[[sensor]]\nid = \"{}\"\nconnect = \"{}\"\nmode = \"MD\"\nheight_m = {height_m:?}\npitch_deg = {pitch_deg:?}\n",
            info.id,
            connect(&info.id),
        ));
        let p = world_from_anchor.inverse() * truth(&info.id)?;
        let mut pose = SensorPose::unregistered(info.id.clone(), "");
        pose.registered = true;
        pose.reason = None;
        pose.x_m = Some(p.translation.x);
        pose.y_m = Some(p.translation.y);
        pose.yaw_deg = Some(yaw_rad(&p).to_degrees());
        pose.z_m = Some(height_m);
        pose.pitch_deg = Some(pitch_deg);
        saved.push(SavedPose::from_pose(
            &pose,
            PoseSource::Registered,
            std::time::SystemTime::now(),
        ));
    }
    PosesFile {
        anchor: anchor.into(),
        sensors: saved,
        building_from_site: None,
    }
    .save(state)?;
    Ok(text)
}

/// Sends one request line and returns the daemon's answer (the VERSION greeting and lines that
/// are not protocol objects skipped).
#[allow(dead_code)] // not every bench asks the socket this way
pub fn ask(stream: &mut BufReader<UnixStream>, req: &str) -> Result<Message, String> {
    stream
        .get_mut()
        .write_all(req.as_bytes())
        .map_err(|e| e.to_string())?;
    let mut line = String::new();
    loop {
        line.clear();
        if stream.read_line(&mut line).map_err(|e| e.to_string())? == 0 {
            return Err("the daemon closed the socket".into());
        }
        match serde_json::from_str::<Message>(&line) {
            Ok(Message::Version(_)) | Err(_) => continue,
            Ok(m) => return Ok(m),
        }
    }
}

/// A generated concourse of `sensors` scanners (seed 1, `crowd` people walking, `seconds` s),
/// recorded with `bin` the first time and cached under `target/bench-data/`.
#[allow(dead_code)] // not every bench replays a concourse
pub fn concourse(
    bin: &str,
    sensors: usize,
    seconds: f64,
    crowd: u32,
) -> Result<std::path::PathBuf, Box<dyn std::error::Error>> {
    let path = bench_data()?.join(format!(
        "concourse-{sensors}-{seconds}s-crowd{crowd}-seed1.mcap"
    ));
    let generate = format!("concourse:{sensors}");
    simulate_once(
        bin,
        &["--generate", &generate, "--crowd", &crowd.to_string()],
        seconds,
        &path,
    )?;
    Ok(path)
}

/// `target/bench-data/`, where benches keep what they simulate.
#[allow(dead_code)]
pub fn bench_data() -> Result<std::path::PathBuf, Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/bench-data");
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// `bin simulate ARGS --seed 1 --seconds S` into `path`, unless it is there already (written
/// under another name and renamed, so an interrupted run leaves no half a recording).
#[allow(dead_code)]
pub fn simulate_once(
    bin: &str,
    args: &[&str],
    seconds: f64,
    path: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    if path.exists() {
        return Ok(());
    }
    let partial = path.with_extension("partial");
    let started = Instant::now();
    let status = Command::new(bin)
        .arg("simulate")
        .args(args)
        .args(["--seed", "1", "--seconds", &seconds.to_string()])
        .args(["--zstd-level", "1", "--out"])
        .arg(&partial)
        .stdout(std::process::Stdio::null())
        .status()?;
    if !status.success() {
        return Err(format!("simulating {} failed: {status}", path.display()).into());
    }
    std::fs::rename(&partial, path)?;
    println!(
        "  recorded {} in {:.0} s",
        path.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The registration worker's core with every sensor of `rec` added (no survey, no pose yet),
/// and every scan of `rec` as its work item, in stamp order as the worker takes them.
#[allow(dead_code)]
pub fn registrar_fed(
    rec: &scanfuse::record::Recording,
    anchor: &str,
) -> (
    scanfuse::daemon::pipeline_register::Registrar,
    Vec<scanfuse::daemon::pipeline_register::WorkItem>,
) {
    use scanfuse::daemon::pipeline_register::{Command as RegCommand, Registrar, WorkItem};
    let config = scanfuse::daemon::config::RegistrationConfig::default();
    let mut r = Registrar::new(anchor, &config);
    for info in &rec.sensors {
        let add = RegCommand::Add {
            id: info.id.clone(),
            mount: info.mount(),
            survey: None,
            pose: None,
            sigma: None,
        };
        r.command(add, 0);
    }
    let mut items: Vec<WorkItem> = rec
        .sensors
        .iter()
        .flat_map(|info| {
            rec.scans_of(&info.id).iter().map(|scan| WorkItem {
                sensor: info.id.clone(),
                scan: scan.clone(),
                geometry: info.geometry,
            })
        })
        .collect();
    items.sort_by_key(|i| i.scan.stamp_ns);
    (r, items)
}
