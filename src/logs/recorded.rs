//! Recorded joint states read from a log, for `aift replay` (docs/logs.md, "Logs in"): a rosbag2
//! bag or bare MCAP file with `sensor_msgs/msg/JointState` (and optionally a camera's
//! `geometry_msgs/msg/PointStamped`), or a CSV with aift's trajectory column names.
//!
//! Everything is checked while reading, before any replay: the topics or columns, the joints
//! (every name in a message must be a joint of the arm; every joint of the arm needs an effort),
//! the times (non-decreasing), the values (a NaN reading is a missing reading, as aift writes
//! them; an infinite reading or a non-finite effort is refused). Counts and sizes are bounded.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::LogError;
use super::messages::read_joint_state;
use crate::sensors::{ChannelLayout, SensorGroup};

/// Largest log file read (bytes; a bag's MCAP files together).
pub const MAX_LOG_BYTES: u64 = 1 << 30;
/// Most messages (or CSV rows) a log may hold.
pub const MAX_LOG_MESSAGES: usize = 20_000_000;
/// The joint-state topic looked for when none is given.
pub const DEFAULT_TOPIC: &str = "/joint_states";
/// The camera topic looked for when none is given (what `aift run --mcap` writes).
pub const DEFAULT_CAMERA_TOPIC: &str = "/camera/point";

/// One recorded sample: its time (s from the log's first joint state) and a value per channel
/// of the layout (None: not in this message); the applied torque per joint when the message
/// carries one.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    pub t: f64,
    pub readings: Vec<Option<f64>>,
    pub effort: Option<Vec<f64>>,
}

/// A log's samples in time order, for one arm's channel layout.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedLog {
    pub source: PathBuf,
    /// Where the samples came from: the topics, or the CSV columns.
    pub described: String,
    pub samples: Vec<Sample>,
}

/// Where to find the joint states in an MCAP log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Topics {
    /// The JointState topic (default: `/joint_states`, else the only JointState topic).
    pub joint_states: Option<String>,
    /// The camera's PointStamped topic (default: `/camera/point` when there is one; without
    /// one the camera's readings are missing).
    pub camera: Option<String>,
}

fn bad(path: &Path, field: &str, message: impl Into<String>) -> LogError {
    LogError::Bad {
        path: path.to_path_buf(),
        field: field.to_string(),
        message: message.into(),
    }
}

impl RecordedLog {
    /// Reads `path`: a folder (a rosbag2 bag: its `*.mcap` files), a `.mcap` file or a `.csv`.
    pub fn read(
        path: &Path,
        layout: &ChannelLayout,
        joint_names: &[String],
        topics: &Topics,
    ) -> Result<Self, LogError> {
        let meta = std::fs::metadata(path).map_err(|source| {
            LogError::File(crate::fsio::FsError::Read {
                path: path.to_path_buf(),
                source,
            })
        })?;
        if meta.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(|source| {
                    LogError::File(crate::fsio::FsError::Read {
                        path: path.to_path_buf(),
                        source,
                    })
                })?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
                .collect();
            files.sort();
            if files.is_empty() {
                return Err(bad(
                    path,
                    "log",
                    "a folder without *.mcap files (a rosbag2 bag in another storage, e.g. \
                     sqlite3, is not read: convert it with `ros2 bag convert`)",
                ));
            }
            let mut parts = Vec::with_capacity(files.len());
            let mut total = 0u64;
            let mut messages = 0usize;
            for f in &files {
                let b = crate::fsio::read_bounded(f, MAX_LOG_BYTES - total)?;
                total += b.len() as u64;
                let part = read_mcap(f, &b, layout, joint_names, topics, messages)?;
                messages += part.messages;
                parts.push((f.clone(), part));
            }
            // Files in time order (a split bag's names need not sort as its times do), one
            // after the other, all on the same clock.
            parts.sort_by_key(|(_, p)| p.first_ns);
            for w in parts.windows(2) {
                let ((fa, a), (fb, b)) = (&w[0], &w[1]);
                if b.first_ns < a.last_ns {
                    return Err(bad(
                        fb,
                        "time",
                        format!("its joint states overlap those of {} in time", fa.display()),
                    ));
                }
                if a.stamped != b.stamped {
                    return Err(bad(
                        fb,
                        "time",
                        format!(
                            "header stamps in one file and not in {}: one clock is needed",
                            fa.display()
                        ),
                    ));
                }
            }
            let described = parts[0].1.described.clone();
            let samples = parts.into_iter().flat_map(|(_, p)| p.samples).collect();
            return Ok(finish(path, described, samples));
        }
        match path.extension().and_then(|e| e.to_str()) {
            Some("mcap") => {
                let bytes = crate::fsio::read_bounded(path, MAX_LOG_BYTES)?;
                let part = read_mcap(path, &bytes, layout, joint_names, topics, 0)?;
                Ok(finish(path, part.described, part.samples))
            }
            Some("csv") => {
                let text = crate::fsio::read_text(path, MAX_LOG_BYTES)?;
                read_csv(path, &text, layout)
            }
            _ => Err(bad(
                path,
                "log",
                "neither a rosbag2 folder, a .mcap file nor a .csv file",
            )),
        }
    }
}

/// One MCAP file's samples, at their absolute times (ns), in time order.
struct McapPart {
    samples: Vec<(u64, Sample)>,
    /// The first and last joint state's time.
    first_ns: u64,
    last_ns: u64,
    stamped: bool,
    messages: usize,
    described: String,
}

/// A log of samples at absolute times: times from the first joint state (samples before it, a
/// camera's, dropped).
fn finish(path: &Path, described: String, samples: Vec<(u64, Sample)>) -> RecordedLog {
    let t0 = samples
        .iter()
        .find(|(_, s)| s.effort.is_some())
        .map_or(0, |(ns, _)| *ns);
    RecordedLog {
        source: path.to_path_buf(),
        described,
        samples: samples
            .into_iter()
            .filter(|(ns, _)| *ns >= t0)
            .map(|(ns, mut s)| {
                s.t = (ns - t0) as f64 * 1e-9;
                s
            })
            .collect(),
    }
}

/// The JointState messages of an MCAP file (and the camera's points); `counted` messages were
/// read from earlier files of the same bag.
fn read_mcap(
    path: &Path,
    bytes: &[u8],
    layout: &ChannelLayout,
    joint_names: &[String],
    topics: &Topics,
    counted: usize,
) -> Result<McapPart, LogError> {
    if !bytes.starts_with(b"\x89MCAP0\r\n") {
        return Err(bad(path, "mcap", "not an MCAP file (no MCAP magic)"));
    }
    let stream = mcap::MessageStream::new(bytes)
        .map_err(|e| bad(path, "mcap", format!("not an MCAP file: {e}")))?;
    // (topic -> schema name) of every channel, and the messages of the two topics wanted.
    let mut channels: BTreeMap<String, String> = BTreeMap::new();
    let mut joint_msgs: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    let mut count = 0usize;
    for m in stream {
        let m = m.map_err(|e| bad(path, "mcap", format!("a corrupt record: {e}")))?;
        count += 1;
        if counted + count > MAX_LOG_MESSAGES {
            return Err(bad(
                path,
                "mcap",
                format!("more than {MAX_LOG_MESSAGES} messages"),
            ));
        }
        let schema = m
            .channel
            .schema
            .as_ref()
            .map_or(String::new(), |s| s.name.clone());
        let topic = m.channel.topic.clone();
        channels.entry(topic.clone()).or_insert(schema.clone());
        let wanted =
            schema == "sensor_msgs/msg/JointState" || schema == "geometry_msgs/msg/PointStamped";
        if wanted {
            if m.channel.message_encoding != "cdr" {
                return Err(bad(
                    path,
                    &topic,
                    format!(
                        "message encoding {:?}; only cdr (ROS 2) is read",
                        m.channel.message_encoding
                    ),
                ));
            }
            joint_msgs
                .entry(topic)
                .or_default()
                .push((m.log_time, m.data.into_owned()));
        }
    }
    let of_type = |ty: &str| -> Vec<&String> {
        channels
            .iter()
            .filter(|(_, s)| s.as_str() == ty)
            .map(|(t, _)| t)
            .collect()
    };
    let joint_topics = of_type("sensor_msgs/msg/JointState");
    let topic = match &topics.joint_states {
        Some(t) => {
            if !joint_topics.contains(&t) {
                return Err(bad(
                    path,
                    "--topic",
                    format!(
                        "{t} is not a sensor_msgs/msg/JointState topic of the log (those: {joint_topics:?})"
                    ),
                ));
            }
            t.clone()
        }
        None if joint_topics.iter().any(|t| *t == DEFAULT_TOPIC) => DEFAULT_TOPIC.to_string(),
        None if joint_topics.len() == 1 => joint_topics[0].clone(),
        None => {
            return Err(bad(
                path,
                "--topic",
                format!(
                    "no {DEFAULT_TOPIC} and {} sensor_msgs/msg/JointState topics ({joint_topics:?}): name one with --topic",
                    joint_topics.len()
                ),
            ));
        }
    };
    let camera_topics = of_type("geometry_msgs/msg/PointStamped");
    let camera = match &topics.camera {
        Some(t) if !camera_topics.contains(&t) => {
            return Err(bad(
                path,
                "--camera-topic",
                format!(
                    "{t} is not a geometry_msgs/msg/PointStamped topic of the log (those: {camera_topics:?})"
                ),
            ));
        }
        Some(t) => Some(t.clone()),
        None => camera_topics
            .iter()
            .any(|t| *t == DEFAULT_CAMERA_TOPIC)
            .then(|| DEFAULT_CAMERA_TOPIC.to_string()),
    };
    let n = layout.n_joints();
    let index: BTreeMap<&str, usize> = joint_names
        .iter()
        .enumerate()
        .map(|(i, s)| (s.as_str(), i))
        .collect();
    let joints = &joint_msgs[&topic];
    // Header stamps when every message has one, else the log times.
    let decoded: Vec<_> = joints
        .iter()
        .enumerate()
        .map(|(k, (log_time, data))| {
            read_joint_state(data)
                .map(|m| (*log_time, m))
                .map_err(|e| bad(path, &topic, format!("message {k}: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let stamped = decoded.iter().all(|(_, m)| m.stamp_ns != 0);
    let time = |log: u64, stamp: u64| if stamped { stamp } else { log };
    let Some(t0) = decoded.first().map(|(l, m)| time(*l, m.stamp_ns)) else {
        return Err(bad(path, &topic, "has no message"));
    };
    let mut events: Vec<(u64, usize, Sample)> = Vec::with_capacity(decoded.len());
    let mut last = t0;
    for (k, (log_time, m)) in decoded.iter().enumerate() {
        let at = |field: &str| format!("{topic} message {k} ({field})");
        let ns = time(*log_time, m.stamp_ns);
        if ns < last {
            return Err(bad(
                path,
                &at("time"),
                format!(
                    "{} s is before the previous message's {} s: times must not decrease",
                    ns as f64 * 1e-9,
                    last as f64 * 1e-9
                ),
            ));
        }
        last = ns;
        let mut readings = vec![None; layout.len()];
        let mut effort = vec![f64::NAN; n];
        for (field, v) in [
            ("position", &m.position),
            ("velocity", &m.velocity),
            ("effort", &m.effort),
        ] {
            if !v.is_empty() && v.len() != m.name.len() {
                return Err(bad(
                    path,
                    &at(field),
                    format!("{} values for {} names", v.len(), m.name.len()),
                ));
            }
        }
        for (i, name) in m.name.iter().enumerate() {
            let &j = index.get(name.as_str()).ok_or_else(|| {
                bad(
                    path,
                    &at("name"),
                    format!(
                        "joint {name:?} is not a joint of the arm (its joints: {joint_names:?})"
                    ),
                )
            })?;
            for (field, v, c) in [
                ("position", &m.position, j),
                ("velocity", &m.velocity, n + j),
            ] {
                if let Some(&x) = v.get(i) {
                    if x.is_infinite() {
                        return Err(bad(path, &at(field), format!("{name}: {x}")));
                    }
                    readings[c] = (!x.is_nan()).then_some(x);
                }
            }
            if let Some(&e) = m.effort.get(i) {
                effort[j] = e;
            }
        }
        if let Some(j) = effort.iter().position(|e| !e.is_finite()) {
            return Err(bad(
                path,
                &at("effort"),
                format!(
                    "joint {:?}: the applied torque is {} (every message needs a finite effort for every joint of the arm)",
                    joint_names[j], effort[j]
                ),
            ));
        }
        events.push((
            ns,
            0,
            Sample {
                t: 0.0,
                readings,
                effort: Some(effort),
            },
        ));
    }
    if let Some(cam) = &camera {
        let range = layout.group_range(SensorGroup::Camera);
        for (k, (log_time, data)) in joint_msgs[cam].iter().enumerate() {
            let at = format!("{cam} message {k}");
            let (stamp, p) =
                super::messages::read_point_stamped(data).map_err(|e| bad(path, &at, e))?;
            let ns = time(*log_time, stamp);
            let mut readings = vec![None; layout.len()];
            for (k, c) in range.clone().enumerate() {
                if p[k].is_infinite() {
                    return Err(bad(path, &at, format!("point {p:?}")));
                }
                readings[c] = (!p[k].is_nan()).then_some(p[k]);
            }
            events.push((
                ns,
                1,
                Sample {
                    t: 0.0,
                    readings,
                    effort: None,
                },
            ));
        }
    }
    events.sort_by_key(|(ns, order, _)| (*ns, *order));
    let stamp_kind = if stamped { "header" } else { "log" };
    Ok(McapPart {
        samples: events.into_iter().map(|(ns, _, s)| (ns, s)).collect(),
        first_ns: t0,
        last_ns: last,
        stamped,
        messages: count,
        described: match camera {
            Some(c) => format!(
                "{topic} (sensor_msgs/msg/JointState), {c} (geometry_msgs/msg/PointStamped), \
                 {stamp_kind} time"
            ),
            None => format!(
                "{topic} (sensor_msgs/msg/JointState; no camera topic: the camera's readings \
                 are missing), {stamp_kind} time"
            ),
        },
    })
}

/// A CSV with a header: `t` (s, non-decreasing), `applied<i>` for every joint (required),
/// `y_<channel>` for any channels (empty or NaN: missing); other columns are ignored, so a run's
/// trajectory.csv is such a file.
fn read_csv(path: &Path, text: &str, layout: &ChannelLayout) -> Result<RecordedLog, LogError> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(text.as_bytes());
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| bad(path, "header", e.to_string()))?
        .iter()
        .map(|s| s.trim().to_string())
        .collect();
    let col = |name: &str| header.iter().position(|h| h == name);
    let t_col = col("t").ok_or_else(|| bad(path, "t", "no column `t` (time in s)"))?;
    let n = layout.n_joints();
    let applied: Vec<usize> = (1..=n)
        .map(|i| {
            col(&format!("applied{i}")).ok_or_else(|| {
                bad(
                    path,
                    &format!("applied{i}"),
                    format!("no column `applied{i}` (the torque applied to joint {i}); the arm has {n} joints"),
                )
            })
        })
        .collect::<Result<_, _>>()?;
    let names = layout.names();
    let reading_cols: Vec<Option<usize>> = names.iter().map(|c| col(&format!("y_{c}"))).collect();
    if reading_cols.iter().all(Option::is_none) {
        return Err(bad(
            path,
            "header",
            format!(
                "no reading column (y_<channel>: {})",
                names
                    .iter()
                    .map(|c| format!("y_{c}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    let mut samples = Vec::new();
    let mut t0 = None;
    let mut last = f64::NEG_INFINITY;
    for (row, record) in reader.records().enumerate() {
        let line = row + 2;
        let record = record.map_err(|e| bad(path, &format!("line {line}"), e.to_string()))?;
        if samples.len() >= MAX_LOG_MESSAGES {
            return Err(bad(path, "rows", format!("more than {MAX_LOG_MESSAGES}")));
        }
        let value = |c: usize, name: &str| -> Result<f64, LogError> {
            let s = record.get(c).unwrap_or("").trim();
            if s.is_empty() {
                return Ok(f64::NAN);
            }
            s.parse::<f64>().map_err(|_| {
                bad(
                    path,
                    &format!("line {line}, column {name}"),
                    format!("{s:?} is not a number"),
                )
            })
        };
        let t = value(t_col, "t")?;
        if !t.is_finite() || t < last {
            return Err(bad(
                path,
                &format!("line {line}, column t"),
                format!("{t}: times must be finite and must not decrease (previous {last})"),
            ));
        }
        last = t;
        let t0 = *t0.get_or_insert(t);
        let mut effort = Vec::with_capacity(n);
        for (i, &c) in applied.iter().enumerate() {
            let name = format!("applied{}", i + 1);
            let e = value(c, &name)?;
            if !e.is_finite() {
                return Err(bad(
                    path,
                    &format!("line {line}, column {name}"),
                    format!("{e}: the applied torque must be finite"),
                ));
            }
            effort.push(e);
        }
        let mut readings = vec![None; layout.len()];
        for (c, col) in reading_cols.iter().enumerate() {
            if let Some(col) = col {
                let name = format!("y_{}", names[c]);
                let v = value(*col, &name)?;
                if v.is_infinite() {
                    return Err(bad(
                        path,
                        &format!("line {line}, column {name}"),
                        format!("{v}: a reading must be finite (NaN or empty: missing)"),
                    ));
                }
                readings[c] = (!v.is_nan()).then_some(v);
            }
        }
        samples.push(Sample {
            t: t - t0,
            readings,
            effort: Some(effort),
        });
    }
    if samples.is_empty() {
        return Err(bad(path, "rows", "no data row"));
    }
    Ok(RecordedLog {
        source: path.to_path_buf(),
        described: format!(
            "CSV columns t, applied1..{n}, {}",
            names
                .iter()
                .zip(&reading_cols)
                .filter(|(_, c)| c.is_some())
                .map(|(n, _)| format!("y_{n}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        samples,
    })
}
