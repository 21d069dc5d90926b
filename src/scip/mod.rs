//! SCIP 2.0, the protocol of Hokuyo laser scanners: commands, reply framing, checksums, the
//! 2/3/4-character encodings and the typed replies. Pure: bytes in, values out, no I/O, no clock.
//!
//! The protocol is Hokuyo's "Communication Protocol Specification for SCIP2.0" (C-42-03320B).
//! A reply is an echo of the command line, a status line, data lines, and an empty line; every
//! line after the echo ends in a one-character checksum.

pub mod checksum;
pub mod command;
pub mod encoding;
pub mod framer;
pub mod info;
pub mod reply;
pub mod scan;
pub mod status;

pub use command::{Command, DataKind, Request, RequestError, ScanRequest, TimeControl};
pub use framer::{Frame, Framer, FramerStats};
pub use info::{InfoError, Parameters, StateInfo, VersionInfo};
pub use reply::{Reply, ReplyError};
pub use scan::{Echo, ScanError, ScipScan};
pub use status::{Status, StatusError, StatusKind};

pub mod capture;
#[cfg(test)]
mod captures;
