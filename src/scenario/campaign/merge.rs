//! Shards merged into the records of the whole campaign.

use std::collections::BTreeSet;
use std::path::Path;

use super::{CAMPAIGN_FORMAT, Campaign, CampaignRecords, CampaignRun, ReachingRun, Shard};

/// Checks one shard's records against the configuration they carry, before anything is
/// allocated from their counts: the format, the shard, the configuration (valid, not edited
/// since the run), the job count, and every run's job, cell, method, seed, arm and task as the
/// configuration places them, each job recorded once.
pub fn check_records(r: &CampaignRecords) -> Result<(), String> {
    if r.format_version != CAMPAIGN_FORMAT {
        return Err(format!(
            "format_version {}: this aift reads {CAMPAIGN_FORMAT}",
            r.format_version
        ));
    }
    let shard = r.shard;
    if shard.count == 0 || shard.count > 100_000 || shard.index == 0 || shard.index > shard.count {
        return Err(format!(
            "shard {}/{}: needs 1 <= K <= N <= 100000",
            shard.index, shard.count
        ));
    }
    if let Some(d) = &r.config_digest
        && *d != super::config_digest(&r.config)
    {
        return Err("its `config` was edited after the run (its digest does not match)".into());
    }
    let methods = super::validate(&r.config, Path::new("records.json"))
        .map_err(|e| format!("its `config`: {}", crate::error_chain(&e)))?;
    if r.campaign != r.config.name {
        return Err(format!(
            "`campaign` {:?} is not its config's name {:?}",
            r.campaign, r.config.name
        ));
    }
    if r.conditions.len() != r.config.arms.len() {
        return Err(format!(
            "{} `conditions` for {} arms",
            r.conditions.len(),
            r.config.arms.len()
        ));
    }
    let plan = Campaign::plan(r.config.clone());
    let seeds = r.config.seeds;
    let per_cell = methods.len() * seeds;
    let cell_jobs = plan.cells.len() * per_cell;
    let tasks = r.config.reaching.as_ref().map_or(0, |rc| rc.tasks);
    let expected = cell_jobs + r.config.arms.len() * tasks;
    if r.jobs != expected {
        return Err(format!("`jobs` is {}; its config makes {expected}", r.jobs));
    }
    let mut seen = BTreeSet::new();
    for run in &r.runs {
        let j = run.job;
        if j >= cell_jobs {
            return Err(format!(
                "a run of job {j}: the config's cells have jobs 0..{cell_jobs}"
            ));
        }
        let (cell, method, seed_index) = plan.job(j).expect("j < cell_jobs");
        let seed = super::run::run_seed(&r.config, seed_index);
        if (run.cell, &run.method, run.seed) != (cell, method, seed) {
            return Err(format!(
                "the run of job {j} says cell {}, {}, seed {}; the job is cell {cell}, {method}, \
                 seed {seed}",
                run.cell, run.method, run.seed
            ));
        }
        if !seen.insert((j, "")) {
            return Err(format!("job {j} is recorded twice"));
        }
    }
    for run in &r.reaching {
        let j = run.job;
        if j < cell_jobs || j >= expected {
            return Err(format!(
                "a reaching run of job {j}: the config's reaching jobs are {cell_jobs}..{expected}"
            ));
        }
        let i = j - cell_jobs;
        if (run.arm, run.task) != (i / tasks, i % tasks) || !methods.contains(&run.method) {
            return Err(format!(
                "the reaching run of job {j} says arm {}, task {}, {}; the job is arm {}, task \
                 {} of methods {}",
                run.arm,
                run.task,
                run.method,
                i / tasks,
                i % tasks,
                methods
                    .iter()
                    .map(|m| m.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        if !seen.insert((j, run.method.name())) {
            return Err(format!("job {j}'s {} run is recorded twice", run.method));
        }
    }
    // A reaching job holds one run per method.
    let mut per_job = std::collections::BTreeMap::new();
    for run in &r.reaching {
        *per_job.entry(run.job).or_insert(0usize) += 1;
    }
    if let Some((j, n)) = per_job.iter().find(|(_, n)| **n != methods.len()) {
        return Err(format!(
            "reaching job {j} has {n} runs; it has one per method ({})",
            methods.len()
        ));
    }
    Ok(())
}

/// Merges shards into the records of the whole campaign: they must be of one campaign
/// (fingerprint), disjoint and complete.
pub fn merge(shards: &[CampaignRecords]) -> Result<CampaignRecords, String> {
    let first = shards.first().ok_or("no shard given")?;
    for s in shards {
        check_records(s).map_err(|e| format!("shard {}/{}: {e}", s.shard.index, s.shard.count))?;
    }
    let mut covered = std::collections::BTreeSet::new();
    let mut seen_shards = std::collections::BTreeSet::new();
    for s in shards {
        if s.fingerprint != first.fingerprint
            || s.campaign != first.campaign
            || s.config != first.config
        {
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
    // As an unsharded run lists them: by job, then in the campaign's order of methods.
    let methods = first.config.method_list();
    let rank = |m: &crate::scenario::method::MethodId| methods.iter().position(|x| x == m);
    reaching.sort_by(|a, b| {
        a.job
            .cmp(&b.job)
            .then(rank(&a.method).cmp(&rank(&b.method)))
    });
    // Every covered job is below `jobs` (checked), so the counts tell completeness; nothing is
    // allocated per job of the config.
    if covered.len() != first.jobs {
        let gaps: Vec<usize> = (0..first.jobs)
            .filter(|j| !covered.contains(j))
            .take(5)
            .collect();
        return Err(format!(
            "the shards are incomplete: jobs {gaps:?}... have no result (was a shard cut short?)"
        ));
    }
    Ok(CampaignRecords {
        format_version: CAMPAIGN_FORMAT,
        config: first.config.clone(),
        campaign: first.campaign.clone(),
        fingerprint: first.fingerprint.clone(),
        config_digest: first.config_digest.clone(),
        shard: Shard::WHOLE,
        jobs: first.jobs,
        conditions: first.conditions.clone(),
        runs,
        reaching,
    })
}
