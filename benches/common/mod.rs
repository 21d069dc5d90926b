//! What the daemon benchmarks share: reaching the socket of a daemon that is starting.

use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::{Duration, Instant};

/// Connects to the daemon's socket, retrying while it starts (up to 10 s).
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
