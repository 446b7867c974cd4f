//! Running a campaign: one job per (cell, method, seed), its verdict and recovery time; shards,
//! the detector calibrations the jobs need, and the records.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::reaching::run_reaching;
use super::{CAMPAIGN_FORMAT, Campaign, CampaignConfig, ReachingRun, VerdictConfig};
use crate::precision::Calibration;
use crate::scenario::calibrate;
use crate::scenario::method::{ExternalMethod, MethodId};
use crate::scenario::runner::{Observer, TickRecord};
use crate::scenario::runner::{ObserverMode, Run};
use crate::scenario::{RunResult, RunSetup, ScenarioError};

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

/// A number of the records that a diverged run leaves not finite: JSON has no NaN, so serde
/// writes it as `null`, and this reads `null` back as NaN (without it, a journal or a shard
/// holding a diverged run could not be read back: resume stopped at that run, merge refused the
/// shard). An infinity is written as `null` too and reads back as NaN.
pub(crate) fn number_or_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// One run of the campaign: everything its tables need, in full precision (shards carry these).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRun {
    pub job: usize,
    pub cell: usize,
    pub method: MethodId,
    pub seed: u64,
    pub outcome: String,
    pub verdict: Verdict,
    /// MSE of (mu - q) of the faulty joints (every joint for camera faults and healthy cells)
    /// from the first fault's start (healthy cells: over the run).
    #[serde(deserialize_with = "number_or_null")]
    pub mse_post: f64,
    #[serde(deserialize_with = "number_or_null")]
    pub max_final_error: f64,
    pub runaway: bool,
    /// Whether the first fault was detected (None: healthy cell).
    pub detected: Option<bool>,
    pub delay: Option<f64>,
    pub isolation_correct: Option<bool>,
    pub false_alarms: usize,
    /// Simulated time (h).
    #[serde(deserialize_with = "number_or_null")]
    pub hours: f64,
    /// Time from the first fault's start until the belief error is back within 3 sigma of its
    /// pre-fault level for good (None: not back by the end, or a healthy cell).
    pub recover_time: Option<f64>,
}

/// The sensor-noise seed of a cell's `seed_index`-th run (the same in every cell and shard):
/// the campaign's `first_seed` + `seed_index` (checked not to overflow when the campaign is).
pub fn run_seed(config: &super::CampaignConfig, seed_index: usize) -> u64 {
    config.first_seed + seed_index as u64
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

/// Whether a joint (other than those `skipped`) is at (within 1 mrad of) one of its limits.
fn at_limit(setup: &RunSetup, q: &[f64], skipped: &[usize]) -> bool {
    setup
        .model
        .joints
        .iter()
        .zip(q)
        .enumerate()
        .any(|(i, (j, &q))| {
            !skipped.contains(&i)
                && j.limits
                    .is_some_and(|(lo, hi)| q <= lo + 1e-3 || q >= hi - 1e-3)
        })
}

/// The verdict from the run and its judged final error (every joint's, or, with a dead or
/// locked motor, the other joints').
fn verdict_of(r: &RunResult, judged: f64, runaway: bool, v: &VerdictConfig) -> Verdict {
    if r.outcome.name() == "diverged" || !judged.is_finite() {
        Verdict::Diverged
    } else if runaway || judged > v.degraded || r.outcome.name() == "chattering" {
        Verdict::Failed
    } else if judged > v.tolerance {
        Verdict::Degraded
    } else {
        Verdict::Recovered
    }
}

/// A run of `method` (built in, or one of `external` by name) with `seed`; `place` names the
/// run's arm and cell for an external method's messages.
pub(super) fn begin_run<'a>(
    setup: &'a RunSetup,
    method: &MethodId,
    seed: u64,
    calibration: Option<&'a Calibration>,
    external: &[ExternalMethod<'_>],
    (place, campaign_path): (&str, &Path),
) -> Result<Run<'a>, ScenarioError> {
    let run = match method {
        MethodId::Builtin(m) => Run::new(setup, *m).calibration(calibration),
        MethodId::External(name) => {
            let e = external
                .iter()
                .find(|e| e.name == *name)
                .ok_or_else(|| missing_external(campaign_path, name))?;
            Run::with_parts(setup, name, (e.build)(setup, seed, place)?)
        }
    };
    Ok(run.seed(seed))
}

fn missing_external(path: &Path, name: &str) -> ScenarioError {
    ScenarioError::Invalid {
        path: path.to_path_buf(),
        field: "external_methods".into(),
        message: format!(
            "{name:?} is a method of the caller's: run this campaign from the library (Rust \
             `run_campaign_with`, Python `aift.campaign(methods=[...])`) with that method"
        ),
    }
}

/// Checks that `external` are exactly the campaign's `external_methods` (by name).
fn check_externals(
    campaign: &Campaign,
    external: &[ExternalMethod<'_>],
) -> Result<(), ScenarioError> {
    let listed = &campaign.config.external_methods;
    if let Some(name) = listed
        .iter()
        .find(|n| !external.iter().any(|e| e.name == **n))
    {
        return Err(missing_external(&campaign.path, name));
    }
    if let Some((_, e)) = external
        .iter()
        .enumerate()
        .find(|(i, e)| external[..*i].iter().any(|o| o.name == e.name))
    {
        return Err(ScenarioError::Invalid {
            path: campaign.path.clone(),
            field: "external_methods".into(),
            message: format!("a method {:?} was given twice", e.name),
        });
    }
    if let Some(e) = external.iter().find(|e| !listed.contains(&e.name)) {
        return Err(ScenarioError::Invalid {
            path: campaign.path.clone(),
            field: "external_methods".into(),
            message: format!(
                "a method {:?} was given, but the campaign does not list it (it lists {:?})",
                e.name, listed
            ),
        });
    }
    Ok(())
}

/// The verdict of a contact cell, where the table may keep the arm from its target: recovered
/// when the run completes without a runaway (resting against the table or at the target), failed
/// on a runaway or chattering, diverged on divergence (docs/campaigns.md, "Contact cells").
fn contact_verdict(r: &RunResult, runaway: bool) -> Verdict {
    match r.outcome.name() {
        "diverged" => Verdict::Diverged,
        _ if !r.max_final_error.is_finite() => Verdict::Diverged,
        "completed" if !runaway => Verdict::Recovered,
        _ => Verdict::Failed,
    }
}

/// Runs one job: (job, cell, method, seed index).
fn run_job(
    campaign: &Campaign,
    setup: &RunSetup,
    (job, cell_index, method, seed_index): (usize, usize, &MethodId, usize),
    calibration: Option<&Calibration>,
    external: &[ExternalMethod<'_>],
) -> Result<CampaignRun, ScenarioError> {
    let cell = &campaign.cells[cell_index];
    let sc = setup.scenario();
    let dt = sc.dt;
    let seed = run_seed(&campaign.config, seed_index);
    let n = setup.layout.n_joints();
    let mut joints: Vec<usize> = setup
        .faults
        .iter()
        .flat_map(|f| crate::scenario::metrics::fault_joints(&setup.layout, f))
        .collect();
    joints.sort_unstable();
    joints.dedup();
    if joints.is_empty() {
        joints = (0..n).collect();
    }
    let fault_tick = setup
        .faults
        .iter()
        .map(|f| f.start_tick(dt))
        .chain(setup.actuator_faults.iter().map(|f| f.start_tick(dt)))
        .min();
    let mut recovery = RecoveryObserver::new(joints.clone(), fault_tick.unwrap_or(u64::MAX), dt);
    let place = format!(
        "arm {}, cell {}",
        campaign.config.arms[cell.arm].name, cell.label
    );
    let r = begin_run(
        setup,
        method,
        seed,
        calibration,
        external,
        (&place, &campaign.path),
    )?
    .observe(&mut recovery, ObserverMode::Always)
    .execute()?;
    let mse_post = match &r.mse_post_fault_per_joint {
        Some(post) => joints.iter().map(|&j| post[j]).sum::<f64>() / joints.len() as f64,
        None => r.mse_per_joint.iter().sum::<f64>() / n as f64,
    };
    // A dead or locked motor cannot be compensated on its own joint: recovery is the rest of the
    // arm reaching its targets and staying safe (docs/method.md, "Actuator faults").
    let lost: Vec<usize> = setup
        .actuator_faults
        .iter()
        .filter(|f| {
            matches!(
                f.kind,
                crate::plant::ActuatorFaultKind::Dead {}
                    | crate::plant::ActuatorFaultKind::Locked {}
            )
        })
        .flat_map(|f| f.joints.iter().copied())
        .collect();
    // Every joint lost: there is no rest of the arm; judge them all.
    let lost = if lost.len() >= n { Vec::new() } else { lost };
    let judged_joints = || (0..n).filter(|j| !lost.contains(j));
    let judged = judged_joints()
        .map(|j| r.final_error_per_joint[j])
        .fold(0.0f64, |a, e| if e.is_nan() { f64::NAN } else { a.max(e) });
    let runaway = judged_joints().any(|j| {
        let e = r.final_error_per_joint[j];
        !e.is_finite() || e > campaign.config.verdict.runaway
    }) || at_limit(setup, &r.q_final, &lost);
    let first = r.faults.first();
    // Actuator cells: the method's own detection when it infers actuator health (the hybrid
    // with `hybrid.actuators`), else the momentum observer's (None when neither runs).
    let actuator = r.actuator_faults.first();
    let (detected, delay, isolation_correct) = match (first, actuator) {
        (Some(f), _) => (Some(f.detected_at.is_some()), f.delay, f.isolation_correct),
        (None, Some(a)) if r.actuator_alarms.is_some() => (
            Some(a.method_detected_at.is_some()),
            a.method_delay,
            a.method_isolation_correct,
        ),
        (None, Some(a)) if r.momentum.is_some() => (
            Some(a.momentum_detected_at.is_some()),
            a.momentum_delay,
            a.momentum_isolation_correct,
        ),
        _ => (None, None, None),
    };
    let verdict = if cell.contact.is_some() {
        contact_verdict(&r, runaway)
    } else {
        verdict_of(&r, judged, runaway, &campaign.config.verdict)
    };
    Ok(CampaignRun {
        job,
        cell: cell_index,
        method: method.clone(),
        seed,
        outcome: r.outcome.name().to_string(),
        verdict,
        mse_post,
        max_final_error: r.max_final_error,
        runaway,
        detected,
        delay,
        isolation_correct,
        // A method's own actuator alarms outside actuator faults are false alarms too.
        false_alarms: r.false_alarms + r.actuator_false_alarms,
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
    /// A label of `config` as written (FNV-1a 64), so that `aift merge` notices a config edited
    /// after the run; absent in records of earlier versions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config_digest: Option<String>,
    pub shard: Shard,
    pub jobs: usize,
    /// Each arm's plant and model error, in the order of the arms.
    pub conditions: Vec<crate::scenario::Conditions>,
    pub runs: Vec<CampaignRun>,
    pub reaching: Vec<ReachingRun>,
}

/// The detector calibrations a set of jobs needs, one per distinct healthy schedule.
fn calibrations(
    campaign: &Campaign,
    jobs: &[(usize, usize, &MethodId, usize)],
    cache: Option<&Path>,
) -> Result<BTreeMap<String, Calibration>, ScenarioError> {
    let mut needed: BTreeMap<String, RunSetup> = BTreeMap::new();
    for &(_, c, m, _) in jobs {
        if m.needs_detector() {
            let setup = campaign.calibration_setup(&campaign.cells[c]);
            needed
                .entry(crate::scenario::fingerprint(&setup))
                .or_insert(setup);
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

/// Runs the jobs of `shard` (cell jobs and reaching jobs alike: job j belongs to shard
/// j mod N + 1), in parallel, in canonical order; `progress(done, total)` is called after each job.
pub fn run_campaign(
    campaign: &Campaign,
    shard: Shard,
    cache: Option<&Path>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<CampaignRecords, ScenarioError> {
    run_campaign_journaled(campaign, shard, cache, progress, None)
}

/// [`run_campaign`] with a journal: the jobs it holds are taken from it, not run again, and each
/// job run is written to it as it finishes (a run stopped by [`crate::scenario::stop_all_runs`]
/// is not). The records are the same as an uninterrupted run's.
pub fn run_campaign_journaled(
    campaign: &Campaign,
    shard: Shard,
    cache: Option<&Path>,
    progress: &(dyn Fn(usize, usize) + Sync),
    journal: Option<&super::Journal>,
) -> Result<CampaignRecords, ScenarioError> {
    run_campaign_with(campaign, shard, cache, progress, journal, &[])
}

/// [`run_campaign_journaled`] with the caller's methods: one per name in the campaign's
/// `external_methods` (each run builds its own parts from any worker thread).
pub fn run_campaign_with(
    campaign: &Campaign,
    shard: Shard,
    cache: Option<&Path>,
    progress: &(dyn Fn(usize, usize) + Sync),
    journal: Option<&super::Journal>,
    external: &[ExternalMethod<'_>],
) -> Result<CampaignRecords, ScenarioError> {
    check_externals(campaign, external)?;
    let all = campaign.jobs();
    let in_shard: Vec<(usize, usize, &MethodId, usize)> = all
        .iter()
        .enumerate()
        .filter(|(j, _)| shard.contains(*j))
        .map(|(j, &(c, m, s))| (j, c, m, s))
        .collect();
    let reaching = campaign.reaching_tasks();
    let reaching_in_shard: Vec<usize> = (0..reaching.len())
        .filter(|i| shard.contains(all.len() + i))
        .collect();
    let total = in_shard.len() + reaching_in_shard.len();
    let kept_run = |j: usize| journal.and_then(|w| w.run(j));
    let kept_reaching = |j: usize| journal.and_then(|w| w.reaching(j));
    let jobs: Vec<_> = in_shard
        .iter()
        .copied()
        .filter(|&(j, ..)| kept_run(j).is_none())
        .collect();
    let reaching_jobs: Vec<usize> = reaching_in_shard
        .iter()
        .copied()
        .filter(|&i| kept_reaching(all.len() + i).is_none())
        .collect();
    let cals = calibrations(campaign, &jobs, cache)?;
    let done = std::sync::atomic::AtomicUsize::new(total - jobs.len() - reaching_jobs.len());
    let stopped = || crate::scenario::runner::all_runs_stopping();
    // A method of the caller's that failed: no job starts and no run is journaled after.
    let failed = || {
        crate::scenario::method::failed_external(external).map(|name| ScenarioError::Invalid {
            path: campaign.path.clone(),
            field: "external_methods".into(),
            message: format!("method {name:?} failed in a run; the campaign stopped"),
        })
    };
    let results: Vec<Result<CampaignRun, ScenarioError>> = jobs
        .par_iter()
        .map(|&(j, c, m, s)| {
            if let Some(e) = failed() {
                return Err(e);
            }
            let started = std::time::Instant::now();
            let cell = &campaign.cells[c];
            let setup = campaign.cell_setup(cell);
            let cal = if m.needs_detector() {
                let key = if cell.contact.is_some() {
                    crate::scenario::fingerprint(&campaign.calibration_setup(cell))
                } else {
                    crate::scenario::fingerprint(&setup)
                };
                cals.get(&key)
            } else {
                None
            };
            let r = run_job(campaign, &setup, (j, c, m, s), cal, external)?;
            if let Some(e) = failed() {
                return Err(e);
            }
            if let Some(w) = journal
                && r.outcome != "stopped"
                && !stopped()
            {
                w.record_run(&r, started.elapsed().as_secs_f64())?;
            }
            progress(
                done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total,
            );
            Ok(r)
        })
        .collect();
    let mut runs: BTreeMap<usize, CampaignRun> = BTreeMap::new();
    for r in results {
        let r = r?;
        runs.insert(r.job, r);
    }
    for &(j, ..) in &in_shard {
        if let Some(r) = kept_run(j) {
            runs.insert(j, r.clone());
        }
    }
    let reach: Vec<Result<(usize, Vec<ReachingRun>), ScenarioError>> = reaching_jobs
        .par_iter()
        .map(|&i| {
            if let Some(e) = failed() {
                return Err(e);
            }
            let started = std::time::Instant::now();
            let job = all.len() + i;
            let r = run_reaching(campaign, &reaching[i], job, cache, external)?;
            if let Some(e) = failed() {
                return Err(e);
            }
            if let Some(w) = journal
                && !stopped()
            {
                w.record_reaching(job, &r, started.elapsed().as_secs_f64())?;
            }
            progress(
                done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                total,
            );
            Ok((job, r))
        })
        .collect();
    let mut reaching_runs: BTreeMap<usize, Vec<ReachingRun>> = BTreeMap::new();
    for r in reach {
        let (job, r) = r?;
        reaching_runs.insert(job, r);
    }
    for &i in &reaching_in_shard {
        if let Some(r) = kept_reaching(all.len() + i) {
            reaching_runs.insert(all.len() + i, r.clone());
        }
    }
    Ok(CampaignRecords {
        format_version: CAMPAIGN_FORMAT,
        config: campaign.config.clone(),
        campaign: campaign.config.name.clone(),
        fingerprint: campaign.fingerprint.clone(),
        config_digest: Some(super::config_digest(&campaign.config)),
        shard,
        jobs: all.len() + reaching.len(),
        conditions: campaign.arms.iter().map(RunSetup::conditions).collect(),
        runs: runs.into_values().collect(),
        reaching: reaching_runs.into_values().flatten().collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A diverged run's NaN numbers are written as null and read back as NaN, and the record
    /// writes the same bytes again (journals and shards hold diverged runs).
    #[test]
    fn a_diverged_run_round_trips_through_its_json() {
        let run = CampaignRun {
            job: 3,
            cell: 1,
            method: MethodId::from_name("hybrid"),
            seed: 2,
            outcome: "diverged".into(),
            verdict: Verdict::Diverged,
            mse_post: f64::NAN,
            max_final_error: f64::NAN,
            runaway: false,
            detected: Some(false),
            delay: None,
            isolation_correct: None,
            false_alarms: 0,
            hours: 1e-3,
            recover_time: None,
        };
        let text = serde_json::to_string(&run).unwrap();
        assert!(text.contains("\"mse_post\":null"), "{text}");
        let back: CampaignRun = serde_json::from_str(&text).unwrap();
        assert!(back.mse_post.is_nan() && back.max_final_error.is_nan());
        assert_eq!(back.hours, 1e-3);
        assert_eq!(serde_json::to_string(&back).unwrap(), text);
        let reaching = r#"{"job":9,"arm":0,"task":0,"method":"no-ft","outcome":"diverged","belief_rmse":null,"overshoot":null,"settling_time":null,"steady_state_error":null,"false_alarms":0}"#;
        let r: ReachingRun = serde_json::from_str(reaching).unwrap();
        assert!(r.belief_rmse.is_nan() && r.overshoot.is_nan() && r.steady_state_error.is_nan());
        assert_eq!(serde_json::to_string(&r).unwrap(), reaching);
    }

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
}
