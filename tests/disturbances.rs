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

/// The Panda's healthy template cut to 10 s on the articulated engine, with a 0.5 kg payload
/// picked up at 3 s and a 60 N push on link 4 from 5 s to 5.3 s, and `option` set.
fn payload_and_push(options: &[&str]) -> aift::scenario::RunSetup {
    let d = "[[disturbances]]\nkind = \"payload\"\nlink = \"ee\"\nstart = 3.0\nmass = 0.5\n\n\
             [[disturbances]]\nkind = \"push\"\nlink = \"panda_link4\"\nstart = 5.0\nend = 5.3\n\
             force = [60.0, 0.0, 0.0]";
    common::with_faults(
        "panda_healthy.toml",
        &[d],
        &[&["duration=10.0", "plant.engine=\"articulated\""], options].concat(),
    )
}

/// The closed loop on the Panda: a 0.5 kg payload picked up at 3 s and a 60 N push on link 4 from
/// 5 s to 5.3 s. Every method finishes at its target (no runaway); the alarms each draws are
/// counted in summary.json's `disturbances`, and the momentum observer sees the push (its alarm
/// is a detection of an unexplained torque, not of a fault; the payload's torque is below the
/// thresholds the healthy runs' model error sets, so it goes unseen).
#[test]
fn payload_and_push_in_the_closed_loop() {
    let setup = payload_and_push(&["momentum.enabled=true"]);
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
            r.detections.is_empty(),
            "{}: {:?}",
            method.name(),
            r.detections
        );
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

/// The hybrid's own actuator alarms (`hybrid.actuators`) during a payload or a push are counted
/// per disturbance, over the same window as the sensor alarms, and as false actuator alarms (no
/// actuator is at fault): each count is the number of the run's actuator alarms in its window.
#[test]
fn actuator_alarms_during_disturbances_are_counted_as_false() {
    let setup = payload_and_push(&["hybrid.actuators=true", "hybrid.model_error_state=false"]);
    let grace = aift::scenario::metrics::FALSE_ALARM_GRACE;
    for seed in [21, 22] {
        let r = aift::scenario::Run::new(&setup, Method::Hybrid)
            .seed(seed)
            .execute()
            .unwrap();
        let alarms = r
            .actuator_alarms
            .as_ref()
            .expect("the hybrid infers actuators");
        eprintln!("seed {seed}: actuator alarms {alarms:?}");
        assert_eq!(r.actuator_false_alarms, alarms.len());
        for d in &r.disturbances {
            let end = d.end.map_or(f64::INFINITY, |e| e + grace);
            let inside = alarms
                .iter()
                .filter(|(t, _)| *t >= d.start - 1e-9 && *t < end - 1e-9)
                .count();
            assert_eq!(d.actuator_alarms, inside, "seed {seed}: {}", d.label);
        }
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
    for (body, key) in cases {
        common::assert_refused(&format!("[[disturbances]]\n{body}"), key);
    }
}

/// The paper arm pressing its tip on a table at rest (rapier, contact on): the table's force on
/// the arm balances gravity and the joint torques, N = J_c^-T (G(q) - tau) with J_c the contact
/// point's Jacobian in closed form; commanded to press with 20 N, the table pushes back 20 N
/// straight up.
#[test]
fn a_table_pushes_back_what_statics_says() {
    let p = PaperArm::default();
    let q: [f64; 2] = [0.3, -0.9];
    let (s1, c1) = q[0].sin_cos();
    let (s12, c12) = (q[0] + q[1]).sin_cos();
    // The lowest corner of link 2's 0.05 m box at the tip: tip - 0.025 (link-frame z in world).
    let tip = [p.l1 * c1 + L2 * c12, p.l1 * s1 + L2 * s12];
    let contact = [tip[0] - 0.025 * (-s12), tip[1] - 0.025 * c12];
    let press = 20.0;
    // tau = G - J_c^T (0, press): column i of J_c is (-z_i, x_i) for the lever (x_i, z_i).
    let g = p.gravity(q);
    let lever2 = contact[0] - p.l1 * c1;
    let tau = [g[0] - press * contact[0], g[1] - press * lever2];
    let table_top = contact[1];
    let settings = aift::plant::PlantSettings {
        engine: Engine::Rapier,
        rapier: aift::plant::RapierSettings {
            obstacles: vec![aift::plant::Obstacle {
                shape: aift::plant::ObstacleShape::Box,
                size: vec![1.0, 1.0, 0.2],
                position: vec![contact[0], 0.0, table_top - 0.1],
                rpy: vec![0.0; 3],
                friction: 0.5,
            }],
            ..Default::default()
        },
        ..Default::default()
    };
    let model = common::model("urdf/planar_2dof.urdf");
    let mut plant = aift::plant::build(model, [0.0, 0.0, -9.81], &settings).unwrap();
    plant.set_state(&q, &[0.0, 0.0]);
    plant.set_torques(&tau);
    let mut mean = Vector3::zeros();
    for k in 0..2000 {
        plant.step(1e-3);
        if k >= 1500 {
            mean += plant.contact_normal_force() / 500.0;
        }
    }
    let (qf, _) = plant.state();
    eprintln!("contact force {mean:?} (expected (0, 0, {press})), q {qf:?} from {q:?}");
    assert!(
        (qf[0] - q[0]).abs() < 1e-4 && (qf[1] - q[1]).abs() < 1e-4,
        "{qf:?}"
    );
    assert!((mean.z - press).abs() < 1e-3 * press, "normal {}", mean.z);
    assert!(
        mean.x.abs() < 1e-3 * press && mean.y.abs() < 1e-6,
        "{mean:?}"
    );
    // Without the table the same torques swing the tip down.
    let mut free = common::plant_of(
        "urdf/planar_2dof.urdf",
        Engine::Rapier,
        Integrator::Euler,
        2,
    );
    assert!(drift(free.as_mut(), q, tau) > 1e-2);
}

/// Obstacles need rapier: the articulated engine refuses them, naming the key.
#[test]
fn the_articulated_engine_refuses_obstacles() {
    common::assert_refused(
        "[plant]\nengine = \"articulated\"\n[[plant.rapier.obstacles]]\nshape = \"box\"\n\
         size = [1.0, 1.0, 0.1]\nposition = [1.5, 0.0, -0.5]",
        "plant.rapier.obstacles",
    );
}

/// The bundled contact scenario: the paper arm reaches for a target below a table and rests on
/// it. Every method completes with the same resting pose (not the target), raises no sensor
/// alarm (nothing failed), the table's force stays finite (its peak is the landing's impact),
/// and the tip does not sink into the table.
#[test]
fn resting_on_a_table_is_not_a_fault() {
    let setup = common::setup("paper_contact.toml", &["duration=12.0"]);
    let p = PaperArm::default();
    let mut rest: Option<Vec<f64>> = None;
    for method in [
        Method::NoFt,
        Method::PlAlways,
        Method::Hybrid,
        Method::EkfGate,
        Method::Imm,
    ] {
        let r = aift::scenario::Run::new(&setup, method)
            .seed(5)
            .execute()
            .unwrap();
        eprintln!(
            "{}: {} final error {:?} alarms {} contact {:.1} N",
            method.name(),
            r.outcome.name(),
            r.final_error_per_joint,
            r.detections.len(),
            r.max_contact_normal_force
        );
        assert_eq!(r.outcome.name(), "completed", "{}", method.name());
        assert_eq!(
            r.detections.len(),
            0,
            "{}: {:?}",
            method.name(),
            r.detections
        );
        // The peak is the impact (about m v / dt over the tick the tip lands in).
        assert!(r.max_contact_normal_force > 1.0 && r.max_contact_normal_force < 1e4);
        let q = &r.q_final;
        let tip_z = p.l1 * q[0].sin() + L2 * (q[0] + q[1]).sin();
        // Table top at -0.6; link 2's box (0.025 half thickness, pointing down) keeps the
        // tip's axis at least 0.02 above it; allow 2 mm of contact softness.
        assert!(
            tip_z > -0.6 + 0.018,
            "{}: tip at z = {tip_z}",
            method.name()
        );
        assert!(
            r.max_final_error > 0.05,
            "the table keeps it from the target"
        );
        match &rest {
            None => rest = Some(q.clone()),
            Some(first) => {
                for (a, b) in first.iter().zip(q) {
                    assert!((a - b).abs() < 1e-3, "{}: rests at {q:?}", method.name());
                }
            }
        }
    }
}

fn contact_campaign(dir: &std::path::Path, depth: f64, targets: &str) -> std::path::PathBuf {
    let text = format!(
        r#"
name = "contact"
seeds = 1
methods = ["no-ft", "hybrid"]
healthy = false
defaults = {{ duration = 12.0, plant = {{ engine = "articulated" }}{targets} }}
[[arms]]
name = "paper"
scenario = "{}"
[[disturbance_cells]]
label = "obstacle on the path"
contact = {{ depth = {depth} }}
"#,
        common::repo("assets/scenarios/paper_healthy.toml").display()
    );
    let path = dir.join("contact.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// A campaign's contact cell places its obstacle per arm on the end effector's motion to the
/// last target (its face `depth` before the target, square to the motion), runs on rapier
/// whatever the campaign's engine, calibrates detectors without it, and holds the arm short of
/// its target without a runaway; a `depth` longer than the motion is refused (exit 2).
#[test]
fn a_contact_cell_puts_an_obstacle_on_each_arms_path() {
    use aift::arm::kinematics::forward;
    use aift::scenario::campaign::{Campaign, Shard, Verdict, run_campaign};
    let tmp = tempfile::tempdir().unwrap();
    let campaign = Campaign::load(&contact_campaign(tmp.path(), 0.05, ""), &[]).unwrap();
    assert_eq!(campaign.cells.len(), 1);
    let cell = &campaign.cells[0];
    assert!(!cell.is_healthy());
    let setup = campaign.cell_setup(cell);
    let plant = &setup.scenario().plant;
    assert_eq!(plant.engine, Engine::Rapier);
    assert_eq!(plant.rapier.obstacles.len(), 1);
    let plain = campaign.calibration_setup(cell);
    assert_eq!(plain.scenario().plant.engine, Engine::Rapier);
    assert!(plain.scenario().plant.rapier.obstacles.is_empty());
    // Geometry, from the end effector's positions at the two targets.
    let sc = setup.scenario();
    let ee = |q: &[f64]| {
        let mut poses = vec![nalgebra::Isometry3::identity(); setup.model.bodies.len()];
        forward(&setup.model, q, &mut poses);
        setup.ee.position(&poses)
    };
    let (a, b) = (ee(&sc.targets[0].q), ee(&sc.targets[1].q));
    let d = (b - a).normalize();
    let o = &plant.rapier.obstacles[0];
    let centre = Vector3::new(o.position[0], o.position[1], o.position[2]);
    let rotation = nalgebra::UnitQuaternion::from_euler_angles(o.rpy[0], o.rpy[1], o.rpy[2]);
    // The box's z axis is the motion; its near face is 0.05 m before the target.
    assert!((rotation * Vector3::z() - d).norm() < 1e-12);
    let face = centre - d * (o.size[2] / 2.0);
    assert!(((b - face).dot(&d) - 0.05).abs() < 1e-12);
    assert!((b - face).cross(&d).norm() < 1e-12, "centred on the line");
    assert!(
        (a - face).dot(&d) < -0.01,
        "the motion starts before the face"
    );
    // The runs: the arm lands on it (a contact force) and rests short of its target.
    let r = aift::scenario::Run::new(&setup, Method::NoFt)
        .seed(1)
        .execute()
        .unwrap();
    assert_eq!(r.outcome.name(), "completed");
    assert!(
        r.max_contact_normal_force > 1.0,
        "{}",
        r.max_contact_normal_force
    );
    assert!(r.max_final_error > 0.01, "{}", r.max_final_error);
    let records = run_campaign(&campaign, Shard::WHOLE, None, &|_, _| {}).unwrap();
    for run in &records.runs {
        assert_eq!(run.verdict, Verdict::Recovered, "{}", run.method);
        assert!(!run.runaway);
        assert_eq!(run.false_alarms, 0, "{}", run.method);
    }
    // An obstacle deeper than the motion is long (2 cm of joint 2): refused, naming the cell.
    let short = ", targets = [{ time = 0.0, q = [-0.2, 0.5] }, { time = 7.5, q = [-0.2, 0.52] }]";
    let out = common::aift_in(
        &[
            "campaign",
            contact_campaign(tmp.path(), 0.05, short).to_str().unwrap(),
            "--out",
            "never",
        ],
        tmp.path(),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("contact") && err.contains("depth"), "{err}");
    assert!(!tmp.path().join("never").exists());
}
