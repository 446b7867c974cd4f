//! A method run over recorded readings and applied torques (`aift replay`): the estimator and
//! the precision method step through the log tick by tick, the controller and the plant are not
//! in the loop (docs/logs.md, "Logs in").
//!
//! Ticks are the scenario's `dt` from the log's first joint state. A sample at time t enters at
//! the first tick at or after t (k = ceil(t / dt)); a tick no sample entered has every reading
//! missing (the estimator predicts through it, as for a dropped reading); two samples in one
//! tick: the later one's values win (counted as superseded). The applied torque is held from
//! the last joint state (a motor's command is held between updates), and, as in a live run,
//! the estimator at tick k is given the torque applied over the step before it.
//!
//! The run is measured by the live run's metrics (`RunMetrics`): detections, isolation and
//! false alarms against the faults the scenario declares (a replay of a log with no declared
//! fault counts every detection as a false alarm: an alarm); the plant's state is unknown, so
//! belief errors are NaN.

use std::time::Instant;

use super::recorded::RecordedLog;
use crate::estimation::EstimatorInput;
use crate::precision::{Calibration, PrecisionInput};
use crate::scenario::metrics::RunMetrics;
use crate::scenario::runner::{
    DivergenceReason, Observer, Observers, Outcome, RunStart, TickRecord,
};
use crate::scenario::{MAX_TICKS, Method, RunResult, RunSetup, ScenarioError};
use crate::sensors::Readings;

/// How the log's samples met the tick grid.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayInfo {
    pub source: String,
    pub described: String,
    pub samples: usize,
    pub ticks: u64,
    /// Ticks with no sample (every reading missing).
    pub empty_ticks: u64,
    /// Channel values overwritten by a later sample of the same tick.
    pub superseded: u64,
}

/// The tick a sample at `t` (s from the first) enters at.
pub fn tick_of(t: f64, dt: f64) -> u64 {
    (t / dt - 1e-9).ceil().max(0.0) as u64
}

/// The duration (s) a scenario needs to cover `log` at tick length `dt`: the last sample's tick
/// plus one, in ticks of `dt`.
pub fn duration_of(log: &RecordedLog, dt: f64) -> f64 {
    let last = log.samples.last().map_or(0.0, |s| s.t);
    (tick_of(last, dt) + 1) as f64 * dt
}

/// Runs `method` over `log` with `setup` (whose scenario's duration should be
/// [`duration_of`] the log, so that the metrics' windows fit it). `extra` observers see every
/// tick (a trajectory writer, the plots' recorder).
pub fn replay(
    setup: &RunSetup,
    method: Method,
    seed: u64,
    calibration: Option<&Calibration>,
    log: &RecordedLog,
    extra: &mut Observers<'_>,
) -> Result<(RunResult, ReplayInfo), ScenarioError> {
    let sc = setup.scenario();
    let dt = sc.dt;
    let layout = setup.layout;
    let n = layout.n_joints();
    let last = log.samples.last().map_or(0.0, |s| s.t);
    let ticks = tick_of(last, dt) + 1;
    if ticks > MAX_TICKS {
        return Err(ScenarioError::Invalid {
            path: log.source.clone(),
            field: "time".into(),
            message: format!(
                "{last} s at dt = {dt} s is {ticks} ticks; at most {MAX_TICKS} are replayed"
            ),
        });
    }
    let nominal = setup.nominal_precisions();
    let (mut estimator, mut precision) = crate::scenario::method::build(
        method,
        &crate::scenario::method::MethodContext {
            setup,
            model: setup.estimator_model(seed),
            layout: &layout,
            nominal: &nominal,
            calibration,
        },
    )?;
    let mut metrics = RunMetrics::new(setup, &nominal);
    let label = method.name();
    let start = RunStart {
        setup,
        label,
        seed,
        ticks,
    };
    extra.init(&start);
    let unknown = vec![f64::NAN; n];
    let mut readings = Readings::missing(&layout);
    let mut precisions = nominal.clone();
    let mut applied_before = vec![0.0; n];
    let mut applied = vec![0.0; n];
    let mut info = ReplayInfo {
        source: log.source.display().to_string(),
        described: log.described.clone(),
        samples: log.samples.len(),
        ticks,
        empty_ticks: 0,
        superseded: 0,
    };
    let mut next = 0;
    let mut outcome = Outcome::Completed;
    let clock = Instant::now();
    for k in 0..ticks {
        readings.values.fill(None);
        let mut any = false;
        while let Some(s) = log.samples.get(next) {
            if tick_of(s.t, dt) > k {
                break;
            }
            for (r, v) in readings.values.iter_mut().zip(&s.readings) {
                if v.is_some() {
                    if r.is_some() {
                        info.superseded += 1;
                    }
                    *r = *v;
                }
            }
            if let Some(e) = &s.effort {
                applied.copy_from_slice(e);
            }
            any = true;
            next += 1;
        }
        if !any {
            info.empty_ticks += 1;
        }
        precisions.copy_from_slice(precision.precisions());
        let estimate = estimator.update(&EstimatorInput {
            tick: k,
            readings: &readings,
            precisions: &precisions,
            applied_torques: &applied_before,
        });
        let free_energy = estimate.free_energy.unwrap_or(f64::NAN);
        precision.update(&PrecisionInput {
            tick: k,
            dt,
            layout: &layout,
            readings: &readings,
            estimate: estimator.estimate(),
            mu: estimator.mu(),
            mu_p: estimator.mu_p(),
            covariance: estimator.covariance(),
            torques: &applied,
        });
        let estimate = estimator.estimate();
        let record = TickRecord {
            tick: k,
            t: k as f64 * dt,
            layout: &layout,
            q: &unknown,
            qd: &unknown,
            mu: estimator.mu(),
            mu_p: estimator.mu_p(),
            target: &unknown,
            torques: &applied,
            applied: &applied,
            readings: &readings,
            precisions: &estimate.precisions_used,
            nominal: &nominal,
            free_energy,
            estimate,
            detection: precision.detection(),
        };
        extra.iter(&record);
        metrics.iter(&record);
        let insane = |v: &[f64], limit: f64| v.iter().any(|x| !x.is_finite() || x.abs() > limit);
        let diverged = if !estimate.finite {
            Some(DivergenceReason::BeliefNonFinite)
        } else if insane(record.mu, 1e3) || insane(record.mu_p, 1e4) {
            Some(DivergenceReason::BeliefOutOfRange)
        } else {
            None
        };
        if let Some(reason) = diverged {
            outcome = Outcome::Diverged { tick: k, reason };
            break;
        }
        applied_before.copy_from_slice(&applied);
    }
    let wall_seconds = clock.elapsed().as_secs_f64();
    extra.finish(&outcome);
    let result = metrics.finish(
        label,
        seed,
        outcome,
        &unknown,
        (precision.detection(), None),
        wall_seconds,
    );
    Ok((result, info))
}
