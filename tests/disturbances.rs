//! Disturbances that are not faults: a payload and a push checked against the paper arm's
//! statics in closed form (both engines), and in the closed loop, what each method makes of
//! them (the correct verdict: no sensor or actuator fault).

mod common;

use aift::plant::{Engine, ExternalForce, Integrator};
use aift::scenario::Method;
use common::PaperArm;
use nalgebra::Vector3;

const L2: f64 = 1.0111;

/// The tip of the paper arm (x-z plane, angles from +x upwards about -y).
fn tip_jacobian(p: &PaperArm, q: [f64; 2]) -> [[f64; 2]; 2] {
    let (s1, c1) = q[0].sin_cos();
    let (s12, c12) = (q[0] + q[1]).sin_cos();
    // Rows x and z, columns joints.
    [
        [-p.l1 * s1 - L2 * s12, -L2 * s12],
        [p.l1 * c1 + L2 * c12, L2 * c12],
    ]
}

/// Holds `tau` on a plant set at `q` at rest for 1 s; returns the largest |q - q0|.
fn drift(plant: &mut dyn aift::plant::Plant, q: [f64; 2], tau: [f64; 2]) -> f64 {
    plant.set_state(&q, &[0.0, 0.0]);
    plant.set_torques(&tau);
    let mut worst = 0.0f64;
    for _ in 0..1000 {
        plant.step(1e-3);
        let (now, _) = plant.state();
        worst = worst.max((now[0] - q[0]).abs()).max((now[1] - q[1]).abs());
    }
    worst
}

fn plants() -> Vec<(Engine, Box<dyn aift::plant::Plant>)> {
    [Engine::Articulated, Engine::Rapier]
        .into_iter()
        .map(|e| {
            (
                e,
                common::plant_of("urdf/planar_2dof.urdf", e, Integrator::Euler, 2),
            )
        })
        .collect()
}

/// A 3 kg payload at the tip: the arm stays at rest under G(q) + the payload's gravity torque
/// in closed form, and sags under G(q) alone.
#[test]
fn a_payload_weighs_what_statics_says() {
    let p = PaperArm::default();
    let q = [-0.4, 0.7];
    let mp = 3.0;
    let g = p.gravity(q);
    let c12 = (q[0] + q[1]).cos();
    let payload = [
        mp * p.g * (p.l1 * q[0].cos() + L2 * c12),
        mp * p.g * L2 * c12,
    ];
    let held = [g[0] + payload[0], g[1] + payload[1]];
    for (engine, mut plant) in plants() {
        let model = plant.model().clone();
        let tip = model.link("ee").unwrap();
        let point = tip.pose.translation.vector;
        plant.set_payload(tip.body, Some((mp, point)));
        let d = drift(plant.as_mut(), q, held);
        eprintln!("{engine:?}: drift with the payload's torque {d:.2e} rad");
        assert!(d < 1e-5, "{engine:?}: {d}");
        let sag = drift(plant.as_mut(), q, g);
        assert!(sag > 1e-2, "{engine:?}: without it the arm sags ({sag})");
        // Dropped: G(q) alone holds it again.
        plant.set_payload(tip.body, None);
        let d = drift(plant.as_mut(), q, g);
        assert!(d < 1e-5, "{engine:?}: after the drop {d}");
    }
}

/// A 20 N push at the tip, down and to the side: the arm stays at rest under G(q) - J^T F (the
/// tip Jacobian in closed form), and moves without the correction.
#[test]
fn a_push_acts_as_j_transpose_f() {
    let p = PaperArm::default();
    let q = [-0.4, 0.7];
    let f = [12.0, -16.0];
    let j = tip_jacobian(&p, q);
    let ext = [
        j[0][0] * f[0] + j[1][0] * f[1],
        j[0][1] * f[0] + j[1][1] * f[1],
    ];
    let g = p.gravity(q);
    let held = [g[0] - ext[0], g[1] - ext[1]];
    for (engine, mut plant) in plants() {
        let tip = plant.model().link("ee").unwrap().clone();
        let push = ExternalForce {
            body: tip.body,
            point: tip.pose.translation.vector,
            force: Vector3::new(f[0], 0.0, f[1]),
        };
        plant.set_external_forces(&[push]);
        let d = drift(plant.as_mut(), q, held);
        eprintln!("{engine:?}: drift under the push with G - J^T F: {d:.2e} rad");
        assert!(d < 1e-4, "{engine:?}: {d}");
        let moved = drift(plant.as_mut(), q, g);
        assert!(
            moved > 1e-2,
            "{engine:?}: without the correction it moves ({moved})"
        );
        plant.set_external_forces(&[]);
        assert!(drift(plant.as_mut(), q, g) < 1e-5, "{engine:?}: released");
    }
}

/// The closed loop on the Panda: a 0.5 kg payload picked up at 3 s and a 60 N push on link 4 from
/// 5 s to 5.3 s. Every method finishes at its target (no runaway); the alarms each draws are
/// counted in summary.json's `disturbances`, and the momentum observer sees the push (its alarm
/// is a detection of an unexplained torque, not of a fault; the payload's 2.5 N m or so on
/// joint 2 is below the healthy runs' residuals from model error, so it goes unseen).
#[test]
fn payload_and_push_in_the_closed_loop() {
    let d = "[[disturbances]]\nkind = \"payload\"\nlink = \"ee\"\nstart = 3.0\nmass = 0.5\n\n\
             [[disturbances]]\nkind = \"push\"\nlink = \"panda_link4\"\nstart = 5.0\nend = 5.3\n\
             force = [60.0, 0.0, 0.0]";
    let setup = common::with_faults(
        "panda_healthy.toml",
        &[d],
        &[
            "duration=10.0",
            "plant.engine=\"articulated\"",
            "momentum.enabled=true",
        ],
    );
    for method in [
        Method::NoFt,
        Method::PlAlways,
        Method::Hybrid,
        Method::EkfGate,
    ] {
        let r = aift::scenario::Run::new(&setup, method)
            .seed(21)
            .execute()
            .unwrap();
        let counts: Vec<(usize, usize)> = r
            .disturbances
            .iter()
            .map(|d| (d.sensor_alarms, d.momentum_alarms))
            .collect();
        eprintln!(
            "{}: outcome {}, final error {:.4}, (sensor, momentum) alarms per disturbance {counts:?}",
            method.name(),
            r.outcome.name(),
            r.max_final_error
        );
        let m = r.momentum.as_ref().unwrap();
        eprintln!(
            "  momentum largest {:?} thresholds {:?}",
            m.largest, m.thresholds
        );
        assert_eq!(r.outcome.name(), "completed", "{}", method.name());
        assert_eq!(r.disturbances.len(), 2);
        assert!(
            r.max_final_error < 0.05,
            "{}: {}",
            method.name(),
            r.max_final_error
        );
        assert!(
            r.disturbances[1].momentum_alarms > 0,
            "{}: the momentum observer sees the push",
            method.name()
        );
    }
}

#[test]
fn bad_disturbances_are_refused_naming_the_key() {
    let cases = [
        (
            "kind = \"payload\"\nlink = \"nope\"\nstart = 1.0\nmass = 1.0",
            "disturbances[0].link",
        ),
        (
            "kind = \"payload\"\nlink = \"world\"\nstart = 1.0\nmass = 1.0",
            "disturbances[0].link",
        ),
        (
            "kind = \"payload\"\nlink = \"ee\"\nstart = 1.0\nmass = 0.0",
            "disturbances[0].mass",
        ),
        (
            "kind = \"push\"\nlink = \"ee\"\nstart = 1.0\nforce = [0.0, nan, 0.0]",
            "disturbances[0].force",
        ),
        (
            "kind = \"push\"\nlink = \"ee\"\nstart = 2.0\nend = 1.0\nforce = [1.0, 0.0, 0.0]",
            "disturbances[0].end",
        ),
        (
            "kind = \"push\"\nlink = \"ee\"\nstart = 1.0\nforce = [1.0, 0.0]",
            "disturbances[0].force",
        ),
        (
            "kind = \"payload\"\nlink = \"ee\"\nstart = 1.0\nmass = 1.0\noffset = [1.0]",
            "disturbances[0].offset",
        ),
    ];
    let tmp = tempfile::tempdir().unwrap();
    for (body, key) in cases {
        let base = std::fs::read_to_string(common::repo("assets/scenarios/paper_healthy.toml"))
            .unwrap()
            .replace(
                "../../urdf/",
                &format!("{}/", common::repo("urdf").display()),
            );
        let path = tmp.path().join("bad.toml");
        std::fs::write(&path, format!("{base}\n[[disturbances]]\n{body}\n")).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_aift"))
            .args(["run", path.to_str().unwrap(), "--out"])
            .arg(tmp.path().join("out"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{body}: {stderr}");
        assert!(stderr.contains(key), "{body}: {stderr} does not name {key}");
        assert!(
            !tmp.path().join("out").exists(),
            "{body}: no output written"
        );
    }
}
