//! A frozen tachometer: the open case (docs/method.md, "Studies"). Measured, not solved: the learners
//! blame the healthy encoder and camera. What holds, and is checked here: no fault tolerance
//! survives it; with the paper's fixed prior recovery needs the coupled prediction (even the
//! oracle fails without it), and with the switched prior (the default) the oracle recovers with
//! either prediction.

mod common;

use aift::scenario::Method;
use common::{run_recorded, setup};

#[test]
fn the_oracle_recovers_only_with_the_coupled_prediction_or_the_switched_prior() {
    let with = |prediction: &str, prior: &str| {
        let prediction = format!("belief.prediction=\"{prediction}\"");
        let prior = format!("belief.prior=\"{prior}\"");
        let s = setup(
            "paper_tachometer_freeze.toml",
            &[prediction.as_str(), prior.as_str()],
        );
        run_recorded(&s, Method::Oracle, 1, None).0
    };
    let c = with("coupled", "fixed");
    let p = with("paper", "fixed");
    let ps = with("paper", "switched");
    eprintln!(
        "oracle, tachometer-1 freeze, fixed prior: coupled MSE {:.2e} final {:.4}; paper MSE \
         {:.2e} final {:.4}; paper with the switched prior MSE {:.2e} final {:.4}",
        c.mse_faulty.unwrap(),
        c.max_final_error,
        p.mse_faulty.unwrap(),
        p.max_final_error,
        ps.mse_faulty.unwrap(),
        ps.max_final_error
    );
    assert!(c.mse_faulty.unwrap() <= 1e-5 && c.max_final_error <= 0.02);
    assert!(p.mse_faulty.unwrap() > 100.0 * c.mse_faulty.unwrap());
    // Without its tachometer the switched prior propagates the velocity belief from the encoder
    // steps and the dynamics; the paper's prediction is then enough.
    assert!(ps.mse_faulty.unwrap() <= 1e-5 && ps.max_final_error <= 0.02);
}

#[test]
fn no_fault_tolerance_survives_and_every_method_returns_a_result() {
    let s = setup("paper_tachometer_freeze.toml", &[]);
    let (no_ft, _) = run_recorded(&s, Method::NoFt, 1, None);
    assert!(no_ft.max_final_error < 0.1, "{}", no_ft.max_final_error);
    for m in [Method::PlAlways, Method::Bayes, Method::Window] {
        let (r, _) = run_recorded(&s, m, 1, None);
        eprintln!(
            "{m}: outcome {}, faulty MSE {:.2e}, final error {:.3}, health {:?}",
            r.outcome.name(),
            r.mse_faulty.unwrap(),
            r.max_final_error,
            r.final_health
        );
        assert!(r.mse_per_joint.iter().all(|v| v.is_finite()));
    }
}

/// `aift init`'s scenario of the UR5 in `tests/data` (no joint damping), shortened to 8 s
/// (target switch at 3.5 s), with its elbow tachometer failing (`kind`) at 4 s.
fn ur5_scenario(dir: &std::path::Path, kind: &str) -> std::path::PathBuf {
    let out = dir.join("ur5.toml");
    common::aift_ok(
        &[
            "init",
            "--urdf",
            common::repo("tests/data/ur5.urdf").to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        dir,
    );
    let text = std::fs::read_to_string(&out)
        .unwrap()
        .replace("\nduration = 15.0\n", "\nduration = 8.0\n")
        .replace("\ntime = 7.5\n", "\ntime = 3.5\n");
    assert!(text.contains("\nduration = 8.0\n") && text.contains("\ntime = 3.5\n"));
    let path = dir.join(format!("ur5_tach3_{kind}.toml"));
    std::fs::write(
        &path,
        format!("{text}\n[[faults]]\nchannel = \"tach3\"\nkind = \"{kind}\"\nstart = 4.0\n"),
    )
    .unwrap();
    path
}

/// A UR5 from outside the project (`tests/data/ur5.urdf`, no joint damping) with `aift init`'s
/// scenario, shortened to 8 s (target switch at 3.5 s), its elbow tachometer frozen at 4 s. The
/// hybrid drops the right channel either way, but with the paper's fixed prior the u-AIC without
/// that tachometer turns encoder differences into a noisy mu' that the PID's damping term
/// amplifies, and the elbow ends off (0.2 rad until the model-error state was carried as a
/// parameter error, 2026-12-05; 0.016 rad since); with `hybrid.prior =
/// "fixed-until-tachometer-fails"` the belief takes the propagated prior once the tachometer is
/// held failed and the arm ends within 0.005 rad, several times closer. The oracle, which drops
/// the tachometer at the fault's first tick, swings the elbow with the fixed prior (0.40 rad off
/// at the end, measured at seed 1) and holds it with `belief.prior = "switched"` (0.0012 rad):
/// dropping a velocity sensor is safe only with a prior that propagates what the belief knows.
/// Both switched priors are the defaults since 2026-12-07; the fixed ones are set by name.
#[test]
fn an_undamped_ur5_holds_through_a_tachometer_freeze_with_the_switched_prior() {
    use aift::estimation::hybrid::HybridPrior;
    let tmp = tempfile::tempdir().unwrap();
    let path = ur5_scenario(tmp.path(), "freeze");
    let engine = "plant.engine=\"articulated\"".to_string();
    let loaded =
        aift::scenario::LoadedScenario::from_file(&path, std::slice::from_ref(&engine)).unwrap();
    // The defaults: `hybrid.prior = "fixed-until-tachometer-fails"`, `belief.prior = "switched"`.
    let switched = aift::scenario::RunSetup::prepare(loaded).unwrap();
    assert_eq!(
        switched
            .scenario()
            .hybrid
            .prior_mode(switched.scenario().belief.update),
        HybridPrior::FixedUntilTachometerFails
    );
    assert_eq!(
        switched.scenario().belief.prior_mode(),
        aift::estimation::uaic::PriorMode::Switched
    );
    // An option as a user gives it, parsed and validated; the camera model reused.
    let with = |set: &str| {
        let loaded =
            aift::scenario::LoadedScenario::from_file(&path, &[engine.clone(), set.to_string()])
                .unwrap();
        let mut setup = switched.clone();
        setup.loaded = loaded;
        setup
    };
    let fixed = with("hybrid.prior=\"fixed\"");
    let (f, _) = run_recorded(&fixed, Method::Hybrid, 1, None);
    let (s, _) = run_recorded(&switched, Method::Hybrid, 1, None);
    eprintln!(
        "ur5 tach3 freeze, hybrid: fixed prior {:?} ({:?}); switched {:?} ({:?})",
        f.final_error_per_joint, f.isolated_channel, s.final_error_per_joint, s.isolated_channel
    );
    assert_eq!(f.isolated_channel.as_deref(), Some("tach3"));
    assert_eq!(s.isolated_channel.as_deref(), Some("tach3"));
    assert!(
        f.max_final_error > 5.0 * s.max_final_error,
        "fixed {:?}, switched {:?}",
        f.final_error_per_joint,
        s.final_error_per_joint
    );
    assert!(s.max_final_error < 0.005, "{:?}", s.final_error_per_joint);
    assert_eq!(s.false_alarms, 0);
    // The oracle, fixed against switched prior.
    let fixed = with("belief.prior=\"fixed\"");
    let (f, _) = run_recorded(&fixed, Method::Oracle, 1, None);
    let (s, _) = run_recorded(&switched, Method::Oracle, 1, None);
    eprintln!(
        "ur5 tach3 freeze, oracle: fixed prior {:?}; switched {:?}",
        f.final_error_per_joint, s.final_error_per_joint
    );
    assert!(f.max_final_error > 0.1, "{:?}", f.final_error_per_joint);
    assert!(s.max_final_error < 0.005, "{:?}", s.final_error_per_joint);
    assert_eq!(s.outcome.name(), "completed");
}

/// The same UR5 with its elbow tachometer silent from 4 s (a dropout: the reading is missing,
/// which is no evidence against the sensor, so no learned precision falls and no hypothesis of
/// the hybrid blames it). Without that reading the joint's velocity belief is the prior's, as
/// when a tachometer is dropped: the switched priors (the defaults) count a missing reading as
/// a dropped tachometer and take the propagated prior, and no-FT, pl-always and the hybrid hold
/// the elbow as the oracle does; with the fixed priors they swing it (0.37-0.40 rad off at
/// seeds 1 and 2 for no-FT and the hybrid, 2-3 rad for pl-always, measured 2026-12-07).
#[test]
fn an_undamped_ur5_holds_through_a_tachometer_dropout_without_the_oracle() {
    let tmp = tempfile::tempdir().unwrap();
    let path = ur5_scenario(tmp.path(), "dropout");
    let prepare = |sets: &[&str]| {
        let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        sets.push("plant.engine=\"articulated\"".to_string());
        let loaded = aift::scenario::LoadedScenario::from_file(&path, &sets).unwrap();
        aift::scenario::RunSetup::prepare(loaded).unwrap()
    };
    let switched = prepare(&[]);
    let seed = 5;
    let (oracle, _) = run_recorded(&switched, Method::Oracle, seed, None);
    assert!(
        oracle.max_final_error < 0.005,
        "{:?}",
        oracle.final_error_per_joint
    );
    for m in [Method::NoFt, Method::PlAlways, Method::Hybrid] {
        let (r, _) = run_recorded(&switched, m, seed, None);
        eprintln!(
            "ur5 tach3 dropout, {m}, switched prior: final {:?}, alarms {}",
            r.final_error_per_joint, r.false_alarms
        );
        assert_eq!(r.outcome.name(), "completed", "{m}");
        assert!(
            r.max_final_error < 2.0 * oracle.max_final_error.max(1e-3),
            "{m}: {:?}, oracle {:?}",
            r.final_error_per_joint,
            oracle.final_error_per_joint
        );
    }
    // The fixed priors, set by name: the joint swings without its velocity reading.
    let fixed = prepare(&["belief.prior=\"fixed\"", "hybrid.prior=\"fixed\""]);
    for m in [Method::NoFt, Method::Hybrid] {
        let (r, _) = run_recorded(&fixed, m, seed, None);
        eprintln!(
            "ur5 tach3 dropout, {m}, fixed prior: final {:?}",
            r.final_error_per_joint
        );
        assert!(
            r.max_final_error > 0.05,
            "{m}: {:?}",
            r.final_error_per_joint
        );
    }
}
