//! `hybrid`: the active-inference method meant to hold at every fault site (docs/method.md,
//! "The hybrid").
//!
//! The belief is the u-AIC's: Gauss-Newton descent on F, with the state prior's precision
//! propagated as a Kalman filter's would be (the inverse of A Sigma A' + Q, Sigma the last
//! posterior covariance), so that when a channel loses its weight the prior loosens and the
//! remaining sensors re-anchor the belief at once instead of over P_mu / P_cam ticks.
//!
//! The precisions are beliefs too. Each sensor's precision is a discrete latent state, healthy
//! (nominal) or failed (nominal / broad^2), inferred by Bayesian model comparison: a bank of
//! hypotheses H_0 (all healthy), H_c (encoder or tachometer c failed) and H_cam (every camera
//! output failed together, `camera_broad` times its noise), each a Kalman filter on the same
//! generative model, scored every tick by its log evidence (the innovation log-likelihood, -F
//! of its Laplace model), with a Markov switching prior between hypotheses; a channel's
//! precision is the posterior expectation nominal x P(not H_c). (`hybrid.camera = "gradient"`
//! learns the camera's precision by the seed paper's gradient rule instead and feeds it back
//! into the bank.)
//!
//! The bank's transition is the arm's own dynamics driven by the applied torques (default), or
//! the constant-velocity model (`hybrid.bank_model = "constant-velocity"`); the dynamics separate
//! a frozen encoder from a frozen tachometer on arms without heavy damping. Its process noise per
//! joint is max(`model_acceleration_noise`, `model_relative_error` x |predicted acceleration|), so
//! a hard acceleration the model gets slightly wrong is not read as every sensor failing, and the
//! masses can be scaled (`mass_scale`) to test model error. When a failure hypothesis becomes the
//! most probable and the belief lies outside its 3-sigma ellipsoid, the belief is re-anchored on
//! that hypothesis' estimate (which never trusted the failed channel); while it keeps winning, the
//! other hypotheses restart from it every `resync_ticks`, so that a fault that ends is seen to end.

use std::sync::Arc;

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::kalman::{ArmDynamics, Ekf, linearise_bank};
use super::uaic::Uaic;
use super::{Estimate, Estimator, EstimatorInput};
use crate::gp::GpModel;
use crate::sensors::{Channel, ChannelLayout};

/// The bank's transition model.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum BankModel {
    /// Constant velocity with white acceleration noise (no model of the arm).
    ConstantVelocity,
    /// The arm's dynamics (the URDF's model, masses scaled by `mass_scale`) and applied torques.
    #[default]
    Dynamics,
}

/// How the hybrid sets the camera's precisions.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum CameraPrecision {
    /// A camera hypothesis in the bank (every output failed together, `camera_broad` times its
    /// noise); the camera's precision is nominal x P(not failed), like the joint sensors'.
    #[default]
    Bank,
    /// The seed paper's gradient rule on the u-AIC's camera residuals, fed back into the bank.
    Gradient,
}

/// Settings of `hybrid` (the `[hybrid]` section).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HybridConfig {
    pub bank_model: BankModel,
    /// The model's masses and inertias as a multiple of the URDF's (model error).
    pub mass_scale: f64,
    /// The bank's process noise with the dynamics model: acceleration error (rad/s^2) as one
    /// standard deviation; with the constant-velocity model the acceleration bound is used.
    pub model_acceleration_noise: f64,
    /// The model's relative acceleration error: each joint's process noise is
    /// max(model_acceleration_noise, this x |predicted acceleration|) (0.1 covers masses 10 %
    /// off and the integrator's own error in fast motion).
    pub model_relative_error: f64,
    /// Per-tick probability of leaving a hypothesis.
    pub switch: f64,
    /// A failed channel's noise standard deviation, as a multiple of its nominal.
    pub broad: f64,
    /// The bank's camera noise as a multiple of the camera's (room for the GP's own error).
    pub camera_inflation: f64,
    /// How the camera's precision is set.
    pub camera: CameraPrecision,
    /// The camera hypothesis' noise as a multiple of the camera's.
    pub camera_broad: f64,
    /// Re-anchor the belief when a failure hypothesis wins and the belief lies outside its
    /// 3-sigma ellipsoid.
    pub reanchor: bool,
    /// While a failure hypothesis keeps winning, every this many ticks the others restart from
    /// its estimate (so that they ask "is the channel healthy from now on?", and a fault that
    /// ends is seen to end); 0: never.
    pub resync_ticks: u64,
}

impl Default for HybridConfig {
    fn default() -> Self {
        Self {
            bank_model: BankModel::Dynamics,
            mass_scale: 1.0,
            model_acceleration_noise: 2.0,
            model_relative_error: 0.1,
            switch: 1e-6,
            broad: 1000.0,
            camera_inflation: 1.2,
            camera: CameraPrecision::Bank,
            camera_broad: 10.0,
            reanchor: true,
            resync_ticks: 500,
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
        if !(self.model_relative_error.is_finite()
            && (0.0..=10.0).contains(&self.model_relative_error))
        {
            return Err(("model_relative_error", "must be in [0, 10]".into()));
        }
        if !(self.switch > 0.0 && self.switch < 0.5) {
            return Err(("switch", "must be in (0, 0.5)".into()));
        }
        if !(self.broad.is_finite() && self.broad > 1.0 && self.broad <= 1e9) {
            return Err(("broad", "must be in (1, 1e9]".into()));
        }
        if !(self.camera_inflation.is_finite()
            && self.camera_inflation >= 1.0
            && self.camera_inflation <= 1e3)
        {
            return Err(("camera_inflation", "must be in [1, 1e3]".into()));
        }
        if !(self.camera_broad.is_finite() && self.camera_broad > 1.0 && self.camera_broad <= 1e9) {
            return Err(("camera_broad", "must be in (1, 1e9]".into()));
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
    winner_since: u64,
    model: Option<ArmDynamics>,
    config: HybridConfig,
    nominal: Vec<f64>,
    precisions: Vec<f64>,
    variances: Vec<f64>,
    floor: f64,
    initialised: bool,
    ticks: u64,
    // Scratch: the model acceleration, the per-joint process noise, each hypothesis' log
    // evidence.
    ll: Vec<f64>,
    acc: Vec<f64>,
    noise: Vec<f64>,
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
        // Hypotheses: H_0; each encoder and tachometer; the camera as one (index = first output).
        let mut failed = vec![None];
        for c in 0..layout.len() {
            if !matches!(layout.channel(c), Channel::Camera(_)) {
                failed.push(Some(c));
            }
        }
        if config.camera == CameraPrecision::Bank {
            failed.push(Some(
                layout
                    .group_range(crate::sensors::SensorGroup::Camera)
                    .start,
            ));
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
            winner_since: 0,
            model,
            config,
            nominal: nominal.to_vec(),
            precisions: nominal.to_vec(),
            variances: vec![0.0; nominal.len()],
            floor,
            initialised: false,
            ticks: 0,
            ll: vec![0.0; h],
            acc: vec![0.0; layout.n_joints()],
            noise: vec![0.0; layout.n_joints()],
        }
    }

    /// Whether the belief lies outside hypothesis j's 3-sigma ellipsoid (with the belief's own
    /// covariance added).
    fn outside(&self, j: usize) -> bool {
        let f = &self.bank[j];
        let b = self.uaic.belief();
        if b.len() != f.x.len() {
            return false;
        }
        let d =
            nalgebra::DVector::from_iterator(b.len(), b.iter().zip(f.x.iter()).map(|(a, c)| a - c));
        let mut s = f.p.clone();
        if let Some(c) = self.uaic.covariance() {
            s += c;
        }
        match s.cholesky() {
            Some(ch) => ch.solve(&d).dot(&d) > 9.0 * b.len() as f64,
            None => false,
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
                    let inflate = self.config.camera_inflation * self.config.camera_inflation;
                    match self.config.camera {
                        // The learned camera precision, and room for the GP's error.
                        CameraPrecision::Gradient => {
                            inflate / self.nominal[c] * (self.nominal[c] / w).max(1.0)
                        }
                        CameraPrecision::Bank => {
                            let cam0 = self
                                .layout
                                .group_range(crate::sensors::SensorGroup::Camera)
                                .start;
                            let broad = if self.failed[j] == Some(cam0) {
                                self.config.camera_broad * self.config.camera_broad
                            } else {
                                1.0
                            };
                            inflate / self.nominal[c] * broad
                        }
                    }
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
            // The model's acceleration at the belief, and the per-joint process noise it implies.
            let n = self.layout.n_joints();
            let x = self.uaic.belief();
            let has_acc = self
                .model
                .as_mut()
                .and_then(|m| m.acceleration(&x[..n], &x[n..], input.applied_torques))
                .map(|a| self.acc.copy_from_slice(a))
                .is_some();
            let (acc, noise) = if has_acc {
                for (s, a) in self.noise.iter_mut().zip(&self.acc) {
                    *s = self
                        .config
                        .model_acceleration_noise
                        .max(self.config.model_relative_error * a.abs());
                }
                (Some(self.acc.as_slice()), Some(self.noise.as_slice()))
            } else {
                (None, None)
            };
            for f in &mut self.bank {
                f.predict_with_noise(acc, noise);
            }
            // The switching prior: stay with 1 - s, leave to each other hypothesis with s/(h-1).
            let s = self.config.switch;
            let leave = s / (h - 1) as f64;
            let total: f64 = self.probability.iter().sum();
            for p in &mut self.probability {
                *p = (1.0 - s) * *p + leave * (total - *p);
            }
        }
        let mut ll = std::mem::take(&mut self.ll);
        linearise_bank(&mut self.bank);
        for j in 0..h {
            self.hypothesis_variances(j, input);
            ll[j] = self.bank[j].update(input.readings, &self.variances);
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
        self.ll = ll;
    }
}

impl Estimator for Hybrid {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        self.step_bank(input);
        // Channel precisions: the bank's posterior expectation for encoders and tachometers,
        // the learned precision for the camera.
        let cam0 = self
            .layout
            .group_range(crate::sensors::SensorGroup::Camera)
            .start;
        for c in 0..self.layout.len() {
            let key = match self.layout.channel(c) {
                Channel::Camera(_) => cam0,
                _ => c,
            };
            self.precisions[c] = match self.layout.channel(c) {
                Channel::Camera(_) if self.config.camera == CameraPrecision::Gradient => {
                    input.precisions[c]
                }
                _ if input.precisions[c] <= 0.0 => 0.0,
                _ => {
                    let failed: f64 = self
                        .failed
                        .iter()
                        .zip(&self.probability)
                        .filter(|(f, _)| **f == Some(key))
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
        let tick = self.ticks;
        if winner != self.winner {
            if winner != 0 && self.config.reanchor && self.outside(winner) {
                let x: Vec<f64> = self.bank[winner].x.iter().copied().collect();
                let p = self.bank[winner].p.clone();
                self.uaic.reanchor(&x, Some(&p));
            }
            self.winner = winner;
            self.winner_since = tick;
        } else if winner != 0
            && self.config.resync_ticks > 0
            && tick > self.winner_since
            && (tick - self.winner_since).is_multiple_of(self.config.resync_ticks)
        {
            let (x, p) = (self.bank[winner].x.clone(), self.bank[winner].p.clone());
            for (j, f) in self.bank.iter_mut().enumerate() {
                if j != winner {
                    f.x.copy_from(&x);
                    f.p.copy_from(&p);
                }
            }
        }
        self.uaic.step(input.readings, &self.precisions)
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
