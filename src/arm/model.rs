//! The arm model: bodies (URDF links merged across fixed joints), movable joints in
//! parent-before-child order, every link's frame and the collision shapes. Built once from a URDF
//! ([`super::urdf`]), immutable, shared by the plants, the sensors, the camera model's training,
//! `init` and the estimators' dynamics ([`super::kinematics`], [`super::dynamics`]).

use std::path::PathBuf;

use nalgebra::{Isometry3, Matrix3, Translation3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::math::Pose;
use parry3d_f64::shape::SharedShape;

use super::ArmError;

/// Kind of a movable joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about the axis, with position limits.
    Revolute,
    /// Rotation about the axis without limits.
    Continuous,
    /// Translation along the axis.
    Prismatic,
}

impl JointKind {
    /// The URDF name of the kind.
    pub fn name(self) -> &'static str {
        match self {
            Self::Revolute => "revolute",
            Self::Continuous => "continuous",
            Self::Prismatic => "prismatic",
        }
    }
}

/// A movable joint between two bodies.
#[derive(Clone, Debug)]
pub struct JointSpec {
    pub name: String,
    pub kind: JointKind,
    /// Index of the parent body in [`ArmModel::bodies`].
    pub parent_body: usize,
    /// Index of the child body in [`ArmModel::bodies`].
    pub child_body: usize,
    /// The joint frame at q = 0, in the parent body's frame.
    pub origin: Isometry3<f64>,
    /// Unit axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Position limits (lower, upper), if the joint has any.
    pub limits: Option<(f64, f64)>,
    /// Largest torque (force) the joint can apply, if given (> 0).
    pub effort: Option<f64>,
    /// Velocity limit as written in the file (reported, not enforced).
    pub velocity_limit: Option<f64>,
    /// Viscous friction `<dynamics damping>` (N m s/rad), 0 when absent.
    pub damping: f64,
    /// Coulomb friction `<dynamics friction>` (N m), 0 when absent.
    pub friction: f64,
}

/// A primitive collision shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ShapeSpec {
    Box {
        half_extents: Vector3<f64>,
    },
    /// Axis along the shape frame's z, as in URDF.
    Cylinder {
        radius: f64,
        length: f64,
    },
    Sphere {
        radius: f64,
    },
    /// Axis along the shape frame's z, as in URDF.
    Capsule {
        radius: f64,
        length: f64,
    },
}

/// A collision shape attached to a body.
#[derive(Clone, Debug)]
pub struct ColliderSpec {
    /// The URDF link that declared it.
    pub link: String,
    /// Index of the body in [`ArmModel::bodies`].
    pub body: usize,
    pub shape: ShapeSpec,
    /// Pose of the shape in its body's frame.
    pub pose: Isometry3<f64>,
    /// The same shape for parry's queries (its cylinders and capsules run along y, URDF's along
    /// z: the pose carries the quarter turn).
    pub parry_shape: SharedShape,
    pub parry_pose: Pose,
}

/// A rigid body: one URDF link plus every link merged into it by fixed joints.
#[derive(Clone, Debug)]
pub struct BodySpec {
    /// The URDF link whose frame is the body frame.
    pub link: String,
    pub mass: f64,
    /// Centre of mass in the body frame.
    pub com: Vector3<f64>,
    /// Inertia tensor about the centre of mass, in body-frame axes.
    pub inertia: Matrix3<f64>,
}

/// Where a URDF link sits: on which body, at which pose.
#[derive(Clone, Debug)]
pub struct LinkFrame {
    pub name: String,
    pub body: usize,
    /// The link frame in its body's frame.
    pub pose: Isometry3<f64>,
    /// Whether the link declared an `<inertial>` (false: a massless frame).
    pub has_inertial: bool,
    /// The link's own mass (0 for a massless frame).
    pub mass: f64,
}

/// A validated arm: bodies, movable joints in parent-before-child order, and every link's frame.
#[derive(Clone, Debug)]
pub struct ArmModel {
    pub name: String,
    /// The file the model came from (for messages).
    pub source: PathBuf,
    /// Body 0 is the root, fixed to the world.
    pub bodies: Vec<BodySpec>,
    pub joints: Vec<JointSpec>,
    pub links: Vec<LinkFrame>,
    /// Collision shapes, each on its body.
    pub colliders: Vec<ColliderSpec>,
    /// Things skipped on the way (meshes, ...), for the user to see.
    pub warnings: Vec<String>,
}

impl ArmModel {
    /// The same arm with a point mass `mass` (kg) added to body `body` at `point` (body frame):
    /// a payload. Mass, centre of mass and inertia combine by the parallel-axis theorem.
    ///
    /// # Panics
    /// If `body` is not a body of the model.
    pub fn with_point_mass(&self, body: usize, mass: f64, point: Vector3<f64>) -> ArmModel {
        let mut model = self.clone();
        let b = &mut model.bodies[body];
        let (m, c, i) =
            combine_parts(&[(b.mass, b.com, b.inertia), (mass, point, Matrix3::zeros())]);
        b.mass = m;
        b.com = c;
        b.inertia = i;
        model
    }

    /// Total mass of the moving bodies plus the root.
    pub fn total_mass(&self) -> f64 {
        self.bodies.iter().map(|b| b.mass).sum()
    }

    /// The frame of a link by name.
    pub fn link(&self, name: &str) -> Option<&LinkFrame> {
        self.links.iter().find(|l| l.name == name)
    }

    /// The error for an end-effector link that does not exist.
    pub fn unknown_link_error(&self, name: &str) -> ArmError {
        ArmError::UnknownEndEffector {
            path: self.source.clone(),
            link: name.to_string(),
            available: self
                .links
                .iter()
                .map(|l| l.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        }
    }
}

/// A nalgebra isometry as parry's pose.
pub fn to_parry_pose(iso: &Isometry3<f64>) -> Pose {
    let q = iso.rotation.quaternion();
    let t = iso.translation.vector;
    Pose::from_parts(
        parry3d_f64::math::Vector::new(t.x, t.y, t.z),
        parry3d_f64::math::Rotation::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

impl ColliderSpec {
    /// A collision shape on `body` at `pose` (in the body frame), with its parry shape.
    pub fn new(link: String, body: usize, shape: ShapeSpec, pose: Isometry3<f64>) -> Self {
        // parry's cylinders and capsules run along y; URDF's along z.
        let y_to_z = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
        );
        let (parry_shape, parry_pose) = match shape {
            ShapeSpec::Box { half_extents } => (
                SharedShape::cuboid(half_extents.x, half_extents.y, half_extents.z),
                pose,
            ),
            ShapeSpec::Sphere { radius } => (SharedShape::ball(radius), pose),
            ShapeSpec::Cylinder { radius, length } => {
                (SharedShape::cylinder(length / 2.0, radius), pose * y_to_z)
            }
            ShapeSpec::Capsule { radius, length } => {
                (SharedShape::capsule_y(length / 2.0, radius), pose * y_to_z)
            }
        };
        Self {
            link,
            body,
            shape,
            pose,
            parry_shape,
            parry_pose: to_parry_pose(&parry_pose),
        }
    }
}

/// A body's mass, centre of mass and inertia about it, from its links' parts.
pub fn combine_parts(
    parts: &[(f64, Vector3<f64>, Matrix3<f64>)],
) -> (f64, Vector3<f64>, Matrix3<f64>) {
    let mass: f64 = parts.iter().map(|(m, _, _)| m).sum();
    let (com, inertia) = if mass > 0.0 {
        let com = parts
            .iter()
            .fold(Vector3::zeros(), |acc, (m, c, _)| acc + c * *m)
            / mass;
        // Parallel-axis theorem about the body's centre of mass.
        let inertia = parts.iter().fold(Matrix3::zeros(), |acc, (m, c, i)| {
            let d = c - com;
            acc + i + (Matrix3::identity() * d.dot(&d) - d * d.transpose()) * *m
        });
        (com, inertia)
    } else {
        (Vector3::zeros(), Matrix3::zeros())
    };
    (mass, com, inertia)
}
