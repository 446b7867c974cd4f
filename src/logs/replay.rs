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

use super::LogError;
use super::recorded::RecordedLog;
use crate::estimation::EstimatorInput;
use crate::precision::{Calibration, PrecisionInput};
use crate::scenario::metrics::{ActuatorAlarms, DivergenceGuard, RunMetrics};
use crate::scenario::runner::{Observer, Observers, Outcome, RunStart, TickRecord};
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

/// The ticks of `dt` that cover `log` (the last sample's tick plus one), checked against
/// [`MAX_TICKS`].
pub fn ticks_of(log: &RecordedLog, dt: f64) -> Result<u64, LogError> {
    let last = log.samples.last().map_or(0.0, |s| s.t);
    // (Times are finite and non-negative: checked when read.)
    if last / dt >= MAX_TICKS as f64 {
        return Err(LogError::Bad {
            path: log.source.clone(),
            field: "time".into(),
            message: format!(
                "the log spans {last} s: at dt = {dt} s more than the {MAX_TICKS} ticks replayed"
            ),
        });
    }
    Ok(tick_of(last, dt) + 1)
}

/// Makes `setup` the replay's: its duration covers `log` (checked: call it before any output is
/// staged), and its method and seed are `method` and `seed`.
pub fn prepare(
    setup: &mut RunSetup,
    log: &RecordedLog,
    method: Method,
    seed: u64,
) -> Result<(), LogError> {
    let dt = setup.scenario().dt;
    let ticks = ticks_of(log, dt)?;
    let sc = &mut setup.loaded.scenario;
    sc.duration = ticks as f64 * dt;
    sc.precision.method = method;
    sc.seed = seed;
    Ok(())
}

/// Runs `method` over `log` with `setup` (made the replay's by [`prepare`], so that the
/// metrics' windows fit the log). `extra` observers see every
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
    let ticks = ticks_of(log, dt).map_err(|e| ScenarioError::Invalid {
        path: log.source.clone(),
        field: "time".into(),
        message: e.to_string(),
    })?;
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
    let mut actuator_alarms = ActuatorAlarms::new(n, dt);
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
        actuator_alarms.update(k, estimator.as_ref());
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
        if let Some(reason) = DivergenceGuard::check_belief(&record) {
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
        crate::scenario::metrics::RunDetectors {
            detection: precision.detection(),
            actuator_alarms: actuator_alarms.alarms(),
            ..Default::default()
        },
        wall_seconds,
    );
    Ok((result, info))
}
