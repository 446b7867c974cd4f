//! Reports: files written from what runs produced (CSV, JSON, SVG plots, tables).
//!
//! Every file is written atomically (a temporary file beside the target, then renamed), and
//! every output folder is staged and moved into place whole ([`crate::fsio::Staged`]), so a
//! failure never leaves a half-written output.

pub mod campaign_files;
pub mod html;
pub mod plots;
pub mod run_files;
pub mod shape;
pub mod table_files;

use std::path::{Path, PathBuf};

use crate::fsio::FsError;
use crate::scenario::ScenarioError;

pub use crate::scenario::trajectory::fmt_f64;

/// Writing a report failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    #[error(transparent)]
    File(#[from] FsError),
    #[error("{path}: cannot draw the plot: {message}")]
    Plot { path: PathBuf, message: String },
    /// Shards that do not make one campaign (overlapping, missing cells, another campaign).
    #[error("{0}")]
    Merge(String),
    /// The run itself failed (bad input found while running).
    #[error(transparent)]
    Scenario(Box<ScenarioError>),
}

impl From<ScenarioError> for ReportError {
    fn from(e: ScenarioError) -> Self {
        Self::Scenario(Box::new(e))
    }
}

impl ReportError {
    /// Whether the input is at fault (as opposed to the disk or aift).
    pub fn is_input_error(&self) -> bool {
        match self {
            Self::File(e) => e.is_input_error(),
            Self::Plot { .. } => false,
            Self::Merge(_) => true,
            Self::Scenario(_) => true,
        }
    }
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    Ok(crate::fsio::write_atomic(path, bytes)?)
}

/// Renders rows of numbers as CSV text with a header; numbers in round-trip form.
pub fn csv_text<'a>(header: &[String], rows: impl Iterator<Item = &'a [f64]>) -> String {
    let mut out = header.join(",");
    out.push('\n');
    for row in rows {
        crate::scenario::trajectory::format_csv_row(row, &mut out);
    }
    out
}
