//! The files of one run: trajectory, summary, the scenario as run, plots, and what is needed to
//! repeat the run from its folder alone (URDF, GP model, detector calibration).

use std::path::{Path, PathBuf};

use serde_json::json;

use super::{ReportError, csv_text, plots, write_atomic};
use crate::precision::Calibration;
use crate::scenario::{Method, Outcome, RunResult, RunSetup, TrajectoryRecorder};
use crate::sensors::ChannelLayout;

/// Names of the files a run writes.
pub const TRAJECTORY: &str = "trajectory.csv";
pub const SUMMARY: &str = "summary.json";
pub const RESOLVED: &str = "scenario.resolved.toml";
pub const ROBOT: &str = "robot.urdf";
pub const GP_MODEL: &str = "gp.json";
pub const CALIBRATION: &str = "calibration.json";
pub const PLOT_JOINTS: &str = "joints.svg";
pub const PLOT_HEALTH: &str = "health.svg";
pub const PLOT_DETECTOR: &str = "detector.svg";
pub const PLOT_FREE_ENERGY: &str = "free_energy.svg";

/// The summary of a run as JSON.
pub fn summary_json(setup: &RunSetup, result: &RunResult) -> serde_json::Value {
    let layout = ChannelLayout::new(setup.model.joints.len());
    let channels: Vec<String> = layout.channels().map(|c| c.name()).collect();
    let per_channel = |v: &[f64]| -> serde_json::Map<String, serde_json::Value> {
        channels
            .iter()
            .zip(v)
            .map(|(c, x)| (c.clone(), json!(x)))
            .collect()
    };
    let diverged_at = match &result.outcome {
        Outcome::Diverged { tick, reason } => {
            json!({"t": *tick as f64 * setup.scenario().dt, "reason": reason})
        }
        Outcome::Completed => serde_json::Value::Null,
    };
    json!({
        "aift_version": env!("CARGO_PKG_VERSION"),
        "scenario": setup.scenario().name,
        "method": result.method.name(),
        "seed": result.seed,
        "outcome": result.outcome.name(),
        "diverged": diverged_at,
        "ticks": result.ticks_run,
        "mse_per_joint": result.mse_per_joint,
        "mse_faulty": result.mse_faulty,
        "mse_healthy": result.mse_healthy,
        "faulty_joints": result.faulty_joints.iter().map(|j| j + 1).collect::<Vec<_>>(),
        "mse_post_fault_per_joint": result.mse_post_fault_per_joint,
        "final_error_per_joint": result.final_error_per_joint,
        "max_final_error": result.max_final_error,
        "detected_at": result.detected_at,
        "detection_kind": result.detection_kind,
        "isolated_channel": result.isolated_channel,
        "isolation_correct": result.isolation_correct,
        "false_alarm": result.false_alarm,
        "final_health": per_channel(&result.final_health),
        "min_health_last_5s": per_channel(&result.min_health_last_5s),
        "ticks_per_second": result.ticks_per_second(),
    })
}

/// The scenario exactly as run: every default filled in, method and seed set, and file paths
/// pointing at the copies in the run folder.
pub fn resolved_scenario(
    setup: &RunSetup,
    method: Method,
    seed: u64,
    with_calibration: bool,
) -> String {
    let mut s = setup.scenario().clone();
    s.precision.method = method;
    s.seed = seed;
    s.robot.urdf = PathBuf::from(ROBOT);
    s.gp.model = Some(PathBuf::from(GP_MODEL));
    s.detector.calibration = with_calibration.then(|| PathBuf::from(CALIBRATION));
    let header = format!(
        "# Resolved by aift {} from {}: every default filled in. Re-run with\n# `aift run {RESOLVED}` from this folder.\n",
        env!("CARGO_PKG_VERSION"),
        setup.loaded.path.display()
    );
    header + &toml::to_string_pretty(&s).expect("a scenario always serialises")
}

/// Writes every file of a run into `dir` (which must exist).
pub fn write_run(
    dir: &Path,
    setup: &RunSetup,
    result: &RunResult,
    recorder: &TrajectoryRecorder,
    calibration: Option<&Calibration>,
) -> Result<(), ReportError> {
    let urdf = setup
        .loaded
        .read_relative(&setup.scenario().robot.urdf)
        .map_err(|source| ReportError::Write {
            path: dir.join(ROBOT),
            source,
        })?
        .1;
    write_atomic(&dir.join(ROBOT), urdf.as_bytes())?;
    write_atomic(&dir.join(GP_MODEL), setup.gp.to_json().as_bytes())?;
    if let Some(cal) = calibration {
        write_atomic(&dir.join(CALIBRATION), cal.to_json().as_bytes())?;
    }
    write_atomic(
        &dir.join(RESOLVED),
        resolved_scenario(setup, result.method, result.seed, calibration.is_some()).as_bytes(),
    )?;
    write_atomic(
        &dir.join(TRAJECTORY),
        csv_text(&recorder.header, recorder.rows.iter().map(Vec::as_slice)).as_bytes(),
    )?;
    let fault = setup
        .faults
        .iter()
        .map(|f| f.start)
        .fold(None, |a: Option<f64>, s| Some(a.map_or(s, |a| a.min(s))));
    plots::joint_angles(&dir.join(PLOT_JOINTS), recorder, fault)?;
    plots::health(&dir.join(PLOT_HEALTH), recorder, fault)?;
    plots::detector(&dir.join(PLOT_DETECTOR), recorder, fault)?;
    plots::free_energy(&dir.join(PLOT_FREE_ENERGY), recorder, fault)?;
    // The summary last: its presence marks a complete run folder.
    let summary = serde_json::to_string_pretty(&summary_json(setup, result))
        .expect("a summary always serialises");
    write_atomic(&dir.join(SUMMARY), summary.as_bytes())
}
