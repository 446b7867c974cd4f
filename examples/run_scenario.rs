//! What `aift run` does, from Rust: load a scenario, prepare the arm and GP, run one method with
//! a trajectory recorder, and write the run's files.
//!
//! `cargo run --release --example run_scenario -- [SCENARIO] [METHOD] [OUT_DIR]`

use std::path::PathBuf;

use aift::report::run_files;
use aift::scenario::{self, LoadedScenario, Method, RunSetup, TrajectoryRecorder, calibrate};
use aift::sensors::ChannelLayout;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let loaded = match args.first() {
        Some(path) => LoadedScenario::from_file(&PathBuf::from(path), &[])?,
        None => LoadedScenario::embedded_default(&[])?,
    };
    let method: Method = args
        .get(1)
        .map(|m| m.parse::<Method>())
        .transpose()
        .map_err(anyhow::Error::msg)?
        .unwrap_or(Method::PlAlways);
    let out = PathBuf::from(args.get(2).cloned().unwrap_or_else(|| "example-run".into()));

    let setup = RunSetup::prepare(loaded)?;
    let calibration = if method.needs_detector() {
        Some(calibrate::calibrate(
            &setup,
            setup.scenario().detector.calibration_runs,
        )?)
    } else {
        None
    };
    let mut recorder = TrajectoryRecorder::new(ChannelLayout::new(setup.model.joints.len()));
    let result = scenario::run(
        &setup,
        method,
        setup.scenario().seed,
        calibration.as_ref(),
        &mut recorder,
    )?;
    std::fs::create_dir_all(&out)?;
    run_files::write_run(&out, &setup, &result, &recorder, calibration.as_ref())?;
    println!(
        "{method}: {} | belief MSE per joint {:?} | final error {:.4} rad | files in {}",
        result.outcome.name(),
        result.mse_per_joint,
        result.max_final_error,
        out.display()
    );
    Ok(())
}
