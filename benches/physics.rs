//! One physics tick (dt = 1 ms): the paper's 2-DOF arm (default 2 solver iterations, and 4),
//! the planar 3-DOF arm, and the 2-DOF and 7-DOF (Panda) arms on both engines.

use std::path::PathBuf;

use aift::plant::{Arm, ArmOptions, Engine};
use criterion::{Criterion, criterion_group, criterion_main};

fn physics_tick(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
    let mut arm = Arm::from_urdf(&path, ArmOptions::default()).expect("paper arm");
    arm.set_state(&[-1.2, 0.8], &[0.5, -0.3]);
    arm.set_torques(&[20.0, 5.0]);
    c.bench_function("physics_tick_2dof", |b| b.iter(|| arm.step(1e-3)));
    let mut arm4 = Arm::from_urdf(
        &path,
        ArmOptions {
            solver_iterations: 4,
            ..ArmOptions::default()
        },
    )
    .expect("paper arm");
    arm4.set_state(&[-1.2, 0.8], &[0.5, -0.3]);
    arm4.set_torques(&[20.0, 5.0]);
    c.bench_function("physics_tick_2dof_4_iterations", |b| {
        b.iter(|| arm4.step(1e-3))
    });
    let path3 = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_3dof.urdf");
    if let Ok(mut arm3) = Arm::from_urdf(&path3, ArmOptions::default()) {
        arm3.set_state(&[-1.2, 0.8, 0.3], &[0.0; 3]);
        arm3.set_torques(&[20.0, 5.0, 1.0]);
        c.bench_function("physics_tick_3dof", |b| b.iter(|| arm3.step(1e-3)));
    }
    let articulated = ArmOptions {
        engine: Engine::Articulated,
        ..ArmOptions::default()
    };
    let mut arm_a = Arm::from_urdf(&path, articulated.clone()).expect("paper arm");
    arm_a.set_state(&[-1.2, 0.8], &[0.5, -0.3]);
    arm_a.set_torques(&[20.0, 5.0]);
    c.bench_function("physics_tick_2dof_articulated", |b| {
        b.iter(|| arm_a.step(1e-3))
    });
    let panda = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
    for (name, engine) in [
        ("physics_tick_7dof", Engine::Rapier),
        ("physics_tick_7dof_articulated", Engine::Articulated),
    ] {
        let options = ArmOptions {
            ee_link: PANDA_EE.to_string(),
            engine,
            ..ArmOptions::default()
        };
        let mut arm7 = Arm::from_urdf(&panda, options).expect("Panda");
        arm7.set_state(&[0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.8], &[0.0; 7]);
        arm7.set_torques(&[1.0; 7]);
        c.bench_function(name, |b| b.iter(|| arm7.step(1e-3)));
    }
}

/// The Panda scenarios' end-effector link.
const PANDA_EE: &str = "ee";

criterion_group!(benches, physics_tick);
criterion_main!(benches);
