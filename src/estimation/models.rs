//! The generative models estimators are composed from (as adskalman composes a filter from a
//! transition model and an observation model):
//!
//! - a [`TransitionModel`] says how the joint state x = [q, qd] moves over one tick: an
//!   acceleration per joint (none for constant velocity) and the white-acceleration noise around
//!   it. [`ConstantVelocity`] is the textbook model of the classical baselines; [`ArmTransition`]
//!   is the arm's own dynamics driven by the applied torques, on the estimator's copy of the arm
//!   model (erred where the scenario says so: the plant keeps the truth);
//! - an [`ObservationModel`] says what each channel reads at a state: encoders q, tachometers
//!   qd, the camera g(q) with its Jacobian ([`GpCamera`]: the channel layout with the GP camera
//!   model).
//!
//! The Kalman filter's predict and update ([`super::kalman::Ekf`]) take them; `ekf-gate`,
//! `vb-akf`, the IMM's and the hybrid's banks ([`super::bank`]) all step through that one filter.
//! The u-AIC reads the same observation model.

use std::sync::Arc;

use crate::arm::model_error::{InertialBudget, ModelUncertainty, length_scale};
use crate::arm::{ArmModel, Dynamics};
use crate::gp::GpModel;
use crate::sensors::ChannelLayout;

/// One tick's transition at a state, as a model evaluated it: each joint's acceleration (None:
/// constant velocity) and white-acceleration noise standard deviation (rad/s^2).
#[derive(Clone, Copy, Debug)]
pub struct Transition<'a> {
    pub acceleration: Option<&'a [f64]>,
    pub noise: &'a [f64],
    /// The same noise split for a filter that carries the model error as a state
    /// ([`super::kalman::Ekf::with_model_error_state`]); None: all of it is white.
    pub correlated: Option<CorrelatedError<'a>>,
}

/// A transition's noise for a filter that carries each joint's model-error acceleration as a
/// state (docs/method.md, "Model error as a state"): the white part, and the standard deviation
/// of the model error's change over the tick (rad/s^2), a random walk's step.
#[derive(Clone, Copy, Debug)]
pub struct CorrelatedError<'a> {
    pub white: &'a [f64],
    pub step: &'a [f64],
    /// Per joint, the factor the model error is carried by over the tick, E[e' | e] = carry e
    /// (docs/method.md, "Model error as a state").
    pub carry: &'a [f64],
}

/// How the joint state moves over one tick.
pub trait TransitionModel: Send {
    /// The transition at x = [q, qd] under the torques applied over the tick. Evaluated once
    /// and shared by as many filters as predict from it (a bank's hypotheses).
    fn evaluate(&mut self, x: &[f64], torques: &[f64]) -> Transition<'_>;

    /// The standard deviation of each joint's velocity at the state the next [`Self::evaluate`]
    /// is given (a joint that may be at rest may be stuck); ignored by default.
    fn set_velocity_spread(&mut self, _spread: &[f64]) {}

    /// The model-error acceleration (rad/s^2) a filter that carries it as a state estimates at
    /// that state (it scales the error's step, [`CorrelatedError`]); ignored by default.
    fn set_model_error(&mut self, _error: &[f64]) {}
}

/// Constant velocity with white acceleration noise: the discrete white-noise acceleration model,
/// Q_j = s_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] per joint.
#[derive(Clone, Debug)]
pub struct ConstantVelocity {
    noise: Vec<f64>,
}

impl ConstantVelocity {
    /// `n` joints, each with acceleration noise `s_a` (rad/s^2).
    pub fn new(n: usize, s_a: f64) -> Self {
        Self {
            noise: vec![s_a; n],
        }
    }
}

impl TransitionModel for ConstantVelocity {
    fn evaluate(&mut self, _: &[f64], _: &[f64]) -> Transition<'_> {
        Transition {
            acceleration: None,
            noise: &self.noise,
            correlated: None,
        }
    }
}

/// The arm's dynamics as a transition: qdd = M^-1 (u - C qd - G - D qd - F) of the estimator's
/// arm model under the applied torques, with each joint's process noise
/// max(`floor`, `relative` x |qdd|) (docs/method.md, "Classical baselines"): a hard acceleration
/// the model gets slightly wrong is noise, not a failed sensor. Where the model's mass matrix is
/// singular, constant velocity with the fallback noise.
#[derive(Clone, Debug)]
pub struct ArmTransition {
    dynamics: Dynamics,
    floor: f64,
    relative: f64,
    acceleration: Vec<f64>,
    noise: Vec<f64>,
    fallback: ConstantVelocity,
    uncertainty: ModelUncertainty,
    /// Scratch: each joint's acceleration variance from the parameter errors.
    acceleration_var: Vec<f64>,
    /// Per joint, the gravity-torque error (N m, one standard deviation) of the centres of mass
    /// beyond it: g sqrt(sum_b (com m_b L_b)^2).
    com_torque: Vec<f64>,
    /// Per body, the centre of mass' error per axis (m, one standard deviation): com x its
    /// length scale.
    com_sigma: Vec<f64>,
    /// Per joint and body, the centre-of-mass error's torque regressors
    /// ([`Dynamics::centre_of_mass_regressors`]) now and at the last evaluation.
    com_grad: Vec<[nalgebra::Vector3<f64>; 2]>,
    last_com_grad: Vec<[nalgebra::Vector3<f64>; 2]>,
    /// Per joint, the inertial torque error's own regressor u (M qdd)_j (signed) now and at the
    /// last evaluation; the columns of the step's inverse matrix now and then (column j at j n).
    regressor: Vec<f64>,
    last_regressor: Vec<f64>,
    columns: Vec<f64>,
    last_columns: Vec<f64>,
    /// Scratch: per joint, the inertial part's covariance between the last state and this one.
    torque_step_cov: Vec<f64>,
    /// Scratch: each joint's torque error and a column of M^-1.
    torque_error: Vec<f64>,
    column: Vec<f64>,
    /// The step of the implicit prediction (s); 0: explicit.
    implicit_step: f64,
    /// The white part of the noise (the floor and the relative term) and the model error's
    /// step over the tick ([`CorrelatedError`]).
    white: Vec<f64>,
    step: Vec<f64>,
    /// Per joint, the signed torques of the rest's moving terms at the last evaluation (mass
    /// bias, damping, the model's friction ramp), and the variance of their change.
    terms: Vec<[f64; 3]>,
    terms_set: bool,
    torque_step: Vec<f64>,
    step_var: Vec<f64>,
    /// Per joint, the factor the model error is carried by ([`CorrelatedError::carry`]); the
    /// last evaluation's inertial and other variances of the budget (rad/s^2)^2;
    /// the inertial torque variance (scratch); and the lead filter's model-error estimate.
    carry: Vec<f64>,
    last_acceleration: Vec<f64>,
    inertial_var: Vec<f64>,
    last_inertial_var: Vec<f64>,
    last_rest_var: Vec<f64>,
    inertial_torque: Vec<f64>,
    model_error: Vec<f64>,
    /// Per joint, the stiction band's torque variance (F^2 / 3 within the friction ramp), and
    /// its acceleration variance (white).
    stiction: Vec<f64>,
    stiction_var: Vec<f64>,
    /// Per joint, the velocity's standard deviation at the evaluated state.
    velocity_spread: Vec<f64>,
    /// Per joint, whether its velocity lies within the stiction band; the Cholesky factor of
    /// M + h D (viscous damping only) a slipping joint responds through.
    stuck: Vec<bool>,
    slip_factor: nalgebra::DMatrix<f64>,
}

impl ArmTransition {
    /// The dynamics of `model` (the estimator's copy) under `gravity`, process noise
    /// max(`floor`, `relative` |qdd|), constant velocity with `fallback` noise where singular.
    pub fn new(
        model: Arc<ArmModel>,
        gravity: [f64; 3],
        floor: f64,
        relative: f64,
        fallback: f64,
    ) -> Self {
        let (n, nb) = (model.joints.len(), model.bodies.len());
        Self {
            dynamics: Dynamics::new(model, gravity),
            floor,
            relative,
            acceleration: vec![0.0; n],
            noise: vec![0.0; n],
            fallback: ConstantVelocity::new(n, fallback),
            uncertainty: ModelUncertainty::default(),
            acceleration_var: vec![0.0; n],
            com_torque: vec![0.0; n],
            com_sigma: vec![0.0; nb],
            com_grad: vec![[nalgebra::Vector3::zeros(); 2]; n * nb],
            last_com_grad: vec![[nalgebra::Vector3::zeros(); 2]; n * nb],
            regressor: vec![0.0; n],
            last_regressor: vec![0.0; n],
            columns: vec![0.0; n * n],
            last_columns: vec![0.0; n * n],
            torque_step_cov: vec![0.0; n],
            torque_error: vec![0.0; n],
            column: vec![0.0; n],
            implicit_step: 0.0,
            white: vec![0.0; n],
            step: vec![0.0; n],
            terms: vec![[0.0; 3]; n],
            terms_set: false,
            torque_step: vec![0.0; n],
            step_var: vec![0.0; n],
            carry: vec![1.0; n],
            last_acceleration: vec![0.0; n],
            inertial_var: vec![0.0; n],
            last_inertial_var: vec![0.0; n],
            last_rest_var: vec![0.0; n],
            inertial_torque: vec![0.0; n],
            model_error: vec![0.0; n],
            stuck: vec![false; n],
            slip_factor: nalgebra::DMatrix::zeros(n, n),
            stiction: vec![0.0; n],
            stiction_var: vec![0.0; n],
            velocity_spread: vec![0.0; n],
        }
    }

    /// The same transition with the model's assumed parameter errors in its process noise: each
    /// joint's torque error sigma_tau_j = sqrt((max(mass, inertia) (M qdd)_j)^2 + (mass bias_j)^2 +
    /// (com torque_j)^2 + (damping D_j qd_j)^2 + (friction F_j)^2), carried to the accelerations through M^-1,
    /// sigma_i = sqrt(sum_j (M^-1_ij sigma_tau_j)^2); the noise is the largest of the floor, the
    /// relative term and sigma_i (docs/method.md, "Model error").
    pub fn with_uncertainty(mut self, uncertainty: ModelUncertainty) -> Self {
        let model = self.dynamics.model().clone();
        let g = self.dynamics.gravity().norm();
        let mut sums = vec![0.0; model.joints.len()];
        for (b, body) in model.bodies.iter().enumerate().skip(1) {
            let moment = uncertainty.com * body.mass * length_scale(&model, b) * g;
            // Every joint on the path from the body to the root carries it.
            let mut at = b;
            while let Some(j) = model.joints.iter().position(|j| j.child_body == at) {
                sums[j] += moment * moment;
                at = model.joints[j].parent_body;
            }
        }
        self.com_torque = sums.into_iter().map(f64::sqrt).collect();
        self.com_sigma = uncertainty.centre_of_mass_sigma(&model);
        self.uncertainty = uncertainty;
        self
    }

    /// The per-joint acceleration error of the model's parameter errors at the state last
    /// evaluated, into `noise` as a lower bound; and how the model error a filter carries as a
    /// state moves since the last evaluation (the first evaluation: all of it, from 0), into
    /// `carry` and `step` (docs/method.md, "Model error as a state"). Per joint i, the error is
    /// an inertial part sum_j M^-1_ij dtau_j, each joint's inertial torque error dtau_j linear
    /// in fixed parameter errors with regressors that move with the state (u (M qdd)_j for the
    /// mass and inertia, the centres of mass' gradients of [`Dynamics::centre_of_mass_regressors`]),
    /// with prior variance A (the budget's inertial terms through M^-1), and the rest b (mass
    /// bias, centre of mass' gravity torque, damping, friction: variance B), whose parameter
    /// errors are fixed, so it moves only as its regressors do (u_k (r_k - r_k,last), the
    /// friction ramp by all of its change, the centre-of-mass bound not at all: variance D).
    /// With A' the inertial variance at the new state and C = sum_j M^-1_ij M'^-1_ij
    /// Cov(dtau_j, dtau'_j) (the regressors' products, then and now), the error's conditional
    /// given its last value e is
    ///   E[e' | e] = (C + B) / (A + B) e,
    ///   Var[e' | e] = kappa (A' + B + D - (C + B)^2 / (A + B)),
    /// kappa = max(1, e^2 / (A + B)) with e the lead filter's estimate: a learned error larger
    /// than the budget scales the budget up.
    fn parameter_noise(&mut self, qd: &[f64], torques: &[f64]) {
        let u = self.uncertainty;
        let model = self.dynamics.model().clone();
        let mut inertial_torque = std::mem::take(&mut self.inertial_torque);
        let per_joint = u.inertial_budget == InertialBudget::PerJoint;
        if per_joint {
            self.dynamics.centre_of_mass_regressors(
                &self.acceleration,
                &self.com_sigma,
                &mut self.com_grad,
            );
        }
        let nb = model.bodies.len();
        for (j, joint) in model.joints.iter().enumerate() {
            // The inertial torque M qdd the model predicts is off by its mass error too.
            let inertial = torques[j] - self.dynamics.bias()[j] - joint.damping * qd[j];
            let terms = [
                u.mass.max(u.inertia) * inertial,
                u.mass * self.dynamics.bias()[j],
                self.com_torque[j],
                u.damping * joint.damping * qd[j],
                u.friction * joint.friction,
            ];
            let com_var: f64 = if per_joint {
                self.com_grad[j * nb..(j + 1) * nb]
                    .iter()
                    .map(|[g, h]| g.norm_squared() + h.norm_squared())
                    .sum()
            } else {
                0.0
            };
            self.torque_error[j] = terms.iter().map(|t| t * t).sum::<f64>() + com_var;
            inertial_torque[j] = terms[0] * terms[0] + com_var;
            if per_joint {
                self.regressor[j] = terms[0];
            }
            // The friction the model applied over the tick (the ramp at the tick's end velocity,
            // saturated, as the implicit step takes it): where the model's friction moves (a
            // joint it sees reverse, stick or slip) the truth need not, so the error moves by
            // all of it, not by its parameter error.
            let end = qd[j] + self.implicit_step * self.acceleration[j];
            let ramp = crate::arm::dynamics::FRICTION_RAMP;
            let signed = [
                terms[1],
                terms[3],
                joint.friction * (end / ramp).clamp(-1.0, 1.0),
            ];
            self.torque_step[j] = if self.terms_set {
                signed
                    .iter()
                    .zip(&self.terms[j])
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
            } else {
                0.0
            };
            self.terms[j] = signed;
            // Within the friction ramp the joint sticks or slips: its friction is anywhere in
            // [-F, F] (variance F^2 / 3), whatever the model's ramp says, and changes as it does.
            let band = crate::arm::dynamics::FRICTION_RAMP + 3.0 * self.velocity_spread[j];
            self.stuck[j] = qd[j].abs() < band;
            self.stiction[j] = if self.stuck[j] {
                joint.friction * joint.friction / 3.0
            } else {
                terms[4] * terms[4]
            };
        }
        let n = self.noise.len();
        let mut var = std::mem::take(&mut self.acceleration_var);
        let mut inertial_var = std::mem::take(&mut self.inertial_var);
        let mut rest_step = std::mem::take(&mut self.step_var);
        let mut stiction_var = std::mem::take(&mut self.stiction_var);
        for v in [
            &mut var,
            &mut inertial_var,
            &mut rest_step,
            &mut stiction_var,
        ] {
            v.iter_mut().for_each(|v| *v = 0.0);
        }
        // A stuck joint's friction torque is not a damper that swallows a torque error: where
        // the implicit step took the friction ramp's slope into its matrix, the stiction band
        // goes through (M + h D)^-1 instead, the joint's response once it slips.
        let ramped = self.implicit_step > 0.0
            && (0..n).any(|j| self.stuck[j] && model.joints[j].friction > 0.0);
        let slip_factored = ramped && self.factor_slip(&model);
        for j in 0..n {
            self.column.fill(0.0);
            self.column[j] = 1.0;
            self.dynamics.solve_factored(&mut self.column);
            if per_joint {
                self.columns[j * n..(j + 1) * n].copy_from_slice(&self.column);
            }
            for (k, m) in self.column.iter().enumerate() {
                let m2 = m * m;
                var[k] += m2 * self.torque_error[j];
                inertial_var[k] += m2 * inertial_torque[j];
                rest_step[k] += m2 * self.torque_step[j];
                if !(slip_factored && self.stuck[j]) {
                    stiction_var[k] += m2 * self.stiction[j];
                }
            }
            if slip_factored && self.stuck[j] {
                self.column.fill(0.0);
                self.column[j] = 1.0;
                crate::arm::dynamics::solve_cholesky(&self.slip_factor, &mut self.column);
                for (k, m) in self.column.iter().enumerate() {
                    stiction_var[k] += m * m * self.stiction[j];
                }
            }
        }
        self.inertial_torque = inertial_torque;
        // The inertial part's covariance between the last state and this one, joint by joint:
        // Cov(e_i, e'_i) = sum_j M^-1_ij M'^-1_ij Cov(tau_j, tau'_j), the torque errors'
        // covariance from their regressors (the joint's own inertial torque, the centres of
        // mass' gradients).
        let mut covariance = std::mem::take(&mut self.torque_step_cov);
        if per_joint {
            covariance.iter_mut().for_each(|v| *v = 0.0);
            for j in 0..n {
                let mut cov = self.regressor[j] * self.last_regressor[j];
                for (now, last) in self.com_grad[j * nb..(j + 1) * nb]
                    .iter()
                    .zip(&self.last_com_grad[j * nb..(j + 1) * nb])
                {
                    cov += now[0].dot(&last[0]) + now[1].dot(&last[1]);
                }
                for (i, c) in covariance.iter_mut().enumerate() {
                    *c += self.columns[j * n + i] * self.last_columns[j * n + i] * cov;
                }
            }
        } else {
            // `shared-cosine`: C = cos(qdd_last, qdd) sqrt(A A') for every joint (an inertial
            // part W_i . qdd with W_i isotropic).
            let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
            for (a, b) in self.last_acceleration.iter().zip(&self.acceleration) {
                aa += a * a;
                ab += a * b;
                bb += b * b;
            }
            let cos = if aa > 0.0 && bb > 0.0 {
                (ab / (aa * bb).sqrt()).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            for (i, c) in covariance.iter_mut().enumerate() {
                *c = cos * (self.last_inertial_var[i] * inertial_var[i]).sqrt();
            }
        }
        for i in 0..n {
            let (a_new, total) = (inertial_var[i], var[i]);
            let b_new = total - a_new;
            let (carry, step) = if self.terms_set {
                carried_error(
                    CarriedError {
                        inertial: self.last_inertial_var[i],
                        rest: self.last_rest_var[i],
                        inertial_now: a_new,
                        covariance: covariance[i],
                        rest_step: rest_step[i],
                    },
                    self.model_error[i],
                )
            } else {
                (1.0, total)
            };
            self.carry[i] = carry;
            self.step[i] = step.sqrt();
            self.last_inertial_var[i] = a_new;
            self.last_rest_var[i] = b_new.max(0.0);
        }
        self.last_acceleration.copy_from_slice(&self.acceleration);
        std::mem::swap(&mut self.last_com_grad, &mut self.com_grad);
        std::mem::swap(&mut self.last_regressor, &mut self.regressor);
        std::mem::swap(&mut self.last_columns, &mut self.columns);
        self.torque_step_cov = covariance;
        self.terms_set = true;
        for (w, v) in self.white.iter_mut().zip(&stiction_var) {
            *w = (*w * *w + v).sqrt();
        }
        for (s, v) in self.noise.iter_mut().zip(&var) {
            *s = s.max(v.sqrt());
        }
        self.acceleration_var = var;
        self.inertial_var = inertial_var;
        self.step_var = rest_step;
        self.stiction_var = stiction_var;
    }

    /// The arm model it predicts with.
    pub fn model(&self) -> &Arc<ArmModel> {
        self.dynamics.model()
    }
}

/// One joint's model-error budget at the last evaluation and now (variances in (rad/s^2)^2).
#[derive(Clone, Copy, Debug)]
struct CarriedError {
    /// A: the inertial part's variance at the last evaluation.
    inertial: f64,
    /// B: the rest's (mass bias, centre of mass, damping, friction).
    rest: f64,
    /// A': the inertial part's variance now.
    inertial_now: f64,
    /// C: the inertial part's covariance between then and now.
    covariance: f64,
    /// D: the variance of the rest's change (its regressors' moves).
    rest_step: f64,
}

/// The model error's carry k and step variance over one tick, given its last value `e`: e =
/// i + b (the inertial part i with Var i = A, Var b = B), e' = i' + b + d (Var i' = A', Var d =
/// D), Cov(i, i') = C (clamped to +-sqrt(A A')); the Gaussian conditional E[e' | e] = k e,
/// k = (C + B) / (A + B), Var[e' | e] = A' + B + D - (C + B)^2 / (A + B), scaled by kappa =
/// max(1, e^2 / (A + B)) (docs/method.md, "Model error as a state").
fn carried_error(b: CarriedError, e: f64) -> (f64, f64) {
    let prior = b.inertial + b.rest;
    if prior.is_nan() || prior <= 0.0 {
        return (1.0, b.inertial_now + b.rest_step);
    }
    let bound = (b.inertial * b.inertial_now).sqrt();
    let c = b.covariance.clamp(-bound, bound);
    let kappa = (e * e / prior).max(1.0);
    let told = (c + b.rest) * (c + b.rest) / prior;
    let var = b.inertial_now + b.rest + b.rest_step - told;
    ((c + b.rest) / prior, kappa * var.max(0.0))
}

impl ArmTransition {
    /// Factors M + h D (the mass matrix of the last evaluation, the joints' viscous damping)
    /// into `slip_factor` in place, without allocating; false if it is not positive definite.
    fn factor_slip(&mut self, model: &ArmModel) -> bool {
        let m = self.dynamics.mass_matrix();
        let l = &mut self.slip_factor;
        let n = m.nrows();
        for j in 0..n {
            let mut d = m[(j, j)] + self.implicit_step * model.joints[j].damping;
            for k in 0..j {
                d -= l[(j, k)] * l[(j, k)];
            }
            if d.is_nan() || d <= 0.0 {
                return false;
            }
            let d = d.sqrt();
            l[(j, j)] = d;
            for i in j + 1..n {
                let mut v = m[(i, j)];
                for k in 0..j {
                    v -= l[(i, k)] * l[(j, k)];
                }
                l[(i, j)] = v / d;
            }
        }
        true
    }

    /// Predicts with the step `step` (with [`crate::arm::PredictionStep::Implicit`], the tick
    /// `dt`; explicit otherwise).
    pub fn with_step(mut self, step: crate::arm::PredictionStep, dt: f64) -> Self {
        self.implicit_step = match step {
            crate::arm::PredictionStep::Explicit => 0.0,
            crate::arm::PredictionStep::Implicit => dt,
        };
        self
    }
}

impl TransitionModel for ArmTransition {
    fn set_velocity_spread(&mut self, spread: &[f64]) {
        self.velocity_spread.copy_from_slice(spread);
    }

    fn set_model_error(&mut self, error: &[f64]) {
        self.model_error.copy_from_slice(error);
    }

    fn evaluate(&mut self, x: &[f64], torques: &[f64]) -> Transition<'_> {
        let n = self.noise.len();
        let (q, qd) = (&x[..n], &x[n..]);
        let solved = if self.implicit_step > 0.0 {
            self.dynamics.forward_dynamics_implicit(
                q,
                qd,
                torques,
                self.implicit_step,
                &mut self.acceleration,
            )
        } else {
            self.dynamics
                .forward_dynamics(q, qd, torques, &mut self.acceleration)
        };
        if !solved {
            return self.fallback.evaluate(x, torques);
        }
        for (s, a) in self.noise.iter_mut().zip(&self.acceleration) {
            *s = self.floor.max(self.relative * a.abs());
        }
        if self.uncertainty.is_zero() {
            return Transition {
                acceleration: Some(&self.acceleration),
                noise: &self.noise,
                correlated: None,
            };
        }
        self.white.copy_from_slice(&self.noise);
        self.parameter_noise(&x[n..], torques);
        Transition {
            acceleration: Some(&self.acceleration),
            noise: &self.noise,
            correlated: Some(CorrelatedError {
                white: &self.white,
                step: &self.step,
                carry: &self.carry,
            }),
        }
    }
}

/// What each channel reads at a state: encoders and tachometers the joint positions and
/// velocities themselves, the camera a smooth function g(q) with a Jacobian.
pub trait ObservationModel: Send + Sync {
    /// The channels.
    fn layout(&self) -> &ChannelLayout;

    /// The camera's outputs g(q) and their Jacobian dg/dq (row-major, outputs x joints) at q.
    fn camera(&self, q: &[f64], g: &mut [f64], jac: &mut [f64]);

    /// The variance of the camera model's own error in dg_r/dq_joint at q (every output the
    /// same): how far its slope may be off. 0 for a model taken as exact. `scratch` is working
    /// space the caller keeps (reserve [`Self::slope_scratch_len`] entries once: no allocation
    /// per call).
    fn slope_variance(&self, q: &[f64], joint: usize, scratch: &mut Vec<f64>) -> f64 {
        let _ = (q, joint, scratch);
        0.0
    }

    /// The entries [`Self::slope_variance`]'s scratch holds (0 for a model taken as exact).
    fn slope_scratch_len(&self) -> usize {
        0
    }

    /// Builds what [`Self::slope_variance`] needs once (called when a filter that will ask is
    /// made, so that no tick allocates it).
    fn prepare_slope_variance(&self) {}
}

/// The channel layout with the GP camera model (docs/method.md, "The camera model").
#[derive(Clone, Debug)]
pub struct GpCamera {
    layout: ChannelLayout,
    gp: Arc<GpModel>,
}

impl GpCamera {
    /// # Panics
    /// If the GP does not take one input per joint and give one output per camera output
    /// (validate before).
    pub fn new(layout: ChannelLayout, gp: Arc<GpModel>) -> Self {
        assert_eq!(
            gp.n_inputs,
            layout.n_joints(),
            "the GP takes one input per joint"
        );
        assert_eq!(
            gp.n_outputs,
            layout.camera_outputs(),
            "the GP gives one output per camera output"
        );
        Self { layout, gp }
    }

    /// The layout and GP as an observation model to share.
    pub fn shared(layout: ChannelLayout, gp: Arc<GpModel>) -> Arc<dyn ObservationModel> {
        Arc::new(Self::new(layout, gp))
    }
}

impl ObservationModel for GpCamera {
    fn layout(&self) -> &ChannelLayout {
        &self.layout
    }

    fn camera(&self, q: &[f64], g: &mut [f64], jac: &mut [f64]) {
        self.gp.predict(q, g, jac);
    }

    fn slope_variance(&self, q: &[f64], joint: usize, scratch: &mut Vec<f64>) -> f64 {
        self.gp
            .slope_variance(self.gp.slope_factor(), q, joint, scratch)
    }

    fn slope_scratch_len(&self) -> usize {
        self.gp.n_points()
    }

    fn prepare_slope_variance(&self) {
        self.gp.slope_factor();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The arm transition's acceleration solves the equations of motion M qdd + C qd + G + D qd
    /// = u, its noise is max(floor, relative |qdd|), and constant velocity has no acceleration
    /// and its own noise (against finite differences of simulated motion: tests/estimator_models.rs).
    #[test]
    fn the_arm_transition_is_the_models_forward_dynamics() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
        let model = Arc::new(crate::arm::load_urdf(&path).unwrap());
        let mut t = ArmTransition::new(model.clone(), [0.0, 0.0, -9.81], 2.0, 0.1, 200.0);
        let x = [0.3, -0.7, 0.5, -1.0];
        let u = [40.0, -3.0];
        let tr = t.evaluate(&x, &u);
        let acc = tr.acceleration.expect("a regular mass matrix").to_vec();
        let noise = tr.noise.to_vec();
        // M qdd + C qd + G + D qd = u, by the independent closed form of the two-link arm.
        let mut d = Dynamics::new(model.clone(), [0.0, 0.0, -9.81]);
        let (m, _) = d.mass_matrix_and_gravity(&x[..2]);
        d.set_configuration(&x[..2]);
        d.compute(&x[2..]);
        let bias = d.bias().clone();
        for i in 0..2 {
            let lhs = m[(i, 0)] * acc[0]
                + m[(i, 1)] * acc[1]
                + bias[i]
                + model.joints[i].damping * x[2 + i];
            assert!((lhs - u[i]).abs() < 1e-9, "joint {i}: {lhs} vs {}", u[i]);
            assert_eq!(noise[i], f64::max(2.0, 0.1 * acc[i].abs()));
        }
        // The implicit step: (M + dt D) qdd + C qd + G + D qd = u (the paper arm has no
        // friction).
        let dt = 1e-3;
        let mut t = ArmTransition::new(model.clone(), [0.0, 0.0, -9.81], 2.0, 0.1, 200.0)
            .with_step(crate::arm::PredictionStep::Implicit, dt);
        let implicit = t.evaluate(&x, &u).acceleration.unwrap().to_vec();
        for i in 0..2 {
            let lhs = m[(i, 0)] * implicit[0]
                + m[(i, 1)] * implicit[1]
                + dt * model.joints[i].damping * implicit[i]
                + bias[i]
                + model.joints[i].damping * x[2 + i];
            assert!((lhs - u[i]).abs() < 1e-9, "joint {i}: {lhs} vs {}", u[i]);
        }
        assert_ne!(implicit, acc);
        let mut cv = ConstantVelocity::new(2, 200.0);
        let tr = cv.evaluate(&x, &u);
        assert!(tr.acceleration.is_none());
        assert_eq!(tr.noise, &[200.0, 200.0]);
    }

    /// The spatial 3-DOF arm (joint 3 given Coulomb friction `friction`), the default model
    /// error's sizes, gravity and its transition with no floor or relative term.
    fn uncertain_spatial_arm(
        friction: f64,
    ) -> (Arc<ArmModel>, ModelUncertainty, [f64; 3], ArmTransition) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/spatial_3dof.urdf");
        let mut arm = crate::arm::load_urdf(&path).unwrap();
        arm.joints[2].friction = friction;
        let model = Arc::new(arm);
        let u = ModelUncertainty {
            mass: 0.15,
            inertia: 0.3,
            com: 0.08,
            damping: 0.5,
            friction: 0.3,
            inertial_budget: InertialBudget::PerJoint,
        };
        let g = [0.0, 0.0, -9.81];
        let t = ArmTransition::new(model.clone(), g, 0.0, 0.0, 200.0).with_uncertainty(u);
        (model, u, g, t)
    }

    /// Per joint, the centre-of-mass error's regressors at `d`'s configuration under `qdd`
    /// (sigma = com x the body's length scale), flattened (joint j's at j * bodies).
    fn com_regressors(
        d: &Dynamics,
        model: &ArmModel,
        u: ModelUncertainty,
        qdd: &[f64],
    ) -> Vec<[nalgebra::Vector3<f64>; 2]> {
        let nb = model.bodies.len();
        let sigma = u.centre_of_mass_sigma(model);
        let mut grad = vec![[nalgebra::Vector3::zeros(); 2]; model.joints.len() * nb];
        d.centre_of_mass_regressors(qdd, &sigma, &mut grad);
        grad
    }

    /// The variance a joint's regressors give (sum of squared norms).
    fn com_var(grad: &[[nalgebra::Vector3<f64>; 2]], j: usize, nb: usize) -> f64 {
        grad[j * nb..(j + 1) * nb]
            .iter()
            .map(|[g, h]| g.norm_squared() + h.norm_squared())
            .sum()
    }

    /// The process noise of an uncertain model against a direct evaluation: the torque errors
    /// of each assumed parameter error carried through M^-1 from nalgebra's inverse.
    #[test]
    fn the_parameter_noise_is_the_torque_error_carried_through_the_inverse_mass_matrix() {
        let (model, u, g, mut t) = uncertain_spatial_arm(0.0);
        let x = [0.3, -0.7, 0.4, 0.5, -1.0, 0.8];
        let tau = [4.0, -3.0, 1.0];
        let evaluated = t.evaluate(&x, &tau);
        let noise = evaluated.noise.to_vec();
        let qdd = evaluated.acceleration.unwrap().to_vec();
        let mut d = Dynamics::new(model.clone(), g);
        d.set_configuration(&x[..3]);
        d.compute(&x[3..]);
        let minv = d.mass_matrix().clone().try_inverse().unwrap();
        let com = t.com_torque.clone();
        let nb = model.bodies.len();
        let grad = com_regressors(&d, &model, u, &qdd);
        for i in 0..3 {
            let mut var = 0.0;
            for (j, joint) in model.joints.iter().enumerate() {
                let inertial = tau[j] - d.bias()[j] - joint.damping * x[3 + j];
                assert!(com_var(&grad, j, nb) > 0.0);
                let s2 = (u.mass.max(u.inertia) * inertial).powi(2)
                    + com_var(&grad, j, nb)
                    + (u.mass * d.bias()[j]).powi(2)
                    + com[j].powi(2)
                    + (u.damping * joint.damping * x[3 + j]).powi(2)
                    + (u.friction * joint.friction).powi(2);
                var += minv[(i, j)].powi(2) * s2;
            }
            assert!(
                (noise[i] - var.sqrt()).abs() < 1e-9 * var.sqrt(),
                "joint {i}: {} against {}",
                noise[i],
                var.sqrt()
            );
        }
        // The com term: a body's moment reaches every joint on its path to the root.
        assert!(
            com[0] >= com[1] && com[1] >= com[2] && com[2] > 0.0,
            "{com:?}"
        );
    }

    /// The model error's step (for a filter that carries it as a state): at the first
    /// evaluation the whole parameter error; then, at the same state with joint 1's torque raised
    /// by d, only the inertial term moves, by max(mass, inertia) d through M^-1's column 1. The
    /// white part is the floor and, for a joint whose velocity may be 0 (within the friction
    /// ramp plus 3 of its spreads), its stiction band F^2 / 3 through M^-1 (outside, the
    /// parameter error of F).
    /// With the implicit step, a joint within the friction ramp is a stiff damper in the
    /// step's matrix (M + h (D + F / ramp)); the stiction band goes through (M + h D)^-1, the
    /// joint's response once it slips, against the inverse computed here.
    #[test]
    fn a_stuck_joint_slips_through_the_undamped_matrix() {
        let (model, _, g, t) = uncertain_spatial_arm(0.5);
        let h = 1e-3;
        let mut t = t.with_step(crate::arm::PredictionStep::Implicit, h);
        // Joint 2 at rest (within the ramp), the others moving.
        let x = [0.3, -0.7, 0.4, 0.5, -1.0, 0.0];
        let tau = [4.0, -3.0, 1.0];
        let white = t.evaluate(&x, &tau).correlated.unwrap().white.to_vec();
        let mut d = Dynamics::new(model.clone(), g);
        d.set_configuration(&x[..3]);
        d.compute(&x[3..]);
        let mut shifted = d.mass_matrix().clone();
        for (j, joint) in model.joints.iter().enumerate() {
            shifted[(j, j)] += h * joint.damping;
        }
        let shifted_copy = shifted.clone();
        let inv = shifted.try_inverse().unwrap();
        // The moving joints' friction is 0 in this arm: only joint 2's band.
        assert_eq!(
            (model.joints[0].friction, model.joints[1].friction),
            (0.0, 0.0)
        );
        for (i, w) in white.iter().enumerate() {
            let want = (inv[(i, 2)] * 0.5 / 3f64.sqrt()).abs();
            assert!(
                (w - want).abs() < 1e-9 * want,
                "joint {i}: {w} against {want}"
            );
        }
        // Through the step's own matrix (the ramp's slope F / ramp = 50 N m s/rad added) it
        // would be smaller (by h F / ramp against the elbow's inertia here; on a light joint,
        // by orders of magnitude).
        let mut ramped = shifted_copy;
        ramped[(2, 2)] += h * 0.5 / crate::arm::dynamics::FRICTION_RAMP;
        let ramped = ramped.try_inverse().unwrap();
        assert!(white[2] > 1.2 * (ramped[(2, 2)] * 0.5 / 3f64.sqrt()).abs());
    }

    /// The carry and step are the Gaussian conditional of e' given e: a Monte Carlo of the
    /// model they assume (an inertial part W . qdd with W isotropic in 3 joints, b, its step d)
    /// regressed e' on e.
    #[test]
    fn the_carried_model_error_is_the_conditional_of_its_model() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let z = Normal::new(0.0, 1.0).unwrap();
        let (qdd, qdd_now) = ([300.0, -120.0, 50.0], [-200.0, 90.0, 400.0]);
        let (s, b_sd, d_sd) = (0.4, 30.0, 12.0);
        let norm = |v: &[f64; 3]| v.iter().map(|x| x * x).sum::<f64>();
        let dot: f64 = qdd.iter().zip(&qdd_now).map(|(a, b)| a * b).sum();
        let budget = CarriedError {
            inertial: s * s * norm(&qdd),
            rest: b_sd * b_sd,
            inertial_now: s * s * norm(&qdd_now),
            covariance: s * s * dot,
            rest_step: d_sd * d_sd,
        };
        let (k, var) = carried_error(budget, 0.0);
        let samples = 400_000;
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for _ in 0..samples {
            let w: Vec<f64> = (0..3).map(|_| s * z.sample(&mut rng)).collect();
            let b = b_sd * z.sample(&mut rng);
            let e: f64 = w.iter().zip(&qdd).map(|(w, a)| w * a).sum::<f64>() + b;
            let e_now: f64 = w.iter().zip(&qdd_now).map(|(w, a)| w * a).sum::<f64>()
                + b
                + d_sd * z.sample(&mut rng);
            sxx += e * e;
            sxy += e * e_now;
            syy += e_now * e_now;
        }
        let slope = sxy / sxx;
        let residual = (syy - sxy * sxy / sxx) / samples as f64;
        assert!((slope - k).abs() < 0.01, "carry {k} against {slope}");
        assert!(
            (residual / var - 1.0).abs() < 0.01,
            "variance {var} against {residual}"
        );
        // Unchanged regressors: carried whole, no step.
        let still = CarriedError {
            inertial_now: budget.inertial,
            covariance: budget.inertial,
            rest_step: 0.0,
            ..budget
        };
        let (k, var) = carried_error(still, 0.0);
        assert!((k - 1.0).abs() < 1e-12 && var.abs() < 1e-9 * budget.inertial);
        // A learned error twice the budget's standard deviation: the step's variance times 4.
        let e = 2.0 * (budget.inertial + budget.rest).sqrt();
        let (_, scaled) = carried_error(budget, e);
        let (_, plain) = carried_error(budget, 0.0);
        assert!((scaled / plain - 4.0).abs() < 1e-9);
    }

    #[test]
    fn the_model_error_steps_as_its_regressors_move() {
        let (model, u, g, mut t) = uncertain_spatial_arm(0.5);
        let x = [0.3, -0.7, 0.4, 0.5, -1.0, 0.8];
        let tau = [4.0, -3.0, 1.0];
        let first = t.evaluate(&x, &tau);
        let c = first.correlated.unwrap();
        assert_eq!(c.step, first.noise);
        let mut d = Dynamics::new(model.clone(), g);
        d.set_configuration(&x[..3]);
        d.compute(&x[3..]);
        let minv = d.mass_matrix().clone().try_inverse().unwrap();
        // Joint 2 moves at 0.8 rad/s: outside the band, its friction's parameter error.
        for (i, w) in c.white.iter().enumerate() {
            let want = (minv[(i, 2)] * u.friction * 0.5).abs();
            assert!(
                (w - want).abs() < 1e-9 * want,
                "joint {i}: {w} against {want}"
            );
        }
        // Joint 1's torque raised by d at the same state: only the inertial part moves. By
        // hand: A and A' the inertial torques u (tau - bias - D qd) and the centre-of-mass
        // regressors' variances through M^-1, B the rest (mass bias, centre of mass' gravity
        // torque, damping, friction), C the inertial part's covariance joint by joint: sum_j
        // M^-1_ij^2 (u^2 r_j r'_j + the regressors' dot products), r_j the inertial torques.
        let com_torque = t.com_torque.clone();
        let nb = model.bodies.len();
        let inertial_torque = |tau: &[f64; 3]| -> Vec<f64> {
            (0..3)
                .map(|j| {
                    let joint = &model.joints[j];
                    u.mass.max(u.inertia) * (tau[j] - d.bias()[j] - joint.damping * x[3 + j])
                })
                .collect()
        };
        let budget = |tau: &[f64; 3], qdd: &[f64]| -> (Vec<f64>, Vec<f64>) {
            let (mut inertial, mut rest) = (vec![0.0; 3], vec![0.0; 3]);
            let r = inertial_torque(tau);
            let grad = com_regressors(&d, &model, u, qdd);
            for j in 0..3 {
                let joint = &model.joints[j];
                let bias = d.bias()[j];
                let others = [
                    u.mass * bias,
                    com_torque[j],
                    u.damping * joint.damping * x[3 + j],
                    u.friction * joint.friction,
                ];
                for i in 0..3 {
                    let m2 = minv[(i, j)] * minv[(i, j)];
                    inertial[i] += m2 * (r[j] * r[j] + com_var(&grad, j, nb));
                    rest[i] += m2 * others.iter().map(|v| v * v).sum::<f64>();
                }
            }
            (inertial, rest)
        };
        let before = t.evaluate(&x, &tau).acceleration.unwrap().to_vec();
        let d_tau = 2.5;
        let raised = [tau[0], tau[1] + d_tau, tau[2]];
        let moved = t.evaluate(&x, &raised);
        let after = moved.acceleration.unwrap().to_vec();
        let c = moved.correlated.unwrap();
        let (carried, stepped) = (c.carry.to_vec(), c.step.to_vec());
        let (a, b) = budget(&tau, &before);
        let (a_now, _) = budget(&raised, &after);
        let (r, r_now) = (inertial_torque(&tau), inertial_torque(&raised));
        let (grad, grad_now) = (
            com_regressors(&d, &model, u, &before),
            com_regressors(&d, &model, u, &after),
        );
        for i in 0..3 {
            let cov: f64 = (0..3)
                .map(|j| {
                    let dots: f64 = (0..nb)
                        .map(|b| {
                            let (p, q) = (grad[j * nb + b], grad_now[j * nb + b]);
                            p[0].dot(&q[0]) + p[1].dot(&q[1])
                        })
                        .sum();
                    minv[(i, j)] * minv[(i, j)] * (r[j] * r_now[j] + dots)
                })
                .sum();
            let carry = (cov + b[i]) / (a[i] + b[i]);
            let step = (a_now[i] + b[i] - (cov + b[i]).powi(2) / (a[i] + b[i])).sqrt();
            assert!(
                (carried[i] - carry).abs() < 1e-9,
                "joint {i}: carry {} against {carry}",
                carried[i]
            );
            assert!(
                (stepped[i] - step).abs() < 1e-6 * step,
                "joint {i}: step {} against {step}",
                stepped[i]
            );
        }
        // Evaluated again at the same state and torques: carried whole, no step.
        let again = t.evaluate(&x, &raised).correlated.unwrap();
        assert!(again.carry.iter().all(|k| (k - 1.0).abs() < 1e-12));
        assert!(
            again
                .step
                .iter()
                .zip(&stepped)
                .all(|(s, was)| *s < 1e-6 * was)
        );
        // A velocity spread that puts joint 2 within reach of rest: the stiction band.
        t.set_velocity_spread(&[0.0, 0.0, 0.5]);
        let white = t.evaluate(&x, &raised).correlated.unwrap().white.to_vec();
        for (i, w) in white.iter().enumerate() {
            let want = (minv[(i, 2)] * 0.5 / 3f64.sqrt()).abs();
            assert!(
                (w - want).abs() < 1e-9 * want,
                "joint {i}: {w} against {want}"
            );
        }
    }
}
