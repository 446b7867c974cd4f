//! The campaign file: its arms, fault kinds and onsets, verdict thresholds and the reaching
//! benchmark's settings, and its loading.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::fsio;
use crate::scenario::{Method, ScenarioError};
use crate::sensors::{FaultKind, FaultSpec};

fn default_seeds() -> usize {
    10
}

fn yes() -> bool {
    true
}

/// When a cell's outcome counts as recovered, degraded or failed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VerdictConfig {
    /// Recovered: every joint's final error within this (rad).
    pub tolerance: f64,
    /// Degraded: within this (rad); beyond it, or a runaway, failed.
    pub degraded: f64,
    /// Runaway: a joint this far (rad) from its target at the end, or at a joint limit.
    pub runaway: f64,
}

impl Default for VerdictConfig {
    fn default() -> Self {
        Self {
            tolerance: 0.02,
            degraded: 0.1,
            runaway: 1.0,
        }
    }
}

/// When faults start.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OnsetConfig {
    /// Fault start of `moving` cells (s).
    pub moving: f64,
    /// Fault start of `rest` and `rest-then-motion` cells (s).
    pub rest: f64,
}

impl Default for OnsetConfig {
    fn default() -> Self {
        Self {
            moving: 8.0,
            rest: 5.0,
        }
    }
}

/// When a fault starts relative to the task's motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Onset {
    Moving,
    Rest,
    RestThenMotion,
}

impl Onset {
    /// Every onset, in the order of the file's documentation.
    pub const ALL: [Onset; 3] = [Onset::Moving, Onset::Rest, Onset::RestThenMotion];

    pub fn name(self) -> &'static str {
        match self {
            Self::Moving => "moving",
            Self::Rest => "rest",
            Self::RestThenMotion => "rest-then-motion",
        }
    }
}

fn moving_only() -> Vec<Onset> {
    vec![Onset::Moving]
}

/// A size per sensor group (encoder rad, tachometer rad/s, camera m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupSizes {
    pub enc: f64,
    pub tach: f64,
    pub cam: f64,
}

impl GroupSizes {
    fn for_channel(&self, channel: &str) -> f64 {
        if channel.starts_with("enc") {
            self.enc
        } else if channel.starts_with("tach") {
            self.tach
        } else {
            self.cam
        }
    }
}

/// A fault kind of the grid, with its parameters (per sensor group where they have units) and
/// the onsets it is run at.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum CampaignKind {
    Freeze {
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Bias {
        offset: GroupSizes,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Drift {
        rate: GroupSizes,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Gain {
        factor: f64,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Noise {
        factor: f64,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Dropout {
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Stuck {
        value: GroupSizes,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Spikes {
        probability: f64,
        magnitude: GroupSizes,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Delayed {
        delay: f64,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Slow {
        period: f64,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Intermittent {
        period: f64,
        duty: f64,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
    Garbage {
        low: GroupSizes,
        high: GroupSizes,
        #[serde(default = "moving_only")]
        onsets: Vec<Onset>,
    },
}

impl CampaignKind {
    pub(super) fn onsets(&self) -> &[Onset] {
        match self {
            Self::Freeze { onsets }
            | Self::Bias { onsets, .. }
            | Self::Drift { onsets, .. }
            | Self::Gain { onsets, .. }
            | Self::Noise { onsets, .. }
            | Self::Dropout { onsets }
            | Self::Stuck { onsets, .. }
            | Self::Spikes { onsets, .. }
            | Self::Delayed { onsets, .. }
            | Self::Slow { onsets, .. }
            | Self::Intermittent { onsets, .. }
            | Self::Garbage { onsets, .. } => onsets,
        }
    }

    /// The scenario fault kind for a channel.
    pub(super) fn fault_kind(&self, channel: &str) -> FaultKind {
        match self {
            Self::Freeze { .. } => FaultKind::Freeze {},
            Self::Bias { offset, .. } => FaultKind::Bias {
                offset: offset.for_channel(channel),
            },
            Self::Drift { rate, .. } => FaultKind::Drift {
                rate: rate.for_channel(channel),
            },
            Self::Gain { factor, .. } => FaultKind::Gain { factor: *factor },
            Self::Noise { factor, .. } => FaultKind::Noise { factor: *factor },
            Self::Dropout { .. } => FaultKind::Dropout {},
            Self::Stuck { value, .. } => FaultKind::Stuck {
                value: value.for_channel(channel),
            },
            Self::Spikes {
                probability,
                magnitude,
                ..
            } => FaultKind::Spikes {
                probability: *probability,
                magnitude: magnitude.for_channel(channel),
            },
            Self::Delayed { delay, .. } => FaultKind::Delayed { delay: *delay },
            Self::Slow { period, .. } => FaultKind::Slow { period: *period },
            Self::Intermittent { period, duty, .. } => FaultKind::Intermittent {
                period: *period,
                duty: *duty,
            },
            Self::Garbage { low, high, .. } => FaultKind::Garbage {
                low: low.for_channel(channel),
                high: high.for_channel(channel),
            },
        }
    }
}

/// An arm of the campaign: a scenario template and the joints whose sensors fail.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmEntry {
    /// Short name (used in tables).
    pub name: String,
    /// A healthy scenario (relative to the campaign file); its faults are replaced.
    pub scenario: PathBuf,
    /// Joints (1-based) that `enc*` and `tach*` expand to.
    #[serde(default = "first_joint")]
    pub joints: Vec<usize>,
    /// Scenario keys laid over the template (after the campaign's `[defaults]`), as a scenario
    /// file writes them (`[arms.overrides.plant] engine = "rapier"`).
    #[serde(default)]
    pub overrides: toml::Table,
}

fn first_joint() -> Vec<usize> {
    vec![1]
}

/// A two-fault cell: its faults as in a scenario file, `enc*` and `tach*` meaning the arm's first
/// listed joint.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PairEntry {
    pub label: String,
    pub faults: Vec<FaultSpec>,
}

/// A disturbance cell: its disturbances as in a scenario file, and or a table to touch (the
/// correct verdict: no fault).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisturbanceEntry {
    pub label: String,
    #[serde(default)]
    pub disturbances: Vec<crate::plant::DisturbanceSpec>,
    /// An obstacle on the end effector's path to its last target, placed per arm (the cell runs
    /// on rapier).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact: Option<ContactEntry>,
}

/// An obstacle on the path, placed per arm: a fixed box square to the end effector's motion
/// from the target before the last to the last (d, the unit vector from the first position to
/// the second), its near face `depth` before the last target's position along d and centred on
/// that line, so that the arm, moving to that target, runs into it and rests against it short of
/// the target: a table when the motion goes down, a wall when it goes sideways
/// (docs/campaigns.md, "Contact cells"). Contact needs rapier: the cell runs on it whatever the
/// campaign's engine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ContactEntry {
    /// How far (m) before the last target's end effector position the obstacle's face lies,
    /// along the motion, in (0, 0.5] (and at least 1 cm short of the whole motion).
    #[serde(default = "default_contact_depth")]
    pub depth: f64,
    /// The box's full extents (m, each in (0, 10]): across the motion (x, y) and along it (z).
    #[serde(default = "default_table_size")]
    pub size: [f64; 3],
    /// Coulomb friction coefficient of its contacts (>= 0, at most 10).
    #[serde(default = "default_table_friction")]
    pub friction: f64,
}

fn default_contact_depth() -> f64 {
    0.03
}

fn default_table_size() -> [f64; 3] {
    [0.3, 0.3, 0.05]
}

fn default_table_friction() -> f64 {
    0.5
}

impl ContactEntry {
    /// Its obstacle for an end effector moving from `from` to `to` (world frame, m); None when
    /// the motion is not longer than `depth` + 1 cm (the face would not lie between them).
    pub fn obstacle(&self, from: [f64; 3], to: [f64; 3]) -> Option<crate::plant::Obstacle> {
        use nalgebra::{UnitQuaternion, Vector3};
        let (a, b) = (Vector3::from(from), Vector3::from(to));
        let length = (b - a).norm();
        if length.is_nan() || length <= self.depth + 0.01 {
            return None;
        }
        let d = (b - a) / length;
        // The box's local z along d: its face at b - depth d, its centre half its thickness on.
        let centre = b + d * (self.size[2] / 2.0 - self.depth);
        let rotation = UnitQuaternion::rotation_between(&Vector3::z(), &d).unwrap_or_else(|| {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
        let (roll, pitch, yaw) = rotation.euler_angles();
        Some(crate::plant::Obstacle {
            shape: crate::plant::ObstacleShape::Box,
            size: self.size.to_vec(),
            position: vec![centre.x, centre.y, centre.z],
            rpy: vec![roll, pitch, yaw],
            friction: self.friction,
        })
    }

    /// Checks its own fields; the message names the offending one.
    pub fn check(&self) -> Result<(), String> {
        if !(self.depth > 0.0 && self.depth <= 0.5) {
            return Err(format!("depth {} must be in (0, 0.5] m", self.depth));
        }
        if !self.size.iter().all(|s| *s > 0.0 && *s <= 10.0) {
            return Err(format!("size {:?}: each extent in (0, 10] m", self.size));
        }
        if !(self.friction >= 0.0 && self.friction <= 10.0) {
            return Err(format!("friction {} must be in [0, 10]", self.friction));
        }
        Ok(())
    }
}

fn is_moving_only(onsets: &[Onset]) -> bool {
    onsets == [Onset::Moving]
}

/// How the reaching benchmark measures a task (docs/campaigns.md, "The healthy reaching
/// benchmark").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReachingProtocol {
    /// aift's: every joint (largest overshoot, settling of all joints into their bands, largest
    /// final error), belief RMSE pooled at the same tick.
    #[default]
    Aift,
    /// The authors' (`matlab/statistical_analysis.m`): MATLAB `stepinfo` overshoot and settling
    /// time (0.5 % band) on one joint, mean final error over joints, and the mean over joints of
    /// the RMS of q(i) - mu(i), mu(i) the belief before reading q(i).
    Authors,
}

/// The healthy reaching benchmark.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReachingConfig {
    /// Reaching tasks per arm.
    pub tasks: usize,
    /// Length of each task (s).
    pub duration: f64,
    /// Seed of the targets (the runs use seed 1).
    pub seed: u64,
    /// Healthy runs of the detector's calibration, per task.
    pub calibration_runs: usize,
    /// Which metrics: `aift` (default) or `authors`.
    pub protocol: ReachingProtocol,
    /// The joint (1-based) whose step response the `authors` protocol measures.
    pub step_joint: usize,
    /// Targets uniform in [lo, hi] rad on every joint (the authors': [-1.57, 1.57]) instead of
    /// the camera model's training box.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_range: Option<Vec<f64>>,
    /// A file of targets, one per line (comma-separated radians, one per joint; `#` comments),
    /// relative to the campaign file: the first `tasks` lines are the tasks of every arm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub targets_file: Option<PathBuf>,
}

impl Default for ReachingConfig {
    fn default() -> Self {
        Self {
            tasks: 100,
            duration: 6.0,
            seed: 1,
            calibration_runs: 10,
            protocol: ReachingProtocol::Aift,
            step_joint: 1,
            target_range: None,
            targets_file: None,
        }
    }
}

/// Most bytes of a reaching targets file.
pub const MAX_TARGETS_FILE_BYTES: u64 = 16 << 20;

/// Reads a reaching targets file: one target per non-empty line, comma-separated finite radians,
/// as many on every line; `#` starts a comment. Returns the first `tasks` targets (the caller
/// checks their length against each arm's joints). Errors name the file, the key
/// (`reaching.targets_file`) and the line.
pub fn read_reaching_targets(
    file: &Path,
    campaign: &Path,
    tasks: usize,
) -> Result<Vec<Vec<f64>>, ScenarioError> {
    let bad = |message: String| ScenarioError::Invalid {
        path: campaign.to_path_buf(),
        field: "reaching.targets_file".into(),
        message: format!("{}: {message}", file.display()),
    };
    if file.as_os_str().is_empty() || campaign.parent().is_some_and(|p| p.join("") == file) {
        return Err(bad("names no file".into()));
    }
    let text = fsio::read_text(file, MAX_TARGETS_FILE_BYTES).map_err(|e| bad(e.to_string()))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut targets = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let values: Vec<&str> = line.split(',').map(str::trim).collect();
        if let Some(first) = targets.first().map(Vec::len)
            && values.len() != first
        {
            return Err(bad(format!(
                "line {}: {} values; the first target has {first}",
                i + 1,
                values.len()
            )));
        }
        if values.len() > 1000 {
            return Err(bad(format!("line {}: more than 1000 joints", i + 1)));
        }
        let mut target = Vec::with_capacity(values.len());
        for v in values {
            match v.parse::<f64>() {
                Ok(x) if x.is_finite() && x.abs() <= 1e6 => target.push(x),
                _ => {
                    return Err(bad(format!(
                        "line {}: {v:?} is not a finite angle (|x| <= 1e6 rad)",
                        i + 1
                    )));
                }
            }
        }
        targets.push(target);
        if targets.len() == tasks {
            break;
        }
    }
    if targets.len() < tasks {
        return Err(bad(format!(
            "holds {} targets; `reaching.tasks` is {tasks}",
            targets.len()
        )));
    }
    Ok(targets)
}

/// A campaign file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignConfig {
    pub name: String,
    #[serde(default)]
    pub description: String,
    #[serde(default = "default_seeds")]
    pub seeds: usize,
    /// The sensor-noise seed of every cell's first run; the k-th run uses `first_seed + k`
    /// (an evaluation campaign's seeds kept apart from the development campaign's 1, 2, ...).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub first_seed: u64,
    /// Methods (default: every method; none when `external_methods` lists some).
    #[serde(default)]
    pub methods: Option<Vec<Method>>,
    /// Methods the caller supplies by name (Python classes given to `aift.campaign`, Rust
    /// [`crate::scenario::method::ExternalMethod`]s), run after `methods`. Not written by hand:
    /// the library sets it, and the records keep it so that `aift merge` and `aift report` show
    /// those methods; `aift campaign` cannot run a file that lists any.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub external_methods: Vec<String>,
    #[serde(default)]
    pub verdict: VerdictConfig,
    #[serde(default)]
    pub onsets: OnsetConfig,
    /// Scenario keys laid over every arm's template (before the arm's own `overrides`), as a
    /// scenario file writes them: `[defaults] duration = 15.0`, `[defaults.plant] engine =
    /// "articulated"`. Typed by the scenario's schema when merged; errors name this file and
    /// `defaults.KEY`.
    #[serde(default)]
    pub defaults: toml::Table,
    pub arms: Vec<ArmEntry>,
    /// Fault channels: `enc*` and `tach*` (each of the arm's joints), `cam` (every camera
    /// output), or any scenario selector (`enc2`, `cam_u`).
    #[serde(default = "default_channels")]
    pub channels: Vec<String>,
    #[serde(default)]
    pub kinds: Vec<CampaignKind>,
    #[serde(default)]
    pub pairs: Vec<PairEntry>,
    /// Actuator fault kinds (as a scenario's `[[actuator_faults]]` writes them, without joint
    /// and times), each on every listed joint of each arm.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actuator_kinds: Vec<crate::plant::ActuatorFaultKind>,
    /// When the actuator faults start (default `["moving"]`).
    #[serde(default = "moving_only", skip_serializing_if = "is_moving_only")]
    pub actuator_onsets: Vec<Onset>,
    /// Disturbance cells (payloads, pushes): no sensor or actuator fault.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub disturbance_cells: Vec<DisturbanceEntry>,
    /// A healthy cell per arm (false alarms per hour).
    #[serde(default = "yes")]
    pub healthy: bool,
    /// The healthy reaching benchmark; absent: not run.
    #[serde(default)]
    pub reaching: Option<ReachingConfig>,
}

impl CampaignConfig {
    /// Reads a campaign file (errors name the file and the key).
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let text = fsio::read_text(path, fsio::MAX_SCENARIO_BYTES)?;
        let parse = |message: String| ScenarioError::Parse {
            path: path.to_path_buf(),
            message,
        };
        let de = toml::Deserializer::parse(&text).map_err(|e| parse(e.to_string()))?;
        serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            let message = e.into_inner().to_string();
            let hint = if message.contains("unknown field `set`") {
                "; `set = [...]` strings became tables with the scenario's own keys: `[defaults]` \
                 for every arm, `[arms.overrides]` for one"
            } else {
                ""
            };
            parse(if key == "." {
                format!("{}{hint}", message.trim_end())
            } else {
                format!("`{key}`: {}{hint}", message.trim_end())
            })
        })
    }
}

fn one() -> u64 {
    1
}

fn is_one(v: &u64) -> bool {
    *v == 1
}

fn default_channels() -> Vec<String> {
    vec!["enc*".into(), "tach*".into(), "cam".into()]
}
