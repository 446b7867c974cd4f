//! What `aift replay` does, from Rust: a run written as MCAP, then a method run over that log
//! (its readings and applied torques) with the controller and the plant out of the loop, and
//! the detections of the two compared.
//!
//! `cargo run --release --example replay_log -- [SCENARIO] [METHOD] [OUT_DIR]`

use std::path::PathBuf;

use aift::fsio::{OutputKind, Staged};
use aift::logs::{RecordedLog, Topics, replay};
use aift::report::run_files;
use aift::scenario::{LoadedScenario, Method, Observers, Run, RunSetup};

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
        .unwrap_or(Method::Hybrid);
    anyhow::ensure!(
        !method.needs_detector(),
        "this example skips the detector's calibration: pick a method without one"
    );
    let out = PathBuf::from(args.get(2).cloned().unwrap_or_else(|| "example-log".into()));

    // A live run, written with its MCAP log.
    let mut setup = RunSetup::prepare(loaded)?;
    let staged = Staged::begin(&out, OutputKind::Folder, true)?;
    let options = run_files::RunFileOptions { mcap: true };
    let live = run_files::run_staged_with(&staged, Run::new(&setup, method), &options)?;
    staged.commit()?;

    // The log read back and replayed (in memory: no folder).
    let joints: Vec<String> = setup.model.joints.iter().map(|j| j.name.clone()).collect();
    let log = RecordedLog::read(
        &out.join(aift::logs::RUN_MCAP),
        &setup.layout,
        &joints,
        &Topics::default(),
    )?;
    let seed = setup.scenario().seed;
    replay::prepare(&mut setup, &log, method, seed)?;
    let (replayed, info) = replay(&setup, method, seed, None, &log, &mut Observers::new())?;
    println!(
        "{method}: live run detected at {:?} ({:?}); replay of {} ({} samples, {} ticks) at {:?} ({:?})",
        live.detected_at,
        live.isolated_channel,
        info.described,
        info.samples,
        info.ticks,
        replayed.detected_at,
        replayed.isolated_channel
    );
    Ok(())
}
