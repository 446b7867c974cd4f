//! Forward kinematics of an [`ArmModel`]: every body's world pose at joint positions q, the end
//! effector's position and its positional Jacobian. The one place poses are computed from q: the
//! articulated plant, the estimators' dynamics, the camera model's training set and `aift init`
//! all come here (the rapier plant reports the poses of its own bodies, which agree to rounding).

use std::sync::Arc;

use nalgebra::{DMatrix, Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::{ArmError, ArmModel, JointKind, JointSpec};

/// A joint's motion at coordinate `q`: a rotation about its axis, or a translation along it.
pub fn joint_motion(joint: &JointSpec, q: f64) -> Isometry3<f64> {
    let axis = joint.axis.into_inner();
    match joint.kind {
        JointKind::Prismatic => {
            Isometry3::from_parts(Translation3::from(axis * q), UnitQuaternion::identity())
        }
        _ => Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_scaled_axis(axis * q),
        ),
    }
}

/// World poses of every body at joint positions `q` (one per joint, in joint order) into
/// `poses` (one per body; body 0, the root, stays where it is: the identity at the world origin).
/// Joints come parent before child, so each parent's pose is ready when its child's is computed.
pub fn forward(model: &ArmModel, q: &[f64], poses: &mut [Isometry3<f64>]) {
    for (j, qi) in model.joints.iter().zip(q) {
        poses[j.child_body] = poses[j.parent_body] * j.origin * joint_motion(j, *qi);
    }
}

/// The end effector: a point fixed in a body's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EndEffector {
    /// Index of the body that carries it in [`ArmModel::bodies`].
    pub body: usize,
    /// The point's frame in that body's frame.
    pub local: Isometry3<f64>,
}

impl EndEffector {
    /// The point `offset` (in the link's frame) on link `link` (any link, merged ones included).
    pub fn new(model: &ArmModel, link: &str, offset: [f64; 3]) -> Result<Self, ArmError> {
        let frame = model
            .link(link)
            .ok_or_else(|| model.unknown_link_error(link))?;
        Ok(Self {
            body: frame.body,
            local: frame.pose
                * Isometry3::from_parts(
                    Translation3::new(offset[0], offset[1], offset[2]),
                    UnitQuaternion::identity(),
                ),
        })
    }

    /// Why the arm is not serial up to this end effector (on link `link`), or `None` when every
    /// joint moves it: a point fixed to the world, or a joint on another branch of a tree. aift
    /// controls serial arms: the camera sees only this point and the camera model is a function
    /// of every joint.
    pub fn not_serial(&self, model: &ArmModel, link: &str) -> Option<String> {
        if self.body == 0 {
            return Some(format!(
                "link '{link}' is fixed to the world: no joint moves it (choose a link at the \
                 end of the chain)"
            ));
        }
        let joint = &model.joints[self.first_joint_not_moving(model)?];
        Some(format!(
            "joint '{}' does not move link '{link}': the arm branches at link '{}' and aift \
             controls serial arms (make the other branch's joints fixed, e.g. a gripper's \
             fingers, or choose an end effector that every joint moves)",
            joint.name, model.bodies[joint.parent_body].link
        ))
    }

    /// The first joint that does not move this end effector, if any.
    fn first_joint_not_moving(&self, model: &ArmModel) -> Option<usize> {
        let mut moves = vec![false; model.joints.len()];
        let mut body = self.body;
        while body != 0 {
            let Some(j) = model.joints.iter().position(|j| j.child_body == body) else {
                break;
            };
            moves[j] = true;
            body = model.joints[j].parent_body;
        }
        moves.iter().position(|m| !m)
    }

    /// Its world position given the bodies' world poses.
    pub fn position(&self, poses: &[Isometry3<f64>]) -> Vector3<f64> {
        self.position_in(&poses[self.body])
    }

    /// Its world position given its body's world pose.
    pub fn position_in(&self, body_pose: &Isometry3<f64>) -> Vector3<f64> {
        (body_pose * self.local).translation.vector
    }
}

/// The end effector's positional Jacobian d(ee)/dq (3 x n) from the joints' world axes, given
/// the bodies' world poses.
pub fn ee_jacobian(model: &ArmModel, ee: &EndEffector, poses: &[Isometry3<f64>]) -> DMatrix<f64> {
    point_jacobian(model, ee.body, &ee.position(poses), poses)
}

/// The positional Jacobian (3 x n) of a point fixed to body `body`, at world position `p`:
/// column i is joint i's axis (x the lever arm for a rotary joint) when joint i moves that
/// body, zero when it does not (a joint after it in the chain).
pub fn point_jacobian(
    model: &ArmModel,
    body: usize,
    p: &Vector3<f64>,
    poses: &[Isometry3<f64>],
) -> DMatrix<f64> {
    let mut jac = DMatrix::zeros(3, model.joints.len());
    let mut moves = vec![false; model.joints.len()];
    let mut b = body;
    while let Some(i) = model.joints.iter().position(|j| j.child_body == b) {
        moves[i] = true;
        b = model.joints[i].parent_body;
    }
    for (i, joint) in model.joints.iter().enumerate() {
        if !moves[i] {
            continue;
        }
        let pose = &poses[joint.child_body];
        let axis = pose.rotation * joint.axis.into_inner();
        let column = match joint.kind {
            JointKind::Prismatic => axis,
            _ => axis.cross(&(p - pose.translation.vector)),
        };
        jac.set_column(i, &column);
    }
    jac
}

/// World position of a link's frame origin plus `offset` (in that link's frame).
pub fn link_point(
    model: &ArmModel,
    poses: &[Isometry3<f64>],
    link: &str,
    offset: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let frame = model.link(link)?;
    Some(
        (poses[frame.body] * frame.pose)
            .transform_point(&Point3::from(*offset))
            .coords,
    )
}

/// Where the arm's bodies are: a plant (the simulated truth) or the model's kinematics at some q.
/// The camera looks through it.
pub trait ArmPose {
    /// The model the poses are of.
    fn model(&self) -> &ArmModel;

    /// World pose of a body (index into [`ArmModel::bodies`]).
    fn body_pose(&self, body: usize) -> Isometry3<f64>;

    /// A body's world pose in parry's type, for collision queries.
    fn collision_pose(&self, body: usize) -> parry3d_f64::math::Pose {
        super::to_parry_pose(&self.body_pose(body))
    }

    /// World position of an end effector.
    fn ee_position(&self, ee: &EndEffector) -> Vector3<f64> {
        ee.position_in(&self.body_pose(ee.body))
    }
}

/// Forward kinematics with its own pose storage: set q, read poses.
#[derive(Clone, Debug)]
pub struct Kinematics {
    model: Arc<ArmModel>,
    poses: Vec<Isometry3<f64>>,
}

impl Kinematics {
    /// The arm at q = 0.
    pub fn new(model: Arc<ArmModel>) -> Self {
        let mut k = Self {
            poses: vec![Isometry3::identity(); model.bodies.len()],
            model,
        };
        let zeros = vec![0.0; k.model.joints.len()];
        k.set(&zeros);
        k
    }

    pub fn shared_model(&self) -> &Arc<ArmModel> {
        &self.model
    }

    /// Moves to joint positions `q`; returns the bodies' world poses.
    pub fn set(&mut self, q: &[f64]) -> &[Isometry3<f64>] {
        forward(&self.model, q, &mut self.poses);
        &self.poses
    }

    /// The bodies' world poses at the last q set.
    pub fn poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }
}

impl ArmPose for Kinematics {
    fn model(&self) -> &ArmModel {
        &self.model
    }

    fn body_pose(&self, body: usize) -> Isometry3<f64> {
        self.poses[body]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_jacobian_matches_finite_differences_of_the_end_effector() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
        let model = Arc::new(crate::arm::load_urdf(&path).unwrap());
        let ee = EndEffector::new(&model, "ee", [0.01, -0.02, 0.03]).unwrap();
        let mut k = Kinematics::new(model.clone());
        let q = [0.3, -0.5, 0.2, -1.9, 0.4, 1.6, -0.7];
        let jac = ee_jacobian(&model, &ee, k.set(&q));
        let h = 1e-6;
        for i in 0..q.len() {
            let (mut plus, mut minus) = (q, q);
            plus[i] += h;
            minus[i] -= h;
            let up = ee.position(k.set(&plus));
            let d = (up - ee.position(k.set(&minus))) / (2.0 * h);
            for r in 0..3 {
                assert!((jac[(r, i)] - d[r]).abs() < 1e-8, "{i} {r}: {jac} {d}");
            }
        }
    }
}
