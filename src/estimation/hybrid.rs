//! `hybrid`: the active-inference method meant to hold at every fault site (docs/method.md,
//! "The hybrid").
//!
//! The belief is the u-AIC's: Gauss-Newton descent on F, with the state prior's precision
//! propagated as a Kalman filter's would be (the inverse of A Sigma A' + Q, Sigma the last
//! posterior covariance), so that when a channel loses its weight the prior loosens and the
//! remaining sensors re-anchor the belief at once instead of over P_mu / P_cam ticks.
//!
//! The precisions are beliefs too, at two levels. Each encoder's and tachometer's precision is a
//! discrete latent state, healthy (nominal) or failed (nominal / broad^2), inferred by Bayesian
//! model comparison: a bank of hypotheses H_0 (all healthy) and H_c (channel c failed), each a
//! Kalman filter on the same generative model, scored every tick by its log evidence (the
//! innovation log-likelihood, -F of its Laplace model), with a Markov switching prior between
//! hypotheses; the channel's precision is the posterior expectation nominal x P(not H_c). The
//! camera's precisions are learned continuously by the seed paper's gradient rule (the camera has
//! no hypothesis: its faults are biases and freezes the gradient rule handles, and a broad-camera
//! hypothesis pays a ln(broad) penalty every tick that makes the bank blame encoders instead); the
//! learned camera precision is fed back into every hypothesis' camera noise.
//!
//! The bank's transition is the constant-velocity model, or (`hybrid.bank_model = "dynamics"`) the
//! arm's own dynamics driven by the applied torques, which separates a frozen encoder from a
//! frozen tachometer on arms without heavy damping (its masses can be scaled to test model error).
//! When a failure hypothesis becomes the most probable, the belief is re-anchored on that
//! hypothesis' estimate (which never trusted the failed channel), and every other hypothesis
//! restarts from it.

use std::sync::Arc;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::kalman::{ArmDynamics, Ekf};
use super::uaic::Uaic;
use super::{Estimate, Estimator, EstimatorInput};
use crate::gp::GpModel;
use crate::sensors::{Channel, ChannelLayout};

/// The bank's transition model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BankModel {
    /// Constant velocity with white acceleration noise (no model of the arm).
    ConstantVelocity,
    /// The arm's dynamics (the URDF's model, masses scaled by `mass_scale`) and applied torques.
    #[default]
    Dynamics,
}

/// Settings of `hybrid` (the `[hybrid]` section).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HybridConfig {
    pub bank_model: BankModel,
    /// The model's masses and inertias as a multiple of the URDF's (model error).
    pub mass_scale: f64,
    /// The bank's process noise with the dynamics model: acceleration error (rad/s^2) as one
    /// standard deviation; with the constant-velocity model the acceleration bound is used.
    pub model_acceleration_noise: f64,
    /// Per-tick probability of leaving a hypothesis.
    pub switch: f64,
    /// A failed channel's noise standard deviation, as a multiple of its nominal.
    pub broad: f64,
    /// The bank's camera noise as a multiple of the camera's (room for the GP's own error).
    pub camera_inflation: f64,
    /// Re-anchor the belief when a failure hypothesis wins.
    pub reanchor: bool,
}

impl Default for HybridConfig {
    fn default() -> Self {
        Self {
            bank_model: BankModel::Dynamics,
            mass_scale: 1.0,
            model_acceleration_noise: 20.0,
            switch: 1e-6,
            broad: 1000.0,
            camera_inflation: 1.2,
            reanchor: true,
        }
    }
}

impl HybridConfig {
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(self.mass_scale.is_finite() && self.mass_scale > 0.0 && self.mass_scale <= 100.0) {
            return Err(("mass_scale", "must be in (0, 100]".into()));
        }
        if !(self.model_acceleration_noise.is_finite()
            && self.model_acceleration_noise > 0.0
            && self.model_acceleration_noise <= 1e9)
        {
            return Err(("model_acceleration_noise", "must be in (0, 1e9]".into()));
        }
        if !(self.switch > 0.0 && self.switch < 0.5) {
            return Err(("switch", "must be in (0, 0.5)".into()));
        }
        if !(self.broad.is_finite() && self.broad > 1.0 && self.broad <= 1e9) {
            return Err(("broad", "must be in (1, 1e9]".into()));
        }
        if !(self.camera_inflation.is_finite() && self.camera_inflation >= 1.0 && self.camera_inflation <= 1e3) {
            return Err(("camera_inflation", "must be in [1, 1e3]".into()));
        }
        Ok(())
    }
}

/// The hybrid's belief and its bank of hypotheses.
pub struct Hybrid {
    uaic: Uaic,
    layout: ChannelLayout,
    bank: Vec<Ekf>,
    /// The channel each hypothesis holds failed (None: H_0).
    failed: Vec<Option<usize>>,
    probability: Vec<f64>,
    winner: usize,
    model: Option<ArmDynamics>,
    config: HybridConfig,
    nominal: Vec<f64>,
    precisions: Vec<f64>,
    variances: Vec<f64>,
    floor: f64,
    initialised: bool,
    ticks: u64,
}

impl Hybrid {
    /// `ekf` is the bank's template (its process noise already chosen for the model).
    pub fn new(
        uaic: Uaic,
        ekf: Ekf,
        model: Option<ArmDynamics>,
        config: HybridConfig,
        nominal: &[f64],
        floor: f64,
    ) -> Self {
        let layout = ekf.layout();
        let mut failed = vec![None];
        for c in 0..layout.len() {
            if !matches!(layout.channel(c), Channel::Camera(_)) {
                failed.push(Some(c));
            }
        }
        let h = failed.len();
        let mut probability = vec![1e-3 / (h - 1) as f64; h];
        probability[0] = 1.0 - 1e-3;
        Self {
            uaic,
            layout,
            bank: vec![ekf; h],
            failed,
            probability,
            winner: 0,
            model,
            config,
            nominal: nominal.to_vec(),
            precisions: nominal.to_vec(),
            variances: vec![0.0; nominal.len()],
            floor,
            initialised: false,
            ticks: 0,
        }
    }

    /// The hypotheses' probabilities (H_0, then one per encoder and tachometer).
    pub fn probabilities(&self) -> &[f64] {
        &self.probability
    }

    /// The bank's variances for hypothesis j, given the camera precisions in force.
    fn hypothesis_variances(&mut self, j: usize, input: &EstimatorInput<'_>) {
        for c in 0..self.layout.len() {
            let w = input.precisions[c];
            self.variances[c] = match self.layout.channel(c) {
                _ if w <= 0.0 => f64::INFINITY,
                Channel::Camera(_) => {
                    // The learned camera precision, and room for the GP's error.
                    let inflate = self.config.camera_inflation * self.config.camera_inflation;
                    inflate / self.nominal[c] * (self.nominal[c] / w).max(1.0)
                }
                _ => {
                    let v = 1.0 / self.nominal[c];
                    if self.failed[j] == Some(c) {
                        v * self.config.broad * self.config.broad
                    } else {
                        v
                    }
                }
            };
        }
    }

    fn step_bank(&mut self, input: &EstimatorInput<'_>) {
        let h = self.bank.len();
        if !self.initialised {
            for j in 0..h {
                self.hypothesis_variances(j, input);
                let v = self.variances.clone();
                self.bank[j].initialise(input.readings, &v);
            }
            self.initialised = true;
        } else {
            let acc = match &mut self.model {
                Some(m) => {
                    let n = self.layout.n_joints();
                    let x = self.uaic.belief();
                    m.acceleration(&x[..n], &x[n..], input.applied_torques)
                        .map(<[f64]>::to_vec)
                }
                None => None,
            };
            for f in &mut self.bank {
                f.predict(acc.as_deref());
            }
            // The switching prior: stay with 1 - s, leave to each other hypothesis with s/(h-1).
            let s = self.config.switch;
            let leave = s / (h - 1) as f64;
            let total: f64 = self.probability.iter().sum();
            for p in &mut self.probability {
                *p = (1.0 - s) * *p + leave * (total - *p);
            }
        }
        let mut ll = vec![0.0; h];
        for j in 0..h {
            self.hypothesis_variances(j, input);
            let v = self.variances.clone();
            self.bank[j].linearise();
            ll[j] = self.bank[j].update(input.readings, &v);
        }
        if std::env::var_os("AIFT_DEBUG_HYBRID").is_some() {
            let t = self.ticks;
            if (7990..8300).contains(&t) && t % 5 == 0 {
                let base = ll[0];
                eprintln!(
                    "t {t} dll {:?} p {:?}",
                    ll.iter().map(|l| format!("{:.2}", l - base)).collect::<Vec<_>>(),
                    self.probability.iter().map(|p| format!("{p:.2e}")).collect::<Vec<_>>()
                );
            }
        }
        self.ticks += 1;
        let best = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for j in 0..h {
            self.probability[j] *= (ll[j] - best).exp();
            total += self.probability[j];
        }
        for p in &mut self.probability {
            *p = (*p / total).max(1e-300);
        }
    }
}

impl Estimator for Hybrid {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        self.step_bank(input);
        // Channel precisions: the bank's posterior expectation for encoders and tachometers,
        // the learned precision for the camera.
        for c in 0..self.layout.len() {
            self.precisions[c] = match self.layout.channel(c) {
                Channel::Camera(_) => input.precisions[c],
                _ if input.precisions[c] <= 0.0 => 0.0,
                _ => {
                    let failed: f64 = self
                        .failed
                        .iter()
                        .zip(&self.probability)
                        .filter(|(f, _)| **f == Some(c))
                        .map(|(_, p)| *p)
                        .sum();
                    self.nominal[c] * (1.0 - failed).max(self.floor)
                }
            };
        }
        // Re-anchoring when a failure hypothesis takes over.
        let winner = (0..self.bank.len())
            .max_by(|&a, &b| self.probability[a].total_cmp(&self.probability[b]))
            .unwrap_or(0);
        if winner != self.winner {
            if winner != 0 && self.config.reanchor && self.uaic.belief().len() == self.bank[winner].x.len() {
                let x: Vec<f64> = self.bank[winner].x.iter().copied().collect();
                let p = self.bank[winner].p.clone();
                self.uaic.reanchor(&x, Some(&p));
            }
            self.winner = winner;
        }
        let precisions = self.precisions.clone();
        self.uaic.step(input.readings, &precisions)
    }

    fn estimate(&self) -> &Estimate {
        self.uaic.estimate()
    }
    fn mu(&self) -> &[f64] {
        self.uaic.mu()
    }
    fn mu_p(&self) -> &[f64] {
        self.uaic.mu_p()
    }
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        self.uaic.covariance()
    }
}

/// Builds the hybrid's parts from the scenario's settings.
#[allow(clippy::too_many_arguments)]
pub fn build(
    uaic: Uaic,
    layout: ChannelLayout,
    gp: Arc<GpModel>,
    dt: f64,
    acceleration_bound: f64,
    model: &crate::plant::ArmModel,
    gravity: [f64; 3],
    config: &HybridConfig,
    nominal: &[f64],
    floor: f64,
) -> Hybrid {
    let (dynamics, noise) = match config.bank_model {
        BankModel::ConstantVelocity => (None, acceleration_bound),
        BankModel::Dynamics => (
            Some(ArmDynamics::new(model, gravity, config.mass_scale)),
            config.model_acceleration_noise,
        ),
    };
    let ekf = Ekf::new(layout, gp, dt, noise);
    Hybrid::new(uaic, ekf, dynamics, config.clone(), nominal, floor)
}
