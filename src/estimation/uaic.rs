//! The unbiased active inference controller's belief (u-AIC): the state estimate from descent
//! on the variational free energy (docs/method.md, "The u-AIC"; the seed paper's eqs. 3-5,
//! after Baioumy et al., ECC 2021).
//!
//! Beliefs mu (joint positions) and mu' (velocities), x = [mu, mu']. With diagonal precisions,
//! ```text
//! F = 1/2 ( sum_i w_i e_i^2 - ln w_i )  +  1/2 ( e_x' P_x e_x - ln|P_x| )
//! ```
//! over the sensory channels i present this tick with w_i > 0 (encoders e = y_q - mu, tachometers
//! e = y_qd - mu', camera e = y_v - g_v(mu)), and the state prior e_x = mu_x - x_hat with the
//! constant-velocity prediction x_hat = [[I, dt I], [0, I]] mu_{x,k-1} (paper eq. 4). The
//! "coupled" prediction (docs/method.md, "Coupled prediction") uses the current velocity belief
//! instead: e_x = [mu - mu_{k-1} - dt mu', mu' - mu'_{k-1}].
//!
//! The target never enters the belief (that is what makes the estimate unbiased): the control
//! law f* and the action belief mu_u live in [`crate::control`]; the e_u term of F vanishes once
//! mu_u = f* and is left out of the belief's gradient, as in the authors' code.
//!
//! Two belief updates: a Gauss-Newton step from the prediction (default; scale-free, lands on
//! the minimum of F's quadratic model for eta = 1) and the paper's explicit gradient descent
//! `mu_x <- mu_x + dt (D mu_x - kappa_mu dF/dmu_x)` (first-order Euler, kept for fidelity).
//! Nothing here knows about rapier: feed readings and precisions; get a belief.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::models::ObservationModel;
use super::{Estimate, Estimator, EstimatorInput};
use crate::sensors::{Channel, ChannelLayout, Readings};

/// How the belief descends the free energy each tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum UpdateScheme {
    /// x = x_hat - eta H^-1 dF/dx at the prediction, H the Gauss-Newton Hessian.
    GaussNewton,
    /// x <- x + dt (D x - kappa_mu dF/dx) (the paper's explicit Euler gradient descent).
    Gradient,
}

/// How the state prior's precision is set.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum PriorMode {
    /// Fixed diagonal precisions P_mu, P_mu' (the paper's).
    #[default]
    Fixed,
    /// The precision a Kalman filter would carry: the inverse of A Sigma A' + Q, with Sigma the
    /// last update's Laplace posterior covariance H^-1 and Q the white-acceleration process
    /// noise of the acceleration bound (docs/method.md, "Propagated prior").
    Propagated,
    /// Fixed while every tachometer reads and its precision in force is at least the prior's
    /// velocity precision P_mu', propagated while one is below it or its reading is missing (a
    /// tachometer dropped, down-weighted or silent): without its tachometer a joint's velocity belief is the prior's, and the
    /// fixed P_mu' then closes a loop with the controller's damping that can oscillate
    /// (docs/method.md, "Propagated prior", a dropped tachometer).
    Switched,
}

/// Which state prediction the prior uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Prediction {
    /// x_hat = [mu_{k-1} + dt mu'_{k-1}, mu'_{k-1}] (the paper's eq. 4).
    Paper,
    /// Position prior residual mu - mu_{k-1} - dt mu' with the current velocity belief.
    Coupled,
    /// A compatibility setting, not a recommendation: the authors' 2-DOF MATLAB benchmark
    /// (`matlab/statistical_analysis.m`, the u-AIC branch): residuals against the previous belief
    /// without motion, e_x = [mu - mu_{k-1}, mu' - mu'_{k-1}], and the velocity update carries
    /// the extra term P_mu (mu - mu_{k-1}) of their `mu_dot_p` (not a gradient of F). Needs
    /// `update = "gradient"` (docs/method.md, "aift against the authors' code").
    AuthorsMatlab,
}

/// Settings of the u-AIC's belief (the scenario's `[belief]` section). Defaults: Gauss-Newton
/// with eta = 1, coupled prediction, a state prior from an acceleration bound of 200 rad/s^2
/// (P_mu = 1e8 and P_mu' = 25 at dt = 1 ms: docs/method.md, "Prior scale"), a 100-tick warm-up
/// of the prior.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct UaicConfig {
    pub update: UpdateScheme,
    /// Gauss-Newton step length eta in (0, 1].
    pub step: f64,
    /// Gradient-descent gain kappa_mu (1/s), used by `update = "gradient"`.
    pub kappa_mu: f64,
    pub prediction: Prediction,
    /// The joint acceleration (rad/s^2) the state prior treats as one standard deviation: the
    /// prior precisions default to P_mu = 1 / (a dt^2 / 2)^2 and P_mu' = 1 / (a dt)^2
    /// (docs/method.md, "Prior scale"), and it is the propagated prior's process noise. 200
    /// gives P_mu = 1e8 and P_mu' = 25 at dt = 1 ms.
    pub acceleration_bound: f64,
    /// Precision of the position prior P_mu (1/rad^2); absent: from `acceleration_bound`.
    pub prior_position_precision: Option<f64>,
    /// Precision of the velocity prior P_mu' (s^2/rad^2); absent: from `acceleration_bound`.
    pub prior_velocity_precision: Option<f64>,
    /// Ticks over which the prior's precisions ramp up from 1/K to 1 times their value, as a
    /// Kalman filter's would from an initial covariance equal to one reading's: the belief
    /// starts at the first (noisy) readings, and a full-strength prior would hold that noise
    /// for about P_mu / encoder precision ticks. 0 disables the ramp.
    pub prior_warmup_ticks: u64,
    /// `fixed` (P_mu, P_mu'), `propagated` (a Kalman filter's prior precision, its process
    /// noise from `acceleration_bound`) or `switched` (fixed while every tachometer's precision
    /// is at least P_mu', propagated while one is below it); the last two need `update =
    /// "gauss-newton"`. Absent: `switched` with the Gauss-Newton update, `fixed` with the
    /// gradient one (which has no posterior covariance to propagate). Every u-AIC method but
    /// `hybrid`, which takes `hybrid.prior`.
    pub prior: Option<PriorMode>,
}

/// The default acceleration bound of the state prior (rad/s^2).
pub const DEFAULT_ACCELERATION_BOUND: f64 = 200.0;

impl Default for UaicConfig {
    fn default() -> Self {
        Self {
            update: UpdateScheme::GaussNewton,
            step: 1.0,
            kappa_mu: 200.0,
            prediction: Prediction::Coupled,
            acceleration_bound: DEFAULT_ACCELERATION_BOUND,
            prior_position_precision: None,
            prior_velocity_precision: None,
            prior_warmup_ticks: 100,
            prior: None,
        }
    }
}

impl UaicConfig {
    /// The state prior a run uses: `prior`, or when it is absent `switched` with the
    /// Gauss-Newton update and `fixed` with the gradient one.
    pub fn prior_mode(&self) -> PriorMode {
        self.prior.unwrap_or(match self.update {
            UpdateScheme::GaussNewton => PriorMode::Switched,
            UpdateScheme::Gradient => PriorMode::Fixed,
        })
    }

    /// The state prior's precisions (P_mu, P_mu') at tick `dt`: as given, else from the
    /// acceleration bound a: P_mu = 1 / (a dt^2 / 2)^2, P_mu' = 1 / (a dt)^2.
    pub fn prior_precisions(&self, dt: f64) -> (f64, f64) {
        let a = self.acceleration_bound;
        (
            self.prior_position_precision
                .unwrap_or_else(|| 1.0 / (0.5 * a * dt * dt).powi(2)),
            self.prior_velocity_precision
                .unwrap_or_else(|| 1.0 / (a * dt).powi(2)),
        )
    }

    /// Checks the settings at tick `dt`.
    pub fn validate(&self, dt: f64) -> Result<(), crate::SettingError> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 && v <= 1e300 {
                Ok(())
            } else {
                Err(crate::SettingError::new(
                    name,
                    format!("{v} must be finite and > 0"),
                ))
            }
        };
        let a = self.acceleration_bound;
        if !(a.is_finite() && a > 0.0 && a <= 1e9) {
            return Err(crate::SettingError::new(
                "acceleration_bound",
                format!("{a} must be finite, > 0 and <= 1e9 rad/s^2"),
            ));
        }
        positive("step", self.step)?;
        if self.step > 1.0 {
            return Err(crate::SettingError::new("step", "must be <= 1"));
        }
        positive("kappa_mu", self.kappa_mu)?;
        let (pm, pv) = self.prior_precisions(dt);
        positive("prior_position_precision", pm)?;
        let prior = self.prior_mode();
        if prior != PriorMode::Fixed && self.update != UpdateScheme::GaussNewton {
            return Err(crate::SettingError::new(
                "prior",
                format!(
                    "\"{}\" needs update = \"gauss-newton\"",
                    if prior == PriorMode::Propagated {
                        "propagated"
                    } else {
                        "switched"
                    }
                ),
            ));
        }
        positive("prior_velocity_precision", pv)?;
        if self.prediction == Prediction::AuthorsMatlab && self.update != UpdateScheme::Gradient {
            return Err(crate::SettingError::new(
                "prediction",
                "\"authors-matlab\" needs update = \"gradient\" (the authors' descent)",
            ));
        }
        if self.prior_warmup_ticks > 1_000_000_000 {
            return Err(crate::SettingError::new(
                "prior_warmup_ticks",
                "must be <= 1e9 ticks",
            ));
        }
        Ok(())
    }
}

/// The u-AIC's belief.
pub struct Uaic {
    config: UaicConfig,
    /// The prior in force this tick: `config.prior_mode()`, or with `switched` the one it picks.
    prior_in_force: PriorMode,
    /// The state prior's precisions P_mu, P_mu' at this tick length.
    prior_position_precision: f64,
    prior_velocity_precision: f64,
    layout: ChannelLayout,
    /// What each channel reads at a state (the camera through its GP).
    observation: Arc<dyn ObservationModel>,
    dt: f64,
    /// Belief x = [mu, mu'] and the previous tick's belief.
    x: DVector<f64>,
    x_prev: DVector<f64>,
    initialised: bool,
    /// Belief updates since the initialisation (drives the prior's warm-up).
    updates: u64,
    // Scratch, reused every tick.
    hessian: DMatrix<f64>,
    /// H^-1, the Laplace posterior covariance of the last update.
    covariance: DMatrix<f64>,
    rhs: DVector<f64>,
    x_hat: DVector<f64>,
    /// The point the update is linearised at (x_hat, or x_{k-1} for the gradient scheme).
    point: DVector<f64>,
    /// The new belief before it is accepted.
    candidate: DVector<f64>,
    /// Storage the Cholesky factor of H is built in.
    factor: DMatrix<f64>,
    /// The prior residual e_x.
    ex: Vec<f64>,
    /// The propagated prior's precision matrix and its scratch.
    prior_info: DMatrix<f64>,
    prior_cov: DMatrix<f64>,
    prior_factor: DMatrix<f64>,
    /// ln |prior_info|.
    prior_log_det: f64,
    /// The camera model at the update point, and its first-order value at the new belief.
    g_point: Vec<f64>,
    g_post: Vec<f64>,
    jac: Vec<f64>,
    report: Estimate,
}

impl Uaic {
    /// A u-AIC belief over the channels of `observation` at tick length `dt`.
    pub fn new(config: UaicConfig, observation: Arc<dyn ObservationModel>, dt: f64) -> Self {
        let layout = *observation.layout();
        let n = layout.n_joints();
        let r = layout.camera_outputs();
        let (pm, pv) = config.prior_precisions(dt);
        Self {
            prior_in_force: match config.prior_mode() {
                PriorMode::Switched => PriorMode::Fixed,
                p => p,
            },
            config,
            prior_position_precision: pm,
            prior_velocity_precision: pv,
            layout,
            observation,
            dt,
            x: DVector::zeros(2 * n),
            x_prev: DVector::zeros(2 * n),
            initialised: false,
            updates: 0,
            hessian: DMatrix::zeros(2 * n, 2 * n),
            covariance: DMatrix::zeros(2 * n, 2 * n),
            rhs: DVector::zeros(2 * n),
            x_hat: DVector::zeros(2 * n),
            point: DVector::zeros(2 * n),
            candidate: DVector::zeros(2 * n),
            factor: DMatrix::zeros(2 * n, 2 * n),
            ex: vec![0.0; 2 * n],
            prior_info: DMatrix::zeros(2 * n, 2 * n),
            prior_cov: DMatrix::zeros(2 * n, 2 * n),
            prior_factor: DMatrix::zeros(2 * n, 2 * n),
            prior_log_det: 0.0,
            g_point: vec![0.0; r],
            g_post: vec![0.0; r],
            jac: vec![0.0; r * n],
            report: Estimate::new(&layout),
        }
    }

    pub fn config(&self) -> &UaicConfig {
        &self.config
    }

    /// Switches the state prior from the next update on (the propagated prior starts from the
    /// last update's posterior covariance).
    pub fn set_prior(&mut self, prior: PriorMode) {
        self.config.prior = Some(prior);
        if prior != PriorMode::Switched {
            self.prior_in_force = prior;
        }
    }

    /// The prior in force at the last update (`fixed` or `propagated`).
    pub fn prior_in_force(&self) -> PriorMode {
        self.prior_in_force
    }

    /// The belief x = [mu, mu'].
    pub fn belief(&self) -> &[f64] {
        self.x.as_slice()
    }

    /// Starts the belief at the first readings (a missing reading starts at 0).
    pub fn initialise(&mut self, readings: &Readings) {
        let n = self.layout.n_joints();
        for i in 0..n {
            self.x[i] = readings.get(i).unwrap_or(0.0);
            self.x[n + i] = readings.get(n + i).unwrap_or(0.0);
        }
        self.x_prev.copy_from(&self.x);
        self.initialised = true;
        self.updates = 0;
    }

    /// Moves the belief to `x` (and, with a propagated prior, its covariance to `covariance`):
    /// re-anchoring from an estimate that never used a channel found faulty.
    pub fn reanchor(&mut self, x: &[f64], covariance: Option<&DMatrix<f64>>) {
        self.x.copy_from_slice(x);
        self.x_prev.copy_from_slice(x);
        if let Some(c) = covariance {
            self.covariance.copy_from(c);
        }
    }

    /// The propagated prior: prior_info = (A Sigma A' + Q)^-1, Sigma the last posterior (or,
    /// at the first tick, each reading's variance).
    fn propagate_prior(&mut self, precisions: &[f64]) {
        let n = self.layout.n_joints();
        let dt = self.dt;
        if self.updates == 0 {
            self.covariance.fill(0.0);
            for i in 0..n {
                for k in [i, n + i] {
                    let w = precisions[k];
                    self.covariance[(k, k)] = if w > 0.0 { 1.0 / w } else { 1.0 };
                }
            }
        }
        let s = &self.covariance;
        let q = &mut self.prior_cov;
        for r in 0..n {
            for c in 0..n {
                let (pqq, pqv, pvq, pvv) =
                    (s[(r, c)], s[(r, n + c)], s[(n + r, c)], s[(n + r, n + c)]);
                q[(r, c)] = pqq + dt * (pqv + pvq) + dt * dt * pvv;
                q[(r, n + c)] = pqv + dt * pvv;
                q[(n + r, c)] = pvq + dt * pvv;
                q[(n + r, n + c)] = pvv;
            }
        }
        let s2 = self.config.acceleration_bound.powi(2);
        for i in 0..n {
            q[(i, i)] += s2 * dt.powi(4) / 4.0;
            q[(i, n + i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, n + i)] += s2 * dt * dt;
        }
        // Factor in reused storage (no allocation): prior_info = Sigma_prior^-1 and
        // ln |prior_info| = -2 sum ln L_ii.
        let d = 2 * n;
        let mut storage = std::mem::replace(&mut self.prior_factor, DMatrix::zeros(0, 0));
        storage.copy_from(&self.prior_cov);
        match nalgebra::linalg::Cholesky::new(storage) {
            Some(ch) => {
                self.prior_info.fill_with_identity();
                ch.solve_mut(&mut self.prior_info);
                let l = ch.l_dirty();
                self.prior_log_det = -2.0 * (0..d).map(|i| l[(i, i)].ln()).sum::<f64>();
                self.prior_factor = ch.unpack_dirty();
            }
            None => {
                // A degenerate covariance: fall back to the fixed diagonal prior.
                self.prior_factor = DMatrix::zeros(d, d);
                self.prior_info.fill(0.0);
                for i in 0..n {
                    self.prior_info[(i, i)] = self.prior_position_precision;
                    self.prior_info[(n + i, n + i)] = self.prior_velocity_precision;
                }
                self.prior_log_det = n as f64
                    * (self.prior_position_precision.ln() + self.prior_velocity_precision.ln());
            }
        }
    }

    /// The prior precisions (P_mu, P_mu') in force, with the warm-up ramp applied.
    pub fn prior_precisions(&self) -> (f64, f64) {
        let k = self.config.prior_warmup_ticks;
        let scale = if k == 0 {
            1.0
        } else {
            ((self.updates + 1) as f64 / k as f64).min(1.0)
        };
        (
            self.prior_position_precision * scale,
            self.prior_velocity_precision * scale,
        )
    }

    /// The sensory prediction of channel `c` at a state, given the GP output `g` at its mu.
    fn predict_channel(&self, c: usize, x: &DVector<f64>, g: &[f64]) -> f64 {
        match self.layout.channel(c) {
            Channel::Encoder(i) => x[i],
            Channel::Tachometer(i) => x[self.layout.n_joints() + i],
            Channel::Camera(r) => g[r],
        }
    }

    /// Adds w J_c' J_c to the Hessian and w J_c' e to the right-hand side.
    fn accumulate(&mut self, c: usize, w: f64, e: f64) {
        let n = self.layout.n_joints();
        match self.layout.channel(c) {
            Channel::Encoder(i) => {
                self.hessian[(i, i)] += w;
                self.rhs[i] += w * e;
            }
            Channel::Tachometer(i) => {
                self.hessian[(n + i, n + i)] += w;
                self.rhs[n + i] += w * e;
            }
            Channel::Camera(r) => {
                let row = &self.jac[r * n..(r + 1) * n];
                for a in 0..n {
                    self.rhs[a] += w * row[a] * e;
                    for b in 0..n {
                        self.hessian[(a, b)] += w * row[a] * row[b];
                    }
                }
            }
        }
    }

    /// Fills the prior's Hessian (A' P_x A) into `self.hessian`.
    fn prior_hessian(&mut self) {
        let n = self.layout.n_joints();
        if self.prior_in_force == PriorMode::Propagated {
            self.hessian.copy_from(&self.prior_info);
            return;
        }
        let (pm, pv) = self.prior_precisions();
        self.hessian.fill(0.0);
        for i in 0..n {
            match self.config.prediction {
                Prediction::Paper | Prediction::AuthorsMatlab => {
                    self.hessian[(i, i)] = pm;
                    self.hessian[(n + i, n + i)] = pv;
                }
                Prediction::Coupled => {
                    // A = [[I, -dt I], [0, I]]: A' P A = [[Pm, -dt Pm], [-dt Pm, dt^2 Pm + Pv]].
                    self.hessian[(i, i)] = pm;
                    self.hessian[(i, n + i)] = -self.dt * pm;
                    self.hessian[(n + i, i)] = -self.dt * pm;
                    self.hessian[(n + i, n + i)] = self.dt * self.dt * pm + pv;
                }
            }
        }
    }

    /// The prior residual e_x at `x` given the previous belief `prev` (paper: x - A prev;
    /// coupled: A x - prev with A = [[I, -dt I], [0, I]]; authors-matlab: x - prev).
    fn prior_residual(&self, x: &DVector<f64>, prev: &DVector<f64>, out: &mut [f64]) {
        let n = self.layout.n_joints();
        for i in 0..n {
            let (mu, mv) = (x[i], x[n + i]);
            let (pmu, pmv) = (prev[i], prev[n + i]);
            out[i] = match self.config.prediction {
                Prediction::Paper => mu - pmu - self.dt * pmv,
                Prediction::Coupled => mu - pmu - self.dt * mv,
                Prediction::AuthorsMatlab => mu - pmu,
            };
            out[n + i] = mv - pmv;
        }
    }

    /// The free energy at belief `x` = [mu, mu'] with the prior relative to the previous belief
    /// `prev`, and its gradient dF/dx (the e_u term, zero when u = f*, left out). Channels
    /// missing from `readings` or with precision 0 are left out. Constant terms (ln 2 pi) are
    /// dropped.
    pub fn free_energy(
        &self,
        x: &[f64],
        prev: &[f64],
        readings: &Readings,
        precisions: &[f64],
    ) -> (f64, Vec<f64>) {
        let n = self.layout.n_joints();
        let r = self.layout.camera_outputs();
        let (mut g, mut jac) = (vec![0.0; r], vec![0.0; r * n]);
        self.observation.camera(&x[..n], &mut g, &mut jac);
        let xv = DVector::from_column_slice(x);
        let mut f = 0.0;
        let mut grad = vec![0.0; 2 * n];
        for c in 0..self.layout.len() {
            let (Some(y), w) = (readings.get(c), precisions[c]) else {
                continue;
            };
            if w <= 0.0 {
                continue;
            }
            let e = y - self.predict_channel(c, &xv, &g);
            f += 0.5 * (w * e * e - w.ln());
            match self.layout.channel(c) {
                Channel::Encoder(i) => grad[i] -= w * e,
                Channel::Tachometer(i) => grad[n + i] -= w * e,
                Channel::Camera(r) => {
                    for a in 0..n {
                        grad[a] -= w * e * jac[r * n + a];
                    }
                }
            }
        }
        let mut ex = vec![0.0; 2 * n];
        self.prior_residual(&xv, &DVector::from_column_slice(prev), &mut ex);
        let (pm, pv) = self.prior_precisions();
        for i in 0..n {
            f +=
                0.5 * (pm * ex[i] * ex[i] - pm.ln()) + 0.5 * (pv * ex[n + i] * ex[n + i] - pv.ln());
            grad[i] += pm * ex[i];
            match self.config.prediction {
                // d e_x,pos / d mu' = -dt.
                Prediction::Coupled => {
                    grad[n + i] += pv * ex[n + i];
                    grad[n + i] -= self.dt * pm * ex[i];
                }
                // The authors' mu_dot_p carries + P_mu0 (mu(i) - mu(i-1)), summed in their order.
                Prediction::AuthorsMatlab => {
                    grad[n + i] += pm * ex[i];
                    grad[n + i] += pv * ex[n + i];
                }
                Prediction::Paper => grad[n + i] += pv * ex[n + i],
            }
        }
        (f, grad)
    }

    /// One tick: update the belief from `readings` with channel precisions `precisions` (0
    /// leaves a channel out). The first call initialises the belief from the readings.
    pub fn step(&mut self, readings: &Readings, precisions: &[f64]) -> &Estimate {
        let n = self.layout.n_joints();
        let m = self.layout.len();
        let r = self.layout.camera_outputs();
        debug_assert_eq!(precisions.len(), m);
        if !self.initialised {
            self.initialise(readings);
        }
        let dt = self.dt;
        self.report.precisions_used.copy_from_slice(precisions);
        if self.config.prior_mode() == PriorMode::Switched {
            let pv = self.prior_velocity_precision;
            let dropped = self
                .layout
                .group_range(crate::sensors::SensorGroup::Tachometers)
                .any(|c| precisions[c] < pv || readings.get(c).is_none());
            self.prior_in_force = if dropped {
                PriorMode::Propagated
            } else {
                PriorMode::Fixed
            };
        }

        // Prediction x_hat = A x_{k-1} and the innovations against it.
        for i in 0..n {
            self.x_hat[i] = self.x[i] + dt * self.x[n + i];
            self.x_hat[n + i] = self.x[n + i];
        }
        let mut g = std::mem::take(&mut self.g_point);
        self.observation
            .camera(&self.x_hat.as_slice()[..n], &mut g, &mut self.jac);
        for c in 0..m {
            self.report.innovations[c] = readings
                .get(c)
                .map(|y| y - self.predict_channel(c, &self.x_hat, &g));
        }

        // The Gauss-Newton Hessian H = sum w J'J + A' P_x A: the GN step's metric and, inverted,
        // the Laplace posterior covariance behind the corrections c_i.
        match self.config.update {
            UpdateScheme::GaussNewton => self.point.copy_from(&self.x_hat),
            UpdateScheme::Gradient => {
                self.point.copy_from(&self.x);
                self.observation
                    .camera(&self.point.as_slice()[..n], &mut g, &mut self.jac);
            }
        }
        if self.prior_in_force == PriorMode::Propagated {
            self.propagate_prior(precisions);
        }
        self.prior_hessian();
        self.rhs.fill(0.0);
        for c in 0..m {
            if let Some(y) = readings.get(c)
                && precisions[c] > 0.0
            {
                let e = y - self.predict_channel(c, &self.point, &g);
                self.accumulate(c, precisions[c], e);
            }
        }
        if self.factor_hessian().is_none() {
            self.g_point = g;
            return self.refuse();
        }
        self.update_candidate(readings, precisions);
        if !self.candidate.iter().all(|v| v.is_finite()) {
            self.g_point = g;
            return self.refuse();
        }
        self.x_prev.copy_from(&self.x);
        self.x.copy_from(&self.candidate);

        // Residuals after the update, the corrections c_i and F at the new belief. The camera's
        // prediction there comes from the GP's first-order expansion about the update point:
        // the belief moves well under 1e-2 rad per tick, so the dropped second-order term stays
        // below 1e-5 m, three orders under the camera noise, and a second GP call is saved.
        for ro in 0..r {
            let mut v = g[ro];
            for d in 0..n {
                v += self.jac[ro * n + d] * (self.x[d] - self.point[d]);
            }
            self.g_post[ro] = v;
        }
        self.g_point = g;
        self.corrections();
        let gg = std::mem::take(&mut self.g_post);
        for c in 0..m {
            self.report.residuals[c] = readings
                .get(c)
                .map(|y| y - self.predict_channel(c, &self.x, &gg));
        }
        self.g_post = gg;
        let free_energy = self.belief_free_energy(precisions);
        self.report.free_energy = Some(free_energy);
        self.report.finite = free_energy.is_finite();
        self.updates += 1;
        &self.report
    }

    /// The update's candidate belief: the Gauss-Newton step from x_hat, or the gradient step from
    /// the previous belief.
    fn update_candidate(&mut self, readings: &Readings, precisions: &[f64]) {
        let n = self.layout.n_joints();
        let dt = self.dt;
        match self.config.update {
            // At x_hat the prior's gradient vanishes: -dF/dx = rhs, and x = x_hat + eta H^-1 rhs.
            UpdateScheme::GaussNewton => {
                self.candidate.gemv(1.0, &self.covariance, &self.rhs, 0.0);
                for i in 0..2 * n {
                    self.candidate[i] = self.x_hat[i] + self.candidate[i] * self.config.step;
                }
            }
            // x_k = x_{k-1} + dt (D x_{k-1} - kappa_mu dF/dx(x_{k-1})), prior mean A x_{k-2}.
            UpdateScheme::Gradient => {
                let (_, grad) = self.free_energy(
                    self.point.as_slice(),
                    self.x_prev.as_slice(),
                    readings,
                    precisions,
                );
                self.candidate.copy_from(&self.point);
                for i in 0..n {
                    self.candidate[i] += dt * self.point[n + i];
                }
                for (v, gr) in self.candidate.iter_mut().zip(&grad) {
                    *v -= dt * self.config.kappa_mu * gr;
                }
            }
        }
    }

    /// F at the updated belief, from the residuals after the update and the prior's residual.
    fn belief_free_energy(&mut self, precisions: &[f64]) -> f64 {
        let n = self.layout.n_joints();
        let m = self.layout.len();
        let mut free_energy = 0.0;
        for c in 0..m {
            if let Some(e) = self.report.residuals[c]
                && precisions[c] > 0.0
            {
                free_energy += 0.5 * (precisions[c] * e * e - precisions[c].ln());
            }
        }
        let mut ex = std::mem::take(&mut self.ex);
        if self.prior_in_force == PriorMode::Propagated {
            // e_x = x - x_hat; 1/2 (e_x' Lambda e_x - ln |Lambda|).
            for i in 0..2 * n {
                ex[i] = self.x[i] - self.x_hat[i];
            }
            let mut quad = 0.0;
            for a in 0..2 * n {
                for b in 0..2 * n {
                    quad += ex[a] * self.prior_info[(a, b)] * ex[b];
                }
            }
            let log_det = self.prior_log_det;
            free_energy += 0.5 * (quad - log_det);
        } else {
            self.prior_residual(&self.x, &self.x_prev, &mut ex);
            let (pm, pv) = self.prior_precisions();
            for i in 0..n {
                free_energy += 0.5 * (pm * ex[i] * ex[i] - pm.ln());
                free_energy += 0.5 * (pv * ex[n + i] * ex[n + i] - pv.ln());
            }
        }
        self.ex = ex;
        free_energy
    }

    /// Factorises H and stores H^-1 as the posterior covariance, reusing the factor's storage.
    fn factor_hessian(&mut self) -> Option<()> {
        let dim = self.hessian.nrows();
        let mut storage = std::mem::replace(&mut self.factor, DMatrix::zeros(0, 0));
        storage.copy_from(&self.hessian);
        let Some(chol) = nalgebra::linalg::Cholesky::new(storage) else {
            self.factor = DMatrix::zeros(dim, dim);
            return None;
        };
        self.covariance.fill_with_identity();
        chol.solve_mut(&mut self.covariance);
        self.factor = chol.unpack_dirty();
        Some(())
    }

    /// c_i = (J_i H^-1 J_i')_ii from the last factorised Hessian.
    fn corrections(&mut self) {
        let n = self.layout.n_joints();
        let cov = &self.covariance;
        for c in 0..self.layout.len() {
            self.report.corrections[c] = match self.layout.channel(c) {
                Channel::Encoder(i) => cov[(i, i)],
                Channel::Tachometer(i) => cov[(n + i, n + i)],
                Channel::Camera(r) => {
                    let row = &self.jac[r * n..(r + 1) * n];
                    let mut s = 0.0;
                    for a in 0..n {
                        for b in 0..n {
                            s += row[a] * cov[(a, b)] * row[b];
                        }
                    }
                    s
                }
            };
        }
    }

    fn refuse(&mut self) -> &Estimate {
        self.report.finite = false;
        &self.report
    }
}

impl Estimator for Uaic {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        self.step(input.readings, input.precisions)
    }

    fn estimate(&self) -> &Estimate {
        &self.report
    }

    fn mu(&self) -> &[f64] {
        &self.x.as_slice()[..self.layout.n_joints()]
    }

    fn mu_p(&self) -> &[f64] {
        &self.x.as_slice()[self.layout.n_joints()..]
    }

    /// The Laplace posterior covariance H^-1 of the last update.
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        Some(&self.covariance)
    }
}
