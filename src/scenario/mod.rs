//! Scenarios: files in, runs and tables out.
//!
//! [`config`] is the TOML schema (every default in one place, one `validate`); this module loads
//! scenarios (from a file, or the embedded default), applies `--set KEY=VALUE` overrides, and
//! prepares what every run of a scenario shares ([`RunSetup`]: the arm model, the GP, the
//! faults). [`runner`] runs one (method, seed); [`calibrate`] makes the detector's healthy
//! statistics; [`table`] runs every method over many seeds.

pub mod bench;
pub mod calibrate;
pub mod config;
mod method;
pub mod runner;
pub mod table;

use std::path::{Path, PathBuf};
use std::sync::Arc;

pub use config::{GpConfig, MAX_TICKS, PrecisionConfig, RobotConfig, Scenario, Target};
pub use method::Method;
pub use runner::{NoObserver, Observer, Outcome, RunResult, TickRecord, TrajectoryRecorder, run};

use crate::gp::{self, GpError, GpModel};
use crate::plant::{self, ArmModel, ArmOptions, PlantError};
use crate::sensors::{Camera, Fault};

/// Errors of the scenario stage; each names the file and the key.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    #[error("{path}: cannot read the scenario")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
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
    Plant(#[from] PlantError),
    #[error("{path}: the camera GP")]
    Gp {
        path: PathBuf,
        #[source]
        source: GpError,
    },
    #[error("{path}: {message}")]
    Calibration { path: PathBuf, message: String },
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
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let scenario = parse_scenario(&text, path, overrides)?;
        Ok(Self {
            scenario,
            path: path.to_path_buf(),
            base_dir: Some(
                path.parent()
                    .map(Path::to_path_buf)
                    .unwrap_or_else(|| PathBuf::from(".")),
            ),
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

    /// Reads a file the scenario names (URDF, GP model, calibration) relative to it.
    pub fn read_relative(&self, relative: &Path) -> Result<(PathBuf, String), std::io::Error> {
        match &self.base_dir {
            Some(dir) => {
                let full = dir.join(relative);
                let text = std::fs::read_to_string(&full)?;
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
                    .ok_or_else(|| {
                        std::io::Error::new(
                            std::io::ErrorKind::NotFound,
                            format!("{key} is not embedded; use a scenario file"),
                        )
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
            .read_relative(&self.scenario.robot.urdf)
            .map_err(|source| PlantError::Unreadable {
                path: self.resolve(&self.scenario.robot.urdf),
                source,
            })?;
        Ok(plant::parse_urdf(&text, &path)?)
    }
}

/// Parses scenario TOML text with overrides applied.
pub fn parse_scenario(
    text: &str,
    path: &Path,
    overrides: &[String],
) -> Result<Scenario, ScenarioError> {
    let parse_error = |message: String| ScenarioError::Parse {
        path: path.to_path_buf(),
        message,
    };
    if overrides.is_empty() {
        // Straight from the text: errors carry the line and column.
        return toml::from_str(text).map_err(|e: toml::de::Error| parse_error(e.to_string()));
    }
    let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
    for item in overrides {
        apply_override(&mut table, item)?;
    }
    let scenario: Scenario = table
        .try_into()
        .map_err(|e: toml::de::Error| parse_error(e.to_string()))?;
    Ok(scenario)
}

/// Applies one `KEY=VALUE` to the TOML table. VALUE is read as TOML (`3`, `[1, 2]`, `true`,
/// `"text"`), falling back to a bare string.
fn apply_override(table: &mut toml::Table, item: &str) -> Result<(), ScenarioError> {
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
                return Ok(());
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
                    return Ok(());
                }
                current = element
                    .as_table_mut()
                    .ok_or_else(|| err(format!("`{name}[{idx}]` is not a table")))?;
            }
        }
    }
    Ok(())
}

/// What every run of a scenario shares: the validated scenario, arm model, GP and faults.
#[derive(Clone)]
pub struct RunSetup {
    pub loaded: LoadedScenario,
    pub model: Arc<ArmModel>,
    pub gp: Arc<GpModel>,
    pub faults: Vec<Fault>,
    /// How the GP was obtained, for reports.
    pub gp_source: GpSource,
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
        sc.validate(n, &loaded.path)?;
        if model.link(&sc.robot.ee_link).is_none() {
            return Err(model.unknown_link_error(&sc.robot.ee_link).into());
        }
        let faults = sc
            .faults
            .iter()
            .map(|f| f.to_fault(n).expect("validated"))
            .collect();
        let (gp, gp_source) = match &sc.gp.model {
            Some(rel) => {
                let path = loaded.resolve(rel);
                let gp = GpModel::load(&path).map_err(|source| ScenarioError::Gp {
                    path: loaded.path.clone(),
                    source,
                })?;
                if gp.n_inputs != n || gp.n_outputs != 2 {
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
        Ok(Self {
            model: Arc::new(model),
            gp: Arc::new(gp),
            faults,
            gp_source,
            loaded,
        })
    }

    pub fn scenario(&self) -> &Scenario {
        &self.loaded.scenario
    }

    /// Arm options from the scenario.
    pub fn arm_options(&self) -> ArmOptions {
        self.scenario().robot.arm_options()
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

/// Trains the scenario's GP with `points` training points (its own seed).
pub fn train_gp(
    loaded: &LoadedScenario,
    model: &ArmModel,
    points: usize,
) -> Result<(GpModel, gp::FitReport), ScenarioError> {
    let sc = &loaded.scenario;
    let mut arm = plant::Arm::new(model.clone(), sc.robot.arm_options())?;
    let camera = Camera::new(sc.camera.clone());
    let bounds = training_box(sc);
    let set = gp::sample_training_set(&mut arm, &camera, &bounds, points, sc.gp.seed);
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

/// A fingerprint of everything that shapes a healthy run's innovations: the scenario without its
/// faults, seed and learner settings (the nominal precisions kept), the URDF's text and the camera
/// GP itself (FNV-1a 64 of the canonical text: a label, not a security hash).
pub fn fingerprint(setup: &RunSetup) -> String {
    let mut s = setup.scenario().clone();
    s.faults.clear();
    s.seed = 0;
    s.precision = PrecisionConfig {
        nominal: s.precision.nominal.clone(),
        ..PrecisionConfig::default()
    };
    s.detector.calibration = None;
    s.detector.calibration_runs = 0;
    s.name = String::new();
    s.description = String::new();
    // Where files live does not change a run; what they hold is hashed below.
    s.robot.urdf = PathBuf::new();
    s.gp = GpConfig::default();
    let urdf = setup
        .loaded
        .read_relative(&setup.scenario().robot.urdf)
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
