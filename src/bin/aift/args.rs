//! Command-line arguments (clap).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

/// aift: fault-tolerant control of robot arms with active inference.
#[derive(Debug, Parser)]
#[command(name = "aift", version, about, long_about = None)]
pub struct Cli {
    /// What to do; without a command, `run` on the embedded default scenario.
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Validate a URDF and print the arm it describes.
    CheckUrdf(CheckUrdfArgs),
    /// Open-loop run of a URDF arm with constant joint torques, written as CSV.
    Simulate(SimulateArgs),
    /// Run a scenario with one method and seed; write trajectory, summary, plots.
    Run(RunArgs),
    /// Run every method over many seeds; write the table beside the paper's Table 1.
    Table(TableArgs),
    /// Calibrate the fault detector on healthy runs of a scenario.
    Calibrate(CalibrateArgs),
    /// Train a scenario's camera GP and save it.
    TrainGp(TrainGpArgs),
    /// Measure the cost of each stage and of the closed loop.
    Bench(BenchArgs),
    /// Write a healthy scenario for any serial URDF arm, every value derived from the arm.
    Init(InitArgs),
    /// Write a random serial arm (URDF) drawn from a seed: arms nobody tuned for, to test methods on.
    GenArm(GenArmArgs),
    /// Run a fault campaign (every fault, channel, arm and method) and write its matrix.
    Campaign(CampaignArgs),
    /// Merge the shards of a campaign into the files of the whole campaign.
    Merge(MergeArgs),
    /// Run a method over recorded readings and applied torques (a rosbag2 bag or MCAP file with
    /// sensor_msgs/JointState, or a CSV): health, alarms, isolated channels and belief, as a run
    /// folder. The controller and the plant are not in the loop.
    Replay(ReplayArgs),
    /// Compare two methods of a campaign cell by cell: the Wilcoxon signed-rank test over the
    /// seeds (paired by seed) on log10 of their post-fault MSE ratio.
    Compare(CompareArgs),
    /// Write report.html (a self-contained page: plots, tables, the scenario) into a run, table
    /// or campaign folder.
    Report(ReportArgs),
    /// Print the scenario file's JSON Schema (for editors: validation and completion), or with
    /// `--markdown` its reference page (docs/scenario.md).
    Schema(SchemaArgs),
    /// Print a shell completion script, e.g. `aift completions bash > ~/.local/share/bash-completion/completions/aift`.
    Completions(CompletionsArgs),
}

#[derive(Debug, Args)]
pub struct SchemaArgs {
    /// Print the scenario reference as Markdown (every key, type, default and meaning) instead of
    /// the JSON Schema.
    #[arg(long)]
    pub markdown: bool,
}

#[derive(Debug, Args)]
pub struct ReportArgs {
    /// A folder written by `aift run`, `aift table`, `aift campaign` or `aift merge`.
    pub dir: PathBuf,
    /// Print {"kind", "report"} as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CompletionsArgs {
    /// The shell.
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

#[derive(Debug, Args)]
pub struct CampaignArgs {
    /// Campaign file (TOML); default: the bundled assets/campaigns/default.toml.
    pub campaign: Option<PathBuf>,
    /// Seeds per cell (default: the campaign's).
    #[arg(long)]
    pub seeds: Option<usize>,
    /// Methods, comma-separated (default: the campaign's).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Output folder (default: campaigns/<name>/).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// Run only the K-th of N disjoint slices of the grid (e.g. 3/8); merge with `aift merge`.
    #[arg(long)]
    pub shard: Option<String>,
    /// Override a value of every arm's scenario (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Print one JSON document on stdout (campaign.json; for a shard, what it ran and wrote); everything else goes to stderr.
    #[arg(long)]
    pub json: bool,
    /// Require a journal of an interrupted run of this same campaign and shard to resume from
    /// (exit 2 if there is none). Without it, a matching journal is resumed anyway.
    #[arg(long, conflicts_with = "fresh")]
    pub resume: bool,
    /// Discard the journal of an interrupted run and start from nothing.
    #[arg(long)]
    pub fresh: bool,
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The log: a rosbag2 bag folder (MCAP storage), a .mcap file, or a .csv with columns t,
    /// applied1..N and y_<channel> (a run's trajectory.csv is one).
    pub log: PathBuf,
    /// The scenario of the arm that was recorded (its URDF, sensors, dt, method settings; the
    /// faults it declares are what detections are scored against); default: the embedded one.
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Override a scenario value (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
    /// Method (default: the scenario's).
    #[arg(long)]
    pub method: Option<String>,
    /// Seed of the estimators' model-error draw (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// The sensor_msgs/msg/JointState topic (default: /joint_states, else the only one).
    #[arg(long)]
    pub topic: Option<String>,
    /// The camera's geometry_msgs/msg/PointStamped topic (default: /camera/point if present;
    /// without one the camera's readings are missing).
    #[arg(long)]
    pub camera_topic: Option<String>,
    /// Output folder (default: runs/replay-<log name>-<method>/).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// Detector calibration file; default: calibrate on the fly.
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Print the summary as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// A campaign folder (written by `aift campaign` or `aift merge`: its records.json is read).
    pub dir: PathBuf,
    /// Method A (a name as in the campaign, e.g. hybrid).
    pub a: String,
    /// Method B.
    pub b: String,
    /// Two-sided significance level, in (0, 0.5].
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    /// Print the comparisons as JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct MergeArgs {
    /// The shards' output folders.
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace a non-empty output folder.
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Args)]
pub struct InitArgs {
    /// The URDF of the arm.
    #[arg(long)]
    pub urdf: PathBuf,
    /// End-effector link (default: `ee`, else a link of the last moving body named end_effector, tcp, tool or flange, else its last link).
    #[arg(long)]
    pub ee: Option<String>,
    /// Repair inertias that break the triangle inequality.
    #[arg(long)]
    pub balance_inertia: bool,
    /// The scenario file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
    /// Write the scenario without the check run (a healthy no-ft run on the articulated engine
    /// that must reach its targets), e.g. to tune its gains by hand.
    #[arg(long)]
    pub no_check: bool,
}

#[derive(Debug, Args)]
pub struct GenArmArgs {
    /// The seed: the same seed gives the same arm, byte for byte.
    #[arg(long)]
    pub seed: u64,
    /// Fewest and most joints, e.g. `2..7` or `7` (at most 12).
    #[arg(long, visible_alias = "dof", default_value = "2..7", value_parser = parse_joint_range)]
    pub joints: (usize, usize),
    /// The URDF file to write (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
}

/// `A..B` or `A` (inclusive).
fn parse_joint_range(text: &str) -> Result<(usize, usize), String> {
    let number = |s: &str| {
        s.trim()
            .parse::<usize>()
            .map_err(|_| format!("`{text}`: expected a joint count or a range such as 2..7"))
    };
    let (lo, hi) = match text.split_once("..") {
        Some((a, b)) => (number(a)?, number(b.trim_start_matches('='))?),
        None => {
            let n = number(text)?;
            (n, n)
        }
    };
    let most = aift::arm::generate::MAX_GENERATED_JOINTS;
    if lo < 1 || lo > hi || hi > most {
        return Err(format!("`{text}`: need 1 <= fewest <= most <= {most}"));
    }
    Ok((lo, hi))
}

/// The scenario and overrides every scenario command takes.
#[derive(Debug, Default, Args)]
pub struct ScenarioArgs {
    /// Scenario file (TOML); default: the embedded paper_encoder_freeze scenario.
    pub scenario: Option<PathBuf>,
    /// Override a scenario value, e.g. `--set belief.step=0.5` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE", allow_hyphen_values = true)]
    pub set: Vec<String>,
}

#[derive(Debug, Default, Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Method: no-ft, pl-always, pl-detect, deterministic, bayes, window, hybrid, ekf-gate,
    /// vb-akf, imm, oracle (default: the scenario's, pl-always unless it says otherwise).
    #[arg(long)]
    pub method: Option<String>,
    /// Sensor-noise seed (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output folder (default: runs/<scenario>-<method>-<seed>/).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write into a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// Detector calibration file (pl-detect, deterministic); default: calibrate on the fly.
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Print one JSON document on stdout (the run's summary.json); everything else goes to stderr.
    #[arg(long)]
    pub json: bool,
    /// Also write run.mcap: the run as ROS 2 messages (JointState readings, truth, belief;
    /// precision, health, F, fault events) for Foxglove / Lichtblick, Rerun and ros2 bag.
    #[arg(long)]
    pub mcap: bool,
}

#[derive(Debug, Args)]
pub struct TableArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Number of seeds (the scenario's seed and the ones after it).
    #[arg(long, default_value_t = 20)]
    pub seeds: usize,
    /// Methods, comma-separated (default: every method).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Output folder (default: tables/<scenario>/).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write into a non-empty output folder.
    #[arg(long)]
    pub force: bool,
    /// Detector calibration file; default: calibrate on the fly.
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Print one JSON document on stdout (the table's table.json); everything else goes to stderr.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Healthy runs (default: the scenario's detector.calibration_runs, 50).
    #[arg(long)]
    pub runs: Option<usize>,
    /// Output JSON file.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct TrainGpArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Training points (default: the scenario's gp.points).
    #[arg(long)]
    pub points: Option<usize>,
    /// Output JSON file.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// Ticks per measured stage.
    #[arg(long, default_value_t = 20_000)]
    pub ticks: u64,
    /// Method of the timed closed loop (default: the scenario's `precision.method`, which
    /// `--set precision.method=...` changes).
    #[arg(long)]
    pub method: Option<String>,
    /// Detector calibration file (pl-detect, deterministic); default: calibrate on the fly.
    #[arg(long)]
    pub calib: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct CheckUrdfArgs {
    /// The URDF file.
    pub path: PathBuf,
    /// End-effector link to check and report.
    #[arg(long)]
    pub ee: Option<String>,
    /// Repair inertias that break the triangle inequality (raise the middle principal moment
    /// just enough), with a warning naming the link.
    #[arg(long)]
    pub balance_inertia: bool,
    /// Print one JSON document on stdout (the arm: joints, links, masses, end effector, warnings); everything else goes to stderr.
    #[arg(long)]
    pub json: bool,
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

/// The plant's engine, as `simulate` takes it.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum EngineArg {
    Rapier,
    Articulated,
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
    /// Solver iterations (rapier) or substeps (articulated) per step (default 2).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// The engine: rapier (default) or articulated.
    #[arg(long, value_enum, default_value = "rapier")]
    pub engine: EngineArg,
    /// Repair inertias that break the triangle inequality.
    #[arg(long)]
    pub balance_inertia: bool,
    /// Output CSV file.
    #[arg(long)]
    pub out: PathBuf,
}
