//! Recordings: MCAP files with one `foxglove.LaserScan` channel per sensor (DESIGN.md "Formats").
//!
//! [`RecordingWriter`] writes them, [`read`]/[`read_lenient`] read them (from scanfuse or any
//! other writer), [`stats`] summarises them for `scanfuse info`. [`carmen`] reads the CARMEN
//! logs of public laser datasets, for evaluation against real data.

pub mod carmen;
pub mod laserscan;
pub mod metadata;
mod reader;
pub mod stats;
mod writer;

use std::path::PathBuf;

pub use reader::{Recording, SkippedChannel, read, read_lenient, read_truth_people};
pub use writer::{
    DEFAULT_ZSTD_LEVEL, PEOPLE_TRUTH_SCHEMA, RecordingWriter, SCIP_ENCODING, partial_path,
};

/// Topic of the people's ground truth in simulated recordings. Channels under `/truth/` are
/// never scans: readers of scans leave them out, and only evaluation and tests read them
/// (through [`read_truth_people`]).
pub const PEOPLE_TRUTH_TOPIC: &str = "/truth/people";
/// Prefix of every ground-truth channel.
pub const TRUTH_PREFIX: &str = "/truth/";

/// What went wrong reading or writing a recording; always names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {what}")]
    Invalid { path: PathBuf, what: String },
}

/// Topic of a sensor's scans.
pub fn scan_topic(sensor_id: &str) -> String {
    format!("/{sensor_id}/scan")
}

/// Topic of a sensor's raw SCIP bytes.
pub fn scip_topic(sensor_id: &str) -> String {
    format!("/{sensor_id}/scip")
}
