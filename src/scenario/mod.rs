//! Scenarios: files in, runs and tables out.
//!
//! [`config`] is the TOML schema (every default in one place, one `validate`); this module loads
//! scenarios (from a file, or the embedded default), applies `--set KEY=VALUE` overrides, and
//! prepares what every run of a scenario shares ([`RunSetup`]: the arm model, its channel
//! layout, the GP, the faults). [`runner`] steps one (method, seed) with observers;
//! [`metrics`] measures it; [`trajectory`] records it; [`calibrate`] makes the detector's
//! healthy statistics; [`table`] runs every method over many seeds.

pub mod bench;
pub mod calibrate;
pub mod campaign;
pub mod config;
pub mod init;
pub mod load;
pub mod method;
pub mod metrics;
pub mod reference;
pub mod runner;
pub mod setup;
pub mod table;
pub mod trajectory;

use std::path::PathBuf;

pub use config::{
    GpConfig, MAX_TICKS, MAX_TRAJECTORY_BYTES, PrecisionConfig, RobotConfig, Scenario, Target,
};
pub use load::{DEFAULT_SCENARIO_NAME, Layer, LoadedScenario, parse_scenario, scenario_schema};
pub use method::Method;
pub use metrics::{
    ActuatorOutcome, ChatterMonitor, Chattering, DisturbanceOutcome, FaultOutcome, MomentumSummary,
    RunMetrics, RunResult, StepInfo, step_info,
};
pub use reference::scenario_reference_markdown;
pub use runner::{
    DivergenceReason, NoObserver, Observer, ObserverMode, Observers, Outcome, Run, RunStart,
    Simulation, StopReason, TickRecord,
};
pub use setup::{
    Conditions, GpSource, RunSetup, fingerprint, train_gp, train_gp_fresh, training_box,
};
pub use trajectory::{TrajectoryColumns, TrajectoryRecorder, TrajectorySchema, TrajectoryWriter};

use crate::arm::ArmError;
use crate::fsio::FsError;
use crate::gp::GpError;
use crate::plant::PlantError;

/// Errors of the scenario stage; each names the file and the key.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    #[error(transparent)]
    File(#[from] FsError),
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: {} {message}", quoted_field(field))]
    Invalid {
        path: PathBuf,
        field: String,
        message: String,
    },
    #[error("--set {key}: {message}")]
    Override { key: String, message: String },
    #[error(transparent)]
    Arm(#[from] ArmError),
    #[error(transparent)]
    Plant(#[from] PlantError),
    #[error("{path}: `{field}`")]
    Robot {
        path: PathBuf,
        field: &'static str,
        #[source]
        source: Box<ArmError>,
    },
    #[error("{path}: the camera GP")]
    Gp {
        path: PathBuf,
        #[source]
        source: GpError,
    },
    #[error("{path}: {message}")]
    Calibration { path: PathBuf, message: String },
}

/// A key in backticks (`faults[0].start`); a phrase that is not one (init's "the end effector
/// ...", a campaign's "cell `x` of arm y: ...") as it is.
fn quoted_field(field: &str) -> String {
    if field.contains(' ') || field.contains('`') {
        field.to_string()
    } else {
        format!("`{field}`")
    }
}

impl ScenarioError {
    /// The override (`KEY=VALUE`) that set the key this error is about, if one did: callers
    /// put it in front of the message (`--set KEY=VALUE: ...`).
    pub fn blamed_override<'a>(&self, overrides: &'a [String]) -> Option<&'a str> {
        let field = match self {
            ScenarioError::Invalid { field, .. } => field.as_str(),
            ScenarioError::Robot { field, .. } => field,
            _ => return None,
        };
        // Overrides apply in order: the last one that touched the key set what is refused.
        overrides
            .iter()
            .rev()
            .find(|o| {
                let key = o.split_once('=').map_or(o.as_str(), |(k, _)| k.trim());
                field == key
                    || field.starts_with(&format!("{key}."))
                    || field.starts_with(&format!("{key}["))
                    || key.starts_with(&format!("{field}."))
                    || key.starts_with(&format!("{field}["))
            })
            .map(String::as_str)
    }

    /// The message as the CLI prints it (after `error: `): this error and its sources, joined
    /// by `: `, with the override that set the offending key in front.
    pub fn message(&self, overrides: &[String]) -> String {
        let chain = crate::error_chain(self);
        match self.blamed_override(overrides) {
            Some(o) => format!("--set {o}: {chain}"),
            None => chain,
        }
    }
}
