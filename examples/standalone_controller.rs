//! The u-AIC on its own, without rapier: hand its belief readings (some missing) and
//! precisions, hand f* the belief and a target, get torques. Here it closes the loop around a crude point model of a joint pair
//! written in a few lines, to show that nothing in the controller knows about the simulator.
//!
//! `cargo run --release --example standalone_controller`

use std::sync::Arc;

use aift::control::{Control, ControlConfig};
use aift::estimation::Estimator;
use aift::estimation::uaic::{Uaic, UaicConfig};
use aift::gp::{FitOptions, derive_box, sample_training_set};
use aift::sensors::{Camera, CameraConfig, CameraModel, ChannelLayout, Readings};

fn main() -> anyhow::Result<()> {
    // A camera model for the paper arm (the GP needs some source of camera data).
    let urdf = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
    let model = Arc::new(aift::arm::load_urdf(&urdf)?);
    let ee = aift::arm::EndEffector::new(&model, "ee", [0.0; 3])?;
    let mut arm = aift::arm::Kinematics::new(model);
    let camera = Camera::new(CameraConfig::default());
    let bounds = derive_box(&[vec![-1.57, 0.0], vec![-0.2, 0.5]], 0.3);
    let (gp, _) =
        sample_training_set(&mut arm, &ee, &camera, &bounds, 150, 1).fit(&FitOptions::default())?;

    let layout = ChannelLayout::new(2, CameraModel::Pinhole);
    let dt = 1e-3;
    let mut belief = Uaic::new(
        UaicConfig::default(),
        aift::estimation::models::GpCamera::shared(layout, Arc::new(gp)),
        dt,
    );
    let mut control = Control::new(&ControlConfig::default());
    let precisions = [1e6, 1e6, 1e6, 1e6, 1e4, 1e4];
    // A toy plant: two decoupled, heavily damped joints with gravity-like offsets.
    let (mut q, mut qd) = ([-1.0f64, 0.2], [0.0f64, 0.0]);
    let target = [-0.4, 0.4];
    for k in 0..5000 {
        let p = {
            let x = 1.0446 * q[0].cos() + 1.0111 * (q[0] + q[1]).cos();
            let z = 1.0446 * q[0].sin() + 1.0111 * (q[0] + q[1]).sin();
            camera.project(&nalgebra::Vector3::new(x, 0.0, z))
        };
        let mut readings = Readings::missing(&layout);
        readings.values[0] = Some(q[0]);
        readings.values[1] = Some(q[1]);
        readings.values[2] = Some(qd[0]);
        readings.values[3] = Some(qd[1]);
        // The camera drops out for the second half second.
        if !(500..1000).contains(&k) {
            readings.values[4] = p.map(|v| v[0]);
            readings.values[5] = p.map(|v| v[1]);
        }
        let free_energy = belief.step(&readings, &precisions).free_energy;
        let torques = control.step(belief.mu(), belief.mu_p(), &target, dt);
        let u = [torques[0], torques[1]];
        for i in 0..2 {
            let qdd = (u[i] - 100.0 * qd[i] - 10.0 * q[i].cos()) / 5.0;
            qd[i] += dt * qdd;
            q[i] += dt * qd[i];
        }
        if k % 1000 == 0 {
            println!(
                "t {:.1} s: q ({:+.3}, {:+.3}) belief ({:+.3}, {:+.3}) F {:.1}",
                k as f64 * dt,
                q[0],
                q[1],
                belief.mu()[0],
                belief.mu()[1],
                free_energy.unwrap_or(f64::NAN)
            );
        }
    }
    println!(
        "final q ({:+.4}, {:+.4}), target ({}, {})",
        q[0], q[1], target[0], target[1]
    );
    Ok(())
}
