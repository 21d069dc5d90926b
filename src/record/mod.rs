//! Recordings: MCAP files with one `foxglove.LaserScan` channel per sensor (DESIGN.md "Formats").

use std::path::PathBuf;

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
