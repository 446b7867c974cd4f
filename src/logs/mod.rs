//! Recorded logs in and out: a run written as ROS 2 messages in an MCAP file (what Foxglove /
//! Lichtblick, Rerun and `ros2 bag` open), and recorded joint states read back for `aift replay`.
//! The messages are encoded in CDR by hand (`cdr.rs`: why) with their `ros2msg` schemas
//! (`messages.rs`); the container is the `mcap` crate's.

pub mod cdr;
pub mod mcap_out;
pub mod messages;

pub use mcap_out::{McapRecorder, RUN_MCAP, TOPICS};
