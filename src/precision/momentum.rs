//! The generalized momentum observer (De Luca and Mattone, ICRA 2003; Haddadin, De Luca and
//! Albu-Schaeffer, IEEE T-RO 2017, section IV): the classical detector and isolator of actuator
//! faults and collisions on a robot arm, usable beside any estimator (it reads the belief).
//!
//! With p = M(q) qd the generalized momentum, Lagrange's equations give
//! p' = tau + C(q, qd)^T qd - g(q) - D qd - F(qd) + tau_x, tau_x the torque the model does not
//! explain (an actuator fault, a contact, a payload). The residual
//! r(t) = K (p(t) - p(0) - int_0^t (tau + C^T qd - g - D qd - F + r) ds) obeys r' = K (tau_x - r):
//! a first-order filter of tau_x per joint, decoupled, so the joint whose residual grows is the
//! joint where the unexplained torque acts. docs/method.md, "Actuator faults".
//!
//! C^T qd = M' qd - C qd, with C qd + g the model's bias (RNEA at zero acceleration) and M' qd
//! the mass matrix's derivative along qd by a central difference of step 1e-6 rad (written by
//! hand: no crate gives M' for an `ArmModel`; tests check r against torques the model does not
//! explain). The integral is the rectangle rule at the tick (the rate of tick k-1 over
//! [k-1, k]).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::arm::ArmModel;
use crate::arm::dynamics::{Dynamics, FRICTION_RAMP};

/// Most momentum alarms a run keeps.
pub const MAX_MOMENTUM_ALARMS: usize = 10_000;

/// Settings of the momentum observer (`[momentum]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct MomentumConfig {
    /// Run the observer beside the method: its alarms and isolated joints go to summary.json.
    pub enabled: bool,
    /// Observer gain K (1/s): the residual follows an unexplained joint torque with time
    /// constant 1/K.
    pub gain: f64,
    /// Healthy runs (the scenario without faults, `no-ft`, seeds from 2^41) the thresholds are
    /// calibrated on. They are the no-ft belief's residuals: another method's belief (the
    /// hybrid's, a Kalman filter's) may leave other residuals on healthy runs.
    #[schemars(range(min = 1, max = 1000))]
    pub calibration_runs: usize,
    /// Threshold per joint: `margin` x the largest |r_j| the healthy runs showed.
    pub margin: f64,
    /// An alarm needs |r_j| above its threshold for this long (s); it re-arms once |r_j| falls
    /// below half the threshold.
    pub dwell: f64,
}

impl Default for MomentumConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            gain: 50.0,
            calibration_runs: 10,
            margin: 1.5,
            dwell: 0.02,
        }
    }
}

impl MomentumConfig {
    /// Checks the values; on error returns the offending field and why.
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        if !(self.gain.is_finite() && self.gain > 0.0 && self.gain <= 1e6) {
            return Err(crate::SettingError::new("gain", "must be in (0, 1e6] 1/s"));
        }
        if self.enabled && !(1..=1000).contains(&self.calibration_runs) {
            return Err(crate::SettingError::new(
                "calibration_runs",
                "must be in 1..=1000",
            ));
        }
        if !(self.margin.is_finite() && self.margin >= 1.0 && self.margin <= 1e6) {
            return Err(crate::SettingError::new("margin", "must be in [1, 1e6]"));
        }
        if !(self.dwell.is_finite() && (0.0..=1e3).contains(&self.dwell)) {
            return Err(crate::SettingError::new("dwell", "must be in [0, 1e3] s"));
        }
        Ok(())
    }
}

/// The observer itself: residual r per joint from the belief and the torques believed applied.
#[derive(Clone, Debug)]
pub struct MomentumObserver {
    dynamics: Dynamics,
    gain: f64,
    p0: Vec<f64>,
    integral: Vec<f64>,
    /// The integrand at the last tick (tau + C^T qd - g - D qd - F + r).
    rate: Vec<f64>,
    residual: Vec<f64>,
    started: bool,
    p: Vec<f64>,
    shifted: Vec<f64>,
    m_dot_qd: Vec<f64>,
}

/// Step of the central difference for M' qd (rad along qd).
const M_DOT_STEP: f64 = 1e-6;

impl MomentumObserver {
    /// An observer on the model `model` (the estimators' model: never the plant's own when the
    /// scenario has model error) under gravity `gravity`, with gain `gain` (1/s).
    pub fn new(model: Arc<ArmModel>, gravity: [f64; 3], gain: f64) -> Self {
        let n = model.joints.len();
        Self {
            dynamics: Dynamics::new(model, gravity),
            gain,
            p0: vec![0.0; n],
            integral: vec![0.0; n],
            rate: vec![0.0; n],
            residual: vec![0.0; n],
            started: false,
            p: vec![0.0; n],
            shifted: vec![0.0; n],
            m_dot_qd: vec![0.0; n],
        }
    }

    /// The residual after the last update (N m per joint).
    pub fn residual(&self) -> &[f64] {
        &self.residual
    }

    /// One tick: the joint angles and velocities `q`, `qd` at this tick (the belief) and the
    /// torques `tau` believed applied from this tick to the next. Returns the residual.
    ///
    /// # Panics
    /// If a slice does not have one entry per joint.
    pub fn update(&mut self, q: &[f64], qd: &[f64], tau: &[f64], dt: f64) -> &[f64] {
        let n = self.p.len();
        assert!(
            q.len() == n && qd.len() == n && tau.len() == n,
            "one per joint"
        );
        // M' qd by a central difference along qd.
        let speed = qd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        self.m_dot_qd.fill(0.0);
        if speed > 0.0 {
            let eps = M_DOT_STEP / speed;
            for sign in [1.0, -1.0] {
                for i in 0..n {
                    self.shifted[i] = q[i] + sign * eps * qd[i];
                }
                self.dynamics.set_configuration(&self.shifted);
                self.dynamics.compute(qd);
                momentum_into(self.dynamics.mass_matrix(), qd, &mut self.p);
                for (d, p) in self.m_dot_qd.iter_mut().zip(&self.p) {
                    *d += sign * p / (2.0 * eps);
                }
            }
        }
        self.dynamics.set_configuration(q);
        self.dynamics.compute(qd);
        momentum_into(self.dynamics.mass_matrix(), qd, &mut self.p);
        if self.started {
            for i in 0..n {
                self.integral[i] += self.rate[i] * dt;
                self.residual[i] = self.gain * (self.p[i] - self.p0[i] - self.integral[i]);
            }
        } else {
            self.p0.copy_from_slice(&self.p);
            self.started = true;
        }
        let bias = self.dynamics.bias();
        for (i, joint) in self.dynamics.model().joints.iter().enumerate() {
            let friction = joint.friction * (qd[i] / FRICTION_RAMP).clamp(-1.0, 1.0);
            // tau + (M' qd - C qd) - g - D qd - F + r, with C qd + g = bias.
            self.rate[i] = tau[i] + self.m_dot_qd[i] - bias[i] - joint.damping * qd[i] - friction
                + self.residual[i];
        }
        &self.residual
    }
}

/// p = M qd, into `p`, without allocating.
fn momentum_into(m: &nalgebra::DMatrix<f64>, qd: &[f64], p: &mut [f64]) {
    for (r, out) in p.iter_mut().enumerate() {
        *out = (0..qd.len()).fold(0.0, |s, c| s + m[(r, c)] * qd[c]);
    }
}

/// An alarm of the momentum observer: when, and the joint (0-based) whose residual crossed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MomentumAlarm {
    pub tick: u64,
    pub joint: usize,
}

/// The observer with thresholds: alarms per joint after a dwell, re-armed below half the
/// threshold. Without thresholds (calibration) it only records the largest |r_j|.
#[derive(Clone, Debug)]
pub struct MomentumMonitor {
    observer: MomentumObserver,
    thresholds: Option<Vec<f64>>,
    dwell_ticks: u64,
    above_since: Vec<Option<u64>>,
    armed: Vec<bool>,
    alarms: Vec<MomentumAlarm>,
    largest: Vec<f64>,
}

impl MomentumMonitor {
    /// A monitor with `thresholds` per joint (None: calibrating), alarms after `dwell` s.
    pub fn new(observer: MomentumObserver, thresholds: Option<Vec<f64>>, dwell_ticks: u64) -> Self {
        let n = observer.residual.len();
        Self {
            observer,
            thresholds,
            dwell_ticks: dwell_ticks.max(1),
            above_since: vec![None; n],
            armed: vec![true; n],
            alarms: Vec::new(),
            largest: vec![0.0; n],
        }
    }

    /// One tick (see [`MomentumObserver::update`]).
    pub fn update(&mut self, tick: u64, q: &[f64], qd: &[f64], tau: &[f64], dt: f64) {
        let r = self.observer.update(q, qd, tau, dt);
        for (j, v) in r.iter().enumerate() {
            let a = v.abs();
            self.largest[j] = if a.is_nan() {
                f64::INFINITY
            } else {
                self.largest[j].max(a)
            };
        }
        let Some(thresholds) = &self.thresholds else {
            return;
        };
        for (j, (v, thr)) in r.iter().zip(thresholds).enumerate() {
            let a = v.abs();
            if self.armed[j] {
                if a > *thr || a.is_nan() {
                    let since = *self.above_since[j].get_or_insert(tick);
                    if tick + 1 - since >= self.dwell_ticks {
                        self.armed[j] = false;
                        if self.alarms.len() < MAX_MOMENTUM_ALARMS {
                            self.alarms.push(MomentumAlarm {
                                tick: since,
                                joint: j,
                            });
                        }
                    }
                } else {
                    self.above_since[j] = None;
                }
            } else if a < 0.5 * thr {
                self.armed[j] = true;
                self.above_since[j] = None;
            }
        }
    }

    /// The residual after the last tick.
    pub fn residual(&self) -> &[f64] {
        self.observer.residual()
    }

    /// The alarms so far, in time order.
    pub fn alarms(&self) -> &[MomentumAlarm] {
        &self.alarms
    }

    /// The largest |r_j| seen per joint (infinite if r became NaN).
    pub fn largest(&self) -> &[f64] {
        &self.largest
    }

    /// The thresholds, if calibrated.
    pub fn thresholds(&self) -> Option<&[f64]> {
        self.thresholds.as_deref()
    }
}
