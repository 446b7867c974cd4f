//! aift: fault-tolerant control of robot arms with active inference.
//!
//! The crate follows the data flow of the method (see `ARCHITECTURE.md` and `docs/method.md`):
//! [`arm`] (the model: URDF, kinematics, dynamics) -> [`plant`] (rapier, articulated) -> [`sensors`] and faults -> generative model ([`gp`]) ->
//! [`estimation`] (the u-AIC and classical estimators) and [`control`] (f*, action) ->
//! [`precision`] learners and detectors -> [`scenario`] runner, metrics, tables -> [`report`].
//! [`fsio`] (bounded reads, atomic and staged writes) sits below them all.

pub mod arm;
pub mod control;
pub mod estimation;
pub mod fsio;
pub mod gp;
pub mod plant;
pub mod precision;
pub mod report;
pub mod scenario;
pub mod sensors;
mod settings;

pub use settings::SettingError;

/// An error and its sources joined by `: `, as the CLI prints them (anyhow's `{:#}`).
pub fn error_chain(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        text.push_str(": ");
        text.push_str(&e.to_string());
        source = e.source();
    }
    text
}
