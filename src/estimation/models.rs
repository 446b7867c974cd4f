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
        }
    }

    /// The arm model it predicts with.
    pub fn model(&self) -> &Arc<ArmModel> {
        self.dynamics.model()
    }
}

impl TransitionModel for ArmTransition {
    fn evaluate(&mut self, x: &[f64], torques: &[f64]) -> Transition<'_> {
        let n = self.noise.len();
        if !self
            .dynamics
            .forward_dynamics(&x[..n], &x[n..], torques, &mut self.acceleration)
        {
            return self.fallback.evaluate(x, torques);
        }
        for (s, a) in self.noise.iter_mut().zip(&self.acceleration) {
            *s = self.floor.max(self.relative * a.abs());
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
        let mut cv = ConstantVelocity::new(2, 200.0);
        let tr = cv.evaluate(&x, &u);
        assert!(tr.acceleration.is_none());
        assert_eq!(tr.noise, &[200.0, 200.0]);
    }
}
