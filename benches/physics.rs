//! One physics tick of the paper's 2-DOF arm (default settings: 4 solver iterations, dt = 1 ms).

use std::path::PathBuf;

use aift::plant::{Arm, ArmOptions};
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
}

criterion_group!(benches, physics_tick);
criterion_main!(benches);
