//! Rigid-body dynamics of an [`ArmModel`] in reduced coordinates: the joint-space mass matrix
//! M(q), the bias torques C(q, qd) qd + G(q), and the forward dynamics
//! qdd = M^-1 (tau - bias - D qd - friction). The articulated plant integrates them; the
//! estimators that carry a model of the arm predict with them (their model, which may be erred); `aift init` reads M and G from them.
//!
//! Written by hand because rapier keeps its multibody dynamics crate-private (mass matrix,
//! accelerations and integration are `pub(crate)` in rapier 0.36), and no maintained Rust crate
//! provides URDF-tree dynamics. The algorithms are textbook (Featherstone, *Rigid Body Dynamics
//! Algorithms*, 2008), in absolute (world-frame) spatial coordinates, where a joint's motion
//! subspace, the bodies' spatial inertias and the composite inertias need no frame changes:
//!
//! - spatial velocity V = (omega, v_O) with v_O the velocity of the body point at the world
//!   origin; a revolute joint at point p with world axis a has S = (a, p x a), a prismatic one
//!   S = (0, a);
//! - spatial inertia of a body of mass m, centre c and rotational inertia I_c about it:
//!   `[[I_c - m [c]x^2, m [c]x], [-m [c]x, m 1]]`;
//! - mass matrix by the composite-rigid-body algorithm, M_ij = S_i' I^c_(deeper of i, j) S_j on a
//!   branch;
//! - bias torques C(q, qd) qd + G(q) by recursive Newton-Euler with qdd = 0 and the base
//!   accelerating at -g: A_b = A_parent + crm(V_b) S qd, F_b = I_b A_b + crf(V_b) I_b V_b.
//!
//! As rapier keeps parameters, state and scratch apart, so does this module: the model is an
//! `Arc<ArmModel>` (never changed), the state (q, qd) is the caller's, and [`Dynamics`] is the
//! workspace the algorithms fill, reused every call without allocating.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, Vector3, Vector6};

use super::{ArmModel, JointKind, JointSpec, kinematics};

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// crm(V) x: the motion cross product.
fn cross_motion(v: &Vector6<f64>, x: &Vector6<f64>) -> Vector6<f64> {
    let (w, vo) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
    let (xw, xv) = (x.fixed_rows::<3>(0), x.fixed_rows::<3>(3));
    let a = w.cross(&xw);
    let b = vo.cross(&xw) + w.cross(&xv);
    Vector6::new(a.x, a.y, a.z, b.x, b.y, b.z)
}

/// crf(V) f: the force cross product.
fn cross_force(v: &Vector6<f64>, f: &Vector6<f64>) -> Vector6<f64> {
    let (w, vo) = (v.fixed_rows::<3>(0), v.fixed_rows::<3>(3));
    let (n, fl) = (f.fixed_rows::<3>(0), f.fixed_rows::<3>(3));
    let a = w.cross(&n) + vo.cross(&fl);
    let b = w.cross(&fl);
    Vector6::new(a.x, a.y, a.z, b.x, b.y, b.z)
}

/// The velocity (rad/s or m/s) below which the model's Coulomb friction fades linearly to zero:
/// F sign(qd) would be discontinuous at rest, where a stuck joint's friction is whatever holds it;
/// a linear ramp over 0.01 rad/s is the usual smooth stand-in of model-based observers.
pub const FRICTION_RAMP: f64 = 0.01;

/// How the forward dynamics treat the joints' Coulomb friction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Friction {
    /// F ramp(qd), faded to zero below [`FRICTION_RAMP`].
    Smooth,
    /// Left out (the caller applies it, as the articulated plant's impulses do).
    Excluded,
}

/// The workspace of the dynamics algorithms for one arm model under gravity g.
#[derive(Clone, Debug)]
pub struct Dynamics {
    model: Arc<ArmModel>,
    gravity: Vector3<f64>,
    /// Joint index whose child is each body (None for the root).
    parent_joint: Vec<Option<usize>>,
    poses: Vec<Isometry3<f64>>,
    s: Vec<Vector6<f64>>,
    inertia: Vec<Matrix6<f64>>,
    composite: Vec<Matrix6<f64>>,
    v: Vec<Vector6<f64>>,
    a: Vec<Vector6<f64>>,
    f: Vec<Vector6<f64>>,
    m: DMatrix<f64>,
    bias: DVector<f64>,
    rhs: DVector<f64>,
    factor: DMatrix<f64>,
    /// Per joint, the sign of the Coulomb friction the implicit step holds saturated at the
    /// tick's end (0: linearised inside its ramp, or explicit outside it).
    friction_end: Vec<f64>,
}

impl Dynamics {
    /// The dynamics of `model` under gravity `gravity` (m/s^2, world frame), at q = 0.
    pub fn new(model: Arc<ArmModel>, gravity: [f64; 3]) -> Self {
        let nb = model.bodies.len();
        let n = model.joints.len();
        let mut parent_joint = vec![None; nb];
        for (i, j) in model.joints.iter().enumerate() {
            parent_joint[j.child_body] = Some(i);
        }
        let mut d = Self {
            model,
            gravity: Vector3::from(gravity),
            parent_joint,
            poses: vec![Isometry3::identity(); nb],
            s: vec![Vector6::zeros(); n],
            inertia: vec![Matrix6::zeros(); nb],
            composite: vec![Matrix6::zeros(); nb],
            v: vec![Vector6::zeros(); nb],
            a: vec![Vector6::zeros(); nb],
            f: vec![Vector6::zeros(); nb],
            m: DMatrix::zeros(n, n),
            bias: DVector::zeros(n),
            rhs: DVector::zeros(n),
            factor: DMatrix::zeros(n, n),
            friction_end: vec![0.0; n],
        };
        d.set_configuration(&vec![0.0; n]);
        d
    }

    pub fn model(&self) -> &Arc<ArmModel> {
        &self.model
    }

    pub fn n_joints(&self) -> usize {
        self.model.joints.len()
    }

    pub fn gravity(&self) -> &Vector3<f64> {
        &self.gravity
    }

    /// Poses, motion subspaces and spatial inertias at joint positions q.
    pub fn set_configuration(&mut self, q: &[f64]) {
        kinematics::forward(&self.model, q, &mut self.poses);
        for (i, j) in self.model.joints.iter().enumerate() {
            let pose = &self.poses[j.child_body];
            let a = pose.rotation * j.axis.into_inner();
            let p = pose.translation.vector;
            self.s[i] = match j.kind {
                JointKind::Prismatic => Vector6::new(0.0, 0.0, 0.0, a.x, a.y, a.z),
                _ => {
                    let pa = p.cross(&a);
                    Vector6::new(a.x, a.y, a.z, pa.x, pa.y, pa.z)
                }
            };
        }
        for (b, body) in self.model.bodies.iter().enumerate() {
            let pose = &self.poses[b];
            let r = pose.rotation.to_rotation_matrix();
            let c = pose.translation.vector + r * body.com;
            let ic = r.matrix() * body.inertia * r.matrix().transpose();
            let cx = skew(&c);
            let m = body.mass;
            let mut i6 = Matrix6::zeros();
            i6.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(ic - cx * cx * m));
            i6.fixed_view_mut::<3, 3>(0, 3).copy_from(&(cx * m));
            i6.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-cx * m));
            i6.fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&(Matrix3::identity() * m));
            self.inertia[b] = i6;
        }
    }

    /// The bodies' world poses at the configuration last set.
    pub fn poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }

    /// M(q) and the bias C(q, qd) qd + G(q) at the configuration last set and velocities `qd`.
    pub fn compute(&mut self, qd: &[f64]) {
        let n = self.n_joints();
        let joints = &self.model.joints;
        // Composite inertias, leaves first (children come after parents in joint order).
        self.composite.copy_from_slice(&self.inertia);
        for j in joints.iter().rev() {
            let c = self.composite[j.child_body];
            self.composite[j.parent_body] += c;
        }
        self.m.fill(0.0);
        for i in 0..n {
            let f = self.composite[joints[i].child_body] * self.s[i];
            self.m[(i, i)] = self.s[i].dot(&f);
            // Walk up the ancestors of joint i.
            let mut body = joints[i].parent_body;
            while let Some(k) = self.parent_joint[body] {
                let v = self.s[k].dot(&f);
                self.m[(i, k)] = v;
                self.m[(k, i)] = v;
                body = joints[k].parent_body;
            }
        }
        // Recursive Newton-Euler, qdd = 0, base accelerating at -g.
        let g = &self.gravity;
        self.v[0] = Vector6::zeros();
        self.a[0] = Vector6::new(0.0, 0.0, 0.0, -g.x, -g.y, -g.z);
        for i in 0..n {
            let j = &joints[i];
            let vs = self.s[i] * qd[i];
            let v = self.v[j.parent_body] + vs;
            self.a[j.child_body] = self.a[j.parent_body] + cross_motion(&v, &vs);
            self.v[j.child_body] = v;
        }
        for b in 0..self.model.bodies.len() {
            let iv = self.inertia[b] * self.v[b];
            self.f[b] = self.inertia[b] * self.a[b] + cross_force(&self.v[b], &iv);
        }
        for i in (0..n).rev() {
            let j = &joints[i];
            self.bias[i] = self.s[i].dot(&self.f[j.child_body]);
            let fc = self.f[j.child_body];
            self.f[j.parent_body] += fc;
        }
    }

    /// The mass matrix of the last [`Self::compute`].
    pub fn mass_matrix(&self) -> &DMatrix<f64> {
        &self.m
    }

    /// The bias torques C(q, qd) qd + G(q) of the last [`Self::compute`].
    pub fn bias(&self) -> &DVector<f64> {
        &self.bias
    }

    /// M(q) and the gravity torques G(q) at rest at q (allocates the copies; for `init` and
    /// tests).
    pub fn mass_matrix_and_gravity(&mut self, q: &[f64]) -> (DMatrix<f64>, Vec<f64>) {
        self.set_configuration(q);
        self.compute(&vec![0.0; q.len()]);
        (self.m.clone(), self.bias.iter().copied().collect())
    }

    /// The forward dynamics at (q, qd) under joint torques u: qdd = M^-1 (u - bias - D qd -
    /// F ramp(qd)) into `out`, with the model's viscous damping D and Coulomb friction F (faded
    /// to zero below [`FRICTION_RAMP`]); without allocating. False (and `out` untouched) if M is
    /// singular.
    pub fn forward_dynamics(&mut self, q: &[f64], qd: &[f64], u: &[f64], out: &mut [f64]) -> bool {
        self.set_configuration(q);
        self.forward_dynamics_here(qd, u, Friction::Smooth, out)
    }

    /// As [`Self::forward_dynamics`] at the configuration last set; `friction` says whether the
    /// Coulomb friction enters (an integrator that applies it as impulses leaves it out).
    pub fn forward_dynamics_here(
        &mut self,
        qd: &[f64],
        u: &[f64],
        friction: Friction,
        out: &mut [f64],
    ) -> bool {
        self.compute(qd);
        self.fill_rhs(qd, u, friction);
        if !self.solve_damped(0.0) {
            return false;
        }
        out.copy_from_slice(self.rhs.as_slice());
        true
    }

    /// rhs = u - bias - D qd (- F ramp(qd) with smooth friction), from the last compute.
    fn fill_rhs(&mut self, qd: &[f64], u: &[f64], friction: Friction) {
        for (i, joint) in self.model.joints.iter().enumerate() {
            self.rhs[i] = u[i] - self.bias[i] - joint.damping * qd[i];
            if friction == Friction::Smooth && joint.friction > 0.0 {
                self.rhs[i] -= joint.friction * (qd[i] / FRICTION_RAMP).clamp(-1.0, 1.0);
            }
        }
    }

    /// As [`Self::forward_dynamics`] with the viscous damping, and the Coulomb friction on joints
    /// inside its ramp (|qd| < [`FRICTION_RAMP`], where it acts as a damping F / ramp), taken at
    /// the end of a step of `h` seconds: (M + h D_eff) qdd = u - bias - D qd - F ramp(qd), the
    /// linearly implicit step the articulated plant takes for its damping (docs/method.md,
    /// "Model error"). The explicit step's velocity v + h qdd is unstable once h D / M > 2 (a
    /// light joint with heavy damping); this one is not. The friction stays bounded by F: a
    /// joint the step carries out of its ramp (|qd + h qdd| > ramp) is solved again with the
    /// friction saturated at F sign(qd + h qdd) instead of the ramp's damping, which would
    /// oppose it with (|qd + h qdd| / ramp) F (at most one more solve per joint). h = 0 is
    /// [`Self::forward_dynamics`].
    pub fn forward_dynamics_implicit(
        &mut self,
        q: &[f64],
        qd: &[f64],
        u: &[f64],
        h: f64,
        out: &mut [f64],
    ) -> bool {
        self.set_configuration(q);
        self.compute(qd);
        let mut end = std::mem::take(&mut self.friction_end);
        end.fill(0.0);
        let mut solved = false;
        for _ in 0..=qd.len() {
            self.fill_rhs(qd, u, Friction::Smooth);
            for (i, joint) in self.model.joints.iter().enumerate() {
                if end[i] != 0.0 {
                    // The ramp's F ramp(qd) replaced by the saturated friction.
                    self.rhs[i] += joint.friction * (qd[i] / FRICTION_RAMP).clamp(-1.0, 1.0)
                        - joint.friction * end[i];
                }
            }
            solved = self.solve_shifted(|i, joint| {
                let mut damping = joint.damping;
                if joint.friction > 0.0 && qd[i].abs() < FRICTION_RAMP && end[i] == 0.0 {
                    damping += joint.friction / FRICTION_RAMP;
                }
                h * damping
            });
            if !solved {
                break;
            }
            let mut left_ramp = false;
            for (i, joint) in self.model.joints.iter().enumerate() {
                let v_end = qd[i] + h * self.rhs[i];
                if joint.friction > 0.0
                    && qd[i].abs() < FRICTION_RAMP
                    && end[i] == 0.0
                    && v_end.abs() > FRICTION_RAMP
                {
                    end[i] = v_end.signum();
                    left_ramp = true;
                }
            }
            if !left_ramp {
                break;
            }
        }
        self.friction_end = end;
        if solved {
            out.copy_from_slice(self.rhs.as_slice());
        }
        solved
    }

    /// The regressors of each joint's inertial torque error when every body's centre of mass is
    /// off by an isotropic error of standard deviation `sigma[b]` per axis (m), under the joint
    /// accelerations `qdd`, at the configuration last set (docs/method.md, "Model error"). Per
    /// joint j and body b it moves, the torque s_j . I_b A_b (A_b = sum of s_k qdd_k over b's
    /// joints) is m_b u_j . w with u_j = v_j + omega_j x c the centre of mass' velocity under
    /// joint j and w = a + alpha x c its acceleration; under c -> c + d it changes by m_b d .
    /// (w x omega_j + u_j x alpha) to first order and by m_b (omega_j x d) . (alpha x d) to
    /// second, whose root mean square for a d across the axis is sqrt(8) m_b sigma^2 |omega_j|
    /// |alpha| (the parallel-axis inertia a centre-of-mass error adds about an axis the body's
    /// centre lies on, which the first order misses). Into `grad[j * bodies + b]`: m_b sigma_b
    /// (w x omega_j + u_j x alpha) and sqrt(8) m_b sigma_b^2 |omega_j| alpha, zero for bodies
    /// joint j does not move; the torque error's variance is the sum of their squared norms
    /// over b, its covariance with another state's the sum of their dot products. Without
    /// allocating.
    pub fn centre_of_mass_regressors(
        &self,
        qdd: &[f64],
        sigma: &[f64],
        grad: &mut [[Vector3<f64>; 2]],
    ) {
        let nb = self.model.bodies.len();
        grad.iter_mut()
            .for_each(|g| *g = [Vector3::zeros(), Vector3::zeros()]);
        let joints = &self.model.joints;
        for (b, body) in self.model.bodies.iter().enumerate().skip(1) {
            let (m, sg) = (body.mass, sigma[b]);
            if m <= 0.0 || sg <= 0.0 {
                continue;
            }
            // The body's spatial acceleration from qdd (velocity products left out).
            let mut acc = Vector6::zeros();
            let mut at = b;
            while let Some(k) = self.parent_joint[at] {
                acc += self.s[k] * qdd[k];
                at = joints[k].parent_body;
            }
            let alpha = Vector3::new(acc[0], acc[1], acc[2]);
            let c = self.poses[b].translation.vector + self.poses[b].rotation * body.com;
            let w = Vector3::new(acc[3], acc[4], acc[5]) + alpha.cross(&c);
            let mut at = b;
            while let Some(j) = self.parent_joint[at] {
                let s = &self.s[j];
                let omega = Vector3::new(s[0], s[1], s[2]);
                let u = Vector3::new(s[3], s[4], s[5]) + omega.cross(&c);
                grad[j * nb + b] = [
                    (w.cross(&omega) + u.cross(&alpha)) * (m * sg),
                    alpha * (8f64.sqrt() * m * sg * sg * omega.norm()),
                ];
                at = joints[j].parent_body;
            }
        }
    }

    /// Solves A x = b in place with the factor of the last successful solve, without allocating
    /// or factoring again: A = M after [`Self::forward_dynamics`], M + h D_eff after
    /// [`Self::forward_dynamics_implicit`].
    pub fn solve_factored(&self, b: &mut [f64]) {
        solve_cholesky(&self.factor, b);
    }

    /// The right-hand side [`Self::solve_damped`] solves in place.
    pub fn rhs_mut(&mut self) -> &mut DVector<f64> {
        &mut self.rhs
    }

    /// Solves (M + h D) x = rhs in place ([`Self::rhs_mut`] holds the right-hand side) with
    /// the mass matrix of the last [`Self::compute`], without allocating; false if singular.
    pub fn solve_damped(&mut self, h: f64) -> bool {
        self.solve_shifted(|_, joint| h * joint.damping)
    }

    /// Solves (M + diag(shift(i, joint i))) x = rhs in place, without allocating; false if
    /// singular.
    fn solve_shifted(&mut self, shift: impl Fn(usize, &JointSpec) -> f64) -> bool {
        let n = self.n_joints();
        let mut storage = std::mem::replace(&mut self.factor, DMatrix::zeros(0, 0));
        storage.copy_from(&self.m);
        for (i, joint) in self.model.joints.iter().enumerate() {
            storage[(i, i)] += shift(i, joint);
        }
        let Some(chol) = nalgebra::linalg::Cholesky::new(storage) else {
            self.factor = DMatrix::zeros(n, n);
            return false;
        };
        chol.solve_mut(&mut self.rhs);
        self.factor = chol.unpack_dirty();
        true
    }
}

/// Solves L L' x = b in place, L the lower triangle of `l` (a Cholesky factor), without
/// allocating.
pub(crate) fn solve_cholesky(l: &DMatrix<f64>, b: &mut [f64]) {
    let n = b.len();
    for i in 0..n {
        let mut v = b[i];
        for k in 0..i {
            v -= l[(i, k)] * b[k];
        }
        b[i] = v / l[(i, i)];
    }
    for i in (0..n).rev() {
        let mut v = b[i];
        for k in i + 1..n {
            v -= l[(k, i)] * b[k];
        }
        b[i] = v / l[(i, i)];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    const TWO_LINK: &str = r#"<robot name="r">
      <link name="world"/>
      <joint name="j1" type="continuous"><parent link="world"/><child link="l1"/><axis xyz="0 -1 0"/></joint>
      <link name="l1"><inertial><origin xyz="0.5 0 0"/><mass value="2"/>
          <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.3" iyz="0" izz="0.3"/></inertial></link>
      <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/><origin xyz="1 0 0"/><axis xyz="0 -1 0"/></joint>
      <link name="l2"><inertial><origin xyz="0.4 0 0"/><mass value="1.5"/>
          <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"/></inertial></link>
    </robot>"#;

    fn two_link() -> Dynamics {
        let model = crate::arm::parse_urdf(TWO_LINK, Path::new("t.urdf")).unwrap();
        Dynamics::new(Arc::new(model), [0.0, 0.0, -9.81])
    }

    /// One joint about z (no gravity torque), inertia 1e-4 kg m^2 about it, damping 20 N m s/rad
    /// and friction 0.5 N m: h D / M = 200 at h = 1 ms.
    const STIFF: &str = r#"<robot name="s">
      <link name="world"/>
      <joint name="j" type="continuous"><parent link="world"/><child link="l"/><axis xyz="0 0 1"/>
        <dynamics damping="20" friction="0.5"/></joint>
      <link name="l"><inertial><mass value="1"/>
          <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>
    </robot>"#;

    /// The implicit step against its closed form on one joint, (I + h D_eff) a = u - D v -
    /// F ramp(v), its h = 0 case against the explicit forward dynamics, and its stability where
    /// the explicit step is not.
    #[test]
    fn the_implicit_step_solves_the_damped_equation_and_stays_stable() {
        let model = crate::arm::parse_urdf(STIFF, Path::new("s.urdf")).unwrap();
        let mut d = Dynamics::new(Arc::new(model), [0.0, 0.0, -9.81]);
        let (i, b, f, h) = (1e-4, 20.0, 0.5, 1e-3);
        let mut a = [0.0];
        let close = |a: f64, expected: f64| (a - expected).abs() <= 1e-12 * expected.abs();
        // Outside the friction ramp (|v| >= 0.01): D_eff = D.
        let (u, v) = (0.3, 0.5);
        assert!(d.forward_dynamics_implicit(&[0.2], &[v], &[u], h, &mut a));
        let expected = (u - b * v - f) / (i + h * b);
        assert!(close(a[0], expected), "{} {expected}", a[0]);
        // Inside it: D_eff = D + F / ramp.
        let v = 0.004;
        assert!(d.forward_dynamics_implicit(&[0.2], &[v], &[u], h, &mut a));
        let expected = (u - b * v - f * v / FRICTION_RAMP) / (i + h * (b + f / FRICTION_RAMP));
        assert!(close(a[0], expected), "{} {expected}", a[0]);
        // A torque that carries the joint out of the ramp within the tick meets the friction
        // saturated at F, not the ramp's damping (which would oppose it with 14 F here).
        let (u_big, v) = (10.0, 0.004);
        assert!(d.forward_dynamics_implicit(&[0.2], &[v], &[u_big], h, &mut a));
        let expected = (u_big - b * v - f) / (i + h * b);
        assert!(close(a[0], expected), "{} {expected}", a[0]);
        assert!(v + h * a[0] > FRICTION_RAMP);
        // And backwards: from inside the ramp, a torque driving it out the other way.
        assert!(d.forward_dynamics_implicit(&[0.2], &[v], &[-u_big], h, &mut a));
        let expected = (-u_big - b * v + f) / (i + h * b);
        assert!(close(a[0], expected), "{} {expected}", a[0]);
        // h = 0 is the explicit forward dynamics, bit for bit.
        let mut e = [0.0];
        assert!(d.forward_dynamics(&[0.2], &[0.5], &[u], &mut e));
        assert!(d.forward_dynamics_implicit(&[0.2], &[0.5], &[u], 0.0, &mut a));
        assert_eq!(a[0].to_bits(), e[0].to_bits());
        // Free decay from 1 rad/s: the explicit step's velocity grows by about |1 - h b / I| =
        // 199 per tick; the implicit one falls to rest within a tick, but for the friction's
        // own step outside its ramp, f h / (I + h b) (the friction is explicit there).
        let (mut v_explicit, mut v_implicit) = (1.0f64, 1.0f64);
        let chatter = f * h / (i + h * b);
        for _ in 0..5 {
            d.forward_dynamics(&[0.0], &[v_explicit], &[0.0], &mut e);
            v_explicit += h * e[0];
            d.forward_dynamics_implicit(&[0.0], &[v_implicit], &[0.0], h, &mut a);
            v_implicit += h * a[0];
            assert!(v_implicit.abs() <= 2.0 * chatter, "{v_implicit}");
        }
        assert!(v_explicit.abs() > 1e9, "{v_explicit}");
    }

    /// The closed-form planar two-link mass matrix and gravity (angles from +x, up positive).
    fn closed_form(q: [f64; 2]) -> ([[f64; 2]; 2], [f64; 2]) {
        let (l1, lc1, lc2, m1, m2, i1, i2, g) = (1.0, 0.5, 0.4, 2.0, 1.5, 0.3, 0.2, 9.81);
        let c2 = q[1].cos();
        let m11 = i1 + i2 + m1 * lc1 * lc1 + m2 * (l1 * l1 + lc2 * lc2 + 2.0 * l1 * lc2 * c2);
        let m12 = i2 + m2 * (lc2 * lc2 + l1 * lc2 * c2);
        let m22 = i2 + m2 * lc2 * lc2;
        let (c1, c12) = (q[0].cos(), (q[0] + q[1]).cos());
        let g1 = g * (m1 * lc1 * c1 + m2 * (lc2 * c12 + l1 * c1));
        let g2 = g * m2 * lc2 * c12;
        ([[m11, m12], [m12, m22]], [g1, g2])
    }

    #[test]
    fn mass_matrix_and_gravity_match_the_closed_form() {
        let mut d = two_link();
        for q in [[0.3, -0.7], [-1.2, 1.1], [2.0, 0.0]] {
            let (m, bias) = d.mass_matrix_and_gravity(&q);
            let (mr, gr) = closed_form(q);
            for r in 0..2 {
                assert!((bias[r] - gr[r]).abs() < 1e-12, "{bias:?} vs {gr:?}");
                for c in 0..2 {
                    assert!((m[(r, c)] - mr[r][c]).abs() < 1e-12, "{m} vs {mr:?}");
                }
            }
        }
    }

    #[test]
    fn coriolis_terms_match_the_closed_form() {
        let model = crate::arm::parse_urdf(TWO_LINK, Path::new("t.urdf")).unwrap();
        let mut d = Dynamics::new(Arc::new(model), [0.0; 3]);
        let (q, qd) = ([0.4, 0.9], [1.3, -0.8]);
        d.set_configuration(&q);
        d.compute(&qd);
        // C(q, qd) qd for the planar two-link arm: h = m2 l1 lc2 sin q2.
        let h = 1.5 * 1.0 * 0.4 * q[1].sin();
        let expected = [
            -h * qd[1] * qd[1] - 2.0 * h * qd[0] * qd[1],
            h * qd[0] * qd[0],
        ];
        for r in 0..2 {
            assert!(
                (d.bias()[r] - expected[r]).abs() < 1e-12,
                "{:?} vs {expected:?}",
                d.bias()
            );
        }
    }

    /// The bias is the gradient structure's check: with the kinetic energy T = qd' M qd / 2,
    /// C(q, qd) qd = dM/dt qd - dT/dq (Lagrange), both sides by central finite differences of M.
    #[test]
    fn coriolis_terms_match_finite_differences_of_the_mass_matrix_on_the_7_dof_arm() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
        let model = Arc::new(crate::arm::load_urdf(&path).unwrap());
        let mut d = Dynamics::new(model, [0.0; 3]);
        let q = [0.3, -0.5, 0.2, -1.9, 0.4, 1.6, -0.7];
        let qd = [0.8, -0.4, 1.1, 0.5, -1.3, 0.9, 2.0];
        let n = 7;
        d.set_configuration(&q);
        d.compute(&qd);
        let bias: Vec<f64> = d.bias().iter().copied().collect();
        let h = 1e-6;
        let mut m_at = |q: &[f64]| {
            d.set_configuration(q);
            d.compute(&[0.0; 7]);
            d.mass_matrix().clone()
        };
        let mut dm: Vec<DMatrix<f64>> = Vec::new();
        for k in 0..n {
            let (mut plus, mut minus) = (q, q);
            plus[k] += h;
            minus[k] -= h;
            dm.push((m_at(&plus) - m_at(&minus)) / (2.0 * h));
        }
        let qdv = DVector::from_column_slice(&qd);
        let mdot = dm
            .iter()
            .zip(&qd)
            .fold(DMatrix::zeros(n, n), |acc, (d, v)| acc + d * *v);
        let first = &mdot * &qdv;
        for i in 0..n {
            let dt_dq = 0.5 * (qdv.transpose() * &dm[i] * &qdv)[(0, 0)];
            let expected = first[i] - dt_dq;
            assert!(
                (bias[i] - expected).abs() < 1e-6 * (1.0 + expected.abs()),
                "joint {i}: {} against {expected}",
                bias[i]
            );
        }
    }

    /// The centre-of-mass regressors on the Panda against the mass matrix itself: the first
    /// order is the central finite difference of (M qdd)_j in the body's centre of mass (each
    /// axis of the body frame, a world direction R e_k), the second order is half the second
    /// difference, m (omega_j x d) . (alpha x d); and for a joint whose axis is parallel to the
    /// body's angular acceleration, a Monte Carlo of that term over isotropic d has the root
    /// mean square the second regressor's norm claims (sqrt(8) m sigma^2 |alpha|).
    #[test]
    fn centre_of_mass_regressors_match_finite_differences_of_the_mass_matrix() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
        let truth = crate::arm::load_urdf(&path).unwrap();
        let q = [0.3, -0.5, 0.2, -1.9, 0.4, 1.6, -0.7];
        let qdd = [40.0, -25.0, 60.0, 15.0, -80.0, 30.0, 120.0];
        let (n, nb) = (7, truth.bodies.len());
        let sigma: Vec<f64> = (0..nb).map(|b| if b == 0 { 0.0 } else { 0.01 }).collect();
        let torque_at = |model: &ArmModel| -> Vec<f64> {
            let mut d = Dynamics::new(Arc::new(model.clone()), [0.0; 3]);
            d.set_configuration(&q);
            d.compute(&[0.0; 7]);
            let m = d.mass_matrix();
            (0..n)
                .map(|j| (0..n).map(|k| m[(j, k)] * qdd[k]).sum())
                .collect()
        };
        let mut d = Dynamics::new(Arc::new(truth.clone()), [0.0; 3]);
        d.set_configuration(&q);
        let mut grad = vec![[Vector3::zeros(), Vector3::zeros()]; n * nb];
        d.centre_of_mass_regressors(&qdd, &sigma, &mut grad);
        let base = torque_at(&truth);
        let h = 1e-4;
        let mut checked = 0;
        for b in 1..nb {
            let rotation = d.poses()[b].rotation;
            for k in 0..3 {
                let shifted = |step: f64| {
                    let mut m = truth.clone();
                    m.bodies[b].com[k] += step;
                    torque_at(&m)
                };
                let (plus, minus) = (shifted(h), shifted(-h));
                let mut e = Vector3::zeros();
                e[k] = 1.0;
                let dir = rotation * e;
                for j in 0..n {
                    let first = (plus[j] - minus[j]) / (2.0 * h);
                    let second = (plus[j] + minus[j] - 2.0 * base[j]) / (h * h) / 2.0;
                    let [g, _] = grad[j * nb + b];
                    let want_first = g.dot(&dir) / sigma[b];
                    let scale = 1e-6 * (1.0 + want_first.abs() + first.abs());
                    assert!(
                        (first - want_first).abs() < scale,
                        "body {b} axis {k} joint {j}: {first} against {want_first}"
                    );
                    // m (omega_j x d) . (alpha x d) for a body joint j moves (else 0).
                    let moved = grad[j * nb + b][0] != Vector3::zeros()
                        || grad[j * nb + b][1] != Vector3::zeros();
                    let want_second = if moved {
                        let s = d.s[j];
                        let omega = Vector3::new(s[0], s[1], s[2]);
                        let mut alpha = Vector3::zeros();
                        let mut at = b;
                        while let Some(i) = d.parent_joint[at] {
                            alpha += Vector3::new(d.s[i][0], d.s[i][1], d.s[i][2]) * qdd[i];
                            at = truth.joints[i].parent_body;
                        }
                        truth.bodies[b].mass * omega.cross(&dir).dot(&alpha.cross(&dir))
                    } else {
                        0.0
                    };
                    assert!(
                        (second - want_second).abs() < 1e-3 * (1.0 + want_second.abs()),
                        "body {b} axis {k} joint {j}: second order {second} against {want_second}"
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, (nb - 1) * 3 * n);
        // Joint 1 alone moving: alpha is along its axis, and the second-order term's root mean
        // square over isotropic d is the second regressor's norm.
        let only = [50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        d.centre_of_mass_regressors(&only, &sigma, &mut grad);
        let s = d.s[0];
        let omega = Vector3::new(s[0], s[1], s[2]);
        let alpha = omega * 50.0;
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (b, samples) = (3, 200_000);
        let m = truth.bodies[b].mass;
        let mut sum = 0.0;
        for _ in 0..samples {
            let z = Vector3::from_fn(|_, _| {
                let v: f64 = StandardNormal.sample(&mut rng);
                v * sigma[b]
            });
            let x = m * omega.cross(&z).dot(&alpha.cross(&z));
            sum += x * x;
        }
        let rms = (sum / samples as f64).sqrt();
        let claimed = grad[b][1].norm();
        assert!(
            (rms / claimed - 1.0).abs() < 0.02,
            "Monte Carlo {rms} against {claimed}"
        );
    }
}
