//! Scenario files (TOML): what to simulate, with every default in one place and one `validate`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Method, ScenarioError};
use crate::SettingError;
use crate::arm::ModelConfig;
use crate::control::ControlConfig;
use crate::estimation::uaic::{UaicConfig, UpdateScheme};
use crate::precision::{DetectorConfig, PrecisionBounds};
use crate::sensors::{CameraConfig, ChannelLayout, FaultSpec, SensorConfig};

/// A scenario: the arm, its start and targets, sensors, camera, GP, controller, precision
/// method, detector and faults, duration, tick and seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name (used for output folders).
    pub name: String,
    /// Free text shown in reports.
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
    #[schemars(range(min = 1))]
    pub record_every: u64,
    /// The arm: URDF, end effector, gravity.
    pub robot: RobotConfig,
    /// The simulated arm's engine and its settings.
    #[serde(default)]
    pub plant: crate::plant::PlantSettings,
    /// The arm model the estimators that carry one are given: the URDF with errors (drawn per
    /// run by default), and how much they trust it.
    #[serde(default)]
    pub model: ModelConfig,
    /// The arm's state at t = 0.
    pub initial: InitialState,
    /// Set points: from `time` on, the target is `q`.
    pub targets: Vec<Target>,
    /// Noise of the joint sensors.
    #[serde(default)]
    pub sensors: SensorConfig,
    /// The virtual camera: pose, distortion, noise, occlusion.
    #[serde(default)]
    pub camera: CameraConfig,
    /// The camera's Gaussian-process model.
    #[serde(default)]
    pub gp: GpConfig,
    /// The u-AIC's belief: its update, prediction and state prior.
    #[serde(default)]
    pub belief: UaicConfig,
    /// The control law f* and the action.
    #[serde(default)]
    pub controller: ControlConfig,
    /// The precision method (`no-ft`, `pl-always`, `hybrid`, ...) and its parameters.
    #[serde(default)]
    pub precision: PrecisionConfig,
    /// The fault detector of `pl-detect` and `deterministic`.
    #[serde(default)]
    pub detector: DetectorConfig,
    /// Settings of the Kalman-filter baselines (`ekf-gate`, `vb-akf`, `imm`).
    #[serde(default)]
    pub kalman: crate::estimation::kalman::KalmanConfig,
    /// Settings of `hybrid`.
    #[serde(default)]
    pub hybrid: crate::estimation::hybrid::HybridConfig,
    /// The generalized momentum observer, run beside any method (actuator faults, contacts).
    #[serde(default)]
    pub momentum: crate::precision::MomentumConfig,
    /// Sensor faults, any number, overlapping or not.
    #[serde(default)]
    pub faults: Vec<FaultSpec>,
    /// Actuator faults (between the commanded torque and the joint), any number.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actuator_faults: Vec<crate::plant::ActuatorFaultSpec>,
    /// Disturbances that are not faults (a payload, a push), any number.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disturbances: Vec<crate::plant::DisturbanceSpec>,
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
    /// The end-effector link (the point the camera sees).
    #[serde(default = "default_ee")]
    pub ee_link: String,
    /// Offset (m) of the seen point from the end-effector link's origin, in that link's frame.
    #[serde(default)]
    pub ee_offset: [f64; 3],
    /// Gravity in the world frame (m/s^2).
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
    /// Joint positions (rad or m), one per joint.
    pub q: Vec<f64>,
    /// Zeros when absent.
    #[serde(default)]
    pub qd: Option<Vec<f64>>,
}

/// The target of a schedule in force at time t: the last whose time is at or before t (the
/// first from the start, whatever its time; the runner's rule, `Simulation::decide`).
pub fn target_in_force(targets: &[Target], t: f64) -> &[f64] {
    let mut current = &targets[0].q;
    for target in targets {
        if target.time <= t + 1e-9 {
            current = &target.q;
        }
    }
    current
}

/// A set point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Time (s) from which this target holds.
    pub time: f64,
    /// Joint positions, one per joint.
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
    /// Hyperparameter-fit restarts (each is one fit from a new start).
    #[schemars(range(min = 1, max = 100))]
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

impl GpConfig {
    /// Checks the training settings for an arm of `n_joints` (a saved model needs none).
    pub fn validate(&self, n_joints: usize) -> Result<(), SettingError> {
        if self.model.is_some() {
            return Ok(());
        }
        if self.points < 2 * n_joints + 2 {
            return Err(SettingError::new(
                "points",
                format!("must be >= {} for {n_joints} joints", 2 * n_joints + 2),
            ));
        }
        if self.points > 5000 {
            return Err(SettingError::new("points", "more than 5000 is refused"));
        }
        if !(self.margin.is_finite() && self.margin >= 0.0) {
            return Err(SettingError::new("margin", "must be finite and >= 0"));
        }
        if let Some(b) = &self.training_box {
            if b.len() != n_joints {
                return Err(SettingError::new(
                    "training_box",
                    format!("has {} rows; the arm has {n_joints} joints", b.len()),
                ));
            }
            if !b
                .iter()
                .all(|[lo, hi]| lo.is_finite() && hi.is_finite() && lo < hi)
            {
                return Err(SettingError::new(
                    "training_box",
                    "each row must be [lower, upper] with lower < upper",
                ));
            }
        }
        if !(1..=100).contains(&self.restarts) {
            return Err(SettingError::new("restarts", "must be in 1..=100"));
        }
        Ok(())
    }
}

/// The precision method and its parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PrecisionConfig {
    /// The fault-tolerance method (see the values below).
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
    /// 1/sigma^2: e.g. all 1, the "tuning units" of the authors' code. 0 leaves a channel out of
    /// the belief (an absent sensor: the authors' MATLAB benchmark has no camera); only with the
    /// fixed-precision methods `no-ft` and `oracle`.
    pub nominal: Option<Vec<f64>>,
}

impl PrecisionConfig {
    /// Checks the learners' settings for the channels of `layout` and a run of `ticks` ticks.
    pub fn validate(&self, layout: &ChannelLayout, ticks: u64) -> Result<(), SettingError> {
        if !(self.kappa_zeta.is_finite() && self.kappa_zeta > 0.0) {
            return Err(SettingError::new(
                "kappa_zeta",
                format!("{} must be finite and > 0", self.kappa_zeta),
            ));
        }
        if !(self.rho > 0.0 && self.rho < 1.0) {
            return Err(SettingError::new("rho", "must be in (0, 1)"));
        }
        if self.window == 0 || self.window as u64 > ticks.max(1) {
            return Err(SettingError::new(
                "window",
                format!("must be in 1..={} (the run's ticks)", ticks.max(1)),
            ));
        }
        let b = self.bounds();
        if !(b.min_ratio.is_finite() && b.min_ratio > 0.0) {
            return Err(SettingError::new("min_ratio", "must be finite and > 0"));
        }
        if !(b.max_ratio.is_finite() && b.max_ratio >= b.min_ratio) {
            return Err(SettingError::new(
                "max_ratio",
                "must be finite and >= min_ratio",
            ));
        }
        if let Some(nominal) = &self.nominal {
            if nominal.len() != layout.len() {
                return Err(SettingError::new(
                    "nominal",
                    format!(
                        "has {} values; the arm has {} channels ({})",
                        nominal.len(),
                        layout.len(),
                        layout.names().join(", ")
                    ),
                ));
            }
            if !nominal.iter().all(|w| w.is_finite() && *w >= 0.0) {
                return Err(SettingError::new(
                    "nominal",
                    "values must be finite and >= 0",
                ));
            }
            if nominal.contains(&0.0) && !matches!(self.method, Method::NoFt | Method::Oracle) {
                return Err(SettingError::new(
                    "nominal",
                    format!(
                        "a 0 (a channel left out, an absent sensor) needs method \"no-ft\" or \
                         \"oracle\"; the method is \"{}\"",
                        self.method.info().name
                    ),
                ));
            }
        }
        Ok(())
    }

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

impl Scenario {
    /// Number of ticks: round(duration / dt).
    pub fn ticks(&self) -> u64 {
        (self.duration / self.dt).round() as u64
    }

    /// The target in force at time t.
    pub fn target_at(&self, t: f64) -> &[f64] {
        target_in_force(&self.targets, t)
    }

    /// Checks everything against the arm's channel layout; errors name `file` and the key.
    /// Each component checks its own settings ([`SettingError`], its key under its section).
    pub fn validate(&self, layout: &ChannelLayout, file: &Path) -> Result<(), ScenarioError> {
        self.check(layout).map_err(|e| ScenarioError::Invalid {
            path: file.to_path_buf(),
            field: e.field,
            message: e.message,
        })
    }

    fn check(&self, layout: &ChannelLayout) -> Result<(), SettingError> {
        let n = layout.n_joints();
        self.check_run(layout)?;
        self.check_task(n)?;
        let within = |section: &'static str| move |e: SettingError| e.within(section);
        self.plant.validate().map_err(within("plant"))?;
        self.model.validate().map_err(within("model"))?;
        self.sensors.validate().map_err(within("sensors"))?;
        self.camera.validate().map_err(within("camera"))?;
        self.gp.validate(n).map_err(within("gp"))?;
        self.belief.validate(self.dt).map_err(within("belief"))?;
        self.controller.validate(n).map_err(within("controller"))?;
        self.precision
            .validate(layout, self.ticks())
            .map_err(within("precision"))?;
        self.detector.validate().map_err(within("detector"))?;
        self.kalman.validate().map_err(within("kalman"))?;
        self.hybrid.validate().map_err(within("hybrid"))?;
        self.momentum.validate().map_err(within("momentum"))?;
        let hybrid_prior = self.hybrid.prior_mode(self.belief.update);
        if hybrid_prior.may_propagate() && self.belief.update != UpdateScheme::GaussNewton {
            return Err(SettingError::new(
                "hybrid.prior",
                format!(
                    "\"{}\" uses the propagated prior, which needs belief.update = \"gauss-newton\"",
                    hybrid_prior.name()
                ),
            ));
        }
        if self.faults.len() > MAX_FAULTS {
            return Err(SettingError::new("faults", format!("at most {MAX_FAULTS}")));
        }
        let mut delay_readings = 0u64;
        for (i, f) in self.faults.iter().enumerate() {
            let fault = f
                .to_fault(layout, self.dt)
                .map_err(|e| e.within(&format!("faults[{i}]")))?;
            delay_readings = delay_readings.saturating_add(fault.delay_readings(self.dt));
        }
        if delay_readings > crate::sensors::faults::MAX_DELAY_READINGS {
            return Err(SettingError::new(
                "faults",
                format!(
                    "the delayed faults keep {delay_readings} readings (delay ticks x channels); \
                     at most {}",
                    crate::sensors::faults::MAX_DELAY_READINGS
                ),
            ));
        }
        if self.actuator_faults.len() > MAX_FAULTS {
            return Err(SettingError::new(
                "actuator_faults",
                format!("at most {MAX_FAULTS}"),
            ));
        }
        if self.disturbances.len() > MAX_FAULTS {
            return Err(SettingError::new(
                "disturbances",
                format!("at most {MAX_FAULTS}"),
            ));
        }
        for (i, f) in self.actuator_faults.iter().enumerate() {
            f.to_fault(layout.n_joints(), self.dt)
                .map_err(|e| e.within(&format!("actuator_faults[{i}]")))?;
        }
        Ok(())
    }

    /// Name, tick, length and recording.
    fn check_run(&self, layout: &ChannelLayout) -> Result<(), SettingError> {
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
        {
            return Err(SettingError::new(
                "name",
                "must be non-empty letters, digits, '_', '-' or '.'",
            ));
        }
        for (field, v) in [("dt", self.dt), ("duration", self.duration)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SettingError::new(
                    field,
                    format!("{v} must be finite and > 0"),
                ));
            }
        }
        if self.dt > 0.1 {
            return Err(SettingError::new("dt", "must be <= 0.1 s"));
        }
        if self.dt < 1e-6 {
            return Err(SettingError::new("dt", "must be >= 1e-6 s"));
        }
        if self.ticks() == 0 {
            return Err(SettingError::new(
                "duration",
                format!(
                    "{} s is shorter than one tick (dt = {} s)",
                    self.duration, self.dt
                ),
            ));
        }
        if self.duration / self.dt > MAX_TICKS as f64 {
            return Err(SettingError::new(
                "duration",
                format!(
                    "{} ticks at dt = {}; at most {MAX_TICKS}",
                    self.duration / self.dt,
                    self.dt
                ),
            ));
        }
        if self.record_every == 0 || self.record_every > self.ticks() {
            return Err(SettingError::new(
                "record_every",
                format!("must be in 1..={} (the run's ticks)", self.ticks()),
            ));
        }
        let columns = super::trajectory::TrajectorySchema::new(layout).len() as u64;
        let rows = self.ticks() / self.record_every + 1;
        if rows.saturating_mul(columns).saturating_mul(24) > MAX_TRAJECTORY_BYTES {
            return Err(SettingError::new(
                "record_every",
                format!(
                    "{rows} trajectory rows of {columns} columns would exceed {} GiB; record every {} ticks or more",
                    MAX_TRAJECTORY_BYTES >> 30,
                    (self.ticks() * columns * 24).div_ceil(MAX_TRAJECTORY_BYTES)
                ),
            ));
        }
        Ok(())
    }

    /// The arm's end effector and gravity, the start and the targets.
    fn check_task(&self, n_joints: usize) -> Result<(), SettingError> {
        let finite_vec = |field: &str, v: &[f64], len: usize| {
            if v.len() != len {
                return Err(SettingError::new(
                    field,
                    format!("has {} values; the arm has {len} joints", v.len()),
                ));
            }
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(SettingError::new(field, "values must be finite"))
            }
        };
        if !self.robot.ee_offset.iter().all(|v| v.is_finite()) {
            return Err(SettingError::new(
                "robot.ee_offset",
                "values must be finite",
            ));
        }
        if !self.robot.gravity.iter().all(|v| v.is_finite()) {
            return Err(SettingError::new("robot.gravity", "values must be finite"));
        }
        finite_vec("initial.q", &self.initial.q, n_joints)?;
        if let Some(qd) = &self.initial.qd {
            finite_vec("initial.qd", qd, n_joints)?;
        }
        if self.targets.is_empty() {
            return Err(SettingError::new(
                "targets",
                "at least one target is needed",
            ));
        }
        if self.targets.len() > MAX_TARGETS {
            return Err(SettingError::new(
                "targets",
                format!("at most {MAX_TARGETS}"),
            ));
        }
        let mut last = f64::NEG_INFINITY;
        for (i, t) in self.targets.iter().enumerate() {
            let field = format!("targets[{i}]");
            finite_vec(&format!("{field}.q"), &t.q, n_joints)?;
            if !t.time.is_finite() || t.time < 0.0 {
                return Err(SettingError::new(
                    format!("{field}.time"),
                    "must be finite and >= 0",
                ));
            }
            if t.time < last {
                return Err(SettingError::new(
                    format!("{field}.time"),
                    "targets must be in time order",
                ));
            }
            last = t.time;
        }
        Ok(())
    }
}
