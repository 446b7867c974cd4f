//! Scenarios: files in, runs and tables out.
//!
//! [`config`] is the TOML schema (every default in one place, one `validate`); this module loads
//! scenarios (from a file, or the embedded default), applies `--set KEY=VALUE` overrides, and
//! prepares what every run of a scenario shares ([`RunSetup`]: the arm model, its channel
//! layout, the GP, the faults). [`runner`] steps one (method, seed) with observers;
//! [`metrics`] measures it; [`trajectory`] records it; [`calibrate`] makes the detector's
//! healthy statistics; [`table`] runs every method over many seeds.

pub mod bench;
pub mod calibrate;
pub mod campaign;
pub mod config;
pub mod init;
pub mod method;
pub mod metrics;
pub mod runner;
pub mod table;
pub mod trajectory;

use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use config::{
    ControllerConfig, GpConfig, MAX_TICKS, PrecisionConfig, RobotConfig, Scenario, Target,
};
pub use method::Method;
pub use metrics::{FaultOutcome, RunMetrics, RunResult};
pub use runner::{
    NoObserver, Observer, Observers, Outcome, Simulation, TickRecord, run, run_parts,
};
pub use trajectory::{TrajectoryColumns, TrajectoryRecorder, TrajectorySchema, TrajectoryWriter};

use crate::arm::{self, ArmError, ArmModel, EndEffector, Kinematics};
use crate::fsio::{self, FsError};
use crate::gp::{self, GpError, GpModel};
use crate::plant::{self, Plant, PlantError};
use crate::sensors::{Camera, ChannelLayout, Fault};

/// Errors of the scenario stage; each names the file and the key.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    #[error(transparent)]
    File(#[from] FsError),
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: `{field}` {message}")]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error("--set {key}: {message}")]
    Override { key: String, message: String },
    #[error(transparent)]
    Arm(#[from] ArmError),
    #[error(transparent)]
    Plant(#[from] PlantError),
    #[error("{path}: `{field}`")]
    Robot {
        path: PathBuf,
        field: &'static str,
        #[source]
        source: Box<ArmError>,
    },
    #[error("{path}: the camera GP")]
    Gp {
        path: PathBuf,
        #[source]
        source: GpError,
    },
    #[error("{path}: {message}")]
    Calibration { path: PathBuf, message: String },
}

impl ScenarioError {
    /// The override (`KEY=VALUE`) that set the key this error is about, if one did: callers
    /// put it in front of the message (`--set KEY=VALUE: ...`).
    pub fn blamed_override<'a>(&self, overrides: &'a [String]) -> Option<&'a str> {
        let field = match self {
            ScenarioError::Invalid { field, .. } => field.as_str(),
            ScenarioError::Robot { field, .. } => field,
            _ => return None,
        };
        overrides
            .iter()
            .find(|o| {
                let key = o.split_once('=').map_or(o.as_str(), |(k, _)| k.trim());
                field == key
                    || field.starts_with(&format!("{key}."))
                    || field.starts_with(&format!("{key}["))
                    || key.starts_with(&format!("{field}."))
                    || key.starts_with(&format!("{field}["))
            })
            .map(String::as_str)
    }

    /// The message as the CLI prints it (after `error: `): this error and its sources, joined
    /// by `: `, with the override that set the offending key in front.
    pub fn message(&self, overrides: &[String]) -> String {
        let chain = crate::error_chain(self);
        match self.blamed_override(overrides) {
            Some(o) => format!("--set {o}: {chain}"),
            None => chain,
        }
    }
}

/// The default scenario and its URDF, embedded so that `aift run` works from any folder.
pub const DEFAULT_SCENARIO_NAME: &str = "paper_encoder_freeze.toml";
const DEFAULT_SCENARIO: &str = include_str!("../../assets/scenarios/paper_encoder_freeze.toml");
const EMBEDDED_FILES: &[(&str, &str)] = &[(
    "../../urdf/planar_2dof.urdf",
    include_str!("../../urdf/planar_2dof.urdf"),
)];

/// A scenario with where it came from, so that relative paths resolve.
#[derive(Clone, Debug)]
pub struct LoadedScenario {
    pub scenario: Scenario,
    /// The scenario file (for messages), or `<embedded>/NAME` for the built-in default.
    pub path: PathBuf,
    /// Folder relative paths resolve against; `None` for the embedded default.
    pub base_dir: Option<PathBuf>,
}

impl LoadedScenario {
    /// Reads a scenario file and applies overrides (`KEY=VALUE`, dotted keys, `[i]` indices).
    pub fn from_file(path: &Path, overrides: &[String]) -> Result<Self, ScenarioError> {
        let text = fsio::read_text(path, fsio::MAX_SCENARIO_BYTES)?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        Self::from_text(&text, path, &base, overrides)
    }

    /// Scenario TOML text, with overrides; `label` names it in messages and relative paths
    /// resolve against `base_dir`.
    pub fn from_text(
        text: &str,
        label: &Path,
        base_dir: &Path,
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        if text.len() as u64 > fsio::MAX_SCENARIO_BYTES {
            return Err(ScenarioError::Parse {
                path: label.to_path_buf(),
                message: format!(
                    "{} bytes, more than the {} a scenario may have",
                    text.len(),
                    fsio::MAX_SCENARIO_BYTES
                ),
            });
        }
        let scenario = parse_scenario(text, label, overrides)?;
        Ok(Self {
            scenario,
            path: label.to_path_buf(),
            base_dir: Some(base_dir.to_path_buf()),
        })
    }

    /// The embedded default scenario (the paper's encoder freeze), with overrides.
    pub fn embedded_default(overrides: &[String]) -> Result<Self, ScenarioError> {
        let path = PathBuf::from("<embedded>").join(DEFAULT_SCENARIO_NAME);
        let scenario = parse_scenario(DEFAULT_SCENARIO, &path, overrides)?;
        Ok(Self {
            scenario,
            path,
            base_dir: None,
        })
    }

    /// Reads a file the scenario names (URDF, GP model, calibration) relative to it, at most
    /// `limit` bytes.
    pub fn read_relative(&self, relative: &Path, limit: u64) -> Result<(PathBuf, String), FsError> {
        match &self.base_dir {
            Some(dir) => {
                let full = dir.join(relative);
                let text = fsio::read_text(&full, limit)?;
                Ok((full, text))
            }
            None => {
                let key = relative.to_string_lossy();
                EMBEDDED_FILES
                    .iter()
                    .find(|(name, _)| *name == key)
                    .map(|(name, text)| {
                        (PathBuf::from("<embedded>").join(name), (*text).to_string())
                    })
                    .ok_or_else(|| FsError::Read {
                        path: PathBuf::from("<embedded>").join(relative),
                        source: std::io::Error::new(
                            std::io::ErrorKind::NotFound,
                            format!("{key} is not embedded; use a scenario file"),
                        ),
                    })
            }
        }
    }

    /// Resolves a path the scenario names (for files written beside it).
    pub fn resolve(&self, relative: &Path) -> PathBuf {
        match &self.base_dir {
            Some(dir) => dir.join(relative),
            None => relative.to_path_buf(),
        }
    }

    /// Loads the scenario's URDF.
    pub fn arm_model(&self) -> Result<ArmModel, ScenarioError> {
        let (path, text) = self
            .read_relative(&self.scenario.robot.urdf, fsio::MAX_URDF_BYTES)
            .map_err(|e| ScenarioError::Invalid {
                path: self.path.clone(),
                field: "robot.urdf".into(),
                message: e.to_string(),
            })?;
        arm::parse_urdf_with(&text, &path, &self.scenario.robot.urdf_options()).map_err(|e| {
            ScenarioError::Robot {
                path: self.path.clone(),
                field: "robot.urdf",
                source: Box::new(e),
            }
        })
    }
}

/// Parses scenario TOML text with overrides applied. Errors name the key (`faults[0].start`),
/// and say when its value came from an override.
pub fn parse_scenario(
    text: &str,
    path: &Path,
    overrides: &[String],
) -> Result<Scenario, ScenarioError> {
    let parse_error = |message: String| ScenarioError::Parse {
        path: path.to_path_buf(),
        message,
    };
    let keyed = |key: String, message: String| {
        let message = format!("{}{}", message.trim_end(), moved_key_hint(&key, &message));
        if key.is_empty() || key == "." {
            message
        } else {
            format!("`{key}`: {message}")
        }
    };
    if overrides.is_empty() {
        // Straight from the text: errors carry the line and column.
        let de = toml::Deserializer::parse(text).map_err(|e| parse_error(e.to_string()))?;
        return serde_path_to_error::deserialize(de)
            .map_err(|e| parse_error(keyed(e.path().to_string(), e.into_inner().to_string())));
    }
    let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
    let mut keys = Vec::new();
    for item in overrides {
        keys.push(apply_override(&mut table, item)?);
    }
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        let key = e.path().to_string();
        let message = e.into_inner().to_string();
        match keys.iter().zip(overrides).rev().find(|(k, _)| {
            key == **k || key.starts_with(&format!("{k}.")) || key.starts_with(&format!("{k}["))
        }) {
            Some((_, item)) => ScenarioError::Override {
                key: item
                    .split_once('=')
                    .map_or(item.as_str(), |(k, _)| k)
                    .trim()
                    .to_string(),
                message: format!("{} (in {})", keyed(key, message), path.display()),
            },
            None => parse_error(keyed(key, message)),
        }
    })
}

/// Keys that moved to another section, with where they went: an unknown-field error on one of
/// them says so.
const MOVED_KEYS: &[(&str, &str, &str)] = &[
    ("robot", "engine", "plant.engine"),
    ("robot", "integrator", "plant.articulated.integrator"),
    (
        "robot",
        "solver_iterations",
        "plant.rapier.solver_iterations (rapier) or plant.articulated.substeps",
    ),
];

/// `; it moved to ...` when `message` is serde's unknown-field error for a key that moved.
fn moved_key_hint(key: &str, message: &str) -> String {
    MOVED_KEYS
        .iter()
        .find(|(s, k, _)| {
            (key == format!("{s}.{k}") || key == *s)
                && message.contains(&format!("unknown field `{k}`"))
        })
        .map_or(String::new(), |(s, k, to)| {
            format!("; `{s}.{k}` moved to `{to}`")
        })
}

/// Applies one `KEY=VALUE` to the TOML table. VALUE is read as TOML (`3`, `[1, 2]`, `true`,
/// `"text"`), falling back to a bare string. Returns the key in path form (`a.b[2].c`).
fn apply_override(table: &mut toml::Table, item: &str) -> Result<String, ScenarioError> {
    let (key, value) = item
        .split_once('=')
        .ok_or_else(|| ScenarioError::Override {
            key: item.to_string(),
            message: "expected KEY=VALUE".into(),
        })?;
    let key = key.trim();
    let err = |message: String| ScenarioError::Override {
        key: key.to_string(),
        message,
    };
    let value = value.trim();
    if item.chars().any(char::is_control) {
        return Err(err(
            "contains a newline or another control character; one KEY=VALUE per --set".into(),
        ));
    }
    let parsed: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
        Ok(mut t) => t.remove("v").expect("just set"),
        Err(_) => toml::Value::String(value.to_string()),
    };
    // Path segments: `a.b[2].c` -> [("a", None), ("b", Some(2)), ("c", None)].
    let mut segments = Vec::new();
    for part in key.split('.') {
        let (name, index) = match part.split_once('[') {
            Some((name, rest)) => {
                let idx = rest
                    .strip_suffix(']')
                    .and_then(|i| i.parse::<usize>().ok())
                    .ok_or_else(|| err(format!("bad index in {part:?}")))?;
                (name, Some(idx))
            }
            None => (part, None),
        };
        if name.is_empty() {
            return Err(err("empty key segment".into()));
        }
        segments.push((name.to_string(), index));
    }
    let mut current = table;
    for (i, (name, index)) in segments.iter().enumerate() {
        let last = i + 1 == segments.len();
        match index {
            None if last => {
                current.insert(name.clone(), parsed);
                return Ok(key.to_string());
            }
            None => {
                let entry = current
                    .entry(name.clone())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()));
                current = entry
                    .as_table_mut()
                    .ok_or_else(|| err(format!("`{name}` is not a table")))?;
            }
            Some(idx) => {
                let array = current
                    .get_mut(name)
                    .and_then(toml::Value::as_array_mut)
                    .ok_or_else(|| err(format!("`{name}` is not an array in the scenario")))?;
                let len = array.len();
                let element = array
                    .get_mut(*idx)
                    .ok_or_else(|| err(format!("`{name}` has {len} entries")))?;
                if last {
                    *element = parsed;
                    return Ok(key.to_string());
                }
                current = element
                    .as_table_mut()
                    .ok_or_else(|| err(format!("`{name}[{idx}]` is not a table")))?;
            }
        }
    }
    Ok(key.to_string())
}

/// The scenario file's JSON Schema (draft 2020-12), generated from the same serde types the loader
/// uses, so editors can validate and complete scenario files (`aift schema`).
pub fn scenario_schema() -> serde_json::Value {
    serde_json::to_value(schemars::schema_for!(Scenario)).expect("a schema serialises")
}

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
    /// How the GP was obtained, for reports.
    pub gp_source: GpSource,
    /// Legitimate but odd settings (a target or fault after the run's end), for stderr.
    pub warnings: Vec<String>,
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
    /// Loads the arm, validates the scenario against it, and loads or trains the GP.
    pub fn prepare(loaded: LoadedScenario) -> Result<Self, ScenarioError> {
        let model = loaded.arm_model()?;
        let n = model.joints.len();
        let sc = &loaded.scenario;
        let layout = ChannelLayout::new(n, sc.camera.model);
        sc.validate(&layout, &loaded.path)?;
        check_joint_limits(sc, &model, &loaded.path)?;
        let ee = end_effector(&loaded, &model)?;
        let faults: Vec<Fault> = sc
            .faults
            .iter()
            .map(|f| f.to_fault(&layout).expect("validated"))
            .collect();
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
        let warnings = late_settings(&loaded.scenario, &faults);
        Ok(Self {
            model: Arc::new(model),
            ee,
            layout,
            gp: Arc::new(gp),
            faults,
            gp_source,
            loaded,
            warnings,
        })
    }

    pub fn scenario(&self) -> &Scenario {
        &self.loaded.scenario
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

    /// A new plant of the scenario's engine, at rest at q = 0.
    pub fn plant(&self) -> Result<Box<dyn Plant>, ScenarioError> {
        let sc = self.scenario();
        Ok(plant::build(
            self.model.clone(),
            sc.robot.gravity,
            &sc.plant,
        )?)
    }
}

/// The scenario's end effector on its arm (`robot.ee_link` and `robot.ee_offset`).
fn end_effector(loaded: &LoadedScenario, model: &ArmModel) -> Result<EndEffector, ScenarioError> {
    let robot = &loaded.scenario.robot;
    EndEffector::new(model, &robot.ee_link, robot.ee_offset).map_err(|e| ScenarioError::Robot {
        path: loaded.path.clone(),
        field: "robot.ee_link",
        source: Box::new(e),
    })
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
    s.seed = 0;
    s.record_every = 1;
    s.precision = PrecisionConfig {
        nominal: s.precision.nominal.clone(),
        ..PrecisionConfig::default()
    };
    let defaults = config::DetectorSettings::default();
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
