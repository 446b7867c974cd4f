//! Reports: files written from what a run produced (CSV, JSON, SVG plots, tables).
//!
//! Every file is written atomically: into a temporary file beside the target, then renamed, so a
//! failure never leaves a half-written output.

pub mod plots;
pub mod run_files;
pub mod table_files;

use std::io::Write;
use std::path::{Path, PathBuf};

/// Writing an output failed (the disk, not the input, is at fault).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    #[error("{path}: cannot write")]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot draw the plot: {message}")]
    Plot { path: PathBuf, message: String },
}

/// Writes `bytes` to `path` atomically (temporary file in the same folder, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ReportError> {
    let err = |source| ReportError::Write {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let tmp = dir.join(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(err)
}

/// Formats an f64 so that it reads back bit for bit (Rust's shortest round-trip form).
pub fn fmt_f64(v: f64) -> String {
    format!("{v}")
}

/// Renders rows of numbers as CSV text with a header; numbers in round-trip form.
pub fn csv_text<'a>(header: &[String], rows: impl Iterator<Item = &'a [f64]>) -> String {
    let mut out = header.join(",");
    out.push('\n');
    for row in rows {
        let mut first = true;
        for v in row {
            if !first {
                out.push(',');
            }
            first = false;
            out.push_str(&fmt_f64(*v));
        }
        out.push('\n');
    }
    out
}
