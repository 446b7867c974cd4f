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

pub mod compare;
mod config;
mod grid;
mod journal;
mod merge;
mod reaching;
mod run;
mod summary;

use std::path::{Path, PathBuf};

use super::method::MethodId;
use super::{LoadedScenario, Method, RunSetup, ScenarioError};
use crate::fsio;

pub use compare::{Better, PairComparison, SignedRank, compare_all, compare_pair, signed_rank};
pub use config::{
    ArmEntry, CampaignConfig, CampaignKind, ContactEntry, DisturbanceEntry, GroupSizes,
    MAX_TARGETS_FILE_BYTES, Onset, OnsetConfig, PairEntry, ReachingConfig, ReachingProtocol,
    VerdictConfig, read_reaching_targets,
};
pub use grid::{Cell, expand};
pub use journal::{JOURNAL_FORMAT, Journal, JournalMode, JournalStart, MAX_JOURNAL_BYTES};
pub use merge::{check_records, merge};
pub use reaching::{ReachingRun, ReachingTask};
pub use run::{
    CampaignRecords, CampaignRun, Shard, Verdict, run_campaign, run_campaign_journaled,
    run_campaign_with, run_seed,
};
pub use summary::{CellSummary, MethodSummary, summarise, worse_than_no_ft};

/// Most cells a campaign may expand to, and most jobs (cells x methods x seeds, and reaching
/// tasks x methods): sized so that what a campaign writes stays within what is read back
/// (campaign.json for the report, about 630 bytes per cell and method, under 256 MiB; each arm's
/// heatmap under 64 MiB; records.json, about 300 bytes per run, under the 1 GiB `aift merge`
/// reads).
pub const MAX_CELLS: usize = 20_000;
pub const MAX_JOBS: usize = 2_000_000;
/// Most seeds per cell.
pub const MAX_SEEDS: usize = 10_000;
/// Version of campaign.json's layout.
pub const CAMPAIGN_FORMAT: u32 = 1;

/// The default campaign of the source tree (`assets/campaigns/default.toml`).
pub fn bundled_campaign_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/campaigns/default.toml")
}

/// A loaded campaign: its file, the arms' setups, the expanded grid.
#[derive(Clone)]
pub struct Campaign {
    pub config: CampaignConfig,
    pub path: PathBuf,
    pub arms: Vec<RunSetup>,
    pub cells: Vec<Cell>,
    /// The methods it runs: the built-in ones (`methods`), then the caller's
    /// (`external_methods`).
    pub methods: Vec<MethodId>,
    pub fingerprint: String,
    /// The reaching targets read from `reaching.targets_file`, if it names one.
    pub reaching_targets: Option<Vec<Vec<f64>>>,
}

/// Most methods of the caller's in one campaign.
pub const MAX_EXTERNAL_METHODS: usize = 64;

/// The bundled default campaign, embedded.
pub const DEFAULT_CAMPAIGN_NAME: &str = "default.toml";

fn invalid(path: &Path, field: &str, message: String) -> ScenarioError {
    ScenarioError::Invalid {
        path: path.to_path_buf(),
        field: field.to_string(),
        message,
    }
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
        let methods = validate(&config, path)?;
        let reaching_targets = match &config.reaching {
            Some(rc) => match &rc.targets_file {
                Some(file) => {
                    let base = path.parent().unwrap_or(Path::new("."));
                    Some(read_reaching_targets(&base.join(file), path, rc.tasks)?)
                }
                None => None,
            },
            None => None,
        };
        let arms = prepare_arms(&config, path, overrides)?;
        if let (Some(targets), Some(rc)) = (&reaching_targets, &config.reaching) {
            for (a, setup) in arms.iter().enumerate() {
                let n = setup.layout.n_joints();
                let file = rc
                    .targets_file
                    .as_deref()
                    .unwrap_or(Path::new(""))
                    .display();
                if targets[0].len() != n {
                    return Err(invalid(
                        path,
                        "reaching.targets_file",
                        format!(
                            "{file}: targets of {} joints; arm {} ({}) has {n}",
                            targets[0].len(),
                            a,
                            config.arms[a].name
                        ),
                    ));
                }
                // A target the arm cannot reach would be measured as a steady-state error.
                for (t, target) in targets.iter().enumerate() {
                    for (j, (q, joint)) in target.iter().zip(&setup.model.joints).enumerate() {
                        if let Some((lo, hi)) = joint.limits
                            && !(lo..=hi).contains(q)
                        {
                            return Err(invalid(
                                path,
                                "reaching.targets_file",
                                format!(
                                    "{file}: target {} puts joint {} of arm {} ({}) at {q} rad, \
                                     outside its limits [{lo}, {hi}]",
                                    t + 1,
                                    j + 1,
                                    a,
                                    config.arms[a].name
                                ),
                            ));
                        }
                    }
                }
            }
        }
        if let Some(rc) = &config.reaching
            && rc.protocol == ReachingProtocol::Authors
        {
            for (a, setup) in arms.iter().enumerate() {
                if rc.step_joint > setup.layout.n_joints() {
                    return Err(invalid(
                        path,
                        "reaching.step_joint",
                        format!(
                            "{} is past the last joint of arm {} ({}: {} joints)",
                            rc.step_joint,
                            a,
                            config.arms[a].name,
                            setup.layout.n_joints()
                        ),
                    ));
                }
            }
        }
        for (a, setup) in arms.iter().enumerate() {
            for m in methods.iter().filter_map(MethodId::builtin) {
                setup.check_method(m).map_err(|e| {
                    invalid(
                        path,
                        &format!("arms[{a}]"),
                        format!("{} ({}): {e}", config.arms[a].name, m.info().name),
                    )
                })?;
            }
        }
        let cells = expand(&config, &config.onsets);
        check_cells(&config, path, &arms, &cells, &methods)?;
        let fingerprint = campaign_fingerprint(&config, &arms, reaching_targets.as_deref());
        Ok(Self {
            config,
            path: path.to_path_buf(),
            arms,
            cells,
            methods,
            fingerprint,
            reaching_targets,
        })
    }

    /// A campaign for writing tables from records alone (`aift merge`): the grid from the
    /// configuration, no arm prepared.
    pub fn plan(config: CampaignConfig) -> Self {
        let cells = expand(&config, &config.onsets);
        let methods = config.method_list();
        Self {
            config,
            path: PathBuf::new(),
            arms: vec![],
            cells,
            methods,
            fingerprint: String::new(),
            reaching_targets: None,
        }
    }

    /// The setup a cell runs: its arm's, with the cell's faults and, at rest, one target.
    pub fn cell_setup(&self, cell: &Cell) -> RunSetup {
        let mut s = self.arms[cell.arm].healthy();
        let (n, dt) = (s.layout.n_joints(), s.scenario().dt);
        s.loaded.scenario.faults = cell.faults.clone();
        s.faults = cell
            .faults
            .iter()
            .map(|f| f.to_fault(&s.layout, dt).expect("validated"))
            .collect();
        s.loaded.scenario.actuator_faults = cell.actuator_faults.clone();
        s.actuator_faults = cell
            .actuator_faults
            .iter()
            .map(|f| f.to_fault(n, dt).expect("validated"))
            .collect();
        s.loaded.scenario.disturbances = cell.disturbances.clone();
        s.disturbances = cell
            .disturbances
            .iter()
            .map(|d| d.to_disturbance(&s.model).expect("validated"))
            .collect();
        if cell.rest {
            s.loaded.scenario.targets.truncate(1);
        }
        if let Some(contact) = &cell.contact {
            let (from, to) = last_motion(&s);
            let obstacle = contact.obstacle(from, to).expect("checked by check_cells");
            let plant = &mut s.loaded.scenario.plant;
            plant.engine = crate::plant::Engine::Rapier;
            // The articulated engine's settings do not apply to rapier (its validation refuses
            // them there).
            plant.articulated = Default::default();
            plant.rapier.obstacles.push(obstacle);
        }
        s
    }

    /// The setup whose detector calibration a cell's detector methods use: the cell's, without
    /// its obstacle (on the same engine: the detector is calibrated on the arm's healthy runs,
    /// as for every other disturbance; contact is what it must not mistake for a fault).
    pub fn calibration_setup(&self, cell: &Cell) -> RunSetup {
        let mut s = self.cell_setup(cell);
        if cell.contact.is_some() {
            s.loaded.scenario.plant.rapier.obstacles.pop();
        }
        s
    }

    /// Every job in canonical order: (cell, method, seed index).
    /// Job `j`'s (cell, method, seed index): the inverse of [`Self::jobs`]'s order, for records
    /// checked without expanding the job list; `None` past the cells' jobs.
    pub fn job(&self, j: usize) -> Option<(usize, &MethodId, usize)> {
        let seeds = self.config.seeds;
        let cell = j / (self.methods.len() * seeds).max(1);
        (cell < self.cells.len()).then(|| {
            (
                cell,
                &self.methods[(j / seeds) % self.methods.len()],
                j % seeds,
            )
        })
    }

    pub fn jobs(&self) -> Vec<(usize, &MethodId, usize)> {
        let mut jobs = Vec::new();
        for c in 0..self.cells.len() {
            for m in &self.methods {
                for s in 0..self.config.seeds {
                    jobs.push((c, m, s));
                }
            }
        }
        jobs
    }
}

impl CampaignConfig {
    /// The methods it runs, in its order: `methods` (every built-in method when absent), then
    /// `external_methods`.
    pub fn method_list(&self) -> Vec<MethodId> {
        let builtin = match (&self.methods, self.external_methods.is_empty()) {
            (Some(m), _) => m.clone(),
            (None, true) => Method::ALL.to_vec(),
            // Only the caller's methods were asked for.
            (None, false) => Vec::new(),
        };
        builtin
            .into_iter()
            .map(MethodId::Builtin)
            .chain(
                self.external_methods
                    .iter()
                    .cloned()
                    .map(MethodId::External),
            )
            .collect()
    }

    /// Checks the campaign file's own fields and its grid's size, without loading any arm;
    /// returns the methods it runs. (`Campaign::load` does this first.)
    pub fn check(&self, path: &Path) -> Result<Vec<MethodId>, ScenarioError> {
        validate(self, path)
    }
}

/// Checks the campaign file's own fields (name, seeds, arms, verdict, onsets, methods, reaching);
/// returns the methods it runs.
fn validate(config: &CampaignConfig, path: &Path) -> Result<Vec<MethodId>, ScenarioError> {
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
    if !(1..=1u64 << 63).contains(&config.first_seed) {
        return Err(bad("first_seed", "must be in 1..=2^63".into()));
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
    if let Some(m) = &config.methods {
        if m.is_empty() && config.external_methods.is_empty() {
            return Err(bad("methods", "lists no method".into()));
        }
        for (i, a) in m.iter().enumerate() {
            if m[..i].contains(a) {
                return Err(bad("methods", format!("{a} is listed twice")));
            }
        }
    }
    let external = &config.external_methods;
    if external.len() > MAX_EXTERNAL_METHODS {
        return Err(bad(
            "external_methods",
            format!("{} methods; at most {MAX_EXTERNAL_METHODS}", external.len()),
        ));
    }
    for (i, name) in external.iter().enumerate() {
        super::method::check_external_name(name).map_err(|e| bad("external_methods", e))?;
        if external[..i].contains(name) {
            return Err(bad("external_methods", format!("{name:?} is listed twice")));
        }
    }
    let methods = config.method_list();
    check_grid(config, path, methods.len())?;
    if let Some(r) = &config.reaching {
        if r.tasks == 0
            || r.tasks > 100_000
            || !(r.duration.is_finite() && r.duration > 0.0 && r.duration <= 1e4)
            || !(2..=10_000).contains(&r.calibration_runs)
        {
            return Err(bad(
                "reaching",
                "needs 1..=100000 tasks, a duration in (0, 1e4] s and 2..=10000 calibration runs"
                    .into(),
            ));
        }
        if r.step_joint == 0 {
            return Err(bad(
                "reaching.step_joint",
                "joints count from 1 (1 is the first joint)".into(),
            ));
        }
        if let Some(range) = &r.target_range {
            let ok = match range[..] {
                [lo, hi] => {
                    lo.is_finite()
                        && hi.is_finite()
                        && lo < hi
                        && lo.abs() <= 1e3
                        && hi.abs() <= 1e3
                }
                _ => false,
            };
            if !ok {
                return Err(bad(
                    "reaching.target_range",
                    format!(
                        "{range:?} must be two numbers [lo, hi], finite, lo < hi, within +-1000 rad"
                    ),
                ));
            }
        }
        if r.target_range.is_some() && r.targets_file.is_some() {
            return Err(bad(
                "reaching.target_range",
                "give `target_range` or `targets_file`, not both".into(),
            ));
        }
    }
    Ok(methods)
}

/// Checks the grid before it is expanded: names (arms name files, so each is unique and safe in
/// a file name), entries listed twice (they would run and count a cell twice, or give two cells
/// one label), and the number of cells and runs, counted from the file's lists (a small file can
/// describe 1e8 cells).
fn check_grid(config: &CampaignConfig, path: &Path, methods: usize) -> Result<(), ScenarioError> {
    let bad = |field: &str, message: String| invalid(path, field, message);
    let safe = |name: &str| {
        !name.is_empty()
            && name.len() <= 100
            && !name.starts_with('.')
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.".contains(c))
    };
    let mut names = std::collections::BTreeSet::new();
    for (i, arm) in config.arms.iter().enumerate() {
        if !safe(&arm.name) {
            return Err(bad(
                &format!("arms[{i}].name"),
                format!(
                    "{:?} must be 1 to 100 letters, digits, '_', '-' or '.', not starting with \
                     '.' (it names the arm's files)",
                    arm.name
                ),
            ));
        }
        if !names.insert(arm.name.as_str()) {
            return Err(bad(
                &format!("arms[{i}].name"),
                format!("{:?} is the name of an earlier arm", arm.name),
            ));
        }
        if let Some((k, j)) = arm
            .joints
            .iter()
            .enumerate()
            .find(|(k, j)| arm.joints[..*k].contains(j))
        {
            return Err(bad(
                &format!("arms[{i}].joints[{k}]"),
                format!("joint {j} is listed twice"),
            ));
        }
    }
    for (i, c) in config.channels.iter().enumerate() {
        if config.channels[..i].contains(c) {
            return Err(bad(
                &format!("channels[{i}]"),
                format!("{c:?} is listed twice"),
            ));
        }
        let group = if c.starts_with("enc") {
            "enc*"
        } else if c.starts_with("tach") {
            "tach*"
        } else {
            ""
        };
        if !group.is_empty() && c != group && config.channels.iter().any(|o| o == group) {
            return Err(bad(
                &format!("channels[{i}]"),
                format!("{c:?} is already one of {group:?}"),
            ));
        }
    }
    for (i, k) in config.kinds.iter().enumerate() {
        let name = k.fault_kind("enc1").name();
        if config.kinds[..i]
            .iter()
            .any(|o| o.fault_kind("enc1").name() == name)
        {
            return Err(bad(
                &format!("kinds[{i}]"),
                format!(
                    "kind {name:?} is listed twice (a cell is named by its channel, kind and \
                     onset; put its onsets in one entry)"
                ),
            ));
        }
        let onsets = k.onsets();
        if onsets.is_empty() {
            return Err(bad(&format!("kinds[{i}].onsets"), "lists no onset".into()));
        }
        if let Some((j, o)) = onsets
            .iter()
            .enumerate()
            .find(|(j, o)| onsets[..*j].contains(o))
        {
            return Err(bad(
                &format!("kinds[{i}].onsets[{j}]"),
                format!("{:?} is listed twice", o.name()),
            ));
        }
    }
    for (i, p) in config.pairs.iter().enumerate() {
        if config.pairs[..i].iter().any(|o| o.label == p.label) {
            return Err(bad(
                &format!("pairs[{i}].label"),
                format!("{:?} is the label of an earlier pair", p.label),
            ));
        }
        // A pair's label must not be taken for another cell's: `healthy`, or `CHANNEL KIND
        // ONSET` as the grid's cells are labelled.
        let onset_word = Onset::ALL
            .iter()
            .any(|o| p.label.ends_with(&format!(" {}", o.name())));
        if p.label == "healthy" || p.label.trim().is_empty() || onset_word {
            return Err(bad(
                &format!("pairs[{i}].label"),
                format!(
                    "{:?} is empty or reads as another cell's label (`healthy`, or a channel, \
                     kind and onset)",
                    p.label
                ),
            ));
        }
        if p.faults.is_empty() {
            return Err(bad(
                &format!("pairs[{i}].faults"),
                "lists no fault (a pair is two or more faults; `healthy = true` gives the \
                 healthy cell)"
                    .into(),
            ));
        }
    }
    for (i, k) in config.actuator_kinds.iter().enumerate() {
        if config.actuator_kinds[..i]
            .iter()
            .any(|o| o.name() == k.name())
        {
            return Err(bad(
                &format!("actuator_kinds[{i}]"),
                format!("kind {:?} is listed twice", k.name()),
            ));
        }
    }
    let a_onsets = &config.actuator_onsets;
    if a_onsets.is_empty() {
        return Err(bad("actuator_onsets", "lists no onset".into()));
    }
    if let Some((j, o)) = a_onsets
        .iter()
        .enumerate()
        .find(|(j, o)| a_onsets[..*j].contains(o))
    {
        return Err(bad(
            &format!("actuator_onsets[{j}]"),
            format!("{:?} is listed twice", o.name()),
        ));
    }
    for (i, d) in config.disturbance_cells.iter().enumerate() {
        let taken = config.pairs.iter().any(|p| p.label == d.label)
            || config.disturbance_cells[..i]
                .iter()
                .any(|o| o.label == d.label);
        let onset_word = Onset::ALL
            .iter()
            .any(|o| d.label.ends_with(&format!(" {}", o.name())));
        if taken || d.label == "healthy" || d.label.trim().is_empty() || onset_word {
            return Err(bad(
                &format!("disturbance_cells[{i}].label"),
                format!(
                    "{:?} is empty, taken by an earlier pair or disturbance cell, or reads as \
                     another cell's label",
                    d.label
                ),
            ));
        }
        if d.disturbances.is_empty() && d.contact.is_none() {
            return Err(bad(
                &format!("disturbance_cells[{i}].disturbances"),
                "lists no disturbance (and the cell has no `contact`)".into(),
            ));
        }
        if let Some(c) = &d.contact {
            c.check()
                .map_err(|e| bad(&format!("disturbance_cells[{i}].contact"), e))?;
        }
    }
    // Cells per arm: healthy + channels x (kinds x onsets) + pairs + joints x actuator kinds x
    // actuator onsets + disturbance cells, counted without expanding.
    let onsets: usize = config
        .kinds
        .iter()
        .fold(0usize, |n, k| n.saturating_add(k.onsets().len()));
    let mut cells = 0usize;
    for arm in &config.arms {
        let channels = config.channels.iter().fold(0usize, |n, c| {
            n.saturating_add(if c == "enc*" || c == "tach*" {
                arm.joints.len()
            } else {
                1
            })
        });
        cells = cells
            .saturating_add(usize::from(config.healthy))
            .saturating_add(channels.saturating_mul(onsets))
            .saturating_add(config.pairs.len())
            .saturating_add(
                arm.joints
                    .len()
                    .saturating_mul(config.actuator_kinds.len())
                    .saturating_mul(a_onsets.len()),
            )
            .saturating_add(config.disturbance_cells.len());
    }
    if cells > MAX_CELLS {
        return Err(bad(
            "kinds",
            format!(
                "the grid has {cells} cells (per arm: healthy, channels x kinds x onsets, \
                 pairs); at most {MAX_CELLS}"
            ),
        ));
    }
    let reaching = config.reaching.as_ref().map_or(0, |r| {
        config
            .arms
            .len()
            .saturating_mul(r.tasks)
            .saturating_mul(methods)
    });
    let jobs = cells
        .saturating_mul(methods)
        .saturating_mul(config.seeds)
        .saturating_add(reaching);
    if jobs > MAX_JOBS {
        return Err(bad(
            "seeds",
            format!(
                "{jobs} runs (cells x methods x seeds, and reaching tasks x methods); at most \
                 {MAX_JOBS}"
            ),
        ));
    }
    if cells == 0 && config.reaching.is_none() {
        return Err(bad(
            "kinds",
            "the grid is empty: no healthy cell, no fault kind with a channel, no pair and no \
             reaching benchmark"
                .into(),
        ));
    }
    Ok(())
}

/// Loads each arm's template (laid over by the campaign's `[defaults]`, the arm's `overrides`,
/// then the command line's), prepares it and checks it against the arm's entry and the onsets.
fn prepare_arms(
    config: &CampaignConfig,
    path: &Path,
    overrides: &[String],
) -> Result<Vec<RunSetup>, ScenarioError> {
    let bad = |field: &str, message: String| invalid(path, field, message);
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
        let template = base.join(&arm.scenario);
        let loaded = LoadedScenario::from_file_layered(&template, &layers, overrides)?;
        // A refused value the campaign file set (and no --set after it) is blamed on the
        // campaign file's key, not on the template that never held it.
        let setup = RunSetup::prepare(loaded).map_err(|e| match e.blamed_override(overrides) {
            Some(_) => e,
            None => super::load::blame_layer(e, &layers, &template),
        })?;
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
                "the template must be healthy (its faults would be mixed with the cells')".into(),
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
    Ok(arms)
}

/// The end effector's world positions at the target before the last and at the last (the
/// initial pose stands for a missing one).
fn last_motion(s: &RunSetup) -> ([f64; 3], [f64; 3]) {
    let sc = s.scenario();
    let n = sc.targets.len();
    let q = |i: Option<usize>| {
        i.and_then(|i| sc.targets.get(i))
            .map_or(&sc.initial.q, |t| &t.q)
    };
    (
        end_effector_at(s, q(n.checked_sub(2))),
        end_effector_at(s, q(n.checked_sub(1))),
    )
}

fn end_effector_at(s: &RunSetup, q: &[f64]) -> [f64; 3] {
    let mut poses = vec![nalgebra::Isometry3::identity(); s.model.bodies.len()];
    crate::arm::kinematics::forward(&s.model, q, &mut poses);
    let p = s.ee.position(&poses);
    [p.x, p.y, p.z]
}

/// Checks the expanded grid: its size, and each cell's faults against its arm (a valid fault
/// that starts before the run ends).
fn check_cells(
    config: &CampaignConfig,
    path: &Path,
    arms: &[RunSetup],
    cells: &[Cell],
    methods: &[MethodId],
) -> Result<(), ScenarioError> {
    let bad = |field: &str, message: String| invalid(path, field, message);
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
    for cell in cells {
        let setup = &arms[cell.arm];
        let sc = setup.scenario();
        if let Some(contact) = &cell.contact {
            // The obstacle lies on the motion to the last target: that motion must exist and be
            // longer than `depth`.
            let field = format!(
                "cell `{}` of arm {}: contact",
                cell.label, config.arms[cell.arm].name
            );
            if sc.targets.len() < 2 {
                return Err(bad(
                    &field,
                    "needs a second target (the motion the obstacle stands in)".into(),
                ));
            }
            // Rapier collides the arm's URDF collision shapes: without one on the end
            // effector's body the arm would pass through the obstacle.
            if !setup
                .model
                .colliders
                .iter()
                .any(|c| c.body == setup.ee.body)
            {
                return Err(bad(
                    &field,
                    "the end effector's link has no <collision> shape in the URDF: the arm \
                     would pass through the obstacle"
                        .into(),
                ));
            }
            let (from, to) = last_motion(setup);
            if contact.obstacle(from, to).is_none() {
                let length = nalgebra::Vector3::from(to) - nalgebra::Vector3::from(from);
                return Err(bad(
                    &field,
                    format!(
                        "the end effector moves {:.3} m to its last target; `depth` ({} m) + \
                         1 cm must be shorter",
                        length.norm(),
                        contact.depth
                    ),
                ));
            }
        }
        for (k, f) in cell.faults.iter().enumerate() {
            f.to_fault(&setup.layout, sc.dt).map_err(|e| {
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
        let arm = &config.arms[cell.arm].name;
        for (k, f) in cell.actuator_faults.iter().enumerate() {
            f.to_fault(setup.layout.n_joints(), sc.dt).map_err(|e| {
                bad(
                    &format!(
                        "cell `{}` of arm {arm}: actuator fault {k}.{}",
                        cell.label, e.field
                    ),
                    e.message,
                )
            })?;
        }
        for (k, d) in cell.disturbances.iter().enumerate() {
            d.to_disturbance(&setup.model).map_err(|e| {
                bad(
                    &format!(
                        "cell `{}` of arm {arm}: disturbance {k}.{}",
                        cell.label, e.field
                    ),
                    e.message,
                )
            })?;
        }
    }
    Ok(())
}

/// A label of a campaign's configuration as written (FNV-1a 64; a label, not a security hash).
pub fn config_digest(config: &CampaignConfig) -> String {
    let mut hash: u64 = 0xcbf29ce484222325;
    for b in toml::to_string(config)
        .expect("a campaign always serialises")
        .bytes()
    {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x100000001b3);
    }
    format!("{hash:016x}")
}

/// A label of everything the campaign's results depend on: the campaign file, each arm's
/// scenario as resolved, its URDF and its GP (FNV-1a 64; a label, not a security hash).
fn campaign_fingerprint(
    config: &CampaignConfig,
    arms: &[RunSetup],
    reaching_targets: Option<&[Vec<f64>]>,
) -> String {
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
    if let Some(t) = reaching_targets {
        feed(&format!("{t:?}"));
    }
    format!("{hash:016x}")
}
