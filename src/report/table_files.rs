//! The files of a Monte Carlo table: table.csv, table.md (beside the paper's Table 1),
//! table.json and runs.csv.

use std::path::Path;

use serde_json::json;

use super::{ReportError, write_atomic};
use crate::scenario::table::Table;
use crate::scenario::{Method, RunSetup};

/// Version of table.json's layout.
pub const TABLE_FORMAT: u32 = 2;
/// The table as JSON (what `aift table --json` prints).
pub const TABLE_JSON: &str = "table.json";

/// Writes the four table files into `dir`.
pub fn write_table(dir: &Path, setup: &RunSetup, table: &Table) -> Result<(), ReportError> {
    write_atomic(&dir.join("runs.csv"), runs_csv(table).as_bytes())?;
    write_atomic(&dir.join("table.csv"), table_csv(table).as_bytes())?;
    let json = serde_json::to_string_pretty(&table_json(setup, table)).expect("serialisable");
    write_atomic(&dir.join(TABLE_JSON), json.as_bytes())?;
    write_atomic(
        &dir.join("table.md"),
        table_markdown(setup, table).as_bytes(),
    )?;
    super::html::write_report(dir).map(|_| ())
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| format!("{x}"))
}

/// table.csv: a row per method.
pub fn table_csv(table: &Table) -> String {
    let mut out = String::from(
        "method,seeds,mse_faulty_mean,mse_faulty_std,mse_healthy_mean,mse_healthy_std,max_final_error_mean,ratio_to_oracle,mse_post_fault_mean,detection_delay_mean,isolation_correct,false_alarms,diverged\n",
    );
    for r in &table.rows {
        out += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.name,
            r.seeds,
            opt(r.mse_faulty_mean),
            opt(r.mse_faulty_std),
            opt(r.mse_healthy_mean),
            opt(r.mse_healthy_std),
            r.max_final_error_mean,
            opt(r.ratio_to_oracle),
            opt(r.mse_post_fault_mean),
            opt(r.detection_delay_mean),
            opt(r.isolation_correct),
            r.false_alarms,
            r.diverged
        );
    }
    out
}

/// runs.csv: a row per (method, seed).
pub fn runs_csv(table: &Table) -> String {
    let n = table.runs.first().map_or(0, |r| r.mse_per_joint.len());
    let mut out = String::from("method,seed,outcome,mse_faulty,mse_healthy");
    for j in 1..=n {
        out += &format!(",mse_joint{j}");
    }
    for j in 1..=n {
        out += &format!(",final_error_joint{j}");
    }
    out += ",detected_at,isolated_channel,isolation_correct,false_alarm\n";
    for r in &table.runs {
        out += &format!(
            "{},{},{},{},{}",
            r.method,
            r.seed,
            r.outcome.name(),
            opt(r.mse_faulty),
            opt(r.mse_healthy)
        );
        for v in &r.mse_per_joint {
            out += &format!(",{v}");
        }
        for v in &r.final_error_per_joint {
            out += &format!(",{v}");
        }
        out += &format!(
            ",{},{},{},{}\n",
            opt(r.detected_at),
            r.isolated_channel.clone().unwrap_or_default(),
            r.isolation_correct
                .map_or_else(String::new, |b| b.to_string()),
            r.false_alarm
        );
    }
    out
}

/// table.json: the rows plus the scenario and seeds.
pub fn table_json(setup: &RunSetup, table: &Table) -> serde_json::Value {
    json!({
        "format_version": TABLE_FORMAT,
        "aift_version": env!("CARGO_PKG_VERSION"),
        "scenario": setup.scenario().name,
        "conditions": setup.conditions().json(),
        "seeds": table.seeds,
        "rows": table.rows.iter().map(|r| json!({
            "method": r.name,
            "seeds": r.seeds,
            "mse_faulty_mean": r.mse_faulty_mean,
            "mse_faulty_std": r.mse_faulty_std,
            "mse_healthy_mean": r.mse_healthy_mean,
            "mse_healthy_std": r.mse_healthy_std,
            "max_final_error_mean": r.max_final_error_mean,
            "ratio_to_oracle": r.ratio_to_oracle,
            "mse_post_fault_mean": r.mse_post_fault_mean,
            "detection_delay_mean": r.detection_delay_mean,
            "isolation_correct": r.isolation_correct,
            "false_alarms": r.false_alarms,
            "diverged": r.diverged,
            "paper_table1": r.method.and_then(|m| m.paper_table1()).filter(|_| is_paper_experiment(setup)).map(|(f, h)| json!({"faulty": f, "healthy": h})),
        })).collect::<Vec<_>>(),
    })
}

fn sci(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), |x| format!("{x:.2e}"))
}

/// Whether the scenario is the paper's experiment (a single encoder freeze), the only one its
/// Table 1 speaks of.
pub fn is_paper_experiment(setup: &RunSetup) -> bool {
    use crate::sensors::{Channel, FaultKind};
    matches!(
        setup.faults.as_slice(),
        [f] if f.kind == FaultKind::Freeze {}
            && matches!(f.channels.as_slice(), [c] if matches!(setup.layout.channel(*c), Channel::Encoder(_)))
    )
}

/// table.md: ours beside the paper's Table 1 (for the paper's experiment, an encoder freeze).
pub fn table_markdown(setup: &RunSetup, table: &Table) -> String {
    let paper_columns = is_paper_experiment(setup);
    let mut out = format!(
        "# {} over {} seeds ({}..={})\n\n{}\n\nMSE of the belief against the truth, (mu - q)^2 averaged over the run; \
         faulty = joints whose own sensor is faulty, healthy = the others. {}\n\n",
        setup.scenario().name,
        table.seeds.len(),
        table.seeds.first().copied().unwrap_or(0),
        table.seeds.last().copied().unwrap_or(0),
        setup.conditions().markdown(),
        if paper_columns {
            "Paper = the seed paper's Table 1 (the same experiment: an encoder freeze)."
        } else {
            "The paper's Table 1 is about an encoder freeze, not this scenario: its columns stay empty."
        }
    );
    out += "| method | faulty MSE (ours) | paper | healthy MSE (ours) | paper | x oracle | max final error (rad) | detection delay (s) | isolation correct | false alarms | diverged |\n";
    out += "|---|---|---|---|---|---|---|---|---|---|---|\n";
    for r in &table.rows {
        let paper = r
            .method
            .and_then(|m| m.paper_table1())
            .filter(|_| paper_columns);
        out += &format!(
            "| {} | {} ± {} | {} | {} ± {} | {} | {} | {:.4} | {} | {} | {} | {} |\n",
            r.name,
            sci(r.mse_faulty_mean),
            sci(r.mse_faulty_std),
            sci(paper.map(|p| p.0)),
            sci(r.mse_healthy_mean),
            sci(r.mse_healthy_std),
            sci(paper.map(|p| p.1)),
            r.ratio_to_oracle.map_or("-".into(), |x| if x < 1000.0 {
                format!("{x:.2}")
            } else {
                format!("{x:.1e}")
            }),
            r.max_final_error_mean,
            r.detection_delay_mean
                .map_or("-".into(), |x| format!("{x:.3}")),
            r.isolation_correct
                .map_or("-".into(), |x| format!("{:.0} %", 100.0 * x)),
            r.false_alarms,
            r.diverged
        );
    }
    out += "\nDetection delay: the detector's alarm for pl-detect and deterministic; for the other methods \
            the first time a channel's health fell below 0.1 and stayed there 20 ms. The oracle zeroes the faulty channel's \
            precision at the fault time; it is the reference, not a usable method.\n";
    if table.rows.iter().any(|r| r.method == Some(Method::Oracle)) {
        out += "`x oracle`: the method's faulty-joint MSE over the oracle's (all-joint MSE when no joint has a faulty sensor).\n";
    }
    out
}
