//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// The Python interpreter of the venv `.ci/run` builds (tests/python/requirements.txt), from
/// `SCANFUSE_TEST_PYTHON`. Without it the interop tests skip with a message, except under CI,
/// where a missing interpreter is a failure: CI must run them.
pub fn test_python(test: &str) -> Option<PathBuf> {
    match std::env::var_os("SCANFUSE_TEST_PYTHON") {
        Some(p) => Some(PathBuf::from(p)),
        None if std::env::var_os("CI").is_some() => {
            panic!("{test}: SCANFUSE_TEST_PYTHON is not set under CI; .ci/run sets it")
        }
        None => {
            eprintln!(
                "{test}: skipped: set SCANFUSE_TEST_PYTHON to a python with tests/python/requirements.txt (.ci/run does)"
            );
            None
        }
    }
}

/// The repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `cmd` to the end and returns its output, failing the test with its stderr unless it
/// exited 0.
pub fn succeeded(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{cmd:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}
