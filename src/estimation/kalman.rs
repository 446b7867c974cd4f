//! Kalman filters on the joint state x = [q, qd]: the extended Kalman filter the classical
//! baselines share ([`Ekf`]), and two of them as estimators, `ekf-gate` ([`EkfGate`]: chi-square
//! gating per channel, exclusion and re-admission) and `vb-akf` ([`VbAkf`]: the variational-Bayes
//! adaptive filter of Sarkka and Nummenmaa 2009, per-channel noise variances with forgetting)
//! (docs/method.md, "Classical baselines").
//!
//! The model: constant velocity with white acceleration noise (the discrete white-noise
//! acceleration model, Q_j = s_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] per joint, s_a the
//! acceleration bound of the u-AIC's prior), or, when an arm model is given, the arm's own
//! dynamics driven by the applied torques (qdd = M^-1 (u - C qd - G - D qd), s_a then the
//! model's acceleration error). Encoders and tachometers measure q and qd; the camera g_v(q)
//! through the GP, linearised at the prediction. Measurements are processed one channel at a
//! time (diagonal noise), which equals the batch update of the linearised model.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::models::{
    ArmTransition, ConstantVelocity, ObservationModel, Transition, TransitionModel,
};
use super::{Estimate, Estimator, EstimatorInput};
use crate::arm::ArmModel;
use crate::sensors::{Channel, ChannelLayout, Readings};

/// Settings of the Kalman-filter baselines (the `[kalman]` section).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct KalmanConfig {
    /// Process noise of the constant-velocity model: the acceleration (rad/s^2) treated as one
    /// standard deviation; absent: the u-AIC's `belief.acceleration_bound`. With
    /// `process_model = "dynamics"` used only where the arm's mass matrix is singular.
    pub acceleration_noise: Option<f64>,
    /// Chi-square gate on a channel's normalised innovation nu^2 / S (1 degree of freedom;
    /// 10.83 is the 99.9 % point).
    pub gate: f64,
    /// Ticks beyond the gate in a row before a channel is excluded.
    pub exclude_after: u64,
    /// Ticks within the gate in a row before an excluded channel is re-admitted.
    pub readmit_after: u64,
    /// Variational iterations per tick of `vb-akf`.
    pub vb_iterations: usize,
    /// Forgetting factor of `vb-akf` (memory about 1 / (1 - rho) ticks).
    pub vb_rho: f64,
    /// Per-tick probability of leaving a hypothesis, `imm`.
    pub imm_switch: f64,
    /// A hypothesis' faulty channel: noise standard deviation this many times the nominal.
    pub imm_broad: f64,
    /// The manoeuvre hypothesis of `imm` (every sensor nominal, the acceleration noise this many
    /// times the model's: a hard acceleration the constant-velocity model misses is a manoeuvre,
    /// not a failed sensor); 0 leaves it out.
    pub imm_manoeuvre: f64,
    /// `ekf-gate`: when this many channels or more fall beyond the gate within `exclude_after`
    /// ticks, the residual is common-mode (the model, not a sensor, is off, as in a hard
    /// acceleration): nothing is gated that tick and the covariance is inflated by the largest
    /// normalised innovation squared of the channels in use (a fading factor); 0: never.
    pub common_mode: usize,
    /// The filters' transition model: constant velocity with `acceleration_noise` (default, as
    /// in the textbook baselines), or the arm's own dynamics driven by the applied torques, the
    /// model the hybrid's bank uses: the estimators' arm model and process noise of `[model]`.
    pub process_model: ProcessModel,
}

/// The Kalman baselines' transition model (`kalman.process_model`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum ProcessModel {
    /// Constant velocity with white acceleration noise.
    #[default]
    ConstantVelocity,
    /// The arm's dynamics (the estimators' model, `[model]`) and applied torques.
    Dynamics,
}

impl Default for KalmanConfig {
    fn default() -> Self {
        Self {
            acceleration_noise: None,
            gate: 10.83,
            exclude_after: 5,
            readmit_after: 500,
            vb_iterations: 3,
            vb_rho: 0.999,
            imm_switch: 1e-4,
            imm_broad: 1000.0,
            imm_manoeuvre: 10.0,
            common_mode: 2,
            process_model: ProcessModel::ConstantVelocity,
        }
    }
}

impl KalmanConfig {
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        if let Some(a) = self.acceleration_noise
            && !(a.is_finite() && a > 0.0 && a <= 1e9)
        {
            return Err(crate::SettingError::new(
                "acceleration_noise",
                "must be finite, > 0 and <= 1e9",
            ));
        }
        if !(self.gate.is_finite() && self.gate > 0.0) {
            return Err(crate::SettingError::new("gate", "must be finite and > 0"));
        }
        if self.exclude_after == 0 || self.exclude_after > 1_000_000_000 {
            return Err(crate::SettingError::new(
                "exclude_after",
                "must be in 1..=1e9",
            ));
        }
        if self.readmit_after == 0 || self.readmit_after > 1_000_000_000 {
            return Err(crate::SettingError::new(
                "readmit_after",
                "must be in 1..=1e9",
            ));
        }
        if !(1..=100).contains(&self.vb_iterations) {
            return Err(crate::SettingError::new(
                "vb_iterations",
                "must be in 1..=100",
            ));
        }
        if !(self.vb_rho > 0.0 && self.vb_rho < 1.0) {
            return Err(crate::SettingError::new("vb_rho", "must be in (0, 1)"));
        }
        if !(self.imm_switch > 0.0 && self.imm_switch < 0.5) {
            return Err(crate::SettingError::new(
                "imm_switch",
                "must be in (0, 0.5)",
            ));
        }
        if !(self.imm_broad.is_finite() && self.imm_broad > 1.0 && self.imm_broad <= 1e9) {
            return Err(crate::SettingError::new("imm_broad", "must be in (1, 1e9]"));
        }
        if !(self.imm_manoeuvre == 0.0
            || (self.imm_manoeuvre.is_finite()
                && self.imm_manoeuvre > 1.0
                && self.imm_manoeuvre <= 1e6))
        {
            return Err(crate::SettingError::new(
                "imm_manoeuvre",
                "must be 0 or in (1, 1e6]",
            ));
        }
        if self.common_mode > 1_000_000 {
            return Err(crate::SettingError::new(
                "common_mode",
                "must be <= 1000000",
            ));
        }
        Ok(())
    }
}

/// The transition model `process` names: the arm's dynamics on `model` (the estimators' copy of
/// the arm) with the process noise of `noise` (`[model]`), or constant velocity with
/// `acceleration_noise` (also the dynamics' fallback where its mass matrix is singular).
pub fn transition_model(
    process: ProcessModel,
    model: Arc<ArmModel>,
    gravity: [f64; 3],
    noise: &crate::arm::ModelConfig,
    acceleration_noise: f64,
    dt: f64,
) -> Box<dyn TransitionModel> {
    let n = model.joints.len();
    match process {
        ProcessModel::ConstantVelocity => Box::new(ConstantVelocity::new(n, acceleration_noise)),
        ProcessModel::Dynamics => Box::new(
            ArmTransition::new(
                model,
                gravity,
                noise.acceleration_noise,
                noise.relative_error,
                acceleration_noise,
            )
            .with_uncertainty(noise.uncertainty())
            .with_step(noise.step, dt),
        ),
    }
}

/// A camera prediction that one joint alone moves: g + J_i (q_i - position), another filter's
/// linearisation with joint i taken from the filter scored against it (the hybrid's pair
/// evidence: docs/method.md, "Pair evidence").
#[derive(Clone, Copy, Debug)]
pub struct CameraReference<'a> {
    pub joint: usize,
    /// The camera's outputs at the linearisation point.
    pub g: &'a [f64],
    /// The Jacobian's column of the joint, per output.
    pub column: &'a [f64],
    /// The joint's position at the linearisation point.
    pub position: f64,
}

impl CameraReference<'_> {
    /// Output r's prediction with the joint where `x` has it.
    pub fn predict(&self, r: usize, x: &DVector<f64>) -> f64 {
        self.g[r] + self.column[r] * (x[self.joint] - self.position)
    }
}

/// The extended Kalman filter on [q, qd]: the one filter step (predict with a transition, update
/// channel by channel with an observation model) every Kalman-type estimator here runs.
#[derive(Clone)]
pub struct Ekf {
    layout: ChannelLayout,
    observation: Arc<dyn ObservationModel>,
    dt: f64,
    pub x: DVector<f64>,
    pub p: DMatrix<f64>,
    initialised: bool,
    /// Whether the state carries each joint's model-error acceleration after [q, qd].
    model_error_state: bool,
    // Scratch.
    x_pred: DVector<f64>,
    p_pred: DMatrix<f64>,
    g: Vec<f64>,
    jac: Vec<f64>,
    ph: DVector<f64>,
    /// Per channel: the prediction's innovation and its variance (with the channel's noise).
    pub innovation: Vec<Option<f64>>,
    pub innovation_variance: Vec<Option<f64>>,
}

impl Ekf {
    /// A filter on the channels of `observation`, ticking every `dt` seconds.
    pub fn new(observation: Arc<dyn ObservationModel>, dt: f64) -> Self {
        let layout = *observation.layout();
        let d = 2 * layout.n_joints();
        let r = layout.camera_outputs();
        Self {
            layout,
            observation,
            dt,
            x: DVector::zeros(d),
            p: DMatrix::zeros(d, d),
            initialised: false,
            model_error_state: false,
            x_pred: DVector::zeros(d),
            p_pred: DMatrix::zeros(d, d),
            g: vec![0.0; r],
            jac: vec![0.0; r * layout.n_joints()],
            ph: DVector::zeros(d),
            innovation: vec![None; layout.len()],
            innovation_variance: vec![None; layout.len()],
        }
    }

    /// The same filter with each joint's model-error acceleration as a state after [q, qd]
    /// (docs/method.md, "Model error as a state"): x = [q, qd, e], the prediction adds e to the
    /// model's acceleration, e is a random walk whose step is the transition's
    /// [`super::models::CorrelatedError::step`], and only the white part of its noise stays white.
    /// e starts at 0 with variance 0: the first prediction's step is the whole parameter error.
    pub fn with_model_error_state(mut self) -> Self {
        let d = 3 * self.n();
        self.model_error_state = true;
        self.x = DVector::zeros(d);
        self.p = DMatrix::zeros(d, d);
        self.x_pred = DVector::zeros(d);
        self.p_pred = DMatrix::zeros(d, d);
        self.ph = DVector::zeros(d);
        self
    }

    /// The camera's outputs and Jacobian (outputs x joints, row-major) at the last
    /// linearisation, and the state it was taken at.
    pub fn camera_linearisation(&self) -> (&[f64], &[f64], &[f64]) {
        (&self.g, &self.jac, self.x_pred.as_slice())
    }

    /// The observation model.
    pub fn observation(&self) -> &Arc<dyn ObservationModel> {
        &self.observation
    }

    /// The joint state [q, qd] (without the model-error state).
    pub fn joint_state(&self) -> &[f64] {
        &self.x.as_slice()[..2 * self.n()]
    }

    pub fn n(&self) -> usize {
        self.layout.n_joints()
    }

    pub fn layout(&self) -> ChannelLayout {
        self.layout
    }

    pub fn initialised(&self) -> bool {
        self.initialised
    }

    /// Starts at the first readings with a covariance of one reading's noise (a missing reading:
    /// 0 with a variance of 1).
    pub fn initialise(&mut self, readings: &Readings, variances: &[f64]) {
        let n = self.n();
        self.p.fill(0.0);
        self.x.fill(0.0);
        for i in 0..n {
            for (k, c) in [(i, i), (n + i, n + i)] {
                match readings.get(c) {
                    Some(y) if variances[c].is_finite() => {
                        self.x[k] = y;
                        self.p[(k, k)] = variances[c];
                    }
                    _ => {
                        self.x[k] = 0.0;
                        self.p[(k, k)] = 1.0;
                    }
                }
            }
        }
        self.initialised = true;
    }

    /// Prediction over one tick with a transition (its acceleration; none: constant velocity),
    /// each joint's process noise its noise times `scale`; the model's velocity damping
    /// `-dt M^-1 D` is left out of the Jacobian F = [[I, dt I], [0, I]] (small at 1 ms).
    pub fn predict(&mut self, transition: &Transition<'_>, scale: f64) {
        self.predict_scaled(transition, |_| scale);
    }

    /// [`Self::predict`] with joint i's process noise (standard deviation) scaled by `scale(i)`.
    pub fn predict_scaled(&mut self, transition: &Transition<'_>, scale: impl Fn(usize) -> f64) {
        if self.model_error_state {
            return self.predict_with_model_error(transition, scale);
        }
        let n = self.n();
        let dt = self.dt;
        let acc = transition.acceleration;
        for i in 0..n {
            let a = acc.map_or(0.0, |a| a[i]);
            self.x_pred[i] = self.x[i] + dt * self.x[n + i] + 0.5 * dt * dt * a;
            self.x_pred[n + i] = self.x[n + i] + dt * a;
        }
        // P = F P F' + Q with F = [[I, dt I], [0, I]], written out by blocks.
        let p = &self.p;
        let q = &mut self.p_pred;
        for r in 0..n {
            for c in 0..n {
                let (pqq, pqv, pvq, pvv) =
                    (p[(r, c)], p[(r, n + c)], p[(n + r, c)], p[(n + r, n + c)]);
                q[(r, c)] = pqq + dt * (pqv + pvq) + dt * dt * pvv;
                q[(r, n + c)] = pqv + dt * pvv;
                q[(n + r, c)] = pvq + dt * pvv;
                q[(n + r, n + c)] = pvv;
            }
        }
        for i in 0..n {
            let s = scale(i) * transition.noise[i];
            let s2 = s * s;
            q[(i, i)] += s2 * dt.powi(4) / 4.0;
            q[(i, n + i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, n + i)] += s2 * dt * dt;
        }
        self.x.copy_from(&self.x_pred);
        self.p.copy_from(&self.p_pred);
    }

    /// [`Self::predict_scaled`] on x = [q, qd, e]: F = [[I, dt I, dt^2/2 I], [0, I, dt I], [0, 0,
    /// I]], the white part of the noise on [q, qd] as there, e's step on e.
    fn predict_with_model_error(
        &mut self,
        transition: &Transition<'_>,
        scale: impl Fn(usize) -> f64,
    ) {
        let n = self.n();
        let d = 3 * n;
        let dt = self.dt;
        let h = 0.5 * dt * dt;
        let acc = transition.acceleration;
        // The model error is carried first (it drives this tick's motion): e <- k e, and e's
        // rows and columns of P times k.
        if let Some(c) = transition.correlated {
            for (i, &k) in c.carry.iter().enumerate() {
                if k != 1.0 {
                    self.x[2 * n + i] *= k;
                    for r in 0..d {
                        self.p[(2 * n + i, r)] *= k;
                    }
                    for r in 0..d {
                        self.p[(r, 2 * n + i)] *= k;
                    }
                }
            }
        }
        for i in 0..n {
            let a = acc.map_or(0.0, |a| a[i]) + self.x[2 * n + i];
            self.x_pred[i] = self.x[i] + dt * self.x[n + i] + h * a;
            self.x_pred[n + i] = self.x[n + i] + dt * a;
            self.x_pred[2 * n + i] = self.x[2 * n + i];
        }
        // The model error steps at the tick's start (it drives this tick's motion), then
        // P = F P F' + Q: T = F P by rows, then T F' by columns.
        let q = &mut self.p_pred;
        q.copy_from(&self.p);
        if let Some(c) = transition.correlated {
            for i in 0..n {
                q[(2 * n + i, 2 * n + i)] += c.step[i] * c.step[i];
            }
        }
        for c in 0..d {
            for i in 0..n {
                let (pq, pv, pe) = (q[(i, c)], q[(n + i, c)], q[(2 * n + i, c)]);
                q[(i, c)] = pq + dt * pv + h * pe;
                q[(n + i, c)] = pv + dt * pe;
            }
        }
        for r in 0..d {
            for i in 0..n {
                let (tq, tv, te) = (q[(r, i)], q[(r, n + i)], q[(r, 2 * n + i)]);
                q[(r, i)] = tq + dt * tv + h * te;
                q[(r, n + i)] = tv + dt * te;
            }
        }
        // The two passes round differently above and below the diagonal: one number for both.
        for c in 0..d {
            for r in 0..c {
                let v = 0.5 * (q[(r, c)] + q[(c, r)]);
                q[(r, c)] = v;
                q[(c, r)] = v;
            }
        }
        let white = transition.correlated.map_or(transition.noise, |c| c.white);
        for i in 0..n {
            // A hypothesis that scales a joint's noise says its torque is not the model's: all
            // of the model's noise, scaled, is white there.
            let k = scale(i);
            let s = if k == 1.0 {
                white[i]
            } else {
                k * transition.noise[i]
            };
            let s2 = s * s;
            q[(i, i)] += s2 * dt.powi(4) / 4.0;
            q[(i, n + i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, i)] += s2 * dt.powi(3) / 2.0;
            q[(n + i, n + i)] += s2 * dt * dt;
            // How the motion within the tick is integrated: dt^2 / 2 a for a constant
            // acceleration; the plants' two semi-implicit Euler substeps move dt^2 / 4 a
            // further (docs/method.md, "Model error as a state"). The acceleration a + e is
            // uncertain by e's variance: the gap's variance is (dt^2 / 4)^2 E[(a + e)^2].
            let a = acc.map_or(0.0, |a| a[i]) + self.x[2 * n + i];
            let a2 = a * a + q[(2 * n + i, 2 * n + i)];
            q[(i, i)] += 0.25 * h * h * a2;
        }
        self.x.copy_from(&self.x_pred);
        self.p.copy_from(&self.p_pred);
    }

    /// The GP at the current mean (the linearisation point of the camera channels).
    pub fn linearise(&mut self) {
        let n = self.n();
        self.observation
            .camera(&self.x.as_slice()[..n], &mut self.g, &mut self.jac);
        self.x_pred.copy_from(&self.x);
    }

    /// [`Self::linearise`], taking the GP's values from the first of `sources` linearised at
    /// exactly this filter's joint positions (bit for bit) instead of evaluating it again: the
    /// result is the same bits. Every source must have been linearised this tick.
    pub fn linearise_from<'a>(&mut self, sources: impl IntoIterator<Item = &'a Ekf>) {
        let n = self.n();
        let same = |d: &&Ekf| (0..n).all(|i| d.x_pred[i].to_bits() == self.x[i].to_bits());
        match sources.into_iter().find(same) {
            Some(d) => {
                self.g.copy_from_slice(&d.g);
                self.jac.copy_from_slice(&d.jac);
                self.x_pred.copy_from(&self.x);
            }
            None => self.linearise(),
        }
    }

    /// The prediction of channel c at the current mean (camera: first order about the
    /// linearisation point).
    pub(crate) fn predicted(&self, c: usize) -> f64 {
        let n = self.n();
        match self.layout.channel(c) {
            Channel::Encoder(i) => self.x[i],
            Channel::Tachometer(i) => self.x[n + i],
            Channel::Camera(r) => {
                let mut v = self.g[r];
                for d in 0..n {
                    v += self.jac[r * n + d] * (self.x[d] - self.x_pred[d]);
                }
                v
            }
        }
    }

    /// H_c P H_c' with the current covariance.
    pub fn projected_variance(&self, c: usize) -> f64 {
        let n = self.n();
        match self.layout.channel(c) {
            Channel::Encoder(i) => self.p[(i, i)],
            Channel::Tachometer(i) => self.p[(n + i, n + i)],
            Channel::Camera(r) => {
                let row = &self.jac[r * n..(r + 1) * n];
                let mut s = 0.0;
                for a in 0..n {
                    for b in 0..n {
                        s += row[a] * self.p[(a, b)] * row[b];
                    }
                }
                s
            }
        }
    }

    /// P H_c' into `ph`.
    fn p_h(&mut self, c: usize) {
        let n = self.n();
        match self.layout.channel(c) {
            Channel::Encoder(i) => self.ph.copy_from(&self.p.column(i)),
            Channel::Tachometer(i) => self.ph.copy_from(&self.p.column(n + i)),
            Channel::Camera(r) => {
                self.ph.fill(0.0);
                for a in 0..self.x.len() {
                    let mut s = 0.0;
                    for b in 0..n {
                        s += self.p[(a, b)] * self.jac[r * n + b];
                    }
                    self.ph[a] = s;
                }
            }
        }
    }

    /// Records every channel's innovation against the current mean (the prediction) and its
    /// variance with the channel's noise `variances` (infinite: left out).
    pub fn record_innovations(&mut self, readings: &Readings, variances: &[f64]) {
        for c in 0..self.layout.len() {
            self.innovation[c] = readings.get(c).map(|y| y - self.predicted(c));
            self.innovation_variance[c] = self.innovation[c].map(|_| {
                let r = variances[c];
                self.projected_variance(c) + if r.is_finite() { r } else { 0.0 }
            });
        }
    }

    /// One scalar update with channel c's reading y and noise variance r; returns the
    /// log-likelihood of the innovation (without the 1/2 ln 2 pi constant).
    pub fn update_channel(&mut self, c: usize, y: f64, r: f64) -> f64 {
        let nu = y - self.predicted(c);
        let s = self.projected_variance(c) + r;
        if !(s.is_finite() && s > 0.0) {
            return 0.0;
        }
        self.p_h(c);
        let d = self.x.len();
        let ph = self.ph.as_slice();
        for (x, h) in self.x.iter_mut().zip(ph) {
            *x += h / s * nu;
        }
        // P -= ph ph' / s, as (ph_a ph_b) (1 / s): the same number for (a, b) and (b, a), so P
        // stays exactly symmetric.
        rank_one_downdate(self.p.as_mut_slice(), d, ph, 1.0 / s);
        -0.5 * (nu * nu / s + s.ln())
    }

    /// Updates with every present channel whose variance is finite; returns the total
    /// log-likelihood.
    pub fn update(&mut self, readings: &Readings, variances: &[f64]) -> f64 {
        let mut ll = 0.0;
        for c in 0..self.layout.len() {
            if let Some(y) = readings.get(c)
                && variances[c].is_finite()
            {
                ll += self.update_channel(c, y, variances[c]);
            }
        }
        ll
    }

    /// [`Self::update`] that also writes, for each channel `scored` picks, its normalised
    /// sequential innovation nu / sqrt(s) (as the log-likelihood takes it; NaN when the channel
    /// has no reading) into `z` and sqrt(s) into `spread`; with a `reference`, the camera's
    /// innovations are taken against its prediction instead of the filter's own: what the hybrid's pair evidence compares between hypotheses
    /// (docs/method.md, "Pair evidence").
    pub fn update_scored(
        &mut self,
        readings: &Readings,
        variances: &[f64],
        scored: impl Fn(usize) -> bool,
        reference: Option<&CameraReference<'_>>,
        z: &mut [f64],
        spread: &mut [f64],
    ) -> f64 {
        let mut ll = 0.0;
        for c in 0..self.layout.len() {
            z[c] = f64::NAN;
            spread[c] = f64::NAN;
            if let Some(y) = readings.get(c)
                && variances[c].is_finite()
            {
                if scored(c) {
                    let nu = y - match (reference, self.layout.channel(c)) {
                        (Some(reference), Channel::Camera(r)) => reference.predict(r, &self.x),
                        _ => self.predicted(c),
                    };
                    let s = self.projected_variance(c) + variances[c];
                    if s.is_finite() && s > 0.0 {
                        z[c] = nu / s.sqrt();
                        spread[c] = s.sqrt();
                    }
                }
                ll += self.update_channel(c, y, variances[c]);
            }
        }
        ll
    }

    /// Fills the post-update part of an [`Estimate`]: residuals and corrections.
    pub fn report_posterior(&self, readings: &Readings, out: &mut Estimate) {
        for c in 0..self.layout.len() {
            out.residuals[c] = readings.get(c).map(|y| y - self.predicted(c));
            out.corrections[c] = self.projected_variance(c);
        }
    }

    /// Whether the mean and covariance are finite.
    pub fn finite(&self) -> bool {
        self.x.iter().all(|v| v.is_finite()) && self.p.iter().all(|v| v.is_finite())
    }
}

/// P -= h h' inv_s on a column-major d x d matrix, entry by entry as `p_ab -= (h_a h_b) inv_s`:
/// the banks' hot loop (every scalar update of every hypothesis). Where the processor has AVX2
/// the same loop is compiled for it and chosen at run time: each entry is still one rounded
/// product, one rounded product and one rounded difference (no fused multiply-add, no
/// reordering), so the result is bit for bit the same on every x86-64 machine; only the number of
/// entries per instruction changes.
fn rank_one_downdate(p: &mut [f64], d: usize, h: &[f64], inv_s: f64) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2 (checked just above).
        unsafe { rank_one_downdate_avx2(p, d, h, inv_s) };
        return;
    }
    rank_one_downdate_portable(p, d, h, inv_s);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn rank_one_downdate_avx2(p: &mut [f64], d: usize, h: &[f64], inv_s: f64) {
    rank_one_downdate_portable(p, d, h, inv_s);
}

#[inline(always)]
fn rank_one_downdate_portable(p: &mut [f64], d: usize, h: &[f64], inv_s: f64) {
    for (b, column) in p.chunks_exact_mut(d).enumerate() {
        let hb = h[b];
        for (v, ha) in column.iter_mut().zip(h) {
            *v -= ha * hb * inv_s;
        }
    }
}

/// Joint-position distance (rad) within which filters of a bank share one linearisation of the
/// GP camera: the first-order camera prediction about a point 1e-3 rad away errs by about
/// |g''| 1e-6 / 2, 5e-7 m for a 1 m arm, against the camera's 0.01 m noise.
pub const SHARED_LINEARISATION: f64 = 1e-3;

/// Linearises every filter of a bank ([`Ekf::linearise`]), with one GP evaluation shared among
/// filters whose joint positions lie within [`SHARED_LINEARISATION`] of an earlier filter's
/// linearisation point (each then predicts the camera to first order about that point). A bank
/// whose hypotheses agree, as when nothing fails, costs one GP evaluation instead of one each.
/// With `active`, only the filters it marks are linearised or shared from.
pub fn linearise_bank(bank: &mut [Ekf], active: Option<&[bool]>) {
    let is_active = |j: usize| active.is_none_or(|a| a[j]);
    for j in 0..bank.len() {
        if !is_active(j) {
            continue;
        }
        let (done, rest) = bank.split_at_mut(j);
        let f = &mut rest[0];
        let n = f.n();
        let near = done
            .iter()
            .enumerate()
            .filter(|(i, _)| is_active(*i))
            .map(|(_, d)| d)
            .find(|d| (0..n).all(|i| (d.x_pred[i] - f.x[i]).abs() <= SHARED_LINEARISATION));
        match near {
            Some(d) => {
                f.g.copy_from_slice(&d.g);
                f.jac.copy_from_slice(&d.jac);
                f.x_pred.copy_from(&d.x_pred);
            }
            None => f.linearise(),
        }
    }
}

/// Variance of each channel from its precision (0: infinite, left out).
pub fn variances_of(precisions: &[f64], out: &mut [f64]) {
    for (v, w) in out.iter_mut().zip(precisions) {
        *v = if *w > 0.0 { 1.0 / w } else { f64::INFINITY };
    }
}

/// `ekf-gate`: an EKF whose channels are gated on their normalised innovation: a reading beyond
/// the gate is not used that tick; a channel beyond it for `exclude_after` ticks in a row is
/// excluded (precision 0) until it has been within it for `readmit_after` ticks.
pub struct EkfGate {
    ekf: Ekf,
    config: KalmanConfig,
    model: Box<dyn TransitionModel>,
    variances: Vec<f64>,
    used: Vec<f64>,
    beyond: Vec<u64>,
    within: Vec<u64>,
    excluded: Vec<bool>,
    nis: Vec<Option<f64>>,
    last_beyond: Vec<Option<u64>>,
    n: usize,
    mu: Vec<f64>,
    mu_p: Vec<f64>,
    report: Estimate,
}

impl EkfGate {
    pub fn new(ekf: Ekf, config: KalmanConfig, model: Box<dyn TransitionModel>) -> Self {
        let layout = ekf.layout;
        let m = layout.len();
        let n = layout.n_joints();
        Self {
            ekf,
            config,
            model,
            variances: vec![0.0; m],
            used: vec![0.0; m],
            beyond: vec![0; m],
            within: vec![0; m],
            excluded: vec![false; m],
            nis: vec![None; m],
            last_beyond: vec![None; m],
            n,
            mu: vec![0.0; n],
            mu_p: vec![0.0; n],
            report: Estimate::new(&layout),
        }
    }
}

/// Predicts an EKF one tick with its transition model evaluated at the filter's mean.
fn predict_with(ekf: &mut Ekf, model: &mut dyn TransitionModel, torques: &[f64]) {
    let transition = model.evaluate(ekf.x.as_slice(), torques);
    ekf.predict(&transition, 1.0);
}

impl Estimator for EkfGate {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        let m = self.variances.len();
        variances_of(input.precisions, &mut self.variances);
        if !self.ekf.initialised() {
            self.ekf.initialise(input.readings, &self.variances);
        } else {
            predict_with(&mut self.ekf, self.model.as_mut(), input.applied_torques);
        }
        self.ekf.linearise();
        self.ekf.record_innovations(input.readings, &self.variances);
        // Normalised innovations squared; the common-mode test over the channels in use.
        let tick = input.tick;
        let mut nis_max = 0.0f64;
        for c in 0..m {
            self.nis[c] = match (self.ekf.innovation[c], self.ekf.innovation_variance[c]) {
                (Some(nu), Some(s)) if s > 0.0 && self.variances[c].is_finite() => {
                    let v = nu * nu / s;
                    if !self.excluded[c] {
                        if v > self.config.gate {
                            self.last_beyond[c] = Some(tick);
                        }
                        nis_max = nis_max.max(v);
                    }
                    Some(v)
                }
                _ => None,
            };
        }
        // Channels beyond the gate within the last `exclude_after` ticks (one of them now).
        let window = self.config.exclude_after.max(1);
        let recent = (0..m)
            .filter(|&c| {
                !self.excluded[c] && self.last_beyond[c].is_some_and(|k| k + window > tick)
            })
            .count();
        let now = (0..m).any(|c| self.last_beyond[c] == Some(tick));
        let common = self.config.common_mode > 0 && now && recent >= self.config.common_mode;
        if common {
            self.last_beyond.fill(None);
            // The fading factor: the covariance grows until the worst channel in use is one
            // standard deviation off; no channel is judged, so none moves towards exclusion.
            let fading = nis_max.max(1.0);
            self.ekf.p *= fading;
            self.beyond.fill(0);
            self.ekf.record_innovations(input.readings, &self.variances);
        }
        for c in 0..m {
            let Some(nis) = self.nis[c] else {
                self.used[c] = 0.0;
                continue;
            };
            if common {
                self.used[c] = if self.excluded[c] {
                    0.0
                } else {
                    input.precisions[c]
                };
                continue;
            }
            if nis > self.config.gate {
                self.beyond[c] += 1;
                self.within[c] = 0;
            } else {
                self.within[c] += 1;
                self.beyond[c] = 0;
            }
            if self.excluded[c] && self.within[c] >= self.config.readmit_after {
                self.excluded[c] = false;
            }
            if !self.excluded[c] && self.beyond[c] >= self.config.exclude_after {
                self.excluded[c] = true;
            }
            let pass = !self.excluded[c] && nis <= self.config.gate;
            self.used[c] = if pass { input.precisions[c] } else { 0.0 };
        }
        let mut ll = 0.0;
        for c in 0..m {
            if self.used[c] > 0.0
                && let Some(y) = input.readings.get(c)
            {
                ll += self.ekf.update_channel(c, y, 1.0 / self.used[c]);
            }
        }
        self.report.innovations.clone_from(&self.ekf.innovation);
        self.report
            .innovation_variances
            .clone_from(&self.ekf.innovation_variance);
        self.ekf.report_posterior(input.readings, &mut self.report);
        self.report.precisions_used.copy_from_slice(&self.used);
        self.report.log_likelihood = Some(ll);
        self.report.free_energy = None;
        self.report.finite = self.ekf.finite();
        let n = self.n;
        if self.report.finite {
            self.mu.copy_from_slice(&self.ekf.x.as_slice()[..n]);
            self.mu_p.copy_from_slice(&self.ekf.x.as_slice()[n..]);
        }
        &self.report
    }

    fn estimate(&self) -> &Estimate {
        &self.report
    }
    fn mu(&self) -> &[f64] {
        &self.mu
    }
    fn mu_p(&self) -> &[f64] {
        &self.mu_p
    }
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        Some(&self.ekf.p)
    }
}

/// `vb-akf`: the variational-Bayes adaptive Kalman filter (Sarkka and Nummenmaa 2009): each
/// channel's noise variance has an inverse-Gamma posterior IG(alpha, beta), spread by the
/// forgetting factor rho at every prediction (alpha <- rho alpha, beta <- rho beta); the update
/// alternates, `vb_iterations` times, a Kalman update with R = beta / alpha and
/// beta = beta_pred + 1/2 ((y - h(x))^2 + H P H'), alpha = alpha_pred + 1/2. Started at the
/// nominal variance, with the healthy steady state alpha0 = 1 / (2 (1 - rho)); the precision
/// alpha / beta is clamped to [1e-6, 1] x nominal like the u-AIC's learners.
pub struct VbAkf {
    ekf: Ekf,
    rho: f64,
    iterations: usize,
    model: Box<dyn TransitionModel>,
    nominal: Vec<f64>,
    alpha: Vec<f64>,
    beta: Vec<f64>,
    alpha_pred: Vec<f64>,
    beta_pred: Vec<f64>,
    x0: DVector<f64>,
    p0: DMatrix<f64>,
    used: Vec<f64>,
    n: usize,
    mu: Vec<f64>,
    mu_p: Vec<f64>,
    report: Estimate,
    min_ratio: f64,
    /// Scratch: each channel's noise variance this tick.
    variances: Vec<f64>,
}

impl VbAkf {
    pub fn new(
        ekf: Ekf,
        config: &KalmanConfig,
        model: Box<dyn TransitionModel>,
        nominal: &[f64],
        min_ratio: f64,
    ) -> Self {
        let layout = ekf.layout;
        let n = layout.n_joints();
        let d = 2 * n;
        let a0 = 0.5 / (1.0 - config.vb_rho);
        Self {
            rho: config.vb_rho,
            iterations: config.vb_iterations,
            model,
            alpha: vec![a0; nominal.len()],
            beta: nominal.iter().map(|w| a0 / w).collect(),
            alpha_pred: vec![0.0; nominal.len()],
            beta_pred: vec![0.0; nominal.len()],
            nominal: nominal.to_vec(),
            x0: DVector::zeros(d),
            p0: DMatrix::zeros(d, d),
            used: nominal.to_vec(),
            n,
            mu: vec![0.0; n],
            mu_p: vec![0.0; n],
            report: Estimate::new(&layout),
            ekf,
            min_ratio,
            variances: vec![0.0; nominal.len()],
        }
    }
}

impl VbAkf {
    /// The precision in force for channel c (alpha / beta, clamped to [min_ratio, 1] x nominal).
    fn precision(&self, c: usize) -> f64 {
        (self.alpha[c] / self.beta[c]).clamp(self.min_ratio * self.nominal[c], self.nominal[c])
    }

    /// Each channel's noise variance from the current estimate; infinite for the channels the
    /// caller leaves out (precision 0).
    fn fill_variances(&self, precisions: &[f64], out: &mut [f64]) {
        for (c, v) in out.iter_mut().enumerate() {
            *v = if precisions[c] <= 0.0 {
                f64::INFINITY
            } else {
                1.0 / self.precision(c)
            };
        }
    }
}

impl Estimator for VbAkf {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        let m = self.nominal.len();
        let mut variances = std::mem::take(&mut self.variances);
        if !self.ekf.initialised() {
            self.fill_variances(input.precisions, &mut variances);
            self.ekf.initialise(input.readings, &variances);
        } else {
            predict_with(&mut self.ekf, self.model.as_mut(), input.applied_torques);
        }
        // The noise parameters' prediction: forgetting spreads the posterior.
        for c in 0..m {
            self.alpha_pred[c] = self.rho * self.alpha[c];
            self.beta_pred[c] = self.rho * self.beta[c];
            self.alpha[c] = self.alpha_pred[c]
                + if input.readings.get(c).is_some() {
                    0.5
                } else {
                    0.0
                };
            self.beta[c] = self.beta_pred[c];
        }
        self.ekf.linearise();
        self.x0.copy_from(&self.ekf.x);
        self.p0.copy_from(&self.ekf.p);
        self.fill_variances(input.precisions, &mut variances);
        self.ekf.record_innovations(input.readings, &variances);
        let mut ll = 0.0;
        for iteration in 0..self.iterations {
            // The first iteration uses the variances just filled (alpha and beta unchanged).
            if iteration > 0 {
                self.fill_variances(input.precisions, &mut variances);
            }
            self.ekf.x.copy_from(&self.x0);
            self.ekf.p.copy_from(&self.p0);
            ll = self.ekf.update(input.readings, &variances);
            for c in 0..m {
                if let Some(y) = input.readings.get(c) {
                    let e = y - self.ekf.predicted(c);
                    self.beta[c] =
                        self.beta_pred[c] + 0.5 * (e * e + self.ekf.projected_variance(c));
                }
            }
        }
        for c in 0..m {
            self.used[c] = if variances[c].is_finite() {
                1.0 / variances[c]
            } else {
                0.0
            };
        }
        self.report.innovations.clone_from(&self.ekf.innovation);
        self.report
            .innovation_variances
            .clone_from(&self.ekf.innovation_variance);
        self.ekf.report_posterior(input.readings, &mut self.report);
        self.report.precisions_used.copy_from_slice(&self.used);
        self.report.log_likelihood = Some(ll);
        self.report.free_energy = None;
        self.report.finite = self.ekf.finite();
        let n = self.n;
        if self.report.finite {
            self.mu.copy_from_slice(&self.ekf.x.as_slice()[..n]);
            self.mu_p.copy_from_slice(&self.ekf.x.as_slice()[n..]);
        }
        self.variances = variances;
        &self.report
    }

    fn estimate(&self) -> &Estimate {
        &self.report
    }
    fn mu(&self) -> &[f64] {
        &self.mu
    }
    fn mu_p(&self) -> &[f64] {
        &self.mu_p
    }
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        Some(&self.ekf.p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::CameraModel;
    use rand::SeedableRng;

    use rand_distr::{Distribution, Normal};

    /// The downdate chosen at run time (AVX2 where the processor has it) is bit for bit the
    /// entry-by-entry formula, on random matrices of the sizes the filters use (2n and 3n for
    /// n = 1..7, odd sizes included: the vector loop's remainder).
    #[test]
    fn the_rank_one_downdate_is_the_entrywise_formula_bit_for_bit() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(41);
        let normal = Normal::new(0.0, 1.0).unwrap();
        for d in [2, 3, 4, 6, 9, 14, 21] {
            for _ in 0..20 {
                let p = DMatrix::from_fn(d, d, |_, _| normal.sample(&mut rng));
                let h: Vec<f64> = (0..d).map(|_| normal.sample(&mut rng)).collect();
                let inv_s = 1.0 / (1.0 + normal.sample(&mut rng).abs());
                let mut expected = p.clone();
                for b in 0..d {
                    for a in 0..d {
                        let product = std::hint::black_box(h[a] * h[b]);
                        expected[(a, b)] -= std::hint::black_box(product * inv_s);
                    }
                }
                let mut fast = p.clone();
                rank_one_downdate(fast.as_mut_slice(), d, &h, inv_s);
                for (x, y) in fast.iter().zip(expected.iter()) {
                    assert_eq!(x.to_bits(), y.to_bits(), "d = {d}");
                }
            }
        }
    }

    fn toy_observation(layout: ChannelLayout) -> Arc<dyn ObservationModel> {
        crate::estimation::models::GpCamera::shared(layout, Arc::new(crate::gp::GpModel::toy()))
    }

    /// `kalman.process_model`: constant velocity has no acceleration; with the dynamics, the
    /// arm's own acceleration and the process noise max(floor, relative |qdd|) per joint, and
    /// the EKF's prediction x + dt v + dt^2 a / 2 with them.
    #[test]
    fn the_dynamics_process_model_predicts_with_the_arms_acceleration() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
        let model = crate::arm::load_urdf(&path).unwrap();
        let g = [0.0, 0.0, -9.81];
        let model = Arc::new(model);
        let noise = crate::arm::ModelConfig::perfect();
        let (q, qd, u) = ([0.3, -0.7], [0.5, -1.0], [40.0, -3.0]);
        let x = [q[0], q[1], qd[0], qd[1]];
        let cv = ProcessModel::ConstantVelocity;
        assert!(
            transition_model(cv, model.clone(), g, &noise, 200.0, 1e-3)
                .evaluate(&x, &u)
                .acceleration
                .is_none()
        );
        let mut prediction = transition_model(
            ProcessModel::Dynamics,
            model.clone(),
            g,
            &noise,
            200.0,
            1e-3,
        );
        let mut direct = crate::arm::Dynamics::new(model, g);
        let mut expected = vec![0.0; 2];
        // The default step (`model.step = "implicit"`): damping at the tick's end.
        assert!(direct.forward_dynamics_implicit(&q, &qd, &u, 1e-3, &mut expected));
        let t = prediction.evaluate(&x, &u);
        assert_eq!(t.acceleration.unwrap(), expected.as_slice());
        for (s, a) in t.noise.iter().zip(&expected) {
            assert_eq!(*s, f64::max(2.0, 0.1 * a.abs()));
        }
        assert!(expected.iter().any(|a| 0.1 * a.abs() > 2.0), "{expected:?}");
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let mut ekf = Ekf::new(toy_observation(layout), 1e-3);
        ekf.x.copy_from_slice(&x);
        predict_with(&mut ekf, prediction.as_mut(), &u);
        for i in 0..2 {
            let dt = 1e-3;
            let want = x[i] + dt * x[2 + i] + 0.5 * dt * dt * expected[i];
            assert!((ekf.x[i] - want).abs() < 1e-15, "{} {want}", ekf.x[i]);
            assert!((ekf.x[2 + i] - (x[2 + i] + dt * expected[i])).abs() < 1e-15);
        }
    }

    /// With the model-error state, the prediction is x' = F K x + [dt^2/2 a, dt a, 0] and P' = F
    /// (K P K' + diag(0, 0, step^2)) F' + Q, against dense matrices built here: K = diag(I, I,
    /// carry), F = [[I, dt I, dt^2/2 I], [0, I, dt I], [0, 0, I]], Q the white noise on [q, qd]
    /// and (dt^2/4)^2 E[(a + e)^2] on q (e's mean and variance after the carry and step).
    #[test]
    fn the_model_error_state_predicts_as_the_dense_equations() {
        let n = 2;
        let layout = ChannelLayout::new(n, CameraModel::Pinhole);
        let dt = 1e-3;
        let h = 0.5 * dt * dt;
        let mut ekf = Ekf::new(toy_observation(layout), dt).with_model_error_state();
        assert_eq!((ekf.x.len(), ekf.p.nrows()), (3 * n, 3 * n));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let a = DMatrix::from_fn(3 * n, 3 * n, |_, _| unit.sample(&mut rng));
        let p0 = &a * a.transpose() + DMatrix::identity(3 * n, 3 * n);
        let x0 = DVector::from_fn(3 * n, |_, _| unit.sample(&mut rng));
        ekf.p.copy_from(&p0);
        ekf.x.copy_from(&x0);
        let (acc, noise, white, step) = ([30.0, -4.0], [9.0, 7.0], [2.0, 3.0], [5.0, 0.5]);
        let carry = [0.7, -0.3];
        let t = Transition {
            acceleration: Some(&acc),
            noise: &noise,
            correlated: Some(crate::estimation::models::CorrelatedError {
                white: &white,
                step: &step,
                carry: &carry,
            }),
        };
        ekf.predict(&t, 1.0);
        let mut f = DMatrix::identity(3 * n, 3 * n);
        let mut k = DMatrix::identity(3 * n, 3 * n);
        let mut q = DMatrix::zeros(3 * n, 3 * n);
        for i in 0..n {
            k[(2 * n + i, 2 * n + i)] = carry[i];
        }
        let x0 = &k * x0;
        let mut stepped = &k * p0 * k.transpose();
        for i in 0..n {
            f[(i, n + i)] = dt;
            f[(i, 2 * n + i)] = h;
            f[(n + i, 2 * n + i)] = dt;
            stepped[(2 * n + i, 2 * n + i)] += step[i] * step[i];
            let w2 = white[i] * white[i];
            let total = acc[i] + x0[2 * n + i];
            let second_moment = total * total + stepped[(2 * n + i, 2 * n + i)];
            q[(i, i)] = w2 * dt.powi(4) / 4.0 + (0.5 * h).powi(2) * second_moment;
            q[(i, n + i)] = w2 * dt.powi(3) / 2.0;
            q[(n + i, i)] = w2 * dt.powi(3) / 2.0;
            q[(n + i, n + i)] = w2 * dt * dt;
        }
        let mut x = &f * &x0;
        for i in 0..n {
            x[i] += h * acc[i];
            x[n + i] += dt * acc[i];
        }
        let p = &f * stepped * f.transpose() + q;
        assert!((&ekf.x - &x).amax() < 1e-14, "{} {}", ekf.x, x);
        assert!((&ekf.p - &p).amax() < 1e-12 * p.amax(), "{} {}", ekf.p, p);
        assert_eq!(ekf.p, ekf.p.transpose());
        assert_eq!(ekf.joint_state(), &ekf.x.as_slice()[..2 * n]);
    }

    /// A fixed model error is the model-error state's fixed point: the arm accelerates at the
    /// model's acceleration plus a constant c the model does not know, encoders and tachometers
    /// read it with their noise, and the filter's e converges to c (within 3 of its standard
    /// deviations, which shrink well below the error's size), while e stays 0 without one.
    #[test]
    fn the_model_error_state_learns_a_fixed_model_error() {
        let n = 2;
        let layout = ChannelLayout::new(n, CameraModel::Pinhole);
        let dt = 1e-3;
        let var = [1e-6, 1e-6, 1e-6, 1e-6, f64::INFINITY, f64::INFINITY];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let unit = Normal::new(0.0, 1.0).unwrap();
        for c in [[40.0, -25.0], [0.0, 0.0]] {
            let mut ekf = Ekf::new(toy_observation(layout), dt).with_model_error_state();
            let (mut q, mut v) = ([0.2, -0.1], [0.0, 0.0]);
            let mut readings = Readings::missing(&layout);
            for k in 0..3000 {
                // The model's acceleration: a slow oscillation it knows.
                let t = k as f64 * dt;
                let acc = [3.0 * (2.0 * t).sin(), -2.0 * (3.0 * t).cos()];
                if k > 0 {
                    for i in 0..n {
                        q[i] += dt * v[i] + 0.5 * dt * dt * (acc[i] + c[i]);
                        v[i] += dt * (acc[i] + c[i]);
                    }
                }
                let truth = [q[0], q[1], v[0], v[1]];
                for (ch, y) in truth.iter().enumerate() {
                    readings.values[ch] = Some(y + var[ch].sqrt() * unit.sample(&mut rng));
                }
                if !ekf.initialised() {
                    ekf.initialise(&readings, &var);
                    continue;
                }
                // The whole parameter error (100 rad/s^2) at the first step, none after.
                let step = if k == 1 { [100.0; 2] } else { [0.0; 2] };
                let t = Transition {
                    acceleration: Some(&acc),
                    noise: &[100.0; 2],
                    correlated: Some(crate::estimation::models::CorrelatedError {
                        white: &[2.0; 2],
                        step: &step,
                        carry: &[1.0; 2],
                    }),
                };
                ekf.predict(&t, 1.0);
                ekf.linearise();
                ekf.update(&readings, &var);
            }
            for i in 0..n {
                let (e, sd) = (ekf.x[2 * n + i], ekf.p[(2 * n + i, 2 * n + i)].sqrt());
                assert!(
                    (e - c[i]).abs() < 3.0 * sd,
                    "joint {i}: e {e} sd {sd}, c {}",
                    c[i]
                );
                assert!(sd < 2.0, "joint {i}: sd {sd}");
            }
        }
    }

    /// `linearise_from` takes the GP's values from a source at exactly the same joint
    /// positions (the same bits as evaluating it), and evaluates the GP itself when no source
    /// is: one 1e-9 rad apart (within the bank's shared-linearisation distance) is not the same
    /// point.
    #[test]
    fn linearising_from_an_identical_point_is_linearising() {
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let filter_at = |q: [f64; 2]| {
            let mut f = Ekf::new(toy_observation(layout), 1e-3);
            f.x[0] = q[0];
            f.x[1] = q[1];
            f.x[2] = 0.3;
            f
        };
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut source = filter_at([0.2, -0.4]);
        source.linearise();
        let mut own = filter_at([0.2, -0.4]);
        own.linearise();
        let mut shared = filter_at([0.2, -0.4]);
        shared.x[3] = 7.0; // velocities do not enter the camera
        shared.linearise_from([&source]);
        assert_eq!(bits(&shared.g), bits(&own.g));
        assert_eq!(bits(&shared.jac), bits(&own.jac));
        assert_eq!(bits(shared.x_pred.as_slice()), bits(shared.x.as_slice()));
        // Not the same point: evaluated, not copied.
        let mut near = filter_at([0.2 + 1e-9, -0.4]);
        near.linearise_from([&source]);
        let mut near_own = filter_at([0.2 + 1e-9, -0.4]);
        near_own.linearise();
        assert_eq!(bits(&near.g), bits(&near_own.g));
        assert_ne!(bits(&near.g), bits(&source.g));
        // No source: evaluated.
        let mut alone = filter_at([0.2, -0.4]);
        alone.linearise_from(std::iter::empty());
        assert_eq!(bits(&alone.g), bits(&own.g));
    }

    /// The EKF's innovation covariance S = H P H' + R against a Monte Carlo estimate: a 2-joint
    /// system that is exactly the filter's model (white acceleration noise, encoders, tachometers
    /// and a camera that is the GP's mean plus white noise), 400 runs; from tick 300 on, the
    /// sample covariance of the encoder/tachometer innovations matches the filter's predicted S
    /// (a full 4x4 block, cross terms included) and each camera channel's normalised innovation
    /// squared averages 1.
    #[test]
    fn innovation_covariance_matches_monte_carlo() {
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let gp = Arc::new(crate::gp::GpModel::toy());
        let dt = 1e-3;
        let s_a = 2.0;
        let mut cv = ConstantVelocity::new(2, s_a);
        let var: [f64; 6] = [1e-6, 1e-6, 4e-6, 4e-6, 1e-4, 1e-4];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let (runs, from, to) = (400, 300, 400);
        // Sums for the encoder/tachometer block (channels 0..4) and camera NIS.
        let mut sum = [0.0; 4];
        let mut outer = [[0.0; 4]; 4];
        let mut predicted = [[0.0; 4]; 4];
        let mut nis = [0.0; 2];
        let mut count = 0.0;
        let mut g = vec![0.0; 2];
        let mut jac = vec![0.0; 4];
        for _ in 0..runs {
            let mut q = [0.1 * unit.sample(&mut rng), 0.1 * unit.sample(&mut rng)];
            let mut v = [0.0, 0.0];
            let mut ekf = Ekf::new(toy_observation(layout), dt);
            let mut readings = Readings::missing(&layout);
            for k in 0..to {
                if k > 0 {
                    for i in 0..2 {
                        let a = s_a * unit.sample(&mut rng);
                        q[i] += dt * v[i] + 0.5 * dt * dt * a;
                        v[i] += dt * a;
                    }
                }
                gp.predict(&q, &mut g, &mut jac);
                let truth = [q[0], q[1], v[0], v[1], g[0], g[1]];
                for c in 0..6 {
                    readings.values[c] = Some(truth[c] + var[c].sqrt() * unit.sample(&mut rng));
                }
                if !ekf.initialised() {
                    ekf.initialise(&readings, &var);
                    // Start from the truth's spread, as the Monte Carlo does.
                    for i in 0..2 {
                        ekf.p[(i, i)] = 0.01;
                        ekf.x[i] = 0.0;
                    }
                    continue;
                }
                ekf.predict(&cv.evaluate(&[], &[]), 1.0);
                ekf.linearise();
                ekf.record_innovations(&readings, &var);
                if k >= from {
                    let nu: Vec<f64> = (0..4).map(|c| ekf.innovation[c].unwrap()).collect();
                    for a in 0..4 {
                        sum[a] += nu[a];
                        for b in 0..4 {
                            outer[a][b] += nu[a] * nu[b];
                            // Channels 0..4 are enc1, enc2, tach1, tach2: H picks state a.
                            predicted[a][b] += ekf.p[(a, b)] + if a == b { var[a] } else { 0.0 };
                        }
                    }
                    for r in 0..2 {
                        let c = 4 + r;
                        nis[r] += ekf.innovation[c].unwrap().powi(2)
                            / ekf.innovation_variance[c].unwrap();
                    }
                    count += 1.0;
                }
                ekf.update(&readings, &var);
            }
        }
        for a in 0..4 {
            let mean = sum[a] / count;
            for b in 0..4 {
                let sample = outer[a][b] / count - mean * sum[b] / count;
                let model = predicted[a][b] / count;
                let scale = (predicted[a][a] * predicted[b][b]).sqrt() / count;
                assert!(
                    (sample - model).abs() < 0.05 * scale,
                    "S[{a}][{b}]: Monte Carlo {sample:e}, filter {model:e}"
                );
            }
        }
        for (r, v) in nis.iter().enumerate() {
            let mean = v / count;
            assert!((mean - 1.0).abs() < 0.05, "camera {r}: mean NIS {mean}");
        }
    }

    /// The VB-AKF's noise learner at its fixed point: a static arm (nearly no process noise),
    /// encoder 1 with 3x its nominal noise standard deviation, the others nominal. The learned
    /// variance of encoder 1 settles at 9x nominal (precision 1/9), the others stay nominal.
    #[test]
    fn vb_akf_learns_a_channels_true_noise_variance() {
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let gp = Arc::new(crate::gp::GpModel::toy());
        let nominal_var: [f64; 6] = [1e-6, 1e-6, 1e-6, 1e-6, 1e-4, 1e-4];
        let mut true_var = nominal_var;
        true_var[0] *= 9.0;
        let nominal: Vec<f64> = nominal_var.iter().map(|v| 1.0 / v).collect();
        let ekf = Ekf::new(toy_observation(layout), 1e-3);
        let cv = Box::new(ConstantVelocity::new(2, 1e-3));
        let mut vb = VbAkf::new(ekf, &KalmanConfig::default(), cv, &nominal, 1e-6);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let unit = Normal::new(0.0, 1.0).unwrap();
        let q = [0.2, -0.3];
        let mut g = vec![0.0; 2];
        let mut jac = vec![0.0; 4];
        gp.predict(&q, &mut g, &mut jac);
        let truth = [q[0], q[1], 0.0, 0.0, g[0], g[1]];
        let mut readings = Readings::missing(&layout);
        let zeros = [0.0, 0.0];
        let mut mean = [0.0; 6];
        let (ticks, from) = (20_000u64, 10_000u64);
        for k in 0..ticks {
            for c in 0..6 {
                readings.values[c] = Some(truth[c] + true_var[c].sqrt() * unit.sample(&mut rng));
            }
            let est = vb.update(&EstimatorInput {
                tick: k,
                readings: &readings,
                precisions: &nominal,
                applied_torques: &zeros,
            });
            if k >= from {
                for c in 0..6 {
                    mean[c] += est.precisions_used[c] / nominal[c] / (ticks - from) as f64;
                }
            }
        }
        assert!((mean[0] - 1.0 / 9.0).abs() < 0.15 / 9.0, "enc1 {}", mean[0]);
        for (c, m) in mean.iter().enumerate().skip(1) {
            assert!(*m > 0.9, "channel {c}: {m}");
        }
    }
}
