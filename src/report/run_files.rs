//! The files of one run: trajectory (streamed while the run goes), summary, the scenario as run,
//! plots, and what is needed to repeat the run from its folder alone (URDF, GP model, detector
//! calibration). [`run_staged`] does all of it into a staged folder, which the caller moves into
//! place only when every file is written.

use std::path::{Path, PathBuf};

use serde_json::json;

use super::{ReportError, plots, write_atomic};
use crate::fsio::{self, Staged};
use crate::precision::Calibration;
use crate::scenario::{
    Method, ObserverMode, Observers, Run, RunResult, RunSetup, ScenarioError, TrajectoryColumns,
    TrajectoryRecorder, TrajectorySchema, TrajectoryWriter,
};

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
/// The run's page (`report.html`).
pub const REPORT: &str = super::html::REPORT;

/// Rows the plots and report.html are drawn from (the run is decimated to at most this many as
/// it goes).
pub const PLOT_ROWS: usize = super::html::REPORT_ROWS;

/// Version of summary.json's layout.
pub const SUMMARY_FORMAT: u32 = 2;

/// The summary of a run as JSON.
pub fn summary_json(setup: &RunSetup, result: &RunResult) -> serde_json::Value {
    let channels = &result.channels;
    let per_channel = |v: &[f64]| -> serde_json::Map<String, serde_json::Value> {
        channels
            .iter()
            .zip(v)
            .map(|(c, x)| (c.clone(), json!(x)))
            .collect()
    };
    let dt = setup.scenario().dt;
    let ended = match result.outcome.early_end() {
        Some((tick, reason)) => json!({"t": tick as f64 * dt, "reason": reason}),
        None => serde_json::Value::Null,
    };
    let layout = setup.layout;
    let names = |cs: &[usize]| cs.iter().map(|&c| layout.name(c)).collect::<Vec<_>>();
    json!({
        "format_version": SUMMARY_FORMAT,
        "aift_version": env!("CARGO_PKG_VERSION"),
        "scenario": setup.scenario().name,
        "conditions": setup.conditions().json(),
        "method": result.method,
        "seed": result.seed,
        "outcome": result.outcome.name(),
        "diverged": ended,
        "chattering": match &result.outcome {
            crate::scenario::Outcome::Chattering(c) => json!(c.describe()),
            _ => serde_json::Value::Null,
        },
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
        "false_alarms": result.false_alarms,
        "detections": result.detections.iter().map(|d| json!({
            "t": d.t, "channels": names(&d.channels),
        })).collect::<Vec<_>>(),
        "faults": result.faults.iter().map(|f| json!({
            "channel": f.label,
            "kind": f.kind,
            "start": f.start,
            "end": f.end,
            "joints": f.joints.iter().map(|j| j + 1).collect::<Vec<_>>(),
            "detected_at": f.detected_at,
            "delay": f.delay,
            "isolated": f.isolated,
            "isolation_correct": f.isolation_correct,
            "mse_during": f.mse_during,
        })).collect::<Vec<_>>(),
        "actuator_faults": result.actuator_faults.iter().map(actuator_fault_json).collect::<Vec<_>>(),
        "disturbances": result.disturbances.iter().map(|d| json!({
            "disturbance": d.label,
            "kind": d.kind,
            "start": d.start,
            "end": d.end,
            "sensor_alarms": d.sensor_alarms,
            "momentum_alarms": d.momentum_alarms,
            "actuator_alarms": d.actuator_alarms,
        })).collect::<Vec<_>>(),
        "max_contact_normal_force": result.max_contact_normal_force,
        "momentum": result.momentum.as_ref().map(|m| json!({
            "thresholds": m.thresholds,
            "largest": m.largest,
            "alarms": m.alarms.iter().map(|(t, j)| json!({
                "t": t, "joint": crate::plant::actuators::motor_name(*j),
            })).collect::<Vec<_>>(),
            "false_alarms": m.false_alarms,
        })),
        "actuator_alarms": result.actuator_alarms.as_ref().map(|a| json!({
            "alarms": a.iter().map(|(t, j)| json!({
                "t": t, "joint": crate::plant::actuators::motor_name(*j),
            })).collect::<Vec<_>>(),
            "false_alarms": result.actuator_false_alarms,
        })),
        "final_health": per_channel(&result.final_health),
        "min_health_last_5s": per_channel(&result.min_health_last_5s),
        "ticks_per_second": result.ticks_per_second(),
    })
}

/// The scenario exactly as run: every default filled in, method and seed set, and file paths
/// pointing at the copies in the run folder.
pub fn resolved_scenario(
    setup: &RunSetup,
    method: Option<Method>,
    seed: u64,
    with_calibration: bool,
) -> String {
    let mut s = setup.scenario().clone();
    if let Some(method) = method {
        s.precision.method = method;
    }
    s.seed = seed;
    // Derived values pinned, so the file runs the same even if a default changes.
    let (pm, pv) = s.belief.prior_precisions(s.dt);
    s.belief.prior_position_precision = Some(pm);
    s.belief.prior_velocity_precision = Some(pv);
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

/// Writes every file of a run but the trajectory into `dir` (which must exist); `plots_rows`
/// holds the (decimated) rows the plots and report.html are drawn from, `trajectory_rows` the
/// rows of the trajectory file.
#[allow(clippy::too_many_arguments)] // one private writer of the run folder's fixed files
fn write_run(
    dir: &Path,
    setup: &RunSetup,
    method: Option<Method>,
    result: &RunResult,
    plots_rows: &TrajectoryRecorder,
    trajectory_rows: u64,
    calibration: Option<&Calibration>,
    replay: Option<&crate::logs::ReplayInfo>,
) -> Result<(), ReportError> {
    let urdf = setup
        .loaded
        .read_relative(&setup.scenario().robot.urdf, fsio::MAX_URDF_BYTES)?
        .1;
    write_atomic(&dir.join(ROBOT), urdf.as_bytes())?;
    write_atomic(&dir.join(GP_MODEL), setup.gp.to_json().as_bytes())?;
    if let Some(cal) = calibration {
        write_atomic(&dir.join(CALIBRATION), cal.to_json().as_bytes())?;
    }
    let resolved = resolved_scenario(setup, method, result.seed, calibration.is_some());
    write_atomic(&dir.join(RESOLVED), resolved.as_bytes())?;
    let fault = setup
        .faults
        .iter()
        .map(|f| f.start)
        .fold(None, |a: Option<f64>, s| Some(a.map_or(s, |a| a.min(s))));
    plots::joint_angles(&dir.join(PLOT_JOINTS), plots_rows, fault)?;
    plots::health(&dir.join(PLOT_HEALTH), plots_rows, fault)?;
    plots::detector(&dir.join(PLOT_DETECTOR), plots_rows, fault)?;
    plots::free_energy(&dir.join(PLOT_FREE_ENERGY), plots_rows, fault)?;
    let mut summary_doc = summary_json(setup, result);
    if let Some(info) = replay {
        summary_doc["replay"] = json!({
            "log": info.source,
            "read": info.described,
            "samples": info.samples,
            "ticks": info.ticks,
            "empty_ticks": info.empty_ticks,
            "superseded": info.superseded,
        });
    }
    let summary = serde_json::to_string_pretty(&summary_doc).expect("a summary always serialises");
    write_atomic(&dir.join(SUMMARY), summary.as_bytes())?;
    let page = super::html::run_page(&summary_doc, Some(&resolved), plots_rows, trajectory_rows);
    write_atomic(&dir.join(super::html::REPORT), page.as_bytes())
}

/// Executes `run` and writes the whole run folder into `staged`: the trajectory streams to its
/// file while the run goes (every `record_every`-th tick), so memory does not grow with the run.
/// The caller commits `staged` (or drops it, and nothing appears: after an interrupted run, say).
pub fn run_staged(staged: &Staged, run: Run<'_>) -> Result<RunResult, ReportError> {
    run_staged_with(staged, run, &RunFileOptions::default())
}

/// trajectory.csv streamed while a run goes, and the rows its plots are drawn from.
struct TrajectoryFiles {
    path: PathBuf,
    every: u64,
    writer: TrajectoryWriter<std::fs::File>,
    /// The rows of the trajectory file (every `record_every`-th tick), decimated as a reader of
    /// that file decimates them: `aift report` on the folder draws the same page.
    plot_rows: TrajectoryRecorder,
}

impl TrajectoryFiles {
    fn create(dir: &Path, setup: &RunSetup) -> Result<Self, ReportError> {
        let path = dir.join(TRAJECTORY);
        let file = std::fs::File::create(&path).map_err(|source| fsio::FsError::Write {
            path: path.clone(),
            source,
        })?;
        let every = setup.scenario().record_every;
        Ok(Self {
            writer: TrajectoryWriter::new(TrajectorySchema::new(&setup.layout), file),
            plot_rows: TrajectoryRecorder::bounded_with_stride(&setup.layout, PLOT_ROWS, every),
            path,
            every,
        })
    }

    fn observe<'a>(&'a mut self, observers: &mut Observers<'a>) {
        observers.push(&mut self.writer, ObserverMode::Every(self.every));
        observers.push(&mut self.plot_rows, ObserverMode::Always);
    }

    /// Flushes the file to disk; the plots' rows and how many rows the file has.
    fn finish(self) -> Result<(TrajectoryRecorder, u64), ReportError> {
        let write_err = |source| fsio::FsError::Write {
            path: self.path.clone(),
            source,
        };
        let rows = self.writer.rows();
        self.writer
            .finish()
            .map_err(write_err)?
            .sync_all()
            .map_err(write_err)?;
        Ok((self.plot_rows, rows))
    }
}

/// What a run folder holds beyond its fixed files.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunFileOptions {
    /// Also write the run as ROS 2 messages in an MCAP file (`run.mcap`; `crate::logs`). Off by
    /// default: the file is written beside trajectory.csv, not instead of it, and costs about
    /// as much time and disk as the CSV again.
    pub mcap: bool,
}

/// [`run_staged`] with `options`.
pub fn run_staged_with(
    staged: &Staged,
    run: Run<'_>,
    options: &RunFileOptions,
) -> Result<RunResult, ReportError> {
    let setup = run.setup();
    let method = run.method();
    let dir = staged.path().to_path_buf();
    let every = setup.scenario().record_every;
    let mut files = TrajectoryFiles::create(&dir, setup)?;
    let calibration = run.calibration_given();
    let mut observers = Observers::new();
    files.observe(&mut observers);
    let mcap_path = dir.join(crate::logs::RUN_MCAP);
    let mcap_err = |e: mcap::McapError| fsio::FsError::Write {
        path: mcap_path.clone(),
        source: std::io::Error::other(e.to_string()),
    };
    let mut mcap = match options.mcap {
        true => {
            let file =
                std::fs::File::create(&mcap_path).map_err(|source| fsio::FsError::Write {
                    path: mcap_path.clone(),
                    source,
                })?;
            Some(
                crate::logs::McapRecorder::new(setup, std::io::BufWriter::new(file))
                    .map_err(mcap_err)?,
            )
        }
        false => None,
    };
    if let Some(m) = mcap.as_mut() {
        observers.push(m, ObserverMode::Every(every));
    }
    let result = run.execute_with(&mut observers)?;
    drop(observers);
    if let Some(m) = mcap {
        let file = m.finish().map_err(mcap_err)?;
        file.into_inner()
            .map_err(|e| fsio::FsError::Write {
                path: mcap_path.clone(),
                source: e.into_error(),
            })?
            .sync_all()
            .map_err(|source| fsio::FsError::Write {
                path: mcap_path.clone(),
                source,
            })?;
    }
    let (plot_rows, trajectory_rows) = files.finish()?;
    write_run(
        &dir,
        setup,
        method,
        &result,
        &plot_rows,
        trajectory_rows,
        calibration,
        None,
    )?;
    Ok(result)
}

/// `aift replay`: `method` run over a recorded log ([`crate::logs::replay`]) into the run
/// folder `staged`: trajectory.csv (the plant's columns NaN), summary.json with a `replay`
/// section, the plots and report.html. `setup`'s duration should cover the log
/// ([`crate::logs::replay::duration_of`]).
pub fn replay_staged(
    staged: &Staged,
    setup: &RunSetup,
    method: Method,
    seed: u64,
    calibration: Option<&Calibration>,
    log: &crate::logs::RecordedLog,
) -> Result<(RunResult, crate::logs::ReplayInfo), ReportError> {
    let dir = staged.path().to_path_buf();
    let mut files = TrajectoryFiles::create(&dir, setup)?;
    let mut observers = Observers::new();
    files.observe(&mut observers);
    let (result, info) =
        crate::logs::replay(setup, method, seed, calibration, log, &mut observers)?;
    drop(observers);
    let (plot_rows, trajectory_rows) = files.finish()?;
    write_run(
        &dir,
        setup,
        Some(method),
        &result,
        &plot_rows,
        trajectory_rows,
        calibration,
        Some(&info),
    )?;
    Ok((result, info))
}

/// Executes `run` without touching disk: the result, its summary (as summary.json has it) and
/// the whole trajectory (every `record_every`-th tick, as trajectory.csv has it). The
/// trajectory's size is checked before the run starts.
pub fn run_in_memory(
    run: Run<'_>,
) -> Result<(RunResult, serde_json::Value, TrajectoryColumns), ScenarioError> {
    let setup = run.setup();
    let sc = setup.scenario();
    let mut columns =
        TrajectoryColumns::new(&setup.layout, sc.ticks(), sc.record_every).map_err(|message| {
            ScenarioError::Invalid {
                path: setup.loaded.path.clone(),
                field: "record_every".into(),
                message,
            }
        })?;
    let mut observers = Observers::new();
    observers.push(&mut columns, ObserverMode::Every(sc.record_every));
    let result = run.execute_with(&mut observers)?;
    drop(observers);
    let summary = summary_json(setup, &result);
    Ok((result, summary, columns))
}

/// One actuator fault's entry of `metrics.json` (joints and motors 1-based).
fn actuator_fault_json(f: &crate::scenario::ActuatorOutcome) -> serde_json::Value {
    json!({
        "joint": f.label,
        "kind": f.kind,
        "start": f.start,
        "end": f.end,
        "joints": f.joints.iter().map(|j| j + 1).collect::<Vec<_>>(),
        "sensor_alarms": f.sensor_alarms,
        "mse_during": f.mse_during,
        "momentum_detected_at": f.momentum_detected_at,
        "momentum_delay": f.momentum_delay,
        "momentum_isolated": f.momentum_joint.map(crate::plant::actuators::motor_name),
        "momentum_isolation_correct": f.momentum_isolation_correct,
        "method_detected_at": f.method_detected_at,
        "method_delay": f.method_delay,
        "method_isolated": f.method_joint.map(crate::plant::actuators::motor_name),
        "method_isolation_correct": f.method_isolation_correct,
    })
}
