//! Shards merged into the records of the whole campaign.

use super::{CAMPAIGN_FORMAT, CampaignRecords, CampaignRun, ReachingRun, Shard};

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
