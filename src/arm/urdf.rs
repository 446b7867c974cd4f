//! Reading a URDF into an engine-independent, validated [`ArmModel`].
//!
//! Our own loader on `urdf-rs` rather than `rapier3d-urdf` (docs/method.md, "Plant"): that crate is
//! f32-only, ignores `<dynamics>` and the inertial frame's rotation, accepts massless links and
//! panics on some bad files. Here every defect becomes a typed [`ArmError`] naming the file and
//! the element.
//!
//! Loading happens in three passes:
//! 1. a streaming XML pass ([`scan`]) that bounds the nesting depth (urdf-rs recurses and would
//!    overflow the stack, an abort no handler catches), checks every numeric attribute it knows,
//!    and records which links carry an `<inertial>` (urdf-rs fills a missing one with zeros);
//! 2. `urdf_rs::read_from_string` for the structure;
//! 3. validation and the merge of fixed joints into bodies ([`build_model`]).

use std::collections::{HashMap, HashSet, VecDeque};
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Translation3, Unit, UnitQuaternion, Vector3};

use super::ArmError;
use super::model::{
    ArmModel, BodySpec, ColliderSpec, JointKind, JointSpec, LinkFrame, ShapeSpec, combine_parts,
};

/// Deepest XML nesting accepted. Real URDFs nest about 5 levels.
pub const MAX_XML_DEPTH: usize = 64;

/// Most movable joints an arm may have: 64 (a 7-DOF arm is the common large case; a 30-joint
/// chain is in the tests). Each estimator's state and the u-AIC's Hessian are 2n wide, the camera
/// model has n inputs; a bound keeps a malformed or generated file from asking for gigabytes.
pub const MAX_JOINTS: usize = 64;

/// Relative tolerance of the inertia triangle inequality (rounding in published tensors).
const TRIANGLE_TOLERANCE: f64 = 1e-6;

/// How a URDF is read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UrdfOptions {
    /// Raise a principal moment of an inertia that breaks the triangle inequality just enough
    /// to satisfy it (with a warning naming the link), as MuJoCo's `balanceinertia` repairs such
    /// files; without it such a file is refused.
    pub balance_inertia: bool,
}

/// Reads and validates a URDF file.
///
/// ```
/// let arm = aift::arm::load_urdf(std::path::Path::new("urdf/planar_2dof.urdf"))?;
/// assert_eq!(arm.joints.len(), 2);
/// assert!(arm.total_mass() > 0.0);
/// # Ok::<(), aift::arm::ArmError>(())
/// ```
pub fn load_urdf(path: &Path) -> Result<ArmModel, ArmError> {
    load_urdf_with(path, &UrdfOptions::default())
}

/// Reads and validates a URDF file with options.
pub fn load_urdf_with(path: &Path, options: &UrdfOptions) -> Result<ArmModel, ArmError> {
    let bytes =
        crate::fsio::read_bounded(path, crate::fsio::MAX_URDF_BYTES).map_err(|e| match e {
            crate::fsio::FsError::Read { path, source } => ArmError::Unreadable { path, source },
            other => ArmError::File(other),
        })?;
    let text = String::from_utf8(bytes).map_err(|_| ArmError::NotText {
        path: path.to_path_buf(),
    })?;
    parse_urdf_with(&text, path, options)
}

/// Parses and validates URDF text; `path` is used in messages only.
pub fn parse_urdf(text: &str, path: &Path) -> Result<ArmModel, ArmError> {
    parse_urdf_with(text, path, &UrdfOptions::default())
}

/// Parses and validates URDF text with options; `path` is used in messages only.
pub fn parse_urdf_with(
    text: &str,
    path: &Path,
    options: &UrdfOptions,
) -> Result<ArmModel, ArmError> {
    if text.trim().is_empty() {
        return Err(ArmError::Empty {
            path: path.to_path_buf(),
        });
    }
    if text.contains('\0') {
        return Err(ArmError::NotText {
            path: path.to_path_buf(),
        });
    }
    if let Some((line, found)) = xacro_markup(text) {
        return Err(ArmError::Xacro {
            path: path.to_path_buf(),
            line,
            found,
        });
    }
    let scanned = scan(text, path)?;
    // urdf-rs is not known to panic once the depth is bounded; a panic is still turned into an
    // error rather than trusted never to happen.
    let parsed = std::panic::catch_unwind(|| urdf_rs::read_from_string(text)).map_err(|_| {
        ArmError::Xml {
            path: path.to_path_buf(),
            message: "the URDF parser failed on this file".into(),
        }
    })?;
    let robot = parsed.map_err(|e| ArmError::Xml {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    build_model(&robot, &scanned, path, options)
}

/// The first piece of xacro markup in `text` (an `<xacro:...>` element, a `${...}` expression
/// or a `$(...)` substitution) with its line: a xacro template is not a URDF until expanded,
/// and read as one its macros vanish in silence (no joint, or numbers that do not parse).
fn xacro_markup(text: &str) -> Option<(usize, String)> {
    // Outside comments: an expanded URDF often names its xacro source, `$(find ...)` and all,
    // in a comment at the top.
    let mut from = 0;
    let pos = loop {
        let rest = &text[from..];
        let next = ["<xacro:", "${", "$("]
            .iter()
            .filter_map(|m| rest.find(m))
            .min()?;
        match rest.find("<!--") {
            Some(c) if c < next => match rest[c..].find("-->") {
                Some(end) => from += c + end + 3,
                None => return None,
            },
            _ => break from + next,
        }
    };
    let line = line_of(text, pos);
    let found: String = text[pos..]
        .chars()
        .take_while(|c| !c.is_whitespace() && *c != '>')
        .take(40)
        .collect();
    Some((line, found))
}

/// What the streaming pass learned beyond the numbers it checked.
#[derive(Debug, Default)]
pub(crate) struct Scan {
    /// Links (top-level `<link>` elements) that contain an `<inertial>`.
    links_with_inertial: HashSet<String>,
    /// What the parser would pass over in silence: elements and attributes of a link or joint
    /// that URDF does not define (a typo such as `<axsi>` or `efort` changes the arm: the axis
    /// or the effort limit takes its default), a `<limit>` without the effort URDF requires
    /// before version 1.2. At most [`MAX_SCAN_WARNINGS`], then a count of the rest.
    warnings: Vec<String>,
}

/// URDF's joint types.
const JOINT_TYPES: [&str; 7] = [
    "revolute",
    "continuous",
    "prismatic",
    "fixed",
    "floating",
    "planar",
    "spherical",
];

/// Most warnings the streaming pass collects; the rest are counted in one last warning.
const MAX_SCAN_WARNINGS: usize = 20;

/// Attributes later URDF versions add: `quat_xyzw` of `<origin>` (1.1), `acceleration`,
/// `deceleration` and `jerk` of a joint's `<limit>` (1.2); urdf-rs reads them from that version
/// on and ignores them before, as urdfdom does.
fn versioned_attribute(path: &[&str], attribute: &str, version: (u32, u32)) -> bool {
    match (path.last().copied(), attribute) {
        (Some("origin"), "quat_xyzw") => version >= (1, 1),
        (Some("limit"), "acceleration" | "deceleration" | "jerk") => {
            path == ["joint", "limit"] && version >= (1, 2)
        }
        _ => false,
    }
}

/// The children URDF defines for an element of a link or joint (by its path below the link
/// or joint), and that element's attributes; `None`: not checked (a visual's geometry and
/// material, extensions).
fn urdf_schema(path: &[&str]) -> Option<(&'static [&'static str], &'static [&'static str])> {
    Some(match path {
        ["joint"] => (
            &[
                "origin",
                "parent",
                "child",
                "axis",
                "calibration",
                "dynamics",
                "limit",
                "mimic",
                "safety_controller",
            ],
            &["name", "type"],
        ),
        ["link"] => (&["inertial", "visual", "collision"], &["name"]),
        ["link", "inertial"] => (&["origin", "mass", "inertia"], &[]),
        ["joint", "limit"] => (&[], &["lower", "upper", "effort", "velocity"]),
        ["joint", "dynamics"] => (&[], &["damping", "friction"]),
        ["joint", "axis"] => (&[], &["xyz"]),
        ["joint" | "link", "origin"] | ["link", "inertial", "origin"] => (&[], &["xyz", "rpy"]),
        ["link", "inertial", "mass"] => (&[], &["value"]),
        ["link", "inertial", "inertia"] => (&[], &["ixx", "ixy", "ixz", "iyy", "iyz", "izz"]),
        _ => return None,
    })
}

/// Which attributes are numeric, and how many numbers each holds.
fn numeric_attribute(element: &str, attribute: &str) -> Option<usize> {
    match (element, attribute) {
        ("origin", "xyz" | "rpy") => Some(3),
        ("axis", "xyz") => Some(3),
        ("box", "size") => Some(3),
        ("mesh", "scale") => Some(3),
        ("mass", "value") => Some(1),
        ("inertia", "ixx" | "ixy" | "ixz" | "iyy" | "iyz" | "izz") => Some(1),
        ("limit", "lower" | "upper" | "effort" | "velocity") => Some(1),
        ("dynamics", "damping" | "friction") => Some(1),
        ("cylinder" | "capsule", "radius" | "length") => Some(1),
        ("sphere", "radius") => Some(1),
        _ => None,
    }
}

fn line_of(text: &str, byte: usize) -> usize {
    1 + text.as_bytes()[..byte.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}

/// The streaming pass: depth bound, numeric attributes, `<inertial>` presence.
pub(crate) fn scan(text: &str, path: &Path) -> Result<Scan, ArmError> {
    use quick_xml::events::Event;

    let xml_error = |message: String| ArmError::Xml {
        path: path.to_path_buf(),
        message,
    };
    let mut reader = quick_xml::Reader::from_str(text);
    let mut stack: Vec<String> = Vec::new();
    // (kind, name) of the enclosing top-level link or joint.
    let mut owner: Option<(&'static str, String)> = None;
    let mut out = Scan::default();
    let mut saw_root = false;
    // `<robot version>` (urdf-rs' reading: absent or malformed is 1.0).
    let mut version = (1u32, 0u32);
    // The line of the current element, counted incrementally (positions only grow).
    let (mut counted_to, mut counted_line) = (0usize, 1usize);
    let mut skipped_warnings = 0usize;
    loop {
        let position = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|e| {
            xml_error(format!(
                "near line {}: {e}",
                line_of(text, reader.error_position() as usize)
            ))
        })?;
        let (element, is_empty) = match &event {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(_) => {
                stack.pop();
                if stack.len() < 2 {
                    owner = None;
                }
                continue;
            }
            Event::Eof => break,
            _ => continue,
        };
        let name = element.name().as_ref().to_string();
        let depth = stack.len() + 1;
        if depth > MAX_XML_DEPTH {
            return Err(ArmError::TooDeep {
                path: path.to_path_buf(),
                depth,
                limit: MAX_XML_DEPTH,
                line: line_of(text, position),
            });
        }
        if depth == 1 {
            if name != "robot" {
                return Err(xml_error(format!(
                    "the root element is <{name}>, expected <robot>"
                )));
            }
            if saw_root {
                return Err(xml_error(format!(
                    "near line {}: a second <robot> element; a URDF describes one robot",
                    line_of(text, position)
                )));
            }
            saw_root = true;
        }
        let mut attributes = Vec::new();
        for attribute in element.attributes() {
            let attribute = attribute.map_err(|e| {
                xml_error(format!(
                    "near line {}: bad attribute in <{name}>: {e}",
                    line_of(text, position)
                ))
            })?;
            let key = attribute.key.as_ref().to_string();
            let value = attribute
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|e| {
                    xml_error(format!(
                        "near line {}: bad value of `{key}` in <{name}>: {e}",
                        line_of(text, position)
                    ))
                })?
                .into_owned();
            attributes.push((key, value));
        }
        if depth == 1
            && let Some((_, v)) = attributes.iter().find(|(k, _)| k == "version")
            && let Some((major, minor)) = v.trim().split_once('.')
            && let (Ok(major), Ok(minor)) = (major.parse(), minor.parse())
        {
            version = (major, minor);
        }
        // Elements and attributes URDF does not define, within a link or joint (extensions with
        // a namespace prefix are not URDF's to judge).
        if depth >= 2 && (depth > 2 || name == "link" || name == "joint") {
            counted_line += text.as_bytes()[counted_to..position.max(counted_to)]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            counted_to = counted_to.max(position);
            let line = counted_line;
            let below: Vec<&str> = stack
                .get(1..)
                .unwrap_or(&[])
                .iter()
                .map(String::as_str)
                .chain(std::iter::once(name.as_str()))
                .collect();
            let what = || match &owner {
                Some((kind, n)) if depth > 2 => format!("{kind} '{n}'"),
                _ => format!(
                    "{name} '{}'",
                    attributes
                        .iter()
                        .find(|(k, _)| k == "name")
                        .map_or("", |(_, v)| v.as_str())
                ),
            };
            if below == ["joint"] {
                match attributes.iter().find(|(k, _)| k == "type") {
                    Some((_, t)) if JOINT_TYPES.contains(&t.as_str()) => {}
                    found => {
                        return Err(xml_error(format!(
                            "{} (line {line}): {}; URDF's joint types are {}",
                            what(),
                            found.map_or("no `type`".to_string(), |(_, t)| format!(
                                "type `{t}` is not a joint type"
                            )),
                            JOINT_TYPES.join(", ")
                        )));
                    }
                }
            }
            let mut warn = |message: String| {
                if out.warnings.len() < MAX_SCAN_WARNINGS {
                    out.warnings.push(message);
                } else {
                    skipped_warnings += 1;
                }
            };
            if depth > 2
                && !name.contains(':')
                && let Some((children, _)) = urdf_schema(&below[..below.len() - 1])
                && !children.contains(&name.as_str())
            {
                warn(format!(
                    "{}: element <{name}> (line {line}) is not URDF's; ignored",
                    what()
                ));
            }
            if let Some((_, known)) = urdf_schema(&below) {
                for (key, _) in &attributes {
                    if !known.contains(&key.as_str())
                        && !key.contains(':')
                        && !key.starts_with("xmlns")
                        && !versioned_attribute(&below, key, version)
                    {
                        warn(format!(
                            "{}: attribute `{key}` of <{name}> (line {line}) is not URDF {}.{}'s; \
                             ignored",
                            what(),
                            version.0,
                            version.1
                        ));
                    }
                }
            }
            // Attributes URDF requires and the parser would refuse without naming the link or
            // joint (a limit's velocity before URDF 1.2).
            let required: &[&str] = match below.as_slice() {
                ["link", "inertial", "mass"] => &["value"],
                ["link", "inertial", "inertia"] => &["ixx", "ixy", "ixz", "iyy", "iyz", "izz"],
                ["joint", "parent" | "child"] => &["link"],
                ["joint", "limit"] if version < (1, 2) => &["velocity"],
                _ => &[],
            };
            for key in required {
                if !attributes.iter().any(|(k, _)| k == key) {
                    return Err(xml_error(format!(
                        "{}: <{name}> (line {line}) has no `{key}`, which URDF {}.{} requires",
                        what(),
                        version.0,
                        version.1
                    )));
                }
            }
            // Before URDF 1.2 a limit's effort is required too; urdf-rs reads it as 0, which
            // the loader takes for no limit. (From 1.2 on an omitted limit means none.)
            if below == ["joint", "limit"]
                && version < (1, 2)
                && !attributes.iter().any(|(k, _)| k == "effort")
            {
                warn(format!(
                    "{}: <limit> (line {line}) has no `effort`, which URDF {}.{} requires; \
                     simulated with no effort limit",
                    what(),
                    version.0,
                    version.1
                ));
            }
            // An explicit effort="0" would hold the joint without torque; it is read as no
            // limit (descriptions write 0 for "unspecified"), and said so.
            if below == ["joint", "limit"]
                && attributes
                    .iter()
                    .any(|(k, v)| k == "effort" && v.trim().parse::<f64>() == Ok(0.0))
            {
                warn(format!(
                    "{}: <limit> (line {line}) has effort=\"0\", read as no effort limit (a \
                     joint with zero torque could not move); give the motor's limit to \
                     saturate the torque",
                    what()
                ));
            }
        }
        if depth == 2 {
            owner = (name == "link" || name == "joint").then(|| {
                let own_name = attributes
                    .iter()
                    .find(|(k, _)| k == "name")
                    .map(|(_, v)| v.clone())
                    .unwrap_or_default();
                (if name == "link" { "link" } else { "joint" }, own_name)
            });
        }
        if let Some((kind, owner_name)) = &owner {
            if *kind == "link" && depth == 3 && name == "inertial" {
                out.links_with_inertial.insert(owner_name.clone());
            }
            for (key, value) in &attributes {
                if let Some(count) = numeric_attribute(&name, key) {
                    check_numbers(value, count).map_err(|expected| ArmError::BadNumber {
                        path: path.to_path_buf(),
                        element: format!(
                            "{kind} '{owner_name}' <{}>",
                            stack
                                .get(2..)
                                .unwrap_or(&[])
                                .iter()
                                .map(String::as_str)
                                .chain(std::iter::once(name.as_str()))
                                .collect::<Vec<_>>()
                                .join("><")
                        ),
                        attribute: key.clone(),
                        value: value.clone(),
                        expected,
                    })?;
                }
            }
        }
        if is_empty {
            if depth == 2 {
                owner = None;
            }
        } else {
            stack.push(name);
        }
    }
    if !saw_root {
        return Err(xml_error("no <robot> element".to_string()));
    }
    if skipped_warnings > 0 {
        out.warnings
            .push(format!("... and {skipped_warnings} more such warnings"));
    }
    Ok(out)
}

/// Checks that `value` holds `count` finite numbers; returns what was expected otherwise.
fn check_numbers(value: &str, count: usize) -> Result<(), String> {
    let expected = || {
        if count == 1 {
            "a finite number".to_string()
        } else {
            format!("{count} finite numbers")
        }
    };
    let mut n = 0;
    for token in value.split_whitespace() {
        match token.parse::<f64>() {
            Ok(v) if v.is_finite() => n += 1,
            _ => return Err(expected()),
        }
    }
    if n == count { Ok(()) } else { Err(expected()) }
}

fn isometry(pose: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = pose.xyz.0;
    let [r, p, yaw] = pose.rpy.0;
    // URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z (R = Rz Ry Rx).
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(r, p, yaw),
    )
}

/// Validates one link's inertia tensor (in its inertial frame); with `balance`, a tensor that
/// breaks the triangle inequality has its middle principal moment raised just enough
/// (e1 = e2 - e0), and the repaired tensor and a warning are returned.
fn check_inertia(
    tensor: &Matrix3<f64>,
    link: &str,
    path: &Path,
    balance: bool,
) -> Result<(Matrix3<f64>, Option<String>), ArmError> {
    let bad = |reason: String| ArmError::BadInertia {
        path: path.to_path_buf(),
        link: link.to_string(),
        reason,
    };
    let eigen = tensor.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let e = order.map(|i| eigen.eigenvalues[i]);
    if e[0] <= 0.0 {
        return Err(bad(format!(
            "is not positive definite (principal moments {:.6e}, {:.6e}, {:.6e})",
            e[0], e[1], e[2]
        )));
    }
    if e[0] + e[1] < e[2] * (1.0 - TRIANGLE_TOLERANCE) {
        if !balance {
            return Err(bad(format!(
                "breaks the triangle inequality: principal moments {:.6e} + {:.6e} < {:.6e} \
                 (no rigid body has such an inertia; `robot.balance_inertia = true`, or \
                 `aift check-urdf --balance-inertia`, raises the middle moment just enough, as \
                 MuJoCo's balanceinertia repairs such files)",
                e[0], e[1], e[2]
            )));
        }
        let mut values = eigen.eigenvalues;
        values[order[1]] = e[2] - e[0];
        let repaired =
            eigen.eigenvectors * Matrix3::from_diagonal(&values) * eigen.eigenvectors.transpose();
        let warning = format!(
            "link '{link}': inertia balanced: principal moments {:.6e}, {:.6e}, {:.6e} broke the \
             triangle inequality; the middle one was raised to {:.6e}",
            e[0],
            e[1],
            e[2],
            e[2] - e[0]
        );
        return Ok((repaired, Some(warning)));
    }
    Ok((*tensor, None))
}

/// Validation and the merge of fixed joints into bodies.
pub(crate) fn build_model(
    robot: &urdf_rs::Robot,
    scanned: &Scan,
    path: &Path,
    options: &UrdfOptions,
) -> Result<ArmModel, ArmError> {
    let p = || path.to_path_buf();
    let mut warnings = scanned.warnings.clone();
    let link_index = index_names(robot, path)?;
    let tree = topology(robot, &link_index, path)?;
    let walk = walk_tree(robot, &link_index, &tree, path, &mut warnings)?;
    let (link_body, parent_joint) = (&walk.link_body, &tree.parent_joint);
    // Links not reached from the root: their parent chain loops.
    if let Some(unreached) = (0..robot.links.len()).find(|&l| link_body[l].is_none()) {
        let joint = parent_joint[unreached].map_or_else(
            || robot.links[unreached].name.clone(),
            |j| robot.joints[j].name.clone(),
        );
        return Err(ArmError::Cycle { path: p(), joint });
    }
    if walk.joints.is_empty() {
        return Err(ArmError::NoMovableJoint { path: p() });
    }
    if walk.joints.len() > MAX_JOINTS {
        return Err(ArmError::TooManyJoints {
            path: p(),
            count: walk.joints.len(),
            limit: MAX_JOINTS,
        });
    }
    for joint in &robot.joints {
        if joint.joint_type != urdf_rs::JointType::Fixed && joint.mimic.is_some() {
            warnings.push(format!(
                "joint '{}': <mimic> ignored; the joint is simulated as independent",
                joint.name
            ));
        }
    }
    let (mut links, bodies, colliders) =
        mass_properties(robot, scanned, &walk, path, options, &mut warnings)?;
    // Keep links in file order for listing.
    links.sort_by_key(|l| link_index[l.name.as_str()]);

    Ok(ArmModel {
        name: robot.name.clone(),
        source: path.to_path_buf(),
        bodies,
        joints: walk.joints,
        links,
        colliders,
        warnings,
    })
}

/// Every link and joint named once; the links' indices by name.
fn index_names<'a>(
    robot: &'a urdf_rs::Robot,
    path: &Path,
) -> Result<HashMap<&'a str, usize>, ArmError> {
    let p = || path.to_path_buf();
    let mut link_index: HashMap<&str, usize> = HashMap::new();
    for (i, link) in robot.links.iter().enumerate() {
        if link_index.insert(link.name.as_str(), i).is_some() {
            return Err(ArmError::DuplicateName {
                path: p(),
                kind: "link",
                name: link.name.clone(),
            });
        }
    }
    let mut joint_names = HashSet::new();
    for joint in &robot.joints {
        if !joint_names.insert(joint.name.as_str()) {
            return Err(ArmError::DuplicateName {
                path: p(),
                kind: "joint",
                name: joint.name.clone(),
            });
        }
    }
    if robot.links.is_empty() {
        return Err(ArmError::NoSingleRoot {
            path: p(),
            roots_found: 0,
            roots: "no <link> at all".into(),
        });
    }
    Ok(link_index)
}

/// The joint tree: each link's parent joint, each link's child joints, the single root.
struct Topology {
    parent_joint: Vec<Option<usize>>,
    children: Vec<Vec<usize>>,
    root: usize,
}

/// The tree the joints make: one parent per link, a single root, no lone link.
fn topology(
    robot: &urdf_rs::Robot,
    link_index: &HashMap<&str, usize>,
    path: &Path,
) -> Result<Topology, ArmError> {
    let p = || path.to_path_buf();
    let mut parent_joint: Vec<Option<usize>> = vec![None; robot.links.len()];
    let mut children: Vec<Vec<usize>> = vec![Vec::new(); robot.links.len()];
    for (j, joint) in robot.joints.iter().enumerate() {
        let find = |name: &str, role: &'static str| {
            link_index
                .get(name)
                .copied()
                .ok_or_else(|| ArmError::UnknownLink {
                    path: p(),
                    joint: joint.name.clone(),
                    role,
                    link: name.to_string(),
                })
        };
        let parent = find(&joint.parent.link, "parent")?;
        let child = find(&joint.child.link, "child")?;
        if parent == child {
            return Err(ArmError::Cycle {
                path: p(),
                joint: joint.name.clone(),
            });
        }
        if let Some(first) = parent_joint[child] {
            return Err(ArmError::MultipleParents {
                path: p(),
                link: joint.child.link.clone(),
                first: robot.joints[first].name.clone(),
                second: joint.name.clone(),
            });
        }
        parent_joint[child] = Some(j);
        children[parent].push(j);
    }
    let roots: Vec<usize> = (0..robot.links.len())
        .filter(|&l| parent_joint[l].is_none())
        .collect();
    let root = match roots.as_slice() {
        [single] => *single,
        [] => {
            // Every link has a parent: the joints close a cycle.
            return Err(ArmError::Cycle {
                path: p(),
                joint: robot.joints[0].name.clone(),
            });
        }
        many => {
            // One tree plus lone links: name the lone link.
            let trees: Vec<usize> = many
                .iter()
                .copied()
                .filter(|&l| !children[l].is_empty())
                .collect();
            if trees.len() == 1 {
                let lone = many.iter().copied().find(|&l| l != trees[0]).unwrap_or(0);
                return Err(ArmError::Disconnected {
                    path: p(),
                    link: robot.links[lone].name.clone(),
                    root: robot.links[trees[0]].name.clone(),
                });
            }
            return Err(ArmError::NoSingleRoot {
                path: p(),
                roots_found: many.len(),
                roots: many
                    .iter()
                    .map(|&l| format!("'{}'", robot.links[l].name))
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
    };
    Ok(Topology {
        parent_joint,
        children,
        root,
    })
}

/// What the breadth-first walk builds: each link's body and pose in it, each body's links and
/// top link, the movable joints.
struct Walk {
    link_body: Vec<Option<(usize, Isometry3<f64>)>>,
    body_links: Vec<Vec<usize>>,
    body_top: Vec<usize>,
    joints: Vec<JointSpec>,
}

/// Breadth-first from the root: bodies (fixed joints merge a link into its parent's body), link
/// frames, movable joints.
fn walk_tree(
    robot: &urdf_rs::Robot,
    link_index: &HashMap<&str, usize>,
    tree: &Topology,
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<Walk, ArmError> {
    let p = || path.to_path_buf();
    let Topology { children, root, .. } = tree;
    let root = *root;
    let mut link_body: Vec<Option<(usize, Isometry3<f64>)>> = vec![None; robot.links.len()];
    link_body[root] = Some((0, Isometry3::identity()));
    let mut body_links: Vec<Vec<usize>> = vec![vec![root]];
    let mut body_top: Vec<usize> = vec![root];
    let mut joints = Vec::new();
    let mut queue = VecDeque::from([root]);
    while let Some(link) = queue.pop_front() {
        let (body, link_pose) = link_body[link].expect("queued links are placed");
        for &j in &children[link] {
            let joint = &robot.joints[j];
            let child = link_index[joint.child.link.as_str()];
            let origin = link_pose * isometry(&joint.origin);
            let kind = match joint.joint_type {
                urdf_rs::JointType::Fixed => None,
                urdf_rs::JointType::Revolute => Some(JointKind::Revolute),
                urdf_rs::JointType::Continuous => Some(JointKind::Continuous),
                urdf_rs::JointType::Prismatic => Some(JointKind::Prismatic),
                ref other => {
                    return Err(ArmError::UnsupportedJoint {
                        path: p(),
                        joint: joint.name.clone(),
                        kind: format!("{other:?}").to_lowercase(),
                    });
                }
            };
            match kind {
                None => {
                    link_body[child] = Some((body, origin));
                    body_links[body].push(child);
                }
                Some(kind) => {
                    let new_body = body_links.len();
                    let spec = movable_joint(joint, kind, body, new_body, origin, path, warnings)?;
                    body_links.push(vec![child]);
                    body_top.push(child);
                    link_body[child] = Some((new_body, Isometry3::identity()));
                    joints.push(spec);
                }
            }
            queue.push_back(child);
        }
    }
    Ok(Walk {
        link_body,
        body_links,
        body_top,
        joints,
    })
}

/// A movable joint: its axis, limits (none when lower = upper), effort, velocity limit, damping
/// and friction checked.
fn movable_joint(
    joint: &urdf_rs::Joint,
    kind: JointKind,
    parent_body: usize,
    child_body: usize,
    origin: Isometry3<f64>,
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<JointSpec, ArmError> {
    let p = || path.to_path_buf();
    let axis = Vector3::from(joint.axis.xyz.0);
    let axis = Unit::try_new(axis, 1e-12).ok_or_else(|| ArmError::ZeroAxis {
        path: p(),
        joint: joint.name.clone(),
    })?;
    let lim = &joint.limit;
    let mut kind = kind;
    let limits = match kind {
        JointKind::Continuous => None,
        _ if lim.lower > lim.upper => {
            return Err(ArmError::BadLimit {
                path: p(),
                joint: joint.name.clone(),
                lower: lim.lower,
                upper: lim.upper,
            });
        }
        _ if lim.lower == lim.upper || (!lim.lower.is_finite() && !lim.upper.is_finite()) => {
            warnings.push(format!(
                "joint '{}': no position limits (lower = upper); simulated without limits",
                joint.name
            ));
            if kind == JointKind::Revolute {
                kind = JointKind::Continuous;
            }
            None
        }
        _ => Some((lim.lower, lim.upper)),
    };
    let dynamics = joint.dynamics.clone().unwrap_or_default();
    for (element, attribute, value) in [
        ("<dynamics>", "damping", dynamics.damping),
        ("<dynamics>", "friction", dynamics.friction),
        ("<limit>", "effort", lim.effort),
        ("<limit>", "velocity", lim.velocity),
    ] {
        if value < 0.0 {
            return Err(ArmError::Negative {
                path: p(),
                joint: joint.name.clone(),
                element,
                attribute,
                value,
            });
        }
    }
    Ok(JointSpec {
        name: joint.name.clone(),
        kind,
        parent_body,
        child_body,
        origin,
        axis,
        limits,
        effort: (lim.effort > 0.0 && lim.effort.is_finite()).then_some(lim.effort),
        velocity_limit: (lim.velocity > 0.0 && lim.velocity.is_finite()).then_some(lim.velocity),
        damping: dynamics.damping,
        friction: dynamics.friction,
    })
}

/// One link's share of its body: mass, centre of mass and inertia in the body's frame.
type MassPart = (f64, Vector3<f64>, Matrix3<f64>);
/// Link frames, mass properties per body, colliders.
type MassProperties = (Vec<LinkFrame>, Vec<BodySpec>, Vec<ColliderSpec>);

/// Mass properties and colliders per body; link frames.
fn mass_properties(
    robot: &urdf_rs::Robot,
    scanned: &Scan,
    walk: &Walk,
    path: &Path,
    options: &UrdfOptions,
    warnings: &mut Vec<String>,
) -> Result<MassProperties, ArmError> {
    let p = || path.to_path_buf();
    let Walk {
        link_body,
        body_links,
        body_top,
        ..
    } = walk;
    let mut links = Vec::with_capacity(robot.links.len());
    let mut bodies = Vec::with_capacity(body_links.len());
    let mut colliders = Vec::new();
    for (b, members) in body_links.iter().enumerate() {
        let mut parts: Vec<MassPart> = Vec::new();
        for &l in members {
            let link = &robot.links[l];
            let (_, pose) = link_body[l].expect("every link is placed");
            let has_inertial = scanned.links_with_inertial.contains(&link.name);
            let part = link_inertia(link, pose, has_inertial, path, options, warnings)?;
            let own_mass = part.map_or(0.0, |(mass, _, _)| mass);
            parts.extend(part);
            link_colliders(link, b, pose, &mut colliders, warnings);
            links.push(LinkFrame {
                name: link.name.clone(),
                body: b,
                pose,
                has_inertial,
                mass: own_mass,
            });
        }
        let (mass, com, inertia) = combine_parts(&parts);
        if b > 0 && mass <= 0.0 {
            return Err(ArmError::MasslessBody {
                path: p(),
                link: robot.links[body_top[b]].name.clone(),
            });
        }
        if b > 0 && inertia.symmetric_eigenvalues().min() <= 0.0 {
            return Err(ArmError::BadInertia {
                path: p(),
                link: robot.links[body_top[b]].name.clone(),
                reason: "has no rotational inertia: the moving body it heads (with the links \
                         fixed to it) is made of point masses alone"
                    .to_string(),
            });
        }
        bodies.push(BodySpec {
            link: robot.links[body_top[b]].name.clone(),
            mass,
            com,
            inertia,
        });
    }
    Ok((links, bodies, colliders))
}

/// A link's mass, centre of mass and inertia (rotated into its body's frame), if it has mass.
fn link_inertia(
    link: &urdf_rs::Link,
    pose: Isometry3<f64>,
    has_inertial: bool,
    path: &Path,
    options: &UrdfOptions,
    warnings: &mut Vec<String>,
) -> Result<Option<MassPart>, ArmError> {
    let p = || path.to_path_buf();
    let mass = link.inertial.mass.value;
    if has_inertial && !(mass.is_finite() && mass >= 0.0) {
        return Err(ArmError::BadMass {
            path: p(),
            link: link.name.clone(),
            mass,
        });
    }
    // A massless link (a fixed root, a flange or tool frame) adds nothing; a moving body
    // left without mass is refused below.
    if has_inertial && mass == 0.0 {
        let i = &link.inertial.inertia;
        if [i.ixx, i.iyy, i.izz, i.ixy, i.ixz, i.iyz]
            .iter()
            .any(|v| *v != 0.0)
        {
            warnings.push(format!(
                "link '{}': mass 0 with a non-zero inertia; the inertia is ignored",
                link.name
            ));
        }
    }
    if has_inertial && mass > 0.0 {
        let inertial = &link.inertial;
        let i = &inertial.inertia;
        let tensor = Matrix3::new(
            i.ixx, i.ixy, i.ixz, //
            i.ixy, i.iyy, i.iyz, //
            i.ixz, i.iyz, i.izz,
        );
        // A mass with an all-zero tensor is a point mass (maintained descriptions give tool and
        // flange frames 1e-9 kg and no inertia): its parallel-axis terms count where it merges;
        // a moving body made of point masses alone is refused below.
        let tensor = if tensor == Matrix3::zeros() {
            warnings.push(format!(
                "link '{}': mass {mass:e} kg with a zero inertia: taken as a point mass",
                link.name
            ));
            tensor
        } else {
            let (tensor, warning) =
                check_inertia(&tensor, &link.name, path, options.balance_inertia)?;
            warnings.extend(warning);
            tensor
        };
        let frame = pose * isometry(&inertial.origin);
        let rot = frame.rotation.to_rotation_matrix();
        let rotated = rot.matrix() * tensor * rot.matrix().transpose();
        return Ok(Some((mass, frame.translation.vector, rotated)));
    }
    Ok(None)
}

/// A link's collision shapes in its body's frame (meshes and degenerate shapes skipped, with a
/// warning).
fn link_colliders(
    link: &urdf_rs::Link,
    body: usize,
    pose: Isometry3<f64>,
    colliders: &mut Vec<ColliderSpec>,
    warnings: &mut Vec<String>,
) {
    for collision in &link.collision {
        let shape_pose = pose * isometry(&collision.origin);
        let shape = match &collision.geometry {
            urdf_rs::Geometry::Box { size } => ShapeSpec::Box {
                half_extents: Vector3::from(size.0) / 2.0,
            },
            urdf_rs::Geometry::Cylinder { radius, length } => ShapeSpec::Cylinder {
                radius: *radius,
                length: *length,
            },
            urdf_rs::Geometry::Capsule { radius, length } => ShapeSpec::Capsule {
                radius: *radius,
                length: *length,
            },
            urdf_rs::Geometry::Sphere { radius } => ShapeSpec::Sphere { radius: *radius },
            urdf_rs::Geometry::Mesh { filename, .. } => {
                warnings.push(format!(
                    "link '{}': collision mesh {:?} skipped (meshes are not loaded; \
                     the camera will not see this shape occlude)",
                    link.name,
                    sanitize_mesh_name(filename)
                ));
                continue;
            }
        };
        let degenerate = match shape {
            ShapeSpec::Box { half_extents } => half_extents.min() <= 0.0,
            ShapeSpec::Cylinder { radius, length } | ShapeSpec::Capsule { radius, length } => {
                radius <= 0.0 || length < 0.0
            }
            ShapeSpec::Sphere { radius } => radius <= 0.0,
        };
        if degenerate {
            warnings.push(format!(
                "link '{}': degenerate collision shape skipped",
                link.name
            ));
            continue;
        }
        colliders.push(ColliderSpec::new(
            link.name.clone(),
            body,
            shape,
            shape_pose,
        ));
    }
}

/// The mesh file name as it may be shown: never resolved against the file system, so a
/// `package://` or absolute path cannot make aift read outside the URDF's folder.
fn sanitize_mesh_name(filename: &str) -> String {
    filename
        .chars()
        .filter(|c| !c.is_control())
        .take(200)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ArmModel, ArmError> {
        parse_urdf(text, Path::new("test.urdf"))
    }

    const TWO_LINK: &str = r#"<robot name="r">
      <link name="world"/>
      <joint name="j1" type="continuous">
        <parent link="world"/><child link="l1"/><axis xyz="0 -1 0"/>
      </joint>
      <link name="l1">
        <inertial><origin xyz="0.5 0 0"/><mass value="2"/>
          <inertia ixx="0.01" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>
        <collision><origin xyz="0.5 0 0"/><geometry><box size="1 0.1 0.1"/></geometry></collision>
      </link>
      <joint name="tip" type="fixed"><origin xyz="1 0 0"/><parent link="l1"/><child link="ee"/></joint>
      <link name="ee"/>
    </robot>"#;

    #[test]
    fn merges_fixed_links_and_keeps_their_frames() {
        let m = parse(TWO_LINK).unwrap();
        assert_eq!(m.bodies.len(), 2);
        assert_eq!(m.joints.len(), 1);
        let ee = m.link("ee").unwrap();
        assert_eq!(ee.body, 1);
        assert!((ee.pose.translation.vector - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-15);
        assert!((m.bodies[1].mass - 2.0).abs() < 1e-15);
        assert_eq!(m.colliders.iter().filter(|c| c.body == 1).count(), 1);
    }

    #[test]
    fn rotated_inertial_frame_rotates_the_tensor() {
        let text = TWO_LINK.replace(
            r#"<origin xyz="0.5 0 0"/><mass"#,
            r#"<origin xyz="0.5 0 0" rpy="0 0 1.5707963267948966"/><mass"#,
        );
        let m = parse(&text).unwrap();
        let i = m.bodies[1].inertia;
        // A quarter turn about z swaps ixx and iyy.
        assert!((i[(0, 0)] - 1.0).abs() < 1e-12, "{i}");
        assert!((i[(1, 1)] - 0.01).abs() < 1e-12, "{i}");
    }

    #[test]
    fn check_numbers_counts_and_rejects_non_finite() {
        assert!(check_numbers("1 2 3", 3).is_ok());
        assert!(check_numbers("1 2", 3).is_err());
        assert!(check_numbers("nan", 1).is_err());
        assert!(check_numbers("inf", 1).is_err());
        assert!(check_numbers("1e3", 1).is_ok());
    }
}
