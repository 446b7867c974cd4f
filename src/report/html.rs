//! `report.html`: one self-contained page per run, table or campaign folder. The page embeds
//! everything it shows: uPlot (vendored, `assets/report/`) and the data for the zoomable time
//! series, SVG for the static plots, and a Content-Security-Policy that forbids every request,
//! so it opens offline and never reaches the network. `run`, `table` and `campaign` write it
//! beside their other files; [`write_report`] (`aift report DIR`) writes it for an existing
//! folder.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::{ReportError, write_atomic};
use crate::fsio::{self, FsError};
use crate::scenario::TrajectoryRecorder;

/// The page's file name.
pub const REPORT: &str = "report.html";

/// Rows of a trajectory a run page embeds (decimated evenly past that).
pub const REPORT_ROWS: usize = 4000;

/// Largest JSON file (summary, table, campaign) a report reads.
const MAX_JSON_BYTES: u64 = 256 << 20;
/// Largest other text file (resolved scenario, runs.csv, heatmap SVG) a report reads.
const MAX_TEXT_BYTES: u64 = 64 << 20;

const UPLOT_JS: &str = include_str!("../../assets/report/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("../../assets/report/uPlot.min.css");
const REPORT_JS: &str = include_str!("../../assets/report/report.js");
const REPORT_CSS: &str = include_str!("../../assets/report/report.css");

/// What kind of folder a report is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FolderKind {
    Run,
    Table,
    Campaign,
}

impl FolderKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Run => "run",
            Self::Table => "table",
            Self::Campaign => "campaign",
        }
    }

    /// What the folder holds: a run (summary.json and trajectory.csv), a table (table.json) or
    /// a campaign (campaign.json).
    pub fn detect(dir: &Path) -> Result<Self, ReportError> {
        let meta = std::fs::metadata(dir).map_err(|source| FsError::Read {
            path: dir.to_path_buf(),
            source,
        })?;
        if !meta.is_dir() {
            return Err(bad(dir, "not a folder".into()));
        }
        if dir.join("summary.json").is_file() && dir.join("trajectory.csv").is_file() {
            Ok(Self::Run)
        } else if dir.join(super::campaign_files::CAMPAIGN_JSON).is_file() {
            Ok(Self::Campaign)
        } else if dir.join(super::table_files::TABLE_JSON).is_file() {
            Ok(Self::Table)
        } else {
            Err(bad(
                dir,
                "not a run, table or campaign folder: it holds neither summary.json and \
                 trajectory.csv, nor table.json, nor campaign.json"
                    .into(),
            ))
        }
    }
}

fn bad(path: &Path, message: String) -> ReportError {
    ReportError::File(FsError::BadOutput {
        path: path.to_path_buf(),
        message,
    })
}

/// Writes `report.html` into the run, table or campaign folder `dir` from the files there.
pub fn write_report(dir: &Path) -> Result<(FolderKind, PathBuf), ReportError> {
    let kind = FolderKind::detect(dir)?;
    let page = match kind {
        FolderKind::Run => {
            let path = dir.join("summary.json");
            let summary = read_json(&path)?;
            super::shape::check_summary(&summary).map_err(|e| bad(&path, e))?;
            let resolved = read_optional(&dir.join(super::run_files::RESOLVED))?;
            let (rows, total) =
                TrajectoryRecorder::read_csv_decimated(&dir.join("trajectory.csv"), REPORT_ROWS)?;
            run_page(&summary, resolved.as_deref(), &rows, total)
        }
        FolderKind::Table => table_page(dir)?,
        FolderKind::Campaign => campaign_page(dir)?,
    };
    let path = dir.join(REPORT);
    write_atomic(&path, page.as_bytes())?;
    Ok((kind, path))
}

fn read_json(path: &Path) -> Result<Value, ReportError> {
    let text = fsio::read_text(path, MAX_JSON_BYTES)?;
    let v: Value = serde_json::from_str(&text).map_err(|e| bad(path, format!("not JSON: {e}")))?;
    match v.get("format_version").and_then(Value::as_u64) {
        Some(_) => Ok(v),
        None => Err(bad(
            path,
            "`format_version`: missing; not a file aift wrote".into(),
        )),
    }
}

fn read_optional(path: &Path) -> Result<Option<String>, ReportError> {
    if path.exists() {
        Ok(Some(fsio::read_text(path, MAX_TEXT_BYTES)?))
    } else {
        Ok(None)
    }
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A number for people: 4 significant digits, scientific when small or large.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 || v == v.trunc() && v.abs() < 1e6 {
        return format!("{v}");
    }
    if (1e-3..1e5).contains(&v.abs()) {
        format!("{v:.4}")
    } else {
        format!("{v:.3e}")
    }
}

fn value_html(v: &Value) -> String {
    match v {
        Value::Null => "-".into(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.as_f64().map_or_else(|| n.to_string(), num),
        Value::String(s) => esc(s),
        Value::Array(a) if a.iter().all(|x| !x.is_object()) => {
            a.iter().map(value_html).collect::<Vec<_>>().join(", ")
        }
        Value::Array(a) => a.iter().map(value_html).collect::<Vec<_>>().join("<br>"),
        Value::Object(o) => o
            .iter()
            .map(|(k, x)| format!("{}: {}", esc(k), value_html(x)))
            .collect::<Vec<_>>()
            .join("; "),
    }
}

/// The page around a body: styles, uPlot, the data as JSON, the drawing script. The CSP allows
/// inline script and style only: no request of any kind.
fn page(title: &str, subtitle: &str, body: &str, data: &Value) -> String {
    // `<` never appears raw inside the data's script element.
    let data = serde_json::to_string(data)
        .expect("report data serialises")
        .replace('<', "\\u003c");
    format!(
        r#"<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; img-src data:">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="aift {version}">
<title>{title}</title>
<style>{UPLOT_CSS}
{REPORT_CSS}</style>
</head>
<body>
<h1>{title}</h1>
<p class="sub">{subtitle}</p>
{body}
<p class="note">Written by aift {version}. Drag across a plot to zoom in, double-click to zoom out; red dashed lines mark fault onsets.</p>
<script>{UPLOT_JS}</script>
<script type="application/json" id="aift-data">{data}</script>
<script>{REPORT_JS}</script>
</body>
</html>
"#,
        title = esc(title),
        subtitle = esc(subtitle),
        version = env!("CARGO_PKG_VERSION"),
    )
}

/// A column of the embedded data: values, NaN and infinities as null (a gap in the plot).
fn column(values: impl Iterator<Item = f64>) -> Value {
    Value::Array(
        values
            .map(|v| if v.is_finite() { json!(v) } else { Value::Null })
            .collect(),
    )
}

/// The page of one run: summary, zoomable joints, belief error, health, detector and free
/// energy, the resolved scenario. `rows` are the (decimated) rows of the trajectory, `total`
/// the rows of the whole file.
pub fn run_page(
    summary: &Value,
    resolved: Option<&str>,
    rows: &TrajectoryRecorder,
    total: u64,
) -> String {
    let s = |k: &str| summary.get(k).cloned().unwrap_or(Value::Null);
    let text = |k: &str| s(k).as_str().map(String::from).unwrap_or_default();
    let title = format!(
        "{}: {} (seed {})",
        text("scenario"),
        text("method"),
        s("seed")
    );
    let (columns, plots, missing) = run_plots(rows);
    let faults: Vec<f64> = s("faults")
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|f| f.get("start").and_then(Value::as_f64))
                .collect()
        })
        .unwrap_or_default();

    let mut body = run_summary(summary);
    let _ = write!(
        body,
        "<h2 id=\"plots\">Plots</h2>\n<p class=\"note\">{} evenly spaced rows of the run's {} recorded rows.</p>\n<div class=\"grid\">",
        rows.rows.len(),
        total
    );
    for p in &plots {
        let _ = write!(
            body,
            "<div class=\"plot\" id=\"{}\"></div>",
            esc(p["id"].as_str().unwrap_or_default())
        );
    }
    body.push_str("</div>\n");
    if !missing.is_empty() {
        let _ = writeln!(
            body,
            "<p class=\"note\">Not plotted: {}.</p>",
            esc(&missing.join("; "))
        );
    }
    body.push_str("<h2 id=\"scenario\">Scenario as run</h2>\n");
    match resolved {
        Some(text) => {
            let _ = writeln!(body, "<pre>{}</pre>", esc(text));
        }
        None => body.push_str("<p>(no scenario.resolved.toml in the folder)</p>\n"),
    }
    let subtitle = format!(
        "outcome {} | {} ticks | aift {}",
        text("outcome"),
        s("ticks"),
        text("aift_version")
    );
    let data = json!({"x": "t", "columns": columns, "plots": plots, "faults": faults});
    page(&title, &subtitle, &body, &data)
}

/// The embedded columns and the plots of a run (joints, belief error, health, detector, free
/// energy), and what could not be plotted.
fn run_plots(
    rows: &TrajectoryRecorder,
) -> (
    serde_json::Map<String, Value>,
    Vec<Value>,
    Vec<&'static str>,
) {
    let series = |name: &str| rows.series(name).unwrap_or_default();
    let n = rows.n_joints();
    let mut columns = serde_json::Map::new();
    let mut plots = Vec::new();
    columns.insert("t".into(), column(series("t").into_iter()));
    for j in 1..=n {
        for prefix in ["q", "mu", "target"] {
            let name = format!("{prefix}{j}");
            columns.insert(name.clone(), column(series(&name).into_iter()));
        }
        let err = series(&format!("mu{j}"))
            .into_iter()
            .zip(series(&format!("q{j}")))
            .map(|(m, q)| m - q);
        columns.insert(format!("err{j}"), column(err));
        plots.push(json!({
            "id": format!("joint-{j}"), "title": format!("Joint {j} (rad)"), "ylabel": "rad",
            "series": [
                {"label": format!("q{j} (plant)"), "column": format!("q{j}"), "color": "#1b1f24"},
                {"label": format!("mu{j} (belief)"), "column": format!("mu{j}"), "color": "#0969da"},
                {"label": format!("target{j}"), "column": format!("target{j}"), "color": "#1a7f37", "dash": [6, 4]},
            ],
        }));
    }
    plots.push(json!({
        "id": "belief-error", "title": "Belief error mu - q (rad)", "ylabel": "rad",
        "series": (1..=n).map(|j| json!({"label": format!("joint {j}"), "column": format!("err{j}")})).collect::<Vec<_>>(),
    }));
    let with_prefix = |prefix: &str| -> Vec<String> {
        rows.header
            .iter()
            .filter(|h| h.starts_with(prefix))
            .cloned()
            .collect()
    };
    let health = with_prefix("health_");
    for h in &health {
        columns.insert(h.clone(), column(series(h).into_iter()));
    }
    plots.push(json!({
        "id": "health", "title": "Sensor health (learned precision / nominal)", "yrange": [0.0, 1.05],
        "series": health.iter().map(|h| json!({"label": h.trim_start_matches("health_"), "column": h})).collect::<Vec<_>>(),
    }));
    let any_finite = |name: &str| series(name).iter().any(|v| v.is_finite());
    let detector: Vec<String> = with_prefix("d_")
        .into_iter()
        .filter(|d| any_finite(d))
        .collect();
    let mut missing = Vec::new();
    if detector.is_empty() {
        missing.push("detector (this method runs none)");
    } else {
        for d in &detector {
            columns.insert(d.clone(), column(series(d).into_iter()));
        }
        columns.insert("alarm".into(), column(series("alarm").into_iter()));
        let mut list: Vec<Value> = detector
            .iter()
            .map(|d| json!({"label": d.trim_start_matches("d_"), "column": d}))
            .collect();
        list.push(json!({"label": "alarm (1 = fired)", "column": "alarm", "color": "#cf222e", "width": 2}));
        plots.push(json!({
            "id": "detector", "title": "Detector: normalised distance per sensor group", "series": list,
        }));
    }
    if any_finite("F") {
        columns.insert("F".into(), column(series("F").into_iter()));
        plots.push(json!({
            "id": "free-energy", "title": "Free energy F", "series": [{"label": "F", "column": "F"}],
        }));
    } else {
        missing.push("free energy (this estimator defines none)");
    }
    (columns, plots, missing)
}

/// The navigation, the summary table and the faults table of a run.
fn run_summary(summary: &Value) -> String {
    let s = |k: &str| summary.get(k).cloned().unwrap_or(Value::Null);
    let mut body = String::new();
    let _ = write!(
        body,
        "<nav><a href=\"#summary\">Summary</a><a href=\"#plots\">Plots</a><a href=\"#scenario\">Scenario</a></nav>\n<h2 id=\"summary\">Summary</h2>\n<table>"
    );
    for key in [
        "outcome",
        "diverged",
        "ticks",
        "mse_per_joint",
        "mse_faulty",
        "mse_healthy",
        "mse_post_fault_per_joint",
        "final_error_per_joint",
        "max_final_error",
        "detected_at",
        "detection_kind",
        "isolated_channel",
        "isolation_correct",
        "false_alarm",
        "false_alarms",
        "final_health",
        "min_health_last_5s",
    ] {
        let _ = write!(
            body,
            "<tr><th>{}</th><td>{}</td></tr>",
            esc(key),
            value_html(&s(key))
        );
    }
    body.push_str("</table>\n");
    if let Some(list) = s("faults").as_array().filter(|a| !a.is_empty()) {
        body.push_str("<h3>Faults</h3><table><tr><th>channel</th><th>kind</th><th>start (s)</th><th>end (s)</th><th>detected at</th><th>delay (s)</th><th>isolated</th><th>correct</th><th>MSE while active</th></tr>");
        for f in list {
            let g = |k: &str| value_html(f.get(k).unwrap_or(&Value::Null));
            let _ = write!(
                body,
                "<tr><td>{}</td><td>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td>{}</td><td>{}</td><td class=num>{}</td></tr>",
                g("channel"),
                g("kind"),
                g("start"),
                g("end"),
                g("detected_at"),
                g("delay"),
                g("isolated"),
                g("isolation_correct"),
                g("mse_during")
            );
        }
        body.push_str("</table>\n");
    }
    body
}

/// A strip plot (one row per method, a dot per seed, log-scaled x) as SVG.
fn strip_svg(title: &str, rows: &[(String, Vec<f64>)]) -> String {
    let values: Vec<f64> = rows
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    let (w, row_h, left, top) = (760.0, 22.0, 120.0, 34.0);
    let h = top + row_h * rows.len() as f64 + 34.0;
    let mut out = format!(
        "<svg class=\"static\" xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" role=\"img\"><title>{}</title><text x=\"4\" y=\"18\" font-size=\"14\" font-weight=\"600\">{}</text>",
        esc(title),
        esc(title)
    );
    if values.is_empty() {
        out.push_str("<text x=\"4\" y=\"40\" font-size=\"12\">no positive values</text></svg>");
        return out;
    }
    let lo = values
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .log10()
        .floor();
    let hi = values
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .log10()
        .ceil()
        .max(lo + 1.0);
    let x = |v: f64| left + (v.log10() - lo) / (hi - lo) * (w - left - 20.0);
    let axis_y = top + row_h * rows.len() as f64;
    let mut decade = lo;
    while decade <= hi {
        let px = x(10f64.powf(decade));
        let _ = write!(
            out,
            "<line x1=\"{px:.1}\" y1=\"{top}\" x2=\"{px:.1}\" y2=\"{axis_y}\" stroke=\"#d0d7de\"/><text x=\"{px:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"middle\">1e{decade}</text>",
            axis_y + 14.0
        );
        decade += 1.0;
    }
    for (i, (label, v)) in rows.iter().enumerate() {
        let cy = top + row_h * (i as f64 + 0.5);
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"12\" text-anchor=\"end\">{}</text>",
            left - 8.0,
            cy + 4.0,
            esc(label)
        );
        for value in v.iter().filter(|v| v.is_finite() && **v > 0.0) {
            let _ = write!(
                out,
                "<circle cx=\"{:.1}\" cy=\"{cy:.1}\" r=\"3.5\" fill=\"#0969da\" fill-opacity=\"0.55\"><title>{} {}</title></circle>",
                x(*value),
                esc(label),
                num(*value)
            );
        }
    }
    out.push_str("</svg>");
    out
}

/// Parses runs.csv into its header and rows of fields.
fn parse_csv(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap_or_default()
        .split(',')
        .map(String::from)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

/// The page of a table folder: the table and the per-method spreads over seeds.
fn table_page(dir: &Path) -> Result<String, ReportError> {
    let path = dir.join(super::table_files::TABLE_JSON);
    let doc = read_json(&path)?;
    super::shape::check_table(&doc).map_err(|e| bad(&path, e))?;
    let rows = doc["rows"].as_array().cloned().unwrap_or_default();
    let mut body = String::from(
        "<h2>Table</h2>\n<table><tr><th>method</th><th>seeds</th><th>MSE faulty joint</th><th>MSE healthy joint</th><th>max final error (rad)</th><th>ratio to oracle</th><th>post-fault MSE</th><th>detection delay (s)</th><th>isolation correct</th><th>false alarms</th><th>diverged</th><th>paper (faulty / healthy)</th></tr>",
    );
    for r in &rows {
        let g = |k: &str| value_html(r.get(k).unwrap_or(&Value::Null));
        let pm = |m: &str, s: &str| format!("{} &plusmn; {}", g(m), g(s));
        let _ = write!(
            body,
            "<tr><td>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td>{}</td></tr>",
            g("method"),
            g("seeds"),
            pm("mse_faulty_mean", "mse_faulty_std"),
            pm("mse_healthy_mean", "mse_healthy_std"),
            g("max_final_error_mean"),
            g("ratio_to_oracle"),
            g("mse_post_fault_mean"),
            g("detection_delay_mean"),
            g("isolation_correct"),
            g("false_alarms"),
            g("diverged"),
            g("paper_table1")
        );
    }
    body.push_str("</table>\n<h2>Spread over seeds</h2>\n");
    match read_optional(&dir.join("runs.csv"))? {
        Some(text) => {
            let (header, runs) = parse_csv(&text);
            let col = |name: &str| header.iter().position(|h| h == name);
            let methods: Vec<String> = rows
                .iter()
                .filter_map(|r| r["method"].as_str().map(String::from))
                .collect();
            let per_method = |c: Option<usize>| -> Vec<(String, Vec<f64>)> {
                methods
                    .iter()
                    .map(|m| {
                        let v = runs
                            .iter()
                            .filter(|r| r.first() == Some(m))
                            .filter_map(|r| c.and_then(|c| r.get(c)?.parse::<f64>().ok()))
                            .collect();
                        (m.clone(), v)
                    })
                    .collect()
            };
            let faulty = per_method(col("mse_faulty"));
            if faulty.iter().any(|(_, v)| !v.is_empty()) {
                body.push_str(&strip_svg("Faulty-joint MSE per seed", &faulty));
            }
            body.push_str(&strip_svg(
                "Healthy-joint MSE per seed",
                &per_method(col("mse_healthy")),
            ));
            let n = header
                .iter()
                .filter(|h| h.starts_with("final_error_joint"))
                .count();
            let finals: Vec<(String, Vec<f64>)> = methods
                .iter()
                .map(|m| {
                    let v = runs
                        .iter()
                        .filter(|r| r.first() == Some(m))
                        .filter_map(|r| {
                            (1..=n)
                                .filter_map(|j| {
                                    r.get(col(&format!("final_error_joint{j}"))?)?
                                        .parse::<f64>()
                                        .ok()
                                })
                                .reduce(f64::max)
                        })
                        .collect();
                    (m.clone(), v)
                })
                .collect();
            body.push_str(&strip_svg(
                "Largest final joint error per seed (rad)",
                &finals,
            ));
        }
        None => body.push_str("<p>(no runs.csv in the folder)</p>\n"),
    }
    let title = format!("Table: {}", doc["scenario"].as_str().unwrap_or("?"));
    let seeds = doc["seeds"]
        .as_array()
        .map(|a| a.len().to_string())
        .unwrap_or_else(|| "?".into());
    let subtitle = format!(
        "{} methods x {seeds} seeds | aift {}",
        rows.len(),
        doc["aift_version"].as_str().unwrap_or("?")
    );
    Ok(page(&title, &subtitle, &body, &json!({"plots": []})))
}

fn verdict_class(v: &str) -> &'static str {
    match v {
        "recovered" => "ok",
        "degraded" => "deg",
        "failed" => "fail",
        "diverged" => "div",
        _ => "",
    }
}

/// The page of a campaign folder: per-method summary, the heatmaps and the matrix per arm with
/// links down to each cell, each cell's numbers, the reaching benchmark.
fn campaign_page(dir: &Path) -> Result<String, ReportError> {
    let path = dir.join(super::campaign_files::CAMPAIGN_JSON);
    let doc = read_json(&path)?;
    super::shape::check_campaign(&doc).map_err(|e| bad(&path, e))?;
    let methods: Vec<String> = doc["methods"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|m| m.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default();
    let cells = doc["cells"].as_array().cloned().unwrap_or_default();
    let mut arms: Vec<String> = Vec::new();
    for c in &cells {
        if let Some(a) = c["arm"].as_str()
            && !arms.iter().any(|x| x == a)
        {
            arms.push(a.to_string());
        }
    }
    let mut body = campaign_summary(&arms, &doc);
    comparisons_matrix(&mut body, &methods, &doc);
    for arm in &arms {
        arm_matrix(&mut body, dir, arm, &methods, &cells)?;
    }
    cell_tables(&mut body, &cells);
    reaching_table(&mut body, &doc);
    let title = format!("Campaign: {}", doc["campaign"].as_str().unwrap_or("?"));
    let subtitle = format!(
        "{} cells x {} methods x {} seeds | fingerprint {} | aift {}",
        cells.len(),
        methods.len(),
        doc["seeds"],
        doc["fingerprint"].as_str().unwrap_or("?"),
        doc["aift_version"].as_str().unwrap_or("?")
    );
    Ok(page(&title, &subtitle, &body, &json!({"plots": []})))
}

/// The navigation (one link per arm) and the per-method table of a campaign.
fn campaign_summary(arms: &[String], doc: &Value) -> String {
    let mut body = String::from("<nav><a href=\"#summary\">Summary</a>");
    for a in arms {
        let _ = write!(body, "<a href=\"#arm-{}\">{}</a>", esc(a), esc(a));
    }
    if doc["comparisons"]["pairs"]
        .as_array()
        .is_some_and(|p| !p.is_empty())
    {
        body.push_str("<a href=\"#comparisons\">Comparisons</a>");
    }
    body.push_str("<a href=\"#cells\">Cells</a></nav>\n<h2 id=\"summary\">Per method</h2>\n<table><tr><th>method</th><th>cells</th><th>recovered</th><th>degraded</th><th>failed</th><th>diverged</th><th>worse than no-FT</th><th>recovers where the oracle does</th><th>within 10x the oracle</th><th>false alarms / h</th></tr>");
    for m in doc["summary"].as_array().into_iter().flatten() {
        let g = |k: &str| value_html(m.get(k).unwrap_or(&Value::Null));
        let _ = write!(
            body,
            "<tr><td>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}/{}</td><td class=num>{}/{}</td><td class=num>{}</td></tr>",
            g("method"),
            g("cells"),
            g("recovered"),
            g("degraded"),
            g("failed"),
            g("diverged"),
            g("worse_than_no_ft"),
            g("recovers_where_oracle_does"),
            g("oracle_recovers"),
            g("within_10x_oracle"),
            g("fault_cells"),
            g("false_alarms_per_hour")
        );
    }
    body.push_str("</table>\n");
    body
}

/// The paired comparisons (campaign.json's `comparisons`, when there are any): per ordered pair,
/// the cells where the row's method is better than the column's.
fn comparisons_matrix(body: &mut String, methods: &[String], doc: &Value) {
    let pairs: Vec<&Value> = doc["comparisons"]["pairs"]
        .as_array()
        .into_iter()
        .flatten()
        .collect();
    if pairs.is_empty() || methods.len() < 2 {
        return;
    }
    let _ = write!(
        body,
        "<h2 id=\"comparisons\">Paired comparisons</h2>\n<p>Entry (row A, column B): the cells where \
         A's post-fault MSE is lower than B's (Wilcoxon signed-rank over the seeds, two-sided, at \
         {}; no correction for the number of cells), out of the cells both ran.</p>\n<table><tr><th>A better than B</th>",
        value_html(&doc["comparisons"]["alpha"])
    );
    for m in methods {
        let _ = write!(body, "<th>{}</th>", esc(m));
    }
    body.push_str("</tr>");
    for a in methods {
        let _ = write!(body, "<tr><td>{}</td>", esc(a));
        for b in methods {
            if a == b {
                body.push_str("<td class=num>-</td>");
                continue;
            }
            let (mut wins, mut of) = (0, 0);
            for p in &pairs {
                let (pa, pb) = (p["a"].as_str(), p["b"].as_str());
                if (pa, pb) == (Some(a), Some(b)) || (pa, pb) == (Some(b), Some(a)) {
                    of += 1;
                    wins += usize::from(p["better"].as_str() == Some(a.as_str()));
                }
            }
            let _ = write!(body, "<td class=num>{wins}/{of}</td>");
        }
        body.push_str("</tr>");
    }
    body.push_str("</table>\n");
}

/// An arm's heatmap and its matrix (a row per cell, an entry per method linking to the cell).
fn arm_matrix(
    body: &mut String,
    dir: &Path,
    arm: &str,
    methods: &[String],
    cells: &[Value],
) -> Result<(), ReportError> {
    let _ = writeln!(body, "<h2 id=\"arm-{}\">{}</h2>", esc(arm), esc(arm));
    // The heatmap as an image (a data URI: the CSP allows it, and nothing in an SVG shown
    // as an image runs); only a plain file name is looked up.
    if arm.contains(['/', '\\']) || arm.contains("..") || arm.is_empty() {
        return Err(bad(
            &dir.join(super::campaign_files::CAMPAIGN_JSON),
            format!("`cells[].arm`: {arm:?} is not a plain name"),
        ));
    }
    let heatmap = dir.join(format!("heatmap_{arm}.svg"));
    if let Some(svg) = read_optional(&heatmap)? {
        use base64::Engine as _;
        let data = base64::engine::general_purpose::STANDARD.encode(svg.as_bytes());
        let _ = writeln!(
            body,
            "<img class=\"static\" alt=\"heatmap of {}\" src=\"data:image/svg+xml;base64,{data}\">",
            esc(arm)
        );
    }
    body.push_str("<table><tr><th>cell</th>");
    for m in methods {
        let _ = write!(body, "<th>{}</th>", esc(m));
    }
    body.push_str("</tr>");
    for c in cells.iter().filter(|c| c["arm"].as_str() == Some(arm)) {
        let index = c["index"].as_u64().unwrap_or(0);
        let _ = write!(
            body,
            "<tr><td><a href=\"#cell-{index}\">{}</a></td>",
            esc(c["label"].as_str().unwrap_or("?"))
        );
        let results = c["results"].as_array().cloned().unwrap_or_default();
        for m in methods {
            match results.iter().find(|r| r["method"].as_str() == Some(m)) {
                Some(r) => {
                    let verdict = r["verdict"].as_str().unwrap_or("");
                    let worse = r["worse_than_no_ft"].as_bool() == Some(true);
                    let ratio = r["ratio_to_oracle"]
                        .as_f64()
                        .map(|x| format!(" {}", num(x)))
                        .unwrap_or_default();
                    let _ = write!(
                        body,
                        "<td class=\"{}{}\" title=\"{}\">{}{}{}</td>",
                        verdict_class(verdict),
                        if worse { " worse" } else { "" },
                        esc(&format!(
                            "{m}: {verdict}, {}/{} seeds recovered",
                            r["recovered_seeds"], r["seeds"]
                        )),
                        esc(verdict),
                        ratio,
                        if worse { " !" } else { "" }
                    );
                }
                None => body.push_str("<td>-</td>"),
            }
        }
        body.push_str("</tr>");
    }
    body.push_str("</table>\n<p class=\"note\">Each entry: verdict and post-fault MSE as a ratio to the oracle's; ! and a red frame: worse than no-FT.</p>\n");
    Ok(())
}

/// Each cell's numbers, a row per method.
fn cell_tables(body: &mut String, cells: &[Value]) {
    body.push_str("<h2 id=\"cells\">Cells</h2>\n");
    let fields = [
        "verdict",
        "recovered_seeds",
        "seeds",
        "mse_post_mean",
        "mse_post_std",
        "ratio_to_oracle",
        "final_error_mean",
        "runaways",
        "detection_delay_mean",
        "missed_detections",
        "isolation_correct",
        "false_alarms_per_hour",
        "recover_time_mean",
        "worse_than_no_ft",
    ];
    for c in cells {
        let index = c["index"].as_u64().unwrap_or(0);
        let _ = write!(
            body,
            "<h3 id=\"cell-{index}\">{} / {} ({}{})</h3><table><tr><th>method</th>",
            esc(c["arm"].as_str().unwrap_or("?")),
            esc(c["label"].as_str().unwrap_or("?")),
            value_html(&c["kind"]),
            c["onset"]
                .as_str()
                .map(|o| format!(", onset {}", esc(o)))
                .unwrap_or_default()
        );
        for f in fields {
            let _ = write!(body, "<th>{}</th>", esc(&f.replace('_', " ")));
        }
        body.push_str("</tr>");
        for r in c["results"].as_array().into_iter().flatten() {
            let verdict = r["verdict"].as_str().unwrap_or("");
            let _ = write!(
                body,
                "<tr class=\"{}\"><td>{}</td>",
                verdict_class(verdict),
                value_html(&r["method"])
            );
            for f in fields {
                let _ = write!(body, "<td class=num>{}</td>", value_html(&r[f]));
            }
            body.push_str("</tr>");
        }
        body.push_str("</table>\n");
    }
}

/// The healthy reaching benchmark's table, if the campaign ran it.
fn reaching_table(body: &mut String, doc: &Value) {
    if let Some(reach) = doc["reaching"].as_array().filter(|a| !a.is_empty()) {
        let heading = doc["reaching_heading"]
            .as_str()
            .unwrap_or("Healthy reaching benchmark");
        let _ = write!(
            body,
            "<h2>{}</h2><p>{}</p>",
            esc(heading),
            esc(doc["reaching_definition"].as_str().unwrap_or(""))
        );
        body.push_str("<table><tr><th>arm</th><th>method</th><th>belief RMSE</th><th>overshoot %</th><th>settling time (s)</th><th>not settled</th><th>steady-state error</th><th>false alarms</th><th>not completed</th></tr>");
        for r in reach {
            let g = |k: &str| value_html(r.get(k).unwrap_or(&Value::Null));
            let _ = write!(
                body,
                "<tr><td>{}</td><td>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td><td class=num>{}</td></tr>",
                g("arm"),
                g("method"),
                g("belief_rmse"),
                g("overshoot_percent"),
                g("settling_time"),
                g("not_settled"),
                g("steady_state_error"),
                g("false_alarms"),
                g("not_completed")
            );
        }
        body.push_str("</table>\n");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup_and_keeps_script_data_inert() {
        assert_eq!(
            esc("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
        let p = page(
            "t",
            "s",
            "",
            &json!({"x": "</script><script>alert(1)</script>"}),
        );
        let data = p.split("id=\"aift-data\">").nth(1).unwrap();
        let data = data.split("</script>").next().unwrap();
        assert!(!data.contains('<'), "{data}");
        let back: Value = serde_json::from_str(data).unwrap();
        assert_eq!(back["x"], "</script><script>alert(1)</script>");
    }

    #[test]
    fn numbers_read_well() {
        assert_eq!(num(0.0), "0");
        assert_eq!(num(20000.0), "20000");
        assert_eq!(num(0.5), "0.5000");
        assert_eq!(num(9.398e-8), "9.398e-8");
        assert_eq!(value_html(&Value::Null), "-");
    }

    #[test]
    fn strip_plot_places_decades_and_dots() {
        let svg = strip_svg(
            "x",
            &[("a".into(), vec![1e-3, 1e-1]), ("b".into(), vec![f64::NAN])],
        );
        assert_eq!(svg.matches("<circle").count(), 2);
        assert!(svg.contains(">1e-3<") && svg.contains(">1e-1<"));
    }
}
