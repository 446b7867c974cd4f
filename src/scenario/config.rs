//! Scenario files (TOML): what to simulate, with every default in one place and one `validate`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Method, ScenarioError};
use crate::control::{ControlConfig, PidGains};
use crate::estimation::uaic::{Prediction, UaicConfig, UpdateScheme};
use crate::precision::{DetectorConfig, DetectorTest, Isolation, PrecisionBounds};
use crate::sensors::{CameraConfig, ChannelLayout, FaultSpec, SensorConfig};

/// A scenario: the arm, its start and targets, sensors, camera, GP, controller, precision
/// method, detector and faults, duration, tick and seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name (used for output folders).
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Run length (s).
    pub duration: f64,
    /// Control tick and physics step (s).
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Seed of the sensor noise (the GP has its own).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Ticks between trajectory rows (1: every tick).
    #[serde(default = "default_record_every")]
    pub record_every: u64,
    pub robot: RobotConfig,
    /// The simulated arm's engine and its settings.
    #[serde(default)]
    pub plant: crate::plant::PlantSettings,
    pub initial: InitialState,
    /// Set points: from `time` on, the target is `q`.
    pub targets: Vec<Target>,
    #[serde(default)]
    pub sensors: SensorConfig,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub gp: GpConfig,
    #[serde(default)]
    pub controller: ControllerConfig,
    #[serde(default)]
    pub precision: PrecisionConfig,
    #[serde(default)]
    pub detector: DetectorSettings,
    /// Settings of the Kalman-filter baselines (`ekf-gate`, `vb-akf`, `imm`).
    #[serde(default)]
    pub kalman: crate::estimation::kalman::KalmanConfig,
    /// Settings of `hybrid`.
    #[serde(default)]
    pub hybrid: crate::estimation::hybrid::HybridConfig,
    #[serde(default)]
    pub faults: Vec<FaultSpec>,
}

/// Longest run, in ticks: 1e9 (about 11.6 days of simulated time at 1 kHz, hours of wall time).
/// A run's memory does not grow with its length; its trajectory file does, by
/// [`MAX_TRAJECTORY_BYTES`].
pub const MAX_TICKS: u64 = 1_000_000_000;

/// Largest trajectory file a run may be set up to write (estimated at 24 bytes per value):
/// 4 GiB. Longer runs record every k-th tick (`record_every`).
pub const MAX_TRAJECTORY_BYTES: u64 = 4 << 30;

/// Most targets and most faults in one scenario.
pub const MAX_TARGETS: usize = 10_000;
pub const MAX_FAULTS: usize = 1_000;

fn default_record_every() -> u64 {
    1
}

fn default_dt() -> f64 {
    1e-3
}

fn default_seed() -> u64 {
    1
}

/// The arm: which URDF, where its end effector is, the world's gravity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// URDF path, relative to the scenario file.
    pub urdf: PathBuf,
    #[serde(default = "default_ee")]
    pub ee_link: String,
    #[serde(default)]
    pub ee_offset: [f64; 3],
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    /// Repair inertias that break the triangle inequality (see [`crate::arm::UrdfOptions`]).
    #[serde(default)]
    pub balance_inertia: bool,
}

impl RobotConfig {
    /// How the URDF is read.
    pub fn urdf_options(&self) -> crate::arm::UrdfOptions {
        crate::arm::UrdfOptions {
            balance_inertia: self.balance_inertia,
        }
    }
}

fn default_ee() -> String {
    "ee".into()
}

fn default_gravity() -> [f64; 3] {
    [0.0, 0.0, -9.81]
}

/// The arm's state at t = 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct InitialState {
    pub q: Vec<f64>,
    /// Zeros when absent.
    #[serde(default)]
    pub qd: Option<Vec<f64>>,
}

/// A set point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Target {
    pub time: f64,
    pub q: Vec<f64>,
}

/// The camera GP: how to get it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct GpConfig {
    /// Training points.
    pub points: usize,
    /// Joint-space training box [lower, upper] per joint; default: the start and the targets
    /// widened by `margin`.
    pub training_box: Option<Vec<[f64; 2]>>,
    /// Margin (rad) around the start and targets when the box is derived.
    pub margin: f64,
    /// Seed of the training set (independent of the run seed: every run shares the GP).
    pub seed: u64,
    /// A saved model to load instead of training (relative to the scenario file).
    pub model: Option<PathBuf>,
    /// Hyperparameter-fit restarts.
    pub restarts: usize,
}

impl Default for GpConfig {
    fn default() -> Self {
        Self {
            points: 200,
            training_box: None,
            margin: 0.3,
            seed: 7,
            model: None,
            restarts: 3,
        }
    }
}

/// The `[controller]` section: the u-AIC's belief ([`UaicConfig`]) and the control stage
/// ([`ControlConfig`]) in one table, as users write it. Defaults are those two structs'.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ControllerConfig {
    pub update: UpdateScheme,
    /// Gauss-Newton step length eta in (0, 1].
    pub step: f64,
    /// Gradient-descent gain kappa_mu (1/s), used by `update = "gradient"`.
    pub kappa_mu: f64,
    pub prediction: Prediction,
    /// The joint acceleration (rad/s^2) the state prior treats as one standard deviation: the
    /// prior precisions default to P_mu = 1 / (a dt^2 / 2)^2 and P_mu' = 1 / (a dt)^2
    /// (docs/method.md, "Prior scale"). 200 gives P_mu = 1e8 and P_mu' = 25 at dt = 1 ms.
    pub acceleration_bound: f64,
    /// Precision of the position prior P_mu (1/rad^2); absent: from `acceleration_bound`.
    pub prior_position_precision: Option<f64>,
    /// Precision of the velocity prior P_mu' (s^2/rad^2); absent: from `acceleration_bound`.
    pub prior_velocity_precision: Option<f64>,
    /// Ticks over which the prior's precisions ramp up (0: no ramp).
    pub prior_warmup_ticks: u64,
    /// `fixed` (P_mu, P_mu') or `propagated` (a Kalman filter's prior precision, its process
    /// noise from `acceleration_bound`). Every u-AIC method but `hybrid`, which takes
    /// `hybrid.prior`.
    pub prior: crate::estimation::uaic::PriorMode,
    /// Finite action gain kappa_u (1/s); absent: u = f* (the authors' kappa_u -> infinity).
    pub kappa_u: Option<f64>,
    /// Control precision P_u, used with a finite kappa_u.
    pub control_precision: f64,
    pub gains: PidGains,
}

/// The default acceleration bound of the state prior (rad/s^2).
pub const DEFAULT_ACCELERATION_BOUND: f64 = 200.0;

impl Default for ControllerConfig {
    fn default() -> Self {
        let b = UaicConfig::default();
        let c = ControlConfig::default();
        Self {
            update: b.update,
            step: b.step,
            kappa_mu: b.kappa_mu,
            prediction: b.prediction,
            acceleration_bound: DEFAULT_ACCELERATION_BOUND,
            prior_position_precision: None,
            prior_velocity_precision: None,
            prior_warmup_ticks: b.prior_warmup_ticks,
            prior: b.prior,
            kappa_u: c.kappa_u,
            control_precision: c.control_precision,
            gains: c.gains,
        }
    }
}

impl ControllerConfig {
    /// The state prior's precisions (P_mu, P_mu') at tick `dt`: as given, else from the
    /// acceleration bound a: P_mu = 1 / (a dt^2 / 2)^2, P_mu' = 1 / (a dt)^2.
    pub fn prior_precisions(&self, dt: f64) -> (f64, f64) {
        let a = self.acceleration_bound;
        (
            self.prior_position_precision
                .unwrap_or_else(|| 1.0 / (0.5 * a * dt * dt).powi(2)),
            self.prior_velocity_precision
                .unwrap_or_else(|| 1.0 / (a * dt).powi(2)),
        )
    }

    /// The u-AIC's belief settings at tick `dt`.
    pub fn uaic(&self, dt: f64) -> UaicConfig {
        let (pm, pv) = self.prior_precisions(dt);
        UaicConfig {
            update: self.update,
            step: self.step,
            kappa_mu: self.kappa_mu,
            prediction: self.prediction,
            prior_position_precision: pm,
            prior_velocity_precision: pv,
            prior_warmup_ticks: self.prior_warmup_ticks,
            prior: self.prior,
            process_acceleration: self.acceleration_bound,
        }
    }

    /// The control stage's settings.
    pub fn control(&self) -> ControlConfig {
        ControlConfig {
            gains: self.gains.clone(),
            kappa_u: self.kappa_u,
            control_precision: self.control_precision,
        }
    }

    /// Checks both parts for an arm of `n_joints` at tick `dt`; returns the offending field and
    /// why.
    pub fn validate(&self, n_joints: usize, dt: f64) -> Result<(), (String, String)> {
        let a = self.acceleration_bound;
        if !(a.is_finite() && a > 0.0 && a <= 1e9) {
            return Err((
                "acceleration_bound".into(),
                format!("{a} must be finite, > 0 and <= 1e9 rad/s^2"),
            ));
        }
        self.uaic(dt).validate()?;
        self.control().validate(n_joints)
    }
}

/// The precision method and its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PrecisionConfig {
    pub method: Method,
    /// Gradient step kappa_zeta (1/s) of `pl-always` and `pl-detect`.
    pub kappa_zeta: f64,
    /// Add the posterior-variance correction c_i to the squared residuals.
    pub correction: bool,
    /// Forgetting factor rho of `bayes`.
    pub rho: f64,
    /// Window length k (ticks) of `window`.
    pub window: usize,
    /// Lower clamp of every learner, as a multiple of the nominal precision.
    pub min_ratio: f64,
    /// Upper clamp of every learner, as a multiple of the nominal precision.
    pub max_ratio: f64,
    /// Nominal precision per channel (enc.., tach.., cam_u, cam_v), overriding the physical
    /// 1/sigma^2: e.g. all 1, the "tuning units" of the authors' code.
    pub nominal: Option<Vec<f64>>,
}

impl PrecisionConfig {
    /// The learners' clamp.
    pub fn bounds(&self) -> PrecisionBounds {
        PrecisionBounds {
            min_ratio: self.min_ratio,
            max_ratio: self.max_ratio,
        }
    }
}

impl Default for PrecisionConfig {
    fn default() -> Self {
        Self {
            method: Method::PlAlways,
            kappa_zeta: 10.0,
            correction: true,
            rho: 0.999,
            window: 100,
            min_ratio: PrecisionBounds::default().min_ratio,
            max_ratio: PrecisionBounds::default().max_ratio,
            nominal: None,
        }
    }
}

/// Detector settings plus an optional calibration file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorSettings {
    /// Chebyshev false-alarm bound: alarm when d_M > sqrt(n / alpha).
    pub alpha: f64,
    /// `channel` (largest normalised residual) or `group` (the ECC recovery).
    pub isolation: Isolation,
    /// Half-width (ticks) of the window the per-step moments are pooled over.
    pub pool_ticks: usize,
    /// Healthy runs for an on-the-fly calibration.
    pub calibration_runs: usize,
    /// Quiet ticks before an isolated channel is re-admitted (0: never).
    pub rearm_ticks: u64,
    /// `chebyshev` (per-tick bound, the ECC paper's) or `cusum` (accumulates slow faults).
    pub test: DetectorTest,
    /// CUSUM drift allowance k (healthy standard deviations per tick).
    pub cusum_drift: f64,
    /// CUSUM alarm threshold h (healthy standard deviations).
    pub cusum_threshold: f64,
    /// A calibration file (relative to the scenario file); default: calibrate on the fly.
    pub calibration: Option<PathBuf>,
}

impl Default for DetectorSettings {
    fn default() -> Self {
        let d = DetectorConfig::default();
        Self {
            alpha: d.alpha,
            isolation: d.isolation,
            pool_ticks: d.pool_ticks,
            calibration_runs: d.calibration_runs,
            rearm_ticks: d.rearm_ticks,
            test: d.test,
            cusum_drift: d.cusum_drift,
            cusum_threshold: d.cusum_threshold,
            calibration: None,
        }
    }
}

impl DetectorSettings {
    /// The detector's configuration.
    pub fn config(&self) -> DetectorConfig {
        DetectorConfig {
            alpha: self.alpha,
            isolation: self.isolation,
            pool_ticks: self.pool_ticks,
            calibration_runs: self.calibration_runs,
            rearm_ticks: self.rearm_ticks,
            test: self.test,
            cusum_drift: self.cusum_drift,
            cusum_threshold: self.cusum_threshold,
        }
    }
}

impl Scenario {
    /// Number of ticks: round(duration / dt).
    pub fn ticks(&self) -> u64 {
        (self.duration / self.dt).round() as u64
    }

    /// The target in force at time t.
    pub fn target_at(&self, t: f64) -> &[f64] {
        let mut current = &self.targets[0].q;
        for target in &self.targets {
            if target.time <= t + 1e-9 {
                current = &target.q;
            }
        }
        current
    }

    /// Checks everything against the arm's channel layout; errors name `file` and the key.
    pub fn validate(&self, layout: &ChannelLayout, file: &Path) -> Result<(), ScenarioError> {
        let n_joints = layout.n_joints();
        let bad = |field: &str, message: String| ScenarioError::Invalid {
            path: file.to_path_buf(),
            field: field.to_string(),
            message,
        };
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(field, format!("{v} must be finite and > 0")))
            }
        };
        let finite_vec = |field: &str, v: &[f64], len: usize| {
            if v.len() != len {
                return Err(bad(
                    field,
                    format!("has {} values; the arm has {len} joints", v.len()),
                ));
            }
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(bad(field, "values must be finite".into()))
            }
        };
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
        {
            return Err(bad(
                "name",
                "must be non-empty letters, digits, '_', '-' or '.'".into(),
            ));
        }
        positive("dt", self.dt)?;
        positive("duration", self.duration)?;
        if self.dt > 0.1 {
            return Err(bad("dt", "must be <= 0.1 s".into()));
        }
        if self.dt < 1e-6 {
            return Err(bad("dt", "must be >= 1e-6 s".into()));
        }
        if self.ticks() == 0 {
            return Err(bad(
                "duration",
                format!(
                    "{} s is shorter than one tick (dt = {} s)",
                    self.duration, self.dt
                ),
            ));
        }
        if self.duration / self.dt > MAX_TICKS as f64 {
            return Err(bad(
                "duration",
                format!(
                    "{} ticks at dt = {}; at most {MAX_TICKS}",
                    self.duration / self.dt,
                    self.dt
                ),
            ));
        }
        if self.record_every == 0 || self.record_every > self.ticks() {
            return Err(bad(
                "record_every",
                format!("must be in 1..={} (the run's ticks)", self.ticks()),
            ));
        }
        let columns = super::trajectory::TrajectorySchema::new(layout).len() as u64;
        let rows = self.ticks() / self.record_every + 1;
        if rows.saturating_mul(columns).saturating_mul(24) > MAX_TRAJECTORY_BYTES {
            return Err(bad(
                "record_every",
                format!(
                    "{rows} trajectory rows of {columns} columns would exceed {} GiB; record every {} ticks or more",
                    MAX_TRAJECTORY_BYTES >> 30,
                    (self.ticks() * columns * 24).div_ceil(MAX_TRAJECTORY_BYTES)
                ),
            ));
        }
        if !self.robot.ee_offset.iter().all(|v| v.is_finite()) {
            return Err(bad("robot.ee_offset", "values must be finite".into()));
        }
        if !self.robot.gravity.iter().all(|v| v.is_finite()) {
            return Err(bad("robot.gravity", "values must be finite".into()));
        }
        self.plant
            .validate()
            .map_err(|e| bad(&format!("plant.{}", e.field), e.message))?;
        finite_vec("initial.q", &self.initial.q, n_joints)?;
        if let Some(qd) = &self.initial.qd {
            finite_vec("initial.qd", qd, n_joints)?;
        }
        if self.targets.is_empty() {
            return Err(bad("targets", "at least one target is needed".into()));
        }
        if self.targets.len() > MAX_TARGETS {
            return Err(bad("targets", format!("at most {MAX_TARGETS}")));
        }
        let mut last = f64::NEG_INFINITY;
        for (i, t) in self.targets.iter().enumerate() {
            let field = format!("targets[{i}]");
            finite_vec(&format!("{field}.q"), &t.q, n_joints)?;
            if !t.time.is_finite() || t.time < 0.0 {
                return Err(bad(
                    &format!("{field}.time"),
                    "must be finite and >= 0".into(),
                ));
            }
            if t.time < last {
                return Err(bad(
                    &format!("{field}.time"),
                    "targets must be in time order".into(),
                ));
            }
            last = t.time;
        }
        self.sensors
            .validate()
            .map_err(|(f, m)| bad(&format!("sensors.{f}"), m))?;
        self.camera
            .validate()
            .map_err(|(f, m)| bad(&format!("camera.{f}"), m))?;
        let gp = &self.gp;
        if gp.model.is_none() {
            if gp.points < 2 * n_joints + 2 {
                return Err(bad(
                    "gp.points",
                    format!("must be >= {} for {n_joints} joints", 2 * n_joints + 2),
                ));
            }
            if gp.points > 5000 {
                return Err(bad("gp.points", "more than 5000 is refused".into()));
            }
            if !(gp.margin.is_finite() && gp.margin >= 0.0) {
                return Err(bad("gp.margin", "must be finite and >= 0".into()));
            }
            if let Some(b) = &gp.training_box {
                if b.len() != n_joints {
                    return Err(bad(
                        "gp.training_box",
                        format!("has {} rows; the arm has {n_joints} joints", b.len()),
                    ));
                }
                if !b
                    .iter()
                    .all(|[lo, hi]| lo.is_finite() && hi.is_finite() && lo < hi)
                {
                    return Err(bad(
                        "gp.training_box",
                        "each row must be [lower, upper] with lower < upper".into(),
                    ));
                }
            }
            if gp.restarts == 0 {
                return Err(bad("gp.restarts", "must be >= 1".into()));
            }
        }
        self.controller
            .validate(n_joints, self.dt)
            .map_err(|(f, m)| bad(&format!("controller.{f}"), m))?;
        let p = &self.precision;
        positive("precision.kappa_zeta", p.kappa_zeta)?;
        if !(p.rho > 0.0 && p.rho < 1.0) {
            return Err(bad("precision.rho", "must be in (0, 1)".into()));
        }
        if p.window == 0 || p.window as u64 > self.ticks().max(1) {
            return Err(bad(
                "precision.window",
                format!("must be in 1..={} (the run's ticks)", self.ticks().max(1)),
            ));
        }
        let b = p.bounds();
        if !(b.min_ratio.is_finite() && b.min_ratio > 0.0) {
            return Err(bad("precision.min_ratio", "must be finite and > 0".into()));
        }
        if !(b.max_ratio.is_finite() && b.max_ratio >= b.min_ratio) {
            return Err(bad(
                "precision.max_ratio",
                "must be finite and >= min_ratio".into(),
            ));
        }
        if let Some(nominal) = &p.nominal {
            if nominal.len() != layout.len() {
                return Err(bad(
                    "precision.nominal",
                    format!(
                        "has {} values; the arm has {} channels ({})",
                        nominal.len(),
                        layout.len(),
                        layout.names().join(", ")
                    ),
                ));
            }
            if !nominal.iter().all(|w| w.is_finite() && *w > 0.0) {
                return Err(bad(
                    "precision.nominal",
                    "values must be finite and > 0".into(),
                ));
            }
        }
        self.detector
            .config()
            .validate()
            .map_err(|(f, m)| bad(&format!("detector.{f}"), m))?;
        self.kalman
            .validate()
            .map_err(|(f, m)| bad(&format!("kalman.{f}"), m))?;
        self.hybrid
            .validate()
            .map_err(|(f, m)| bad(&format!("hybrid.{f}"), m))?;
        if self.hybrid.prior.may_propagate() && self.controller.update != UpdateScheme::GaussNewton
        {
            return Err(bad(
                "hybrid.prior",
                format!(
                    "\"{}\" uses the propagated prior, which needs controller.update = \"gauss-newton\"",
                    self.hybrid.prior.name()
                ),
            ));
        }
        if self.faults.len() > MAX_FAULTS {
            return Err(bad("faults", format!("at most {MAX_FAULTS}")));
        }
        for (i, f) in self.faults.iter().enumerate() {
            f.to_fault(layout)
                .map_err(|(field, m)| bad(&format!("faults[{i}].{field}"), m))?;
        }
        Ok(())
    }
}
