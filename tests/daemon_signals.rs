//! Real signals, sent to this test process by `kill`, reach the daemon's handler. (A test
//! binary of its own: the handlers change how the whole process treats these signals.)

use std::process::Command;
use std::time::Duration;

use scanfuse::daemon::signals::{Request, Signals};

fn kill(signal: &str) {
    let pid = std::process::id().to_string();
    let status = Command::new("kill")
        .args([signal, &pid])
        .status()
        .expect("run kill");
    assert!(status.success());
}

#[tokio::test]
async fn hup_reloads_term_and_int_terminate() {
    let mut signals = Signals::install().unwrap();
    for (signal, want) in [
        ("-HUP", Request::Reload),
        ("-TERM", Request::Terminate),
        ("-INT", Request::Terminate),
        ("-HUP", Request::Reload),
    ] {
        kill(signal);
        let got = tokio::time::timeout(Duration::from_secs(10), signals.next())
            .await
            .expect("the signal arrives");
        assert_eq!(got, want, "{signal}");
    }
}
