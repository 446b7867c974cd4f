//! aift: fault-tolerant control of robot arms with active inference.
//!
//! The crate follows the data flow of the method (see `ARCHITECTURE.md` and `docs/method.md`):
//! [`arm`] (the model: URDF, kinematics, dynamics) -> [`plant`] (rapier, articulated) -> [`sensors`] and faults -> generative model ([`gp`]) ->
//! [`estimation`] (the u-AIC and classical estimators) and [`control`] (f*, action) ->
//! [`precision`] learners and detectors -> [`scenario`] runner, metrics, tables -> [`report`].
//! [`fsio`] (bounded reads, atomic and staged writes) sits below them all.
//!
//! A run in a few lines, what `aift run` does without writing files (the embedded default
//! scenario: the paper's arm, joint 1's encoder freezing at 8 s; shortened here):
//!
//! ```
//! use aift::scenario::{LoadedScenario, Method, RunSetup, runner::Run};
//!
//! let loaded = LoadedScenario::embedded_default(&["duration=1.0".to_string()])?;
//! let setup = RunSetup::prepare(loaded)?; // loads the URDF, trains the camera GP
//! let result = Run::new(&setup, Method::PlAlways).seed(2).execute()?;
//! assert_eq!(result.outcome.name(), "completed");
//! println!("belief MSE per joint {:?}", result.mse_per_joint);
//! # Ok::<(), aift::scenario::ScenarioError>(())
//! ```
//!
//! `examples/` has the rest: a run folder, a Monte Carlo table, a u-AIC fed by hand.

pub mod arm;
pub mod control;
pub mod estimation;
pub mod fsio;
pub mod gp;
pub mod logs;
pub mod plant;
pub mod precision;
pub mod report;
pub mod scenario;
pub mod sensors;
mod settings;

pub use fsio::SOURCE_DIGEST;
pub use settings::{SettingError, check_window, tick_at};

/// Most worker threads aift's thread pool is given, whatever `RAYON_NUM_THREADS` asks for:
/// four per core, and at least 64 (`RAYON_NUM_THREADS=100000` spent minutes creating threads).
pub fn max_worker_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    cores.saturating_mul(4).max(64)
}

/// Sets up the global thread pool with `RAYON_NUM_THREADS` bounded by [`max_worker_threads`];
/// returns a warning when it was lowered. Call it before any parallel work (the CLI and the
/// Python package do); a pool that already exists is left as it is.
pub fn init_thread_pool() -> Option<String> {
    let asked = std::env::var("RAYON_NUM_THREADS").ok()?;
    let max = max_worker_threads();
    let n: u128 = asked.trim().parse().ok()?;
    if n <= max as u128 {
        return None;
    }
    let built = rayon::ThreadPoolBuilder::new()
        .num_threads(max)
        .build_global();
    built.ok().map(|()| {
        format!("RAYON_NUM_THREADS={asked} is more than {max} (four per core, at least 64); using {max} threads")
    })
}

/// An error and its sources joined by `: ` (a source the text already ends with once), as the
/// CLI prints them.
pub fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        push_cause(&mut text, &e.to_string());
        source = e.source();
    }
    text
}

/// Appends `: cause` to an error's text, unless the text already ends with `: cause` (an error
/// whose message includes its source's, which `#[source]` also exposes, would print it twice).
pub fn push_cause(text: &mut String, cause: &str) {
    let told = text
        .strip_suffix(cause)
        .is_some_and(|head| head.ends_with(": "));
    if !told {
        text.push_str(": ");
        text.push_str(cause);
    }
}
