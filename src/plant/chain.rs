//! aift's own rigid-body dynamics of a URDF tree in reduced coordinates: an independent engine
//! beside rapier, used to cross-check it, to integrate accurately (RK4) when the trajectory
//! itself matters, and to simulate fast.
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
//! Two integrators. `Euler`: semi-implicit Euler with the joints' viscous damping implicit,
//! (M + h D) qd' = M qd + h (tau - bias), q' = q + h qd', exactly the map rapier applies
//! (docs/method.md, "Plant"), first order in the substep h. `Rk4`: classical Runge-Kutta on
//! (q, qd), fourth order. Joint limits: an inelastic stop, by sequential impulses through M^-1;
//! Coulomb friction: impulses bounded by friction x h. Both act only when engaged.

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6,
};

use super::urdf::{ArmModel, JointKind};

/// How the articulated engine integrates.
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
pub enum Integrator {
    /// Semi-implicit Euler with implicit damping (rapier's map), first order.
    #[default]
    Euler,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
}

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

#[derive(Clone, Debug)]
struct ChainJoint {
    parent: usize,
    child: usize,
    origin: Isometry3<f64>,
    axis: Vector3<f64>,
    kind: JointKind,
    damping: f64,
    friction: f64,
    limits: Option<(f64, f64)>,
}

#[derive(Clone, Debug)]
struct ChainBody {
    mass: f64,
    com: Vector3<f64>,
    inertia: Matrix3<f64>,
}

/// The articulated engine's model and state.
#[derive(Clone, Debug)]
pub struct Chain {
    joints: Vec<ChainJoint>,
    bodies: Vec<ChainBody>,
    /// Joint index whose child is each body (None for the root).
    parent_joint: Vec<Option<usize>>,
    q: Vec<f64>,
    qd: Vec<f64>,
    poses: Vec<Isometry3<f64>>,
    // Scratch, reused every step.
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
    rk4: Rk4Scratch,
    // Scratch of the constraint impulses: the engaged joints, (M + h D)^-1's columns for them
    // (column k for the k-th engaged joint), their friction impulses.
    engaged: Vec<usize>,
    columns: DMatrix<f64>,
    friction_impulse: Vec<f64>,
}

impl Chain {
    pub fn new(model: &ArmModel) -> Self {
        let nb = model.bodies.len();
        let n = model.joints.len();
        let mut parent_joint = vec![None; nb];
        let joints: Vec<ChainJoint> = model
            .joints
            .iter()
            .enumerate()
            .map(|(i, j)| {
                parent_joint[j.child_body] = Some(i);
                ChainJoint {
                    parent: j.parent_body,
                    child: j.child_body,
                    origin: j.origin,
                    axis: j.axis.into_inner(),
                    kind: j.kind,
                    damping: j.damping,
                    friction: j.friction,
                    limits: j.limits,
                }
            })
            .collect();
        let bodies = model
            .bodies
            .iter()
            .map(|b| ChainBody {
                mass: b.mass,
                com: b.com,
                inertia: b.inertia,
            })
            .collect();
        let mut c = Self {
            joints,
            bodies,
            parent_joint,
            q: vec![0.0; n],
            qd: vec![0.0; n],
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
            rk4: Rk4Scratch::default(),
            engaged: Vec::with_capacity(n),
            columns: DMatrix::zeros(n, n),
            friction_impulse: vec![0.0; n],
        };
        c.kinematics();
        c
    }

    pub fn n_joints(&self) -> usize {
        self.q.len()
    }

    pub fn q(&self) -> &[f64] {
        &self.q
    }

    pub fn qd(&self) -> &[f64] {
        &self.qd
    }

    pub fn set_state(&mut self, q: &[f64], qd: &[f64]) {
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
        self.kinematics();
    }

    /// World pose of body `b` at the current q.
    pub fn pose(&self, b: usize) -> &Isometry3<f64> {
        &self.poses[b]
    }

    /// Poses, motion subspaces and spatial inertias at the current q.
    fn kinematics(&mut self) {
        for (i, j) in self.joints.iter().enumerate() {
            let motion = match j.kind {
                JointKind::Prismatic => Isometry3::from_parts(
                    Translation3::from(j.axis * self.q[i]),
                    UnitQuaternion::identity(),
                ),
                _ => Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_scaled_axis(j.axis * self.q[i]),
                ),
            };
            let pose = self.poses[j.parent] * j.origin * motion;
            let a = pose.rotation * j.axis;
            let p = pose.translation.vector;
            self.s[i] = match j.kind {
                JointKind::Prismatic => Vector6::new(0.0, 0.0, 0.0, a.x, a.y, a.z),
                _ => {
                    let pa = p.cross(&a);
                    Vector6::new(a.x, a.y, a.z, pa.x, pa.y, pa.z)
                }
            };
            self.poses[j.child] = pose;
        }
        for (b, body) in self.bodies.iter().enumerate() {
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

    /// M(q) and the bias C(q, qd) qd + G(q) at the current state, for gravity `g`.
    fn dynamics(&mut self, g: &Vector3<f64>) {
        let n = self.n_joints();
        // Composite inertias, leaves first (children come after parents in joint order).
        self.composite.copy_from_slice(&self.inertia);
        for j in self.joints.iter().rev() {
            let c = self.composite[j.child];
            self.composite[j.parent] += c;
        }
        self.m.fill(0.0);
        for i in 0..n {
            let f = self.composite[self.joints[i].child] * self.s[i];
            self.m[(i, i)] = self.s[i].dot(&f);
            // Walk up the ancestors of joint i.
            let mut body = self.joints[i].parent;
            while let Some(k) = self.parent_joint[body] {
                let v = self.s[k].dot(&f);
                self.m[(i, k)] = v;
                self.m[(k, i)] = v;
                body = self.joints[k].parent;
            }
        }
        // Recursive Newton-Euler, qdd = 0, base accelerating at -g.
        self.v[0] = Vector6::zeros();
        self.a[0] = Vector6::new(0.0, 0.0, 0.0, -g.x, -g.y, -g.z);
        for i in 0..n {
            let j = &self.joints[i];
            let vs = self.s[i] * self.qd[i];
            let v = self.v[j.parent] + vs;
            self.a[j.child] = self.a[j.parent] + cross_motion(&v, &vs);
            self.v[j.child] = v;
        }
        for b in 0..self.bodies.len() {
            let iv = self.inertia[b] * self.v[b];
            self.f[b] = self.inertia[b] * self.a[b] + cross_force(&self.v[b], &iv);
        }
        for i in (0..n).rev() {
            let j = &self.joints[i];
            self.bias[i] = self.s[i].dot(&self.f[j.child]);
            let fc = self.f[j.child];
            self.f[j.parent] += fc;
        }
    }

    /// The mass matrix and bias torques at the current state (for tests and probes).
    pub fn mass_matrix_and_bias(&mut self, g: &Vector3<f64>) -> (DMatrix<f64>, Vec<f64>) {
        self.dynamics(g);
        (self.m.clone(), self.bias.iter().copied().collect())
    }

    /// The forward dynamics at the state set: qdd = M^-1 (u - bias - D qd) into `out`, without
    /// allocating; false (and `out` untouched) if M is singular.
    pub fn forward_dynamics(&mut self, u: &[f64], g: &Vector3<f64>, out: &mut [f64]) -> bool {
        self.dynamics(g);
        for i in 0..self.n_joints() {
            self.rhs[i] = u[i] - self.bias[i] - self.joints[i].damping * self.qd[i];
        }
        if !self.solve_damped(0.0) {
            return false;
        }
        out.copy_from_slice(self.rhs.as_slice());
        true
    }

    /// Solves (M + h D) x = rhs in place (rhs holds the right-hand side), without allocating.
    fn solve_damped(&mut self, h: f64) -> bool {
        let n = self.n_joints();
        let mut storage = std::mem::replace(&mut self.factor, DMatrix::zeros(0, 0));
        storage.copy_from(&self.m);
        for i in 0..n {
            storage[(i, i)] += h * self.joints[i].damping;
        }
        let Some(chol) = nalgebra::linalg::Cholesky::new(storage) else {
            self.factor = DMatrix::zeros(n, n);
            return false;
        };
        chol.solve_mut(&mut self.rhs);
        self.factor = chol.unpack_dirty();
        true
    }

    /// Column i of (M + h D)^-1, written into `rhs`.
    fn inverse_column(&mut self, i: usize, h: f64) {
        self.rhs.fill(0.0);
        self.rhs[i] = 1.0;
        self.solve_damped(h);
    }

    /// Impulses for engaged joint limits and Coulomb friction, applied to qd (in place), with
    /// the effective mass (M + h D) of the last factorisation's state.
    fn constraints(&mut self, h: f64) {
        let n = self.n_joints();
        let mut engaged = std::mem::take(&mut self.engaged);
        engaged.clear();
        engaged.extend((0..n).filter(|&i| {
            let j = &self.joints[i];
            j.friction > 0.0
                || j.limits.is_some_and(|(lo, hi)| {
                    let next = self.q[i] + h * self.qd[i];
                    next < lo || next > hi
                })
        }));
        if engaged.is_empty() {
            self.engaged = engaged;
            return;
        }
        // Columns of (M + h D)^-1 for the engaged joints.
        for (k, &i) in engaged.iter().enumerate() {
            self.inverse_column(i, h);
            self.columns.set_column(k, &self.rhs);
        }
        self.friction_impulse.fill(0.0);
        for _ in 0..8 {
            for (k, &i) in engaged.iter().enumerate() {
                let j = &self.joints[i];
                let w = self.columns[(i, k)];
                if w <= 0.0 {
                    continue;
                }
                if let Some((lo, hi)) = j.limits {
                    let next = self.q[i] + h * self.qd[i];
                    let target = if next > hi {
                        Some((hi - self.q[i]) / h)
                    } else if next < lo {
                        Some((lo - self.q[i]) / h)
                    } else {
                        None
                    };
                    if let Some(target) = target {
                        let lambda = (target - self.qd[i]) / w;
                        for r in 0..n {
                            self.qd[r] += self.columns[(r, k)] * lambda;
                        }
                    }
                }
                if j.friction > 0.0 {
                    let bound = j.friction * h;
                    let old = self.friction_impulse[k];
                    let new = (old - self.qd[i] / w).clamp(-bound, bound);
                    let lambda = new - old;
                    self.friction_impulse[k] = new;
                    for r in 0..n {
                        self.qd[r] += self.columns[(r, k)] * lambda;
                    }
                }
            }
        }
        self.engaged = engaged;
    }

    /// Advances by `dt` in `substeps` substeps with joint torques `tau` and gravity `g`.
    /// Returns false if the dynamics became singular (the state is then unchanged).
    pub fn step(
        &mut self,
        tau: &[f64],
        g: &Vector3<f64>,
        dt: f64,
        substeps: usize,
        integrator: Integrator,
    ) -> bool {
        let h = dt / substeps.max(1) as f64;
        for _ in 0..substeps.max(1) {
            let ok = match integrator {
                Integrator::Euler => self.euler(tau, g, h),
                Integrator::Rk4 => self.rk4(tau, g, h),
            };
            if !ok {
                return false;
            }
        }
        true
    }

    fn euler(&mut self, tau: &[f64], g: &Vector3<f64>, h: f64) -> bool {
        let n = self.n_joints();
        self.dynamics(g);
        // (M + h D) qd' = M qd + h (tau - bias).
        for r in 0..n {
            let mut s = h * (tau[r] - self.bias[r]);
            for c in 0..n {
                s += self.m[(r, c)] * self.qd[c];
            }
            self.rhs[r] = s;
        }
        if !self.solve_damped(h) {
            return false;
        }
        for i in 0..n {
            self.qd[i] = self.rhs[i];
        }
        self.constraints(h);
        for i in 0..n {
            self.q[i] += h * self.qd[i];
        }
        self.kinematics();
        true
    }

    /// qdd = M^-1 (tau - bias - D qd) at (q, qd) after q changed, into `out`.
    fn acceleration(&mut self, tau: &[f64], g: &Vector3<f64>, out: &mut [f64]) -> bool {
        self.kinematics();
        self.forward_dynamics(tau, g, out)
    }

    fn rk4(&mut self, tau: &[f64], g: &Vector3<f64>, h: f64) -> bool {
        let n = self.n_joints();
        let mut k = std::mem::take(&mut self.rk4);
        k.resize(n);
        k.q0.copy_from_slice(&self.q);
        k.qd0.copy_from_slice(&self.qd);
        let weights = [0.0, 0.5, 0.5, 1.0];
        for stage in 0..4 {
            if stage > 0 {
                let w = weights[stage] * h;
                for i in 0..n {
                    self.q[i] = k.q0[i] + w * k.kq[stage - 1][i];
                    self.qd[i] = k.qd0[i] + w * k.kv[stage - 1][i];
                }
            }
            k.kq[stage].copy_from_slice(&self.qd);
            if !self.acceleration(tau, g, &mut k.kv[stage]) {
                self.q.copy_from_slice(&k.q0);
                self.qd.copy_from_slice(&k.qd0);
                self.kinematics();
                self.rk4 = k;
                return false;
            }
        }
        let (kq, kv) = (&k.kq, &k.kv);
        for i in 0..n {
            self.q[i] = k.q0[i] + h / 6.0 * (kq[0][i] + 2.0 * kq[1][i] + 2.0 * kq[2][i] + kq[3][i]);
            self.qd[i] =
                k.qd0[i] + h / 6.0 * (kv[0][i] + 2.0 * kv[1][i] + 2.0 * kv[2][i] + kv[3][i]);
        }
        // Limits and friction as an impulse at the end of the step.
        k.q_end.copy_from_slice(&self.q);
        self.q.copy_from_slice(&k.q0);
        self.kinematics();
        self.dynamics(g);
        self.constraints(h);
        self.q.copy_from_slice(&k.q_end);
        for (i, j) in self.joints.iter().enumerate() {
            if let Some((lo, hi)) = j.limits {
                self.q[i] = self.q[i].clamp(lo, hi);
            }
        }
        self.kinematics();
        self.rk4 = k;
        true
    }
}

/// RK4's per-step storage, kept between steps: the start state, the four stages' slopes, and q at
/// the end before the limits act.
#[derive(Clone, Debug, Default)]
struct Rk4Scratch {
    q0: Vec<f64>,
    qd0: Vec<f64>,
    kq: [Vec<f64>; 4],
    kv: [Vec<f64>; 4],
    q_end: Vec<f64>,
}

impl Rk4Scratch {
    fn resize(&mut self, n: usize) {
        for v in [&mut self.q0, &mut self.qd0, &mut self.q_end]
            .into_iter()
            .chain(&mut self.kq)
            .chain(&mut self.kv)
        {
            v.resize(n, 0.0);
        }
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
        let model = crate::plant::parse_urdf(TWO_LINK, Path::new("t.urdf")).unwrap();
        let mut chain = Chain::new(&model);
        for q in [[0.3, -0.7], [-1.2, 1.1], [2.0, 0.0]] {
            chain.set_state(&q, &[0.0, 0.0]);
            let (m, bias) = chain.mass_matrix_and_bias(&Vector3::new(0.0, 0.0, -9.81));
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
        let model = crate::plant::parse_urdf(TWO_LINK, Path::new("t.urdf")).unwrap();
        let mut chain = Chain::new(&model);
        let (q, qd) = ([0.4, 0.9], [1.3, -0.8]);
        chain.set_state(&q, &qd);
        let (_, bias) = chain.mass_matrix_and_bias(&Vector3::zeros());
        // C(q, qd) qd for the planar two-link arm: h = m2 l1 lc2 sin q2.
        let h = 1.5 * 1.0 * 0.4 * q[1].sin();
        let expected = [
            -h * qd[1] * qd[1] - 2.0 * h * qd[0] * qd[1],
            h * qd[0] * qd[0],
        ];
        for r in 0..2 {
            assert!(
                (bias[r] - expected[r]).abs() < 1e-12,
                "{bias:?} vs {expected:?}"
            );
        }
    }
}
