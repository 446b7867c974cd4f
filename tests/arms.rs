//! The arms people have: every bundled arm (the paper's, the paper's without damping, the planar
//! and spatial 3-DOF arms, the low-damping spatial arm, the Panda 7-DOF) reaches its targets under
//! every method when healthy; `pl-always` recovers an encoder freeze on each; the oracle recovers a
//! tachometer freeze on each; and `aift init` writes, for each bundled URDF, a scenario whose
//! healthy run reaches its targets under every method.

mod common;

use std::collections::BTreeMap;

use aift::scenario::calibrate::calibrate;
use aift::scenario::table::run_table;
use aift::scenario::{LoadedScenario, Method, RunSetup};
use aift::sensors::{FaultKind, FaultSpec};

/// Each bundled arm's encoder-freeze scenario and the joint its faults go on.
const ARMS: [(&str, &str); 6] = [
    ("paper_encoder_freeze.toml", "1"),
    ("undamped2_encoder_freeze.toml", "1"),
    ("planar3_encoder_freeze.toml", "1"),
    ("spatial3_encoder_freeze.toml", "1"),
    ("spatial3low_encoder_freeze.toml", "1"),
    ("panda_encoder_freeze.toml", "2"),
];

/// The same setup (arm, GP) with other faults.
fn with_faults(setup: &RunSetup, faults: Vec<FaultSpec>) -> RunSetup {
    let mut s = setup.clone();
    s.faults = faults
        .iter()
        .map(|f| f.to_fault(&s.layout, s.scenario().dt).unwrap())
        .collect();
    s.loaded.scenario.faults = faults;
    s
}

fn freeze(channel: &str) -> FaultSpec {
    FaultSpec {
        channel: channel.into(),
        start: 8.0,
        end: None,
        kind: FaultKind::Freeze {},
    }
}

/// Runs every method once (seed 1) and returns (method, final error, outcome).
fn every_method(setup: &RunSetup) -> Vec<(String, f64, String)> {
    let cal = calibrate(setup, 10).expect("calibration");
    let table = run_table(setup, &Method::ALL, &[1], Some(&cal), &|| {}).expect("runs");
    table
        .runs
        .iter()
        .map(|r| {
            (
                r.method.clone(),
                r.max_final_error,
                r.outcome.name().to_string(),
            )
        })
        .collect()
}

#[test]
fn every_bundled_arm_reaches_its_targets_under_every_method_recovers_an_encoder_freeze_and_the_oracle_a_tachometer_freeze()
 {
    let mut failures = Vec::new();
    for (file, joint) in ARMS {
        let base = common::setup(file, &[]);
        let healthy = with_faults(&base, vec![]);
        for (method, error, outcome) in every_method(&healthy) {
            eprintln!("{file} healthy {method}: final error {error:.2e} ({outcome})");
            if error.is_nan() || error > 0.01 || outcome != "completed" {
                failures.push(format!("{file} healthy {method}: {error}"));
            }
        }
        let enc = with_faults(&base, vec![freeze(&format!("enc{joint}"))]);
        let (r, _) = common::run_recorded(&enc, Method::PlAlways, 1, None);
        eprintln!(
            "{file} enc{joint} freeze pl-always: final error {:.2e}, faulty MSE {:.2e}",
            r.max_final_error,
            r.mse_faulty.unwrap()
        );
        if r.max_final_error.is_nan() || r.max_final_error > 0.02 {
            failures.push(format!("{file} encoder freeze: {}", r.max_final_error));
        }
        let tach = with_faults(&base, vec![freeze(&format!("tach{joint}"))]);
        let (r, _) = common::run_recorded(&tach, Method::Oracle, 1, None);
        eprintln!(
            "{file} tach{joint} freeze oracle: final error {:.2e}, faulty MSE {:.2e}",
            r.max_final_error,
            r.mse_faulty.unwrap()
        );
        if r.max_final_error.is_nan() || r.max_final_error > 0.02 || r.mse_faulty.unwrap() > 1e-5 {
            failures.push(format!("{file} tachometer freeze oracle: {r:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn init_writes_a_scenario_that_reaches_its_targets_under_every_method() {
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for urdf in [
        "planar_2dof",
        "planar_2dof_undamped",
        "planar_3dof",
        "spatial_3dof",
        "spatial_3dof_lowdamp",
        "panda_7dof",
    ] {
        let out = tmp.path().join(format!("{urdf}.toml"));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_aift"))
            .args(["init", "--urdf"])
            .arg(common::repo(&format!("urdf/{urdf}.urdf")))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{urdf}: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(
            text.contains("# PID from the largest row sum of |M|"),
            "{text}"
        );
        // The fault example that closes the file, uncommented, is a valid fault for this arm.
        let example: String = text
            .lines()
            .skip_while(|l| *l != "# [[faults]]")
            .map(|l| format!("{}\n", l.trim_start_matches("# ")))
            .collect();
        assert!(example.starts_with("[[faults]]\n"), "{text}");
        let faulted = tmp.path().join(format!("{urdf}_fault.toml"));
        std::fs::write(&faulted, format!("{text}{example}")).unwrap();
        let loaded = LoadedScenario::from_file(&faulted, &[]).unwrap();
        assert_eq!(loaded.scenario.faults.len(), 1, "{urdf}");
        let setup = RunSetup::prepare(LoadedScenario::from_file(&out, &[]).unwrap()).unwrap();
        for (method, error, outcome) in every_method(&setup) {
            eprintln!("init {urdf} {method}: final error {error:.2e} ({outcome})");
            if error.is_nan() || error > 0.01 || outcome != "completed" {
                failures.push(format!("init {urdf} {method}: {error}"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// An arm from outside the project: a Kinova Jaco2 (`tests/data/kinova_j2s6s200.urdf`, no joint
/// damping, wrist joints of 1e-3 kg m^2 under a 1.5 kg m^2 shoulder, three continuous joints, a
/// gripper). `aift init`'s gains hold it: without fault tolerance it ends within 0.01 rad of its
/// targets on the articulated engine (the diagonal-inertia rule of 2026-12-01 left the wrist
/// 0.42 rad off; the row-sum rule without the discrete-time limits reached them but chattered at
/// the tick rate, which ends a run `chattering`), and the end effector goes on the link named
/// as one, not on a finger.
#[test]
fn init_gains_hold_a_light_wristed_arm_from_outside_the_project() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("jaco2.toml");
    let o = common::aift_ok(
        &[
            "init",
            "--urdf",
            common::repo("tests/data/kinova_j2s6s200.urdf")
                .to_str()
                .unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        tmp.path(),
    );
    assert!(o.status.success());
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(
        text.contains("ee_link = \"j2s6s200_end_effector\""),
        "{text}"
    );
    let loaded = LoadedScenario::from_file(&out, &["plant.engine=\"articulated\"".into()]).unwrap();
    let setup = RunSetup::prepare(loaded).unwrap();
    let (r, _) = common::run_recorded(&setup, Method::NoFt, 1, None);
    eprintln!("jaco2 no-ft: final error {:?}", r.final_error_per_joint);
    assert_eq!(r.outcome.name(), "completed");
    assert!(r.max_final_error < 0.01, "{:?}", r.final_error_per_joint);
}

/// `init` keeps its gains stable in discrete time (src/scenario/init.rs, "Discrete-time
/// limits"): a light roll joint whose centre of mass sits 0.5 mm off its axis, 0.6 m out on a
/// heavy pitch joint (`tests/data/coaxial_wrist.urdf`), moves about 3.5e-7 kg m^2, while its
/// row of the mass matrix couples to the shoulder; gains from that row alone chattered at the
/// tick rate (kd dt / m_eff about 4). With the limits, no-FT reaches its targets and completes.
#[test]
fn init_gains_are_stable_in_discrete_time_on_a_light_coupled_roll_joint() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("coaxial.toml");
    let urdf = common::repo("tests/data/coaxial_wrist.urdf");
    let args = ["init", "--urdf", urdf.to_str().unwrap(), "--ee", "hand"];
    let mut args: Vec<&str> = args.to_vec();
    args.extend(["--out", out.to_str().unwrap()]);
    common::aift_ok(&args, tmp.path());
    for engine in ["articulated", "rapier"] {
        let set = format!("plant.engine=\"{engine}\"");
        let loaded = LoadedScenario::from_file(&out, &[set]).unwrap();
        let setup = RunSetup::prepare(loaded).unwrap();
        let (r, _) = common::run_recorded(&setup, Method::NoFt, 2, None);
        assert_eq!(r.outcome.name(), "completed", "{engine}: {:?}", r.outcome);
        assert!(
            r.max_final_error < 0.01,
            "{engine}: {:?}",
            r.final_error_per_joint
        );
    }
}

/// What no gain can fix is refused before anything is written: a shoulder whose effort limit is
/// below the gravity torque it must hold at the start or a target; the message names the URDF,
/// the joint and the two torques; exit 2; no scenario file.
#[test]
fn init_refuses_a_joint_too_weak_to_hold_its_load_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(common::repo("tests/data/coaxial_wrist.urdf")).unwrap();
    let weak = text.replacen(r#"effort="80""#, r#"effort="0.5""#, 1);
    assert_ne!(weak, text);
    let urdf = tmp.path().join("weak.urdf");
    std::fs::write(&urdf, weak).unwrap();
    let out = tmp.path().join("weak.toml");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["init", "--urdf"])
        .arg(&urdf)
        .args(["--ee", "hand", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("weak.urdf") && err.contains("joint 'shoulder' <limit effort>"),
        "{err}"
    );
    assert!(err.contains("gravity torque"), "{err}");
    assert!(!out.exists());
}

#[test]
fn init_gains_come_from_the_model_and_overcome_the_urdf_coulomb_friction() {
    // Issue 24: an earlier init probed the mass matrix by finite differences of the forward
    // dynamics, which the Coulomb friction corrupted (kd up to 7.1e6 on a 6-DOF arm); the gains
    // now come from the model's mass matrix and gravity, and friction enters only where a
    // PID must overcome it: kp >= F / 0.01 rad and an integral clamp of 1.5 (G + F). With gains
    // that ignored it, 4 N m of Coulomb friction held the Panda's light wrist 0.15 rad off its
    // target and init's check run refused the arm.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let text = std::fs::read_to_string(common::repo("urdf/panda_7dof.urdf")).unwrap();
    let rough = text.replace(r#"friction="0"/>"#, r#"friction="4.0"/>"#);
    assert!(rough != text);
    std::fs::write(d.join("smooth.urdf"), &text).unwrap();
    std::fs::write(d.join("rough.urdf"), &rough).unwrap();
    let gains = |name: &str, check: bool| -> BTreeMap<String, Vec<f64>> {
        let urdf = format!("{name}.urdf");
        let out = format!("{name}.toml");
        let mut args = vec!["init", "--urdf", &urdf, "--out", &out];
        if !check {
            args.push("--no-check");
        }
        common::aift_ok(&args, d);
        let v: toml::Value =
            toml::from_str(&std::fs::read_to_string(d.join(&out)).unwrap()).unwrap();
        v["controller"]["gains"]
            .as_table()
            .unwrap()
            .iter()
            // The per-joint lists (a per-mode `kd_matrix`, when written, has kd as its diagonal).
            .filter(|(k, _)| !k.ends_with("_matrix"))
            .map(|(k, v)| {
                let list = v.as_array().unwrap();
                (
                    k.clone(),
                    list.iter().map(|x| x.as_float().unwrap()).collect(),
                )
            })
            .collect()
    };
    let smooth = gains("smooth", false);
    // The check run passes: the arm reaches its targets within 0.01 rad despite the friction.
    let rough = gains("rough", true);
    for (k, v) in smooth.iter().chain(&rough) {
        assert!(
            v.iter().all(|x| x.is_finite() && (0.0..=1e4).contains(x)),
            "{k}: {v:?}"
        );
    }
    for i in 0..7 {
        assert!(rough["kp"][i] >= smooth["kp"][i], "joint {i}");
        // 4 N m over 0.01 rad, rounded to 4 significant digits in the file.
        assert!(
            rough["kp"][i] >= 400.0 * (1.0 - 1e-3),
            "joint {i}: {}",
            rough["kp"][i]
        );
        assert!(rough["integral_limit"][i] >= 1.5 * 4.0 * (1.0 - 1e-3));
        assert!(rough["integral_limit"][i] >= smooth["integral_limit"][i]);
    }
}

#[test]
fn init_handles_a_pendulum_whose_joints_share_one_origin() {
    // Issue 24: five continuous joints about x, every joint origin at one point (a public
    // package's 5-link pendulum). An earlier init wrote kp = 1.5e15 from a "joint inertia" of
    // 2.4e13 kg m^2 for 2 kg links; the gains now come from the mass matrix.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let mut links = vec![r#"<link name="base"/>"#.to_string()];
    let mut joints = Vec::new();
    let mut parent = "base".to_string();
    for i in 1..=5 {
        links.push(format!(
            r#"<link name="l{i}"><inertial><origin xyz="0 0 -0.5"/><mass value="2.0"/>
<inertia ixx="0.02" iyy="0.02" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><origin xyz="0 0 -0.5"/><geometry><cylinder radius="0.02" length="1.0"/></geometry></collision></link>"#
        ));
        joints.push(format!(
            r#"<joint name="j{i}" type="continuous"><parent link="{parent}"/><child link="l{i}"/>
<origin xyz="0 0 0"/><axis xyz="1 0 0"/><dynamics damping="0.1"/></joint>"#
        ));
        parent = format!("l{i}");
    }
    let urdf = format!(
        "<robot name=\"pendulum\">{}{}</robot>",
        links.join("\n"),
        joints.join("\n")
    );
    std::fs::write(d.join("pendulum.urdf"), urdf).unwrap();
    common::aift_ok(&["init", "--urdf", "pendulum.urdf", "--out", "p.toml"], d);
    let text = std::fs::read_to_string(d.join("p.toml")).unwrap();
    let sc = aift::scenario::parse_scenario(&text, &d.join("p.toml"), &[]).unwrap();
    let g = &sc.controller.gains;
    assert!(
        g.kp.iter().chain(&g.kd).all(|k| k.is_finite() && *k < 1e4),
        "{g:?}"
    );
    let out = common::aift_ok(
        &["run", "p.toml", "--method", "no-ft", "--out", "r", "--json"],
        d,
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["outcome"], "completed");
    assert!(
        summary["max_final_error"].as_f64().unwrap() < 0.01,
        "{summary}"
    );
}

/// `init` says which joints the camera cannot check (issue 24, "sensors nobody else can
/// check"): on `tests/data/coaxial_wrist.urdf` the end effector ("hand") is the roll joint's
/// origin, on its axis, so turning it moves nothing the camera sees; `init` names that joint in
/// the scenario's comments, as a value of the library and in a note on stderr, and lists every
/// joint's sensitivity; likewise the Panda's joint 7 (its flange on the joint's axis). With a
/// tool 0.1 m off the roll axis the camera sees every joint, and nothing is named.
#[test]
fn init_names_the_joints_the_camera_cannot_see() {
    use aift::scenario::init::{InitOptions, init_scenario_noted};
    let tmp = tempfile::tempdir().unwrap();
    let on_axis = common::repo("tests/data/coaxial_wrist.urdf");
    let text = std::fs::read_to_string(&on_axis).unwrap();
    let tool = text.replacen(
        "</robot>",
        r#"<joint name="tool_mount" type="fixed"><parent link="hand"/><child link="tool"/>
             <origin xyz="0.1 0 0"/></joint>
           <link name="tool"><inertial><mass value="0.05"/>
             <inertia ixx="1e-6" iyy="1e-6" izz="1e-6" ixy="0" ixz="0" iyz="0"/></inertial></link>
         </robot>"#,
        1,
    );
    let off_axis = tmp.path().join("tool.urdf");
    std::fs::write(&off_axis, tool).unwrap();
    let options = |ee: &str| InitOptions {
        ee_link: Some(ee.into()),
        balance_inertia: false,
        urdf_in_scenario: "arm.urdf".into(),
        name: "arm".into(),
    };
    let blind = init_scenario_noted(&on_axis, &options("hand")).unwrap();
    assert_eq!(blind.camera_blind, vec!["roll".to_string()]);
    assert!(
        blind.text.contains("# The camera cannot see joint 'roll'"),
        "{}",
        blind.text
    );
    // A real arm: the Panda's end effector (its flange) lies on joint 7's axis.
    let panda = common::repo("urdf/panda_7dof.urdf");
    let panda_ee = aift::scenario::init::default_ee(&aift::arm::load_urdf(&panda).unwrap());
    let panda = init_scenario_noted(&panda, &options(&panda_ee)).unwrap();
    assert_eq!(panda.camera_blind, vec!["panda_joint7".to_string()]);
    let seen = init_scenario_noted(&off_axis, &options("tool")).unwrap();
    assert!(seen.camera_blind.is_empty(), "{:?}", seen.camera_blind);
    assert!(!seen.text.contains("cannot see"), "{}", seen.text);
    // Both list a sensitivity per joint; the roll joint's is 0 on its axis only.
    let listed = |text: &str| -> Vec<f64> {
        let line = text
            .lines()
            .skip_while(|l| !l.contains("as this many encoder readings"))
            .nth(2)
            .unwrap();
        line.trim_start_matches("# [")
            .trim_end_matches("].")
            .split(", ")
            .map(|v| v.parse().unwrap())
            .collect()
    };
    let (b, s) = (listed(&blind.text), listed(&seen.text));
    assert_eq!((b.len(), s.len()), (2, 2));
    assert!(b[0] > 1e-3 && b[1] < 1e-6 && s[1] > 1e-4, "{b:?} {s:?}");
    // The CLI says it too (without the check run: the note comes before it).
    let out = tmp.path().join("blind.toml");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["init", "--no-check", "--ee", "hand", "--urdf"])
        .arg(&on_axis)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("note: the camera cannot see joint 'roll'"),
        "{err}"
    );
}
