//! Recorded logs in and out: a run written as ROS 2 messages in an MCAP file (what Foxglove /
//! Lichtblick, Rerun and `ros2 bag` open), and recorded joint states read back for `aift replay`.
//! The messages are encoded in CDR by hand (`cdr.rs`: why) with their `ros2msg` schemas
//! (`messages.rs`); the container is the `mcap` crate's.

pub mod cdr;
pub mod mcap_out;
pub mod messages;

pub use mcap_out::{McapRecorder, RUN_MCAP, TOPICS};
pub mod recorded;
pub mod replay;

pub use recorded::{RecordedLog, Topics};
pub use replay::{ReplayInfo, replay};

use std::path::PathBuf;

/// What went wrong reading a log.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error(transparent)]
    File(#[from] crate::fsio::FsError),
    /// The log lacks something or holds something it must not: the file and the field (a topic
    /// and message, a CSV line and column) named.
    #[error("{path}: {field}: {message}")]
    Bad {
        path: PathBuf,
        field: String,
        message: String,
    },
}

impl LogError {
    /// Whether the input is at fault (as opposed to the disk).
    pub fn is_input_error(&self) -> bool {
        match self {
            Self::File(e) => e.is_input_error(),
            Self::Bad { .. } => true,
        }
    }
}
