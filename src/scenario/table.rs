//! Monte Carlo tables: every method over many seeds, in parallel, reduced in seed order so the
//! numbers are bit-identical whatever the thread count.

use rayon::prelude::*;

pub use super::method::ExternalMethod;
use super::runner::Run;
use super::{Method, RunResult, RunSetup, ScenarioError};
use crate::precision::Calibration;

/// One method's row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct TableRow {
    /// The method's name (a built-in method's, or the caller's for an [`ExternalMethod`]).
    pub name: String,
    /// The built-in method (None for an [`ExternalMethod`]).
    pub method: Option<Method>,
    pub seeds: usize,
    pub mse_faulty_mean: Option<f64>,
    pub mse_faulty_std: Option<f64>,
    pub mse_healthy_mean: Option<f64>,
    pub mse_healthy_std: Option<f64>,
    /// Mean MSE over all joints (used for the oracle ratio when no joint has a faulty sensor).
    pub mse_all_mean: f64,
    pub max_final_error_mean: f64,
    /// This method's faulty-joint MSE over the oracle's (all-joint MSE without faulty joints).
    pub ratio_to_oracle: Option<f64>,
    pub mse_post_fault_mean: Option<f64>,
    /// Mean of (detected_at - fault start) over runs that detected after the fault started.
    pub detection_delay_mean: Option<f64>,
    /// Fraction of runs whose isolation named a faulty channel (of runs that isolated).
    pub isolation_correct: Option<f64>,
    pub false_alarms: usize,
    /// Runs that did not end `completed`: diverged, stopped, or chattering (docs/method.md,
    /// "Metrics").
    pub diverged: usize,
}

/// A whole table: rows and every run.
#[derive(Clone, Debug)]
pub struct Table {
    pub rows: Vec<TableRow>,
    pub runs: Vec<RunResult>,
    pub seeds: Vec<u64>,
}

fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = if values.len() > 1 {
        values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (mean, var.sqrt())
}

/// Runs every method in `methods` for every seed in `seeds`; `progress` is called after each run.
///
/// ```no_run
/// use aift::scenario::{LoadedScenario, Method, RunSetup, calibrate, table};
///
/// let setup = RunSetup::prepare(LoadedScenario::embedded_default(&[])?)?;
/// // the detector methods need a calibration on healthy runs
/// let calibration = calibrate::calibrate(&setup, 50)?;
/// let seeds: Vec<u64> = (1..=20).collect();
/// let result = table::run_table(&setup, &Method::ALL, &seeds, Some(&calibration), &|| {})?;
/// print!("{}", aift::report::table_files::table_markdown(&setup, &result));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn run_table(
    setup: &RunSetup,
    methods: &[Method],
    seeds: &[u64],
    calibration: Option<&Calibration>,
    progress: &(dyn Fn() + Sync),
) -> Result<Table, ScenarioError> {
    run_table_with(setup, methods, &[], seeds, calibration, progress)
}

/// [`run_table`] with methods of the caller's beside the built-in ones (after them, in order).
pub fn run_table_with(
    setup: &RunSetup,
    methods: &[Method],
    external: &[ExternalMethod<'_>],
    seeds: &[u64],
    calibration: Option<&Calibration>,
    progress: &(dyn Fn() + Sync),
) -> Result<Table, ScenarioError> {
    for &m in methods {
        setup.check_method(m)?;
    }
    let mut names: Vec<String> = methods.iter().map(|m| m.name().to_string()).collect();
    for e in external {
        let bad = |message: String| ScenarioError::Invalid {
            path: setup.loaded.path.clone(),
            field: "methods".into(),
            message,
        };
        super::method::check_external_name(&e.name).map_err(bad)?;
        if names.contains(&e.name) {
            return Err(ScenarioError::Invalid {
                path: setup.loaded.path.clone(),
                field: "methods".into(),
                message: format!("{:?} is in the table twice (names must differ)", e.name),
            });
        }
        names.push(e.name.clone());
    }
    let columns = methods.len() + external.len();
    let jobs: Vec<(usize, u64)> = (0..columns)
        .flat_map(|c| seeds.iter().map(move |&s| (c, s)))
        .collect();
    let results: Vec<Result<RunResult, ScenarioError>> = jobs
        .par_iter()
        .map(|&(column, seed)| {
            let r = match methods.get(column) {
                Some(&method) => Run::new(setup, method)
                    .seed(seed)
                    .calibration(calibration)
                    .execute(),
                None => {
                    let e = &external[column - methods.len()];
                    (e.build)(setup, seed, "").and_then(|parts| {
                        Run::with_parts(setup, &e.name, parts).seed(seed).execute()
                    })
                }
            };
            progress();
            r
        })
        .collect();
    let runs: Vec<RunResult> = results.into_iter().collect::<Result<_, _>>()?;
    let first_fault = setup
        .faults
        .iter()
        .map(|f| f.start)
        .fold(None, |a: Option<f64>, s| Some(a.map_or(s, |a| a.min(s))));
    let mut rows: Vec<TableRow> = names
        .iter()
        .enumerate()
        .map(|(column, name)| {
            let mine: Vec<&RunResult> = runs.iter().filter(|r| r.method == *name).collect();
            let stat = |f: &dyn Fn(&RunResult) -> Option<f64>| {
                let v: Vec<f64> = mine.iter().filter_map(|r| f(r)).collect();
                (!v.is_empty()).then(|| mean_std(&v))
            };
            let faulty = stat(&|r| r.mse_faulty);
            let healthy = stat(&|r| r.mse_healthy);
            let all =
                stat(&|r| Some(r.mse_per_joint.iter().sum::<f64>() / r.mse_per_joint.len() as f64))
                    .map_or(f64::NAN, |s| s.0);
            let post = stat(&|r| {
                r.mse_post_fault_per_joint
                    .as_ref()
                    .map(|v| v.iter().sum::<f64>() / v.len() as f64)
            });
            let final_error = stat(&|r| Some(r.max_final_error)).map_or(f64::NAN, |s| s.0);
            let delay = first_fault.and_then(|f0| {
                stat(&|r| r.detected_at.filter(|d| *d >= f0 - 1e-9).map(|d| d - f0))
            });
            let isolated: Vec<bool> = mine.iter().filter_map(|r| r.isolation_correct).collect();
            TableRow {
                name: name.clone(),
                method: methods.get(column).copied(),
                seeds: mine.len(),
                mse_faulty_mean: faulty.map(|s| s.0),
                mse_faulty_std: faulty.map(|s| s.1),
                mse_healthy_mean: healthy.map(|s| s.0),
                mse_healthy_std: healthy.map(|s| s.1),
                mse_all_mean: all,
                max_final_error_mean: final_error,
                ratio_to_oracle: None,
                mse_post_fault_mean: post.map(|s| s.0),
                detection_delay_mean: delay.map(|s| s.0),
                isolation_correct: (!isolated.is_empty()).then(|| {
                    isolated.iter().filter(|b| **b).count() as f64 / isolated.len() as f64
                }),
                false_alarms: mine.iter().filter(|r| r.false_alarm).count(),
                diverged: mine
                    .iter()
                    .filter(|r| r.outcome != super::Outcome::Completed)
                    .count(),
            }
        })
        .collect();
    if let Some(oracle) = rows
        .iter()
        .find(|r| r.method == Some(Method::Oracle))
        .cloned()
    {
        for row in &mut rows {
            row.ratio_to_oracle = match (row.mse_faulty_mean, oracle.mse_faulty_mean) {
                (Some(m), Some(o)) => Some(m / o),
                _ => Some(row.mse_all_mean / oracle.mse_all_mean),
            };
        }
    }
    Ok(Table {
        rows,
        runs,
        seeds: seeds.to_vec(),
    })
}
