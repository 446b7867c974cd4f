//! The plant: a URDF arm simulated in rapier with torque-driven joints.
//!
//! [`urdf`] turns a file into a validated, engine-independent [`ArmModel`]; [`Arm`] builds the
//! rapier multibody from it and steps it. Nothing here knows about sensors or active inference.

mod arm;
pub mod chain;
mod error;
mod open_loop;
pub mod urdf;

pub(crate) use arm::to_dvec;
pub use arm::{Arm, ArmCollider, ArmOptions, Engine};
pub use chain::{Chain, Integrator};
pub use error::PlantError;
pub use open_loop::{OpenLoopSample, open_loop_header, run_open_loop};
pub use urdf::{
    ArmModel, JointKind, UrdfOptions, load_urdf, load_urdf_with, parse_urdf, parse_urdf_with,
};
