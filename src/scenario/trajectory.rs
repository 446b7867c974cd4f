//! The trajectory of a run: its column schema (defined once, here, for the writer, the plots and
//! any reader), a writer that streams rows to a file while the run goes, an in-memory recorder
//! (optionally decimating, so its memory stays bounded), and a reader.
//!
//! Columns: `t`, `q<i>`, `qd<i>`, `mu<i>`, `mu_p<i>`, `target<i>`, `u<i>` (commanded torque),
//! `applied<i>` (the torque the joint receives: after effort limits and actuator faults; joints
//! 1-based),
//! `y_<channel>` (NaN when missing), `precision_<channel>`, `health_<channel>`, `F` (NaN where the
//! estimator defines no free energy), `alarm` (1 once the detector has fired), `isolated`
//! (channels isolated now), and `d_<group>` (the detector's normalised distance per sensor group,
//! NaN when not evaluated).

use std::io::Write;
use std::path::Path;

use super::runner::{Observer, TickRecord};
use crate::fsio::{self, FsError};
use crate::precision;
use crate::sensors::ChannelLayout;

/// Formats an f64 so that it reads back bit for bit (the shortest round-trip form, by Ryu).
pub fn fmt_f64(v: f64) -> String {
    ryu::Buffer::new().format(v).to_string()
}

/// Appends a row of numbers as one CSV line (shortest round-trip form by Ryu, `NaN`, `inf` and
/// `-inf` for non-finite values; newline-terminated).
pub fn format_csv_row(row: &[f64], out: &mut String) {
    let mut buffer = ryu::Buffer::new();
    for (i, v) in row.iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        out.push_str(buffer.format(*v));
    }
    out.push('\n');
}

/// The column names of a layout's trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct TrajectorySchema {
    columns: Vec<String>,
    n_joints: usize,
}

impl TrajectorySchema {
    pub fn new(layout: &ChannelLayout) -> Self {
        let n = layout.n_joints();
        let mut columns = vec!["t".to_string()];
        for prefix in ["q", "qd", "mu", "mu_p", "target", "u", "applied"] {
            columns.extend((1..=n).map(|i| format!("{prefix}{i}")));
        }
        let names = layout.names();
        for prefix in ["y", "precision", "health"] {
            columns.extend(names.iter().map(|c| format!("{prefix}_{c}")));
        }
        columns.extend(["F", "alarm", "isolated"].map(String::from));
        columns.extend(layout.groups().iter().map(|g| format!("d_{}", g.name())));
        Self {
            columns,
            n_joints: n,
        }
    }

    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    pub fn len(&self) -> usize {
        self.columns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.columns.is_empty()
    }

    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// Index of a column by name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|h| h == name)
    }

    /// The row of a tick, written into `row` (cleared first).
    pub fn row(&self, r: &TickRecord<'_>, row: &mut Vec<f64>) {
        row.clear();
        row.push(r.t);
        for v in [r.q, r.qd, r.mu, r.mu_p, r.target, r.torques, r.applied] {
            row.extend_from_slice(v);
        }
        row.extend(r.readings.values.iter().map(|v| v.unwrap_or(f64::NAN)));
        row.extend_from_slice(r.precisions);
        row.extend(
            r.precisions
                .iter()
                .zip(r.nominal)
                .map(|(w, n)| precision::health(*w, *n)),
        );
        row.push(r.free_energy);
        match r.detection {
            Some(d) => {
                row.push(if d.fired() { 1.0 } else { 0.0 });
                row.push(d.isolated.len() as f64);
                row.extend(d.normalised_distance.iter().map(|d| d.unwrap_or(f64::NAN)));
            }
            None => {
                row.push(0.0);
                row.push(0.0);
                row.extend(r.layout.groups().iter().map(|_| f64::NAN));
            }
        }
        debug_assert_eq!(row.len(), self.columns.len());
    }
}

/// Streams every `every`-th tick's row to a writer as CSV (numbers in round-trip form). Memory
/// stays constant however long the run. The first write error is kept and returned by
/// [`TrajectoryWriter::finish`].
pub struct TrajectoryWriter<W: Write> {
    schema: TrajectorySchema,
    out: std::io::BufWriter<W>,
    row: Vec<f64>,
    line: String,
    error: Option<std::io::Error>,
    rows: u64,
}

impl<W: Write> TrajectoryWriter<W> {
    /// A writer of every tick it is shown (register it with `ObserverMode::Every(record_every)`).
    pub fn new(schema: TrajectorySchema, out: W) -> Self {
        let mut w = Self {
            out: std::io::BufWriter::with_capacity(1 << 16, out),
            row: Vec::with_capacity(schema.len()),
            line: String::with_capacity(32 * schema.len()),
            error: None,
            rows: 0,
            schema,
        };
        let header = w.schema.columns.join(",") + "\n";
        if let Err(e) = w.out.write_all(header.as_bytes()) {
            w.error = Some(e);
        }
        w
    }

    /// Rows written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flushes and returns the writer, or the first error.
    pub fn finish(self) -> std::io::Result<W> {
        if let Some(e) = self.error {
            return Err(e);
        }
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

impl<W: Write> Observer for TrajectoryWriter<W> {
    fn iter(&mut self, r: &TickRecord<'_>) {
        if self.error.is_some() {
            return;
        }
        self.schema.row(r, &mut self.row);
        self.line.clear();
        format_csv_row(&self.row, &mut self.line);
        if let Err(e) = self.out.write_all(self.line.as_bytes()) {
            self.error = Some(e);
        }
        self.rows += 1;
    }
}

/// Rows of a trajectory in memory. Records every `every`-th tick; with a row bound, once it is
/// reached every other row is dropped and the stride doubles, so memory stays bounded.
#[derive(Clone, Debug)]
pub struct TrajectoryRecorder {
    pub header: Vec<String>,
    pub rows: Vec<Vec<f64>>,
    n_joints: usize,
    schema: TrajectorySchema,
    every: u64,
    max_rows: Option<usize>,
}

impl TrajectoryRecorder {
    /// Records every tick.
    pub fn new(layout: &ChannelLayout) -> Self {
        Self::with_stride(layout, 1)
    }

    /// Records every `every`-th tick.
    pub fn with_stride(layout: &ChannelLayout, every: u64) -> Self {
        let schema = TrajectorySchema::new(layout);
        Self {
            header: schema.columns.clone(),
            rows: Vec::new(),
            n_joints: layout.n_joints(),
            schema,
            every: every.max(1),
            max_rows: None,
        }
    }

    /// Keeps at most `max_rows` rows (>= 2), decimating as the run goes (for plots).
    pub fn bounded(layout: &ChannelLayout, max_rows: usize) -> Self {
        Self::bounded_with_stride(layout, max_rows, 1)
    }

    /// Records every `every`-th tick and keeps at most `max_rows` rows (>= 2), decimating as
    /// the run goes.
    pub fn bounded_with_stride(layout: &ChannelLayout, max_rows: usize, every: u64) -> Self {
        Self {
            max_rows: Some(max_rows.max(2)),
            ..Self::with_stride(layout, every)
        }
    }

    /// Adds a row; past the row bound every other row is dropped and the stride doubles. The
    /// one rule both a run's recorder and [`Self::read_csv_decimated`] follow, so that they
    /// keep the same rows.
    fn push_decimated(&mut self, row: Vec<f64>) {
        self.rows.push(row);
        if let Some(max) = self.max_rows
            && self.rows.len() >= max
        {
            let mut keep = 0;
            for i in (0..self.rows.len()).step_by(2) {
                self.rows.swap(keep, i);
                keep += 1;
            }
            self.rows.truncate(keep);
            self.every *= 2;
        }
    }

    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// Ticks between the rows kept.
    pub fn stride(&self) -> u64 {
        self.every
    }

    /// Index of a column by name.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// A column's values.
    pub fn series(&self, name: &str) -> Option<Vec<f64>> {
        let c = self.column(name)?;
        Some(self.rows.iter().map(|r| r[c]).collect())
    }

    /// Reads a trajectory CSV written by [`TrajectoryWriter`].
    pub fn read_csv(path: &Path) -> Result<Self, FsError> {
        let text = fsio::read_text(path, fsio::MAX_TRAJECTORY_BYTES)?;
        let bad = |line: usize, what: &str| FsError::BadOutput {
            path: path.to_path_buf(),
            message: format!("line {line}: {what}"),
        };
        let mut lines = text.lines();
        let header: Vec<String> = lines
            .next()
            .ok_or_else(|| bad(1, "no header"))?
            .split(',')
            .map(String::from)
            .collect();
        let n_joints = header.iter().filter(|h| h.starts_with("mu_p")).count();
        let mut rows = Vec::new();
        for (i, line) in lines.enumerate() {
            let row: Vec<f64> = line
                .split(',')
                .map(|v| v.parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| bad(i + 2, "not a number"))?;
            if row.len() != header.len() {
                return Err(bad(i + 2, "wrong number of columns"));
            }
            rows.push(row);
        }
        let schema = TrajectorySchema {
            columns: header.clone(),
            n_joints,
        };
        Ok(Self {
            header,
            rows,
            n_joints,
            schema,
            every: 1,
            max_rows: None,
        })
    }
}

impl TrajectoryRecorder {
    /// Reads a trajectory CSV streaming, keeping at most `max_rows` rows (decimated as
    /// [`Self::bounded`] does while a run goes), so memory stays bounded however long the file.
    /// Returns the rows kept and the number of rows in the file.
    pub fn read_csv_decimated(path: &Path, max_rows: usize) -> Result<(Self, u64), FsError> {
        use std::io::{BufRead, Read};
        /// Longest line and most columns read (a trajectory row of 10,000 columns is ~250 kB).
        const MAX_LINE_BYTES: u64 = 4 << 20;
        const MAX_COLUMNS: usize = 100_000;
        let (file, _) = fsio::open_bounded(path, fsio::MAX_TRAJECTORY_BYTES)?;
        let bad = |line: u64, what: &str| FsError::BadOutput {
            path: path.to_path_buf(),
            message: format!("line {line}: {what}"),
        };
        let mut reader = std::io::BufReader::with_capacity(1 << 16, file);
        let mut line = String::new();
        let mut bytes = 0u64;
        let mut read = |reader: &mut std::io::BufReader<_>, line: &mut String, number: u64| {
            line.clear();
            let n = reader
                .by_ref()
                .take(MAX_LINE_BYTES + 1)
                .read_line(line)
                .map_err(|source| FsError::Read {
                    path: path.to_path_buf(),
                    source,
                })? as u64;
            if n > MAX_LINE_BYTES {
                return Err(bad(number, "line longer than 4 MiB"));
            }
            bytes += n;
            if bytes > fsio::MAX_TRAJECTORY_BYTES {
                return Err(FsError::TooLarge {
                    path: path.to_path_buf(),
                    size: bytes,
                    limit: fsio::MAX_TRAJECTORY_BYTES,
                });
            }
            Ok(n)
        };
        if read(&mut reader, &mut line, 1)? == 0 {
            return Err(bad(1, "no header"));
        }
        let header: Vec<String> = line.trim_end().split(',').map(String::from).collect();
        if header.len() > MAX_COLUMNS {
            return Err(bad(1, "more than 100000 columns"));
        }
        let n_joints = header.iter().filter(|h| h.starts_with("mu_p")).count();
        // The columns a run's trajectory always has: t, and per joint q, mu, target.
        if n_joints == 0 {
            return Err(bad(
                1,
                "no joint columns (mu_p1, ...): not a trajectory aift wrote",
            ));
        }
        let mut required = vec!["t".to_string()];
        for j in 1..=n_joints {
            for prefix in ["q", "mu", "target"] {
                required.push(format!("{prefix}{j}"));
            }
        }
        if let Some(missing) = required.iter().find(|c| !header.contains(c)) {
            return Err(bad(1, &format!("no column `{missing}`")));
        }
        for (i, h) in header.iter().enumerate() {
            if header[..i].contains(h) {
                return Err(bad(1, &format!("column `{h}` appears twice")));
            }
        }
        let schema = TrajectorySchema {
            columns: header.clone(),
            n_joints,
        };
        let mut out = Self {
            header,
            rows: Vec::new(),
            n_joints,
            schema,
            every: 1,
            max_rows: Some(max_rows.max(2)),
        };
        let mut total = 0u64;
        let mut number = 1u64;
        let mut row = Vec::with_capacity(out.header.len());
        loop {
            number += 1;
            if read(&mut reader, &mut line, number)? == 0 {
                break;
            }
            let text = line.trim_end();
            if text.is_empty() {
                continue;
            }
            // Every row is checked, kept or not: a damaged late row is an error, not a gap.
            row.clear();
            for (c, v) in text.split(',').enumerate() {
                let x = v.parse::<f64>().map_err(|_| {
                    let column = out
                        .header
                        .get(c)
                        .map_or("(beyond the header)", String::as_str);
                    bad(number, &format!("column `{column}`: {v:?} is not a number"))
                })?;
                row.push(x);
            }
            if row.len() != out.header.len() {
                return Err(bad(
                    number,
                    &format!(
                        "{} values; the header has {} columns",
                        row.len(),
                        out.header.len()
                    ),
                ));
            }
            if total.is_multiple_of(out.every) {
                out.push_decimated(row.clone());
            }
            total += 1;
        }
        if total == 0 {
            return Err(bad(2, "no rows after the header"));
        }
        Ok((out, total))
    }
}

impl Observer for TrajectoryRecorder {
    fn iter(&mut self, r: &TickRecord<'_>) {
        if !r.tick.is_multiple_of(self.every) {
            return;
        }
        let mut row = Vec::with_capacity(self.schema.len());
        self.schema.row(r, &mut row);
        self.push_decimated(row);
    }
}

/// Most values a [`TrajectoryColumns`] may hold: 2^27 numbers, 1 GiB.
pub const MAX_IN_MEMORY_VALUES: u64 = 1 << 27;

/// A whole trajectory in memory, column by column (every `every`-th tick, as the CSV file has
/// it): what the Python package hands to numpy without touching disk. Its size is checked
/// before the run ([`TrajectoryColumns::new`]), so it never grows past
/// [`MAX_IN_MEMORY_VALUES`].
#[derive(Clone, Debug)]
pub struct TrajectoryColumns {
    schema: TrajectorySchema,
    columns: Vec<Vec<f64>>,
    row: Vec<f64>,
}

impl TrajectoryColumns {
    /// Room for `ticks` ticks recorded every `every`-th (register it with
    /// `ObserverMode::Every(every)`); an error message when that would pass
    /// [`MAX_IN_MEMORY_VALUES`].
    pub fn new(layout: &ChannelLayout, ticks: u64, every: u64) -> Result<Self, String> {
        let schema = TrajectorySchema::new(layout);
        let every = every.max(1);
        let rows = ticks.div_ceil(every);
        let values = rows.saturating_mul(schema.len() as u64);
        if values > MAX_IN_MEMORY_VALUES {
            return Err(format!(
                "the trajectory would hold {values} numbers in memory ({rows} rows x {} \
                 columns), more than {MAX_IN_MEMORY_VALUES}; raise `record_every` or write it \
                 to a folder",
                schema.len()
            ));
        }
        let columns = (0..schema.len())
            .map(|_| Vec::with_capacity(rows as usize))
            .collect();
        Ok(Self {
            row: Vec::with_capacity(schema.len()),
            schema,
            columns,
        })
    }

    pub fn names(&self) -> &[String] {
        self.schema.columns()
    }

    /// The values of every column, in the order of [`Self::names`].
    pub fn columns(&self) -> &[Vec<f64>] {
        &self.columns
    }

    pub fn rows(&self) -> usize {
        self.columns.first().map_or(0, Vec::len)
    }
}

impl Observer for TrajectoryColumns {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.schema.row(r, &mut self.row);
        for (column, v) in self.columns.iter_mut().zip(&self.row) {
            column.push(*v);
        }
    }
}

#[cfg(test)]
mod format_tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 20_000, .. ProptestConfig::default() })]
        /// Every f64 bit pattern reads back bit for bit (NaN as NaN).
        #[test]
        fn csv_numbers_round_trip_exactly(bits in any::<u64>()) {
            let v = f64::from_bits(bits);
            let mut row = String::new();
            format_csv_row(&[v, -v], &mut row);
            let back: Vec<f64> = row.trim_end().split(',').map(|s| s.parse().unwrap()).collect();
            for (a, b) in [v, -v].iter().zip(&back) {
                prop_assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "{a:e} -> {b:e}");
            }
        }
    }

    #[test]
    fn special_values_are_spelled_as_rust_and_python_read_them() {
        let mut row = String::new();
        format_csv_row(
            &[f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, 1e-7],
            &mut row,
        );
        assert_eq!(row, "NaN,inf,-inf,0.0,-0.0,1e-7\n");
    }
}
