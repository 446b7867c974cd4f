//! Precision methods: one precision (inverse variance) per sensory channel, set every tick so
//! that a failing sensor loses its weight in the belief (docs/method.md, "Precision learning").
//!
//! A [`PrecisionMethod`] sees what its estimator reported after each tick's update (innovations,
//! residuals and their corrections, the belief and its covariance, the readings, the torques,
//! the channel layout) and leaves the precisions for the next tick. The paper's learners
//! ([`learners`]) work per channel on post-update residuals; detector-driven methods
//! ([`supervised`]) wrap the deterministic detector ([`detector`]); [`supervised::PerGroup`]
//! gives each sensor group its own method; the oracle knows each fault's window.
//!
//! Every learner starts at the nominal precision 1/sigma^2 and clamps to
//! [omega_min, omega_max] = [1e-6, 1] x nominal by default: a sensor is never trusted beyond its
//! datasheet, and learning can only take weight away. A precision of exactly 0 (deterministic
//! recovery, the oracle) leaves the channel out of the belief update. A channel's health is
//! omega / omega_nominal, in [0, 1].

pub mod detector;
pub mod learners;
pub mod momentum;
pub mod supervised;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

pub use detector::{
    Alarm, Calibration, CalibrationAccumulator, Detection, Detector, DetectorConfig, DetectorTest,
    Isolation,
};
pub use learners::{Bayes, Fixed, Gradient, Window};
pub use momentum::{MomentumAlarm, MomentumConfig, MomentumMonitor, MomentumObserver};
pub use supervised::{Deterministic, GatedLearning, Oracle, PerGroup};

use crate::estimation::Estimate;
use crate::sensors::{ChannelLayout, Readings};

/// What a precision method sees after each tick's belief update.
#[derive(Clone, Copy, Debug)]
pub struct PrecisionInput<'a> {
    pub tick: u64,
    pub dt: f64,
    pub layout: &'a ChannelLayout,
    pub readings: &'a Readings,
    /// The estimator's report of this tick.
    pub estimate: &'a Estimate,
    /// The updated belief.
    pub mu: &'a [f64],
    pub mu_p: &'a [f64],
    /// The belief's covariance, where the estimator has one.
    pub covariance: Option<&'a DMatrix<f64>>,
    /// The torques commanded this tick (applied over the next step).
    pub torques: &'a [f64],
}

impl PrecisionInput<'_> {
    /// (channel, e^2 [+ c]) for every channel with a residual this tick; the posterior-variance
    /// correction c is added when `correct` is set.
    pub fn squared_residuals(&self, correct: bool) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.estimate
            .residuals
            .iter()
            .zip(&self.estimate.corrections)
            .enumerate()
            .filter_map(move |(c, (e, corr))| {
                e.map(|e| (c, e * e + if correct { *corr } else { 0.0 }))
            })
    }
}

/// A precision method: one scalar precision per channel, updated after every tick.
pub trait PrecisionMethod: Send {
    /// The precisions to use for the next tick.
    fn precisions(&self) -> &[f64];
    /// Learns from the tick.
    fn update(&mut self, input: &PrecisionInput<'_>);
    /// The detector's state, for methods that run one.
    fn detection(&self) -> Option<&Detection> {
        None
    }
}

/// Clamp of every learner, as multiples of the nominal precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PrecisionBounds {
    pub min_ratio: f64,
    pub max_ratio: f64,
}

impl Default for PrecisionBounds {
    fn default() -> Self {
        Self {
            min_ratio: 1e-6,
            max_ratio: 1.0,
        }
    }
}

impl PrecisionBounds {
    pub(crate) fn clamp(&self, omega: f64, nominal: f64) -> f64 {
        omega.clamp(self.min_ratio * nominal, self.max_ratio * nominal)
    }
}

/// Health of a channel: omega / omega_nominal clamped to [0, 1].
pub fn health(omega: f64, nominal: f64) -> f64 {
    (omega / nominal).clamp(0.0, 1.0)
}

#[cfg(test)]
pub(crate) mod testing {
    //! Feeding precision methods by hand.
    use super::*;
    use crate::sensors::CameraModel;

    /// A one-joint layout (4 channels).
    pub fn layout() -> ChannelLayout {
        ChannelLayout::new(1, CameraModel::Pinhole)
    }

    /// Calls `update` with the given residuals, corrections and innovations.
    pub fn feed(
        method: &mut dyn PrecisionMethod,
        tick: u64,
        residuals: &[Option<f64>],
        corrections: &[f64],
        innovations: &[Option<f64>],
    ) {
        let m = residuals.len();
        let estimate = Estimate {
            innovations: innovations.to_vec(),
            innovation_variances: vec![None; m],
            residuals: residuals.to_vec(),
            corrections: corrections.to_vec(),
            precisions_used: vec![1.0; m],
            free_energy: None,
            log_likelihood: None,
            finite: true,
        };
        let layout = layout();
        let readings = Readings {
            values: vec![None; m],
        };
        method.update(&PrecisionInput {
            tick,
            dt: 1e-3,
            layout: &layout,
            readings: &readings,
            estimate: &estimate,
            mu: &[0.0],
            mu_p: &[0.0],
            covariance: None,
            torques: &[0.0],
        });
    }
}
