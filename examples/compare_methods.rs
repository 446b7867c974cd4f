//! Every method once on a scenario, each against the oracle (20-run calibration for speed):
//! `cargo run --release --example compare_methods -- [SCENARIO] [SEED] [KEY=VALUE ...]`
use aift::scenario::{LoadedScenario, Method, Run, RunSetup, calibrate::calibrate};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .cloned()
        .unwrap_or_else(|| "assets/scenarios/paper_encoder_freeze.toml".into());
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let overrides: Vec<String> = args.iter().skip(2).cloned().collect();
    let loaded = LoadedScenario::from_file(std::path::Path::new(&path), &overrides).unwrap();
    let setup = RunSetup::prepare(loaded).unwrap();
    let t = std::time::Instant::now();
    let cal = calibrate(&setup, 20);
    eprintln!(
        "calibration {:.1} s: {}",
        t.elapsed().as_secs_f64(),
        if cal.is_ok() {
            "ok".to_string()
        } else {
            format!("{:?}", cal.as_ref().err())
        }
    );
    let cal = cal.ok();
    for method in Method::ALL {
        if method.needs_detector() && cal.is_none() {
            continue;
        }
        let r = Run::new(&setup, method)
            .seed(seed)
            .calibration(cal.as_ref())
            .execute()
            .unwrap();
        println!(
            "{:14} {:9} mse {:?} final {:?} det {:?} iso {:?} health {:?} min5 {:?} {:.0} t/s",
            method.name(),
            r.outcome.name(),
            r.mse_per_joint
                .iter()
                .map(|v| format!("{v:.2e}"))
                .collect::<Vec<_>>(),
            r.final_error_per_joint
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>(),
            r.detected_at,
            r.isolated_channel,
            r.final_health
                .iter()
                .map(|v| format!("{v:.2e}"))
                .collect::<Vec<_>>(),
            r.min_health_last_5s
                .iter()
                .map(|v| format!("{v:.2}"))
                .collect::<Vec<_>>(),
            r.ticks_per_second()
        );
    }
}
