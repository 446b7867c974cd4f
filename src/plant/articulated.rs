//! The articulated plant: aift's own reduced-coordinate dynamics ([`crate::arm::dynamics`])
//! integrated by hand, an independent engine beside rapier, used to cross-check it, to integrate
//! accurately (RK4) when the trajectory itself matters, and to simulate fast.
//!
//! Two integrators. `Euler`: semi-implicit Euler with the joints' viscous damping implicit,
//! (M + h D) qd' = M qd + h (tau - bias), q' = q + h qd', exactly the map rapier applies
//! (docs/method.md, "Plant"), first order in the substep h. `Rk4`: classical Runge-Kutta on
//! (q, qd), fourth order. `ExplicitEuler`: forward Euler, the authors' MATLAB plant (a
//! compatibility setting). Joint limits: an inelastic stop, by sequential impulses through M^-1;
//! Coulomb friction: impulses bounded by friction x h. Both act only when engaged.

use std::sync::Arc;

use nalgebra::{DMatrix, Isometry3};
use serde::{Deserialize, Serialize};

use super::{ArmPose, Plant, PlantError, clamp_to_effort};
use crate::arm::ArmModel;
use crate::arm::dynamics::{Dynamics, Friction};

/// How the articulated plant integrates.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// Semi-implicit Euler with implicit damping (rapier's map), first order.
    #[default]
    Euler,
    /// Classical fourth-order Runge-Kutta.
    Rk4,
    /// Explicit (forward) Euler with the damping explicit: q' = q + h qd, qd' = qd + h qdd(q, qd).
    /// A compatibility setting, not a recommendation: the plant of the authors' 2-DOF MATLAB
    /// benchmark (`dq(:,i+1) = dq(:,i) + h*ddq(:,i); q(:,i+1) = q(:,i) + h*dq(:,i)`). Unstable
    /// once h D / M exceeds 2.
    ExplicitEuler,
}

/// Most substeps per tick.
pub const MAX_SUBSTEPS: usize = 1000;

/// Settings of the articulated plant (`[plant.articulated]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ArticulatedSettings {
    /// Substeps per tick (>= 1): 2 by default, the same first-order map as rapier's default.
    #[schemars(range(min = 1, max = 1000))]
    pub substeps: usize,
    /// `euler` (rapier's map, default), `rk4` or `explicit-euler` (the authors' MATLAB plant).
    pub integrator: Integrator,
}

impl Default for ArticulatedSettings {
    fn default() -> Self {
        Self {
            substeps: 2,
            integrator: Integrator::Euler,
        }
    }
}

impl ArticulatedSettings {
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        if !(1..=MAX_SUBSTEPS).contains(&self.substeps) {
            return Err(crate::SettingError::new(
                "substeps",
                format!("must be in 1..={MAX_SUBSTEPS}"),
            ));
        }
        Ok(())
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

/// The articulated plant: the model's dynamics and the joint state, stepped by hand.
#[derive(Clone, Debug)]
pub struct ArticulatedPlant {
    settings: ArticulatedSettings,
    dynamics: Dynamics,
    q: Vec<f64>,
    qd: Vec<f64>,
    torques: Vec<f64>,
    rk4: Rk4Scratch,
    // Scratch of the constraint impulses: the engaged joints, (M + h D)^-1's columns for them
    // (column k for the k-th engaged joint), their friction impulses.
    engaged: Vec<usize>,
    columns: DMatrix<f64>,
    friction_impulse: Vec<f64>,
    /// Per joint: the position a brake holds it at (a locked-joint fault), if engaged.
    brakes: Vec<Option<f64>>,
    /// The arm as built, and the payload per body.
    base: Arc<ArmModel>,
    payloads: super::Payloads,
    /// External forces, and the torques with their generalized forces added (scratch).
    external: Vec<super::ExternalForce>,
    loaded_torques: Vec<f64>,
}

impl ArticulatedPlant {
    /// The arm at rest at q = 0 under gravity `gravity`.
    pub fn new(
        model: Arc<ArmModel>,
        gravity: [f64; 3],
        settings: &ArticulatedSettings,
    ) -> Result<Self, PlantError> {
        settings
            .validate()
            .map_err(|e| PlantError::setting(&model, "plant.articulated", e))?;
        super::check_gravity(&model, gravity)?;
        let n = model.joints.len();
        Ok(Self {
            base: model.clone(),
            payloads: super::Payloads::new(model.bodies.len()),
            external: Vec::new(),
            loaded_torques: vec![0.0; n],
            settings: settings.clone(),
            dynamics: Dynamics::new(model, gravity),
            q: vec![0.0; n],
            qd: vec![0.0; n],
            torques: vec![0.0; n],
            rk4: Rk4Scratch::default(),
            engaged: Vec::with_capacity(n),
            columns: DMatrix::zeros(n, n),
            friction_impulse: vec![0.0; n],
            brakes: vec![None; n],
        })
    }

    /// Column i of (M + h D)^-1, written into the dynamics' right-hand side.
    fn inverse_column(&mut self, i: usize, h: f64) {
        let rhs = self.dynamics.rhs_mut();
        rhs.fill(0.0);
        rhs[i] = 1.0;
        self.dynamics.solve_damped(h);
    }

    /// Impulses for engaged joint limits and Coulomb friction, applied to qd (in place), with
    /// the effective mass (M + h D) of the last dynamics computed.
    fn constraints(&mut self, h: f64) {
        let n = self.q.len();
        let model = self.dynamics.model().clone();
        let joints = &model.joints;
        let brakes = std::mem::take(&mut self.brakes);
        // A brake is a limit at the held position; a braked joint has no friction to overcome.
        let limits = |i: usize| brakes[i].map(|b| (b, b)).or(joints[i].limits);
        let friction = |i: usize| {
            if brakes[i].is_some() {
                0.0
            } else {
                joints[i].friction
            }
        };
        let mut engaged = std::mem::take(&mut self.engaged);
        engaged.clear();
        engaged.extend((0..n).filter(|&i| {
            friction(i) > 0.0
                || limits(i).is_some_and(|(lo, hi)| {
                    let next = self.q[i] + h * self.qd[i];
                    next < lo || next > hi
                })
        }));
        if engaged.is_empty() {
            self.engaged = engaged;
            self.brakes = brakes;
            return;
        }
        // Columns of (M + h D)^-1 for the engaged joints.
        for (k, &i) in engaged.iter().enumerate() {
            self.inverse_column(i, h);
            self.columns.set_column(k, self.dynamics.rhs_mut());
        }
        self.friction_impulse.fill(0.0);
        for _ in 0..super::GAUSS_SEIDEL_SWEEPS {
            for (k, &i) in engaged.iter().enumerate() {
                let w = self.columns[(i, k)];
                if w <= 0.0 {
                    continue;
                }
                if let Some((lo, hi)) = limits(i) {
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
                if friction(i) > 0.0 {
                    let bound = friction(i) * h;
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
        self.brakes = brakes;
    }

    /// Advances by `dt` in the settings' substeps with the current torques. Returns false if the
    /// dynamics became singular (the state is then unchanged).
    fn advance(&mut self, dt: f64) -> bool {
        let substeps = self.settings.substeps.max(1);
        let h = dt / substeps as f64;
        let commanded = std::mem::take(&mut self.torques);
        let mut loaded = std::mem::take(&mut self.loaded_torques);
        let mut ok = true;
        for _ in 0..substeps {
            let tau: &[f64] = if self.external.is_empty() {
                &commanded
            } else {
                self.with_external_forces(&commanded, &mut loaded);
                &loaded
            };
            ok = match self.settings.integrator {
                Integrator::Euler => self.euler(tau, h),
                Integrator::Rk4 => self.rk4(tau, h),
                Integrator::ExplicitEuler => self.explicit_euler(tau, h),
            };
            if !ok {
                break;
            }
        }
        self.torques = commanded;
        self.loaded_torques = loaded;
        ok
    }

    /// `tau` plus the external forces' generalized forces J^T F at the current configuration,
    /// into `out` (held over the substep).
    fn with_external_forces(&self, tau: &[f64], out: &mut [f64]) {
        out.copy_from_slice(tau);
        let poses = self.dynamics.poses();
        let model = self.dynamics.model();
        for f in &self.external {
            let point = poses[f.body].transform_point(&f.point.into()).coords;
            let jac = crate::arm::kinematics::point_jacobian(model, f.body, &point, poses);
            for (i, t) in out.iter_mut().enumerate() {
                *t += jac.column(i).dot(&f.force);
            }
        }
    }

    fn euler(&mut self, tau: &[f64], h: f64) -> bool {
        let n = self.q.len();
        self.dynamics.compute(&self.qd);
        // (M + h D) qd' = M qd + h (tau - bias).
        for r in 0..n {
            let mut s = h * (tau[r] - self.dynamics.bias()[r]);
            for c in 0..n {
                s += self.dynamics.mass_matrix()[(r, c)] * self.qd[c];
            }
            self.dynamics.rhs_mut()[r] = s;
        }
        if !self.dynamics.solve_damped(h) {
            return false;
        }
        for i in 0..n {
            self.qd[i] = self.dynamics.rhs_mut()[i];
        }
        self.constraints(h);
        for i in 0..n {
            self.q[i] += h * self.qd[i];
        }
        self.dynamics.set_configuration(&self.q);
        true
    }

    /// qdd = M^-1 (tau - bias - D qd) at (q, qd) after q changed, into `out` (friction is an
    /// impulse at the end of the step).
    fn acceleration(&mut self, tau: &[f64], out: &mut [f64]) -> bool {
        self.dynamics.set_configuration(&self.q);
        if !self
            .dynamics
            .forward_dynamics_here(&self.qd, tau, Friction::Excluded, out)
        {
            return false;
        }
        if self.brakes.iter().any(Option::is_some) {
            self.hold_braked(out);
        }
        true
    }

    /// The acceleration with every braked joint held (its qdd = 0), from the unconstrained one
    /// and M's factor of the last forward dynamics: qdd += W lambda, W = M^-1 E (E the braked
    /// joints' unit vectors), (E^T W) lambda = -E^T qdd (Gauss's principle: the brake torque
    /// lambda is the least that holds them).
    fn hold_braked(&mut self, qdd: &mut [f64]) {
        let n = qdd.len();
        let braked: Vec<usize> = (0..n).filter(|&i| self.brakes[i].is_some()).collect();
        let m = braked.len();
        let mut column = vec![0.0; n];
        for (k, &b) in braked.iter().enumerate() {
            column.fill(0.0);
            column[b] = 1.0;
            self.dynamics.solve_factored(&mut column);
            for r in 0..n {
                self.columns[(r, k)] = column[r];
            }
        }
        let a = DMatrix::from_fn(m, m, |r, c| self.columns[(braked[r], c)]);
        let mut lambda = nalgebra::DVector::from_fn(m, |r, _| -qdd[braked[r]]);
        if let Some(chol) = nalgebra::linalg::Cholesky::new(a) {
            chol.solve_mut(&mut lambda);
            for (r, v) in qdd.iter_mut().enumerate() {
                for k in 0..m {
                    *v += self.columns[(r, k)] * lambda[k];
                }
            }
        }
        for &b in &braked {
            qdd[b] = 0.0;
        }
    }

    fn rk4(&mut self, tau: &[f64], h: f64) -> bool {
        let n = self.q.len();
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
            if !self.acceleration(tau, &mut k.kv[stage]) {
                self.q.copy_from_slice(&k.q0);
                self.qd.copy_from_slice(&k.qd0);
                self.dynamics.set_configuration(&self.q);
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
        self.end_of_step(k, h);
        true
    }

    /// Forward Euler: qdd at the start of the step, q' = q + h qd, qd' = qd + h qdd.
    fn explicit_euler(&mut self, tau: &[f64], h: f64) -> bool {
        let n = self.q.len();
        let mut k = std::mem::take(&mut self.rk4);
        k.resize(n);
        k.q0.copy_from_slice(&self.q);
        if !self.acceleration(tau, &mut k.kv[0]) {
            self.rk4 = k;
            return false;
        }
        for i in 0..n {
            self.q[i] += h * self.qd[i];
            self.qd[i] += h * k.kv[0][i];
        }
        self.end_of_step(k, h);
        true
    }

    /// Limits and friction as an impulse at the end of an explicit step that went from `k.q0`
    /// to the current (q, qd); gives the scratch back.
    fn end_of_step(&mut self, mut k: Rk4Scratch, h: f64) {
        k.q_end.copy_from_slice(&self.q);
        self.q.copy_from_slice(&k.q0);
        self.dynamics.set_configuration(&self.q);
        self.dynamics.compute(&self.qd);
        self.constraints(h);
        self.q.copy_from_slice(&k.q_end);
        for (i, j) in self.dynamics.model().joints.iter().enumerate() {
            if let Some((lo, hi)) = self.brakes[i].map(|b| (b, b)).or(j.limits) {
                self.q[i] = self.q[i].clamp(lo, hi);
            }
        }
        self.dynamics.set_configuration(&self.q);
        self.rk4 = k;
    }
}

impl Plant for ArticulatedPlant {
    fn set_state(&mut self, q: &[f64], qd: &[f64]) {
        assert_eq!(q.len(), self.q.len(), "q has the wrong length");
        assert_eq!(qd.len(), self.qd.len(), "qd has the wrong length");
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
        self.dynamics.set_configuration(q);
    }

    fn read_state(&self, q: &mut [f64], qd: &mut [f64]) {
        q.copy_from_slice(&self.q);
        qd.copy_from_slice(&self.qd);
    }

    fn set_torques(&mut self, tau: &[f64]) {
        clamp_to_effort(self.dynamics.model(), tau, &mut self.torques);
    }

    fn torques(&self) -> &[f64] {
        &self.torques
    }

    fn set_payload(&mut self, body: usize, payload: Option<(f64, nalgebra::Vector3<f64>)>) {
        self.payloads.set(body, payload);
        let gravity = *self.dynamics.gravity();
        self.dynamics = Dynamics::new(
            Arc::new(self.payloads.apply(&self.base)),
            [gravity.x, gravity.y, gravity.z],
        );
        self.dynamics.set_configuration(&self.q);
    }

    fn set_external_forces(&mut self, forces: &[super::ExternalForce]) {
        self.external.clear();
        self.external.extend_from_slice(forces);
    }

    fn set_brake(&mut self, joint: usize, engaged: bool) {
        self.brakes[joint] = engaged.then_some(self.q[joint]);
    }

    /// A singular mass matrix (a degenerate model) leaves the state unchanged; the runner's
    /// divergence guard sees the arm stop moving, not a panic.
    fn step(&mut self, dt: f64) {
        self.advance(dt);
    }

    fn body_poses_into(&self, out: &mut [Isometry3<f64>]) {
        out.copy_from_slice(self.dynamics.poses());
    }
}

impl ArmPose for ArticulatedPlant {
    fn model(&self) -> &ArmModel {
        self.dynamics.model()
    }

    fn body_pose(&self, body: usize) -> Isometry3<f64> {
        self.dynamics.poses()[body]
    }
}

/// Forward kinematics are the model's: the articulated plant's poses are
/// [`crate::arm::kinematics::forward`]'s at its q.
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn its_poses_are_the_models_forward_kinematics() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
        let model = Arc::new(crate::arm::load_urdf(&path).unwrap());
        let mut plant = ArticulatedPlant::new(
            model.clone(),
            [0.0, 0.0, -9.81],
            &ArticulatedSettings::default(),
        )
        .unwrap();
        let q = [0.1, -0.4, 0.3, -1.7, 0.2, 1.5, 0.6];
        plant.set_state(&q, &[0.0; 7]);
        let mut k = crate::arm::Kinematics::new(model);
        let poses = k.set(&q);
        for (b, pose) in poses.iter().enumerate() {
            assert_eq!(*pose, plant.body_pose(b));
        }
    }
}
