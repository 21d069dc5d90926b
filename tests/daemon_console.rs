//! What the daemon commands print when nobody reads them at a terminal (the journal, a file,
//! a pipe): each event once, as a structured log line, and the results on stdout.

use crate::daemon_run_common;

use daemon_run_common::{bin, fixture};

#[test]
fn off_a_terminal_each_event_is_printed_once() {
    let dir = tempfile::tempdir().unwrap();
    let output = std::process::Command::new(bin())
        .arg("replay")
        .arg(fixture("lab.mcap"))
        .args(["--speed", "1", "--out"])
        .arg(dir.path().join("out"))
        .env_remove("RUST_LOG")
        .env_remove("JOURNAL_STREAM")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let all: Vec<&str> = stdout.lines().chain(stderr.lines()).collect();
    let count = |needle: &str| all.iter().filter(|l| l.contains(needle)).count();

    // The events, as the log has them: `… INFO scanfuse::event: MESSAGE sensor=… kind=…`.
    let events: Vec<&str> = stderr
        .lines()
        .filter_map(|l| l.split_once("scanfuse::event: ")?.1.rsplit_once(" sensor="))
        .map(|(message, _)| message)
        .collect();
    assert!(
        events.iter().any(|m| m.starts_with("registering ")),
        "{stderr}"
    );
    for message in &events {
        // Once per event: several sensors may have the same message.
        let times = events.iter().filter(|m| *m == message).count();
        assert_eq!(
            count(message),
            times,
            "{message:?} {times} times in:\n{stdout}\n{stderr}"
        );
    }
    // Each sensor's connection once (the driver's line; the event is not logged again).
    for id in ["bench", "east", "entrance", "north"] {
        let connected = all
            .iter()
            .filter(|l| l.contains(" connected"))
            .filter(|l| l.split(|c: char| !c.is_alphanumeric()).any(|w| w == id))
            .count();
        assert_eq!(connected, 1, "{id} connected once in:\n{stdout}\n{stderr}");
    }
    // No person's event lines (`HH:MM:SS  …`) on stdout, and no colour codes in the log.
    assert!(
        !stdout.lines().any(|l| l.len() > 10
            && l.as_bytes()[2] == b':'
            && l.as_bytes()[5] == b':'
            && l.as_bytes()[8..10] == *b"  "),
        "{stdout}"
    );
    assert!(!stderr.contains('\u{1b}'), "{stderr}");
    // The results are there once.
    assert_eq!(count("poses in the frame of \"entrance\""), 1, "{stdout}");
    assert_eq!(count("wrote poses.toml"), 1, "{stdout}");
}
