//! The arm, once: one immutable model of the arm ([`ArmModel`], read from a URDF by [`urdf`]),
//! its forward kinematics ([`kinematics`]: body poses, the end effector, its Jacobian) and its
//! rigid-body dynamics ([`dynamics`]: mass matrix, bias torques, forward dynamics), and the
//! errors the estimators' copy of it carries ([`model_error`]). Shared as `Arc<ArmModel>` by the
//! plants, the sensors, the camera model's training, `aift init` and the estimators. Nothing here
//! knows how the arm is simulated.

pub mod dynamics;
mod error;
pub mod generate;
pub mod kinematics;
mod model;
pub mod model_error;
pub mod urdf;

pub use dynamics::Dynamics;
pub use error::ArmError;
pub use generate::{GenerateOptions, generate_arm};
pub use kinematics::{EndEffector, Kinematics};
pub use model::{
    ArmModel, BodySpec, ColliderSpec, JointKind, JointSpec, LinkFrame, ShapeSpec, to_parry_pose,
};
pub use model_error::{ModelConfig, PredictionStep};
pub use urdf::{UrdfOptions, load_urdf, load_urdf_with, parse_urdf, parse_urdf_with};

/// The arm as `aift check-urdf --json` prints it: joints (kind, parent and child links, axis,
/// limits, effort, damping, friction), links (mass, the body they merge into), total mass, the
/// end effector (`ee`, given or the link named `ee`) and the loader's warnings.
pub fn describe_arm(
    model: &ArmModel,
    urdf: &std::path::Path,
    ee: Option<&str>,
) -> serde_json::Value {
    let joints: Vec<_> = model
        .joints
        .iter()
        .map(|j| {
            let axis = j.axis.into_inner();
            serde_json::json!({
                "name": j.name,
                "kind": j.kind.name(),
                "parent": model.bodies[j.parent_body].link,
                "child": model.bodies[j.child_body].link,
                "axis": [axis.x, axis.y, axis.z],
                "limits": j.limits.map(|(lo, hi)| [lo, hi]),
                "effort": j.effort,
                "damping": j.damping,
                "friction": j.friction,
            })
        })
        .collect();
    let links: Vec<_> = model
        .links
        .iter()
        .map(|l| {
            serde_json::json!({
                "name": l.name,
                "mass": if l.has_inertial { Some(l.mass) } else { None },
                "body": model.bodies[l.body].link,
            })
        })
        .collect();
    let ee = ee.or_else(|| model.link("ee").map(|_| "ee"));
    serde_json::json!({
        "format_version": 1,
        "urdf": urdf,
        "name": model.name,
        "joints": joints,
        "links": links,
        "total_mass": model.total_mass(),
        "end_effector": ee,
        "warnings": model.warnings,
    })
}
