//! Arms nobody tuned for: `aift gen-arm` draws a serial arm from a seed (src/arm/generate.rs),
//! the same seed giving the same bytes; every generated arm loads, `init` writes a scenario for
//! it that loads, and without faults that scenario runs to its end without chattering.

mod common;

use common::aift_in as aift;

/// Writes `arm{seed}.urdf` with `gen-arm` into `dir` and runs `init` on it: the scenario's path
/// and `init`'s output (it may refuse the arm).
fn generate_and_init(
    seed: u64,
    dir: &std::path::Path,
) -> (std::path::PathBuf, std::process::Output) {
    let urdf = dir.join(format!("arm{seed}.urdf"));
    let scenario = dir.join(format!("arm{seed}.toml"));
    let (u, sc) = (urdf.to_str().unwrap(), scenario.to_str().unwrap());
    common::aift_ok(&["gen-arm", "--seed", &seed.to_string(), "--out", u], dir);
    let init = aift(&["init", "--urdf", u, "--out", sc], dir);
    (scenario, init)
}

/// `generate_and_init` (which must accept the arm), then the healthy scenario init wrote without
/// fault tolerance on the articulated engine, run seed 1: the result and the joint count.
fn init_and_run_healthy(seed: u64, dir: &std::path::Path) -> (aift::scenario::RunResult, usize) {
    let (scenario, init) = generate_and_init(seed, dir);
    assert_eq!(
        init.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&init.stderr)
    );
    let set = ["plant.engine=\"articulated\"".to_string()];
    let loaded = aift::scenario::LoadedScenario::from_file(&scenario, &set).unwrap();
    let setup = aift::scenario::RunSetup::prepare(loaded).unwrap();
    let (r, _) = common::run_recorded(&setup, aift::scenario::Method::NoFt, 1, None);
    (r, setup.model.joints.len())
}

#[test]
fn the_same_seed_gives_the_same_arm_and_the_joint_count_asked_for() {
    let tmp = tempfile::tempdir().unwrap();
    let a = aift(&["gen-arm", "--seed", "41"], tmp.path());
    let b = aift(&["gen-arm", "--seed", "41"], tmp.path());
    let c = aift(&["gen-arm", "--seed", "42"], tmp.path());
    assert_eq!(
        a.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&a.stderr)
    );
    assert_eq!(a.stdout, b.stdout);
    assert_ne!(a.stdout, c.stdout);
    let seven = aift(
        &[
            "gen-arm", "--seed", "5", "--joints", "7", "--out", "arm.urdf",
        ],
        tmp.path(),
    );
    assert_eq!(
        seven.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&seven.stderr)
    );
    let model = aift::arm::load_urdf(&tmp.path().join("arm.urdf")).unwrap();
    assert_eq!(model.joints.len(), 7);
    // An existing file is kept unless --force.
    let again = aift(&["gen-arm", "--seed", "6", "--out", "arm.urdf"], tmp.path());
    assert_eq!(again.status.code(), Some(2));
    let text = std::fs::read_to_string(tmp.path().join("arm.urdf")).unwrap();
    assert!(text.contains("gen_5"), "the file was replaced");
}

#[test]
fn a_bad_joint_range_is_refused_with_exit_2_naming_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    for bad in ["0", "13", "5..3", "x", "2..", "1..99"] {
        let o = aift(&["gen-arm", "--seed", "1", "--joints", bad], tmp.path());
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{bad}: {err}");
        assert!(err.contains("--joints"), "{bad}: {err}");
        assert!(o.stdout.is_empty(), "{bad}");
    }
}

/// Ten arms of 2-7 joints from seeds no tuning saw: init, then the healthy scenario it wrote (two
/// targets, 15 s) without fault tolerance on the articulated engine: it completes (no
/// divergence, no chattering) and every joint ends within 0.05 rad of its last target.
#[test]
fn init_holds_generated_arms_it_never_saw() {
    let tmp = tempfile::tempdir().unwrap();
    let mut misses = Vec::new();
    for seed in 77001..77011u64 {
        let (r, joints) = init_and_run_healthy(seed, tmp.path());
        if r.outcome.name() != "completed" || r.max_final_error > 0.05 {
            misses.push(format!(
                "seed {seed}: {joints} joints, {:?}, final error {:?}",
                r.outcome, r.final_error_per_joint
            ));
        }
    }
    assert!(misses.is_empty(), "{misses:#?}");
}

/// The evaluation campaign (assets/campaigns/eval.toml, written by tools/make-eval-campaign.py)
/// is what it says: at least 20 arms, each the URDF `gen-arm` writes today for its seed (so a
/// generator change cannot leave it describing other arms), generator seeds apart from every
/// test's (below 100 000) and screen's (below 800 000), a listed joint the arm has, run seeds
/// apart from the development campaign's, every fault kind, and a campaign that validates
/// (without preparing its arms: that trains 20 camera models).
#[test]
fn the_evaluation_campaign_is_generated_arms_apart_from_development() {
    use aift::scenario::campaign::CampaignConfig;
    let path = common::repo("assets/campaigns/eval.toml");
    let config = CampaignConfig::load(&path).unwrap();
    let dev = CampaignConfig::load(&common::repo("assets/campaigns/default.toml")).unwrap();
    assert!(config.arms.len() >= 20, "{} arms", config.arms.len());
    let dev_seeds = dev.first_seed..dev.first_seed + dev.seeds as u64;
    let eval_seeds = config.first_seed..config.first_seed + config.seeds as u64;
    assert!(
        eval_seeds.start >= dev_seeds.end || eval_seeds.end <= dev_seeds.start,
        "run seeds {eval_seeds:?} overlap the development campaign's {dev_seeds:?}"
    );
    assert!(config.seeds >= 5);
    // Every fault kind, at the development campaign's sizes, onsets, pairs and verdicts.
    let kinds: std::collections::HashSet<_> =
        config.kinds.iter().map(std::mem::discriminant).collect();
    assert_eq!(kinds.len(), 8, "{:?}", config.kinds);
    assert_eq!(config.kinds, dev.kinds);
    assert_eq!(config.pairs, dev.pairs);
    assert_eq!(
        (&config.verdict, &config.onsets, &config.defaults),
        (&dev.verdict, &dev.onsets, &dev.defaults)
    );
    let tmp = tempfile::tempdir().unwrap();
    for arm in &config.arms {
        let seed: u64 = arm.name.strip_prefix("arm").unwrap().parse().unwrap();
        assert!(
            seed >= 800_000,
            "{}: a seed tests or screens may use",
            arm.name
        );
        let scenario = path.parent().unwrap().join(&arm.scenario);
        let urdf = scenario.with_extension("urdf");
        let o = aift(&["gen-arm", "--seed", &seed.to_string()], tmp.path());
        assert_eq!(o.status.code(), Some(0));
        assert_eq!(
            o.stdout,
            std::fs::read(&urdf).unwrap(),
            "{}: not what `gen-arm --seed {seed}` writes today (rerun tools/make-eval-campaign.py)",
            urdf.display()
        );
        let model = aift::arm::load_urdf(&urdf).unwrap();
        assert!(
            arm.joints
                .iter()
                .all(|&j| j >= 1 && j <= model.joints.len())
        );
        let loaded = aift::scenario::LoadedScenario::from_file(&scenario, &[]).unwrap();
        assert!(
            loaded.scenario.faults.is_empty(),
            "{}: a healthy template",
            arm.name
        );
    }
    config.check(&path).unwrap();
}

/// Joints whose effort limit slows their loop (w = sqrt(effort / (0.5 m)) below 4.3 rad/s) get
/// an integral time of at most a quarter of a target's hold (src/scenario/init.rs): their
/// overshoot's tail is gone before the target switches. The four arms of 79001..79060 whose
/// largest final error under the integral time 8 / w was above 0.005 rad (0.0053, 0.0060,
/// 0.0118, 0.0055: 79039 was refused by the check run) end at 0.0008-0.0016 with it (no-FT,
/// articulated engine, run seed 1). The rule was found on generator seeds 652001..652060.
#[test]
fn an_effort_limited_joint_settles_before_its_target_switches() {
    let tmp = tempfile::tempdir().unwrap();
    let mut misses = Vec::new();
    for seed in [79001u64, 79007, 79039, 79060] {
        let (r, _) = init_and_run_healthy(seed, tmp.path());
        eprintln!("seed {seed}: {:?}", r.final_error_per_joint);
        if r.outcome.name() != "completed" || r.max_final_error > 0.004 {
            misses.push(format!(
                "seed {seed}: {:?}, final error {:?}",
                r.outcome, r.final_error_per_joint
            ));
        }
    }
    assert!(misses.is_empty(), "{misses:#?}");
}

/// Two nearly coaxial joints move almost no inertia turning against each other and much turning
/// together: no per-joint kd damps the second within the first's per-tick limit, and the
/// per-joint rule left such arms refused by init's own check run (docs/method.md, "Bring your
/// own arm"). With the derivative gain per mode (`kd_matrix`) init accepts them, and the
/// healthy scenario it wrote ends within 0.01 rad under no-FT and the hybrid, without an alarm.
/// The arms were found by a scan of 81001..81200 for arms the per-joint rule left refused (0.69,
/// 0.75 and 0.017 rad off), made with the modes alone, before the per-joint margin was added
/// (prompted by arm71006 of the property test below; docs/method.md, "Bring your own arm").
#[test]
fn init_damps_coupled_joints_per_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let mut misses = Vec::new();
    for seed in [81020u64, 81081, 81108] {
        let (scenario, init) = generate_and_init(seed, tmp.path());
        assert_eq!(
            init.status.code(),
            Some(0),
            "seed {seed}: {}",
            String::from_utf8_lossy(&init.stderr)
        );
        let text = std::fs::read_to_string(&scenario).unwrap();
        assert!(
            text.contains("\nkd_matrix = "),
            "seed {seed}: no per-mode gain"
        );
        let set = ["plant.engine=\"articulated\"".to_string()];
        let loaded = aift::scenario::LoadedScenario::from_file(&scenario, &set).unwrap();
        let setup = aift::scenario::RunSetup::prepare(loaded).unwrap();
        for method in [aift::scenario::Method::NoFt, aift::scenario::Method::Hybrid] {
            let (r, _) = common::run_recorded(&setup, method, 1, None);
            eprintln!(
                "seed {seed} {}: {:?}",
                method.name(),
                r.final_error_per_joint
            );
            if r.outcome.name() != "completed" || r.max_final_error > 0.01 || r.false_alarms > 0 {
                misses.push(format!(
                    "seed {seed} {}: {:?}, final error {:?}, {} alarms",
                    method.name(),
                    r.outcome,
                    r.final_error_per_joint,
                    r.false_alarms
                ));
            }
        }
    }
    assert!(misses.is_empty(), "{misses:#?}");
}

/// The property the issue on arms users bring asks for, on 20 generated arms (generator seeds
/// 71001 on, a range no screen and no tuning used; seeds `init` refuses are counted and skipped,
/// at most 4; the range before, 70001.., was looked at to design `init`'s friction rule): each
/// arm's `init` scenario, healthy, under every method on the articulated engine with the erred
/// model (15 s, one seed): every run completes (no divergence, no chattering) and every joint
/// ends within 0.01 rad of its target; neither the hybrid nor the oracle raises an alarm. An
/// encoder freeze on a random joint of each arm (at 8 s, while it moves): the hybrid recovers
/// (within the campaign's 0.02 rad) wherever the oracle does. What it does not assert, with the
/// numbers it prints: the other methods' false alarms and the oracle's own misses
/// (docs/arms.md, "Arms nobody tuned for").
///
/// In CI since 2026-12-05 (fourteenth session), when it first passed: with the model-error
/// state carried as a parameter error the hybrid raises no alarm on the 20 healthy arms (2 on 2
/// with the thirteenth session's state, 7 on 4 without the state, 8 on 5 before the friction
/// bound; on 70001.. with the explicit step 19 on 10). It takes about 4.5 minutes on two cores
/// (20 arms' `init`, camera models and detector calibrations, 11 methods; 8.5 beside a campaign).
#[test]
fn every_method_holds_on_twenty_generated_arms_nobody_tuned_for() {
    use aift::scenario::Method;
    use aift::scenario::campaign::{Campaign, Shard, Verdict, run_campaign};
    let tmp = tempfile::tempdir().unwrap();
    let mut arms = String::new();
    let mut refused = Vec::new();
    let mut draw = 0x9e37_79b9_7f4a_7c15u64;
    let mut seed = 71_001u64;
    let mut count = 0;
    while count < 20 {
        assert!(seed < 71_025, "init refused {refused:?}");
        let name = format!("arm{seed}");
        let (scenario, init) = generate_and_init(seed, tmp.path());
        let urdf = scenario.with_extension("urdf");
        if init.status.code() == Some(0) {
            let n = aift::arm::load_urdf(&urdf).unwrap().joints.len() as u64;
            // xorshift: a random joint per arm, the same in every run of the test.
            draw ^= draw << 13;
            draw ^= draw >> 7;
            draw ^= draw << 17;
            let joint = 1 + draw % n;
            arms += &format!(
                "\n[[arms]]\nname = \"{name}\"\nscenario = \"{name}.toml\"\njoints = [{joint}]\n"
            );
            count += 1;
        } else {
            assert_eq!(
                init.status.code(),
                Some(2),
                "{}",
                String::from_utf8_lossy(&init.stderr)
            );
            refused.push(seed);
        }
        seed += 1;
    }
    assert!(refused.len() <= 4, "init refused {refused:?}");
    let file = tmp.path().join("property.toml");
    std::fs::write(
        &file,
        format!(
            "name = \"property\"\nseeds = 1\nchannels = [\"enc*\"]\n\
             [defaults]\nduration = 15.0\nplant = {{ engine = \"articulated\" }}\n\
             [[kinds]]\nkind = \"freeze\"\nonsets = [\"moving\"]\n{arms}"
        ),
    )
    .unwrap();
    let campaign = Campaign::load(&file, &[]).unwrap();
    let records = run_campaign(&campaign, Shard::WHOLE, None, &|_, _| {}).unwrap();
    let mut misses = Vec::new();
    let mut alarms = std::collections::BTreeMap::<aift::scenario::method::MethodId, usize>::new();
    let mut oracle_misses = std::collections::BTreeSet::new();
    for run in &records.runs {
        let cell = &campaign.cells[run.cell];
        let arm = &campaign.config.arms[cell.arm].name;
        if cell.is_healthy() {
            *alarms.entry(run.method.clone()).or_default() += run.false_alarms;
            if run.outcome != "completed" || run.max_final_error > 0.01 {
                misses.push(format!(
                    "{arm} healthy {}: {} {:.4} rad",
                    run.method, run.outcome, run.max_final_error
                ));
            }
            if (run.method == Method::Hybrid || run.method == Method::Oracle)
                && run.false_alarms > 0
            {
                misses.push(format!(
                    "{arm} healthy {}: {} alarms",
                    run.method, run.false_alarms
                ));
            }
        } else if run.method == Method::Oracle && run.verdict != Verdict::Recovered {
            oracle_misses.insert(run.cell);
        }
    }
    for run in &records.runs {
        let cell = &campaign.cells[run.cell];
        if cell.is_healthy() || run.method != Method::Hybrid || run.verdict == Verdict::Recovered {
            continue;
        }
        let arm = &campaign.config.arms[cell.arm].name;
        if !oracle_misses.contains(&run.cell) {
            misses.push(format!(
                "{arm} {}: the hybrid {:?}, the oracle recovered",
                cell.label, run.verdict
            ));
        }
    }
    eprintln!("false alarms on the 20 healthy runs, per method: {alarms:?}");
    let oracle_misses: Vec<String> = oracle_misses
        .iter()
        .map(|&c| {
            let cell = &campaign.cells[c];
            format!("{} {}", campaign.config.arms[cell.arm].name, cell.label)
        })
        .collect();
    eprintln!(
        "encoder freezes the oracle does not recover: {oracle_misses:?}; init refused {refused:?}"
    );
    assert!(misses.is_empty(), "{misses:#?}");
}
