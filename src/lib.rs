//! aift: fault-tolerant control of robot arms with active inference.
//!
//! The crate follows the data flow of the method (see `ARCHITECTURE.md`):
//! [`plant`] (URDF, physics) -> sensors and faults -> generative model (GP) -> u-AIC estimation and
//! control -> precision learners and detector -> scenario runner -> reports.

pub mod gp;
pub mod plant;
pub mod precision;
pub mod report;
pub mod scenario;
pub mod sensors;
pub mod uaic;
