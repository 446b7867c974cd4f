//! Every malformed-URDF kind gives its typed error naming the file; nothing panics.

mod common;

use std::path::Path;

use aift::arm::{ArmError as PlantError, EndEffector, UrdfOptions, parse_urdf, parse_urdf_with};
use aift::plant::PlantSettings;
use proptest::prelude::*;

fn parse(text: &str) -> Result<aift::arm::ArmModel, PlantError> {
    parse_urdf(text, Path::new("bad.urdf"))
}

/// A valid two-joint arm; tests break one thing in it.
fn arm(links: &str, joints: &str) -> String {
    format!("<robot name=\"t\">{links}{joints}</robot>")
}

const WORLD: &str = r#"<link name="world"/>"#;

fn link(name: &str) -> String {
    format!(
        r#"<link name="{name}"><inertial><origin xyz="0.5 0 0"/><mass value="1"/>
        <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>"#
    )
}

fn joint(name: &str, kind: &str, parent: &str, child: &str) -> String {
    format!(
        r#"<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>
        <origin xyz="1 0 0"/><axis xyz="0 -1 0"/><limit lower="-1" upper="1" effort="10" velocity="1"/></joint>"#
    )
}

fn good() -> String {
    arm(
        &format!("{WORLD}{}{}", link("a"), link("b")),
        &format!(
            "{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j2", "continuous", "a", "b")
        ),
    )
}

#[test]
fn the_base_arm_is_valid() {
    let m = parse(&good()).unwrap();
    assert_eq!(m.joints.len(), 2);
}

macro_rules! assert_err {
    ($result:expr, $pattern:pat) => {
        match $result {
            Err(e @ $pattern) => {
                let msg = e.to_string();
                assert!(
                    msg.contains("bad.urdf") || msg.contains(".urdf"),
                    "message names the file: {msg}"
                );
                eprintln!("{msg}");
            }
            other => panic!(
                "expected {}, got {:?}",
                stringify!($pattern),
                other.map(|m| m.name)
            ),
        }
    };
}

#[test]
fn unreadable_file() {
    let r = aift::arm::load_urdf(Path::new("/nonexistent/arm.urdf"));
    assert!(matches!(r, Err(PlantError::Unreadable { .. })));
}

#[test]
fn empty_file() {
    assert_err!(parse(""), PlantError::Empty { .. });
    assert_err!(parse("  \n "), PlantError::Empty { .. });
}

#[test]
fn binary_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bin.urdf");
    std::fs::write(&path, [0u8, 159, 146, 150, 255, 0, 1, 2]).unwrap();
    assert!(matches!(
        aift::arm::load_urdf(&path),
        Err(PlantError::NotText { .. })
    ));
    assert_err!(parse("<robot>\0</robot>"), PlantError::NotText { .. });
}

#[test]
fn deeply_nested_file_is_refused_before_the_parser_sees_it() {
    let depth = 50_000;
    let text = format!(
        "<robot>{}{}</robot>",
        "<a>".repeat(depth),
        "</a>".repeat(depth)
    );
    assert_err!(parse(&text), PlantError::TooDeep { .. });
}

#[test]
fn xml_errors() {
    assert_err!(
        parse("<robot><link name=\"a\"></robot>"),
        PlantError::Xml { .. }
    );
    assert_err!(parse("not xml at all"), PlantError::Xml { .. });
    assert_err!(parse("<notrobot/>"), PlantError::Xml { .. });
}

#[test]
fn bad_numbers_name_the_element_and_attribute() {
    for (from, to) in [
        (r#"<mass value="1"/>"#, r#"<mass value="one"/>"#),
        (r#"<mass value="1"/>"#, r#"<mass value="nan"/>"#),
        (r#"ixx="0.01""#, r#"ixx="1e""#),
        (r#"<origin xyz="1 0 0"/>"#, r#"<origin xyz="1 0"/>"#),
        (r#"<axis xyz="0 -1 0"/>"#, r#"<axis xyz="0 -1 inf"/>"#),
    ] {
        let text = good().replacen(from, to, 1);
        match parse(&text) {
            Err(PlantError::BadNumber {
                element, attribute, ..
            }) => {
                eprintln!("{element} {attribute}");
                assert!(element.contains("link '") || element.contains("joint '"));
            }
            other => panic!("{to}: expected BadNumber, got {:?}", other.map(|m| m.name)),
        }
    }
}

#[test]
fn unknown_link_in_a_joint() {
    let text = arm(
        &format!("{WORLD}{}", link("a")),
        &joint("j1", "revolute", "world", "nope"),
    );
    assert_err!(parse(&text), PlantError::UnknownLink { .. });
}

#[test]
fn duplicate_names() {
    let text = arm(
        &format!("{WORLD}{}{}", link("a"), link("a")),
        &joint("j1", "revolute", "world", "a"),
    );
    assert_err!(parse(&text), PlantError::DuplicateName { kind: "link", .. });
    let text = arm(
        &format!("{WORLD}{}{}", link("a"), link("b")),
        &format!(
            "{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j1", "revolute", "a", "b")
        ),
    );
    assert_err!(
        parse(&text),
        PlantError::DuplicateName { kind: "joint", .. }
    );
}

#[test]
fn no_single_root() {
    let text = arm(
        &format!("{WORLD}{}{}{}", link("a"), link("b"), link("c")),
        &format!(
            "{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j2", "revolute", "b", "c")
        ),
    );
    assert_err!(parse(&text), PlantError::NoSingleRoot { .. });
}

#[test]
fn cycles() {
    let text = arm(
        &format!("{WORLD}{}{}", link("a"), link("b")),
        &format!(
            "{}{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j2", "revolute", "b", "b"),
            ""
        ),
    );
    assert_err!(parse(&text), PlantError::Cycle { .. });
    // a -> b -> a hanging off nothing, beside a proper root.
    let text = arm(
        &format!("{WORLD}{}{}{}", link("a"), link("b"), link("c")),
        &format!(
            "{}{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j2", "revolute", "b", "c"),
            joint("j3", "revolute", "c", "b")
        ),
    );
    assert_err!(parse(&text), PlantError::Cycle { .. });
}

#[test]
fn a_link_not_connected() {
    let text = arm(
        &format!("{WORLD}{}{}", link("a"), link("lonely")),
        &joint("j1", "revolute", "world", "a"),
    );
    assert_err!(parse(&text), PlantError::Disconnected { .. });
}

#[test]
fn a_link_with_two_parents() {
    let text = arm(
        &format!("{WORLD}{}{}", link("a"), link("b")),
        &format!(
            "{}{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("j2", "revolute", "world", "b"),
            joint("j3", "revolute", "a", "b")
        ),
    );
    assert_err!(parse(&text), PlantError::MultipleParents { .. });
}

#[test]
fn bad_masses() {
    let with_mass = |mass: &str| {
        good().replacen(
            r#"<mass value="1"/>"#,
            &format!(r#"<mass value="{mass}"/>"#),
            1,
        )
    };
    assert_err!(parse(&with_mass("-1")), PlantError::BadMass { .. });
    // Zero mass on a moving body that nothing else gives mass: still refused.
    assert_err!(parse(&with_mass("0")), PlantError::MasslessBody { .. });
}

/// Common URDFs of industrial arms give the fixed base and the flange `<mass value="0"/>`:
/// accepted, as MuJoCo accepts them.
#[test]
fn zero_mass_fixed_root_and_flange_load() {
    let massless = |name: &str| {
        format!(
            r#"<link name="{name}"><inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>"#
        )
    };
    let text = arm(
        &format!(
            "{}{}{}{}",
            massless("base"),
            link("a"),
            link("b"),
            massless("flange")
        ),
        &format!(
            "{}{}{}",
            joint("j1", "revolute", "base", "a"),
            joint("j2", "revolute", "a", "b"),
            joint("f", "fixed", "b", "flange")
        ),
    );
    let m = parse(&text).unwrap();
    assert_eq!(m.joints.len(), 2);
    assert_eq!(m.bodies[0].mass, 0.0);
    assert!(
        (m.bodies[2].mass - 1.0).abs() < 1e-15,
        "the flange adds nothing"
    );
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    let ee = EndEffector::new(&m, "flange", [0.0; 3]).unwrap();
    let arm = aift::plant::build(m.into(), [0.0, 0.0, -9.81], &PlantSettings::default()).unwrap();
    assert!((arm.ee_position(&ee).x - 3.0).abs() < 1e-12);
}

#[test]
fn a_massless_link_with_an_inertia_is_warned_about() {
    let text = good().replacen(
        r#"<link name="world"/>"#,
        r#"<link name="world"><inertial><mass value="0"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>"#,
        1,
    );
    let m = parse(&text).unwrap();
    assert!(
        m.warnings.iter().any(|w| w.contains("world")),
        "{:?}",
        m.warnings
    );
}

/// A maintained description's tool frame: 1e-9 kg and an all-zero inertia on a fixed joint. It is
/// a point mass merged into the body it is fixed to (a warning names it); a moving body of point
/// masses alone has no rotational inertia and is refused, naming its link.
#[test]
fn a_point_mass_frame_merges_and_a_moving_point_mass_is_refused() {
    let frame = r#"<link name="flange"><inertial><origin xyz="0.2 0 0"/><mass value="1e-9"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>"#;
    let fixed = r#"<joint name="jf" type="fixed"><parent link="b"/><child link="flange"/><origin xyz="1 0 0"/></joint>"#;
    let text = good().replacen("</robot>", &format!("{frame}{fixed}</robot>"), 1);
    let m = parse(&text).unwrap();
    let plain = parse(&good()).unwrap();
    assert_eq!(m.joints.len(), 2);
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("flange") && w.contains("point mass")),
        "{:?}",
        m.warnings
    );
    assert!((m.bodies[2].mass - plain.bodies[2].mass - 1e-9).abs() < 1e-15);
    // The same point mass as a moving link of its own.
    let moving = good().replacen(
        r#"<mass value="1"/>
        <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>"#,
        r#"<mass value="1e-9"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>"#,
        1,
    );
    assert_ne!(moving, good(), "the test edits the first link");
    match parse(&moving) {
        Err(e @ PlantError::BadInertia { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("'a'") && msg.contains("point masses"), "{msg}");
        }
        other => panic!("expected BadInertia, got {:?}", other.map(|m| m.name)),
    }
}

/// The triangle inequality: refused with a message naming the option; with the option, the
/// middle principal moment is raised just enough and the link is named in a warning.
#[test]
fn balance_inertia_repairs_the_triangle_inequality_just_enough() {
    let triangle = good().replacen(r#"iyy="0.1""#, r#"iyy="0.5""#, 1);
    match parse(&triangle) {
        Err(PlantError::BadInertia { reason, .. }) => {
            assert!(reason.contains("balance_inertia"), "{reason}")
        }
        other => panic!("{:?}", other.map(|m| m.name)),
    }
    let m = parse_urdf_with(
        &triangle,
        Path::new("bad.urdf"),
        &UrdfOptions {
            balance_inertia: true,
        },
    )
    .unwrap();
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("link 'a'") && w.contains("balanced"))
    );
    // Moments were (0.01, 0.1, 0.5): the middle one becomes 0.5 - 0.01 = 0.49.
    let i = m.bodies[1].inertia;
    let mut e: Vec<f64> = i.symmetric_eigen().eigenvalues.iter().copied().collect();
    e.sort_by(f64::total_cmp);
    assert!(
        (e[0] - 0.01).abs() < 1e-12 && (e[1] - 0.49).abs() < 1e-12 && (e[2] - 0.5).abs() < 1e-12,
        "{e:?}"
    );
    // A valid tensor is left exactly as it was.
    let ok = parse_urdf_with(
        &good(),
        Path::new("good.urdf"),
        &UrdfOptions {
            balance_inertia: true,
        },
    )
    .unwrap();
    assert_eq!(
        ok.bodies[1].inertia,
        parse(&good()).unwrap().bodies[1].inertia
    );
}

#[test]
fn negative_dynamics_and_limits_are_refused() {
    for (from, to, attribute) in [
        (
            "<axis xyz=\"0 -1 0\"/>",
            "<axis xyz=\"0 -1 0\"/><dynamics damping=\"-0.5\"/>",
            "damping",
        ),
        (
            "<axis xyz=\"0 -1 0\"/>",
            "<axis xyz=\"0 -1 0\"/><dynamics friction=\"-1\"/>",
            "friction",
        ),
        ("effort=\"10\"", "effort=\"-10\"", "effort"),
        ("velocity=\"1\"", "velocity=\"-1\"", "velocity"),
    ] {
        let text = good().replacen(from, to, 1);
        match parse(&text) {
            Err(e @ PlantError::Negative { .. }) => {
                assert!(e.to_string().contains(attribute), "{e}");
                assert!(e.to_string().contains("j1"), "{e}");
            }
            other => panic!("{attribute}: {:?}", other.map(|m| m.name)),
        }
    }
}

#[test]
fn a_second_robot_element_is_refused() {
    let text = format!("{}{}", good(), good());
    assert_err!(parse(&text), PlantError::Xml { .. });
}

#[test]
fn bad_inertia() {
    let not_pd = good().replacen(r#"ixx="0.01""#, r#"ixx="-0.01""#, 1);
    assert_err!(parse(&not_pd), PlantError::BadInertia { .. });
    let zero = good().replacen(r#"ixx="0.01""#, r#"ixx="0""#, 1);
    assert_err!(parse(&zero), PlantError::BadInertia { .. });
    let triangle = good().replacen(r#"iyy="0.1""#, r#"iyy="0.5""#, 1);
    match parse(&triangle) {
        Err(PlantError::BadInertia { reason, .. }) => {
            assert!(reason.contains("triangle"), "{reason}")
        }
        other => panic!(
            "expected a triangle-inequality error, got {:?}",
            other.map(|m| m.name)
        ),
    }
}

#[test]
fn zero_axis() {
    let text = good().replacen(r#"<axis xyz="0 -1 0"/>"#, r#"<axis xyz="0 0 0"/>"#, 1);
    assert_err!(parse(&text), PlantError::ZeroAxis { .. });
}

#[test]
fn inverted_limits() {
    let text = good().replacen(r#"lower="-1" upper="1""#, r#"lower="1" upper="-1""#, 1);
    assert_err!(parse(&text), PlantError::BadLimit { .. });
}

#[test]
fn no_movable_joint() {
    let text = arm(
        &format!("{WORLD}{}", link("a")),
        &joint("j1", "fixed", "world", "a"),
    );
    assert_err!(parse(&text), PlantError::NoMovableJoint { .. });
}

#[test]
fn unsupported_joint_kind_names_the_joint() {
    let text = arm(
        &format!("{WORLD}{}", link("a")),
        &joint("free_base", "floating", "world", "a"),
    );
    match parse(&text) {
        Err(PlantError::UnsupportedJoint { joint, kind, .. }) => {
            assert_eq!(joint, "free_base");
            assert_eq!(kind, "floating");
        }
        other => panic!("{:?}", other.map(|m| m.name)),
    }
}

#[test]
fn massless_moving_body() {
    let text = arm(
        r#"<link name="world"/><link name="ghost"/>"#,
        &joint("j1", "revolute", "world", "ghost"),
    );
    assert_err!(parse(&text), PlantError::MasslessBody { .. });
}

#[test]
fn massless_tip_merged_by_a_fixed_joint_is_fine_and_can_be_the_end_effector() {
    let text = arm(
        &format!(r#"{WORLD}{}<link name="tip"/>"#, link("a")),
        &format!(
            "{}{}",
            joint("j1", "revolute", "world", "a"),
            joint("tipj", "fixed", "a", "tip")
        ),
    );
    let model = parse(&text).unwrap();
    let ee = EndEffector::new(&model, "tip", [0.0; 3]).unwrap();
    let arm =
        aift::plant::build(model.into(), [0.0, 0.0, -9.81], &PlantSettings::default()).unwrap();
    let p = arm.ee_position(&ee);
    assert!((p.x - 2.0).abs() < 1e-12, "{p}");
}

#[test]
fn unknown_end_effector() {
    let model = parse(&good()).unwrap();
    let r = EndEffector::new(&model, "hand", [0.0; 3]);
    assert!(matches!(r, Err(PlantError::UnknownEndEffector { .. })));
}

#[test]
fn meshes_are_skipped_with_a_warning_and_never_resolved() {
    for file in [
        "package://evil/../../../etc/passwd",
        "/etc/shadow",
        "../../x.stl",
    ] {
        let text = good().replacen(
            "</inertial></link>",
            &format!(
                r#"</inertial><collision><geometry><mesh filename="{file}"/></geometry></collision></link>"#
            ),
            1,
        );
        let m = parse(&text).unwrap();
        assert!(
            m.warnings.iter().any(|w| w.contains("mesh")),
            "{:?}",
            m.warnings
        );
    }
}

#[test]
fn bundled_urdfs_are_valid() {
    for file in [
        "urdf/planar_2dof.urdf",
        "urdf/planar_2dof_undamped.urdf",
        "urdf/planar_3dof.urdf",
        "urdf/spatial_3dof.urdf",
        "urdf/spatial_3dof_lowdamp.urdf",
        "urdf/panda_7dof.urdf",
    ] {
        let m = aift::arm::load_urdf(&common::repo(file)).unwrap();
        assert!(m.warnings.is_empty(), "{file}: {:?}", m.warnings);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, .. ProptestConfig::default() })]

    /// Random edits of a valid file: the loader returns Ok or Err, never panics.
    #[test]
    fn mutated_files_never_panic(
        edits in prop::collection::vec((0usize..4000, 0u8..4, prop::sample::select(
            vec!['<', '>', '"', '/', '0', '-', 'e', ' ', 'x', '=', '1', '.'])), 1..6)
    ) {
        let mut text: Vec<char> = std::fs::read_to_string(common::repo("urdf/planar_2dof.urdf"))
            .unwrap()
            .chars()
            .collect();
        for (pos, op, ch) in edits {
            if text.is_empty() { break; }
            let pos = pos % text.len();
            match op {
                0 => { text.remove(pos); }
                1 => text.insert(pos, ch),
                2 => text[pos] = ch,
                _ => text.truncate(pos),
            }
        }
        let text: String = text.into_iter().collect();
        if let Ok(model) = parse(&text) {
            // Whatever loads must also build, on both engines.
            let model = std::sync::Arc::new(model);
            for engine in [aift::plant::Engine::Rapier, aift::plant::Engine::Articulated] {
                let settings = PlantSettings { engine, ..Default::default() };
                let _ = aift::plant::build(model.clone(), [0.0, 0.0, -9.81], &settings);
            }
        }
    }
}

/// A joint type URDF does not define is refused naming the joint and its line (not the
/// parser's bare "unknown variant"); a missing type too.
#[test]
fn an_unknown_joint_type_names_the_joint() {
    let text = good().replace(
        r#"name="j2" type="continuous""#,
        r#"name="j2" type="revolut""#,
    );
    match parse(&text) {
        Err(e @ PlantError::Xml { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("joint 'j2'") && msg.contains("`revolut`"),
                "{msg}"
            );
            assert!(
                msg.contains("line ") && msg.contains("revolute, continuous"),
                "{msg}"
            );
        }
        other => panic!("expected an XML error, got {:?}", other.map(|m| m.name)),
    }
    let text = good().replace(r#"name="j1" type="revolute""#, r#"name="j1""#);
    let msg = parse(&text).unwrap_err().to_string();
    assert!(
        msg.contains("joint 'j1'") && msg.contains("no `type`"),
        "{msg}"
    );
}

/// Typos that urdf-rs passes over in silence, and that change the arm (the axis or a limit
/// takes its default), are warned about naming the joint or link, the element and the line;
/// so is a `<limit>` without the effort or velocity URDF requires. A valid file draws none.
#[test]
fn typos_that_change_the_arm_are_warned_about() {
    assert!(parse(&good()).unwrap().warnings.is_empty());
    let warned = |from: &str, to: &str, expect: &[&str]| {
        let text = good().replacen(from, to, 1);
        assert_ne!(text, good(), "{from}");
        let m = parse(&text).unwrap();
        assert!(
            m.warnings
                .iter()
                .any(|w| expect.iter().all(|e| w.contains(e))),
            "{from} -> {to}: {:?}",
            m.warnings
        );
    };
    warned(
        r#"effort="10""#,
        r#"efort="10""#,
        &["joint 'j1'", "`efort`", "not URDF 1.0's"],
    );
    warned(
        r#"effort="10""#,
        r#"efort="10""#,
        &["joint 'j1'", "<limit>", "no `effort`", "no effort limit"],
    );
    // An explicit zero effort is read as no limit, and said so.
    warned(
        r#"effort="10""#,
        r#"effort="0""#,
        &["joint 'j1'", "<limit>", "effort=\"0\"", "no effort limit"],
    );
    let typo = good().replacen("<axis", "<axsi", 1);
    let line = 1 + typo[..typo.find("<axsi").unwrap()].matches('\n').count();
    warned(
        "<axis",
        "<axsi",
        &[
            "joint 'j1'",
            "element <axsi>",
            &format!("(line {line})"),
            "ignored",
        ],
    );
    warned(
        r#"<origin xyz="1 0 0"/>"#,
        r#"<origin xyz="1 0 0" rpz="0 0 1"/>"#,
        &["joint 'j1'", "`rpz`", "<origin>"],
    );
    // An attribute URDF requires, missing (the parser's own message names no link): an error
    // naming the link or joint, the element and the line.
    for (from, to, expect) in [
        (
            r#"<mass value="1"/>"#,
            r#"<mass valeu="1"/>"#,
            ["link 'a'", "<mass>", "`value`"],
        ),
        (
            r#"ixy="0""#,
            r#"ixyy="0""#,
            ["link 'a'", "<inertia>", "`ixy`"],
        ),
        (
            r#"<child link="b"/>"#,
            r#"<child lnk="b"/>"#,
            ["joint 'j2'", "<child>", "`link`"],
        ),
        (
            r#"velocity="1""#,
            r#"velocty="1""#,
            ["joint 'j1'", "<limit>", "`velocity`"],
        ),
    ] {
        let text = good().replacen(from, to, 1);
        assert_ne!(text, good(), "{from}");
        match parse(&text) {
            Err(e @ PlantError::Xml { .. }) => {
                let msg = e.to_string();
                assert!(expect.iter().all(|x| msg.contains(x)), "{msg}");
                assert!(msg.contains("(line ") && msg.contains("bad.urdf"), "{msg}");
            }
            other => panic!(
                "{to}: expected an XML error, got {:?}",
                other.map(|m| m.name)
            ),
        }
    }
    // Extensions outside links and joints (a transmission naming a joint) are not URDF's
    // link or joint elements and draw nothing.
    let text = good().replace(
        "</robot>",
        r#"<transmission name="t1"><joint name="j1"><hardwareInterface>x</hardwareInterface></joint></transmission><gazebo reference="a"><mu1>0.2</mu1></gazebo></robot>"#,
    );
    assert!(parse(&text).unwrap().warnings.is_empty());
}

/// What later URDF versions define is not warned about in files of those versions
/// (`quat_xyzw` from 1.1; a limit's `acceleration`, `deceleration`, `jerk` from 1.2, where an
/// omitted effort or velocity means no limit), nor are namespaced extensions; in a 1.0 file the
/// newer attributes are warned about (urdf-rs ignores them there). Warnings are bounded: a
/// file full of unknown attributes draws at most 20 and a count of the rest.
#[test]
fn later_urdf_versions_and_extensions_are_not_typos_and_warnings_are_bounded() {
    let v12 = good()
        .replacen(
            r#"<robot name="t">"#,
            r#"<robot name="t" version="1.2" xmlns:drake="http://drake.mit.edu">"#,
            1,
        )
        .replacen(
            r#"effort="10" velocity="1""#,
            r#"acceleration="5" jerk="100""#,
            1,
        )
        .replacen(
            r#"<origin xyz="1 0 0"/>"#,
            r#"<origin xyz="1 0 0" quat_xyzw="0 0 0 1"/>"#,
            1,
        )
        .replacen(
            r#"<axis xyz="0 -1 0"/>"#,
            r#"<axis xyz="0 -1 0" drake:acc="1"/>"#,
            1,
        );
    let m = parse(&v12).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    let v10 = good().replacen(
        r#"effort="10" velocity="1""#,
        r#"effort="10" velocity="1" jerk="100""#,
        1,
    );
    let m = parse(&v10).unwrap();
    assert!(
        m.warnings
            .iter()
            .any(|w| w.contains("`jerk`") && w.contains("not URDF 1.0's")),
        "{:?}",
        m.warnings
    );
    let many: String = (0..30).map(|i| format!(" x{i}=\"1\"")).collect();
    let noisy = good().replacen(
        r#"<mass value="1"/>"#,
        &format!(r#"<mass value="1"{many}/>"#),
        1,
    );
    let m = parse(&noisy).unwrap();
    assert_eq!(m.warnings.len(), 21, "{:?}", m.warnings);
    assert!(m.warnings[20].contains("10 more"), "{:?}", m.warnings[20]);
}

/// A xacro template is refused with the line of its first macro and how to expand it; the same
/// markup inside a comment (an expanded URDF naming its source) is not.
#[test]
fn xacro_templates_are_refused_with_a_hint_and_comments_are_not() {
    let template = good().replacen(
        "<link name=\"world\"/>",
        "<link name=\"world\"/>\n<xacro:include filename=\"$(find arm)/a.xacro\"/>",
        1,
    );
    match parse(&template) {
        Err(e @ PlantError::Xacro { line: 2, .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("bad.urdf") && msg.contains("xacro:include"),
                "{msg}"
            );
            assert!(msg.contains("xacro bad.urdf > arm.urdf"), "{msg}");
        }
        other => panic!(
            "expected a xacro error on line 2, got {:?}",
            other.map(|m| m.name)
        ),
    }
    let expression = good().replacen("value=\"1\"", "value=\"${mass}\"", 1);
    assert_err!(parse(&expression), PlantError::Xacro { .. });
    let commented = format!(
        "<!-- generated by xacro from $(find arm)/urdf/arm.urdf.xacro with ${{prefix}} -->\n{}",
        good()
    );
    assert_eq!(parse(&commented).unwrap().joints.len(), 2);
    let unclosed = format!("{}<!-- ${{x}}", good());
    assert!(!matches!(parse(&unclosed), Err(PlantError::Xacro { .. })));
}

/// A chain of `n` revolute joints.
fn chain(n: usize) -> String {
    let mut links = String::from(WORLD);
    let mut joints = String::new();
    let mut parent = "world".to_string();
    for i in 0..n {
        let child = format!("l{i}");
        links.push_str(&link(&child));
        joints.push_str(&joint(&format!("j{i}"), "revolute", &parent, &child));
        parent = child;
    }
    arm(&links, &joints)
}

/// The joint count is bounded (a 20 000-joint chain once asked the articulated engine for
/// gigabytes): 64 loads, 65 is refused naming the count and the bound.
#[test]
fn more_joints_than_the_bound_are_refused() {
    let limit = aift::arm::urdf::MAX_JOINTS;
    assert_eq!(parse(&chain(limit)).unwrap().joints.len(), limit);
    match parse(&chain(limit + 1)) {
        Err(e @ PlantError::TooManyJoints { .. }) => {
            let text = e.to_string();
            assert!(text.contains("bad.urdf"), "{text}");
            assert!(
                text.contains(&format!("{} movable joints", limit + 1)),
                "{text}"
            );
            assert!(text.contains(&format!("more than {limit}")), "{text}");
        }
        other => panic!("expected TooManyJoints, got {other:?}"),
    }
}
