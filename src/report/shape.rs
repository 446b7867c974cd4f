//! The shape of the JSON files a report is built from (`summary.json`, `table.json`,
//! `campaign.json`): every field the page reads has the type the writers give it, so that a
//! damaged or hand-edited file is an error naming the file, the row and the field, not an empty
//! page. The writers are `run_files`, `table_files` and `campaign_files`.

use serde_json::Value;

/// What a field may hold.
#[derive(Clone, Copy)]
enum Want {
    Str,
    /// A string or null.
    OptStr,
    Int,
    /// A number or null (means, ratios, delays).
    OptNum,
    Bool,
    /// An object or null.
    OptObj,
    /// An array of strings.
    Strs,
}

impl Want {
    fn name(self) -> &'static str {
        match self {
            Self::Str => "a string",
            Self::OptStr => "a string or null",
            Self::Int => "a whole number >= 0",
            Self::OptNum => "a number or null",
            Self::Bool => "true or false",
            Self::OptObj => "a table (object) or null",
            Self::Strs => "a list of strings",
        }
    }

    fn accepts(self, v: &Value) -> bool {
        match self {
            Self::Str => v.is_string(),
            Self::OptStr => v.is_string() || v.is_null(),
            Self::Int => v.is_u64(),
            Self::OptNum => v.is_number() || v.is_null(),
            Self::Bool => v.is_boolean(),
            Self::OptObj => v.is_object() || v.is_null(),
            Self::Strs => v.as_array().is_some_and(|a| a.iter().all(Value::is_string)),
        }
    }
}

fn kind_of(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "a table",
    }
}

/// Checks that `v` at `at` is an object with each field as wanted (every field required).
fn fields(v: &Value, at: &str, want: &[(&str, Want)]) -> Result<(), String> {
    let obj = v
        .as_object()
        .ok_or_else(|| format!("{at}: expected a table, found {}", kind_of(v)))?;
    for (key, w) in want {
        let here = if at.is_empty() {
            format!("`{key}`")
        } else {
            format!("{at}.{key}")
        };
        match obj.get(*key) {
            None => return Err(format!("{here}: missing")),
            Some(x) if !w.accepts(x) => {
                return Err(format!(
                    "{here}: expected {}, found {}",
                    w.name(),
                    kind_of(x)
                ));
            }
            Some(_) => {}
        }
    }
    Ok(())
}

fn list<'a>(v: &'a Value, key: &str, non_empty: bool) -> Result<&'a Vec<Value>, String> {
    let a = v
        .get(key)
        .ok_or_else(|| format!("`{key}`: missing"))?
        .as_array()
        .ok_or_else(|| format!("`{key}`: expected a list, found {}", kind_of(&v[key])))?;
    if non_empty && a.is_empty() {
        return Err(format!("`{key}`: empty"));
    }
    Ok(a)
}

/// `summary.json` of a run.
pub fn check_summary(doc: &Value) -> Result<(), String> {
    use Want::*;
    fields(
        doc,
        "",
        &[
            ("scenario", Str),
            ("method", Str),
            ("seed", Int),
            ("outcome", Str),
            ("ticks", Int),
        ],
    )
}

/// `table.json` of a table.
pub fn check_table(doc: &Value) -> Result<(), String> {
    use Want::*;
    fields(doc, "", &[("scenario", Str), ("aift_version", Str)])?;
    list(doc, "seeds", true)?;
    for (i, row) in list(doc, "rows", true)?.iter().enumerate() {
        fields(
            row,
            &format!("`rows[{i}]`"),
            &[
                ("method", Str),
                ("seeds", Int),
                ("mse_faulty_mean", OptNum),
                ("mse_faulty_std", OptNum),
                ("mse_healthy_mean", OptNum),
                ("mse_healthy_std", OptNum),
                ("max_final_error_mean", OptNum),
                ("ratio_to_oracle", OptNum),
                ("mse_post_fault_mean", OptNum),
                ("detection_delay_mean", OptNum),
                ("isolation_correct", OptNum),
                ("false_alarms", Int),
                ("diverged", Int),
                ("paper_table1", OptObj),
            ],
        )?;
    }
    Ok(())
}

/// `campaign.json` of a campaign.
pub fn check_campaign(doc: &Value) -> Result<(), String> {
    use Want::*;
    fields(
        doc,
        "",
        &[
            ("campaign", Str),
            ("fingerprint", Str),
            ("aift_version", Str),
            ("methods", Strs),
            ("seeds", Int),
        ],
    )?;
    for (i, arm) in list(doc, "arms", true)?.iter().enumerate() {
        fields(arm, &format!("`arms[{i}]`"), &[("name", Str)])?;
    }
    // A campaign of the reaching benchmark alone has no cells.
    for (i, cell) in list(doc, "cells", false)?.iter().enumerate() {
        let at = format!("`cells[{i}]`");
        fields(
            cell,
            &at,
            &[
                ("arm", Str),
                ("channel", Str),
                ("index", Int),
                ("kind", Str),
                ("label", Str),
                ("onset", OptStr),
            ],
        )?;
        for (k, r) in list(cell, "results", true)
            .map_err(|e| format!("{at}.{}", e.trim_start_matches('`').replacen('`', "", 1)))?
            .iter()
            .enumerate()
        {
            let at = format!("{at}.results[{k}]");
            fields(
                r,
                &at,
                &[
                    ("method", Str),
                    ("verdict", Str),
                    ("seeds", Int),
                    ("recovered_seeds", Int),
                    ("runaways", Int),
                    ("missed_detections", Int),
                    ("mse_post_mean", OptNum),
                    ("mse_post_std", OptNum),
                    ("final_error_mean", OptNum),
                    ("ratio_to_oracle", OptNum),
                    ("detection_delay_mean", OptNum),
                    ("recover_time_mean", OptNum),
                    ("false_alarms_per_hour", OptNum),
                    ("isolation_correct", OptNum),
                    ("worse_than_no_ft", Bool),
                ],
            )?;
            let v = r["verdict"].as_str().unwrap_or_default();
            if !["recovered", "degraded", "failed", "diverged"].contains(&v) {
                return Err(format!("{at}.verdict: {v:?} is not a verdict"));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn a_wrong_type_is_named_with_its_row_and_field() {
        let row = json!({"method": "no-ft", "seeds": 3, "mse_faulty_mean": "x",
            "mse_faulty_std": 0.0, "mse_healthy_mean": 0.0, "mse_healthy_std": 0.0,
            "max_final_error_mean": 0.0, "ratio_to_oracle": null, "mse_post_fault_mean": null,
            "detection_delay_mean": null, "isolation_correct": null, "false_alarms": 0,
            "diverged": 0, "paper_table1": null});
        let doc = json!({"scenario": "s", "aift_version": "0", "seeds": [1], "rows": [row]});
        let e = check_table(&doc).unwrap_err();
        assert!(
            e.contains("`rows[0]`.mse_faulty_mean") && e.contains("a string"),
            "{e}"
        );
        let mut ok = doc.clone();
        ok["rows"][0]["mse_faulty_mean"] = json!(1e-3);
        check_table(&ok).unwrap();
        ok["rows"] = json!([]);
        assert!(check_table(&ok).unwrap_err().contains("`rows`: empty"));
    }
}
