//! A sensor address that takes the SYN and never answers: the driver's connect must time out,
//! say so in its counters and last error, and retry with backoff, never panicking.
//!
//! The hang is made on loopback: a listener with a backlog of 1 that never accepts. Once its
//! accept queue is full, Linux drops further SYNs, so the next connect waits for an answer that
//! never comes, exactly like a powered-off unit on the LAN. tokio's clock is paused, so the
//! timeouts and backoffs are checked to the millisecond without waiting for them.

use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use scanfuse::sensor::{Driver, DriverConfig, DriverEvent};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// Fills the accept queue of `addr` until a connect hangs; returns the held connections.
fn fill_accept_queue(addr: SocketAddr) -> Vec<TcpStream> {
    let mut held = Vec::new();
    for _ in 0..64 {
        match TcpStream::connect_timeout(&addr, Duration::from_millis(300)) {
            Ok(stream) => held.push(stream),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return held,
            Err(e) => panic!("unexpected connect error while filling the queue: {e}"),
        }
    }
    panic!("the accept queue never filled: this kernel does not drop SYNs on a full queue");
}

#[tokio::test(start_paused = true)]
async fn a_connect_that_hangs_times_out_is_counted_and_retried_with_backoff() {
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let listener = socket.listen(1).unwrap();
    let addr = listener.local_addr().unwrap();
    let held = fill_accept_queue(addr);
    assert!(!held.is_empty());

    let mut config = DriverConfig::new("hall", format!("tcp://{addr}"));
    config.connect_timeout = Duration::from_millis(200);
    config.backoff_initial = Duration::from_millis(100);
    config.backoff_max = Duration::from_millis(400);
    let driver = Driver::new(config);
    let counters = driver.counters();
    let (tx, mut rx) = mpsc::channel(64);
    let (stop, stop_rx) = watch::channel(false);
    let started = Instant::now();
    let task = tokio::spawn(driver.run(tx, stop_rx));

    // Each failed attempt ends in a Disconnected event when its connect times out.
    let mut failures_ms = Vec::new();
    while failures_ms.len() < 6 {
        match rx.recv().await {
            Some(DriverEvent::Disconnected { reason }) => {
                assert!(reason.contains("timed out"), "{reason}");
                assert!(reason.contains(&addr.to_string()), "{reason}");
                failures_ms.push(started.elapsed().as_millis());
            }
            Some(other) => panic!("nothing should connect: {other:?}"),
            None => panic!("the driver gave up"),
        }
    }
    // Attempt k starts after the previous timeout (200 ms) plus a backoff of 100, 200, 400,
    // 400… ms, so the timeouts fall at 200, 500, 900, 1500, 2100, 2700 ms.
    let gaps: Vec<u128> = failures_ms.windows(2).map(|w| w[1] - w[0]).collect();
    assert_eq!(failures_ms[0], 200, "{failures_ms:?}");
    assert_eq!(gaps, vec![300, 400, 600, 600, 600], "{failures_ms:?}");

    let c = counters.snapshot();
    assert_eq!((c.connects, c.scans), (0, 0));
    assert!(c.connect_failures >= 6, "{c:?}");
    assert!(c.reconnects >= 5, "{c:?}");
    let last = c.last_error.unwrap();
    assert!(last.contains("timed out after 200ms"), "{last}");

    stop.send(true).unwrap();
    task.await.expect("the driver ends without panicking");
    drop(held);
    drop(listener);
}
