//! Paired comparisons of methods in a campaign: the Wilcoxon signed-rank statistics written in
//! campaign.csv / campaign.json / campaign.md and printed by `aift compare` are those of the
//! per-seed post-fault MSEs of the run rows; bad input to `aift compare` is refused with exit 2.
//! (The test's statistic itself is checked by hand and by enumeration in
//! src/scenario/campaign/compare.rs.)

mod common;

use std::collections::BTreeMap;

use aift::scenario::campaign::signed_rank;

fn csv_rows(text: &str) -> Vec<BTreeMap<String, String>> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|l| {
            assert_eq!(l.split(',').count(), header.len(), "{l}");
            header
                .iter()
                .zip(l.split(','))
                .map(|(h, v)| (h.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

#[test]
fn a_campaign_compares_every_pair_of_methods_over_its_seeds() {
    let tmp = tempfile::tempdir().unwrap();
    // Six seeds: the fewest with which the two-sided exact test can reach 5 % (p >= 2 / 2^6).
    let text = common::tiny_campaign("pairs", "").replace("seeds = 1", "seeds = 6");
    std::fs::write(tmp.path().join("c.toml"), text).unwrap();
    common::aift_ok(&["campaign", "c.toml", "--out", "out"], tmp.path());
    let dir = tmp.path().join("out");
    let rows = csv_rows(&std::fs::read_to_string(dir.join("campaign.csv")).unwrap());
    let mse = |method: &str| -> BTreeMap<String, f64> {
        rows.iter()
            .filter(|r| r["row"] == "run" && r["method"] == method && r["cell"].contains("freeze"))
            .map(|r| (r["seed"].clone(), r["mse_post"].parse().unwrap()))
            .collect()
    };
    let (no_ft, oracle) = (mse("no-ft"), mse("oracle"));
    assert_eq!(no_ft.len(), 6);
    let d: Vec<f64> = no_ft
        .iter()
        .map(|(seed, m)| m.log10() - oracle[seed].log10())
        .collect();
    let expected = signed_rank(&d);
    let pairs: Vec<_> = rows
        .iter()
        .filter(|r| r["row"] == "pair" && r["cell"].contains("freeze"))
        .collect();
    assert_eq!(pairs.len(), 1, "one pair of methods in the fault cell");
    let p = pairs[0];
    assert_eq!(
        (p["method"].as_str(), p["method_b"].as_str()),
        ("no-ft", "oracle")
    );
    assert_eq!(p["seed"], "6");
    assert_eq!(p["w_plus"].parse::<f64>().unwrap(), expected.w_plus);
    assert_eq!(p["p_value"].parse::<f64>().unwrap(), expected.p_value);
    // A frozen encoder without fault tolerance: every seed's belief error is above the oracle's,
    // so the test is at its smallest p-value and favours the oracle.
    assert!(d.iter().all(|&x| x > 0.0), "{d:?}");
    assert!((expected.p_value - 2.0 / 64.0).abs() < 1e-15);
    assert_eq!(p["better"], "oracle");
    let md = std::fs::read_to_string(dir.join("campaign.md")).unwrap();
    assert!(md.contains("## Paired comparisons"), "{md}");
    assert!(md.contains("| oracle | 1/2 | - |"), "{md}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("campaign.json")).unwrap()).unwrap();
    let in_json = json["comparisons"]["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["better"] == "oracle")
        .expect("the fault cell's comparison");
    assert_eq!(in_json["p_value"].as_f64(), Some(expected.p_value));

    // `aift compare` prints the same, either order.
    let out = common::aift_ok(&["compare", "out", "oracle", "no-ft", "--json"], tmp.path());
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["a_better"], 1, "{doc}");
    assert_eq!(doc["b_better"], 0, "{doc}");
    let cell = doc["pairs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["cell"].as_str().unwrap().contains("freeze"))
        .unwrap();
    assert_eq!(cell["w_minus"].as_f64(), Some(expected.w_plus));
    assert_eq!(cell["p_value"].as_f64(), Some(expected.p_value));
    let out = common::aift_ok(&["compare", "out", "no-ft", "oracle"], tmp.path());
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(
        printed.contains("no-ft better than oracle in 0 cells, oracle better in 1"),
        "{printed}"
    );

    // Bad input: exit 2, naming what is wrong.
    for (args, named) in [
        (
            vec!["compare", "out", "hybrid", "oracle"],
            "not in campaign",
        ),
        (vec!["compare", "out", "nope", "oracle"], "nope"),
        (vec!["compare", "out", "oracle", "oracle"], "both"),
        (
            vec!["compare", "out", "no-ft", "oracle", "--alpha", "0.9"],
            "--alpha",
        ),
        (
            vec!["compare", "missing", "no-ft", "oracle"],
            "records.json",
        ),
    ] {
        let out = common::aift_in(&args, tmp.path());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(named), "{args:?}: {stderr}");
    }
}
