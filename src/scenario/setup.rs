//! What every run of a scenario shares ([`RunSetup`]): the validated scenario, the arm model (the
//! plant's truth) and the estimators' copy of it per run, the channel layout, the camera GP and
//! the faults; the GP's training and the calibration fingerprint.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{GpConfig, LoadedScenario, Method, PrecisionConfig, Scenario, ScenarioError, runner};
use crate::arm::{ArmModel, EndEffector, Kinematics};
use crate::fsio;
use crate::gp::{self, GpError, GpModel};
use crate::plant::{self, Plant};
use crate::sensors::{Camera, ChannelLayout, Fault};

/// Targets and faults that start at or after the run's end: legitimate (a run shortened with
/// `--set duration=...`) but they never act; the metrics leave such faults out by the same test
/// ([`Fault::acts_within`]).
fn late_settings(sc: &Scenario, faults: &[Fault]) -> Vec<String> {
    let end = sc.duration;
    let mut out = Vec::new();
    for (i, t) in sc.targets.iter().enumerate() {
        if t.time >= end {
            out.push(format!(
                "`targets[{i}].time` {} s is not before the run's end ({end} s): it never acts",
                t.time
            ));
        }
    }
    for (i, f) in faults.iter().enumerate() {
        if !f.acts_within(sc.ticks(), sc.dt) {
            out.push(format!(
                "`faults[{i}].start` {} s is not before the run's end ({end} s): it never acts \
                 and is left out of the faulty joints and detections",
                f.start
            ));
        }
    }
    out
}

/// The initial state and every target inside the arm's joint limits (the physics would clamp
/// them silently and the clamp would be reported as controller error).
fn check_joint_limits(sc: &Scenario, model: &ArmModel, path: &Path) -> Result<(), ScenarioError> {
    let check = |field: String, q: &[f64]| {
        for (i, (v, joint)) in q.iter().zip(&model.joints).enumerate() {
            if let Some((lo, hi)) = joint.limits
                && !(lo - 1e-9..=hi + 1e-9).contains(v)
            {
                return Err(ScenarioError::Invalid {
                    path: path.to_path_buf(),
                    field: format!("{field}[{i}]"),
                    message: format!(
                        "{v} is outside joint {} ('{}')'s limits [{lo}, {hi}] in {}",
                        i + 1,
                        joint.name,
                        model.source.display()
                    ),
                });
            }
        }
        Ok(())
    };
    check("initial.q".into(), &sc.initial.q)?;
    for (i, t) in sc.targets.iter().enumerate() {
        check(format!("targets[{i}].q"), &t.q)?;
    }
    Ok(())
}

/// What every run of a scenario shares: the validated scenario, arm model, channel layout, GP
/// and faults.
#[derive(Clone)]
pub struct RunSetup {
    pub loaded: LoadedScenario,
    /// The arm as the plant simulates it (the truth).
    pub model: Arc<ArmModel>,
    /// The point the camera sees.
    pub ee: EndEffector,
    pub layout: ChannelLayout,
    pub gp: Arc<GpModel>,
    pub faults: Vec<Fault>,
    /// Actuator faults, checked against the arm.
    pub actuator_faults: Vec<crate::plant::ActuatorFault>,
    /// Disturbances (payloads, pushes), checked against the arm.
    pub disturbances: Vec<crate::plant::Disturbance>,
    /// The momentum observer's thresholds per joint (`[momentum] enabled`), calibrated on
    /// healthy runs when the setup is prepared ([`super::calibrate::calibrate_momentum`]).
    pub momentum_thresholds: Option<Arc<Vec<f64>>>,
    /// How the GP was obtained, for reports.
    pub gp_source: GpSource,
    /// Legitimate but odd settings (a target or fault after the run's end), for stderr.
    pub warnings: Vec<String>,
}

/// The plant and the model error a result was measured under.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Conditions {
    /// The plant's engine and settings (`articulated (euler, 2 substeps)`).
    pub plant: String,
    /// The estimators' arm model against the plant's (`perfect (the plant's own)`, or the
    /// drawn and given errors).
    pub model: String,
}

impl Conditions {
    /// One markdown line: `Plant: ... Estimators' arm model: ...`.
    pub fn markdown(&self) -> String {
        format!(
            "Plant: {}. Model-based estimators' arm model: {}.",
            self.plant, self.model
        )
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({"plant": self.plant, "model_error": self.model})
    }
}

/// Where the GP came from.
#[derive(Clone, Debug, PartialEq)]
pub enum GpSource {
    Trained {
        points: usize,
        seconds: f64,
        evaluations: usize,
    },
    Loaded(PathBuf),
}

impl RunSetup {
    /// Checks the scenario against its arm (the URDF loaded, every setting validated, the end
    /// effector, disturbances and faults resolved): everything [`Self::prepare`] refuses but
    /// the GP's model file, without the GP's fit. Commands run it before staging their output.
    pub fn check(loaded: &LoadedScenario) -> Result<(), ScenarioError> {
        checked(loaded).map(|_| ())
    }

    /// Loads the arm, validates the scenario against it, and loads or trains the GP.
    pub fn prepare(loaded: LoadedScenario) -> Result<Self, ScenarioError> {
        let checked = checked(&loaded)?;
        let (model, layout) = (checked.model, checked.layout);
        let n = model.joints.len();
        let sc = &loaded.scenario;
        let (gp, gp_source) = match &sc.gp.model {
            Some(rel) => {
                let path = loaded.resolve(rel);
                let gp = GpModel::load(&path).map_err(|source| ScenarioError::Gp {
                    path: loaded.path.clone(),
                    source,
                })?;
                if gp.n_inputs != n || gp.n_outputs != layout.camera_outputs() {
                    return Err(ScenarioError::Gp {
                        path: loaded.path.clone(),
                        source: GpError::WrongInputs {
                            path,
                            model: gp.n_inputs,
                            arm: n,
                        },
                    });
                }
                (gp, GpSource::Loaded(path))
            }
            None => {
                let start = std::time::Instant::now();
                let (gp, report) = train_gp(&loaded, &model, sc.gp.points)?;
                (
                    gp,
                    GpSource::Trained {
                        points: sc.gp.points,
                        seconds: start.elapsed().as_secs_f64(),
                        evaluations: report.evaluations,
                    },
                )
            }
        };
        let warnings = late_settings(&loaded.scenario, &checked.faults);
        let mut setup = Self {
            model: Arc::new(model),
            ee: checked.ee,
            layout,
            gp: Arc::new(gp),
            faults: checked.faults,
            actuator_faults: checked.actuator_faults,
            disturbances: checked.disturbances,
            momentum_thresholds: None,
            gp_source,
            loaded,
            warnings,
        };
        if setup.scenario().momentum.enabled {
            let thresholds = super::calibrate::calibrate_momentum(&setup)?;
            setup.momentum_thresholds = Some(Arc::new(thresholds));
        }
        Ok(setup)
    }

    /// The same setup without faults (sensor and actuator) and disturbances: what calibration
    /// and the healthy benchmarks run.
    pub fn healthy(&self) -> Self {
        let mut s = self.clone();
        s.faults.clear();
        s.actuator_faults.clear();
        s.disturbances.clear();
        s.loaded.scenario.faults.clear();
        s.loaded.scenario.actuator_faults.clear();
        s.loaded.scenario.disturbances.clear();
        s
    }

    pub fn scenario(&self) -> &Scenario {
        &self.loaded.scenario
    }

    /// Whether `method` can run this setup: a nominal precision of 0 (a channel left out) needs a
    /// fixed-precision method (`no-ft`, `oracle`). Checked before any run.
    pub fn check_method(&self, method: Method) -> Result<(), ScenarioError> {
        if self.nominal_precisions().contains(&0.0)
            && !matches!(method, Method::NoFt | Method::Oracle)
        {
            return Err(ScenarioError::Invalid {
                path: self.loaded.path.clone(),
                field: "precision.nominal".into(),
                message: format!(
                    "a 0 (a channel left out) needs method \"no-ft\" or \"oracle\"; method \
                     \"{}\" learns or gates precisions relative to the nominal ones",
                    method.info().name
                ),
            });
        }
        Ok(())
    }

    /// Nominal precision per channel: the scenario's `precision.nominal`, else 1 / sigma^2 of
    /// each channel's noise.
    pub fn nominal_precisions(&self) -> Vec<f64> {
        let sc = self.scenario();
        sc.precision.nominal.clone().unwrap_or_else(|| {
            let sigmas: Vec<f64> = self
                .layout
                .channels()
                .map(|c| match c {
                    crate::sensors::Channel::Encoder(_) => sc.sensors.encoder_sigma,
                    crate::sensors::Channel::Tachometer(_) => sc.sensors.tachometer_sigma,
                    crate::sensors::Channel::Camera(_) => sc.camera.sigma,
                })
                .collect();
            runner::nominal_precisions(&sigmas)
        })
    }

    /// The arm model the estimators of run `seed` are given: the plant's with the scenario's
    /// model error (`[model]`: drawn from the seed, given, or none). Never handed to the plant.
    pub fn estimator_model(&self, seed: u64) -> Arc<ArmModel> {
        let config = &self.scenario().model;
        if config.is_perfect() {
            self.model.clone()
        } else {
            Arc::new(config.erred(&self.model, seed))
        }
    }

    /// The conditions every result of this setup was measured under, for tables and reports:
    /// the plant (engine and settings) and the estimators' model error.
    pub fn conditions(&self) -> Conditions {
        let sc = self.scenario();
        Conditions {
            plant: sc.plant.describe(),
            model: sc.model.describe(),
        }
    }

    /// A new plant of the scenario's engine, at rest at q = 0 (the truth: the URDF's model).
    pub fn plant(&self) -> Result<Box<dyn Plant>, ScenarioError> {
        let sc = self.scenario();
        Ok(plant::build(
            self.model.clone(),
            sc.robot.gravity,
            &sc.plant,
        )?)
    }
}

/// What [`RunSetup::check`] resolves, and [`RunSetup::prepare`] keeps.
struct Checked {
    model: ArmModel,
    layout: ChannelLayout,
    ee: EndEffector,
    disturbances: Vec<crate::plant::Disturbance>,
    faults: Vec<Fault>,
    actuator_faults: Vec<crate::plant::ActuatorFault>,
}

fn checked(loaded: &LoadedScenario) -> Result<Checked, ScenarioError> {
    let model = loaded.arm_model()?;
    let n = model.joints.len();
    let sc = &loaded.scenario;
    let layout = ChannelLayout::new(n, sc.camera.model);
    // The end effector first: on a tree (not every joint moves it) no per-joint value can be
    // right, and the error says why.
    let ee = end_effector(loaded, &model)?;
    sc.validate(&layout, &loaded.path)?;
    check_joint_limits(sc, &model, &loaded.path)?;
    sc.model
        .check_names(&model)
        .map_err(|e| ScenarioError::Invalid {
            path: loaded.path.clone(),
            field: format!("model.{}", e.field),
            message: e.message,
        })?;
    let mut disturbances = Vec::with_capacity(sc.disturbances.len());
    for (i, d) in sc.disturbances.iter().enumerate() {
        disturbances.push(
            d.to_disturbance(&model)
                .map_err(|e| ScenarioError::Invalid {
                    path: loaded.path.clone(),
                    field: format!("disturbances[{i}].{}", e.field),
                    message: e.message,
                })?,
        );
    }
    let faults: Vec<Fault> = sc
        .faults
        .iter()
        .map(|f| f.to_fault(&layout, sc.dt).expect("validated"))
        .collect();
    let actuator_faults = sc
        .actuator_faults
        .iter()
        .map(|f| f.to_fault(n, sc.dt).expect("validated"))
        .collect();
    Ok(Checked {
        model,
        layout,
        ee,
        disturbances,
        faults,
        actuator_faults,
    })
}

/// The scenario's end effector on its arm (`robot.ee_link` and `robot.ee_offset`).
fn end_effector(loaded: &LoadedScenario, model: &ArmModel) -> Result<EndEffector, ScenarioError> {
    let robot = &loaded.scenario.robot;
    let ee = EndEffector::new(model, &robot.ee_link, robot.ee_offset).map_err(|e| {
        ScenarioError::Robot {
            path: loaded.path.clone(),
            field: "robot.ee_link",
            source: Box::new(e),
        }
    })?;
    // aift controls serial arms: every joint must move the end effector.
    match ee.not_serial(model, &robot.ee_link) {
        Some(message) => Err(ScenarioError::Invalid {
            path: loaded.path.clone(),
            field: "robot.ee_link".into(),
            message,
        }),
        None => Ok(ee),
    }
}

/// The GP's training box: given, or the start and targets widened by the margin.
pub fn training_box(scenario: &Scenario) -> Vec<[f64; 2]> {
    match &scenario.gp.training_box {
        Some(b) => b.clone(),
        None => {
            let mut points = vec![scenario.initial.q.clone()];
            points.extend(scenario.targets.iter().map(|t| t.q.clone()));
            gp::derive_box(&points, scenario.gp.margin)
        }
    }
}

/// What `aift train-gp` makes: the scenario's GP trained from scratch (any saved model it names
/// ignored) on `points` points (default: the scenario's), after the scenario is checked against
/// its arm; with the fit and the held-out error on 2000 fresh configurations.
pub fn train_gp_fresh(
    loaded: &LoadedScenario,
    points: Option<usize>,
) -> Result<(GpModel, gp::FitReport, gp::HeldOutError), ScenarioError> {
    let mut loaded = loaded.clone();
    loaded.scenario.gp.model = None;
    if let Some(p) = points {
        loaded.scenario.gp.points = p;
    }
    let model = loaded.arm_model()?;
    let layout = ChannelLayout::new(model.joints.len(), loaded.scenario.camera.model);
    loaded.scenario.validate(&layout, &loaded.path)?;
    let (gp, fit) = train_gp(&loaded, &model, loaded.scenario.gp.points)?;
    let ee = end_effector(&loaded, &model)?;
    let mut arm = Kinematics::new(Arc::new(model));
    let camera = Camera::new(loaded.scenario.camera.clone());
    let held = gp::evaluate_held_out(
        &gp,
        &mut arm,
        &ee,
        &camera,
        2000,
        loaded.scenario.gp.seed.wrapping_add(1),
    );
    Ok((gp, fit, held))
}

/// Trains the scenario's GP with `points` training points (its own seed).
pub fn train_gp(
    loaded: &LoadedScenario,
    model: &ArmModel,
    points: usize,
) -> Result<(GpModel, gp::FitReport), ScenarioError> {
    let sc = &loaded.scenario;
    let ee = end_effector(loaded, model)?;
    let mut arm = Kinematics::new(Arc::new(model.clone()));
    let camera = Camera::new(sc.camera.clone());
    let bounds = training_box(sc);
    let set = gp::sample_training_set(&mut arm, &ee, &camera, &bounds, points, sc.gp.seed);
    let gp_err = |source| ScenarioError::Gp {
        path: loaded.path.clone(),
        source,
    };
    if set.inputs.len() < 2 * model.joints.len() + 2 {
        return Err(gp_err(GpError::BadData(format!(
            "the camera saw only {} of {points} training configurations",
            set.inputs.len()
        ))));
    }
    set.fit(&gp::FitOptions {
        restarts: sc.gp.restarts,
        ..gp::FitOptions::default()
    })
    .map_err(gp_err)
}

/// A fingerprint of everything a calibration's data depend on: the scenario without its faults,
/// seed, learner settings (the nominal precisions kept), recording and the detector settings
/// that act only when testing (alpha, isolation, re-admission), plus the URDF's text and the
/// camera GP itself (FNV-1a 64 of the canonical text: a label, not a security hash).
pub fn fingerprint(setup: &RunSetup) -> String {
    let mut s = setup.scenario().clone();
    s.faults.clear();
    s.actuator_faults.clear();
    s.disturbances.clear();
    s.momentum = Default::default();
    s.seed = 0;
    s.record_every = 1;
    s.precision = PrecisionConfig {
        nominal: s.precision.nominal.clone(),
        ..PrecisionConfig::default()
    };
    let defaults = crate::precision::DetectorConfig::default();
    s.detector.calibration = None;
    s.detector.calibration_runs = 0;
    s.detector.alpha = defaults.alpha;
    s.detector.isolation = defaults.isolation;
    s.detector.rearm_ticks = defaults.rearm_ticks;
    s.detector.test = defaults.test;
    s.detector.cusum_drift = defaults.cusum_drift;
    s.detector.cusum_threshold = defaults.cusum_threshold;
    s.name = String::new();
    s.description = String::new();
    // Where files live does not change a run; what they hold is hashed below.
    s.robot.urdf = PathBuf::new();
    s.gp = GpConfig::default();
    let urdf = setup
        .loaded
        .read_relative(&setup.scenario().robot.urdf, fsio::MAX_URDF_BYTES)
        .map(|(_, text)| text)
        .unwrap_or_default();
    let mut hash: u64 = 0xcbf29ce484222325;
    for text in [
        toml::to_string(&s).expect("a scenario always serialises"),
        urdf,
        setup.gp.to_json(),
    ] {
        for b in text.bytes().chain(std::iter::once(0)) {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x100000001b3);
        }
    }
    format!("{hash:016x}")
}
