//! `hybrid.pair_evidence` (on by default; docs/method.md, "Pair evidence"): an encoder drift on a
//! joint the camera sees moderately is blamed on the encoder once the camera's evidence, kept
//! over the fault's life, outweighs the bank's per-tick odds; without it the hybrid blames the
//! tachometer and the belief follows the drifting encoder. Checked on a generated arm from the
//! tests' seed range (below 100 000: no screen's and no evaluation arm). Not blind to the
//! design: arm52006 belongs to the set 52001..52012 on which the two-sided version was checked
//! (this joint at run seeds 11-13) and whose trace (arm52003) led to the third side; a joint
//! chosen by rule from unseen arms (arm53001's joint 1, S 32, run seed 13) goes from 0.136 rad
//! to 0.017 with the option: recovered by the campaigns' 0.02 tolerance, not within this test's
//! 0.01. The same joint's tachometer bias stays blamed on the tachometer, and a healthy run
//! raises no alarm. On joints the camera cannot see at all, a tachometer bias stays the
//! tachometer's (the first version of the contest ran it away).

mod common;

use aift::scenario::Method;
use common::run_recorded;

/// `aift gen-arm --seed 52006` with `aift init`'s scenario, and a fault on its first joint
/// from 8 s (its camera sensitivity is 9.6-18 encoder sigmas per radian: moderate).
fn arm_with(dir: &std::path::Path, name: &str, fault: &str) -> std::path::PathBuf {
    generated_with(dir, 52006, name, fault)
}

/// `aift gen-arm --seed <seed>` with `aift init`'s scenario and `fault` appended.
fn generated_with(dir: &std::path::Path, seed: u64, name: &str, fault: &str) -> std::path::PathBuf {
    let urdf = dir.join(format!("arm{seed}.urdf"));
    let scenario = dir.join(format!("arm{seed}.toml"));
    if !scenario.exists() {
        common::aift_ok(
            &[
                "gen-arm",
                "--seed",
                &seed.to_string(),
                "--out",
                urdf.to_str().unwrap(),
            ],
            dir,
        );
        common::aift_ok(
            &[
                "init",
                "--urdf",
                urdf.to_str().unwrap(),
                "--out",
                scenario.to_str().unwrap(),
            ],
            dir,
        );
    }
    let text = std::fs::read_to_string(&scenario).unwrap();
    let path = dir.join(format!("arm{seed}_{name}.toml"));
    std::fs::write(&path, format!("{text}\n{fault}")).unwrap();
    path
}

/// The scenario on the articulated engine with `sets` laid over it.
fn prepared(path: &std::path::Path, sets: &[&str]) -> aift::scenario::RunSetup {
    let mut all = vec!["plant.engine=\"articulated\"".to_string()];
    all.extend(sets.iter().map(|s| s.to_string()));
    let loaded = aift::scenario::LoadedScenario::from_file(path, &all).unwrap();
    aift::scenario::RunSetup::prepare(loaded).unwrap()
}

fn setup(path: &std::path::Path, pair: bool) -> aift::scenario::RunSetup {
    prepared(path, &[&format!("hybrid.pair_evidence={pair}")])
}

#[test]
fn pair_evidence_blames_a_drifting_encoder_the_camera_sees_and_keeps_the_rest() {
    let tmp = tempfile::tempdir().unwrap();
    let drift = arm_with(
        tmp.path(),
        "drift",
        "[[faults]]\nchannel = \"enc1\"\nkind = \"drift\"\nrate = 0.02\nstart = 8.0\n",
    );
    let seed = 13;
    let (without, _) = run_recorded(&setup(&drift, false), Method::Hybrid, seed, None);
    let (with, _) = run_recorded(&setup(&drift, true), Method::Hybrid, seed, None);
    eprintln!(
        "enc1 drift: default {:?}, pair evidence {:?}",
        without.final_error_per_joint, with.final_error_per_joint
    );
    // Default: the belief follows the encoder (0.02 rad/s for 7 s).
    assert!(
        without.max_final_error > 0.1,
        "{:?}",
        without.final_error_per_joint
    );
    assert!(
        with.max_final_error < 0.01,
        "{:?}",
        with.final_error_per_joint
    );
    assert_eq!(with.outcome.name(), "completed");

    // The tachometer's bias on the same joint: still the tachometer's.
    let bias = arm_with(
        tmp.path(),
        "bias",
        "[[faults]]\nchannel = \"tach1\"\nkind = \"bias\"\noffset = 0.1\nstart = 8.0\n",
    );
    let (r, _) = run_recorded(&setup(&bias, true), Method::Hybrid, seed, None);
    eprintln!("tach1 bias, pair evidence: {:?}", r.final_error_per_joint);
    assert!(r.max_final_error < 0.01, "{:?}", r.final_error_per_joint);

    // Healthy: no alarm.
    let healthy = arm_with(tmp.path(), "healthy", "");
    let (h, _) = run_recorded(&setup(&healthy, true), Method::Hybrid, seed, None);
    assert_eq!(h.false_alarms, 0);
    assert!(h.max_final_error < 0.01, "{:?}", h.final_error_per_joint);
}

/// On is the default: a run of a scenario that does not name the option is that of one that
/// sets it, tick for tick, and turning it off is written in the resolved scenario (so its
/// fingerprint differs) and changes the run.
#[test]
fn pair_evidence_on_is_the_default_and_off_is_written() {
    assert!(aift::estimation::hybrid::HybridConfig::default().pair_evidence);
    let tmp = tempfile::tempdir().unwrap();
    let drift = arm_with(
        tmp.path(),
        "drift",
        "[[faults]]\nchannel = \"enc1\"\nkind = \"drift\"\nrate = 0.02\nstart = 8.0\n",
    );
    let plain = prepared(&drift, &[]);
    let on = setup(&drift, true);
    let off = setup(&drift, false);
    let written = |s: &aift::scenario::RunSetup| toml::to_string(s.scenario()).unwrap();
    assert!(!written(&plain).contains("pair_evidence"));
    assert!(!written(&on).contains("pair_evidence"));
    assert!(written(&off).contains("pair_evidence = false"));
    let (a, ta) = run_recorded(&plain, Method::Hybrid, 3, None);
    let (b, tb) = run_recorded(&on, Method::Hybrid, 3, None);
    let (c, tc) = run_recorded(&off, Method::Hybrid, 3, None);
    assert_eq!(a.final_error_per_joint, b.final_error_per_joint);
    // Bit for bit (a missing reading is recorded as NaN).
    let bits = |rows: &[Vec<f64>]| -> Vec<Vec<u64>> {
        rows.iter()
            .map(|r| r.iter().map(|v| v.to_bits()).collect())
            .collect()
    };
    assert!(
        bits(&ta.rows) == bits(&tb.rows),
        "the recorded trajectories differ"
    );
    assert!(
        bits(&ta.rows) != bits(&tc.rows),
        "turning the option off changed nothing: {:?} and {:?}",
        a.final_error_per_joint,
        c.final_error_per_joint
    );
}

/// A joint the camera cannot see (the end effector on its axis: `aift init` names it) is
/// checked by nothing but its own two sensors and the dynamics, so the camera must not decide
/// between them: a 0.1 rad/s tachometer bias at rest, before the target switch, stays the
/// tachometer's. The first version of the contest, scored on the sides' whole camera
/// residuals, ran both of these away (0.98 and 0.88 rad; arms 57074 and 57099 were found by
/// `aift init` on 57071..57100 after the design was fixed, each the arm's one unseen joint).
#[test]
fn pair_evidence_leaves_a_joint_the_camera_cannot_see_to_its_own_sensors() {
    let tmp = tempfile::tempdir().unwrap();
    for seed in [57074u64, 57099] {
        let path = generated_with(
            tmp.path(),
            seed,
            "tach5_bias",
            "[[faults]]\nchannel = \"tach5\"\nkind = \"bias\"\noffset = 0.1\nstart = 5.0\n",
        );
        let scenario = std::fs::read_to_string(tmp.path().join(format!("arm{seed}.toml"))).unwrap();
        assert!(
            scenario.contains("cannot see joint 'joint5'"),
            "arm{seed}: init no longer names joint 5 unseen"
        );
        let (r, _) = run_recorded(&setup(&path, true), Method::Hybrid, 3, None);
        eprintln!(
            "arm{seed} tach5 bias, pair evidence: {:?}",
            r.final_error_per_joint
        );
        assert_eq!(r.outcome.name(), "completed");
        assert!(
            r.max_final_error < 0.01,
            "arm{seed}: {:?}",
            r.final_error_per_joint
        );
    }
}

/// The contest decides which of a joint's two sensors failed, not whether one still has: a
/// fault that ends is seen to end with the option on, as without it. The paper arm's encoder 1
/// biased by 0.05 rad from 8 to 9 s (the twenty-eighth session's build kept it dropped for
/// the rest of the run: its camera evidence from the fault's life outweighed the bank), and on
/// a generated arm an encoder bias and an encoder drift that end after 2 s: each is dropped
/// while it acts (at some time), taken back within 0.5 s of its end, kept, and the run ends
/// at the target.
#[test]
fn pair_evidence_takes_back_a_sensor_whose_fault_ended() {
    let check = |label: &str, setup: &aift::scenario::RunSetup, start: f64, end: f64| {
        let (r, rec) = run_recorded(setup, Method::Hybrid, 5, None);
        let nominal = common::at(&rec, "precision_enc1", start - 0.1);
        let during = common::min_between(&rec, "precision_enc1", start, end);
        let after = common::min_between(&rec, "precision_enc1", end + 0.5, f64::INFINITY);
        eprintln!(
            "{label}: enc1 precision {nominal:.3e} before, at least {during:.3e} during, at least \
             {after:.3e} from 0.5 s after its end; final error {:.1e}",
            r.max_final_error
        );
        assert!(during < 1e-3 * nominal, "{label}: dropped during the fault");
        assert!(after > 0.5 * nominal, "{label}: back and kept after it");
        assert!(
            r.max_final_error < 0.01,
            "{label}: {:?}",
            r.final_error_per_joint
        );
    };
    let paper = common::with_faults(
        "paper_healthy.toml",
        &["[[faults]]\nchannel = \"enc1\"\nkind = \"bias\"\noffset = 0.05\nstart = 8.0\nend = 9.0"],
        &["hybrid.pair_evidence=true"],
    );
    check("paper arm, enc1 bias 8-9 s", &paper, 8.0, 9.0);
    let tmp = tempfile::tempdir().unwrap();
    for (name, fault) in [
        ("bias", "kind = \"bias\"\noffset = 0.05"),
        ("drift", "kind = \"drift\"\nrate = 0.02"),
    ] {
        let path = arm_with(
            tmp.path(),
            &format!("{name}_ending"),
            &format!("[[faults]]\nchannel = \"enc1\"\n{fault}\nstart = 8.0\nend = 10.0\n"),
        );
        check(
            &format!("arm52006, enc1 {name} 8-10 s"),
            &setup(&path, true),
            8.0,
            10.0,
        );
    }
}

/// A reading that fits the contest's leader better than the bank's "neither" is not a recovery
/// when the sensor returns garbage: one value in a thousand lands near the joint, and the bank's
/// "neither", having absorbed the garbage, sits far from it. The twenty-ninth session's form let
/// such a reading raise "neither" above the leader (found on the actuator campaign's Panda
/// encoder-4 garbage cell, 0.50 rad off; traced on the paper arm); here, on a generated arm
/// apart from both, it readmitted the encoder for 2734 of the 6800 ticks after 8.2 s. The
/// reading may now take the contest's evidence against "neither" down to one switch, never
/// below, and the encoder stays dropped, as without the option.
#[test]
fn pair_evidence_keeps_a_garbage_encoder_dropped() {
    let tmp = tempfile::tempdir().unwrap();
    let path = arm_with(
        tmp.path(),
        "garbage",
        "[[faults]]\nchannel = \"enc1\"\nkind = \"garbage\"\nlow = -3.0\nhigh = 3.0\nstart = 8.0\n",
    );
    let (r, rec) = run_recorded(&setup(&path, true), Method::Hybrid, 11, None);
    let nominal = common::at(&rec, "precision_enc1", 7.9);
    let c = rec.column("precision_enc1").unwrap();
    let readmitted = rec
        .rows
        .iter()
        .filter(|row| row[0] >= 8.2 && row[c] > 1e-3 * nominal)
        .count();
    eprintln!(
        "arm52006, enc1 garbage: {readmitted} ticks readmitted after 8.2 s, final error {:.1e}",
        r.max_final_error
    );
    assert_eq!(readmitted, 0, "the garbage encoder was readmitted");
    assert!(r.max_final_error < 0.01, "{:?}", r.final_error_per_joint);
}

/// A contest weighs two explanations of a disagreement between a joint's two sensors; while
/// one of them is silent there is none, and it gathers no camera evidence. On a generated arm
/// whose encoder 2 drops out from 8 s (a 40 s run, so that the wander of a position integrated
/// from the tachometer has time to grow), the build before this rule held tachometer 2 failed
/// for 6667 ticks and ended 10x the oracle's error (0.0049 against 0.00045 rad); with it the
/// tachometer stays trusted and the joint ends where the oracle's does. arm58009 is from the
/// tests' seed range, found with the rule already designed (on 58001..58010, each joint's
/// encoder dropping out in turn, run seed 1: the rule moved this arm's four joints, joints 2-4
/// by 2.6-11x, and nothing else); the rule came from the evaluation campaign's arm880018
/// (docs/method.md, "Pair evidence", a silent sensor).
#[test]
fn a_silent_encoder_opens_no_case_against_its_tachometer() {
    let tmp = tempfile::tempdir().unwrap();
    let path = generated_with(
        tmp.path(),
        58009,
        "enc2_dropout",
        "[[faults]]\nchannel = \"enc2\"\nkind = \"dropout\"\nstart = 8.0\n",
    );
    let setup = prepared(&path, &["duration=40.0"]);
    assert!(aift::estimation::hybrid::HybridConfig::default().pair_evidence);
    let (h, rec) = run_recorded(&setup, Method::Hybrid, 1, None);
    let (o, _) = run_recorded(&setup, Method::Oracle, 1, None);
    let health = common::min_between(&rec, "health_tach2", 8.0, f64::INFINITY);
    eprintln!(
        "arm58009 enc2 dropout: hybrid {:?}, oracle {:?}, tach2 health at least {health:.3}",
        h.final_error_per_joint, o.final_error_per_joint
    );
    assert_eq!(h.outcome.name(), "completed");
    assert!(health > 0.5, "the silent encoder's tachometer was blamed");
    assert!(
        h.final_error_per_joint[1] < 2.0 * o.final_error_per_joint[1] + 1e-4,
        "hybrid {:?}, oracle {:?}",
        h.final_error_per_joint,
        o.final_error_per_joint
    );
}
