//! GP accuracy and cost against the number of training points, for the paper's 2-DOF arm and
//! the 3-DOF arm: held-out RMS and maximum error against the noise-free distorted camera, fit
//! time, and per-call prediction cost (mean + Jacobian).
//!
//! `cargo run --release --example gp_accuracy`

use std::time::Instant;

use aift::gp::{FitOptions, derive_box, evaluate_held_out, sample_training_set};
use aift::sensors::{Camera, CameraConfig};

fn main() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let cases = [
        (
            "urdf/planar_2dof.urdf",
            vec![
                vec![-std::f64::consts::FRAC_PI_2, 0.0],
                vec![-0.2, 0.5],
                vec![-0.6, 0.2],
            ],
        ),
        (
            "urdf/planar_3dof.urdf",
            vec![
                vec![-std::f64::consts::FRAC_PI_2, 0.0, 0.0],
                vec![-0.4, 0.6, 0.3],
                vec![-0.8, 0.4, -0.2],
            ],
        ),
    ];
    println!(
        "| joints | points | held-out RMS (mm) | held-out max (mm) | fit (s) | predict mean + Jacobian (us) |"
    );
    println!("|---|---|---|---|---|---|");
    for (file, points) in cases {
        let model = std::sync::Arc::new(aift::arm::load_urdf(&root.join(file)).unwrap());
        let ee = aift::arm::EndEffector::new(&model, "ee", [0.0; 3]).unwrap();
        let n_joints = model.joints.len();
        let mut arm = aift::arm::Kinematics::new(model);
        let camera = Camera::new(CameraConfig::default());
        let bounds = derive_box(&points, 0.3);
        for count in [100, 200, 400] {
            let set = sample_training_set(&mut arm, &ee, &camera, &bounds, count, 1);
            let t = Instant::now();
            let (model, report) = set.fit(&FitOptions::default()).unwrap();
            eprintln!(
                "evaluations {} per start {:?} hyper {:?}",
                report.evaluations, report.per_start, model.hyperparameters
            );
            let fit_s = t.elapsed().as_secs_f64();
            let err = evaluate_held_out(&model, &mut arm, &ee, &camera, 2000, 2);
            let q: Vec<f64> = bounds.iter().map(|[lo, hi]| 0.5 * (lo + hi)).collect();
            let (mut g, mut jac) = ([0.0; 2], vec![0.0; 2 * q.len()]);
            let reps = 20_000;
            let t = Instant::now();
            for _ in 0..reps {
                model.predict(std::hint::black_box(&q), &mut g, &mut jac);
            }
            let us = t.elapsed().as_secs_f64() * 1e6 / reps as f64;
            println!(
                "| {} | {count} | {:.2} | {:.2} | {fit_s:.2} | {us:.2} |",
                n_joints,
                err.rms * 1e3,
                err.max * 1e3
            );
        }
    }
}
