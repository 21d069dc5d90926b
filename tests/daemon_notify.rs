//! systemd notifications, checked the way systemd receives them: a child process (this test
//! binary, running its ignored `child` test) gets `NOTIFY_SOCKET` pointing at a datagram socket
//! the parent bound, and the parent reads what arrives.

use std::os::unix::net::UnixDatagram;
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use scanfuse::daemon::notify::Notifier;

const MODE: &str = "SCANFUSE_NOTIFY_CHILD_MODE";

fn run_child(mode: &str, notify_socket: Option<&std::path::Path>) -> std::process::ExitStatus {
    // The test's name in this binary: its module path without the crate's name.
    let (_, module) = module_path!().split_once("::").unwrap();
    let mut cmd = Command::new(std::env::current_exe().unwrap());
    cmd.args([
        "--ignored",
        "--exact",
        &format!("{module}::child"),
        "--nocapture",
        "--test-threads=1",
    ])
    .env(MODE, mode)
    .env_remove("NOTIFY_SOCKET")
    .env_remove("WATCHDOG_PID");
    match notify_socket {
        Some(path) => cmd
            .env("NOTIFY_SOCKET", path)
            .env("WATCHDOG_USEC", "200000"),
        None => cmd.env_remove("WATCHDOG_USEC"),
    };
    cmd.status().unwrap()
}

#[test]
fn the_daemon_side_sends_ready_status_watchdog_and_stopping() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    assert!(
        run_child("notify", Some(&path)).success(),
        "the child's own checks failed"
    );
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = socket.recv(&mut buf).expect("a datagram from the child");
        let text = String::from_utf8_lossy(&buf[..n]).into_owned();
        let done = text == "STOPPING=1\n";
        got.push(text);
        if done {
            break;
        }
    }
    assert_eq!(got[0], "READY=1\nSTATUS=1/2 sensors\n");
    assert_eq!(got[1], "STATUS=2/2 sensors, registered\n");
    let marker = got
        .iter()
        .position(|d| d == "STATUS=pipeline stalled\n")
        .unwrap();
    let pings = got[2..marker]
        .iter()
        .filter(|d| *d == "WATCHDOG=1\n")
        .count();
    assert!(
        pings >= 2,
        "pings every 100 ms while alive for 350 ms: {got:?}"
    );
    assert!(
        !got[marker..].iter().any(|d| d == "WATCHDOG=1\n"),
        "no pings once the pipeline is not alive: {got:?}"
    );
    assert!(
        got[marker + 1].starts_with("RELOADING=1\nMONOTONIC_USEC="),
        "{got:?}"
    );
}

#[test]
fn without_notify_socket_everything_is_a_quiet_no_op() {
    assert!(
        run_child("absent", None).success(),
        "the child's own checks failed"
    );
}

/// Runs only as the child of the tests above.
#[test]
#[ignore = "runs as a child process of the notify tests"]
fn child() {
    let mode = std::env::var(MODE).expect("started by a parent test");
    let notifier = Notifier::from_env();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    if mode == "absent" {
        assert_eq!(notifier.watchdog_interval(), None);
        notifier.ready("x").unwrap();
        notifier.watchdog().unwrap();
        // Returns at once: no watchdog was asked for.
        runtime.block_on(notifier.run_watchdog(|| true, std::future::pending()));
        return;
    }
    assert_eq!(
        notifier.watchdog_interval(),
        Some(Duration::from_millis(100))
    );
    notifier.ready("1/2 sensors").unwrap();
    notifier.status("2/2 sensors, registered").unwrap();
    let alive = Arc::new(AtomicBool::new(true));
    let flag = Arc::clone(&alive);
    runtime.block_on(async {
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let watchdog = tokio::spawn(notifier.run_watchdog(
            move || flag.load(Ordering::SeqCst),
            async {
                let _ = stop_rx.await;
            },
        ));
        tokio::time::sleep(Duration::from_millis(350)).await;
        alive.store(false, Ordering::SeqCst);
        notifier.status("pipeline stalled").unwrap();
        tokio::time::sleep(Duration::from_millis(350)).await;
        let _ = stop_tx.send(());
        watchdog.await.unwrap();
    });
    notifier.reloading().unwrap();
    notifier.stopping().unwrap();
}
