//! Accuracy and cost of each plant setting: rapier at 1-16 solver iterations (substeps), aift's
//! articulated engine with semi-implicit Euler and with RK4, on the paper arm, the paper arm
//! without damping and the Panda 7-DOF arm. Error: largest |q(T) - q_ref(T)| after a free swing
//! from rest (zero torque, 2 s; the Panda 0.5 s from its ready pose with gravity held plus a small
//! push, so that no joint limit is reached), against the articulated engine with RK4 at 64
//! substeps (which `tests/engines.rs` checks against the closed-form two-link dynamics to 1e-8).
//! Cost: wall time per 1 ms tick, the best of three.
//!
//! `cargo run --release --example plant_accuracy > results/plant_accuracy.md`

use std::time::Instant;

use aift::plant::{Engine, Integrator, Plant, PlantSettings};

fn arm(file: &str, engine: Engine, integrator: Integrator, iterations: usize) -> Box<dyn Plant> {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let model = std::sync::Arc::new(aift::arm::load_urdf(&root.join(file)).expect("arm"));
    let mut settings = PlantSettings {
        engine,
        ..PlantSettings::default()
    };
    match engine {
        Engine::Rapier => settings.rapier.solver_iterations = iterations,
        Engine::Articulated => {
            settings.articulated.substeps = iterations;
            settings.articulated.integrator = integrator;
        }
    }
    aift::plant::build(model, [0.0, 0.0, -9.81], &settings).expect("plant")
}

fn swing(arm: &mut dyn Plant, q0: &[f64], tau: &[f64], duration: f64) -> (Vec<f64>, f64) {
    let dt = 1e-3;
    let steps = (duration / dt).round() as usize;
    let mut best = f64::INFINITY;
    let mut q = Vec::new();
    for _ in 0..3 {
        arm.set_state(q0, &vec![0.0; q0.len()]);
        arm.set_torques(tau);
        let start = Instant::now();
        for _ in 0..steps {
            arm.step(dt);
        }
        best = best.min(start.elapsed().as_secs_f64() * 1e6 / steps as f64);
        q = arm.state().0;
    }
    (q, best)
}

fn main() {
    println!(
        "Produced by `cargo run --release --example plant_accuracy` (aift {}).\n",
        env!("CARGO_PKG_VERSION")
    );
    println!("| arm | case | engine | integrator | substeps | error (rad) | us per tick |");
    println!("|---|---|---|---|---|---|---|");
    let panda_q0 = vec![0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78];
    let cases: Vec<(&str, &str, Vec<f64>, f64)> = vec![
        ("urdf/planar_2dof.urdf", "paper arm", vec![0.3, 0.2], 2.0),
        (
            "urdf/planar_2dof_undamped.urdf",
            "paper arm, no damping",
            vec![0.3, 0.2],
            2.0,
        ),
        ("urdf/panda_7dof.urdf", "Panda 7-DOF", panda_q0, 0.5),
    ];
    for (file, label, q0, duration) in cases {
        let n = q0.len();
        let mut reference = arm(file, Engine::Articulated, Integrator::Rk4, 64);
        let tau = if n == 7 {
            let (_, g) =
                aift::arm::Dynamics::new(reference.model().clone().into(), [0.0, 0.0, -9.81])
                    .mass_matrix_and_gravity(&q0);
            let push = [2.0, 3.0, -1.0, 2.0, 0.05, -0.05, 0.005];
            g.iter().zip(push).map(|(g, p)| g + p).collect()
        } else {
            vec![0.0; n]
        };
        let case = if n == 7 {
            "0.5 s, gravity held + push"
        } else {
            "free swing, 2 s"
        };
        let (q_ref, _) = swing(reference.as_mut(), &q0, &tau, duration);
        let mut settings = vec![];
        for it in [1, 2, 4, 8, 16] {
            settings.push((Engine::Rapier, Integrator::Euler, it));
        }
        for it in [1, 2, 4] {
            settings.push((Engine::Articulated, Integrator::Euler, it));
        }
        settings.push((Engine::Articulated, Integrator::Rk4, 1));
        for (engine, integrator, it) in settings {
            let mut a = arm(file, engine, integrator, it);
            let (q, us) = swing(a.as_mut(), &q0, &tau, duration);
            let err = q
                .iter()
                .zip(&q_ref)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let engine = match engine {
                Engine::Rapier => "rapier",
                Engine::Articulated => "articulated",
            };
            let integrator = match (engine, integrator) {
                ("rapier", _) => "(rapier's)",
                (_, Integrator::Euler) => "euler",
                (_, Integrator::Rk4) => "rk4",
                (_, Integrator::ExplicitEuler) => "explicit-euler",
            };
            let default = if engine == "rapier" && it == 2 {
                " (default)"
            } else {
                ""
            };
            println!(
                "| {label} | {case} | {engine}{default} | {integrator} | {it} | {err:.1e} | {us:.2} |"
            );
        }
    }
}
