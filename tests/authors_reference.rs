//! The authors' reference: aift in its compatibility settings (assets/scenarios/authors_matlab.toml)
//! against the figures of the authors' own benchmark script (github.com/cpezzato/unbiased_aic,
//! matlab/statistical_analysis.m, the u-AIC branch) run in GNU Octave 7.3 on their 100 stored
//! targets (tests/data/authors_reference/README.md says how), measured by the authors' protocol
//! (`[reaching] protocol = "authors"`); and the compatibility settings' bad input.

mod common;

use std::path::{Path, PathBuf};

use aift::scenario::campaign::{Campaign, ReachingRun, Shard, run_campaign};
use aift::scenario::{Method, Simulation, step_info};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// One task of the authors' script: their target and four measures.
#[derive(Debug)]
struct Figures {
    target: [f64; 2],
    overshoot: f64,
    settling_time: f64,
    steady_state_error: f64,
    rmse: f64,
}

fn octave_figures(name: &str) -> Vec<Figures> {
    let text = std::fs::read_to_string(root().join("tests/data/authors_reference").join(name))
        .expect("test data");
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("task"))
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            Figures {
                target: [v[1], v[2]],
                overshoot: v[3],
                settling_time: v[4],
                steady_state_error: v[5],
                rmse: v[6],
            }
        })
        .collect()
}

/// The authors' protocol on the first `tasks` stored targets, the compatibility scenario with
/// `overrides`, through the library's campaign runner.
fn aift_figures(dir: &Path, tasks: usize, overrides: &[&str]) -> Vec<ReachingRun> {
    let campaign = dir.join("authors.toml");
    std::fs::write(
        &campaign,
        format!(
            "name = \"authors\"\nseeds = 1\nmethods = [\"no-ft\"]\nchannels = []\nkinds = []\n\
             healthy = false\n[[arms]]\nname = \"authors-matlab\"\nscenario = {:?}\n\
             [reaching]\nprotocol = \"authors\"\nstep_joint = 1\ntargets_file = {:?}\n\
             tasks = {tasks}\nduration = 20.0\n",
            root().join("assets/scenarios/authors_matlab.toml"),
            root().join("assets/reference/authors_targets.csv"),
        ),
    )
    .unwrap();
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let c = Campaign::load(&campaign, &overrides).expect("campaign loads");
    let mut runs = run_campaign(&c, Shard::WHOLE, None, &|_, _| {})
        .expect("campaign runs")
        .reaching;
    runs.sort_by_key(|r| r.task);
    runs
}

#[test]
fn noiseless_loop_reproduces_the_authors_script_to_machine_precision() {
    let reference = octave_figures("octave_noiseless_reset.csv");
    assert_eq!(reference.len(), 100);
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().to_path_buf();
    let ours = aift_figures(
        &dir,
        reference.len(),
        &["sensors.encoder_sigma=0", "sensors.tachometer_sigma=0"],
    );
    let mut worst = [0.0f64; 4];
    for (r, f) in ours.iter().zip(&reference) {
        let settling = r.settling_time.unwrap_or(20.0);
        let d = [
            (r.overshoot - f.overshoot).abs(),
            (settling - f.settling_time).abs(),
            (r.steady_state_error - f.steady_state_error).abs(),
            (r.belief_rmse - f.rmse).abs() / f.rmse,
        ];
        for (w, v) in worst.iter_mut().zip(d) {
            *w = w.max(v);
        }
    }
    eprintln!(
        "largest differences over 100 tasks: overshoot {:.1e} %, settling {:.1e} s, \
         steady-state {:.1e} rad, RMSE {:.1e} (relative)",
        worst[0], worst[1], worst[2], worst[3]
    );
    print_means(
        "the authors' script, integral reset per task, noise off",
        &figures_of(&reference),
    );
    // Machine precision, with room for 20 000 ticks of rounding in a different order (MATLAB's
    // inv(M)*x against a Cholesky solve, Ki on the error sum against a torque sum).
    assert!(worst[0] <= 1e-8, "overshoot differs by {} %", worst[0]);
    assert!(worst[1] <= 1e-8, "settling time differs by {} s", worst[1]);
    assert!(
        worst[2] <= 1e-12,
        "steady-state error differs by {} rad",
        worst[2]
    );
    assert!(worst[3] <= 1e-9, "RMSE differs by {} (relative)", worst[3]);
}

/// The authors' four measures of one run, recomputed here from the trajectory (independent of
/// `reaching.rs`): their arrays start with the initial state and belief, then one sample per
/// tick; RMSE pairs q(i) with the belief before reading it.
fn measures(q: &[[f64; 2]], mu_before: &[[f64; 2]], target: [f64; 2]) -> [f64; 4] {
    let q0 = q[0];
    let mut y = vec![0.0];
    y.extend(q.iter().map(|v| v[0] - q0[0]));
    let info = step_info(&y, 1e-3, target[0] - q0[0], 0.005);
    let last = q[q.len() - 1];
    let ess = ((target[0] - last[0]).abs() + (target[1] - last[1]).abs()) / 2.0;
    let samples = (q.len() + 1) as f64;
    let rmse = (0..2)
        .map(|j| {
            let sq: f64 = q
                .iter()
                .zip(mu_before)
                .map(|(a, b)| (a[j] - b[j]).powi(2))
                .sum();
            (sq / samples).sqrt()
        })
        .sum::<f64>()
        / 2.0;
    [
        info.overshoot,
        info.settling_time.unwrap_or(20.0),
        ess,
        rmse,
    ]
}

/// Prints the means over the tasks of the four measures, as docs/method.md quotes them.
fn print_means(label: &str, v: &[[f64; 4]]) {
    let n = v.len() as f64;
    let m = |i: usize| v.iter().map(|x| x[i]).sum::<f64>() / n;
    let unsettled = v.iter().filter(|x| x[1] >= 20.0).count();
    eprintln!(
        "{label}: overshoot {:.2} %, settling time {:.3} s ({unsettled} never), steady-state \
         error {:.3e} rad, RMSE {:.3e} rad",
        m(0),
        m(1),
        m(2),
        m(3)
    );
}

fn figures_of(reference: &[Figures]) -> Vec<[f64; 4]> {
    reference
        .iter()
        .map(|f| [f.overshoot, f.settling_time, f.steady_state_error, f.rmse])
        .collect()
}

/// The authors' script as published on their 100 targets, in aift: the compatibility scenario with
/// `overrides`, noise seed `seed`, each task's `controller.gains.integral_initial` chained from
/// the task before (the script sets its integral once, before the loop over tasks; our
/// second-to-last tick's integral is their last update's). Returns the four measures per task.
fn chained(reference: &[Figures], overrides: &[&str], seed: u64) -> Vec<[f64; 4]> {
    let base = common::setup("authors_matlab.toml", overrides);
    let ticks = base.scenario().ticks() as usize;
    assert_eq!(ticks, 20_000);
    let mut integral = vec![0.0, 0.0];
    let mut out = Vec::new();
    for f in reference {
        let mut s = base.clone();
        s.loaded.scenario.targets[0].q = f.target.to_vec();
        s.loaded.scenario.controller.gains.integral_initial = Some(integral.clone());
        let mut sim = Simulation::new(&s, Method::NoFt, seed, None).unwrap();
        let (mut q, mut mu_before) = (Vec::with_capacity(ticks), Vec::with_capacity(ticks));
        let mut last_mu = [0.0; 2];
        for k in 0..ticks {
            sim.decide(None);
            let r = sim.record();
            if k == 0 {
                last_mu = [r.readings.get(0).unwrap(), r.readings.get(1).unwrap()];
            }
            q.push([r.q[0], r.q[1]]);
            mu_before.push(last_mu);
            last_mu = [r.mu[0], r.mu[1]];
            if k + 2 == ticks {
                integral = sim.integral().to_vec();
            }
            sim.actuate(None);
        }
        out.push(measures(&q, &mu_before, f.target));
    }
    out
}

/// Chaining the integral reproduces the script as published, noise off, to machine precision.
#[test]
fn chaining_the_integral_reproduces_the_script_as_published() {
    let reference = octave_figures("octave_noiseless.csv");
    let ours = chained(
        &reference,
        &["sensors.encoder_sigma=0", "sensors.tachometer_sigma=0"],
        1,
    );
    let mut worst = [0.0f64; 4];
    for (o, f) in ours.iter().zip(&reference) {
        let theirs = [f.overshoot, f.settling_time, f.steady_state_error, f.rmse];
        for i in 0..4 {
            let d = (o[i] - theirs[i]).abs() / if i == 3 { theirs[i] } else { 1.0 };
            worst[i] = worst[i].max(d);
        }
    }
    eprintln!("largest differences, integral chained over 100 tasks: {worst:?}");
    print_means("the authors' script, noise off", &figures_of(&reference));
    print_means(
        "aift, compatibility settings, integral chained, noise off",
        &ours,
    );
    assert!(worst[0] <= 1e-8 && worst[1] <= 1e-8, "{worst:?}");
    assert!(worst[2] <= 1e-12 && worst[3] <= 1e-9, "{worst:?}");
}

/// With noise on, the two sides draw different noise (Octave's generator, aift's seed 1): their
/// means over the 100 tasks must agree within the spread of such means from seed to seed.
/// The tolerances are 5 x sqrt(2) x the standard deviation of that mean over aift's seeds 1 to 5
/// (overshoot 0.0037 %, settling time 0.018 s, steady-state error 2.4e-5 rad, RMSE 9.8e-7 rad;
/// measured from `aift run assets/scenarios/authors_matlab.toml --seed S --set
/// 'targets[0].q=[..]'` on each target, integral reset): two independent draws differ by
/// sqrt(2) of it, and 5 of those leaves room for the spread's own uncertainty from 5 seeds.
const TOLERANCES: [f64; 4] = [0.026, 0.125, 1.7e-4, 6.9e-6];

#[test]
fn with_noise_the_means_agree_within_seed_noise() {
    let reference = octave_figures("octave_noisy.csv");
    let ours = chained(&reference, &[], 1);
    let n = reference.len() as f64;
    let theirs = figures_of(&reference);
    print_means("the authors' script as published (noise on)", &theirs);
    print_means(
        "aift, compatibility settings, integral chained, seed 1",
        &ours,
    );
    let mean = |v: &[[f64; 4]], i: usize| v.iter().map(|x| x[i]).sum::<f64>() / n;
    let names = [
        "overshoot (%)",
        "settling time (s)",
        "steady-state error (rad)",
        "RMSE (rad)",
    ];
    for (i, tol) in TOLERANCES.iter().enumerate() {
        let (a, b) = (mean(&ours, i), mean(&theirs, i));
        eprintln!(
            "{}: aift {a:.6e}, the authors' script {b:.6e}, tolerance {tol:.1e}",
            names[i]
        );
        assert!((a - b).abs() <= *tol, "{}: {a} vs {b}", names[i]);
    }
}

/// Exit 2 with a message naming `file` and `key`, and no output folder.
fn refused(args: &[&str], dir: &Path, file: &str, key: &str) {
    let out = common::aift_in(args, dir);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(file) && err.contains(key), "{args:?}: {err}");
    assert!(!dir.join("out").exists(), "{args:?} wrote an output folder");
}

#[test]
fn bad_compatibility_settings_are_refused_naming_the_file_and_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().to_path_buf();
    let scenario = root().join("assets/scenarios/authors_matlab.toml");
    let text = std::fs::read_to_string(&scenario).unwrap().replace(
        "urdf = \"../../urdf/planar_2dof.urdf\"",
        &format!("urdf = {:?}", root().join("urdf/planar_2dof.urdf")),
    );
    let write = |name: &str, from: &str, to: &str| {
        assert!(text.contains(from), "{from}");
        std::fs::write(dir.join(name), text.replace(from, to)).unwrap();
    };
    write(
        "shape.toml",
        "kd_matrix = [[100.0, 0.0], [20.0, 0.0]]",
        "kd_matrix = [[100.0, 0.0, 0.0], [20.0, 0.0, 0.0]]",
    );
    refused(
        &["run", "shape.toml", "--out", "out"],
        &dir,
        "shape.toml",
        "kd_matrix",
    );
    write(
        "diagonal.toml",
        "kd_matrix = [[100.0, 0.0], [20.0, 0.0]]",
        "kd_matrix = [[100.0, 0.0], [20.0, 5.0]]",
    );
    refused(
        &["run", "diagonal.toml", "--out", "out"],
        &dir,
        "diagonal.toml",
        "kd_matrix",
    );
    write(
        "clamp.toml",
        "integral_lower = [-inf, -inf]",
        "integral_lower = [50.0, -inf]",
    );
    refused(
        &["run", "clamp.toml", "--out", "out"],
        &dir,
        "clamp.toml",
        "integral_lower",
    );
    write(
        "nan.toml",
        "integral_upper = [45.0, 4.5]",
        "integral_upper = [nan, 4.5]",
    );
    refused(
        &["run", "nan.toml", "--out", "out"],
        &dir,
        "nan.toml",
        "integral_upper",
    );
    write(
        "gn.toml",
        "update = \"gradient\"",
        "update = \"gauss-newton\"",
    );
    refused(
        &["run", "gn.toml", "--out", "out"],
        &dir,
        "gn.toml",
        "prediction",
    );
    write(
        "upper.toml",
        "integral_upper = [45.0, 4.5]",
        "integral_upper = [-inf, 4.5]",
    );
    refused(
        &["run", "upper.toml", "--out", "out"],
        &dir,
        "upper.toml",
        "integral_upper",
    );
    write("delay.toml", "delay_ticks = 1", "delay_ticks = 5000");
    refused(
        &["run", "delay.toml", "--out", "out"],
        &dir,
        "delay.toml",
        "delay_ticks",
    );
    // A channel left out (nominal 0) with a learning method.
    refused(
        &[
            "run",
            "diagonal.toml",
            "--method",
            "pl-always",
            "--out",
            "out",
        ],
        &dir,
        "diagonal.toml",
        "kd_matrix",
    );
    std::fs::write(dir.join("ok.toml"), &text).unwrap();
    refused(
        &["run", "ok.toml", "--method", "pl-always", "--out", "out"],
        &dir,
        "ok.toml",
        "precision.nominal",
    );

    // Targets files: the wrong joint count, a non-finite value, too few lines.
    let campaign = |targets: &str, extra: &str| {
        format!(
            "name = \"c\"\nseeds = 1\nmethods = [\"no-ft\"]\nchannels = []\nkinds = []\n\
             healthy = false\n[[arms]]\nname = \"a\"\nscenario = {:?}\n[reaching]\n\
             protocol = \"authors\"\ntargets_file = \"{targets}\"\ntasks = 2\n\
             duration = 1.0\n{extra}",
            dir.join("ok.toml")
        )
    };
    for (name, body, key_text) in [
        ("three.csv", "0.1, 0.2, 0.3\n0.1, 0.2, 0.3\n", "3 joints"),
        (
            "nonfinite.csv",
            "# a comment\n0.1, 0.2\n0.1, inf\n",
            "line 3",
        ),
        ("short.csv", "0.1, 0.2\n", "holds 1 targets"),
        ("ragged.csv", "0.1, 0.2\n0.1\n", "line 2"),
    ] {
        std::fs::write(dir.join(name), body).unwrap();
        std::fs::write(dir.join("c.toml"), campaign(name, "")).unwrap();
        let out = common::aift_in(&["campaign", "c.toml", "--out", "out"], &dir);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains("c.toml")
                && err.contains("reaching.targets_file")
                && err.contains(name)
                && err.contains(key_text),
            "{name}: {err}"
        );
        assert!(!dir.join("out").exists());
    }
    std::fs::write(dir.join("two.csv"), "0.1, 0.2\n0.3, 0.4\n").unwrap();
    for (extra, key) in [
        ("step_joint = 3\n", "reaching.step_joint"),
        ("target_range = [1.0, -1.0]\n", "reaching.target_range"),
        ("target_range = [-1.0, 0.0, 1.0]\n", "reaching.target_range"),
    ] {
        std::fs::write(dir.join("c.toml"), campaign("two.csv", extra)).unwrap();
        refused(&["campaign", "c.toml", "--out", "out"], &dir, "c.toml", key);
    }
    // A target outside a joint's limits (the Panda's joint 7 stops at 2.9 rad).
    std::fs::write(dir.join("panda.csv"), "0, 0, 0, -1.5, 0, 1.5, 5.0\n").unwrap();
    std::fs::write(
        dir.join("p.toml"),
        format!(
            "name = \"p\"\nseeds = 1\nmethods = [\"no-ft\"]\nchannels = []\nkinds = []\n\
             healthy = false\n[[arms]]\nname = \"panda\"\nscenario = {:?}\n[reaching]\n\
             targets_file = \"panda.csv\"\ntasks = 1\nduration = 1.0\n",
            root().join("assets/scenarios/panda_healthy.toml")
        ),
    )
    .unwrap();
    let out = common::aift_in(&["campaign", "p.toml", "--out", "out"], &dir);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("reaching.targets_file") && err.contains("joint 7") && err.contains("limits"),
        "{err}"
    );
    // And the same campaign, well formed, runs.
    std::fs::write(dir.join("c.toml"), campaign("two.csv", "")).unwrap();
    common::aift_ok(&["campaign", "c.toml", "--out", "out"], &dir);
}
