//! The hybrid's model error as a state (`hybrid.model_error_state`, docs/method.md, "Model error
//! as a state"): the bank's filters carry each joint's model-error acceleration as a random walk
//! stepped by the change of the parameter-error torques. On generated arms no screen or campaign
//! uses (`aift gen-arm --seed 78001..=78006`, `aift init`; model error drawn; the campaign's
//! articulated engine), healthy runs raise no more false alarms with the state than without,
//! and wherever the oracle (told the faulty channel) recovers from the last joint's tachometer
//! frozen while the arm moves, the hybrid with the state recovers too. The unit tests beside
//! the code check the prediction against dense equations, the step against M^-1 and a fixed
//! model error as the state's fixed point.

mod common;

use std::path::Path;

/// One 15 s run's summary.json.
fn run(dir: &Path, scenario: &str, method: &str, state: bool, out: &str) -> serde_json::Value {
    let state = format!("hybrid.model_error_state={state}");
    let args = [
        "run",
        scenario,
        "--method",
        method,
        "--seed",
        "3",
        "--set",
        "plant.engine=\"articulated\"",
        "--set",
        "duration=15.0",
        "--set",
        &state,
        "--out",
        out,
    ];
    common::aift_ok(&args, dir);
    let text = std::fs::read_to_string(dir.join(out).join("summary.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn alarms(s: &serde_json::Value) -> usize {
    s["detections"].as_array().map_or(0, Vec::len)
}

fn max_final_error(s: &serde_json::Value) -> f64 {
    s["final_error_per_joint"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_f64().unwrap())
        .fold(0.0, f64::max)
}

#[test]
fn the_model_error_state_keeps_healthy_runs_quiet_and_frozen_tachometers_recovered() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (mut with, mut without, mut arms, mut judged) = (0, 0, 0, 0);
    let mut failures = Vec::new();
    for seed in 78001..=78006 {
        let Some((scenario, n)) = common::generated_arm(seed, d) else {
            continue;
        };
        arms += 1;
        let a = alarms(&run(d, &scenario, "hybrid", true, &format!("w{seed}")));
        let b = alarms(&run(d, &scenario, "hybrid", false, &format!("o{seed}")));
        eprintln!("arm {seed}: healthy alarms with the state {a}, without {b}");
        with += a;
        without += b;
        // The last joint's tachometer frozen at 8 s, 0.5 s after the switch of target.
        let faulted = format!("f{seed}.toml");
        let text = std::fs::read_to_string(d.join(&scenario)).unwrap()
            + &format!("\n[[faults]]\nchannel = \"tach{n}\"\nkind = \"freeze\"\nstart = 8.0\n");
        std::fs::write(d.join(&faulted), text).unwrap();
        let oracle = max_final_error(&run(d, &faulted, "oracle", false, &format!("fo{seed}")));
        let hybrid = max_final_error(&run(d, &faulted, "hybrid", true, &format!("fh{seed}")));
        eprintln!("arm {seed}: tach{n} freeze, final error oracle {oracle:.4}, hybrid {hybrid:.4}");
        if oracle <= 0.02 {
            judged += 1;
            if hybrid > 0.02 {
                failures.push(format!("arm {seed}: tach{n} freeze, hybrid {hybrid:.4}"));
            }
        }
    }
    assert!(arms >= 4, "init accepted only {arms} of 6 arms");
    assert!(
        judged >= 3,
        "the oracle recovered only {judged} freezes: not a test"
    );
    assert!(
        with <= without,
        "healthy alarms with the state {with}, without {without}"
    );
    assert!(failures.is_empty(), "{failures:#?}");
}
