//! Actuator faults: what each kind does to the torque the joint receives, a locked joint held
//! by the plant's brake (against a closed-form reference, in both engines), and bad input.

mod common;

use aift::plant::{Engine, Integrator, Plant};
use aift::scenario::Method;
use common::PaperArm;

/// The paper arm's closed-loop run (1 s, target step at 0.3 s) with actuator faults appended.
fn paper_run(faults: &[&str]) -> aift::scenario::TrajectoryRecorder {
    let setup = common::with_faults(
        "paper_healthy.toml",
        faults,
        &["duration=1.0", "targets[1].time=0.3"],
    );
    common::run_recorded(&setup, Method::NoFt, 3, None).1
}

/// (commanded, applied) of joint `j` (1-based) per tick.
fn torques(rec: &aift::scenario::TrajectoryRecorder, j: usize) -> Vec<(f64, f64)> {
    let u = rec.column(&format!("u{j}")).unwrap();
    let a = rec.column(&format!("applied{j}")).unwrap();
    rec.rows.iter().map(|r| (r[u], r[a])).collect()
}

/// The paper arm has no effort limits: applied equals commanded outside faults.
fn assert_untouched_outside(tq: &[(f64, f64)], from: usize, to: usize) {
    for (k, (u, a)) in tq.iter().enumerate() {
        if k < from || k >= to {
            assert_eq!(u, a, "tick {k} outside the fault");
        }
    }
}

#[test]
fn effectiveness_bias_dead_and_saturation_transform_the_torque() {
    type Expected = fn(f64) -> f64;
    let cases: [(&str, Expected); 4] = [
        ("kind = \"effectiveness\"\nfactor = 0.25", |u| 0.25 * u),
        ("kind = \"bias\"\ntorque = -7.5", |u| u - 7.5),
        ("kind = \"dead\"", |_| 0.0),
        ("kind = \"saturation\"\nlimit = 4.0", |u| u.clamp(-4.0, 4.0)),
    ];
    for (kind, expected) in cases {
        let fault = format!("[[actuator_faults]]\njoint = 2\nstart = 0.2\nend = 0.6\n{kind}");
        let rec = paper_run(&[&fault]);
        let tq = torques(&rec, 2);
        assert_untouched_outside(&tq, 200, 600);
        let mut changed = 0;
        for (k, &(u, a)) in tq.iter().enumerate().take(600).skip(200) {
            assert_eq!(a, expected(u), "{kind}: tick {k}");
            changed += usize::from(a != u);
        }
        assert!(changed > 100, "{kind}: the fault changed {changed} ticks");
        // Joint 1 is not touched.
        let tq1 = torques(&rec, 1);
        assert!(tq1.iter().all(|(u, a)| u == a), "{kind}: joint 1");
    }
}

#[test]
fn intermittent_cuts_the_first_duty_of_every_cycle() {
    let fault = "[[actuator_faults]]\njoint = [1, 2]\nstart = 0.2\nend = 0.6\n\
                 kind = \"intermittent\"\nperiod = 0.05\nduty = 0.4";
    let rec = paper_run(&[fault]);
    for j in [1, 2] {
        let tq = torques(&rec, j);
        assert_untouched_outside(&tq, 200, 600);
        for (k, &(u, a)) in tq.iter().enumerate().take(600).skip(200) {
            let off = (k - 200) % 50 < 20;
            assert_eq!(a, if off { 0.0 } else { u }, "joint {j} tick {k}");
        }
    }
}

/// Faults on one joint apply in file order; effort limits clamp what the joint receives.
#[test]
fn faults_compose_in_file_order_within_the_effort_limits() {
    let a = "[[actuator_faults]]\njoint = 1\nstart = 0.2\nkind = \"effectiveness\"\nfactor = 0.5";
    let b = "[[actuator_faults]]\njoint = 1\nstart = 0.4\nkind = \"bias\"\ntorque = 3.0";
    let rec = paper_run(&[a, b]);
    let tq = torques(&rec, 1);
    for (k, &(u, applied)) in tq.iter().enumerate() {
        let expected = match k {
            0..200 => u,
            200..400 => 0.5 * u,
            _ => 0.5 * u + 3.0,
        };
        assert_eq!(applied, expected, "tick {k}");
    }
    // The Panda has effort limits: a bias beyond them is clamped to the limit.
    let setup = common::with_faults(
        "panda_healthy.toml",
        &["[[actuator_faults]]\njoint = 7\nstart = 0.1\nkind = \"bias\"\ntorque = 500.0"],
        &["duration=0.3", "plant.engine=\"articulated\""],
    );
    let effort = setup.model.joints[6]
        .effort
        .expect("the Panda's joints have limits");
    let (_, rec) = common::run_recorded(&setup, Method::NoFt, 1, None);
    assert_eq!(common::at(&rec, "applied7", 0.2), effort);
}

/// A locked joint stays where it was at the fault's start while the other joint swings, and
/// the swinging joint follows the one-link pendulum the rest of the arm becomes
/// (m22 q2'' = tau2 - d2 q2' - m2 g lc2 cos(q1 + q2), q1 fixed), in both engines.
#[test]
fn a_locked_joint_is_held_and_the_rest_moves_as_the_reduced_arm() {
    let p = PaperArm::default();
    let q1 = 0.3;
    let tau2 = 6.0;
    let m22 = p.i2 + p.m2 * p.lc2 * p.lc2;
    // Reference: RK4 at 1e-5 s over 1 s from q2 = 0.2 at rest.
    let (mut x, mut v) = (0.2f64, 0.0f64);
    let f = |x: f64, v: f64| (tau2 - p.d2 * v - p.m2 * p.g * p.lc2 * (q1 + x).cos()) / m22;
    let h = 1e-5;
    for _ in 0..100_000 {
        let (k1x, k1v) = (v, f(x, v));
        let (k2x, k2v) = (v + h / 2.0 * k1v, f(x + h / 2.0 * k1x, v + h / 2.0 * k1v));
        let (k3x, k3v) = (v + h / 2.0 * k2v, f(x + h / 2.0 * k2x, v + h / 2.0 * k2v));
        let (k4x, k4v) = (v + h * k3v, f(x + h * k3x, v + h * k3v));
        x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    }
    for engine in [Engine::Articulated, Engine::Rapier] {
        for integrator in [Integrator::Euler, Integrator::Rk4] {
            if engine == Engine::Rapier && integrator == Integrator::Rk4 {
                continue;
            }
            let mut arm = common::plant_of("urdf/planar_2dof.urdf", engine, integrator, 2);
            arm.set_state(&[q1, 0.2], &[0.0, 0.0]);
            arm.set_brake(0, true);
            // A large torque on the braked joint changes nothing.
            arm.set_torques(&[80.0, tau2]);
            for _ in 0..1000 {
                arm.step(1e-3);
                let (q, _) = arm.state();
                assert!(
                    (q[0] - q1).abs() < 1e-6,
                    "{engine:?}/{integrator:?}: joint 1 at {} (held at {q1})",
                    q[0]
                );
            }
            let (q, qd) = arm.state();
            eprintln!(
                "{engine:?}/{integrator:?}: q2 {} ref {x}, qd2 {} ref {v}",
                q[1], qd[1]
            );
            // Measured: 4e-16 (articulated RK4), 4e-7 (articulated Euler), 6e-6 (rapier).
            let bound = match (engine, integrator) {
                (Engine::Articulated, Integrator::Rk4) => 1e-12,
                (Engine::Articulated, _) => 2e-6,
                _ => 2e-5,
            };
            assert!((q[1] - x).abs() < bound, "{engine:?}: q2 {} ref {x}", q[1]);
            // Released (no torque on joint 1 now): it falls under gravity.
            arm.set_torques(&[0.0, tau2]);
            arm.set_brake(0, false);
            for _ in 0..100 {
                arm.step(1e-3);
            }
            let (q, _) = arm.state();
            assert!((q[0] - q1).abs() > 1e-3, "{engine:?}: joint 1 released");
        }
    }
}

/// In the closed loop, a locked joint is held from the fault's tick and released at its end;
/// the Panda's other joints still reach their targets while joint 4 is locked (rapier and
/// articulated).
#[test]
fn a_locked_joint_in_the_closed_loop_is_held_then_released() {
    for engine in ["articulated", "rapier"] {
        let setup = common::with_faults(
            "panda_healthy.toml",
            &["[[actuator_faults]]\njoint = 4\nstart = 0.5\nend = 3.0\nkind = \"locked\""],
            &["duration=10.0", &format!("plant.engine=\"{engine}\"")],
        );
        let (result, rec) = common::run_recorded(&setup, Method::NoFt, 1, None);
        assert_eq!(result.outcome.name(), "completed", "{engine}");
        let held = common::at(&rec, "q4", 0.5);
        let c = rec.column("q4").unwrap();
        for r in rec
            .rows
            .iter()
            .filter(|r| r[0] > 0.5 + 1e-9 && r[0] < 3.0 - 1e-9)
        {
            assert!(
                (r[c] - held).abs() < 1e-4,
                "{engine}: q4 {} at {} s, held at {held}",
                r[c],
                r[0]
            );
        }
        assert!(
            (common::at(&rec, "q4", 4.9) - held).abs() > 1e-2,
            "{engine}: q4 released after 3 s"
        );
        // The last target (at 7.5 s) is reached once released.
        assert!(result.max_final_error < 0.05, "{engine}: {result:?}");
    }
}

#[test]
fn bad_actuator_faults_are_refused_naming_the_key() {
    let cases = [
        (
            "joint = 3\nstart = 1.0\nkind = \"dead\"",
            "actuator_faults[0].joint",
        ),
        (
            "joint = 0\nstart = 1.0\nkind = \"dead\"",
            "actuator_faults[0].joint",
        ),
        (
            "joint = []\nstart = 1.0\nkind = \"dead\"",
            "actuator_faults[0].joint",
        ),
        (
            "joint = 1\nstart = 1.0\nkind = \"effectiveness\"\nfactor = 1.5",
            "actuator_faults[0].factor",
        ),
        (
            "joint = 1\nstart = 1.0\nkind = \"saturation\"\nlimit = -1.0",
            "actuator_faults[0].limit",
        ),
        (
            "joint = 1\nstart = 1.0\nkind = \"intermittent\"\nperiod = 0.001\nduty = 0.5",
            "actuator_faults[0].period",
        ),
        (
            "joint = 1\nstart = 1.0\nkind = \"intermittent\"\nperiod = 0.1\nduty = 0.0",
            "actuator_faults[0].duty",
        ),
        (
            "joint = 1\nstart = 2.0\nend = 1.0\nkind = \"dead\"",
            "actuator_faults[0].end",
        ),
        (
            "joint = 1\nstart = 1.0\nkind = \"bias\"\ntorque = inf",
            "actuator_faults[0].torque",
        ),
        // A key the kind does not have.
        (
            "joint = 1\nstart = 1.0\nkind = \"dead\"\nfactor = 0.5",
            "factor",
        ),
    ];
    for (body, key) in cases {
        common::assert_refused(&format!("[[actuator_faults]]\n{body}"), key);
    }
}

/// The plant's brake is part of the Plant trait: engaging it on a joint at rest under gravity
/// keeps the joint there (no torque at all), in both engines (rapier's limit constraint is
/// stabilised, not exact: within 1e-5 rad over 2 s).
#[test]
fn a_brake_holds_a_joint_against_gravity() {
    for engine in [Engine::Articulated, Engine::Rapier] {
        let mut arm: Box<dyn Plant> =
            common::plant_of("urdf/planar_2dof.urdf", engine, Integrator::Euler, 2);
        arm.set_state(&[0.0, 0.0], &[0.0, 0.0]);
        arm.set_brake(1, true);
        arm.set_brake(0, true);
        for _ in 0..2000 {
            arm.step(1e-3);
        }
        let (q, _) = arm.state();
        assert!(q.iter().all(|v| v.abs() < 1e-5), "{engine:?}: {q:?}");
    }
}

/// summary.json's actuator entries: the sensor alarms within the fault (and a second after),
/// recounted here from the run's detections, and the belief's error on the fault's joints.
#[test]
fn actuator_faults_are_reported_with_the_alarms_they_drew() {
    let setup = common::with_faults(
        "paper_healthy.toml",
        &[
            "[[actuator_faults]]\njoint = 1\nstart = 2.0\nend = 4.0\nkind = \"effectiveness\"\nfactor = 0.1",
        ],
        &["duration=8.0"],
    );
    let (result, rec) = common::run_recorded(&setup, Method::PlAlways, 2, None);
    assert_eq!(result.actuator_faults.len(), 1);
    let a = &result.actuator_faults[0];
    assert_eq!((a.label.as_str(), a.kind), ("motor1", "effectiveness"));
    assert_eq!(
        (a.start, a.end, a.joints.clone()),
        (2.0, Some(4.0), vec![0])
    );
    let within = result
        .detections
        .iter()
        .filter(|d| d.t >= 2.0 - 1e-9 && d.t < 5.0 - 1e-9)
        .count();
    assert_eq!(a.sensor_alarms, within);
    // The belief's MSE on joint 1 from 2 s to 4 s, recomputed from the trajectory.
    let (mu, q) = (rec.column("mu1").unwrap(), rec.column("q1").unwrap());
    let window: Vec<f64> = rec
        .rows
        .iter()
        .filter(|r| r[0] >= 2.0 - 1e-9 && r[0] < 4.0 - 1e-9)
        .map(|r| (r[mu] - r[q]).powi(2))
        .collect();
    let mse = window.iter().sum::<f64>() / window.len() as f64;
    let got = a.mse_during.unwrap();
    assert!(
        (got - mse).abs() <= 1e-12 * mse.max(1e-300),
        "{got} vs {mse}"
    );
}

/// The hybrid with actuator hypotheses (`hybrid.actuators`) on the Panda with the scenario's
/// model error: healthy runs raise no actuator alarm; a locked joint, a loss of effectiveness
/// and a dead motor, starting during the motion to the second target, are each detected by the
/// hybrid's own bank (an actuator's health, one minus its failure probability, under the
/// channels' alarm rule) and its first actuator alarm names the faulty joint; a campaign's
/// actuator cell reports that detection as the hybrid's (no momentum observer running). With
/// the `shared-cosine` model-error budget, as docs/method.md measures them: with `per-joint` (the
/// default) the dead wrist motor (joint 6, from 7.6 s, 0.1 s after the target step) went
/// undetected in 4 of 6 seeds (shared-cosine: 1 of 6).
#[test]
fn the_hybrid_detects_and_isolates_actuator_faults_with_its_own_hypotheses() {
    let on = [
        "hybrid.actuators=true",
        "hybrid.model_error_state=false",
        "model.inertial_budget=\"shared-cosine\"",
        "duration=10.0",
        "plant.engine=\"articulated\"",
    ];
    let healthy = common::with_faults("panda_healthy.toml", &[], &on);
    for seed in [31, 32] {
        let r = aift::scenario::Run::new(&healthy, Method::Hybrid)
            .seed(seed)
            .execute()
            .unwrap();
        assert_eq!(r.actuator_alarms, Some(vec![]), "healthy seed {seed}");
        assert_eq!(r.actuator_false_alarms, 0);
    }
    // Without actuator hypotheses the hybrid reports none.
    let plain = common::with_faults("panda_healthy.toml", &[], &["duration=1.0"]);
    let r = aift::scenario::Run::new(&plain, Method::Hybrid)
        .execute()
        .unwrap();
    assert_eq!(r.actuator_alarms, None);
    for (joint, kind) in common::PANDA_ACTUATOR_FAULTS {
        let r = common::panda_actuator_fault_run(joint, kind, &on, Method::Hybrid, 31);
        let a = &r.actuator_faults[0];
        eprintln!(
            "joint {joint} {kind}: detected {:?} delay {:?} joint {:?}; alarms {:?}",
            a.method_detected_at, a.method_delay, a.method_joint, r.actuator_alarms
        );
        assert_eq!(a.method_joint, Some(joint - 1), "joint {joint} {kind}");
        assert_eq!(a.method_isolation_correct, Some(true));
        // Measured at another seed: 4, 46 and 17 ms.
        assert!(a.method_delay.unwrap() < 0.2, "joint {joint} {kind}");
        assert_eq!(r.actuator_false_alarms, 0, "joint {joint} {kind}");
        // The momentum observer does not run here: the detection is the hybrid's alone.
        assert!(r.momentum.is_none() && a.momentum_detected_at.is_none());
    }
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("hybrid_actuators.toml");
    std::fs::write(
        &file,
        format!(
            "name = \"hybrid-actuators\"\nseeds = 1\nfirst_seed = 33\nmethods = [\"hybrid\"]\n\
             channels = []\nactuator_kinds = [{{ kind = \"effectiveness\", factor = 0.3 }}]\n\
             [defaults]\nduration = 10.0\nplant = {{ engine = \"articulated\" }}\n\
             hybrid = {{ actuators = true, model_error_state = false }}\n\
             [[arms]]\nname = \"panda\"\nscenario = \"{}\"\njoints = [2]\n",
            common::repo("assets/scenarios/panda_healthy.toml").display()
        ),
    )
    .unwrap();
    use aift::scenario::campaign::{Campaign, Shard, run_campaign};
    let campaign = Campaign::load(&file, &[]).unwrap();
    let records = run_campaign(&campaign, Shard::WHOLE, None, &|_, _| {}).unwrap();
    let mut actuator_cells = 0;
    for run in &records.runs {
        let cell = &campaign.cells[run.cell];
        eprintln!(
            "{}: {:?} {:?} {:?}",
            cell.label, run.detected, run.delay, run.false_alarms
        );
        if cell.is_healthy() {
            assert_eq!(run.detected, None);
            assert_eq!(run.false_alarms, 0, "{}", cell.label);
        } else {
            // Its sensor alarms (the bank also blames sensors for part of the torque; counted
            // in results/actuators) are not what is checked here.
            actuator_cells += 1;
            assert_eq!(run.detected, Some(true), "{}", cell.label);
            assert_eq!(run.isolation_correct, Some(true), "{}", cell.label);
        }
    }
    assert_eq!(actuator_cells, 1);
}
