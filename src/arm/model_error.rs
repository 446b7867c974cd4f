//! Model error: the estimators' copy of the arm differs from the plant's (the scenario's `[model]`
//! section). The plant simulates the URDF as written (the truth); every estimator that carries a
//! model of the arm (the hybrid's bank, the Kalman baselines with `kalman.process_model =
//! "dynamics"`) gets [`ModelConfig::erred`]: the URDF with each body's mass, inertia and centre
//! of mass and each joint's damping and Coulomb friction off by errors drawn per run from the
//! run's seed (deterministic, the same for every method of a run and whatever the shard), or
//! given exactly, or both. docs/method.md, "Model error", says where the default sizes come from.
//!
//! The section also holds what those estimators assume about their model's accuracy: the
//! process noise max(`acceleration_noise`, `relative_error` x |predicted acceleration|) per joint.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use nalgebra::Matrix3;

use super::ArmModel;
use crate::SettingError;

/// The stream of the model-error draws (apart from the sensors' and the GP's).
const MODEL_STREAM: u64 = 60_000;

/// Draws are truncated at this many standard deviations (a model is never absurdly wrong).
pub const TRUNCATION: f64 = 3.0;

/// An exact error on one body (named by any URDF link merged into it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct BodyError {
    /// A link of the body.
    pub link: String,
    /// The model's mass as a multiple of the truth's.
    #[serde(default = "one")]
    pub mass: f64,
    /// The model's rotational inertia (about the centre of mass) as a multiple of the truth's.
    #[serde(default = "one")]
    pub inertia: f64,
    /// The model's centre of mass minus the truth's, in the body frame (m).
    #[serde(default)]
    pub com: [f64; 3],
}

/// An exact error on one joint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct JointError {
    /// The joint's URDF name.
    pub joint: String,
    /// The model's viscous damping as a multiple of the truth's.
    #[serde(default = "one")]
    pub damping: f64,
    /// The model's Coulomb friction as a multiple of the truth's (0: the model has none).
    #[serde(default = "one")]
    pub friction: f64,
    /// Coulomb friction (N m) the model has on top: friction the plant may not have at all.
    #[serde(default)]
    pub friction_offset: f64,
}

fn one() -> f64 {
    1.0
}

/// The `[model]` section: how the estimators' arm model differs from the plant's, and how much
/// they trust it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Draw errors per run with the sizes below (default); false: the model is the plant's
    /// but for `mass_scale` and the given errors (`--set model.draw=false` for a perfect model).
    pub draw: bool,
    /// Each moving body's mass times exp(mass x z), z standard normal (log-normal, about this
    /// relative error), drawn per run.
    pub mass: f64,
    /// Each principal moment of each moving body's rotational inertia times exp(inertia x z)
    /// (axes kept, triangle inequality kept), drawn per run.
    pub inertia: f64,
    /// Each moving body's centre of mass moved by com x L x z per axis, L the body's length
    /// scale (the farthest of its child joints' origins, twice its centre of mass, twice its
    /// radius of gyration, from its frame's origin), drawn per run.
    pub com: f64,
    /// Each joint's viscous damping times exp(damping x z), drawn per run.
    pub damping: f64,
    /// Each joint's Coulomb friction times exp(friction x z), drawn per run.
    pub friction: f64,
    /// Every mass and inertia of the model times this (a systematic error, e.g. a payload the
    /// model does not know of), on top of the drawn ones.
    pub mass_scale: f64,
    /// Exact errors per body, on top of the drawn ones (factors multiply, offsets add).
    pub bodies: Vec<BodyError>,
    /// Exact errors per joint, on top of the drawn ones.
    pub joints: Vec<JointError>,
    /// The least process noise (rad/s^2, one standard deviation) a model-based estimator
    /// assumes for its predicted acceleration.
    pub acceleration_noise: f64,
    /// The relative error a model-based estimator assumes for its predicted acceleration: each
    /// joint's process noise is max(`acceleration_noise`, this x |qdd|).
    pub relative_error: f64,
    /// How a model-based estimator predicts a tick: `implicit` (the default: damping and the
    /// friction ramp at the tick's end, stable for any damping, as the articulated plant steps)
    /// or `explicit` (the acceleration at the tick's start, the default until 2026-12-04;
    /// measured in docs/method.md, "Model error").
    pub step: PredictionStep,
    /// How a model-based estimator budgets the inertial part of its model error and, carrying
    /// it as a state (the hybrid's bank), moves it from tick to tick (docs/method.md, "Model
    /// error as a state"): `per-joint` (the default since 2026-12-06: each joint's own
    /// regressors, with the inertia a centre-of-mass error adds about a joint's axis) or
    /// `shared-cosine` (one cosine for every joint, the default before). Written only when not
    /// the default; the build digest in journals and calibration caches keeps results of the
    /// two defaults apart.
    #[serde(skip_serializing_if = "InertialBudget::is_default")]
    pub inertial_budget: InertialBudget,
}

/// How a model's inertial error is budgeted and carried from tick to tick (`model.inertial_budget`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum InertialBudget {
    /// The inertial torque error u (M qdd)_j per joint (u the larger of the mass and inertia
    /// sizes), carried by one cosine of the model's acceleration vectors then and now for every
    /// joint.
    SharedCosine,
    /// The same torque error plus the centres of mass' (their gradients and the parallel-axis
    /// inertia a centre-of-mass error adds about an axis), each joint's carried by its own
    /// regressors' covariance then and now.
    #[default]
    PerJoint,
}

impl InertialBudget {
    fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

/// How a model-based estimator predicts one tick from the model.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum PredictionStep {
    /// qdd = M^-1 (u - bias - D qd - F ramp(qd)) at the tick's start.
    Explicit,
    /// (M + dt D_eff) qdd = u - bias - D qd - F ramp(qd): damping (and friction inside its ramp)
    /// at the tick's end (`Dynamics::forward_dynamics_implicit`).
    #[default]
    Implicit,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            draw: true,
            mass: 0.15,
            inertia: 0.3,
            com: 0.08,
            damping: 0.5,
            friction: 0.3,
            mass_scale: 1.0,
            bodies: Vec::new(),
            joints: Vec::new(),
            acceleration_noise: 2.0,
            relative_error: 0.1,
            step: PredictionStep::Implicit,
            inertial_budget: InertialBudget::PerJoint,
        }
    }
}

/// The relative (one standard deviation) errors an estimator assumes its model has, per
/// [`ModelConfig`]'s draws: masses and inertias, centres of mass (relative to each body's length
/// scale), damping and friction. Zero: the model is taken as exact.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModelUncertainty {
    pub mass: f64,
    pub inertia: f64,
    pub com: f64,
    pub damping: f64,
    pub friction: f64,
    /// How the inertial part is budgeted and carried.
    pub inertial_budget: InertialBudget,
}

impl ModelUncertainty {
    /// Per body of `model`, its centre of mass' assumed error per axis (m, one standard
    /// deviation): `com` x the body's length scale ([`length_scale`]); 0 for the root.
    pub fn centre_of_mass_sigma(&self, model: &ArmModel) -> Vec<f64> {
        (0..model.bodies.len())
            .map(|b| {
                if b == 0 {
                    0.0
                } else {
                    self.com * length_scale(model, b)
                }
            })
            .collect()
    }

    pub fn is_zero(&self) -> bool {
        self.mass == 0.0
            && self.inertia == 0.0
            && self.com == 0.0
            && self.damping == 0.0
            && self.friction == 0.0
    }
}

/// A body's length scale (m): the farthest of its child joints' origins, twice its centre of
/// mass and twice its radius of gyration sqrt(largest principal moment / mass), from its frame's
/// origin.
pub fn length_scale(model: &ArmModel, body: usize) -> f64 {
    let b = &model.bodies[body];
    let children = model
        .joints
        .iter()
        .filter(|j| j.parent_body == body)
        .map(|j| j.origin.translation.vector.norm())
        .fold(0.0, f64::max);
    let gyration = if b.mass > 0.0 {
        (b.inertia.symmetric_eigenvalues().max().max(0.0) / b.mass).sqrt()
    } else {
        0.0
    };
    children.max(2.0 * b.com.norm()).max(2.0 * gyration)
}

/// `inertia` with each principal moment times exp(sigma z_k), the principal axes kept; where the
/// new moments break the triangle inequality, the largest is lowered to the sum of the others.
fn perturbed_inertia(inertia: &Matrix3<f64>, sigma: f64, z: [f64; 3]) -> Matrix3<f64> {
    if sigma == 0.0 || z.iter().all(|v| *v == 0.0) {
        return *inertia;
    }
    let eigen = inertia.symmetric_eigen();
    let mut e = eigen.eigenvalues;
    for (v, zk) in e.iter_mut().zip(z) {
        *v *= (sigma * zk).exp();
    }
    let (mut big, mut rest) = (0, 0.0);
    for k in 0..3 {
        if e[k] > e[big] {
            big = k;
        }
    }
    for k in 0..3 {
        if k != big {
            rest += e[k];
        }
    }
    if e[big] > rest {
        e[big] = rest;
    }
    let t = eigen.eigenvectors * Matrix3::from_diagonal(&e) * eigen.eigenvectors.transpose();
    (t + t.transpose()) * 0.5
}

/// Most exact errors per section.
pub const MAX_GIVEN: usize = 10_000;

impl ModelConfig {
    /// A perfect model: the plant's own, nothing drawn.
    pub fn perfect() -> Self {
        Self {
            draw: false,
            ..Self::default()
        }
    }

    /// Whether errors are drawn per run.
    fn draws(&self) -> bool {
        self.draw
            && [
                self.mass,
                self.inertia,
                self.com,
                self.damping,
                self.friction,
            ]
            .iter()
            .any(|v| *v > 0.0)
    }

    /// Whether the estimators' model is the plant's own.
    pub fn is_perfect(&self) -> bool {
        !self.draws() && self.mass_scale == 1.0 && self.bodies.is_empty() && self.joints.is_empty()
    }

    /// Checks the sizes (not the names: [`Self::check_names`] does, with the arm).
    pub fn validate(&self) -> Result<(), SettingError> {
        for (name, v, max) in [
            ("mass", self.mass, 2.0),
            ("inertia", self.inertia, 2.0),
            ("com", self.com, 1.0),
            ("damping", self.damping, 2.0),
            ("friction", self.friction, 2.0),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                return Err(SettingError::new(
                    name,
                    format!("{v} must be in [0, {max}]"),
                ));
            }
        }
        if !(self.mass_scale.is_finite() && self.mass_scale > 0.0 && self.mass_scale <= 100.0) {
            return Err(SettingError::new("mass_scale", "must be in (0, 100]"));
        }
        let a = self.acceleration_noise;
        if !(a.is_finite() && a > 0.0 && a <= 1e9) {
            return Err(SettingError::new(
                "acceleration_noise",
                "must be in (0, 1e9]",
            ));
        }
        let r = self.relative_error;
        if !(r.is_finite() && (0.0..=10.0).contains(&r)) {
            return Err(SettingError::new("relative_error", "must be in [0, 10]"));
        }
        if self.bodies.len() > MAX_GIVEN || self.joints.len() > MAX_GIVEN {
            return Err(SettingError::new(
                "bodies",
                format!("at most {MAX_GIVEN} given errors per list"),
            ));
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let at = |f: &str| format!("bodies[{i}].{f}");
            for (f, v) in [("mass", b.mass), ("inertia", b.inertia)] {
                if !(v.is_finite() && v > 0.0 && v <= 100.0) {
                    return Err(SettingError::new(at(f), format!("{v} must be in (0, 100]")));
                }
            }
            if !b.com.iter().all(|c| c.is_finite() && c.abs() <= 10.0) {
                return Err(SettingError::new(
                    at("com"),
                    "entries must be finite and within 10 m",
                ));
            }
        }
        for (i, j) in self.joints.iter().enumerate() {
            let at = |f: &str| format!("joints[{i}].{f}");
            for (f, v) in [
                ("damping", j.damping),
                ("friction", j.friction),
                ("friction_offset", j.friction_offset),
            ] {
                if !(v.is_finite() && (0.0..=1e6).contains(&v)) {
                    return Err(SettingError::new(at(f), format!("{v} must be in [0, 1e6]")));
                }
            }
        }
        Ok(())
    }

    /// Checks that every given error names a link and a movable joint of `model`.
    pub fn check_names(&self, model: &ArmModel) -> Result<(), SettingError> {
        for (i, b) in self.bodies.iter().enumerate() {
            match model.link(&b.link) {
                Some(l) if l.body > 0 => {}
                Some(_) => {
                    return Err(SettingError::new(
                        format!("bodies[{i}].link"),
                        format!("'{}' is on the fixed root, which moves nothing", b.link),
                    ));
                }
                None => {
                    return Err(SettingError::new(
                        format!("bodies[{i}].link"),
                        format!("'{}' is not a link of {}", b.link, model.source.display()),
                    ));
                }
            }
        }
        for (i, j) in self.joints.iter().enumerate() {
            if !model.joints.iter().any(|m| m.name == j.joint) {
                return Err(SettingError::new(
                    format!("joints[{i}].joint"),
                    format!(
                        "'{}' is not a movable joint of {} ({})",
                        j.joint,
                        model.source.display(),
                        model
                            .joints
                            .iter()
                            .map(|m| m.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The estimators' model of run `seed`: `truth` with the drawn errors (one fixed-order
    /// stream per seed: per moving body its mass, three principal-moment and three
    /// centre-of-mass draws, then per joint its damping and friction draws, each a standard
    /// normal truncated at [`TRUNCATION`]), the mass scale and the given errors. Names are
    /// checked beforehand ([`Self::check_names`]); an unknown one is skipped here.
    pub fn erred(&self, truth: &ArmModel, seed: u64) -> ArmModel {
        let mut model = truth.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(MODEL_STREAM);
        let on = if self.draws() { 1.0 } else { 0.0 };
        let mut draw = || {
            let z: f64 = StandardNormal.sample(&mut rng);
            on * z.clamp(-TRUNCATION, TRUNCATION)
        };
        let scales: Vec<f64> = (0..model.bodies.len())
            .map(|b| length_scale(truth, b))
            .collect();
        for (body, scale) in model.bodies.iter_mut().zip(&scales).skip(1) {
            let zm = draw();
            let zi = [draw(), draw(), draw()];
            let zc = [draw(), draw(), draw()];
            body.mass *= (self.mass * zm).exp() * self.mass_scale;
            body.inertia = perturbed_inertia(&body.inertia, self.inertia, zi) * self.mass_scale;
            for (c, z) in body.com.iter_mut().zip(zc) {
                *c += self.com * scale * z;
            }
        }
        for joint in &mut model.joints {
            let (zd, zf) = (draw(), draw());
            joint.damping *= (self.damping * zd).exp();
            joint.friction *= (self.friction * zf).exp();
        }
        for b in &self.bodies {
            let Some(body) = model.link(&b.link).map(|l| l.body) else {
                continue;
            };
            let spec = &mut model.bodies[body];
            spec.mass *= b.mass;
            spec.inertia *= b.inertia;
            for (c, d) in spec.com.iter_mut().zip(b.com) {
                *c += d;
            }
        }
        for j in &self.joints {
            if let Some(joint) = model.joints.iter_mut().find(|m| m.name == j.joint) {
                joint.damping *= j.damping;
                joint.friction = joint.friction * j.friction + j.friction_offset;
            }
        }
        model
    }

    /// What an estimator with this model may assume about its accuracy: the drawn sizes (none
    /// for a model that is not drawn).
    pub fn uncertainty(&self) -> ModelUncertainty {
        if self.draws() {
            ModelUncertainty {
                mass: self.mass,
                inertia: self.inertia,
                com: self.com,
                damping: self.damping,
                friction: self.friction,
                inertial_budget: self.inertial_budget,
            }
        } else {
            ModelUncertainty::default()
        }
    }

    /// One line for tables and reports.
    pub fn describe(&self) -> String {
        if self.is_perfect() {
            return "perfect (the plant's own)".into();
        }
        let mut parts = Vec::new();
        if self.draws() {
            parts.push(format!(
                "drawn per run seed (log-normal, 1 sigma, truncated at {TRUNCATION}): mass {}, \
                 principal inertias {}, centre of mass {} of the link's length, damping {}, \
                 Coulomb friction {}",
                self.mass, self.inertia, self.com, self.damping, self.friction
            ));
        }
        if self.mass_scale != 1.0 {
            parts.push(format!("masses x {}", self.mass_scale));
        }
        if !self.bodies.is_empty() || !self.joints.is_empty() {
            parts.push(format!(
                "given errors on {} bodies and {} joints",
                self.bodies.len(),
                self.joints.len()
            ));
        }
        parts.join("; ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn panda() -> ArmModel {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_7dof.urdf");
        crate::arm::load_urdf(&path).unwrap()
    }

    #[test]
    fn a_perfect_model_is_the_truth_and_a_drawn_one_is_reproducible_per_seed() {
        let truth = panda();
        let perfect = ModelConfig::perfect().erred(&truth, 3);
        for (a, b) in perfect.bodies.iter().zip(&truth.bodies) {
            assert_eq!((a.mass, a.com, a.inertia), (b.mass, b.com, b.inertia));
        }
        let config = ModelConfig::default();
        let a = config.erred(&truth, 7);
        let b = config.erred(&truth, 7);
        let c = config.erred(&truth, 8);
        for ((x, y), z) in a.bodies.iter().zip(&b.bodies).zip(&c.bodies).skip(1) {
            assert_eq!((x.mass, x.com, x.inertia), (y.mass, y.com, y.inertia));
            assert_ne!(x.mass, z.mass);
        }
        assert_eq!(
            a.bodies[0].mass, truth.bodies[0].mass,
            "the root is not drawn"
        );
    }

    /// Over many seeds the logarithms of the drawn mass factors have the configured spread (the
    /// truncated normal's standard deviation, 0.9866 sigma at 3 sigma) and mean 0, and no factor
    /// leaves the truncation.
    #[test]
    fn drawn_errors_have_the_configured_spread() {
        let truth = panda();
        let config = ModelConfig::default();
        let (mut sum, mut sum2, mut n) = (0.0, 0.0, 0.0);
        for seed in 0..2000 {
            let m = config.erred(&truth, seed);
            for (e, t) in m.bodies.iter().zip(&truth.bodies).skip(1) {
                let f = (e.mass / t.mass).ln();
                assert!(f.abs() <= config.mass * TRUNCATION + 1e-12);
                sum += f;
                sum2 += f * f;
                n += 1.0;
            }
        }
        let mean = sum / n;
        let sd = (sum2 / n - mean * mean).sqrt();
        let want = config.mass * 0.9866;
        assert!(mean.abs() < 4.0 * config.mass / n.sqrt(), "{mean}");
        assert!((sd / want - 1.0).abs() < 0.05, "{sd} against {want}");
    }

    #[test]
    fn given_errors_apply_exactly_and_unknown_names_are_refused() {
        let truth = panda();
        let config = ModelConfig {
            bodies: vec![BodyError {
                link: "panda_link3".into(),
                mass: 1.5,
                inertia: 0.5,
                com: [0.01, 0.0, -0.02],
            }],
            joints: vec![JointError {
                joint: "panda_joint2".into(),
                damping: 0.0,
                friction: 1.0,
                friction_offset: 0.7,
            }],
            ..ModelConfig::perfect()
        };
        config.check_names(&truth).unwrap();
        let m = config.erred(&truth, 1);
        let b = truth.link("panda_link3").unwrap().body;
        assert_eq!(m.bodies[b].mass, 1.5 * truth.bodies[b].mass);
        assert_eq!(m.bodies[b].inertia, truth.bodies[b].inertia * 0.5);
        // A drawn inertia stays physical: positive and within the triangle inequality.
        for seed in 0..200 {
            for body in ModelConfig::default()
                .erred(&truth, seed)
                .bodies
                .iter()
                .skip(1)
            {
                let mut e: Vec<f64> = body
                    .inertia
                    .symmetric_eigenvalues()
                    .iter()
                    .copied()
                    .collect();
                e.sort_by(f64::total_cmp);
                assert!(e[0] > 0.0 && e[0] + e[1] >= e[2] * (1.0 - 1e-9), "{e:?}");
            }
        }
        assert_eq!(m.bodies[b].com.x, truth.bodies[b].com.x + 0.01);
        assert_eq!(m.joints[1].damping, 0.0);
        assert_eq!(
            m.joints[1].friction, 0.7,
            "friction the plant does not have"
        );
        let bad = ModelConfig {
            joints: vec![JointError {
                joint: "elbow".into(),
                damping: 1.0,
                friction: 1.0,
                friction_offset: 0.0,
            }],
            ..ModelConfig::perfect()
        };
        let e = bad.check_names(&truth).unwrap_err();
        assert_eq!(e.field, "joints[0].joint");
    }
}
