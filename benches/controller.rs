//! One u-AIC tick (belief update with the GP's mean and Jacobian, corrections, F, f*) on the
//! paper arm's 200-point camera GP, and one precision-learner update.

use std::sync::Arc;

use aift::control::{Control, ControlConfig};
use aift::estimation::uaic::{Uaic, UaicConfig};
use aift::estimation::{Estimate, Estimator};
use aift::gp::{FitOptions, derive_box, sample_training_set};
use aift::precision::{Gradient, PrecisionBounds, PrecisionInput, PrecisionMethod};
use aift::sensors::{Camera, CameraConfig, CameraModel, ChannelLayout, Readings};
use criterion::{Criterion, criterion_group, criterion_main};

fn controller_tick(c: &mut Criterion) {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
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
    let (gp, _) = sample_training_set(&mut arm, &ee, &camera, &bounds, 200, 1)
        .fit(&FitOptions::default())
        .expect("fit");
    let layout = ChannelLayout::new(2, CameraModel::Pinhole);
    let mut belief = Uaic::new(
        UaicConfig::default(),
        aift::estimation::models::GpCamera::shared(layout, Arc::new(gp)),
        1e-3,
    );
    let mut control = Control::new(&ControlConfig::default());
    let readings = Readings {
        values: vec![
            Some(-0.6),
            Some(0.2),
            Some(0.01),
            Some(-0.01),
            Some(1.53),
            Some(-0.4),
        ],
    };
    let precisions = [1e6, 1e6, 1e6, 1e6, 1e4, 1e4];
    c.bench_function("uaic_tick_2dof_gp200", |b| {
        b.iter(|| {
            belief.step(std::hint::black_box(&readings), &precisions);
            control.step(belief.mu(), belief.mu_p(), &[-0.6, 0.2], 1e-3);
        })
    });
    let mut learner = Gradient::new(&precisions, 10.0, true, PrecisionBounds::default());
    let mut estimate = Estimate::new(&layout);
    estimate.residuals = vec![
        Some(1e-3),
        Some(-1e-3),
        Some(2e-4),
        Some(0.0),
        Some(1e-2),
        Some(-5e-3),
    ];
    c.bench_function("gradient_learner_update_6_channels", |b| {
        b.iter(|| {
            learner.update(&PrecisionInput {
                tick: 0,
                dt: 1e-3,
                layout: &layout,
                readings: &readings,
                estimate: std::hint::black_box(&estimate),
                mu: &[-0.6, 0.2],
                mu_p: &[0.0, 0.0],
                covariance: None,
                torques: &[0.0, 0.0],
            })
        })
    });
}

criterion_group!(benches, controller_tick);
criterion_main!(benches);
