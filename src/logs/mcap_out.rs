//! A run as an MCAP file of ROS 2 messages (`aift run --mcap`: `run.mcap` beside
//! trajectory.csv), for Foxglove / Lichtblick, Rerun and ROS 2 tools (`ros2 bag` reads a bare
//! MCAP file). Every `record_every`-th tick (the ticks of trajectory.csv), stamped with the
//! simulated time from 0:
//!
//! | topic | type | content |
//! |---|---|---|
//! | `/joint_states` | sensor_msgs/msg/JointState | the readings: position = encoders, velocity = tachometers, effort = applied torque (NaN = missing reading) |
//! | `/true_joint_states` | sensor_msgs/msg/JointState | the plant's q, qd and applied torque |
//! | `/belief` | sensor_msgs/msg/JointState | position = mu, velocity = mu' |
//! | `/command` | sensor_msgs/msg/JointState | effort = the commanded torque |
//! | `/target` | sensor_msgs/msg/JointState | position = the target |
//! | `/camera/point` | geometry_msgs/msg/PointStamped | the camera's reading (image: x = u, y = v, z = 0; tracker: x, y, z) |
//! | `/precision`, `/health` | std_msgs/msg/Float64MultiArray | per channel, in layout order (the dimension's label lists the channels) |
//! | `/free_energy` | std_msgs/msg/Float64 | F |
//! | `/detector` | std_msgs/msg/Float64MultiArray | alarm, isolated, d per sensor group (labelled) |
//! | `/events` | rcl_interfaces/msg/Log | each sensor fault, actuator fault and disturbance starting (WARN) and ending (INFO), at its time; `msg` is JSON |
//!
//! Written with the `mcap` crate (zstd-compressed chunks); the messages in CDR (`cdr.rs`).

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use super::cdr::CdrWriter;
use super::messages::{self as msg, MessageType};
use crate::scenario::runner::{Observer, TickRecord};
use crate::scenario::{RunSetup, trajectory::TrajectorySchema};

/// The file name of a run's MCAP log.
pub const RUN_MCAP: &str = "run.mcap";

/// Topics, in the order their channels are added.
pub const TOPICS: [&str; 11] = [
    "/joint_states",
    "/true_joint_states",
    "/belief",
    "/command",
    "/target",
    "/camera/point",
    "/precision",
    "/health",
    "/free_energy",
    "/detector",
    "/events",
];

/// A fault or disturbance starting or ending, as `/events` logs it.
struct Event {
    ns: u64,
    level: u8,
    text: String,
}

fn ns(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// The events of a run's scenario, in time order.
fn events(setup: &RunSetup) -> Vec<Event> {
    let layout = setup.layout;
    let mut out = Vec::new();
    let mut edges = |class: &str,
                     kind: &str,
                     label: &str,
                     targets: serde_json::Value,
                     start: f64,
                     end: Option<f64>| {
        for (edge, t, level) in [
            ("start", Some(start), msg::LOG_WARN),
            ("end", end, msg::LOG_INFO),
        ] {
            let Some(t) = t else { continue };
            let text = serde_json::json!({
                "event": edge,
                "class": class,
                "kind": kind,
                "label": label,
                "targets": targets,
                "t": t,
            });
            out.push(Event {
                ns: ns(t),
                level,
                text: text.to_string(),
            });
        }
    };
    for f in &setup.faults {
        let channels: Vec<String> = f.channels.iter().map(|&c| layout.name(c)).collect();
        edges(
            "sensor",
            f.kind.name(),
            &f.label,
            serde_json::json!(channels),
            f.start,
            f.end,
        );
    }
    for f in &setup.actuator_faults {
        let joints: Vec<usize> = f.joints.iter().map(|j| j + 1).collect();
        edges(
            "actuator",
            f.kind.name(),
            &f.label,
            serde_json::json!(joints),
            f.start,
            f.end,
        );
    }
    for d in &setup.disturbances {
        edges(
            "disturbance",
            d.kind.name(),
            &d.label,
            serde_json::json!(setup.model.bodies[d.body].link),
            d.start,
            d.end,
        );
    }
    out.sort_by_key(|e| e.ns);
    out
}

/// Streams a run into an MCAP file as it goes (an [`Observer`]: register it with
/// `ObserverMode::Every(record_every)`). The first error is kept and returned by
/// [`McapRecorder::finish`].
pub struct McapRecorder<W: Write + Seek> {
    writer: Option<mcap::Writer<W>>,
    channel_ids: Vec<u16>,
    sequence: u32,
    cdr: CdrWriter,
    joint_names: Vec<String>,
    channel_label: String,
    detector_label: String,
    camera_frame: &'static str,
    events: Vec<Event>,
    next_event: usize,
    row: Vec<f64>,
    enc: Vec<f64>,
    tach: Vec<f64>,
    schema: TrajectorySchema,
    error: Option<mcap::McapError>,
    messages: u64,
}

impl<W: Write + Seek> McapRecorder<W> {
    /// A recorder of `setup`'s run into `out` (its schemas and channels written now).
    pub fn new(setup: &RunSetup, out: W) -> Result<Self, mcap::McapError> {
        let options = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("aift ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd));
        let mut writer = options.create(out)?;
        let types: [MessageType; 11] = [
            msg::joint_state_type(),
            msg::joint_state_type(),
            msg::joint_state_type(),
            msg::joint_state_type(),
            msg::joint_state_type(),
            msg::point_stamped_type(),
            msg::float64_multi_array_type(),
            msg::float64_multi_array_type(),
            msg::float64_type(),
            msg::float64_multi_array_type(),
            msg::log_type(),
        ];
        let mut schema_ids: BTreeMap<&str, u16> = BTreeMap::new();
        let mut channel_ids = Vec::with_capacity(TOPICS.len());
        for (topic, ty) in TOPICS.iter().zip(&types) {
            let schema = match schema_ids.get(ty.name) {
                Some(&id) => id,
                None => {
                    let id = writer.add_schema(ty.name, "ros2msg", ty.schema.as_bytes())?;
                    schema_ids.insert(ty.name, id);
                    id
                }
            };
            channel_ids.push(writer.add_channel(schema, topic, "cdr", &BTreeMap::new())?);
        }
        let layout = setup.layout;
        Ok(Self {
            writer: Some(writer),
            channel_ids,
            sequence: 0,
            cdr: CdrWriter::new(),
            joint_names: setup.model.joints.iter().map(|j| j.name.clone()).collect(),
            channel_label: layout.names().join(","),
            detector_label: std::iter::once("alarm".to_string())
                .chain(std::iter::once("isolated".to_string()))
                .chain(layout.groups().iter().map(|g| format!("d_{}", g.name())))
                .collect::<Vec<_>>()
                .join(","),
            camera_frame: if layout.camera_outputs() == 2 {
                "image"
            } else {
                "world"
            },
            events: events(setup),
            next_event: 0,
            row: Vec::new(),
            enc: Vec::with_capacity(layout.n_joints()),
            tach: Vec::with_capacity(layout.n_joints()),
            schema: TrajectorySchema::new(&layout),
            error: None,
            messages: 0,
        })
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    fn put(&mut self, topic: usize, ns: u64) {
        let Some(w) = self.writer.as_mut() else {
            return;
        };
        let header = mcap::records::MessageHeader {
            channel_id: self.channel_ids[topic],
            sequence: self.sequence,
            log_time: ns,
            publish_time: ns,
        };
        self.sequence = self.sequence.wrapping_add(1);
        if let Err(e) = w.write_to_known_channel(&header, self.cdr.bytes()) {
            self.error.get_or_insert(e);
            self.writer = None;
        }
        self.messages += 1;
    }

    /// Logs the events up to `upto` ns (inclusive): events between recorded ticks keep their
    /// own time; those after the run's last recorded tick are not logged.
    fn flush_events(&mut self, upto: u64) {
        while let Some(e) = self.events.get(self.next_event) {
            if e.ns > upto {
                break;
            }
            let (t, level) = (e.ns, e.level);
            let text = std::mem::take(&mut self.events[self.next_event].text);
            msg::log(&mut self.cdr, t, level, "aift.events", &text);
            self.put(10, t);
            self.next_event += 1;
        }
    }

    /// Writes the summary and index, and returns the output (or the first error).
    pub fn finish(mut self) -> Result<W, mcap::McapError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        let mut w = self.writer.take().expect("no error: the writer is there");
        w.finish()?;
        Ok(w.into_inner())
    }
}

impl<W: Write + Seek> Observer for McapRecorder<W> {
    fn iter(&mut self, r: &TickRecord<'_>) {
        if self.writer.is_none() {
            return;
        }
        let t = ns(r.t);
        self.flush_events(t);
        let n = r.q.len();
        let layout = r.layout;
        let reading = |c: usize| r.readings.values[c].unwrap_or(f64::NAN);
        // Reused buffers: no allocation per tick.
        let mut enc = std::mem::take(&mut self.enc);
        let mut tach = std::mem::take(&mut self.tach);
        enc.clear();
        enc.extend((0..n).map(reading));
        tach.clear();
        tach.extend((n..2 * n).map(reading));
        let names = std::mem::take(&mut self.joint_names);
        msg::joint_state(&mut self.cdr, t, &names, &enc, &tach, r.applied);
        self.put(0, t);
        msg::joint_state(&mut self.cdr, t, &names, r.q, r.qd, r.applied);
        self.put(1, t);
        msg::joint_state(&mut self.cdr, t, &names, r.mu, r.mu_p, &[]);
        self.put(2, t);
        msg::joint_state(&mut self.cdr, t, &names, &[], &[], r.torques);
        self.put(3, t);
        msg::joint_state(&mut self.cdr, t, &names, r.target, &[], &[]);
        self.put(4, t);
        self.joint_names = names;
        self.enc = enc;
        self.tach = tach;
        let cam = layout.group_range(crate::sensors::SensorGroup::Camera);
        let mut p = [0.0; 3];
        for (k, c) in cam.enumerate() {
            p[k] = reading(c);
        }
        msg::point_stamped(&mut self.cdr, t, self.camera_frame, p);
        self.put(5, t);
        // Precision, health and the detector as trajectory.csv has them: from its row.
        self.schema.row(r, &mut self.row);
        let channels = layout.len();
        let first = 1 + 7 * n + channels;
        let label = std::mem::take(&mut self.channel_label);
        let row = std::mem::take(&mut self.row);
        msg::float64_multi_array(&mut self.cdr, &label, &row[first..first + channels]);
        self.put(6, t);
        msg::float64_multi_array(
            &mut self.cdr,
            &label,
            &row[first + channels..first + 2 * channels],
        );
        self.put(7, t);
        msg::float64(&mut self.cdr, r.free_energy);
        self.put(8, t);
        let detector_label = std::mem::take(&mut self.detector_label);
        msg::float64_multi_array(
            &mut self.cdr,
            &detector_label,
            &row[first + 2 * channels + 1..],
        );
        self.put(9, t);
        self.detector_label = detector_label;
        self.channel_label = label;
        self.row = row;
    }
}
