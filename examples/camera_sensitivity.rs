//! Which joints the camera can check: at a scenario's start and at each of its targets, the
//! information one camera frame carries about each joint, in encoder readings
//! (`Camera::joint_sensitivity` x the encoder's sigma: the true camera and the arm's own URDF).
//! Near zero, nothing but the joint's own sensors and the dynamics can check that joint (an end
//! effector on the last joint's axis; a joint moving it along the line of sight), and an encoder
//! drift there looks like a tachometer bias to every method but the oracle (docs/method.md,
//! "Sensors nobody else can check").
//!
//! `cargo run --release --example camera_sensitivity -- SCENARIO...` prints one tab-separated
//! row per scenario and joint: the scenario, the joint (from 1), the least and greatest
//! sensitivity over the poses in encoder readings, and the same per radian in camera sigmas (S).
//! A pose at which the end effector is behind the camera counts as 0.

use std::path::PathBuf;

use aift::arm::kinematics::EndEffector;
use aift::scenario::LoadedScenario;
use aift::sensors::camera::Camera;

fn main() -> anyhow::Result<()> {
    let paths: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    anyhow::ensure!(
        !paths.is_empty(),
        "usage: camera_sensitivity SCENARIO.toml [SCENARIO.toml ...]"
    );
    println!(
        "scenario\tjoint\tmin_encoder_readings\tmax_encoder_readings\tmin_per_radian\tmax_per_radian"
    );
    for path in &paths {
        let loaded = LoadedScenario::from_file(path, &[])?;
        let model = loaded.arm_model()?;
        let sc = &loaded.scenario;
        let ee = EndEffector::new(&model, &sc.robot.ee_link, sc.robot.ee_offset)?;
        let qs = std::iter::once(&sc.initial.q).chain(sc.targets.iter().map(|t| &t.q));
        let (least, most) = Camera::new(sc.camera.clone()).joint_sensitivity_range(
            &model,
            &ee,
            qs.map(|q| q.as_slice()),
        );
        let sigma = sc.sensors.encoder_sigma;
        for (j, (l, m)) in least.iter().zip(&most).enumerate() {
            println!(
                "{}\t{}\t{:.3e}\t{:.3e}\t{:.3e}\t{:.3e}",
                path.display(),
                j + 1,
                l * sigma,
                m * sigma,
                l,
                m
            );
        }
    }
    Ok(())
}
