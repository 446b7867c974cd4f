//! Plants: the simulated arm, the truth the sensors read and the torques act on.
//!
//! A [`Plant`] sets and reads the joint state, takes joint torques (clamped to the model's effort
//! limits), steps, and reports every body's world pose. Two implementations over the same
//! [`ArmModel`]: [`RapierPlant`] (rapier3d-f64's multibody, the default of `aift run`) and
//! [`ArticulatedPlant`] (aift's own dynamics, [`crate::arm::dynamics`], integrated by hand: the
//! campaigns' fast engine, cross-checked against rapier in `tests/engines.rs`). [`build`] makes
//! the one the settings name; nothing outside this folder knows which it is, and no rapier type
//! leaves it. Nothing here knows about sensors or active inference.

pub mod actuators;
mod articulated;
pub mod disturbances;
mod open_loop;
mod rapier;

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

pub use actuators::{
    ActuatorFault, ActuatorFaultKind, ActuatorFaultSpec, Actuators, JointSelection,
};
pub use articulated::{ArticulatedPlant, ArticulatedSettings, Integrator, MAX_SUBSTEPS};
pub use disturbances::{Disturbance, DisturbanceKind, DisturbanceSpec, Disturbances};
pub use open_loop::{OpenLoopSample, open_loop_header, run_open_loop, run_open_loop_with};
pub use rapier::{
    MAX_OBSTACLES, MAX_SOLVER_ITERATIONS, Obstacle, ObstacleShape, RapierPlant, RapierSettings,
};

use crate::arm::ArmModel;
pub use crate::arm::kinematics::ArmPose;

/// Projected Gauss-Seidel sweeps over a tick's coupled joint constraints (dry friction, limits,
/// brakes): the articulated plant's impulse solve and the rapier plant's default
/// `pgs_iterations` (docs/method.md, "Plant").
pub const GAUSS_SEIDEL_SWEEPS: usize = 8;

/// A simulated arm. Its [`ArmPose`] is the truth: the model it was built from and where its
/// bodies are.
pub trait Plant: ArmPose + Send {
    /// Number of movable joints.
    fn n_joints(&self) -> usize {
        self.model().joints.len()
    }

    /// Sets the joint positions and velocities (one per joint).
    ///
    /// # Panics
    /// If a slice has the wrong length.
    fn set_state(&mut self, q: &[f64], qd: &[f64]);

    /// Writes joint positions and velocities into the slices, without allocating.
    fn read_state(&self, q: &mut [f64], qd: &mut [f64]);

    /// Joint positions and velocities.
    fn state(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n_joints();
        let (mut q, mut qd) = (vec![0.0; n], vec![0.0; n]);
        self.read_state(&mut q, &mut qd);
        (q, qd)
    }

    /// Sets the joint torques (forces for prismatic joints) applied from the next step on,
    /// clamped to each joint's URDF effort limit when it has one.
    ///
    /// # Panics
    /// If `tau` does not have one entry per joint.
    fn set_torques(&mut self, tau: &[f64]);

    /// The torques that will be applied (after the effort clamp).
    fn torques(&self) -> &[f64];

    /// Advances the simulation by `dt` seconds with the current torques.
    fn step(&mut self, dt: f64);

    /// Puts a point mass (kg, at a point in the body's frame) on body `body`, replacing the one
    /// set there before; `None` takes it off. A payload picked up or dropped: the plant's
    /// [`ArmPose::model`] is the arm with its payloads.
    ///
    /// # Panics
    /// If `body` is not a body of the arm, or is the root.
    fn set_payload(&mut self, body: usize, payload: Option<(f64, nalgebra::Vector3<f64>)>);

    /// The external forces acting from the next step on, replacing those set before (a push on
    /// a link; empty: none).
    fn set_external_forces(&mut self, forces: &[ExternalForce]);

    /// The normal part of the force (N, world frame) the environment's obstacles exert on the
    /// arm over the last step (friction left out); zero for a plant without contact.
    fn contact_normal_force(&self) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::zeros()
    }

    /// Engages (`true`) a brake on `joint` (0-based) that holds it at its current position,
    /// whatever the torques, until released (`false`); the rest of the arm moves on with the
    /// joint held. A locked-joint actuator fault ([`actuators`]).
    ///
    /// # Panics
    /// If `joint` is not a joint of the arm.
    fn set_brake(&mut self, joint: usize, engaged: bool);

    /// Every body's world pose, into `out` (one per body).
    fn body_poses_into(&self, out: &mut [Isometry3<f64>]) {
        for (b, pose) in out.iter_mut().enumerate() {
            *pose = self.body_pose(b);
        }
    }
}

/// A force on a body: where (a point fixed to the body, in its frame) and how much (N, world
/// frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExternalForce {
    pub body: usize,
    pub point: nalgebra::Vector3<f64>,
    pub force: nalgebra::Vector3<f64>,
}

/// The payload on each body of a plant's arm.
#[derive(Clone, Debug)]
pub(crate) struct Payloads(Vec<Option<(f64, nalgebra::Vector3<f64>)>>);

impl Payloads {
    pub fn new(bodies: usize) -> Self {
        Self(vec![None; bodies])
    }

    pub fn set(&mut self, body: usize, payload: Option<(f64, nalgebra::Vector3<f64>)>) {
        assert!(body > 0 && body < self.0.len(), "a moving body of the arm");
        self.0[body] = payload;
    }

    /// The arm `base` with these payloads.
    pub fn apply(&self, base: &ArmModel) -> ArmModel {
        let mut model = base.clone();
        for (b, p) in self.0.iter().enumerate() {
            if let Some((mass, point)) = p {
                model = model.with_point_mass(b, *mass, *point);
            }
        }
        model
    }
}

/// Which plant steps the arm.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Engine {
    /// rapier3d-f64's multibody (reduced coordinates), `[plant.rapier]`.
    #[default]
    Rapier,
    /// aift's own articulated-body dynamics, `[plant.articulated]`: the same map as rapier with
    /// the Euler integrator, or fourth-order Runge-Kutta.
    Articulated,
}

impl Engine {
    pub fn name(self) -> &'static str {
        match self {
            Self::Rapier => "rapier",
            Self::Articulated => "articulated",
        }
    }
}

/// Settings of the plant (the scenario's `[plant]` section): which engine, and each engine's
/// own settings (the other's are refused unless left at their defaults).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PlantSettings {
    /// `rapier` (default) or `articulated` (aift's own dynamics; docs/method.md, "Plant").
    pub engine: Engine,
    /// Settings of the rapier engine.
    pub rapier: RapierSettings,
    /// Settings of the articulated engine.
    pub articulated: ArticulatedSettings,
}

impl PlantSettings {
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        self.rapier.validate().map_err(|e| e.within("rapier"))?;
        self.articulated
            .validate()
            .map_err(|e| e.within("articulated"))?;
        match self.engine {
            Engine::Rapier if self.articulated != ArticulatedSettings::default() => {
                Err(crate::SettingError::new(
                    "articulated",
                    "applies to engine = \"articulated\" (rapier integrates its own way)",
                ))
            }
            Engine::Articulated if !self.rapier.obstacles.is_empty() => {
                Err(crate::SettingError::new(
                    "rapier.obstacles",
                    "contact needs engine = \"rapier\" (the articulated engine has no contact)",
                ))
            }
            Engine::Articulated if self.rapier != RapierSettings::default() => Err(
                crate::SettingError::new("rapier", "applies to engine = \"rapier\""),
            ),
            _ => Ok(()),
        }
    }

    /// A short description for tables and reports: `articulated (euler, 2 substeps)`.
    pub fn describe(&self) -> String {
        match self.engine {
            Engine::Rapier => {
                let contact = match self.rapier.obstacles.len() {
                    0 => String::new(),
                    k => format!(", contact with {k} obstacle(s)"),
                };
                format!(
                    "rapier ({} solver iterations x {} Gauss-Seidel sweeps{contact})",
                    self.rapier.solver_iterations, self.rapier.pgs_iterations
                )
            }
            Engine::Articulated => format!(
                "articulated ({}, {} substeps)",
                match self.articulated.integrator {
                    Integrator::Euler => "euler",
                    Integrator::Rk4 => "rk4",
                    Integrator::ExplicitEuler => "explicit-euler",
                },
                self.articulated.substeps
            ),
        }
    }
}

/// The plant the settings name, built from `model` under gravity `gravity`, at q = 0.
pub fn build(
    model: Arc<ArmModel>,
    gravity: [f64; 3],
    settings: &PlantSettings,
) -> Result<Box<dyn Plant>, PlantError> {
    Ok(match settings.engine {
        Engine::Rapier => Box::new(RapierPlant::new(model, gravity, &settings.rapier)?),
        Engine::Articulated => Box::new(ArticulatedPlant::new(
            model,
            gravity,
            &settings.articulated,
        )?),
    })
}

/// Errors of building a plant.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlantError {
    #[error("{path}: `{field}`: {message}")]
    BadSetting {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error("{path}: rapier refused joint '{joint}' (it would close a kinematic cycle)")]
    Rejected { path: PathBuf, joint: String },
}

impl PlantError {
    fn setting(model: &ArmModel, section: &str, e: crate::SettingError) -> Self {
        let e = e.within(section);
        Self::BadSetting {
            path: model.source.clone(),
            field: e.field,
            message: e.message,
        }
    }
}

fn check_gravity(model: &ArmModel, gravity: [f64; 3]) -> Result<(), PlantError> {
    if gravity.iter().all(|g| g.is_finite()) {
        Ok(())
    } else {
        Err(PlantError::BadSetting {
            path: model.source.clone(),
            field: "gravity".into(),
            message: "must be finite".into(),
        })
    }
}

/// `tau` clamped to each joint's URDF effort limit (where it has one), into `out`: what
/// [`Plant::set_torques`] applies.
///
/// # Panics
/// If `tau` does not have one entry per joint.
pub fn clamp_to_effort(model: &ArmModel, tau: &[f64], out: &mut [f64]) {
    assert_eq!(tau.len(), model.joints.len(), "tau has the wrong length");
    for ((out, &t), joint) in out.iter_mut().zip(tau).zip(&model.joints) {
        *out = match joint.effort {
            Some(e) => t.clamp(-e, e),
            None => t,
        };
    }
}
