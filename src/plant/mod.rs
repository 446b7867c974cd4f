//! The plant: a URDF arm simulated in rapier with torque-driven joints.
//!
//! [`urdf`] turns a file into a validated, engine-independent [`ArmModel`]; [`Arm`] builds the
//! rapier multibody from it and steps it. Nothing here knows about sensors or active inference.

mod arm;
mod error;
pub mod urdf;

pub use arm::{Arm, ArmCollider, ArmOptions};
pub(crate) use arm::{to_dvec, to_isometry, to_vector};
pub use error::PlantError;
pub use urdf::{load_urdf, parse_urdf, ArmModel, JointKind};
