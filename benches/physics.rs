//! One physics tick (dt = 1 ms): the paper's 2-DOF arm (rapier with the default 2 solver
//! iterations, and 4), the planar 3-DOF arm, and the 2-DOF and 7-DOF (Panda) arms on both plants.

use std::path::PathBuf;
use std::sync::Arc;

use aift::plant::{Engine, Plant, PlantSettings};
use criterion::{Criterion, criterion_group, criterion_main};

fn plant(file: &str, settings: &PlantSettings) -> Box<dyn Plant> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(file);
    let model = Arc::new(aift::arm::load_urdf(&path).expect("the arm loads"));
    aift::plant::build(model, [0.0, 0.0, -9.81], settings).expect("the plant builds")
}

fn physics_tick(c: &mut Criterion) {
    let rapier = PlantSettings::default();
    let articulated = PlantSettings {
        engine: Engine::Articulated,
        ..PlantSettings::default()
    };
    let mut four = PlantSettings::default();
    four.rapier.solver_iterations = 4;
    for (name, file, settings, q, tau) in [
        (
            "physics_tick_2dof",
            "urdf/planar_2dof.urdf",
            &rapier,
            vec![-1.2, 0.8],
            vec![20.0, 5.0],
        ),
        (
            "physics_tick_2dof_4_iterations",
            "urdf/planar_2dof.urdf",
            &four,
            vec![-1.2, 0.8],
            vec![20.0, 5.0],
        ),
        (
            "physics_tick_3dof",
            "urdf/planar_3dof.urdf",
            &rapier,
            vec![-1.2, 0.8, 0.3],
            vec![20.0, 5.0, 1.0],
        ),
        (
            "physics_tick_2dof_articulated",
            "urdf/planar_2dof.urdf",
            &articulated,
            vec![-1.2, 0.8],
            vec![20.0, 5.0],
        ),
        (
            "physics_tick_7dof",
            "urdf/panda_7dof.urdf",
            &rapier,
            vec![0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.8],
            vec![1.0; 7],
        ),
        (
            "physics_tick_7dof_articulated",
            "urdf/panda_7dof.urdf",
            &articulated,
            vec![0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.8],
            vec![1.0; 7],
        ),
    ] {
        let mut arm = plant(file, settings);
        let qd = if q.len() == 2 {
            vec![0.5, -0.3]
        } else {
            vec![0.0; q.len()]
        };
        arm.set_state(&q, &qd);
        arm.set_torques(&tau);
        c.bench_function(name, |b| b.iter(|| arm.step(1e-3)));
    }
}

criterion_group!(benches, physics_tick);
criterion_main!(benches);
