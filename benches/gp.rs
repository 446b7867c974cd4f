//! GP prediction (mean + Jacobian) per control tick: N = 100, 200, 400 points, 2 joints.

use std::path::PathBuf;

use aift::gp::{FitOptions, derive_box, sample_training_set};
use aift::sensors::{Camera, CameraConfig};
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};

fn gp_predict(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
    let model = std::sync::Arc::new(aift::arm::load_urdf(&path).expect("paper arm"));
    let ee = aift::arm::EndEffector::new(&model, "ee", [0.0; 3]).expect("an ee link");
    let mut arm = aift::arm::Kinematics::new(model);
    let camera = Camera::new(CameraConfig::default());
    let bounds = derive_box(
        &[
            vec![-std::f64::consts::FRAC_PI_2, 0.0],
            vec![-0.2, 0.5],
            vec![-0.6, 0.2],
        ],
        0.3,
    );
    let mut group = c.benchmark_group("gp_predict_2dof");
    for n in [100, 200, 400] {
        let (model, _) = sample_training_set(&mut arm, &ee, &camera, &bounds, n, 1)
            .fit(&FitOptions::default())
            .expect("fit");
        let q = [-0.6, 0.2];
        let (mut g, mut jac) = ([0.0; 2], [0.0; 4]);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| model.predict(std::hint::black_box(&q), &mut g, &mut jac))
        });
    }
    group.finish();
}

criterion_group!(benches, gp_predict);
criterion_main!(benches);
