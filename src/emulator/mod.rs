//! A SCIP 2.0 sensor made of a recording: serves a sensor's scans over TCP (or any byte
//! stream, such as a pty) the way a real unit does, so drivers and other SCIP clients can be
//! tested without hardware.
//!
//! - [`unit`]: the sensor's state machine (idle, streaming, time-adjust), pure: command line in,
//!   reply bytes out.
//! - [`playback`]: which recorded scan is current at what time, at `--speed`, with `--loop`.
//! - [`faults`]: failures to inject (drop, corrupt, stall, garbage, refuse, booting, an abnormal
//!   state until rebooted, no multi-echo, no returns).
//! - [`gate`]: a replay's shared clock, held back by the pipeline it feeds.
//! - [`server`]: the tokio edge: sockets, timers, fault injection.

pub mod faults;
pub mod gate;
pub mod playback;
pub mod server;
pub mod unit;

pub use faults::{EmulatorStats, Faults};
pub use gate::ReplayGate;
pub use playback::Playback;
pub use server::{Emulator, EmulatorConfig, EmulatorError, Gated};
pub use unit::{ClockSetting, SourceScan, SyntheticEchoes, Unit};
