//! The studies behind the README's findings, each a Monte Carlo over a few seeds:
//!
//! - `update-scheme`: Gauss-Newton against the paper's gradient descent, with physical
//!   precisions and in the authors' "tuning units" (every precision 1);
//! - `prior-scale`: who gets blamed for a frozen encoder as the state prior P_mu varies;
//! - `prediction`: the paper's against the coupled prediction, encoder and tachometer freezes;
//! - `fault-sites`: every method on tachometer-1 freeze, camera freeze and camera bias;
//! - `integral-gain`: how far joint 1 is from the first target at 7.5 s for Ki = 50 and 150;
//! - `warm-up`: the lowest channel health of a 200 s healthy run with and without the prior's
//!   warm-up.
//!
//! `cargo run --release --example studies -- STUDY [SEEDS]` (every study when none is named).

use aift::scenario::calibrate::calibrate;
use aift::scenario::table::run_table;
use aift::scenario::{LoadedScenario, Method, ObserverMode, Run, RunSetup, TrajectoryRecorder};

fn setup(file: &str, overrides: &[&str]) -> RunSetup {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let loaded = LoadedScenario::from_file(&root.join(file), &overrides).expect("scenario");
    RunSetup::prepare(loaded).expect("setup")
}

fn sci(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.2e}"))
}

/// Runs `methods` over `seeds` and prints one markdown row per method, prefixed by `label`.
fn rows(label: &str, setup: &RunSetup, methods: &[Method], seeds: &[u64]) {
    let calibration = methods
        .iter()
        .any(|m| m.needs_detector())
        .then(|| calibrate(setup, 20));
    let calibration = match calibration {
        Some(Ok(c)) => Some(c),
        Some(Err(e)) => {
            println!("| {label} | (no calibration: {e}) | | | | | |");
            None
        }
        None => None,
    };
    let methods: Vec<Method> = methods
        .iter()
        .copied()
        .filter(|m| !m.needs_detector() || calibration.is_some())
        .collect();
    let table = run_table(setup, &methods, seeds, calibration.as_ref(), &|| {}).expect("runs");
    let layout = setup.layout;
    for row in &table.rows {
        let runs: Vec<_> = table.runs.iter().filter(|r| r.method == row.name).collect();
        // Mean final health per channel, to see who got blamed.
        let health: Vec<String> = (0..layout.len())
            .map(|c| {
                let mean = runs.iter().map(|r| r.final_health[c]).sum::<f64>() / runs.len() as f64;
                format!("{}={:.2}", layout.name(c), mean)
            })
            .collect();
        let all = runs
            .iter()
            .map(|r| r.mse_per_joint.iter().copied().fold(0.0, f64::max))
            .sum::<f64>()
            / runs.len() as f64;
        println!(
            "| {label} | {} | {} | {} | {} | {:.4} | {}/{} | {} |",
            row.name,
            sci(row.mse_faulty_mean),
            sci(row.mse_healthy_mean),
            sci(Some(all)),
            row.max_final_error_mean,
            row.diverged,
            row.seeds,
            health.join(" ")
        );
    }
}

fn header() {
    println!(
        "| case | method | faulty MSE | healthy MSE | worst-joint MSE | max final error (rad) | diverged | mean final health |"
    );
    println!("|---|---|---|---|---|---|---|---|");
}

const ENC: &str = "assets/scenarios/paper_encoder_freeze.toml";
const HEALTHY: &str = "assets/scenarios/paper_healthy.toml";
const TACH: &str = "assets/scenarios/paper_tachometer_freeze.toml";
const CAM_FREEZE: &str = "assets/scenarios/paper_camera_freeze.toml";
const CAM_BIAS: &str = "assets/scenarios/paper_camera_bias.toml";

fn update_scheme(seeds: &[u64]) {
    println!("\n### update scheme (encoder freeze at 8 s)\n");
    header();
    let m = [Method::NoFt, Method::PlAlways, Method::Oracle];
    rows(
        "Gauss-Newton, physical precisions",
        &setup(ENC, &[]),
        &m,
        seeds,
    );
    for kappa in ["200.0", "1e-5", "1e-6"] {
        let k = format!("belief.kappa_mu={kappa}");
        rows(
            &format!("gradient kappa_mu={kappa}, physical precisions"),
            &setup(ENC, &["belief.update=\"gradient\"", &k]),
            &m,
            seeds,
        );
    }
    let unit = [
        "belief.update=\"gradient\"",
        "belief.kappa_mu=200.0",
        "belief.prediction=\"paper\"",
        "belief.prior_position_precision=1.0",
        "belief.prior_velocity_precision=1.0",
        "precision.nominal=[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]",
        "precision.max_ratio=1e6",
    ];
    rows(
        "authors' units: every precision 1, gradient kappa_mu=200",
        &setup(ENC, &unit),
        &m,
        seeds,
    );
    rows(
        "authors' units, healthy run",
        &setup(HEALTHY, &unit),
        &[Method::NoFt],
        seeds,
    );
}

fn prior_scale(seeds: &[u64]) {
    println!("\n### state prior scale (encoder freeze at 8 s)\n");
    header();
    for pm in ["1e6", "1e7", "1e8", "1e9"] {
        let o = format!("belief.prior_position_precision={pm}");
        rows(
            &format!("P_mu = {pm}"),
            &setup(ENC, &[&o]),
            &[
                Method::PlAlways,
                Method::Bayes,
                Method::Window,
                Method::Deterministic,
            ],
            seeds,
        );
    }
}

fn prediction(seeds: &[u64]) {
    println!("\n### prediction: paper against coupled\n");
    header();
    for (case, file) in [("encoder freeze", ENC), ("tachometer-1 freeze", TACH)] {
        for p in ["paper", "coupled"] {
            let o = format!("belief.prediction=\"{p}\"");
            rows(
                &format!("{case}, {p}"),
                &setup(file, &[&o]),
                &Method::ALL,
                seeds,
            );
        }
    }
}

fn fault_sites(seeds: &[u64]) {
    println!("\n### other fault sites (coupled prediction, defaults)\n");
    header();
    for (case, file) in [
        ("tachometer-1 freeze", TACH),
        ("camera freeze", CAM_FREEZE),
        ("camera bias +0.04 m", CAM_BIAS),
    ] {
        rows(case, &setup(file, &[]), &Method::ALL, seeds);
    }
}

fn integral_gain(seeds: &[u64]) {
    println!("\n### integral gain: distance to the first target at 7.5 s (healthy run, no-ft)\n");
    println!("| Ki (N m/(rad s)) | joint 1 (rad) | joint 2 (rad) |");
    println!("|---|---|---|");
    for ki in ["50.0", "150.0"] {
        let o = format!("controller.gains.ki=[{ki}, {ki}]");
        let s = setup(HEALTHY, &[&o]);
        let mut err = [0.0; 2];
        for &seed in seeds {
            let mut rec = TrajectoryRecorder::new(&s.layout);
            Run::new(&s, Method::NoFt)
                .seed(seed)
                .observe(&mut rec, ObserverMode::Always)
                .execute()
                .expect("run");
            let row = &rec.rows[7499];
            for j in 0..2 {
                let q = row[rec.column(&format!("q{}", j + 1)).unwrap()];
                let target = s.scenario().targets[0].q[j];
                err[j] += (q - target).abs() / seeds.len() as f64;
            }
        }
        println!("| {ki} | {:.4} | {:.4} |", err[0], err[1]);
    }
}

fn warm_up(seeds: &[u64]) {
    println!("\n### prior warm-up: lowest health over a 200 s healthy run (when)\n");
    println!("| warm-up ticks | method | lowest health | channel | at t (s) |");
    println!("|---|---|---|---|---|");
    for ticks in ["100", "0"] {
        let o = format!("belief.prior_warmup_ticks={ticks}");
        let s = setup(HEALTHY, &["duration=200.0", &o]);
        for method in [Method::PlAlways, Method::Window] {
            let mut lowest = (f64::INFINITY, String::new(), 0.0);
            for &seed in seeds {
                let mut rec = TrajectoryRecorder::new(&s.layout);
                Run::new(&s, method)
                    .seed(seed)
                    .observe(&mut rec, ObserverMode::Always)
                    .execute()
                    .expect("run");
                for name in rec.header.iter().filter(|h| h.starts_with("health_")) {
                    let c = rec.column(name).unwrap();
                    for row in &rec.rows {
                        if row[c] < lowest.0 {
                            lowest = (row[c], name.replace("health_", ""), row[0]);
                        }
                    }
                }
            }
            println!(
                "| {ticks} | {} | {:.3} | {} | {:.3} |",
                method.name(),
                lowest.0,
                lowest.1,
                lowest.2
            );
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let study = args.first().map(String::as_str).unwrap_or("all");
    let n: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(4);
    let seeds: Vec<u64> = (1..=n).collect();
    println!("seeds 1..={n}");
    match study {
        "update-scheme" => update_scheme(&seeds),
        "prior-scale" => prior_scale(&seeds),
        "prediction" => prediction(&seeds),
        "fault-sites" => fault_sites(&seeds),
        "integral-gain" => integral_gain(&seeds),
        "warm-up" => warm_up(&seeds),
        _ => {
            update_scheme(&seeds);
            prior_scale(&seeds);
            prediction(&seeds);
            fault_sites(&seeds);
            integral_gain(&seeds);
            warm_up(&seeds);
        }
    }
}
