//! What `aift table` does, from Rust: every method over N seeds in parallel, the detector
//! calibrated on separate healthy seeds, and the table files written.
//!
//! `cargo run --release --example monte_carlo_table -- [SEEDS] [OUT_DIR]`

use std::path::PathBuf;

use aift::report::table_files;
use aift::scenario::{LoadedScenario, Method, RunSetup, calibrate, table};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: u64 = args.first().map(|s| s.parse()).transpose()?.unwrap_or(5);
    let out = PathBuf::from(
        args.get(1)
            .cloned()
            .unwrap_or_else(|| "example-table".into()),
    );
    let setup = RunSetup::prepare(LoadedScenario::embedded_default(&[])?)?;
    let calibration = calibrate::calibrate(&setup, setup.scenario().detector.calibration_runs)?;
    let seeds: Vec<u64> = (1..=n).collect();
    let result = table::run_table(&setup, &Method::ALL, &seeds, Some(&calibration), &|| {})?;
    std::fs::create_dir_all(&out)?;
    table_files::write_table(&out, &setup, &result)?;
    print!("{}", table_files::table_markdown(&setup, &result));
    Ok(())
}
