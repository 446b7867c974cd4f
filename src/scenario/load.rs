//! Loading scenarios: from a file or the embedded default, with layers of scenario keys (a
//! campaign's `[defaults]` and an arm's `overrides`) and `--set KEY=VALUE` overrides on top;
//! errors name the file and the key, and the layer or override that set it.

use std::path::{Path, PathBuf};

use super::{Scenario, ScenarioError};
use crate::arm::{self, ArmModel};
use crate::fsio::{self, FsError};

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
        Self::from_file_layered(path, &[], overrides)
    }

    /// Reads a scenario file, merges the layers of scenario keys over it in order (a
    /// campaign's `[defaults]`, an arm's `overrides`), then applies the overrides.
    pub fn from_file_layered(
        path: &Path,
        layers: &[Layer],
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        let text = fsio::read_text(path, fsio::MAX_SCENARIO_BYTES)?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let scenario = parse_scenario_layered(&text, path, layers, overrides)?;
        Ok(Self {
            scenario,
            path: path.to_path_buf(),
            base_dir: Some(base),
        })
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

/// Scenario keys from another file laid over a scenario: a campaign's `[defaults]` or an arm's
/// `overrides` table, typed by the scenario's own schema when merged.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// The file the table is in.
    pub file: PathBuf,
    /// Where in that file (`defaults`, `arms[2].overrides`).
    pub key: String,
    pub table: toml::Table,
}

/// Merges `layer` into `table`: tables key by key, anything else replaced.
fn merge(table: &mut toml::Table, layer: &toml::Table) {
    for (k, v) in layer {
        match (table.get_mut(k), v) {
            (Some(toml::Value::Table(t)), toml::Value::Table(l)) => merge(t, l),
            _ => {
                table.insert(k.clone(), v.clone());
            }
        }
    }
}

/// Every leaf key a table sets, in path form (`plant.engine`).
fn leaf_keys(table: &toml::Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in table {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            toml::Value::Table(t) if !t.is_empty() => leaf_keys(t, &key, out),
            _ => out.push(key),
        }
    }
}

/// A check's error about a key one of `layers` set (the last that set it: `defaults.KEY` or
/// `arms[i].overrides.KEY` of a campaign file) is moved onto that layer's file and key, the
/// template named after it; any other error is returned as it is.
pub(crate) fn blame_layer(
    error: ScenarioError,
    layers: &[Layer],
    template: &Path,
) -> ScenarioError {
    let ScenarioError::Invalid { field, message, .. } = &error else {
        return error;
    };
    let blamed = layers.iter().rev().find(|layer| {
        let mut set = Vec::new();
        leaf_keys(&layer.table, "", &mut set);
        set.iter().any(|k| about(field, k) || about(k, field))
    });
    match blamed {
        Some(layer) => ScenarioError::Invalid {
            path: layer.file.clone(),
            field: format!("{}.{field}", layer.key),
            message: format!("{message} (over {})", template.display()),
        },
        None => error,
    }
}

/// Whether error key `key` is about `set` (the key itself, or inside it).
fn about(key: &str, set: &str) -> bool {
    key == set || key.starts_with(&format!("{set}.")) || key.starts_with(&format!("{set}["))
}

/// Parses scenario TOML text with overrides applied. Errors name the key (`faults[0].start`),
/// and say when its value came from an override.
pub fn parse_scenario(
    text: &str,
    path: &Path,
    overrides: &[String],
) -> Result<Scenario, ScenarioError> {
    parse_scenario_layered(text, path, &[], overrides)
}

/// Parses scenario TOML text with layers merged over it and overrides applied. An error names
/// the key and where its value came from: an override (`--set KEY`), a layer (its file and
/// `defaults.KEY`), or the text.
pub fn parse_scenario_layered(
    text: &str,
    path: &Path,
    layers: &[Layer],
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
    if overrides.is_empty() && layers.is_empty() {
        // Straight from the text: errors carry the line and column.
        let de = toml::Deserializer::parse(text).map_err(|e| parse_error(e.to_string()))?;
        return serde_path_to_error::deserialize(de)
            .map_err(|e| parse_error(keyed(e.path().to_string(), e.into_inner().to_string())));
    }
    let mut table: toml::Table = toml::from_str(text).map_err(|e| parse_error(e.to_string()))?;
    let mut layered: Vec<(String, &Layer)> = Vec::new();
    for layer in layers {
        merge(&mut table, &layer.table);
        let mut set = Vec::new();
        leaf_keys(&layer.table, "", &mut set);
        layered.extend(set.into_iter().map(|k| (k, layer)));
    }
    let mut keys = Vec::new();
    for item in overrides {
        keys.push(apply_override(&mut table, item)?);
    }
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        let key = e.path().to_string();
        let message = e.into_inner().to_string();
        // The key the error is about, or a table above it (an unknown field is reported at
        // the table that does not have it: `--set nosuch.key=1` fails at `nosuch`).
        let touches = |k: &str| about(&key, k) || (!key.is_empty() && about(k, &key));
        if let Some((_, layer)) = layered.iter().rev().find(|(k, _)| touches(k))
            && !keys.iter().any(|k| touches(k))
        {
            return ScenarioError::Parse {
                path: layer.file.clone(),
                message: format!(
                    "`{}.{key}`: {}{} (over {})",
                    layer.key,
                    message.trim_end(),
                    moved_key_hint(&key, &message),
                    path.display()
                ),
            };
        }
        match keys.iter().zip(overrides).rev().find(|(k, _)| touches(k)) {
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
    ("controller", "update", "belief.update"),
    ("controller", "step", "belief.step"),
    ("controller", "kappa_mu", "belief.kappa_mu"),
    ("controller", "prediction", "belief.prediction"),
    (
        "controller",
        "acceleration_bound",
        "belief.acceleration_bound",
    ),
    (
        "controller",
        "prior_position_precision",
        "belief.prior_position_precision",
    ),
    (
        "controller",
        "prior_velocity_precision",
        "belief.prior_velocity_precision",
    ),
    (
        "controller",
        "prior_warmup_ticks",
        "belief.prior_warmup_ticks",
    ),
    ("controller", "prior", "belief.prior"),
    ("kalman", "mass_scale", "model.mass_scale"),
    (
        "kalman",
        "model_acceleration_noise",
        "model.acceleration_noise",
    ),
    ("kalman", "model_relative_error", "model.relative_error"),
    ("hybrid", "mass_scale", "model.mass_scale"),
    (
        "hybrid",
        "model_acceleration_noise",
        "model.acceleration_noise",
    ),
    ("hybrid", "model_relative_error", "model.relative_error"),
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
