//! Which joints the camera can check: at a scenario's start and at each of its targets, the
//! information one camera frame carries about each joint, in encoder readings
//! (`Camera::joint_sensitivity` x the encoder's sigma: the true camera and the arm's own URDF).
//! Near zero, nothing but the joint's own sensors and the dynamics can check that joint (an end
//! effector on the last joint's axis; a joint moving it along the line of sight), and an encoder
//! drift there looks like a tachometer bias to every method but the oracle (docs/method.md,
//! "Sensors nobody else can check").
//!
//! `cargo run --release --example camera_sensitivity -- SCENARIO...` prints one tab-separated
//! row per scenario and joint: the scenario, the joint (from 1), and the least and greatest
//! sensitivity over the poses.

use std::path::PathBuf;

use aift::arm::kinematics::{EndEffector, forward};
use aift::scenario::LoadedScenario;
use aift::sensors::camera::Camera;
use nalgebra::Isometry3;

fn main() -> anyhow::Result<()> {
    let paths: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    anyhow::ensure!(
        !paths.is_empty(),
        "usage: camera_sensitivity SCENARIO.toml [SCENARIO.toml ...]"
    );
    println!("scenario\tjoint\tmin_encoder_readings\tmax_encoder_readings");
    for path in &paths {
        let loaded = LoadedScenario::from_file(path, &[])?;
        let model = loaded.arm_model()?;
        let sc = &loaded.scenario;
        let ee = EndEffector::new(&model, &sc.robot.ee_link, sc.robot.ee_offset)?;
        let camera = Camera::new(sc.camera.clone());
        let n = model.joints.len();
        let mut poses = vec![Isometry3::identity(); model.bodies.len()];
        let (mut least, mut most) = (vec![f64::INFINITY; n], vec![0.0_f64; n]);
        let start = std::iter::once(&sc.initial.q);
        for q in start.chain(sc.targets.iter().map(|t| &t.q)) {
            forward(&model, q, &mut poses);
            let sensitivity = camera.joint_sensitivity(&model, &ee, &poses).map_err(|e| {
                anyhow::anyhow!("{}: the camera sees nothing: {e:?}", path.display())
            })?;
            for (j, s) in sensitivity.iter().enumerate() {
                let readings = s * sc.sensors.encoder_sigma;
                least[j] = least[j].min(readings);
                most[j] = most[j].max(readings);
            }
        }
        for j in 0..n {
            println!(
                "{}\t{}\t{:.3e}\t{:.3e}",
                path.display(),
                j + 1,
                least[j],
                most[j]
            );
        }
    }
    Ok(())
}
