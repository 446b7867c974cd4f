//! What `aift run` does, from Rust: load a scenario, prepare the arm and GP, stage the output
//! folder, run one method with the trajectory streaming to its file, and move the folder into
//! place with every file written.
//!
//! `cargo run --release --example run_scenario -- [SCENARIO] [METHOD] [OUT_DIR]`

use std::path::PathBuf;

use aift::fsio::{OutputKind, Staged};
use aift::report::run_files;
use aift::scenario::{LoadedScenario, Method, Run, RunSetup, calibrate};

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
    // Checked before any work: where the folder goes, and that no other process writes it.
    let staged = Staged::begin(&out, OutputKind::Folder, true)?;
    let calibration = if method.needs_detector() {
        Some(calibrate::calibrate(
            &setup,
            setup.scenario().detector.calibration_runs,
        )?)
    } else {
        None
    };
    let run = Run::new(&setup, method).calibration(calibration.as_ref());
    let result = run_files::run_staged(&staged, run)?;
    staged.commit()?;
    println!(
        "{method}: {} | belief MSE per joint {:?} | final error {:.4} rad | files in {}",
        result.outcome.name(),
        result.mse_per_joint,
        result.max_final_error,
        out.display()
    );
    Ok(())
}
