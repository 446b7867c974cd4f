//! The simulated arm: a rapier multibody (reduced coordinates) built from an [`ArmModel`],
//! driven by joint torques.
//!
//! Facts this relies on (docs/method.md, "Plant"): rapier has no generalized-force API, so a joint
//! torque tau about axis a is `+tau a` on the child body and `-tau a` on the parent, reset every
//! tick; multibody joints get a default damping of 0.1 that must be replaced by the URDF's
//! `<dynamics damping>` (0 when absent); q is read from the joint coordinates and qd from the
//! multibody's generalized velocity; sleeping is disabled on every link.

use nalgebra::{DMatrix, Isometry3, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::glamx::{DQuat, DVec3};
use rapier3d_f64::math::Pose;
use rapier3d_f64::parry::shape::SharedShape;
use rapier3d_f64::prelude::{
    GenericJoint, JointAxesMask, JointAxis, MassProperties, MultibodyIndex, PhysicsWorld,
    RigidBodyBuilder, RigidBodyHandle,
};

use super::PlantError;
use super::urdf::{ArmModel, JointKind, ShapeSpec};

/// Which dynamics engine steps the arm.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Engine {
    /// rapier3d-f64's multibody (reduced coordinates); `solver_iterations` substeps.
    #[default]
    Rapier,
    /// aift's own articulated-body dynamics ([`super::chain`]): the same map as rapier with the
    /// Euler integrator, or fourth-order Runge-Kutta.
    Articulated,
}

/// Settings of the simulated arm. Defaults: end effector `ee`, no offset, gravity 9.81 m/s^2
/// along -z, rapier with 2 solver iterations (they act as substeps, docs/method.md, "Plant"): on the paper arm a
/// tick costs 6.1 us with 2 and 9.7 us with 4, and the error against the closed-form RK4 oracle
/// after 2 s is of order 1e-5 rad (tests/plant_dynamics.rs, results/criterion.txt).
#[derive(Clone, Debug, PartialEq)]
pub struct ArmOptions {
    /// Link whose frame carries the end effector (any link, merged ones included).
    pub ee_link: String,
    /// End-effector point in that link's frame.
    pub ee_offset: [f64; 3],
    /// Gravity in world coordinates (m/s^2).
    pub gravity: [f64; 3],
    /// rapier's `num_solver_iterations` (>= 1), or the articulated engine's substeps.
    pub solver_iterations: usize,
    pub engine: Engine,
    /// The articulated engine's integrator (rapier has its own).
    pub integrator: super::chain::Integrator,
}

impl Default for ArmOptions {
    fn default() -> Self {
        Self {
            ee_link: "ee".to_string(),
            ee_offset: [0.0; 3],
            gravity: [0.0, 0.0, -9.81],
            solver_iterations: 2,
            engine: Engine::Rapier,
            integrator: super::chain::Integrator::Euler,
        }
    }
}

/// One movable joint as simulated.
#[derive(Clone, Debug)]
struct SimJoint {
    /// Index of the child's link inside the multibody.
    link: usize,
    /// Index of the child body in [`ArmModel::bodies`].
    child_body: usize,
    parent: RigidBodyHandle,
    child: RigidBodyHandle,
    /// Joint axis in the child body's frame (the child frame is the joint frame).
    axis_child: Vector3<f64>,
    kind: JointKind,
}

/// A collision shape with the body it is attached to.
#[derive(Clone)]
pub struct ArmCollider {
    /// Index of the body in [`ArmModel::bodies`].
    pub body: usize,
    pub shape: SharedShape,
    /// Pose of the shape in its body's frame.
    pub local_pose: Pose,
}

/// A URDF arm simulated in rapier, torque-driven.
pub struct Arm {
    model: ArmModel,
    options: ArmOptions,
    world: PhysicsWorld,
    bodies: Vec<RigidBodyHandle>,
    joints: Vec<SimJoint>,
    ee_body: usize,
    ee_local: Isometry3<f64>,
    torques: Vec<f64>,
    colliders: Vec<ArmCollider>,
    /// The multibody holding every link.
    multibody: MultibodyIndex,
    /// Generalized-coordinate index of each joint.
    dofs: Vec<usize>,
    /// Scratch for state changes (one entry per multibody dof).
    scratch: Vec<f64>,
    /// The articulated engine, when it steps the arm instead of rapier.
    chain: Option<super::chain::Chain>,
    gravity: Vector3<f64>,
}

pub(crate) fn to_dvec(v: &Vector3<f64>) -> DVec3 {
    DVec3::new(v.x, v.y, v.z)
}

pub(crate) fn to_vector(v: DVec3) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

pub(crate) fn to_pose(iso: &Isometry3<f64>) -> Pose {
    let q = iso.rotation.quaternion();
    Pose::from_parts(
        to_dvec(&iso.translation.vector),
        DQuat::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

pub(crate) fn to_isometry(pose: &Pose) -> Isometry3<f64> {
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

impl Arm {
    /// Builds the arm from a validated model.
    pub fn new(model: ArmModel, options: ArmOptions) -> Result<Self, PlantError> {
        let bad = |field: &str, message: String| PlantError::BadOption {
            path: model.source.clone(),
            field: field.to_string(),
            message,
        };
        if options.solver_iterations == 0 {
            return Err(bad("solver_iterations", "must be >= 1".into()));
        }
        if !options.gravity.iter().all(|g| g.is_finite()) {
            return Err(bad("gravity", "must be finite".into()));
        }
        if !options.ee_offset.iter().all(|g| g.is_finite()) {
            return Err(bad("ee_offset", "must be finite".into()));
        }
        let ee = model
            .link(&options.ee_link)
            .ok_or_else(|| model.unknown_link_error(&options.ee_link))?;
        let ee_body = ee.body;
        let ee_local = ee.pose
            * Isometry3::from_parts(
                Translation3::new(
                    options.ee_offset[0],
                    options.ee_offset[1],
                    options.ee_offset[2],
                ),
                UnitQuaternion::identity(),
            );

        let mut world = PhysicsWorld::new();
        world.gravity = DVec3::from_array(options.gravity);
        world.integration_parameters.num_solver_iterations = options.solver_iterations;

        // Bodies are created at their pose for q = 0.
        let mut world_poses: Vec<Isometry3<f64>> = vec![Isometry3::identity(); model.bodies.len()];
        for joint in &model.joints {
            world_poses[joint.child_body] = world_poses[joint.parent_body] * joint.origin;
        }
        let mut bodies = Vec::with_capacity(model.bodies.len());
        for (b, spec) in model.bodies.iter().enumerate() {
            let builder = if b == 0 {
                RigidBodyBuilder::fixed()
            } else {
                let mprops = MassProperties::with_inertia_matrix(
                    to_dvec(&spec.com),
                    spec.mass,
                    rapier3d_f64::glamx::DMat3::from_cols_array(&[
                        spec.inertia[(0, 0)],
                        spec.inertia[(1, 0)],
                        spec.inertia[(2, 0)],
                        spec.inertia[(0, 1)],
                        spec.inertia[(1, 1)],
                        spec.inertia[(2, 1)],
                        spec.inertia[(0, 2)],
                        spec.inertia[(1, 2)],
                        spec.inertia[(2, 2)],
                    ]),
                );
                RigidBodyBuilder::dynamic()
                    .additional_mass_properties(mprops)
                    .can_sleep(false)
                    .linear_damping(0.0)
                    .angular_damping(0.0)
            };
            let builder = builder.pose(to_pose(&world_poses[b]));
            bodies.push(world.insert_body(builder));
        }

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
                .ok_or_else(|| PlantError::Cycle {
                    path: model.source.clone(),
                    joint: spec.name.clone(),
                })?;
            joints.push(SimJoint {
                link: 0,
                child_body: spec.child_body,
                parent,
                child,
                axis_child: spec.axis.into_inner(),
                kind: spec.kind,
            });
        }

        let mut colliders = Vec::new();
        for (b, spec) in model.bodies.iter().enumerate() {
            for c in &spec.colliders {
                // parry's cylinders and capsules run along y; URDF's along z.
                let y_to_z = Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f64::consts::FRAC_PI_2,
                    ),
                );
                let (shape, pose) = match c.shape {
                    ShapeSpec::Box { half_extents } => (
                        SharedShape::cuboid(half_extents.x, half_extents.y, half_extents.z),
                        c.pose,
                    ),
                    ShapeSpec::Sphere { radius } => (SharedShape::ball(radius), c.pose),
                    ShapeSpec::Cylinder { radius, length } => {
                        (SharedShape::cylinder(length / 2.0, radius), c.pose * y_to_z)
                    }
                    ShapeSpec::Capsule { radius, length } => (
                        SharedShape::capsule_y(length / 2.0, radius),
                        c.pose * y_to_z,
                    ),
                };
                colliders.push(ArmCollider {
                    body: b,
                    shape,
                    local_pose: to_pose(&pose),
                });
            }
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
        let chain =
            (options.engine == Engine::Articulated).then(|| super::chain::Chain::new(&model));
        let gravity = Vector3::from(options.gravity);
        Ok(Self {
            chain,
            gravity,
            model,
            options,
            world,
            bodies,
            joints,
            ee_body,
            ee_local,
            torques: vec![0.0; n],
            colliders,
            multibody,
            dofs,
            scratch: Vec::new(),
        })
    }

    /// Loads a URDF and builds the arm.
    pub fn from_urdf(path: &std::path::Path, options: ArmOptions) -> Result<Self, PlantError> {
        Self::new(super::urdf::load_urdf(path)?, options)
    }

    /// The validated model the arm was built from.
    pub fn model(&self) -> &ArmModel {
        &self.model
    }

    /// The options the arm was built with.
    pub fn options(&self) -> &ArmOptions {
        &self.options
    }

    /// Number of movable joints.
    pub fn n_joints(&self) -> usize {
        self.joints.len()
    }

    /// Names of the movable joints, in control order.
    pub fn joint_names(&self) -> Vec<&str> {
        self.model.joints.iter().map(|j| j.name.as_str()).collect()
    }

    /// Joint axes, each in its joint frame.
    pub fn joint_axes(&self) -> Vec<Vector3<f64>> {
        self.joints.iter().map(|j| j.axis_child).collect()
    }

    /// Sets the joint positions and velocities (lengths = [`Self::n_joints`]).
    ///
    /// # Panics
    /// If a slice has the wrong length.
    pub fn set_state(&mut self, q: &[f64], qd: &[f64]) {
        assert_eq!(q.len(), self.n_joints(), "q has the wrong length");
        assert_eq!(qd.len(), self.n_joints(), "qd has the wrong length");
        if let Some(chain) = &mut self.chain {
            chain.set_state(q, qd);
            return;
        }
        let (q_now, _) = self.state();
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
    }

    /// Joint positions and velocities.
    pub fn state(&self) -> (Vec<f64>, Vec<f64>) {
        let mut q = vec![0.0; self.n_joints()];
        let mut qd = vec![0.0; self.n_joints()];
        self.read_state(&mut q, &mut qd);
        (q, qd)
    }

    /// Writes joint positions and velocities into the slices, without allocating.
    pub fn read_state(&self, q: &mut [f64], qd: &mut [f64]) {
        if let Some(chain) = &self.chain {
            q.copy_from_slice(chain.q());
            qd.copy_from_slice(chain.qd());
            return;
        }
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

    /// Sets the joint torques (forces for prismatic joints) applied from the next step on,
    /// clamped to each joint's URDF effort limit when it has one.
    pub fn set_torques(&mut self, tau: &[f64]) {
        assert_eq!(tau.len(), self.n_joints(), "tau has the wrong length");
        for (i, (out, &t)) in self.torques.iter_mut().zip(tau).enumerate() {
            *out = match self.model.joints[i].effort {
                Some(e) => t.clamp(-e, e),
                None => t,
            };
        }
    }

    /// The torques that will be applied (after the effort clamp).
    pub fn torques(&self) -> &[f64] {
        &self.torques
    }

    /// Advances the simulation by `dt` seconds with the current torques.
    pub fn step(&mut self, dt: f64) {
        if let Some(chain) = &mut self.chain {
            // A singular mass matrix (a degenerate model) leaves the state unchanged; the
            // runner's divergence guard sees the arm stop moving, not a panic.
            chain.step(
                &self.torques,
                &self.gravity,
                dt,
                self.options.solver_iterations,
                self.options.integrator,
            );
            return;
        }
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
        self.world.integration_parameters.dt = dt;
        self.world.step();
    }

    /// The joint-space mass matrix M(q) and gravity torque G(q) at rest at `q`, measured from
    /// the simulator itself: one step from rest gives qd = dt (M + dt D)^-1 (tau - G) (tested in
    /// `tests/plant_dynamics.rs`), so n + 1 probing steps with small torques recover M and G.
    /// The arm's state is restored afterwards.
    pub fn probe_dynamics(&mut self, q: &[f64], dt: f64) -> (DMatrix<f64>, Vec<f64>) {
        let n = self.n_joints();
        let (q_saved, qd_saved) = self.state();
        let saved_torques = self.torques.clone();
        let zeros = vec![0.0; n];
        let response = |arm: &mut Self, tau: &[f64]| {
            arm.set_state(q, &zeros);
            arm.torques.copy_from_slice(tau);
            arm.step(dt);
            arm.state().1
        };
        let free = response(self, &zeros);
        // Small probing torques stay clear of effort limits; the response is linear in them.
        let eps = 1e-3;
        let mut inverse = DMatrix::zeros(n, n);
        for i in 0..n {
            let mut tau = zeros.clone();
            tau[i] = eps;
            let qd = response(self, &tau);
            for r in 0..n {
                inverse[(r, i)] = (qd[r] - free[r]) / (dt * eps);
            }
        }
        let mut m = inverse
            .try_inverse()
            .unwrap_or_else(|| DMatrix::identity(n, n));
        for (i, joint) in self.model.joints.iter().enumerate() {
            m[(i, i)] -= dt * joint.damping;
        }
        let m = (&m + m.transpose()) * 0.5;
        let free_v = nalgebra::DVector::from_column_slice(&free);
        let mut md = m.clone();
        for (i, joint) in self.model.joints.iter().enumerate() {
            md[(i, i)] += dt * joint.damping;
        }
        let g: Vec<f64> = (-(md * free_v) / dt).iter().copied().collect();
        self.set_state(&q_saved, &qd_saved);
        self.torques = saved_torques;
        (m, g)
    }

    /// World pose of a body (index into [`ArmModel::bodies`]).
    pub fn body_pose(&self, body: usize) -> Isometry3<f64> {
        match &self.chain {
            Some(chain) => *chain.pose(body),
            None => to_isometry(self.world.bodies[self.bodies[body]].position()),
        }
    }

    /// World position of the end effector.
    pub fn ee_position(&self) -> Vector3<f64> {
        (self.body_pose(self.ee_body) * self.ee_local)
            .translation
            .vector
    }

    /// Index of the body that carries the end effector.
    pub fn ee_body(&self) -> usize {
        self.ee_body
    }

    /// World position of a link's frame origin plus `offset` (in that link's frame).
    pub fn link_point(&self, link: &str, offset: &Vector3<f64>) -> Option<Vector3<f64>> {
        let frame = self.model.link(link)?;
        Some(
            (self.body_pose(frame.body) * frame.pose)
                .transform_point(&nalgebra::Point3::from(*offset))
                .coords,
        )
    }

    /// The end effector's positional Jacobian d(ee)/dq (3 x n), from the joints' world axes.
    pub fn ee_jacobian(&self) -> DMatrix<f64> {
        let p = self.ee_position();
        let mut jac = DMatrix::zeros(3, self.n_joints());
        for (i, joint) in self.joints.iter().enumerate() {
            let pose = self.body_pose(joint.child_body);
            let axis = pose.rotation * joint.axis_child;
            let column = match joint.kind {
                JointKind::Prismatic => axis,
                _ => axis.cross(&(p - pose.translation.vector)),
            };
            jac.set_column(i, &column);
        }
        jac
    }

    /// The collision shapes, attached to bodies.
    pub fn colliders(&self) -> &[ArmCollider] {
        &self.colliders
    }

    /// World pose of a body in rapier's types (for parry's ray casts).
    pub fn body_pose_raw(&self, body: usize) -> Pose {
        match &self.chain {
            Some(chain) => to_pose(chain.pose(body)),
            None => *self.world.bodies[self.bodies[body]].position(),
        }
    }
}
