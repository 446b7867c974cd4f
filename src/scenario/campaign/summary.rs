//! The records summarised: per (cell, method) over the seeds, and per method over the cells.

use std::collections::BTreeMap;

use super::{Campaign, CampaignRun, Verdict};
use crate::scenario::Method;
use crate::scenario::method::MethodId;

/// A cell's numbers for one method, over its seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct CellSummary {
    pub cell: usize,
    pub method: MethodId,
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
    pub method: MethodId,
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
    let mut by: BTreeMap<(usize, &MethodId), Vec<&CampaignRun>> = BTreeMap::new();
    for r in runs {
        by.entry((r.cell, &r.method)).or_default().push(r);
    }
    let mut cells = Vec::new();
    for c in 0..campaign.cells.len() {
        let mut rows: Vec<CellSummary> = Vec::new();
        for m in &campaign.methods {
            let Some(rs) = by.get(&(c, m)) else { continue };
            rows.push(cell_summary(c, m.clone(), rs));
        }
        compare_with_references(&mut rows, tolerance);
        cells.extend(rows);
    }
    let methods = campaign
        .methods
        .iter()
        .map(|m| method_summary(campaign, &cells, m))
        .collect();
    (cells, methods)
}

/// One method's numbers in one cell, over its seeds (compared with the oracle and no-FT later).
fn cell_summary(c: usize, m: MethodId, rs: &[&CampaignRun]) -> CellSummary {
    let (mse_mean, mse_std) = mean_std(&rs.iter().map(|r| r.mse_post).collect::<Vec<_>>());
    let final_error_mean = mean_std(&rs.iter().map(|r| r.max_final_error).collect::<Vec<_>>()).0;
    let delays: Vec<f64> = rs.iter().filter_map(|r| r.delay).collect();
    let iso: Vec<bool> = rs.iter().filter_map(|r| r.isolation_correct).collect();
    let rec: Vec<f64> = rs.iter().filter_map(|r| r.recover_time).collect();
    let hours: f64 = rs.iter().map(|r| r.hours).sum();
    CellSummary {
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
    }
}

/// Each row's ratio to the oracle's post-fault MSE and the "worse than no-FT" flag, from the
/// cell's oracle and no-FT rows.
fn compare_with_references(rows: &mut [CellSummary], tolerance: f64) {
    let oracle = rows
        .iter()
        .find(|r| r.method == Method::Oracle)
        .map(|r| r.mse_post_mean);
    let no_ft = rows
        .iter()
        .find(|r| r.method == Method::NoFt)
        .map(|r| (r.mse_post_mean, r.final_error_mean));
    for r in rows.iter_mut() {
        r.ratio_to_oracle = oracle.map(|o| r.mse_post_mean / o);
        if let Some((m, f)) = no_ft
            && r.method != Method::NoFt
        {
            r.worse_than_no_ft =
                worse_than_no_ft(r.mse_post_mean, r.final_error_mean, m, f, tolerance);
        }
    }
}

/// A method's totals over the cells' summaries.
fn method_summary(campaign: &Campaign, cells: &[CellSummary], m: &MethodId) -> MethodSummary {
    let mine: Vec<&CellSummary> = cells.iter().filter(|c| c.method == *m).collect();
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
        method: m.clone(),
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
            healthy.iter().map(|c| c.false_alarms_per_hour).sum::<f64>() / healthy.len() as f64
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
