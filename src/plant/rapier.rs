//! The rapier plant: a rapier3d-f64 multibody (reduced coordinates) built from an [`ArmModel`],
//! driven by joint torques.
//!
//! Facts this relies on (docs/method.md, "Plant"): rapier has no generalized-force API, so a joint
//! torque tau about axis a is `+tau a` on the child body and `-tau a` on the parent, reset every
//! tick; multibody joints get a default damping of 0.1 that must be replaced by the URDF's
//! `<dynamics damping>` (0 when absent); q is read from the joint coordinates and qd from the
//! multibody's generalized velocity; sleeping is disabled on every link. rapier's types stay in
//! this file: the rest of aift sees the [`Plant`] trait.

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::glamx::{DQuat, DVec3};
use rapier3d_f64::math::Pose;
use rapier3d_f64::prelude::{
    ColliderBuilder, GenericJoint, Group, InteractionGroups, InteractionTestMode, JointAxesMask,
    JointAxis, MassProperties, MultibodyIndex, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle,
};
use serde::{Deserialize, Serialize};

use super::{ArmPose, Plant, PlantError, clamp_to_effort};
use crate::arm::{ArmModel, JointKind};

/// Most solver iterations per tick.
pub const MAX_SOLVER_ITERATIONS: usize = 1000;

/// Most obstacles in one scene.
pub const MAX_OBSTACLES: usize = 100;

/// Settings of the rapier plant (`[plant.rapier]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct RapierSettings {
    /// rapier's `num_solver_iterations` (>= 1); they act as substeps (docs/method.md, "Plant"):
    /// on the paper arm the error against the closed-form RK4 oracle after 2 s is of order
    /// 1e-5 rad with the default 2 (tests/plant_dynamics.rs).
    pub solver_iterations: usize,
    /// rapier's `num_internal_pgs_iterations` (>= 1): projected Gauss-Seidel sweeps over the
    /// joint constraints in each solver iteration. The dry-friction and limit rows of one arm are
    /// coupled through its mass matrix; one sweep leaves them unconverged, so a joint held by
    /// friction creeps within the tick while it reports zero velocity (docs/method.md, "Plant").
    pub pgs_iterations: usize,
    /// Obstacles fixed in the world that the arm's collision shapes touch (contact forces on,
    /// in rapier; the arm's links never collide with each other). The camera does not see them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub obstacles: Vec<Obstacle>,
}

impl Default for RapierSettings {
    fn default() -> Self {
        Self {
            solver_iterations: 2,
            pgs_iterations: super::GAUSS_SEIDEL_SWEEPS,
            obstacles: Vec::new(),
        }
    }
}

impl RapierSettings {
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        for (key, value) in [
            ("solver_iterations", self.solver_iterations),
            ("pgs_iterations", self.pgs_iterations),
        ] {
            if !(1..=MAX_SOLVER_ITERATIONS).contains(&value) {
                return Err(crate::SettingError::new(
                    key,
                    format!("must be in 1..={MAX_SOLVER_ITERATIONS}"),
                ));
            }
        }
        if self.obstacles.len() > MAX_OBSTACLES {
            return Err(crate::SettingError::new(
                "obstacles",
                format!("at most {MAX_OBSTACLES}"),
            ));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            o.validate()
                .map_err(|e| e.within(&format!("obstacles[{i}]")))?;
        }
        Ok(())
    }
}

/// The shape of an obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum ObstacleShape {
    /// A box: `size` = [x, y, z] full extents (m).
    Box,
    /// A ball: `size` = [radius] (m).
    Ball,
}

/// An obstacle fixed in the world (a table, a wall, something on the path).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    pub shape: ObstacleShape,
    /// `box`: [x, y, z] full extents; `ball`: [radius] (m, each in (0, 1e3]).
    pub size: Vec<f64>,
    /// Centre (m, world frame).
    pub position: Vec<f64>,
    /// Orientation: roll, pitch, yaw (rad, URDF's convention).
    #[serde(default = "zeros3")]
    pub rpy: Vec<f64>,
    /// Coulomb friction coefficient of its contacts (>= 0).
    #[serde(default = "half")]
    pub friction: f64,
}

fn zeros3() -> Vec<f64> {
    vec![0.0; 3]
}

fn half() -> f64 {
    0.5
}

impl Obstacle {
    fn validate(&self) -> Result<(), crate::SettingError> {
        let sizes = match self.shape {
            ObstacleShape::Box => 3,
            ObstacleShape::Ball => 1,
        };
        if self.size.len() != sizes {
            return Err(crate::SettingError::new(
                "size",
                format!("a {:?} takes {sizes} number(s)", self.shape).to_lowercase(),
            ));
        }
        if !self
            .size
            .iter()
            .all(|s| s.is_finite() && *s > 0.0 && *s <= 1e3)
        {
            return Err(crate::SettingError::new("size", "each in (0, 1e3] m"));
        }
        for (name, v, bound) in [("position", &self.position, 1e3), ("rpy", &self.rpy, 1e3)] {
            if v.len() != 3 {
                return Err(crate::SettingError::new(name, "takes 3 numbers"));
            }
            if !v.iter().all(|x| x.is_finite() && x.abs() <= bound) {
                return Err(crate::SettingError::new(
                    name,
                    format!("each finite and at most {bound} in size"),
                ));
            }
        }
        if !(self.friction.is_finite() && (0.0..=1e3).contains(&self.friction)) {
            return Err(crate::SettingError::new("friction", "must be in [0, 1e3]"));
        }
        Ok(())
    }

    /// Its pose in the world.
    fn pose(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.position[0], self.position[1], self.position[2]),
            UnitQuaternion::from_euler_angles(self.rpy[0], self.rpy[1], self.rpy[2]),
        )
    }
}

/// One movable joint as simulated.
#[derive(Clone, Debug)]
struct SimJoint {
    /// Index of the child's link inside the multibody.
    link: usize,
    parent: RigidBodyHandle,
    child: RigidBodyHandle,
    /// Joint axis in the child body's frame (the child frame is the joint frame).
    axis_child: Vector3<f64>,
    kind: JointKind,
}

fn to_dvec(v: &Vector3<f64>) -> DVec3 {
    DVec3::new(v.x, v.y, v.z)
}

fn to_vector(v: DVec3) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

fn to_pose(iso: &Isometry3<f64>) -> Pose {
    let q = iso.rotation.quaternion();
    Pose::from_parts(
        to_dvec(&iso.translation.vector),
        DQuat::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

fn to_isometry(pose: &Pose) -> Isometry3<f64> {
    let r = pose.rotation;
    Isometry3::from_parts(
        Translation3::from(to_vector(pose.translation)),
        UnitQuaternion::new_normalize(nalgebra::Quaternion::new(r.w, r.x, r.y, r.z)),
    )
}

/// The rotation taking +x to `axis` (rapier's joints act about or along their local x).
fn x_to(axis: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::x(), axis).unwrap_or_else(|| {
        // axis = -x: any half turn about an orthogonal axis.
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
    })
}

/// A URDF arm simulated in rapier, torque-driven.
pub struct RapierPlant {
    /// The arm with its payloads (the truth).
    model: Arc<ArmModel>,
    /// The arm as built, and the payload (mass, point in the body frame) per body.
    base: Arc<ArmModel>,
    payloads: super::Payloads,
    /// External forces: (body, point in the body frame, world force).
    external: Vec<super::ExternalForce>,
    world: PhysicsWorld,
    bodies: Vec<RigidBodyHandle>,
    joints: Vec<SimJoint>,
    torques: Vec<f64>,
    /// The multibody holding every link.
    multibody: MultibodyIndex,
    /// Generalized-coordinate index of each joint.
    dofs: Vec<usize>,
    /// Scratch for state changes (one entry per multibody dof).
    scratch: Vec<f64>,
    /// Scratch for state reads.
    q_now: Vec<f64>,
    qd_now: Vec<f64>,
}

impl RapierPlant {
    /// Builds the multibody from a validated model, at q = 0.
    pub fn new(
        model: Arc<ArmModel>,
        gravity: [f64; 3],
        settings: &RapierSettings,
    ) -> Result<Self, PlantError> {
        settings
            .validate()
            .map_err(|e| PlantError::setting(&model, "plant.rapier", e))?;
        super::check_gravity(&model, gravity)?;
        let mut world = PhysicsWorld::new();
        world.gravity = DVec3::from_array(gravity);
        world.integration_parameters.num_solver_iterations = settings.solver_iterations;
        world.integration_parameters.num_internal_pgs_iterations = settings.pgs_iterations;
        let bodies = insert_bodies(&mut world, &model);
        let mut joints = Vec::with_capacity(model.joints.len());
        for spec in &model.joints {
            let frame = x_to(&spec.axis);
            let (locked, axis) = match spec.kind {
                JointKind::Prismatic => (JointAxesMask::LOCKED_PRISMATIC_AXES, JointAxis::LinX),
                _ => (JointAxesMask::LOCKED_REVOLUTE_AXES, JointAxis::AngX),
            };
            let mut generic = GenericJoint::new(locked);
            generic.set_local_frame1(to_pose(&(spec.origin * frame)));
            generic.set_local_frame2(to_pose(&Isometry3::from_parts(
                Translation3::identity(),
                frame,
            )));
            generic.set_contacts_enabled(false);
            if let Some((lower, upper)) = spec.limits {
                generic.set_limits(axis, [lower, upper]);
            }
            let parent = bodies[spec.parent_body];
            let child = bodies[spec.child_body];
            world
                .insert_multibody_joint(parent, child, generic)
                .ok_or_else(|| PlantError::Rejected {
                    path: model.source.clone(),
                    joint: spec.name.clone(),
                })?;
            joints.push(SimJoint {
                link: 0,
                parent,
                child,
                axis_child: spec.axis.into_inner(),
                kind: spec.kind,
            });
        }
        // The first forward kinematics turns rapier's provisional free root into a fixed one and
        // shifts the assembly ids; only then are the dofs read and damping and friction set.
        let multibody = world
            .multibody_joints
            .rigid_body_link(joints[0].child)
            .expect("the first joint's child is a multibody link")
            .multibody;
        let mut dofs = Vec::with_capacity(joints.len());
        for joint in &mut joints {
            joint.link = world
                .multibody_joints
                .rigid_body_link(joint.child)
                .expect("every child is a multibody link")
                .id;
        }
        {
            let mb = world
                .multibody_joints
                .get_multibody_mut(multibody)
                .expect("the arm is one multibody");
            mb.forward_kinematics(&world.bodies, true);
            mb.update_rigid_bodies(&mut world.bodies, true);
            for (joint, spec) in joints.iter().zip(&model.joints) {
                let dof = mb.link(joint.link).expect("link exists").assembly_id();
                mb.damping_mut()[dof] = spec.damping;
                mb.frictions_mut()[dof] = spec.friction;
                dofs.push(dof);
            }
        }
        let n = joints.len();
        if !settings.obstacles.is_empty() {
            insert_contact_shapes(&mut world, &model, &bodies, &settings.obstacles);
        }
        Ok(Self {
            base: model.clone(),
            payloads: super::Payloads::new(model.bodies.len()),
            external: Vec::new(),
            model,
            world,
            bodies,
            joints,
            torques: vec![0.0; n],
            multibody,
            dofs,
            scratch: Vec::new(),
            q_now: vec![0.0; n],
            qd_now: vec![0.0; n],
        })
    }
}

/// Every body at its pose for q = 0: the root fixed, the others dynamic with the model's mass
/// properties, never asleep, without rapier's own damping.
fn insert_bodies(world: &mut PhysicsWorld, model: &ArmModel) -> Vec<RigidBodyHandle> {
    let mut world_poses: Vec<Isometry3<f64>> = vec![Isometry3::identity(); model.bodies.len()];
    for joint in &model.joints {
        world_poses[joint.child_body] = world_poses[joint.parent_body] * joint.origin;
    }
    let mut bodies = Vec::with_capacity(model.bodies.len());
    for (b, spec) in model.bodies.iter().enumerate() {
        let builder = if b == 0 {
            RigidBodyBuilder::fixed()
        } else {
            RigidBodyBuilder::dynamic()
                .additional_mass_properties(mass_properties(spec))
                .can_sleep(false)
                .linear_damping(0.0)
                .angular_damping(0.0)
        };
        let builder = builder.pose(to_pose(&world_poses[b]));
        bodies.push(world.insert_body(builder));
    }
    bodies
}

/// The arm's collision shapes on its links (no mass: the URDF's inertials hold it; touching only
/// the obstacles) and the obstacles as fixed colliders.
fn insert_contact_shapes(
    world: &mut PhysicsWorld,
    model: &ArmModel,
    bodies: &[RigidBodyHandle],
    obstacles: &[Obstacle],
) {
    let arm = InteractionGroups::new(Group::GROUP_1, Group::GROUP_2, InteractionTestMode::And);
    let scene = InteractionGroups::new(Group::GROUP_2, Group::GROUP_1, InteractionTestMode::And);
    for c in &model.colliders {
        if c.body == 0 {
            continue;
        }
        let collider = ColliderBuilder::new(c.parry_shape.clone())
            .position(c.parry_pose)
            .density(0.0)
            .collision_groups(arm);
        world.insert_collider(collider, Some(bodies[c.body]));
    }
    for o in obstacles {
        let builder = match o.shape {
            ObstacleShape::Box => {
                ColliderBuilder::cuboid(o.size[0] / 2.0, o.size[1] / 2.0, o.size[2] / 2.0)
            }
            ObstacleShape::Ball => ColliderBuilder::ball(o.size[0]),
        };
        let collider = builder
            .position(to_pose(&o.pose()))
            .friction(o.friction)
            .collision_groups(scene);
        world.insert_collider(collider, None);
    }
}

/// A body's mass, centre of mass and inertia in rapier's type.
fn mass_properties(spec: &crate::arm::BodySpec) -> MassProperties {
    let i = &spec.inertia;
    MassProperties::with_inertia_matrix(
        to_dvec(&spec.com),
        spec.mass,
        rapier3d_f64::glamx::DMat3::from_cols_array(&[
            i[(0, 0)],
            i[(1, 0)],
            i[(2, 0)],
            i[(0, 1)],
            i[(1, 1)],
            i[(2, 1)],
            i[(0, 2)],
            i[(1, 2)],
            i[(2, 2)],
        ]),
    )
}

impl Plant for RapierPlant {
    fn set_state(&mut self, q: &[f64], qd: &[f64]) {
        assert_eq!(q.len(), self.joints.len(), "q has the wrong length");
        assert_eq!(qd.len(), self.joints.len(), "qd has the wrong length");
        let (mut q_now, mut qd_now) = (
            std::mem::take(&mut self.q_now),
            std::mem::take(&mut self.qd_now),
        );
        self.read_state(&mut q_now, &mut qd_now);
        let mb = self
            .world
            .multibody_joints
            .get_multibody_mut(self.multibody)
            .expect("the arm is one multibody");
        self.scratch.clear();
        self.scratch.resize(mb.ndofs(), 0.0);
        for (i, &dof) in self.dofs.iter().enumerate() {
            self.scratch[dof] = q[i] - q_now[i];
        }
        mb.apply_displacements(&self.scratch);
        mb.forward_kinematics(&self.world.bodies, false);
        mb.update_rigid_bodies(&mut self.world.bodies, true);
        let mut velocity = mb.generalized_velocity_mut();
        for (i, &dof) in self.dofs.iter().enumerate() {
            velocity[dof] = qd[i];
        }
        self.q_now = q_now;
        self.qd_now = qd_now;
    }

    fn read_state(&self, q: &mut [f64], qd: &mut [f64]) {
        let mb = self
            .world
            .multibody_joints
            .get_multibody(self.multibody)
            .expect("the arm is one multibody");
        let velocity = mb.generalized_velocity();
        for (i, joint) in self.joints.iter().enumerate() {
            let coords = mb.link(joint.link).expect("link exists").joint().coords();
            q[i] = match joint.kind {
                JointKind::Prismatic => coords[0],
                _ => coords[3],
            };
            qd[i] = velocity[self.dofs[i]];
        }
    }

    fn set_torques(&mut self, tau: &[f64]) {
        clamp_to_effort(&self.model, tau, &mut self.torques);
    }

    fn torques(&self) -> &[f64] {
        &self.torques
    }

    fn set_payload(&mut self, body: usize, payload: Option<(f64, Vector3<f64>)>) {
        self.payloads.set(body, payload);
        self.model = Arc::new(self.payloads.apply(&self.base));
        let spec = &self.model.bodies[body];
        self.world.bodies[self.bodies[body]]
            .set_additional_mass_properties(mass_properties(spec), true);
    }

    fn set_external_forces(&mut self, forces: &[super::ExternalForce]) {
        self.external.clear();
        self.external.extend_from_slice(forces);
    }

    /// The sum over the arm's touching contact pairs of their normal impulse over the last step
    /// / dt, as the force on the arm (rapier's `total_impulse` holds no friction impulse).
    fn contact_normal_force(&self) -> Vector3<f64> {
        let dt = self.world.integration_parameters.dt;
        let mut total = Vector3::zeros();
        for pair in self.world.narrow_phase.contact_pairs() {
            if !pair.has_any_active_contact() {
                continue;
            }
            let on_arm = |h: rapier3d_f64::prelude::ColliderHandle| {
                self.world.colliders[h]
                    .parent()
                    .is_some_and(|b| self.bodies[1..].contains(&b))
            };
            let impulse = to_vector(pair.total_impulse());
            // The impulse pushes collider 2 away from collider 1.
            if on_arm(pair.collider2) {
                total += impulse / dt;
            } else if on_arm(pair.collider1) {
                total -= impulse / dt;
            }
        }
        total
    }

    /// A brake is a joint limit at the held position (rapier's multibody limit constraint);
    /// releasing it restores the URDF's limits, or none.
    fn set_brake(&mut self, joint: usize, engaged: bool) {
        let (mut q, mut qd) = (vec![0.0; self.joints.len()], vec![0.0; self.joints.len()]);
        self.read_state(&mut q, &mut qd);
        let sim = &self.joints[joint];
        let axis = match sim.kind {
            JointKind::Prismatic => JointAxis::LinX,
            _ => JointAxis::AngX,
        };
        let spec_limits = self.model.joints[joint].limits;
        let mb = self
            .world
            .multibody_joints
            .get_multibody_mut(self.multibody)
            .expect("the arm is one multibody");
        let data = &mut mb.link_mut(sim.link).expect("link exists").joint.data;
        match (engaged, spec_limits) {
            (true, _) => {
                data.set_limits(axis, [q[joint], q[joint]]);
            }
            (false, Some((lower, upper))) => {
                data.set_limits(axis, [lower, upper]);
            }
            (false, None) => {
                data.limit_axes.remove(axis.into());
            }
        }
    }

    fn step(&mut self, dt: f64) {
        for &h in &self.bodies {
            if let Some(rb) = self.world.bodies.get_mut(h) {
                rb.reset_torques(false);
                rb.reset_forces(false);
            }
        }
        for (joint, &tau) in self.joints.iter().zip(&self.torques) {
            if tau == 0.0 {
                continue;
            }
            let child_rot = self.world.bodies[joint.child].position().rotation;
            let world_axis = child_rot * to_dvec(&joint.axis_child);
            match joint.kind {
                JointKind::Prismatic => {
                    self.world.bodies[joint.child].add_force(world_axis * tau, false);
                    self.world.bodies[joint.parent].add_force(-world_axis * tau, false);
                }
                _ => {
                    self.world.bodies[joint.child].add_torque(world_axis * tau, false);
                    self.world.bodies[joint.parent].add_torque(-world_axis * tau, false);
                }
            }
        }
        for f in &self.external {
            let pose = to_isometry(self.world.bodies[self.bodies[f.body]].position());
            let point = pose.transform_point(&f.point.into()).coords;
            self.world.bodies[self.bodies[f.body]].add_force_at_point(
                to_dvec(&f.force),
                to_dvec(&point),
                false,
            );
        }
        self.world.integration_parameters.dt = dt;
        self.world.step();
    }
}

impl ArmPose for RapierPlant {
    fn model(&self) -> &ArmModel {
        &self.model
    }

    fn body_pose(&self, body: usize) -> Isometry3<f64> {
        to_isometry(self.world.bodies[self.bodies[body]].position())
    }

    /// rapier keeps poses in parry's type: handed over without a round trip through nalgebra.
    fn collision_pose(&self, body: usize) -> parry3d_f64::math::Pose {
        *self.world.bodies[self.bodies[body]].position()
    }
}
