//! Fault campaigns: every fault on every channel of every arm, run by every method over the same
//! seeds, summarised as a matrix with the metrics of the fault-diagnosis literature; and the
//! healthy reaching benchmark beside it (what fault tolerance costs when nothing fails).
//!
//! A campaign file names arms (scenario templates: a healthy task whose first target is held from
//! t = 0 and whose second target comes at the switch time), fault channels, fault kinds with their
//! size per sensor group, onsets and two-fault pairs. The grid is expanded into cells
//! ([`expand`]); each cell runs every method over the seeds 1..=N. Jobs (cell x method x seed) are
//! numbered in one canonical order, and `--shard K/N` runs those whose number is K-1 modulo N: a
//! run's seed depends only on its cell and seed index, so shards merged ([`merge`]) give exactly
//! the unsharded records.
//!
//! Onsets: `moving`, the fault at `onsets.moving` (8 s), while the arm travels to the second
//! target (switch at 7.5 s in the bundled templates); `rest`, the fault at `onsets.rest` (5 s)
//! with the second target removed, so the arm rests until the end; `rest-then-motion`, the fault
//! at `onsets.rest` with the second target kept, so the arm moves after the fault.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_distr::{Distribution, Uniform};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::calibrate;
use super::runner::{Observer, TickRecord};
use super::runner::{ObserverMode, Run};
use super::{LoadedScenario, Method, RunResult, RunSetup, ScenarioError};
use crate::fsio;
use crate::precision::Calibration;
use crate::sensors::{ChannelSelection, FaultKind, FaultSpec};

/// Most cells a campaign may expand to, and most jobs (cells x methods x seeds).
pub const MAX_CELLS: usize = 100_000;
pub const MAX_JOBS: usize = 10_000_000;
/// Most seeds per cell.
pub const MAX_SEEDS: usize = 10_000;
/// Version of campaign.json's layout.
pub const CAMPAIGN_FORMAT: u32 = 1;

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
}

impl CampaignKind {
    fn onsets(&self) -> &[Onset] {
        match self {
            Self::Freeze { onsets }
            | Self::Bias { onsets, .. }
            | Self::Drift { onsets, .. }
            | Self::Gain { onsets, .. }
            | Self::Noise { onsets, .. }
            | Self::Dropout { onsets }
            | Self::Stuck { onsets, .. }
            | Self::Spikes { onsets, .. } => onsets,
        }
    }

    /// The scenario fault kind for a channel.
    fn fault_kind(&self, channel: &str) -> FaultKind {
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

/// The healthy reaching benchmark.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReachingConfig {
    /// Random reaching tasks per arm.
    pub tasks: usize,
    /// Length of each task (s).
    pub duration: f64,
    /// Seed of the targets (the runs use seed 1).
    pub seed: u64,
    /// Healthy runs of the detector's calibration, per task.
    pub calibration_runs: usize,
}

impl Default for ReachingConfig {
    fn default() -> Self {
        Self {
            tasks: 100,
            duration: 6.0,
            seed: 1,
            calibration_runs: 10,
        }
    }
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
    /// Methods (default: every method).
    #[serde(default)]
    pub methods: Option<Vec<Method>>,
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

/// The default campaign of the source tree (`assets/campaigns/default.toml`).
pub fn bundled_campaign_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/campaigns/default.toml")
}

fn default_channels() -> Vec<String> {
    vec!["enc*".into(), "tach*".into(), "cam".into()]
}

/// One cell of the grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    /// Index into the campaign's arms.
    pub arm: usize,
    /// `healthy`, `enc1 freeze moving`, or a pair's label.
    pub label: String,
    /// The channel(s) at fault (empty for healthy cells).
    pub channel: String,
    /// The fault kind (`healthy`, `pair` for two-fault cells).
    pub kind: String,
    pub onset: Option<Onset>,
    /// Whether the second target is removed (the arm rests).
    pub rest: bool,
    pub faults: Vec<FaultSpec>,
}

impl Cell {
    pub fn is_healthy(&self) -> bool {
        self.faults.is_empty()
    }
}

/// A loaded campaign: its file, the arms' setups, the expanded grid.
#[derive(Clone)]
pub struct Campaign {
    pub config: CampaignConfig,
    pub path: PathBuf,
    pub arms: Vec<RunSetup>,
    pub cells: Vec<Cell>,
    pub methods: Vec<Method>,
    pub fingerprint: String,
}

/// The bundled default campaign, embedded.
pub const DEFAULT_CAMPAIGN_NAME: &str = "default.toml";

fn invalid(path: &Path, field: &str, message: String) -> ScenarioError {
    ScenarioError::Invalid {
        path: path.to_path_buf(),
        field: field.to_string(),
        message,
    }
}

/// Expands the grid of `config` for arms with the given joint counts (validated against each
/// arm's layout by [`Campaign::load`]).
pub fn expand(config: &CampaignConfig, onsets: &OnsetConfig) -> Vec<Cell> {
    let mut cells = Vec::new();
    for (a, arm) in config.arms.iter().enumerate() {
        if config.healthy {
            cells.push(Cell {
                arm: a,
                label: "healthy".into(),
                channel: String::new(),
                kind: "healthy".into(),
                onset: None,
                rest: false,
                faults: vec![],
            });
        }
        let mut channels = Vec::new();
        for c in &config.channels {
            match c.as_str() {
                "enc*" => channels.extend(arm.joints.iter().map(|j| format!("enc{j}"))),
                "tach*" => channels.extend(arm.joints.iter().map(|j| format!("tach{j}"))),
                other => channels.push(other.to_string()),
            }
        }
        for kind in &config.kinds {
            for channel in &channels {
                for &onset in kind.onsets() {
                    let start = match onset {
                        Onset::Moving => onsets.moving,
                        Onset::Rest | Onset::RestThenMotion => onsets.rest,
                    };
                    let fault = FaultSpec {
                        channel: ChannelSelection::One(channel.clone()),
                        start,
                        end: None,
                        kind: kind.fault_kind(channel),
                    };
                    cells.push(Cell {
                        arm: a,
                        label: format!("{channel} {} {}", fault.kind.name(), onset.name()),
                        channel: channel.clone(),
                        kind: fault.kind.name().into(),
                        onset: Some(onset),
                        rest: onset == Onset::Rest,
                        faults: vec![fault],
                    });
                }
            }
        }
        let first = arm.joints.first().copied().unwrap_or(1);
        for pair in &config.pairs {
            let faults: Vec<FaultSpec> = pair
                .faults
                .iter()
                .map(|f| {
                    let mut f = f.clone();
                    let sel: Vec<String> = f
                        .channel
                        .selectors()
                        .iter()
                        .map(|s| match *s {
                            "enc*" => format!("enc{first}"),
                            "tach*" => format!("tach{first}"),
                            other => other.to_string(),
                        })
                        .collect();
                    f.channel = if sel.len() == 1 {
                        ChannelSelection::One(sel[0].clone())
                    } else {
                        ChannelSelection::Many(sel)
                    };
                    f
                })
                .collect();
            let channel = faults
                .iter()
                .map(|f| f.channel.label())
                .collect::<Vec<_>>()
                .join(" then ");
            cells.push(Cell {
                arm: a,
                label: pair.label.clone(),
                channel,
                kind: "pair".into(),
                onset: None,
                rest: false,
                faults,
            });
        }
    }
    cells
}

impl Campaign {
    /// Reads a campaign file, applies `overrides` to every arm's template, and prepares it.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self, ScenarioError> {
        Self::from_config(CampaignConfig::load(path)?, path, overrides)
    }

    /// Validates a campaign and prepares its arms (loading each template, training its GP).
    pub fn from_config(
        config: CampaignConfig,
        path: &Path,
        overrides: &[String],
    ) -> Result<Self, ScenarioError> {
        let bad = |field: &str, message: String| invalid(path, field, message);
        if config.name.is_empty()
            || !config
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
        {
            return Err(bad(
                "name",
                "must be non-empty letters, digits, '_', '-' or '.'".into(),
            ));
        }
        if !(1..=MAX_SEEDS).contains(&config.seeds) {
            return Err(bad("seeds", format!("must be in 1..={MAX_SEEDS}")));
        }
        if config.arms.is_empty() {
            return Err(bad("arms", "at least one arm is needed".into()));
        }
        if config.arms.len() > 1000 {
            return Err(bad("arms", "at most 1000".into()));
        }
        let v = &config.verdict;
        if !(v.tolerance > 0.0
            && v.degraded >= v.tolerance
            && v.runaway >= v.degraded
            && v.tolerance.is_finite()
            && v.runaway.is_finite())
        {
            return Err(bad(
                "verdict",
                "needs 0 < tolerance <= degraded <= runaway, all finite".into(),
            ));
        }
        let o = &config.onsets;
        if !(o.moving.is_finite() && o.moving >= 0.0 && o.rest.is_finite() && o.rest >= 0.0) {
            return Err(bad("onsets", "times must be finite and >= 0".into()));
        }
        let methods = match &config.methods {
            Some(m) if m.is_empty() => return Err(bad("methods", "lists no method".into())),
            Some(m) => {
                for (i, a) in m.iter().enumerate() {
                    if m[..i].contains(a) {
                        return Err(bad("methods", format!("{a} is listed twice")));
                    }
                }
                m.clone()
            }
            None => Method::ALL.to_vec(),
        };
        if let Some(r) = &config.reaching
            && (r.tasks == 0
                || r.tasks > 100_000
                || !(r.duration.is_finite() && r.duration > 0.0 && r.duration <= 1e4)
                || !(2..=10_000).contains(&r.calibration_runs))
        {
            return Err(bad(
                "reaching",
                "needs 1..=100000 tasks, a duration in (0, 1e4] s and 2..=10000 calibration runs"
                    .into(),
            ));
        }
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let mut arms = Vec::new();
        for (i, arm) in config.arms.iter().enumerate() {
            let field = format!("arms[{i}]");
            if arm.joints.is_empty() {
                return Err(bad(&format!("{field}.joints"), "lists no joint".into()));
            }
            let layers = [
                super::Layer {
                    file: path.to_path_buf(),
                    key: "defaults".into(),
                    table: config.defaults.clone(),
                },
                super::Layer {
                    file: path.to_path_buf(),
                    key: format!("{field}.overrides"),
                    table: arm.overrides.clone(),
                },
            ];
            let loaded =
                LoadedScenario::from_file_layered(&base.join(&arm.scenario), &layers, overrides)?;
            let setup = RunSetup::prepare(loaded)?;
            let sc = setup.scenario();
            let n = setup.layout.n_joints();
            if let Some(&j) = arm.joints.iter().find(|&&j| j == 0 || j > n) {
                return Err(bad(
                    &format!("{field}.joints"),
                    format!("joint {j} is not a joint of the arm (1..={n})"),
                ));
            }
            if !sc.faults.is_empty() {
                return Err(bad(
                    &format!("{field}.scenario"),
                    "the template must be healthy (its faults would be mixed with the cells')"
                        .into(),
                ));
            }
            let needs_motion = config
                .kinds
                .iter()
                .any(|k| k.onsets().iter().any(|o| *o != Onset::Rest));
            if needs_motion && sc.targets.len() < 2 {
                return Err(bad(
                    &format!("{field}.scenario"),
                    "needs a second target (the motion of `moving` and `rest-then-motion` cells)"
                        .into(),
                ));
            }
            arms.push(setup);
        }
        let cells = expand(&config, &config.onsets);
        if cells.len() > MAX_CELLS {
            return Err(bad(
                "kinds",
                format!("{} cells; at most {MAX_CELLS}", cells.len()),
            ));
        }
        let jobs = cells
            .len()
            .saturating_mul(methods.len())
            .saturating_mul(config.seeds);
        if jobs > MAX_JOBS {
            return Err(bad(
                "seeds",
                format!("{jobs} runs (cells x methods x seeds); at most {MAX_JOBS}"),
            ));
        }
        for cell in &cells {
            let setup = &arms[cell.arm];
            let sc = setup.scenario();
            for (k, f) in cell.faults.iter().enumerate() {
                f.to_fault(&setup.layout).map_err(|e| {
                    bad(
                        &format!(
                            "cell `{}` of arm {}: fault {k}.{}",
                            cell.label, config.arms[cell.arm].name, e.field
                        ),
                        e.message,
                    )
                })?;
                if f.start >= sc.duration {
                    return Err(bad(
                        &format!("cell `{}`", cell.label),
                        format!(
                            "its fault starts at {} s, after the run ends ({} s)",
                            f.start, sc.duration
                        ),
                    ));
                }
            }
        }
        let fingerprint = campaign_fingerprint(&config, &arms);
        Ok(Self {
            config,
            path: path.to_path_buf(),
            arms,
            cells,
            methods,
            fingerprint,
        })
    }

    /// The setup a cell runs: its arm's, with the cell's faults and, at rest, one target.
    pub fn cell_setup(&self, cell: &Cell) -> RunSetup {
        let mut s = self.arms[cell.arm].clone();
        s.loaded.scenario.faults = cell.faults.clone();
        s.faults = cell
            .faults
            .iter()
            .map(|f| f.to_fault(&s.layout).expect("validated"))
            .collect();
        if cell.rest {
            s.loaded.scenario.targets.truncate(1);
        }
        s
    }

    /// Every job in canonical order: (cell, method, seed index).
    pub fn jobs(&self) -> Vec<(usize, Method, usize)> {
        let mut jobs = Vec::new();
        for c in 0..self.cells.len() {
            for &m in &self.methods {
                for s in 0..self.config.seeds {
                    jobs.push((c, m, s));
                }
            }
        }
        jobs
    }
}

/// A label of everything the campaign's results depend on: the campaign file, each arm's
/// scenario as resolved, its URDF and its GP (FNV-1a 64; a label, not a security hash).
fn campaign_fingerprint(config: &CampaignConfig, arms: &[RunSetup]) -> String {
    let mut hash: u64 = 0xcbf29ce484222325;
    let mut feed = |text: &str| {
        for b in text.bytes().chain(std::iter::once(0)) {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x100000001b3);
        }
    };
    feed(env!("CARGO_PKG_VERSION"));
    feed(&toml::to_string(config).expect("a campaign always serialises"));
    for a in arms {
        let mut s = a.scenario().clone();
        s.robot.urdf = PathBuf::new();
        feed(&toml::to_string(&s).expect("a scenario always serialises"));
        if let Ok((_, urdf)) = a
            .loaded
            .read_relative(&a.scenario().robot.urdf, fsio::MAX_URDF_BYTES)
        {
            feed(&urdf);
        }
        feed(&a.gp.to_json());
    }
    format!("{hash:016x}")
}

/// How one run ended, as the campaign sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    Recovered,
    Degraded,
    Failed,
    Diverged,
}

impl Verdict {
    pub fn name(self) -> &'static str {
        match self {
            Self::Recovered => "recovered",
            Self::Degraded => "degraded",
            Self::Failed => "failed",
            Self::Diverged => "diverged",
        }
    }
}

/// One run of the campaign: everything its tables need, in full precision (shards carry these).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRun {
    pub job: usize,
    pub cell: usize,
    pub method: Method,
    pub seed: u64,
    pub outcome: String,
    pub verdict: Verdict,
    /// MSE of (mu - q) of the faulty joints (every joint for camera faults and healthy cells)
    /// from the first fault's start (healthy cells: over the run).
    pub mse_post: f64,
    pub max_final_error: f64,
    pub runaway: bool,
    /// Whether the first fault was detected (None: healthy cell).
    pub detected: Option<bool>,
    pub delay: Option<f64>,
    pub isolation_correct: Option<bool>,
    pub false_alarms: usize,
    /// Simulated time (h).
    pub hours: f64,
    /// Time from the first fault's start until the belief error is back within 3 sigma of its
    /// pre-fault level for good (None: not back by the end, or a healthy cell).
    pub recover_time: Option<f64>,
}

/// Tracks the belief error of the faulty joints and when it is back within 3 sigma of its level
/// before the fault.
struct RecoveryObserver {
    joints: Vec<usize>,
    fault_tick: u64,
    from_tick: u64,
    sum2: f64,
    count: u64,
    threshold: Option<f64>,
    last_above: Option<u64>,
    last_tick: u64,
}

impl RecoveryObserver {
    fn new(joints: Vec<usize>, fault_tick: u64, dt: f64) -> Self {
        let skip = (1.0 / dt).round() as u64;
        Self {
            joints,
            fault_tick,
            from_tick: if fault_tick > skip { skip } else { 0 },
            sum2: 0.0,
            count: 0,
            threshold: None,
            last_above: None,
            last_tick: 0,
        }
    }

    /// Seconds from the fault until the error stayed within the threshold; None if it did not.
    fn recover_time(&self, dt: f64) -> Option<f64> {
        match self.last_above {
            None => Some(0.0),
            Some(k) if k >= self.last_tick => None,
            Some(k) => Some((k + 1 - self.fault_tick) as f64 * dt),
        }
    }
}

impl Observer for RecoveryObserver {
    fn iter(&mut self, r: &TickRecord<'_>) {
        let e = self
            .joints
            .iter()
            .map(|&j| (r.mu[j] - r.q[j]).abs())
            .fold(0.0, f64::max);
        self.last_tick = r.tick;
        if r.tick < self.fault_tick {
            if r.tick >= self.from_tick {
                self.sum2 += e * e;
                self.count += 1;
            }
            return;
        }
        let threshold = *self
            .threshold
            .get_or_insert_with(|| 3.0 * (self.sum2 / self.count.max(1) as f64).sqrt());
        if e > threshold {
            self.last_above = Some(r.tick);
        }
    }
}

/// Whether a joint is at (within 1 mrad of) one of its limits.
fn at_limit(setup: &RunSetup, q: &[f64]) -> bool {
    setup.model.joints.iter().zip(q).any(|(j, &q)| {
        j.limits
            .is_some_and(|(lo, hi)| q <= lo + 1e-3 || q >= hi - 1e-3)
    })
}

fn verdict_of(r: &RunResult, runaway: bool, v: &VerdictConfig) -> Verdict {
    if r.outcome.name() == "diverged" || !r.max_final_error.is_finite() {
        Verdict::Diverged
    } else if runaway || r.max_final_error > v.degraded {
        Verdict::Failed
    } else if r.max_final_error > v.tolerance {
        Verdict::Degraded
    } else {
        Verdict::Recovered
    }
}

/// Runs one job.
fn run_job(
    campaign: &Campaign,
    setup: &RunSetup,
    job: usize,
    cell_index: usize,
    method: Method,
    seed_index: usize,
    calibration: Option<&Calibration>,
) -> Result<CampaignRun, ScenarioError> {
    let cell = &campaign.cells[cell_index];
    let sc = setup.scenario();
    let dt = sc.dt;
    let seed = 1 + seed_index as u64;
    let n = setup.layout.n_joints();
    let mut joints: Vec<usize> = setup
        .faults
        .iter()
        .flat_map(|f| super::metrics::fault_joints(&setup.layout, f))
        .collect();
    joints.sort_unstable();
    joints.dedup();
    if joints.is_empty() {
        joints = (0..n).collect();
    }
    let fault_tick = setup.faults.iter().map(|f| f.start_tick(dt)).min();
    let mut recovery = RecoveryObserver::new(joints.clone(), fault_tick.unwrap_or(u64::MAX), dt);
    let r = Run::new(setup, method)
        .seed(seed)
        .calibration(calibration)
        .observe(&mut recovery, ObserverMode::Always)
        .execute()?;
    let mse_post = match &r.mse_post_fault_per_joint {
        Some(post) => joints.iter().map(|&j| post[j]).sum::<f64>() / joints.len() as f64,
        None => r.mse_per_joint.iter().sum::<f64>() / n as f64,
    };
    let runaway = r
        .final_error_per_joint
        .iter()
        .any(|e| !e.is_finite() || *e > campaign.config.verdict.runaway)
        || at_limit(setup, &r.q_final);
    let first = r.faults.first();
    Ok(CampaignRun {
        job,
        cell: cell_index,
        method,
        seed,
        outcome: r.outcome.name().to_string(),
        verdict: verdict_of(&r, runaway, &campaign.config.verdict),
        mse_post,
        max_final_error: r.max_final_error,
        runaway,
        detected: first.map(|f| f.detected_at.is_some()),
        delay: first.and_then(|f| f.delay),
        isolation_correct: first.and_then(|f| f.isolation_correct),
        false_alarms: r.false_alarms,
        hours: r.ticks_run as f64 * dt / 3600.0,
        recover_time: if cell.is_healthy() {
            None
        } else {
            recovery.recover_time(dt)
        },
    })
}

/// A shard: which K of N.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub const WHOLE: Shard = Shard { index: 1, count: 1 };

    /// Parses `K/N` (1 <= K <= N <= 100000).
    pub fn parse(text: &str) -> Result<Self, String> {
        let (k, n) = text
            .split_once('/')
            .ok_or_else(|| format!("{text:?} is not K/N"))?;
        let k: usize = k
            .trim()
            .parse()
            .map_err(|_| format!("{text:?}: K is not a number"))?;
        let n: usize = n
            .trim()
            .parse()
            .map_err(|_| format!("{text:?}: N is not a number"))?;
        if n == 0 || n > 100_000 || k == 0 || k > n {
            return Err(format!("{text:?}: needs 1 <= K <= N <= 100000"));
        }
        Ok(Self { index: k, count: n })
    }

    pub fn contains(&self, job: usize) -> bool {
        job % self.count == self.index - 1
    }
}

/// The records of a campaign run (or of one shard of it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRecords {
    pub format_version: u32,
    /// The campaign as run (what the tables need to be written again from the records alone).
    pub config: CampaignConfig,
    pub campaign: String,
    pub fingerprint: String,
    pub shard: Shard,
    pub jobs: usize,
    /// Each arm's plant and model error, in the order of the arms.
    pub conditions: Vec<super::Conditions>,
    pub runs: Vec<CampaignRun>,
    pub reaching: Vec<ReachingRun>,
}

/// The detector calibrations a set of jobs needs, one per distinct healthy schedule.
fn calibrations(
    campaign: &Campaign,
    jobs: &[(usize, usize, Method, usize)],
    cache: Option<&Path>,
) -> Result<BTreeMap<String, Calibration>, ScenarioError> {
    let mut needed: BTreeMap<String, RunSetup> = BTreeMap::new();
    for &(_, c, m, _) in jobs {
        if m.needs_detector() {
            let setup = campaign.cell_setup(&campaign.cells[c]);
            needed.entry(super::fingerprint(&setup)).or_insert(setup);
        }
    }
    let mut out = BTreeMap::new();
    for (key, setup) in needed {
        let runs = setup.scenario().detector.calibration_runs;
        let (cal, _) = calibrate::cached_calibration(&setup, runs, cache)?;
        out.insert(key, cal);
    }
    Ok(out)
}

/// Runs the jobs of `shard` (and, with the whole campaign, the reaching benchmark), in parallel,
/// in canonical order; `progress(done, total)` is called after each job.
pub fn run_campaign(
    campaign: &Campaign,
    shard: Shard,
    cache: Option<&Path>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<CampaignRecords, ScenarioError> {
    let all = campaign.jobs();
    let jobs: Vec<(usize, usize, Method, usize)> = all
        .iter()
        .enumerate()
        .filter(|(j, _)| shard.contains(*j))
        .map(|(j, &(c, m, s))| (j, c, m, s))
        .collect();
    let reaching = campaign.reaching_tasks();
    let reaching_jobs: Vec<usize> = (0..reaching.len())
        .filter(|i| shard.contains(all.len() + i))
        .collect();
    let total = jobs.len() + reaching_jobs.len();
    let cals = calibrations(campaign, &jobs, cache)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<Result<CampaignRun, ScenarioError>> = jobs
        .par_iter()
        .map(|&(j, c, m, s)| {
            let setup = campaign.cell_setup(&campaign.cells[c]);
            let cal = if m.needs_detector() {
                cals.get(&super::fingerprint(&setup))
            } else {
                None
            };
            let r = run_job(campaign, &setup, j, c, m, s, cal);
            progress(
                done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total,
            );
            r
        })
        .collect();
    let runs = results.into_iter().collect::<Result<Vec<_>, _>>()?;
    let reach: Vec<Result<Vec<ReachingRun>, ScenarioError>> = reaching_jobs
        .par_iter()
        .map(|&i| {
            let r = run_reaching(campaign, &reaching[i], all.len() + i, cache);
            progress(
                done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total,
            );
            r
        })
        .collect();
    let mut reaching_runs = Vec::new();
    for r in reach {
        reaching_runs.extend(r?);
    }
    Ok(CampaignRecords {
        format_version: CAMPAIGN_FORMAT,
        config: campaign.config.clone(),
        campaign: campaign.config.name.clone(),
        fingerprint: campaign.fingerprint.clone(),
        shard,
        jobs: all.len() + reaching.len(),
        conditions: campaign.arms.iter().map(RunSetup::conditions).collect(),
        runs,
        reaching: reaching_runs,
    })
}

/// Merges shards into the records of the whole campaign: they must be of one campaign
/// (fingerprint), disjoint and complete.
pub fn merge(shards: &[CampaignRecords]) -> Result<CampaignRecords, String> {
    let first = shards.first().ok_or("no shard given")?;
    let mut covered = std::collections::BTreeSet::new();
    let mut seen_shards = std::collections::BTreeSet::new();
    for s in shards {
        if s.fingerprint != first.fingerprint || s.campaign != first.campaign {
            return Err(format!(
                "shard {}/{} is of another campaign ({} {}, not {} {})",
                s.shard.index,
                s.shard.count,
                s.campaign,
                s.fingerprint,
                first.campaign,
                first.fingerprint
            ));
        }
        if s.conditions != first.conditions {
            return Err(format!(
                "shard {}/{} ran under other conditions (plant or model error)",
                s.shard.index, s.shard.count
            ));
        }
        if s.shard.count != first.shard.count || s.jobs != first.jobs {
            return Err("the shards split the campaign differently".into());
        }
        if !seen_shards.insert(s.shard.index) {
            return Err(format!(
                "shard {}/{} is given twice",
                s.shard.index, s.shard.count
            ));
        }
        for j in s
            .runs
            .iter()
            .map(|r| r.job)
            .chain(s.reaching.iter().map(|r| r.job))
        {
            if !s.shard.contains(j) {
                return Err(format!(
                    "shard {}/{} holds job {j}, which is not its own",
                    s.shard.index, s.shard.count
                ));
            }
            covered.insert(j);
        }
    }
    let missing: Vec<usize> = (1..=first.shard.count)
        .filter(|k| !seen_shards.contains(k))
        .collect();
    if !missing.is_empty() {
        return Err(format!(
            "shards {missing:?} of {} are missing",
            first.shard.count
        ));
    }
    let mut runs: Vec<CampaignRun> = shards.iter().flat_map(|s| s.runs.iter().cloned()).collect();
    runs.sort_by_key(|r| r.job);
    let mut reaching: Vec<ReachingRun> = shards
        .iter()
        .flat_map(|s| s.reaching.iter().cloned())
        .collect();
    reaching.sort_by(|a, b| a.job.cmp(&b.job).then(a.method.cmp(&b.method)));
    let all: std::collections::BTreeSet<usize> = (0..first.jobs).collect();
    if covered != all {
        let gaps: Vec<usize> = all.difference(&covered).take(5).copied().collect();
        return Err(format!(
            "the shards are incomplete: jobs {gaps:?}... have no result (was a shard cut short?)"
        ));
    }
    Ok(CampaignRecords {
        format_version: CAMPAIGN_FORMAT,
        config: first.config.clone(),
        campaign: first.campaign.clone(),
        fingerprint: first.fingerprint.clone(),
        shard: Shard::WHOLE,
        jobs: first.jobs,
        conditions: first.conditions.clone(),
        runs,
        reaching,
    })
}

/// A cell's numbers for one method, over its seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct CellSummary {
    pub cell: usize,
    pub method: Method,
    pub seeds: usize,
    /// The worst verdict over the seeds.
    pub verdict: Verdict,
    pub recovered: usize,
    pub mse_post_mean: f64,
    pub mse_post_std: f64,
    /// mse_post_mean over the oracle's (None without an oracle row).
    pub ratio_to_oracle: Option<f64>,
    pub final_error_mean: f64,
    pub runaways: usize,
    pub detection_delay_mean: Option<f64>,
    pub missed_detections: usize,
    pub isolation_correct: Option<f64>,
    pub false_alarms_per_hour: f64,
    pub recover_time_mean: Option<f64>,
    pub not_recovered_belief: usize,
    /// Worse than no-FT in this cell ([`worse_than_no_ft`]).
    pub worse_than_no_ft: bool,
}

/// A method's numbers over every cell.
#[derive(Clone, Debug, PartialEq)]
pub struct MethodSummary {
    pub method: Method,
    pub cells: usize,
    pub recovered: usize,
    pub degraded: usize,
    pub failed: usize,
    pub diverged: usize,
    pub worse_than_no_ft: usize,
    /// Fault cells where the oracle recovers.
    pub oracle_recovers: usize,
    /// Of those, cells this method recovers too.
    pub recovers_where_oracle_does: usize,
    /// Fault cells within 10x the oracle's post-fault MSE.
    pub within_10x_oracle: usize,
    pub fault_cells: usize,
    pub false_alarms_per_hour: f64,
}

fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    if values.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mean = values.iter().sum::<f64>() / n;
    let var = if values.len() > 1 {
        values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (mean, var.sqrt())
}

/// The "worse than no-FT" rule: a method is worse than no fault tolerance in a cell when its
/// mean post-fault MSE exceeds no-FT's by more than half again and by more than
/// (tolerance / 20)^2 (1 mrad RMS at the default tolerance of 0.02 rad), or its mean final error
/// exceeds no-FT's by more than half the recovery tolerance. (The margins keep seed noise, and
/// differences far below what any tolerance cares about, from being flagged.)
pub fn worse_than_no_ft(
    mse: f64,
    final_error: f64,
    no_ft_mse: f64,
    no_ft_final_error: f64,
    tolerance: f64,
) -> bool {
    !mse.is_finite()
        || !final_error.is_finite()
        || (mse > 1.5 * no_ft_mse && mse - no_ft_mse > (tolerance / 20.0).powi(2))
        || final_error > no_ft_final_error + 0.5 * tolerance
}

/// Per (cell, method) summaries and per method totals.
pub fn summarise(
    campaign: &Campaign,
    runs: &[CampaignRun],
) -> (Vec<CellSummary>, Vec<MethodSummary>) {
    let tolerance = campaign.config.verdict.tolerance;
    let mut by: BTreeMap<(usize, Method), Vec<&CampaignRun>> = BTreeMap::new();
    for r in runs {
        by.entry((r.cell, r.method)).or_default().push(r);
    }
    let mut cells = Vec::new();
    for c in 0..campaign.cells.len() {
        let mut rows: Vec<CellSummary> = Vec::new();
        for &m in &campaign.methods {
            let Some(rs) = by.get(&(c, m)) else { continue };
            let (mse_mean, mse_std) = mean_std(&rs.iter().map(|r| r.mse_post).collect::<Vec<_>>());
            let final_error_mean =
                mean_std(&rs.iter().map(|r| r.max_final_error).collect::<Vec<_>>()).0;
            let delays: Vec<f64> = rs.iter().filter_map(|r| r.delay).collect();
            let iso: Vec<bool> = rs.iter().filter_map(|r| r.isolation_correct).collect();
            let rec: Vec<f64> = rs.iter().filter_map(|r| r.recover_time).collect();
            let hours: f64 = rs.iter().map(|r| r.hours).sum();
            rows.push(CellSummary {
                cell: c,
                method: m,
                seeds: rs.len(),
                verdict: rs
                    .iter()
                    .map(|r| r.verdict)
                    .max()
                    .unwrap_or(Verdict::Recovered),
                recovered: rs
                    .iter()
                    .filter(|r| r.verdict == Verdict::Recovered)
                    .count(),
                mse_post_mean: mse_mean,
                mse_post_std: mse_std,
                ratio_to_oracle: None,
                final_error_mean,
                runaways: rs.iter().filter(|r| r.runaway).count(),
                detection_delay_mean: (!delays.is_empty()).then(|| mean_std(&delays).0),
                missed_detections: rs.iter().filter(|r| r.detected == Some(false)).count(),
                isolation_correct: (!iso.is_empty())
                    .then(|| iso.iter().filter(|b| **b).count() as f64 / iso.len() as f64),
                false_alarms_per_hour: if hours > 0.0 {
                    rs.iter().map(|r| r.false_alarms).sum::<usize>() as f64 / hours
                } else {
                    0.0
                },
                recover_time_mean: (!rec.is_empty()).then(|| mean_std(&rec).0),
                not_recovered_belief: rs
                    .iter()
                    .filter(|r| r.recover_time.is_none() && r.detected.is_some())
                    .count(),
                worse_than_no_ft: false,
            });
        }
        let oracle = rows
            .iter()
            .find(|r| r.method == Method::Oracle)
            .map(|r| r.mse_post_mean);
        let no_ft = rows
            .iter()
            .find(|r| r.method == Method::NoFt)
            .map(|r| (r.mse_post_mean, r.final_error_mean));
        for r in &mut rows {
            r.ratio_to_oracle = oracle.map(|o| r.mse_post_mean / o);
            if let Some((m, f)) = no_ft
                && r.method != Method::NoFt
            {
                r.worse_than_no_ft =
                    worse_than_no_ft(r.mse_post_mean, r.final_error_mean, m, f, tolerance);
            }
        }
        cells.extend(rows);
    }
    let methods = campaign
        .methods
        .iter()
        .map(|&m| {
            let mine: Vec<&CellSummary> = cells.iter().filter(|c| c.method == m).collect();
            let count = |v: Verdict| mine.iter().filter(|c| c.verdict == v).count();
            let fault: Vec<&&CellSummary> = mine
                .iter()
                .filter(|c| !campaign.cells[c.cell].is_healthy())
                .collect();
            let oracle_ok = |cell: usize| {
                cells.iter().any(|o| {
                    o.cell == cell && o.method == Method::Oracle && o.verdict == Verdict::Recovered
                })
            };
            let healthy: Vec<&&CellSummary> = mine
                .iter()
                .filter(|c| campaign.cells[c.cell].is_healthy())
                .collect();
            MethodSummary {
                method: m,
                cells: mine.len(),
                recovered: count(Verdict::Recovered),
                degraded: count(Verdict::Degraded),
                failed: count(Verdict::Failed),
                diverged: count(Verdict::Diverged),
                worse_than_no_ft: mine.iter().filter(|c| c.worse_than_no_ft).count(),
                oracle_recovers: fault.iter().filter(|c| oracle_ok(c.cell)).count(),
                recovers_where_oracle_does: fault
                    .iter()
                    .filter(|c| oracle_ok(c.cell) && c.verdict == Verdict::Recovered)
                    .count(),
                within_10x_oracle: fault
                    .iter()
                    .filter(|c| c.ratio_to_oracle.is_some_and(|r| r <= 10.0))
                    .count(),
                fault_cells: fault.len(),
                false_alarms_per_hour: if healthy.is_empty() {
                    0.0
                } else {
                    healthy.iter().map(|c| c.false_alarms_per_hour).sum::<f64>()
                        / healthy.len() as f64
                },
            }
        })
        .collect();
    (cells, methods)
}

/// One task of the reaching benchmark.
#[derive(Clone, Debug, PartialEq)]
pub struct ReachingTask {
    pub arm: usize,
    pub task: usize,
    pub target: Vec<f64>,
}

/// One method on one reaching task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachingRun {
    pub job: usize,
    pub arm: usize,
    pub task: usize,
    pub method: Method,
    pub belief_rmse: f64,
    /// Largest overshoot beyond the target along the step, over joints (% of the step).
    pub overshoot: f64,
    /// Time after which every joint stays within 0.5 % of its step of the target (s; None: never).
    pub settling_time: Option<f64>,
    pub steady_state_error: f64,
    pub false_alarms: usize,
}

impl Campaign {
    /// A campaign for writing tables from records alone (`aift merge`): the grid from the
    /// configuration, no arm prepared.
    pub fn plan(config: CampaignConfig) -> Self {
        let cells = expand(&config, &config.onsets);
        let methods = config
            .methods
            .clone()
            .unwrap_or_else(|| Method::ALL.to_vec());
        Self {
            config,
            path: PathBuf::new(),
            arms: vec![],
            cells,
            methods,
            fingerprint: String::new(),
        }
    }

    /// The reaching tasks: per arm, targets uniform in the arm's camera-model box (its GP's
    /// training box) clipped 10 % inside the joint limits.
    pub fn reaching_tasks(&self) -> Vec<ReachingTask> {
        let Some(rc) = &self.config.reaching else {
            return vec![];
        };
        let mut tasks = Vec::new();
        for (a, setup) in self.arms.iter().enumerate() {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(rc.seed);
            rng.set_stream(a as u64);
            let boxes: Vec<(f64, f64)> = setup
                .gp
                .training_box
                .iter()
                .zip(&setup.model.joints)
                .map(|([lo, hi], j)| match j.limits {
                    Some((llo, lhi)) => {
                        let m = 0.1 * (lhi - llo);
                        (lo.max(llo + m), hi.min(lhi - m))
                    }
                    None => (*lo, *hi),
                })
                .collect();
            for t in 0..rc.tasks {
                let target = boxes
                    .iter()
                    .map(|&(lo, hi)| {
                        if hi > lo {
                            Uniform::new(lo, hi).expect("lo < hi").sample(&mut rng)
                        } else {
                            0.5 * (lo + hi)
                        }
                    })
                    .collect();
                tasks.push(ReachingTask {
                    arm: a,
                    task: t,
                    target,
                });
            }
        }
        tasks
    }
}

/// Records what the reaching metrics need.
struct ReachingObserver {
    start: Vec<f64>,
    target: Vec<f64>,
    dt: f64,
    sq: f64,
    count: u64,
    overshoot: f64,
    last_outside: Option<u64>,
    last_tick: u64,
    band: Vec<f64>,
}

impl Observer for ReachingObserver {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.last_tick = r.tick;
        for j in 0..self.target.len() {
            let e = r.mu[j] - r.q[j];
            self.sq += e * e;
            let step = self.target[j] - self.start[j];
            if step.abs() > 1e-9 {
                let beyond = (r.q[j] - self.target[j]) * step.signum() / step.abs() * 100.0;
                self.overshoot = self.overshoot.max(beyond);
            }
            if (r.q[j] - self.target[j]).abs() > self.band[j] {
                self.last_outside = Some(r.tick);
            }
        }
        self.count += self.target.len() as u64;
    }
}

fn run_reaching(
    campaign: &Campaign,
    task: &ReachingTask,
    job: usize,
    cache: Option<&Path>,
) -> Result<Vec<ReachingRun>, ScenarioError> {
    let rc = campaign
        .config
        .reaching
        .as_ref()
        .expect("reaching configured");
    let mut setup = campaign.arms[task.arm].clone();
    let sc = &mut setup.loaded.scenario;
    sc.faults.clear();
    setup.faults.clear();
    sc.duration = rc.duration;
    sc.targets = vec![super::Target {
        time: 0.0,
        q: task.target.clone(),
    }];
    let start = sc.initial.q.clone();
    let largest = task
        .target
        .iter()
        .zip(&start)
        .map(|(t, s)| (t - s).abs())
        .fold(0.0, f64::max);
    let band: Vec<f64> = task
        .target
        .iter()
        .zip(&start)
        .map(|(t, s)| 0.005 * (t - s).abs().max(0.01 * largest).max(1e-4))
        .collect();
    let dt = sc.dt;
    let calibration = if campaign.methods.iter().any(|m| m.needs_detector()) {
        Some(calibrate::cached_calibration(&setup, rc.calibration_runs, cache)?.0)
    } else {
        None
    };
    let mut out = Vec::new();
    for &m in &campaign.methods {
        let mut obs = ReachingObserver {
            start: start.clone(),
            target: task.target.clone(),
            dt,
            sq: 0.0,
            count: 0,
            overshoot: 0.0,
            last_outside: None,
            last_tick: 0,
            band: band.clone(),
        };
        let r = Run::new(&setup, m)
            .seed(1)
            .calibration(calibration.as_ref())
            .observe(&mut obs, ObserverMode::Always)
            .execute()?;
        let settling_time = match obs.last_outside {
            None => Some(0.0),
            Some(k) if k >= obs.last_tick => None,
            Some(k) => Some((k + 1) as f64 * obs.dt),
        };
        out.push(ReachingRun {
            job,
            arm: task.arm,
            task: task.task,
            method: m,
            belief_rmse: (obs.sq / obs.count.max(1) as f64).sqrt(),
            overshoot: obs.overshoot.max(0.0),
            settling_time,
            steady_state_error: r.max_final_error,
            false_alarms: r.false_alarms,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_partition_the_jobs() {
        let shards: Vec<Shard> = (1..=3).map(|k| Shard { index: k, count: 3 }).collect();
        for job in 0..100 {
            assert_eq!(shards.iter().filter(|s| s.contains(job)).count(), 1);
        }
        assert!(Shard::parse("0/3").is_err());
        assert!(Shard::parse("4/3").is_err());
        assert!(Shard::parse("3").is_err());
        assert_eq!(Shard::parse("2/5").unwrap(), Shard { index: 2, count: 5 });
    }

    #[test]
    fn the_worse_than_no_ft_rule() {
        // Alike: not flagged.
        assert!(!worse_than_no_ft(1.2e-8, 0.001, 1.0e-8, 0.001, 0.02));
        // Twice the MSE, but both far below a milliradian: not flagged; well above: flagged.
        assert!(!worse_than_no_ft(2.0e-8, 0.001, 1.0e-8, 0.001, 0.02));
        assert!(worse_than_no_ft(4.0e-6, 0.001, 1.0e-6, 0.001, 0.02));
        // A final error 0.011 rad worse (more than half the tolerance): flagged.
        assert!(worse_than_no_ft(1.0e-8, 0.012, 1.0e-8, 0.001, 0.02));
        // Better: not flagged.
        assert!(!worse_than_no_ft(1e-9, 0.0001, 1.0, 3.0, 0.02));
        assert!(worse_than_no_ft(f64::NAN, 0.0, 1.0, 0.0, 0.02));
    }
}
