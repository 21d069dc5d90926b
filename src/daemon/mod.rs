//! The daemon's foundations: its config file, the status socket and its protocol, the state it
//! keeps on disk, its conversation with systemd (notifications, signals), the queue to the
//! registration worker and the scan-rate meter behind `status`.
//!
//! The pipeline (drivers, registration, fuser) plugs in through [`socket::StatusSource`] and
//! [`socket::Publisher`]; nothing here knows how scans are made.

pub mod config;
pub mod lines;
pub mod notify;
pub mod pipeline;
pub mod pipeline_fuse;
pub mod pipeline_register;
pub mod protocol;
pub mod queue;
pub mod rate;
pub mod run;
pub mod signals;
pub mod socket;
pub mod state;
