//! The documented example config parses, and documents every key the loader accepts.

use std::path::Path;

use scanfuse::daemon::config::{Config, Connect, ScanMode};

fn example_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/site-example.toml")
}

#[test]
fn the_example_config_parses() {
    let config = Config::load(&example_path()).unwrap();
    assert_eq!(config.site.name, "hall-3f");
    assert_eq!(config.site.anchor, "entrance");
    assert_eq!(config.site.socket_mode, 0o660);
    assert_eq!(config.sensors.len(), 3);
    assert_eq!(config.sensors[1].mode, ScanMode::MD);
    assert!(config.sensors[1].survey.is_some());
    assert_eq!(
        config.sensors[2].connect,
        Connect::Tcp {
            host: "fd00::20".into(),
            port: 10940
        }
    );
}

#[test]
fn the_example_sets_every_key() {
    let text = std::fs::read_to_string(example_path()).unwrap();
    let keys = [
        "name",
        "state_dir",
        "socket",
        "socket_mode",
        "anchor",
        "role",
        "max_clients",
        "zones_frame", // [site]
        "id",
        "connect",
        "mode",
        "height_m",
        "pitch_deg",
        "survey", // [[sensor]]
        "x_m",
        "y_m",
        "yaw_deg",
        "sigma_xy_m",
        "sigma_yaw_deg", // survey
        "queue_scans",
        "static_view_s",
        "moved_fraction",
        "moved_persist_s",
        "refine_radius_m",
        "refine_yaw_deg",
        "motion_buffer_s", // [registration]
        "map_cell_m",
        "save_interval_s",
        "map_rate_hz",
        "watch_backlog",
        "occupied_thresh",
        "free_thresh", // [publish]
        "listen",
        "max_clients",
        "frames_per_s",
        "send_queue", // [web] (token_file is shown commented out: check needs the file), [foxglove]
        "enabled",
        "background_s",
        "death_s", // [track]
    ];
    for key in keys {
        let set = text.lines().any(|l| {
            let l = l.trim_start();
            !l.starts_with('#')
                && (l.starts_with(&format!("{key} =")) || l.contains(&format!(" {key} =")))
        });
        assert!(set, "config/site-example.toml does not set {key}");
    }
    // Keys that name a file are shown commented out (`scanfuse check` needs the file), but
    // shown.
    let commented = [
        "drawing",
        "drawing_layers",
        "drawing_scale",
        "drawing_pairs",
    ];
    for key in commented {
        let shown = text
            .lines()
            .any(|l| l.trim_start().starts_with(&format!("# {key} =")));
        assert!(shown, "config/site-example.toml does not show {key}");
    }
    // Every key the loader accepts is in the lists above: an unknown key is rejected with the
    // list of valid ones, which must all be documented.
    for table in [
        "[site]",
        "[registration]",
        "[publish]",
        "[foxglove]",
        "[track]",
    ] {
        let probe = text.replacen(table, &format!("{table}\nzz_probe = 1"), 1);
        let err = Config::parse(&probe, &example_path())
            .unwrap_err()
            .to_string();
        let valid: Vec<&str> = err.split('`').skip(3).step_by(2).collect();
        assert!(!valid.is_empty(), "{err}");
        for key in valid {
            assert!(
                keys.contains(&key) || commented.contains(&key),
                "{table} accepts {key}, which the example does not set: {err}"
            );
        }
    }
}
