//! A method defined outside the library, run through the same loop, metrics and run folder as
//! the built-in ones: a precision method of its own (a residual gate with a memory) driving the
//! library's u-AIC, plugged in with the public API `Run::with_parts` (as `aift.run` does for a
//! method written in Python).
//!
//! `cargo run --release --example custom_method -- [SCENARIO]`

use std::path::PathBuf;

use aift::precision::{PrecisionInput, PrecisionMethod};
use aift::scenario::method::{MethodContext, build};
use aift::scenario::{LoadedScenario, Method, Run, RunSetup};

/// A channel whose residual stays beyond `k` standard deviations of its nominal noise for
/// `patience` ticks in a row is dropped (precision 0) for good; the others keep their nominal
/// precision.
struct PatientGate {
    nominal: Vec<f64>,
    precisions: Vec<f64>,
    beyond: Vec<u32>,
    k: f64,
    patience: u32,
}

impl PrecisionMethod for PatientGate {
    fn precisions(&self) -> &[f64] {
        &self.precisions
    }

    fn update(&mut self, input: &PrecisionInput<'_>) {
        for (c, r) in input.estimate.residuals.iter().enumerate() {
            let sigma = 1.0 / self.nominal[c].sqrt();
            match r {
                Some(r) if r.abs() > self.k * sigma => self.beyond[c] += 1,
                _ => self.beyond[c] = 0,
            }
            if self.beyond[c] >= self.patience {
                self.precisions[c] = 0.0;
            }
        }
    }
}

fn main() -> anyhow::Result<()> {
    let loaded = match std::env::args().nth(1) {
        Some(path) => LoadedScenario::from_file(&PathBuf::from(path), &[])?,
        None => LoadedScenario::embedded_default(&[])?,
    };
    let setup = RunSetup::prepare(loaded)?;
    let seed = setup.scenario().seed;
    let nominal = setup.nominal_precisions();
    // The library's u-AIC (no-FT's estimator: its precisions come from the method beside it).
    let (uaic, _) = build(
        Method::NoFt,
        &MethodContext {
            setup: &setup,
            model: setup.estimator_model(seed),
            layout: &setup.layout,
            nominal: &nominal,
            calibration: None,
        },
    )?;
    let gate = PatientGate {
        precisions: nominal.clone(),
        beyond: vec![0; nominal.len()],
        nominal,
        k: 4.0,
        patience: 20,
    };
    for (label, result) in [
        (
            "patient-gate",
            Run::with_parts(&setup, "patient-gate", (uaic, Box::new(gate)))
                .seed(seed)
                .execute()?,
        ),
        (
            "no-ft",
            Run::new(&setup, Method::NoFt).seed(seed).execute()?,
        ),
    ] {
        println!(
            "{label:>12}: {} | faulty-joint MSE {:?} | final error {:.4} rad | detected at {:?}, isolated {:?}",
            result.outcome.name(),
            result.mse_faulty,
            result.max_final_error,
            result.detected_at,
            result.isolated_channel
        );
    }
    Ok(())
}
