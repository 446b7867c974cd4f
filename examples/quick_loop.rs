//! Scratch closed loop (development aid): healthy or encoder-freeze reaching with fixed precisions.
use std::sync::Arc;

use aift::gp::{FitOptions, derive_box, sample_training_set};
use aift::plant::{Arm, ArmOptions};
use aift::sensors::{
    Camera, CameraConfig, ChannelLayout, FaultSpec, Readings, SensorConfig, SensorSuite,
};
use aift::uaic::{Controller, ControllerConfig};

fn main() {
    let freeze = std::env::args().nth(1).is_some_and(|a| a == "freeze");
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut arm =
        Arm::from_urdf(&root.join("urdf/planar_2dof.urdf"), ArmOptions::default()).unwrap();
    let camera = Camera::new(CameraConfig::default());
    let down = -std::f64::consts::FRAC_PI_2;
    let bounds = derive_box(&[vec![down, 0.0], vec![-0.2, 0.5], vec![-0.6, 0.2]], 0.3);
    let (gp, _) = sample_training_set(&mut arm, &camera, &bounds, 200, 1)
        .fit(&FitOptions::default())
        .unwrap();
    let layout = ChannelLayout::new(2);
    let faults = if freeze {
        vec![
            FaultSpec {
                channel: "enc1".into(),
                kind: "freeze".into(),
                start: 8.0,
                end: None,
                offset: None,
                rate: None,
                factor: None,
                value: None,
                probability: None,
                magnitude: None,
            }
            .to_fault(2)
            .unwrap(),
        ]
    } else {
        vec![]
    };
    let dt = 1e-3;
    let mut sensors = SensorSuite::new(layout, &SensorConfig::default(), camera, &faults, dt, 42);
    let mut config = ControllerConfig::default();
    if let Ok(ki) = std::env::var("KI") {
        let ki: f64 = ki.parse().unwrap();
        config.gains.ki = vec![ki, ki];
    }
    if let Ok(v) = std::env::var("KD") {
        let v: Vec<f64> = v.split(',').map(|x| x.parse().unwrap()).collect();
        config.gains.kd = v;
    }
    if let Ok(v) = std::env::var("ILIM") {
        let v: f64 = v.parse().unwrap();
        config.gains.integral_limit = vec![v, v];
    }
    let mut ctrl = Controller::new(config, layout, Arc::new(gp), dt);
    let precisions: Vec<f64> = sensors.sigmas().iter().map(|s| 1.0 / (s * s)).collect();
    arm.set_state(&[down, 0.0], &[0.0, 0.0]);
    let mut readings = Readings::missing(layout);
    let (mut se, mut count) = ([0.0; 2], 0.0);
    let t0 = std::time::Instant::now();
    for k in 0..20_000u64 {
        let t = k as f64 * dt;
        let target = if t < 7.5 { [-0.2, 0.5] } else { [-0.6, 0.2] };
        sensors.read(&arm, k, &mut readings);
        let report = ctrl.step(&readings, &target, &precisions);
        let u = report.torques.clone();
        let f = report.free_energy;
        let (q, _) = arm.state();
        for i in 0..2 {
            se[i] += (ctrl.mu()[i] - q[i]).powi(2);
        }
        count += 1.0;
        if k == 7499 {
            println!("at 7.5 s: q {:?}", arm.state().0);
        }
        if k % 1000 == 0 && std::env::var("QUIET").is_err() {
            println!(
                "t {t:5.1} q {:+.4} {:+.4} mu {:+.4} {:+.4} u {:+.2} {:+.2} F {:.3e}",
                q[0],
                q[1],
                ctrl.mu()[0],
                ctrl.mu()[1],
                u[0],
                u[1],
                f
            );
        }
        arm.set_torques(&u);
        arm.step(dt);
    }
    let (q, _) = arm.state();
    println!(
        "final q {:?}, MSE {:.3e} {:.3e}, {:.2} us/tick",
        q,
        se[0] / count,
        se[1] / count,
        t0.elapsed().as_secs_f64() * 1e6 / 20000.0
    );
}
