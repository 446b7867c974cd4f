//! Command-line arguments (clap).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

/// aift: fault-tolerant control of robot arms with active inference.
#[derive(Debug, Parser)]
#[command(name = "aift", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Validate a URDF and print the arm it describes.
    CheckUrdf(CheckUrdfArgs),
    /// Open-loop run of a URDF arm with constant joint torques, written as CSV.
    Simulate(SimulateArgs),
}

#[derive(Debug, Args)]
pub struct CheckUrdfArgs {
    /// The URDF file.
    pub path: PathBuf,
    /// End-effector link to check and report.
    #[arg(long)]
    pub ee: Option<String>,
}

/// A comma-separated list of finite numbers, e.g. `-1.2,0.8`.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatList(pub Vec<f64>);

/// Parses `a,b,c` into finite numbers.
pub fn parse_float_list(text: &str) -> Result<FloatList, String> {
    let mut values = Vec::new();
    for (i, item) in text.split(',').enumerate() {
        let item = item.trim();
        match item.parse::<f64>() {
            Ok(v) if v.is_finite() => values.push(v),
            Ok(_) => return Err(format!("item {} ({item:?}) is not finite", i + 1)),
            Err(_) => return Err(format!("item {} ({item:?}) is not a number", i + 1)),
        }
    }
    Ok(FloatList(values))
}

#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// The URDF file of the arm.
    #[arg(long)]
    pub urdf: PathBuf,
    /// End-effector link.
    #[arg(long, default_value = "ee")]
    pub ee: String,
    /// Initial joint positions, comma-separated (rad or m).
    #[arg(long, value_parser = parse_float_list, allow_hyphen_values = true)]
    pub q0: FloatList,
    /// Initial joint velocities, comma-separated (default: zeros).
    #[arg(long, value_parser = parse_float_list, allow_hyphen_values = true)]
    pub qd0: Option<FloatList>,
    /// Constant joint torques, comma-separated (default: zeros).
    #[arg(long, value_parser = parse_float_list, allow_hyphen_values = true)]
    pub torque: Option<FloatList>,
    /// Duration (s).
    #[arg(long)]
    pub duration: f64,
    /// Time step (s).
    #[arg(long, default_value_t = 0.001)]
    pub dt: f64,
    /// Solver iterations (substeps) per step.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Output CSV file.
    #[arg(long)]
    pub out: PathBuf,
}
