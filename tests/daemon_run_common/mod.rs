//! Shared by the `daemon_run_*` tests: the real `scanfuse` binary as a child process (daemon
//! and emulators), a site config written into a temp dir, and a blocking status-socket client.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use scanfuse::daemon::protocol::{Message, Poses, Status};

/// The `scanfuse` binary under test: this build's, or `SCANFUSE_BIN` (e.g. a release build,
/// to see the timing figures an installation would have).
pub fn bin() -> String {
    std::env::var("SCANFUSE_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_scanfuse").to_string())
}

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// A child process killed when dropped.
pub struct Proc(pub Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Proc {
    pub fn signal(&self, name: &str) {
        let ok = Command::new("kill")
            .args([format!("-{name}"), self.0.id().to_string()])
            .status()
            .expect("kill runs")
            .success();
        assert!(ok, "kill -{name} failed");
    }

    /// Waits for the exit; panics after `timeout`.
    pub fn wait_exit(&mut self, timeout: Duration) -> std::process::ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(status) = self.0.try_wait().expect("try_wait") {
                return status;
            }
            assert!(
                start.elapsed() < timeout,
                "the process did not exit within {timeout:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// The hall fixture's sensors and their mounts, as `[[sensor]]` extra lines.
pub const HALL: [(&str, &str); 5] = [
    ("gate", "height_m = 1.1"),
    ("dock", "height_m = 1.1"),
    ("mezz", "height_m = 1.0"),
    ("tough", "height_m = 1.2"),
    ("tilt", "height_m = 2.5\npitch_deg = -20.0"),
];

/// `write_config` sensors replaying `file`: each (id, extra lines) as `replay:FILE#id`.
pub fn replay_sensors<'a>(
    file: &Path,
    sensors: &[(&'a str, &'a str)],
) -> Vec<(&'a str, String, &'a str)> {
    sensors
        .iter()
        .map(|(id, extra)| (*id, format!("replay:{}#{id}", file.display()), *extra))
        .collect()
}

/// `[[sensor]]` tables: (id, connect, extra lines); `mode = "MD"` unless the extra lines set one.
pub fn write_config(
    dir: &Path,
    anchor: &str,
    sensors: &[(&str, String, &str)],
    publish: &str,
) -> PathBuf {
    let mut text = format!(
        "[site]\nname = \"test\"\nstate_dir = \"{}\"\nsocket = \"{}\"\nanchor = \"{anchor}\"\n",
        dir.join("state").display(),
        dir.join("s.sock").display()
    );
    for (id, connect, extra) in sensors {
        let mode = if extra.contains("mode =") {
            ""
        } else {
            "mode = \"MD\"\n"
        };
        text.push_str(&format!(
            "\n[[sensor]]\nid = \"{id}\"\nconnect = \"{connect}\"\n{mode}{extra}\n"
        ));
    }
    text.push_str(&format!("\n[publish]\n{publish}\n"));
    // No page unless a test serves one: tests run side by side, and 8080 is the user's.
    if !publish.contains("[web]") {
        text.push_str("\n[web]\nlisten = \"\"\n");
    }
    let path = dir.join("site.toml");
    std::fs::write(&path, text).expect("write config");
    path
}

/// `scanfuse run --config FILE`, logs to `dir/daemon.log`.
pub fn start_daemon(config: &Path, dir: &Path) -> Proc {
    start_daemon_with(config, dir, &[])
}

/// `scanfuse run --config FILE ARGS…`, logs to `dir/daemon.log`.
pub fn start_daemon_with(config: &Path, dir: &Path, args: &[&str]) -> Proc {
    let log = std::fs::File::create(dir.join("daemon.log")).expect("log file");
    Proc(
        Command::new(bin())
            .args(["run", "--config"])
            .arg(config)
            .args(args)
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("start scanfuse run"),
    )
}

/// `scanfuse emulate FILE --sensor ID --loop --listen ADDR`; returns it and its address.
pub fn start_emulator(file: &Path, sensor: &str, listen: &str) -> (Proc, String) {
    start_emulator_logged(file, sensor, listen, None)
}

/// `start_emulator` with its log (stderr, `info` level) written to `log`.
pub fn start_emulator_logged(
    file: &Path,
    sensor: &str,
    listen: &str,
    log: Option<&Path>,
) -> (Proc, String) {
    start_emulator_faulty(file, sensor, listen, log, &[])
}

/// `start_emulator_logged` with more `emulate` arguments (its faults).
pub fn start_emulator_faulty(
    file: &Path,
    sensor: &str,
    listen: &str,
    log: Option<&Path>,
    args: &[&str],
) -> (Proc, String) {
    let stderr = match log {
        Some(path) => Stdio::from(std::fs::File::create(path).expect("emulator log file")),
        None => Stdio::null(),
    };
    let mut child = Command::new(bin())
        .arg("emulate")
        .arg(file)
        .args(["--sensor", sensor, "--loop", "--listen", listen])
        .args(args)
        .stdout(Stdio::piped())
        .stderr(stderr)
        .spawn()
        .expect("start scanfuse emulate");
    let addr = if listen.ends_with(":0") {
        let stdout = child.stdout.take().expect("stdout");
        let mut line = String::new();
        BufReader::new(stdout)
            .read_line(&mut line)
            .expect("emulator prints its address");
        line.trim().to_string()
    } else {
        listen.to_string()
    };
    (Proc(child), addr)
}

/// A blocking status-socket client.
pub struct Client {
    reader: BufReader<UnixStream>,
    writer: UnixStream,
}

impl Client {
    /// Connects (retrying until the daemon has bound the socket) and reads the banner.
    pub fn connect(path: &Path, timeout: Duration) -> Client {
        let start = Instant::now();
        let stream = loop {
            match UnixStream::connect(path) {
                Ok(s) => break s,
                Err(e) => {
                    assert!(
                        start.elapsed() < timeout,
                        "no socket at {}: {e}",
                        path.display()
                    );
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
        };
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .expect("timeout");
        let mut client = Client {
            reader: BufReader::new(stream.try_clone().expect("clone")),
            writer: stream,
        };
        match client.read() {
            Message::Version(_) => {}
            other => panic!("expected the VERSION banner, got {other:?}"),
        }
        client
    }

    pub fn read(&mut self) -> Message {
        let mut line = String::new();
        self.reader.read_line(&mut line).expect("a reply line");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line:?}"))
    }

    pub fn request(&mut self, line: &str) -> Message {
        self.writer
            .write_all(format!("{line}\n").as_bytes())
            .expect("send");
        self.read()
    }

    pub fn status(&mut self) -> Status {
        match self.request(r#"{"cmd":"status"}"#) {
            Message::Status(s) => s,
            other => panic!("status answered {other:?}"),
        }
    }

    pub fn poses(&mut self) -> Poses {
        match self.request(r#"{"cmd":"poses"}"#) {
            Message::Poses(p) => p,
            other => panic!("poses answered {other:?}"),
        }
    }
}

/// Polls `check` every 200 ms until it returns `Some`, or panics with `what` after `timeout`.
pub fn wait_for<T>(timeout: Duration, what: &str, mut check: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = check() {
            return v;
        }
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Checks map.pgm/map.yaml/map.ply in `dir` are whole and agree with each other.
pub fn check_map_files(dir: &Path) {
    let pgm = std::fs::read(dir.join("map.pgm")).expect("map.pgm");
    let header: Vec<&[u8]> = pgm.splitn(5, |&b| b == b'\n').collect();
    assert_eq!(header[0], b"P5", "PGM magic");
    let dims = std::str::from_utf8(header[2]).expect("dims");
    let (w, h) = dims.split_once(' ').expect("w h");
    let (w, h): (usize, usize) = (w.parse().expect("w"), h.parse().expect("h"));
    assert!(w > 10 && h > 10, "a map of a site, not {w}×{h}");
    assert_eq!(header[4].len(), w * h, "PGM pixels");
    assert!(header[4].contains(&0), "some cell is occupied");
    assert!(header[4].contains(&254), "some cell is free");
    let yaml = std::fs::read_to_string(dir.join("map.yaml")).expect("map.yaml");
    assert!(yaml.contains("image: map.pgm"), "{yaml}");
    assert!(yaml.contains("resolution: 0.05"), "{yaml}");
    let ply = std::fs::read(dir.join("map.ply")).expect("map.ply");
    let end = b"end_header\n";
    let at = ply
        .windows(end.len())
        .position(|w| w == end)
        .expect("PLY header");
    let head = std::str::from_utf8(&ply[..at]).expect("ascii header");
    let count: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .expect("vertex count")
        .parse()
        .expect("count");
    assert!(count > 100, "points in the cloud: {count}");
    // x y z float, r g b uchar, sensor ushort.
    assert_eq!(ply.len() - at - end.len(), count * 17, "PLY body size");
}
