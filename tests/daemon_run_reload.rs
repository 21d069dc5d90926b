//! SIGHUP re-reads the config: sensors added start streaming, sensors removed disappear, the
//! others keep running; a broken config is refused and the daemon keeps the old one.

use crate::daemon_run_common;

use std::time::Duration;

use daemon_run_common::*;
use scanfuse::daemon::protocol::SensorState;

#[test]
fn sighup_adds_and_removes_sensors_without_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let lab = fixture("lab.mcap");
    let sensor = |id: &'static str| (id, format!("replay:{}#{id}", lab.display()), "");
    let config = write_config(
        dir.path(),
        "entrance",
        &[sensor("entrance"), sensor("bench")],
        "save_interval_s = 0",
    );
    let mut daemon = start_daemon(&config, dir.path());
    let mut client = Client::connect(&dir.path().join("s.sock"), Duration::from_secs(30));
    let streaming = |client: &mut Client| -> Vec<String> {
        client
            .status()
            .sensors
            .iter()
            .filter(|s| s.state == SensorState::Streaming)
            .map(|s| s.id.clone())
            .collect()
    };
    wait_for(Duration::from_secs(30), "two sensors streaming", || {
        (streaming(&mut client) == ["bench", "entrance"]).then_some(())
    });

    // Add north, drop bench.
    write_config(
        dir.path(),
        "entrance",
        &[sensor("entrance"), sensor("north")],
        "save_interval_s = 0",
    );
    daemon.signal("HUP");
    wait_for(
        Duration::from_secs(30),
        "entrance and north streaming",
        || {
            let status = client.status();
            let ids: Vec<&str> = status.sensors.iter().map(|s| s.id.as_str()).collect();
            (ids == ["entrance", "north"]
                && status
                    .sensors
                    .iter()
                    .all(|s| s.state == SensorState::Streaming))
            .then_some(())
        },
    );

    // A broken config changes nothing.
    std::fs::write(&config, "[site]\nname = \"x\"\nbogus = 1\n").unwrap();
    daemon.signal("HUP");
    std::thread::sleep(Duration::from_secs(1));
    let status = client.status();
    assert_eq!(status.sensors.len(), 2, "{status:?}");
    assert!(daemon.0.try_wait().unwrap().is_none(), "still running");

    daemon.signal("TERM");
    assert!(daemon.wait_exit(Duration::from_secs(30)).success());
}
