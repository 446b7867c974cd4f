//! Estimation: the belief sources the closed loop talks to.
//!
//! An [`Estimator`] turns each tick's readings, the channel precisions in force and the torques
//! applied over the last step into a belief about the joint state (positions mu, velocities mu')
//! and reports what the later stages need ([`Estimate`]): per-channel innovations against the
//! prediction (with their predicted variance where the estimator has one), post-update residuals
//! with their posterior-variance corrections, the precisions it actually used, and the free
//! energy or log-likelihood where defined. The control law f* is not part of it
//! ([`crate::control`]).
//!
//! Estimators are composed from models ([`models`]: a transition model, constant velocity or the
//! arm's dynamics on the estimator's copy of the arm; an observation model, the channel layout
//! with the GP camera). Implementations: the u-AIC's free-energy descent ([`uaic::Uaic`]), and
//! the classical baselines: an extended Kalman filter with innovation gating and the
//! variational-Bayes adaptive filter ([`kalman`], whose [`kalman::Ekf`] is the one filter step
//! every Kalman-type estimator here runs), and an interacting-multiple-model bank ([`imm`]);
//! the hybrid ([`hybrid`]) drives the u-AIC from a bank of failure hypotheses. The IMM and the
//! hybrid share their bank's core ([`bank`]). A new estimator plugs in by implementing the
//! trait; the runner does not change.

pub mod bank;
pub mod hybrid;
pub mod imm;
pub mod kalman;
pub mod models;
pub mod uaic;

use nalgebra::DMatrix;

use crate::sensors::{ChannelLayout, Readings};

/// What an estimator is given each tick.
#[derive(Clone, Copy, Debug)]
pub struct EstimatorInput<'a> {
    pub tick: u64,
    pub readings: &'a Readings,
    /// Precision (inverse noise variance) per channel for this tick; 0 leaves a channel out.
    pub precisions: &'a [f64],
    /// The torques applied over the step that led to this tick (zeros at the first tick).
    pub applied_torques: &'a [f64],
}

/// What an estimator reports after a tick, per channel in layout order.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// Innovations y - h(x_hat): readings against the prediction, before the update
    /// (`None`: missing this tick).
    pub innovations: Vec<Option<f64>>,
    /// Predicted variance of each innovation, (H P_pred H')_ii + 1/omega_i, where the estimator
    /// carries a covariance (`None` for the u-AIC).
    pub innovation_variances: Vec<Option<f64>>,
    /// Residuals y - h(x) after the update (what precision learners see).
    pub residuals: Vec<Option<f64>>,
    /// Posterior-variance correction per channel, c_i = (H P H')_ii at the updated belief.
    pub corrections: Vec<f64>,
    /// The precision each channel entered the update with (0: left out, e.g. gated).
    pub precisions_used: Vec<f64>,
    /// Variational free energy at the updated belief (the u-AIC), in nats without constants.
    pub free_energy: Option<f64>,
    /// Log-likelihood of this tick's innovations (Kalman filters), in nats without constants.
    pub log_likelihood: Option<f64>,
    /// Whether the update stayed finite (false: refused; the belief is unchanged).
    pub finite: bool,
}

impl Estimate {
    /// An empty report for `layout`.
    pub fn new(layout: &ChannelLayout) -> Self {
        let m = layout.len();
        Self {
            innovations: vec![None; m],
            innovation_variances: vec![None; m],
            residuals: vec![None; m],
            corrections: vec![0.0; m],
            precisions_used: vec![0.0; m],
            free_energy: None,
            log_likelihood: None,
            finite: true,
        }
    }
}

/// A belief source for the closed loop.
pub trait Estimator: Send {
    /// One tick: update the belief from the readings.
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate;
    /// What the last update reported.
    fn estimate(&self) -> &Estimate;
    /// Position belief mu.
    fn mu(&self) -> &[f64];
    /// Velocity belief mu'.
    fn mu_p(&self) -> &[f64];
    /// Covariance of the belief [mu, mu'] (2n x 2n) where the estimator has one.
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        None
    }
    /// The estimator's probability that joint `joint`'s actuator failed: `None` when it infers
    /// no actuator health (every estimator but the hybrid with `hybrid.actuators`).
    fn actuator_failure_probability(&self, _joint: usize) -> Option<f64> {
        None
    }
}
