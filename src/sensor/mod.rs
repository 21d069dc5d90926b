//! Drivers for SCIP 2.0 sensors over TCP or USB serial: connect, handshake, time sync, stream,
//! watch for silence, reconnect. One tokio task per sensor; scans come out on a channel.
//!
//! - [`transport`]: URIs, TCP and serial links.
//! - [`clock`]: 24-bit unwrap, TM1 sync, drift (pure).
//! - [`counters`]: what happened, for status reports; never reset.
//! - [`driver`]: the state machine.

pub mod clock;
pub mod counters;
pub mod driver;
pub mod transport;

pub use counters::{CounterSnapshot, Counters};
pub use driver::{
    Connector, Driver, DriverConfig, DriverError, DriverEvent, QUIT_TIMEOUT, ScanMode, SensorScan,
};
pub use transport::{Endpoint, Link, TransportError};
