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

use crate::arm::model_error::{ModelUncertainty, length_scale};
use crate::arm::{ArmModel, Dynamics};
use crate::gp::GpModel;
use crate::sensors::ChannelLayout;

/// One tick's transition at a state, as a model evaluated it: each joint's acceleration (None:
/// constant velocity) and white-acceleration noise standard deviation (rad/s^2).
#[derive(Clone, Copy, Debug)]
pub struct Transition<'a> {
    pub acceleration: Option<&'a [f64]>,
    pub noise: &'a [f64],
}

/// How the joint state moves over one tick.
pub trait TransitionModel: Send {
    /// The transition at x = [q, qd] under the torques applied over the tick. Evaluated once
    /// and shared by as many filters as predict from it (a bank's hypotheses).
    fn evaluate(&mut self, x: &[f64], torques: &[f64]) -> Transition<'_>;
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
    /// Scratch: each joint's torque error and a column of M^-1.
    torque_error: Vec<f64>,
    column: Vec<f64>,
    /// The step of the implicit prediction (s); 0: explicit.
    implicit_step: f64,
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
        let n = model.joints.len();
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
            torque_error: vec![0.0; n],
            column: vec![0.0; n],
            implicit_step: 0.0,
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
        self.uncertainty = uncertainty;
        self
    }

    /// The per-joint acceleration error of the model's parameter errors at the state last
    /// evaluated, into `noise` as a lower bound.
    fn parameter_noise(&mut self, qd: &[f64], torques: &[f64]) {
        let u = self.uncertainty;
        let model = self.dynamics.model().clone();
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
            self.torque_error[j] = terms.iter().map(|t| t * t).sum::<f64>();
        }
        let n = self.noise.len();
        let mut var = std::mem::take(&mut self.acceleration_var);
        var.iter_mut().for_each(|v| *v = 0.0);
        for j in 0..n {
            if self.torque_error[j] == 0.0 {
                continue;
            }
            self.column.fill(0.0);
            self.column[j] = 1.0;
            self.dynamics.solve_factored(&mut self.column);
            for (v, m) in var.iter_mut().zip(&self.column) {
                *v += m * m * self.torque_error[j];
            }
        }
        for (s, v) in self.noise.iter_mut().zip(&var) {
            *s = s.max(v.sqrt());
        }
        self.acceleration_var = var;
    }

    /// The arm model it predicts with.
    pub fn model(&self) -> &Arc<ArmModel> {
        self.dynamics.model()
    }
}

impl ArmTransition {
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
        if !self.uncertainty.is_zero() {
            self.parameter_noise(&x[n..], torques);
        }
        Transition {
            acceleration: Some(&self.acceleration),
            noise: &self.noise,
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

    /// The process noise of an uncertain model against a direct evaluation: the torque errors
    /// of each assumed parameter error carried through M^-1 from nalgebra's inverse.
    #[test]
    fn the_parameter_noise_is_the_torque_error_carried_through_the_inverse_mass_matrix() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/spatial_3dof.urdf");
        let model = Arc::new(crate::arm::load_urdf(&path).unwrap());
        let u = ModelUncertainty {
            mass: 0.15,
            inertia: 0.3,
            com: 0.08,
            damping: 0.5,
            friction: 0.3,
        };
        let g = [0.0, 0.0, -9.81];
        let mut t = ArmTransition::new(model.clone(), g, 0.0, 0.0, 200.0).with_uncertainty(u);
        let x = [0.3, -0.7, 0.4, 0.5, -1.0, 0.8];
        let tau = [4.0, -3.0, 1.0];
        let noise = t.evaluate(&x, &tau).noise.to_vec();
        let mut d = Dynamics::new(model.clone(), g);
        d.set_configuration(&x[..3]);
        d.compute(&x[3..]);
        let minv = d.mass_matrix().clone().try_inverse().unwrap();
        let com = t.com_torque.clone();
        for i in 0..3 {
            let mut var = 0.0;
            for (j, joint) in model.joints.iter().enumerate() {
                let inertial = tau[j] - d.bias()[j] - joint.damping * x[3 + j];
                let s2 = (u.mass.max(u.inertia) * inertial).powi(2)
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
}
