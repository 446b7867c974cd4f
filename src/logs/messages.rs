//! The ROS 2 messages aift writes and reads: their schemas (the `ros2msg` text rosbag2 stores:
//! the message's definition, then each type it uses after a line of 80 `=` and `MSG: pkg/Type`)
//! and their CDR encodings.

use super::cdr::{CdrReader, CdrResult, CdrWriter};

const SEPARATOR: &str =
    "================================================================================";

const TIME: &str = "int32 sec\nuint32 nanosec\n";
const HEADER: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";

fn with_dependencies(main: &str, deps: &[(&str, &str)]) -> String {
    let mut text = main.to_string();
    for (name, def) in deps {
        text.push_str(SEPARATOR);
        text.push_str("\nMSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(def);
    }
    text
}

/// A message type: its ROS 2 name and schema text.
pub struct MessageType {
    pub name: &'static str,
    pub schema: String,
}

pub fn joint_state_type() -> MessageType {
    MessageType {
        name: "sensor_msgs/msg/JointState",
        schema: with_dependencies(
            "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
            &[
                ("std_msgs/Header", HEADER),
                ("builtin_interfaces/Time", TIME),
            ],
        ),
    }
}

pub fn point_stamped_type() -> MessageType {
    MessageType {
        name: "geometry_msgs/msg/PointStamped",
        schema: with_dependencies(
            "std_msgs/Header header\ngeometry_msgs/Point point\n",
            &[
                ("std_msgs/Header", HEADER),
                ("builtin_interfaces/Time", TIME),
                ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
            ],
        ),
    }
}

pub fn float64_multi_array_type() -> MessageType {
    MessageType {
        name: "std_msgs/msg/Float64MultiArray",
        schema: with_dependencies(
            "std_msgs/MultiArrayLayout layout\nfloat64[] data\n",
            &[
                (
                    "std_msgs/MultiArrayLayout",
                    "std_msgs/MultiArrayDimension[] dim\nuint32 data_offset\n",
                ),
                (
                    "std_msgs/MultiArrayDimension",
                    "string label\nuint32 size\nuint32 stride\n",
                ),
            ],
        ),
    }
}

pub fn float64_type() -> MessageType {
    MessageType {
        name: "std_msgs/msg/Float64",
        schema: "float64 data\n".into(),
    }
}

pub fn log_type() -> MessageType {
    MessageType {
        name: "rcl_interfaces/msg/Log",
        schema: with_dependencies(
            "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n\
             builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\n\
             string function\nuint32 line\n",
            &[("builtin_interfaces/Time", TIME)],
        ),
    }
}

/// A time in nanoseconds as ROS's (sec, nanosec).
pub fn stamp(ns: u64) -> (i32, u32) {
    (
        (ns / 1_000_000_000).min(i32::MAX as u64) as i32,
        (ns % 1_000_000_000) as u32,
    )
}

fn header(w: &mut CdrWriter, ns: u64, frame_id: &str) {
    let (sec, nanosec) = stamp(ns);
    w.i32(sec);
    w.u32(nanosec);
    w.string(frame_id);
}

/// sensor_msgs/msg/JointState.
pub fn joint_state(
    w: &mut CdrWriter,
    ns: u64,
    names: &[String],
    position: &[f64],
    velocity: &[f64],
    effort: &[f64],
) {
    w.reset();
    header(w, ns, "");
    w.strings(names);
    w.f64s(position);
    w.f64s(velocity);
    w.f64s(effort);
}

/// geometry_msgs/msg/PointStamped.
pub fn point_stamped(w: &mut CdrWriter, ns: u64, frame_id: &str, p: [f64; 3]) {
    w.reset();
    header(w, ns, frame_id);
    for x in p {
        w.f64(x);
    }
}

/// std_msgs/msg/Float64MultiArray with one dimension labelled `label`.
pub fn float64_multi_array(w: &mut CdrWriter, label: &str, data: &[f64]) {
    w.reset();
    w.u32(1);
    w.string(label);
    w.u32(data.len() as u32);
    w.u32(data.len() as u32);
    w.u32(0);
    w.f64s(data);
}

/// std_msgs/msg/Float64.
pub fn float64(w: &mut CdrWriter, v: f64) {
    w.reset();
    w.f64(v);
}

/// rcl_interfaces/msg/Log's levels.
pub const LOG_INFO: u8 = 20;
pub const LOG_WARN: u8 = 30;

/// rcl_interfaces/msg/Log.
pub fn log(w: &mut CdrWriter, ns: u64, level: u8, name: &str, msg: &str) {
    w.reset();
    let (sec, nanosec) = stamp(ns);
    w.i32(sec);
    w.u32(nanosec);
    w.u8(level);
    w.string(name);
    w.string(msg);
    w.string("");
    w.string("");
    w.u32(0);
}

/// A decoded sensor_msgs/msg/JointState.
#[derive(Clone, Debug, PartialEq)]
pub struct JointStateMessage {
    /// The header's stamp (ns; 0 when the stamp is negative).
    pub stamp_ns: u64,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

/// A header stamp in ns (0 for a negative one).
fn stamp_ns(sec: i32, nanosec: u32) -> u64 {
    (sec.max(0) as u64) * 1_000_000_000 + u64::from(nanosec)
}

/// Decodes a geometry_msgs/msg/PointStamped: its stamp (ns) and point.
pub fn read_point_stamped(data: &[u8]) -> CdrResult<(u64, [f64; 3])> {
    let mut r = CdrReader::new(data)?;
    let sec = r.i32()?;
    let nanosec = r.u32()?;
    let _frame_id = r.string()?;
    Ok((stamp_ns(sec, nanosec), [r.f64()?, r.f64()?, r.f64()?]))
}

/// Decodes a sensor_msgs/msg/JointState from its CDR bytes.
pub fn read_joint_state(data: &[u8]) -> CdrResult<JointStateMessage> {
    let mut r = CdrReader::new(data)?;
    let sec = r.i32()?;
    let nanosec = r.u32()?;
    let _frame_id = r.string()?;
    Ok(JointStateMessage {
        stamp_ns: stamp_ns(sec, nanosec),
        name: r.strings()?,
        position: r.f64s()?,
        velocity: r.f64s()?,
        effort: r.f64s()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joint_state_round_trips() {
        let mut w = CdrWriter::new();
        let names = vec!["j1".to_string(), "joint_two".to_string()];
        joint_state(
            &mut w,
            1_000_000_002,
            &names,
            &[1.5, f64::NAN],
            &[],
            &[0.25, -1.0],
        );
        let m = read_joint_state(w.bytes()).unwrap();
        let mut p = CdrWriter::new();
        point_stamped(&mut p, 3_000_000_004, "image", [1.0, -2.0, 0.0]);
        assert_eq!(
            read_point_stamped(p.bytes()).unwrap(),
            (3_000_000_004, [1.0, -2.0, 0.0])
        );
        assert_eq!(m.stamp_ns, 1_000_000_002);
        assert_eq!(m.name, names);
        assert_eq!(m.position[0], 1.5);
        assert!(m.position[1].is_nan());
        assert!(m.velocity.is_empty());
        assert_eq!(m.effort, vec![0.25, -1.0]);
        // A message cut short is an error, not a panic.
        assert!(read_joint_state(&w.bytes()[..w.bytes().len() - 3]).is_err());
    }

    #[test]
    fn bytes_equal_an_independent_serialiser() {
        // The same messages serialised by PyPI's mcap-ros2-support and rosbags' serialize_cdr
        // (identical bytes from both; 2026-12-04).
        let hex = |b: &[u8]| b.iter().map(|x| format!("{x:02x}")).collect::<String>();
        let mut w = CdrWriter::new();
        joint_state(
            &mut w,
            1_000_000_002,
            &["j1".to_string()],
            &[1.5],
            &[],
            &[0.25],
        );
        assert_eq!(
            hex(w.bytes()),
            "000100000100000002000000010000000000000001000000030000006a31000001000000000000000000f83f0000000001000000000000000000d03f"
        );
        float64_multi_array(&mut w, "x", &[1.0, 2.0]);
        assert_eq!(
            hex(w.bytes()),
            "000100000100000002000000780000000200000002000000000000000200000000000000000000000000f03f0000000000000040"
        );
        float64(&mut w, 3.25);
        assert_eq!(hex(w.bytes()), "000100000000000000000a40");
        log(&mut w, 5_000_000_006, LOG_INFO, "node", "hello");
        // (Theirs had file "a.rs", function "main", line 42: the same up to the name and msg.)
        assert!(hex(w.bytes()).starts_with(
            "00010000050000000600000014000000050000006e6f6465000000000600000068656c6c6f00"
        ));
        point_stamped(&mut w, 1_000_000_002, "world", [1.0, 2.0, 3.0]);
        assert_eq!(
            hex(w.bytes()),
            "00010000010000000200000006000000776f726c6400000000000000000000000000f03f00000000000000400000000000000840"
        );
    }

    #[test]
    fn schemas_name_their_dependencies() {
        let s = joint_state_type().schema;
        assert!(s.contains(&format!("{SEPARATOR}\nMSG: std_msgs/Header\n")));
        assert!(s.contains("MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"));
    }
}
