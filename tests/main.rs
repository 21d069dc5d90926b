//! Every end-to-end test in one binary: one link instead of one per file, and the tests of
//! different files run side by side (most wait on daemons, replays and browsers, not the CPU).
//! Filter by file: `cargo test --test integration zenoh_site`.

// Helpers the test files share.
mod common;
mod daemon_common;
mod daemon_run_common;
mod driver_support;

// One module per file.
mod cli_simulate_info;
mod daemon_cli;
mod daemon_config;
mod daemon_console;
mod daemon_map_after_move;
mod daemon_notify;
mod daemon_run_demo;
mod daemon_run_faults;
mod daemon_run_moved;
mod daemon_run_moved_live;
mod daemon_run_reload;
mod daemon_run_walkers;
mod daemon_signals;
mod daemon_socket;
mod daemon_state;
mod daemon_systemd;
mod drawing_align;
mod driver_clock_wrap;
mod driver_connect_timeout;
mod driver_emulator;
mod driver_fixtures;
mod driver_hokuyolx;
mod driver_paused_clock;
mod driver_record_cli;
mod driver_serial;
mod map_files;
mod people_outputs;
mod python_interop;
mod recording;
mod register_cli;
mod register_clocks;
mod register_pair;
mod register_real;
mod replay_servers;
mod replay_speed;
mod replay_wall_clock;
mod track_sim;
mod web_contract;
mod web_page_browser;
mod web_page_tracks;
mod zenoh_site;
mod zenoh_zone;

/// A file in tests/ that is not a module here would never run (`autotests = false`).
#[test]
fn every_test_file_is_a_module_of_this_binary() {
    let tests = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let main = std::fs::read_to_string(tests.join("main.rs")).unwrap();
    for entry in std::fs::read_dir(&tests).unwrap() {
        let path = entry.unwrap().path();
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else {
            continue;
        };
        let is_rust = path.extension().is_some_and(|e| e == "rs");
        let is_module_dir = path.join("mod.rs").is_file();
        if (is_rust && stem != "main") || is_module_dir {
            assert!(
                main.lines().any(|l| l == format!("mod {stem};")),
                "tests/{stem} is not declared in tests/main.rs, so it never runs"
            );
        }
    }
}
