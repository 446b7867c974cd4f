//! The files of a campaign: `campaign.csv` (a row per cell x method x seed, then a row per
//! cell x method), `campaign.md` (a matrix per arm and the per-method summary), `campaign.json`,
//! `heatmap_<arm>.svg` (cells by methods, coloured by log10 of the ratio to the oracle's
//! post-fault MSE, failures crossed), `reaching.csv` and `records.json` (every run in full
//! precision: what `aift merge` reads). Every file is a function of the records alone, so a
//! merged set of shards writes the same bytes as the unsharded run.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::*;
use serde_json::json;

use super::{ReportError, write_atomic};
use crate::scenario::campaign::{
    Better, CAMPAIGN_FORMAT, Campaign, CampaignRecords, CellSummary, MethodSummary, PairComparison,
    ReachingProtocol, Verdict, compare, compare_all, summarise,
};
use crate::scenario::method::MethodId;

/// The records file of a run or shard.
pub const RECORDS: &str = "records.json";
/// The campaign as JSON (what `aift campaign --json` prints).
pub const CAMPAIGN_JSON: &str = "campaign.json";

/// A CSV field: quoted when it holds a comma, a quote or a newline.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| format!("{x}"))
}

fn sci(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1e}")
    } else {
        "-".into()
    }
}

/// Short form of a verdict and ratio for the matrix: `ok 1.2`, `deg 35`, `FAIL`, `DIV`.
fn entry(s: &CellSummary) -> String {
    let ratio = s.ratio_to_oracle.map_or(String::new(), |r| {
        if r < 100.0 {
            format!(" {r:.1}")
        } else {
            format!(" {r:.0e}")
        }
    });
    let mark = if s.worse_than_no_ft { "!" } else { "" };
    match s.verdict {
        Verdict::Recovered => format!("ok{ratio}{mark}"),
        Verdict::Degraded => format!("deg{ratio}{mark}"),
        Verdict::Failed => format!("FAIL ({}/{}){mark}", s.recovered, s.seeds),
        Verdict::Diverged => format!("DIV{mark}"),
    }
}

/// Writes a shard's records (what `aift merge` reads) into `dir` (which must exist).
pub fn write_shard(dir: &Path, records: &CampaignRecords) -> Result<(), ReportError> {
    write_atomic(
        &dir.join(RECORDS),
        serde_json::to_string(records)
            .expect("records serialise")
            .as_bytes(),
    )
}

/// Reads the records of a campaign folder or shard (`DIR/records.json`), for `aift merge`.
pub fn read_records(dir: &Path) -> Result<CampaignRecords, ReportError> {
    let path = dir.join(RECORDS);
    let text = crate::fsio::read_text(&path, crate::fsio::MAX_CALIBRATION_BYTES)?;
    let bad = |message: String| {
        ReportError::File(crate::fsio::FsError::BadOutput {
            path: path.clone(),
            message,
        })
    };
    let records: CampaignRecords =
        serde_json::from_str(&text).map_err(|e| bad(format!("not a campaign shard: {e}")))?;
    crate::scenario::campaign::check_records(&records).map_err(bad)?;
    Ok(records)
}

/// Merges shards (their folders) into the files of the whole campaign, written into `dir`
/// (which must exist); returns the merged records.
pub fn merge_into(
    dir: &Path,
    shards: &[std::path::PathBuf],
) -> Result<CampaignRecords, ReportError> {
    let records = shards
        .iter()
        .map(|d| read_records(d))
        .collect::<Result<Vec<_>, _>>()?;
    let merged = crate::scenario::campaign::merge(&records).map_err(ReportError::Merge)?;
    let campaign = Campaign::plan(merged.config.clone());
    write_campaign(dir, &campaign, &merged)?;
    Ok(merged)
}

/// Writes every campaign file into `dir` (which must exist), and the records.
pub fn write_campaign(
    dir: &Path,
    campaign: &Campaign,
    records: &CampaignRecords,
) -> Result<(), ReportError> {
    let (cells, methods) = summarise(campaign, &records.runs);
    let pairs = compare_all(campaign, &records.runs, compare::ALPHA);
    write_atomic(
        &dir.join(RECORDS),
        serde_json::to_string(records)
            .expect("records serialise")
            .as_bytes(),
    )?;
    write_atomic(
        &dir.join("campaign.csv"),
        csv(campaign, records, &cells, &pairs).as_bytes(),
    )?;
    write_atomic(
        &dir.join("campaign.md"),
        markdown(campaign, records, &cells, &methods, &pairs).as_bytes(),
    )?;
    let j =
        serde_json::to_string_pretty(&campaign_json(campaign, records, &cells, &methods, &pairs))
            .expect("serialisable");
    write_atomic(&dir.join(CAMPAIGN_JSON), j.as_bytes())?;
    if !records.reaching.is_empty() {
        write_atomic(
            &dir.join("reaching.csv"),
            reaching_csv(campaign, records).as_bytes(),
        )?;
    }
    for (a, arm) in campaign.config.arms.iter().enumerate() {
        heatmap(
            &dir.join(format!("heatmap_{}.svg", arm.name)),
            campaign,
            a,
            &cells,
        )?;
    }
    super::html::write_report(dir).map(|_| ())
}

fn csv(
    campaign: &Campaign,
    records: &CampaignRecords,
    cells: &[CellSummary],
    pairs: &[PairComparison],
) -> String {
    let mut out = String::from(
        "row,arm,cell,channel,kind,onset,method,seed,outcome,verdict,mse_post,mse_post_std,ratio_to_oracle,max_final_error,runaway,detected,detection_delay,isolation_correct,false_alarms,false_alarms_per_hour,recover_time,worse_than_no_ft,method_b,median_log10_ratio,w_plus,w_minus,p_value,better\n",
    );
    let cell_cols = |c: usize| {
        let cell = &campaign.cells[c];
        format!(
            "{},{},{},{},{}",
            field(&campaign.config.arms[cell.arm].name),
            field(&cell.label),
            field(&cell.channel),
            cell.kind,
            cell.onset.map_or("", |o| o.name())
        )
    };
    for r in &records.runs {
        let _ = writeln!(
            out,
            "run,{},{},{},{},{},{},,,{},{},{},{},{},{},,{},,,,,,,",
            cell_cols(r.cell),
            r.method,
            r.seed,
            r.outcome,
            r.verdict.name(),
            r.mse_post,
            r.max_final_error,
            r.runaway,
            r.detected.map_or(String::new(), |b| b.to_string()),
            opt(r.delay),
            r.isolation_correct.map_or(String::new(), |b| b.to_string()),
            r.false_alarms,
            opt(r.recover_time),
        );
    }
    for s in cells {
        let _ = writeln!(
            out,
            "cell,{},{},{},,{},{},{},{},{},{},{},{},{},,{},{},{},,,,,,",
            cell_cols(s.cell),
            s.method,
            s.seeds,
            s.verdict.name(),
            s.mse_post_mean,
            s.mse_post_std,
            opt(s.ratio_to_oracle),
            s.final_error_mean,
            s.runaways,
            s.seeds - s.missed_detections,
            opt(s.detection_delay_mean),
            opt(s.isolation_correct),
            s.false_alarms_per_hour,
            opt(s.recover_time_mean),
            s.worse_than_no_ft,
        );
    }
    for p in pairs {
        let _ = writeln!(
            out,
            "pair,{},{},{},,,,,,,,,,,,,,,{},{},{},{},{},{}",
            cell_cols(p.cell),
            p.a,
            p.seeds,
            p.b,
            p.median_log10_ratio,
            p.test.w_plus,
            p.test.w_minus,
            p.test.p_value,
            p.better_name(),
        );
    }
    out
}

/// The campaign.md section of paired comparisons: per ordered pair, the cells where the row's
/// method is better than the column's at 95 %.
fn comparisons_markdown(campaign: &Campaign, pairs: &[PairComparison]) -> String {
    let m = &campaign.methods;
    let seeds = campaign.config.seeds;
    let mut out = format!(
        "\n## Paired comparisons\n\nEntry (row A, column B): the cells where A's post-fault MSE is \
         lower than B's at the 5 % level (two-sided Wilcoxon signed-rank test over the {seeds} \
         seeds paired by seed, on log10 of the MSE ratio; a diverged run counts as the worst; \
         exact p-values; no correction for the number of cells: with no real difference about \
         2.5 % of cells favour each side by chance). Out of the cells both methods ran.\n"
    );
    if compare::smallest_p_value(seeds) >= compare::ALPHA {
        let _ = writeln!(
            out,
            "\nWith {seeds} seeds the smallest p-value the test can give is {:.3}: no cell can \
             reach 5 % (6 seeds are needed).",
            compare::smallest_p_value(seeds)
        );
    }
    out += "\n| A better than B |";
    for b in m {
        let _ = write!(out, " {b} |");
    }
    out += "\n|---|";
    out += &"---|".repeat(m.len());
    out += "\n";
    for a in m {
        let _ = write!(out, "| {a} |");
        for b in m {
            if a == b {
                out += " - |";
                continue;
            }
            let (wins, of) = pairs
                .iter()
                .filter(|p| (&p.a, &p.b) == (a, b) || (&p.a, &p.b) == (b, a))
                .fold((0, 0), |(w, n), p| {
                    let a_wins = (p.a == *a && p.better == Better::A)
                        || (p.b == *a && p.better == Better::B);
                    (w + usize::from(a_wins), n + 1)
                });
            let _ = write!(out, " {wins}/{of} |");
        }
        out += "\n";
    }
    out
}

fn markdown(
    campaign: &Campaign,
    records: &CampaignRecords,
    cells: &[CellSummary],
    methods: &[MethodSummary],
    pairs: &[PairComparison],
) -> String {
    let c = &campaign.config;
    // Run seeds other than 1, 2, ... (an evaluation campaign's) are named.
    let seeds = if c.first_seed == 1 {
        format!("{} seeds", c.seeds)
    } else {
        format!(
            "{} seeds from {}",
            c.seeds,
            crate::scenario::campaign::run_seed(c, 0)
        )
    };
    let mut out = format!(
        "# Campaign {} ({} cells x {} methods x {seeds}; fingerprint {})\n\n",
        c.name,
        campaign.cells.len(),
        campaign.methods.len(),
        records.fingerprint
    );
    // A campaign of the reaching benchmark alone has no cell: no summary and no matrices, only
    // each arm's conditions before the reaching table.
    let grid = !campaign.cells.is_empty();
    if grid {
        let _ = writeln!(
            out,
            "Entries: `ok` recovered in every seed (final error within {} rad), `deg` degraded \
         (within {} rad in the worst seed), `FAIL (k/n)` failed (k of n seeds recovered; a \
         runaway: a joint at its limit or {} rad off), `DIV` diverged; the number is the \
         post-fault MSE of the faulty joints over the oracle's; `!` marks worse than no-FT (MSE \
         over 1.5x no-FT's and {:.0e} rad^2 above it, or final error {} rad above it).\n",
            c.verdict.tolerance,
            c.verdict.degraded,
            c.verdict.runaway,
            (c.verdict.tolerance / 20.0).powi(2),
            0.5 * c.verdict.tolerance
        );
        out += "## Summary per method\n\n";
        out += "| method | recovered | degraded | failed | diverged | worse than no-FT | recovers where the oracle does | within 10x oracle | false alarms / h (healthy) |\n";
        out += "|---|---|---|---|---|---|---|---|---|\n";
        for m in methods {
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {} | {}/{} | {}/{} | {:.1} |",
                m.method,
                m.recovered,
                m.degraded,
                m.failed,
                m.diverged,
                m.worse_than_no_ft,
                m.recovers_where_oracle_does,
                m.oracle_recovers,
                m.within_10x_oracle,
                m.fault_cells,
                m.false_alarms_per_hour
            );
        }
        if campaign.methods.len() > 1 {
            out += &comparisons_markdown(campaign, pairs);
        }
    }
    for (a, arm) in c.arms.iter().enumerate() {
        let _ = write!(
            out,
            "\n## {} (`{}`)\n\n{}\n",
            arm.name,
            arm.scenario.display(),
            records
                .conditions
                .get(a)
                .map_or_else(String::new, |c| c.markdown())
        );
        if !grid {
            continue;
        }
        out += "\n| cell |";
        for m in &campaign.methods {
            let _ = write!(out, " {m} |");
        }
        out += "\n|---|";
        out += &"---|".repeat(campaign.methods.len());
        out += "\n";
        for (ci, cell) in campaign
            .cells
            .iter()
            .enumerate()
            .filter(|(_, c)| c.arm == a)
        {
            let _ = write!(out, "| {} |", cell.label);
            for m in &campaign.methods {
                let e = cells
                    .iter()
                    .find(|s| s.cell == ci && s.method == *m)
                    .map_or("-".to_string(), entry);
                let _ = write!(out, " {e} |");
            }
            out += "\n";
        }
    }
    if !records.reaching.is_empty() {
        out += &reaching_markdown(campaign, records);
    }
    out
}

/// Means per arm and method of the reaching benchmark.
fn reaching_rows(
    campaign: &Campaign,
    records: &CampaignRecords,
) -> Vec<(usize, MethodId, [f64; 5], usize, usize)> {
    let mut rows = Vec::new();
    for a in 0..campaign.config.arms.len() {
        for m in &campaign.methods {
            let rs: Vec<_> = records
                .reaching
                .iter()
                .filter(|r| r.arm == a && r.method == *m)
                .collect();
            if rs.is_empty() {
                continue;
            }
            let n = rs.len() as f64;
            let settled: Vec<f64> = rs.iter().filter_map(|r| r.settling_time).collect();
            let authors = campaign
                .config
                .reaching
                .as_ref()
                .is_some_and(|rc| rc.protocol == ReachingProtocol::Authors);
            let duration = campaign
                .config
                .reaching
                .as_ref()
                .map_or(0.0, |rc| rc.duration);
            rows.push((
                a,
                m.clone(),
                [
                    rs.iter().map(|r| r.belief_rmse).sum::<f64>() / n,
                    rs.iter().map(|r| r.overshoot).sum::<f64>() / n,
                    if authors {
                        // Their script counts a task that never settles as the run's length.
                        rs.iter()
                            .map(|r| r.settling_time.unwrap_or(duration))
                            .sum::<f64>()
                            / n
                    } else if settled.is_empty() {
                        f64::NAN
                    } else {
                        settled.iter().sum::<f64>() / settled.len() as f64
                    },
                    rs.iter().map(|r| r.steady_state_error).sum::<f64>() / n,
                    rs.iter().map(|r| r.false_alarms).sum::<usize>() as f64,
                ],
                rs.len() - settled.len(),
                rs.iter().filter(|r| r.outcome != "completed").count(),
            ));
        }
    }
    rows
}

/// The reaching table's heading and the sentence that defines its columns, per protocol.
pub(crate) fn reaching_heading(campaign: &Campaign) -> (String, String) {
    let Some(rc) = campaign.config.reaching.as_ref() else {
        return (String::new(), String::new());
    };
    let source = if rc.targets_file.is_some() {
        "tasks from the targets file"
    } else {
        "random tasks"
    };
    match rc.protocol {
        ReachingProtocol::Aift => (
            format!("Healthy reaching benchmark ({} {source} per arm)", rc.tasks),
            "Means over the tasks: belief RMSE (rad), overshoot beyond the target (% of the step), settling time into a 0.5 % band (s; tasks that never settle counted apart), steady-state error (rad), false alarms (total).".into(),
        ),
        ReachingProtocol::Authors => (
            format!(
                "Reaching benchmark, the authors' protocol ({} {source} per arm, {} s each)",
                rc.tasks, rc.duration
            ),
            format!(
                "Means over the tasks, as the authors' matlab/statistical_analysis.m defines them: belief RMSE = the mean over joints of the RMS of q(i) - mu(i), mu(i) the belief before reading q(i) (rad); overshoot and settling time of joint {} by MATLAB's stepinfo (0.5 % band; a task that never settles counts as its length, as their script means to; the count is given apart); steady-state error = the mean over joints of |mu_d - q(T)| (rad); false alarms (total).",
                rc.step_joint
            ),
        ),
    }
}

fn reaching_markdown(campaign: &Campaign, records: &CampaignRecords) -> String {
    let (title, definition) = reaching_heading(campaign);
    let mut out = format!(
        "\n## {title}\n\n{definition} Tasks whose run did not complete (diverged, chattering) are counted apart; their measures cover only the ticks they ran.\n\n| arm | method | belief RMSE | overshoot (%) | settling time (s) | not settled | steady-state error | false alarms | not completed |\n|---|---|---|---|---|---|---|---|---|\n"
    );
    for (a, m, v, unsettled, broken) in reaching_rows(campaign, records) {
        let _ = writeln!(
            out,
            "| {} | {m} | {} | {:.2} | {:.3} | {unsettled} | {} | {} | {broken} |",
            campaign.config.arms[a].name,
            sci(v[0]),
            v[1],
            v[2],
            sci(v[3]),
            v[4]
        );
    }
    out
}

fn reaching_csv(campaign: &Campaign, records: &CampaignRecords) -> String {
    let mut out = String::from(
        "arm,task,method,outcome,belief_rmse,overshoot_percent,settling_time,steady_state_error,false_alarms\n",
    );
    for r in &records.reaching {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{}",
            field(&campaign.config.arms[r.arm].name),
            r.task,
            r.method,
            r.outcome,
            r.belief_rmse,
            r.overshoot,
            opt(r.settling_time),
            r.steady_state_error,
            r.false_alarms
        );
    }
    out
}

pub fn campaign_json(
    campaign: &Campaign,
    records: &CampaignRecords,
    cells: &[CellSummary],
    methods: &[MethodSummary],
    pairs: &[PairComparison],
) -> serde_json::Value {
    json!({
        "format_version": CAMPAIGN_FORMAT,
        "aift_version": env!("CARGO_PKG_VERSION"),
        "campaign": campaign.config.name,
        "fingerprint": records.fingerprint,
        "arms": campaign.config.arms.iter().zip(&records.conditions).map(|(a, c)| json!({
            "name": a.name,
            "conditions": c.json(),
        })).collect::<Vec<_>>(),
        "seeds": campaign.config.seeds,
        "methods": campaign.methods.iter().map(|m| m.name()).collect::<Vec<_>>(),
        "verdict": {
            "tolerance": campaign.config.verdict.tolerance,
            "degraded": campaign.config.verdict.degraded,
            "runaway": campaign.config.verdict.runaway,
        },
        "cells": campaign.cells.iter().enumerate().map(|(i, c)| json!({
            "index": i,
            "arm": campaign.config.arms[c.arm].name,
            "label": c.label,
            "channel": c.channel,
            "kind": c.kind,
            "onset": c.onset.map(|o| o.name()),
            "results": cells.iter().filter(|s| s.cell == i).map(|s| json!({
                "method": s.method.name(),
                "verdict": s.verdict.name(),
                "recovered_seeds": s.recovered,
                "seeds": s.seeds,
                "mse_post_mean": s.mse_post_mean,
                "mse_post_std": s.mse_post_std,
                "ratio_to_oracle": s.ratio_to_oracle,
                "final_error_mean": s.final_error_mean,
                "runaways": s.runaways,
                "detection_delay_mean": s.detection_delay_mean,
                "missed_detections": s.missed_detections,
                "isolation_correct": s.isolation_correct,
                "false_alarms_per_hour": s.false_alarms_per_hour,
                "recover_time_mean": s.recover_time_mean,
                "worse_than_no_ft": s.worse_than_no_ft,
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "summary": methods.iter().map(|m| json!({
            "method": m.method.name(),
            "cells": m.cells,
            "recovered": m.recovered,
            "degraded": m.degraded,
            "failed": m.failed,
            "diverged": m.diverged,
            "worse_than_no_ft": m.worse_than_no_ft,
            "oracle_recovers": m.oracle_recovers,
            "recovers_where_oracle_does": m.recovers_where_oracle_does,
            "within_10x_oracle": m.within_10x_oracle,
            "fault_cells": m.fault_cells,
            "false_alarms_per_hour": m.false_alarms_per_hour,
        })).collect::<Vec<_>>(),
        "comparisons": {
            "test": "Wilcoxon signed-rank, two-sided, seeds paired, log10 of the post-fault MSE ratio a/b",
            "alpha": compare::ALPHA,
            "pairs": pairs.iter().map(|p| {
                let mut j = p.json();
                j["cell"] = json!(p.cell);
                j
            }).collect::<Vec<_>>(),
        },
        "reaching_heading": reaching_heading(campaign).0,
        "reaching_definition": reaching_heading(campaign).1,
        "reaching": reaching_rows(campaign, records).iter().map(|(a, m, v, unsettled, broken)| json!({
            "arm": campaign.config.arms[*a].name,
            "method": m.name(),
            "belief_rmse": v[0],
            "overshoot_percent": v[1],
            "settling_time": v[2],
            "not_settled": unsettled,
            "not_completed": broken,
            "steady_state_error": v[3],
            "false_alarms": v[4],
        })).collect::<Vec<_>>(),
    })
}

/// A colour for log10(ratio to the oracle): green at 0 (or below), through yellow, to red at 4.
fn colour(log_ratio: f64) -> RGBColor {
    let x = (log_ratio / 4.0).clamp(0.0, 1.0);
    let (r, g) = if x < 0.5 {
        (x * 2.0, 1.0)
    } else {
        (1.0, 2.0 - 2.0 * x)
    };
    RGBColor((60.0 + 180.0 * r) as u8, (60.0 + 160.0 * g) as u8, 70)
}

fn heatmap(
    path: &Path,
    campaign: &Campaign,
    arm: usize,
    cells: &[CellSummary],
) -> Result<(), ReportError> {
    let rows: Vec<(usize, &str)> = campaign
        .cells
        .iter()
        .enumerate()
        .filter(|(_, c)| c.arm == arm)
        .map(|(i, c)| (i, c.label.as_str()))
        .collect();
    let cols = &campaign.methods;
    let (cw, rh, left, top) = (90i32, 18i32, 220i32, 60i32);
    let width = (left + cw * cols.len() as i32 + 20) as u32;
    let height = (top + rh * rows.len() as i32 + 40) as u32;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| ReportError::Plot {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let title = format!(
            "{}: log10(post-fault MSE / oracle's); X failed or diverged",
            campaign.config.arms[arm].name
        );
        root.draw(&Text::new(title, (10, 10), ("sans-serif", 15)))
            .map_err(|e| err(&e))?;
        for (k, m) in cols.iter().enumerate() {
            root.draw(&Text::new(
                m.name().to_string(),
                (left + cw * k as i32 + 4, top - 18),
                ("sans-serif", 12),
            ))
            .map_err(|e| err(&e))?;
        }
        for (r, (ci, label)) in rows.iter().enumerate() {
            let y = top + rh * r as i32;
            root.draw(&Text::new(
                label.to_string(),
                (6, y + 3),
                ("sans-serif", 11),
            ))
            .map_err(|e| err(&e))?;
            for (k, m) in cols.iter().enumerate() {
                let x = left + cw * k as i32;
                let Some(s) = cells.iter().find(|s| s.cell == *ci && s.method == *m) else {
                    continue;
                };
                let lr = s.ratio_to_oracle.map_or(0.0, |v| v.max(1e-300).log10());
                root.draw(&Rectangle::new(
                    [(x, y), (x + cw - 2, y + rh - 2)],
                    colour(lr).filled(),
                ))
                .map_err(|e| err(&e))?;
                let text = match s.verdict {
                    Verdict::Failed | Verdict::Diverged => "X".to_string(),
                    _ => format!("{lr:.1}"),
                };
                root.draw(&Text::new(text, (x + 30, y + 3), ("sans-serif", 11)))
                    .map_err(|e| err(&e))?;
            }
        }
        root.present().map_err(|e| err(&e))?;
    }
    write_atomic(path, svg.as_bytes())
}
