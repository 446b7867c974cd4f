//! The commands: each parses nothing itself, calls the library, prints, and maps errors to exit
//! codes.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::anyhow;

use aift::arm;
use aift::fsio::{FsError, OutputKind, Staged};
use aift::plant::{self, Engine, PlantSettings};
use aift::precision::Calibration;
use aift::report::{self, ReportError, run_files, table_files};
use aift::scenario::campaign::{Campaign, CampaignRecords, CampaignRun, Shard};
use aift::scenario::{self, LoadedScenario, Method, RunSetup, calibrate, table};

use crate::args::{
    BenchArgs, CalibrateArgs, CampaignArgs, CheckUrdfArgs, Cli, Command, CompareArgs, GenArmArgs,
    InitArgs, MergeArgs, ReplayArgs, RunArgs, ScenarioArgs, SimulateArgs, TableArgs, TrainGpArgs,
};

/// A line for people: on stdout, or on stderr when `--json` keeps stdout for one JSON document.
macro_rules! say {
    ($json:expr, $($arg:tt)*) => {
        if $json {
            errln!($($arg)*)
        } else {
            outln!($($arg)*)
        }
    };
}

/// Prints the JSON document `--json` asks for: a file the command wrote, as written.
fn print_json_file(path: &Path) -> Result<(), Failure> {
    let text =
        aift::fsio::read_text(path, aift::fsio::MAX_CALIBRATION_BYTES).map_err(file_failure)?;
    outln!("{}", text.trim_end());
    Ok(())
}

/// A failed command: the error and the exit code it maps to.
pub struct Failure {
    pub error: anyhow::Error,
    pub code: u8,
}

/// Exit code 2: the input is at fault.
fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        error: error.into(),
        code: 2,
    }
}

/// Exit code 1: aift or the machine is at fault.
fn internal(error: impl Into<anyhow::Error>) -> Failure {
    Failure {
        error: error.into(),
        code: 1,
    }
}

/// A file error: exit 2 when the path given is at fault, 1 when the disk is.
fn file_failure(error: FsError) -> Failure {
    if error.is_input_error() {
        bad_input(error)
    } else {
        internal(error)
    }
}

/// A report error: exit 2 when the input is at fault, 1 otherwise.
fn report_failure(error: ReportError) -> Failure {
    if error.is_input_error() {
        bad_input(error)
    } else {
        internal(error)
    }
}

/// Stages an output (checked before any work: location, --force, a concurrent writer).
fn stage(path: &Path, kind: OutputKind, force: bool) -> Result<Staged, Failure> {
    Staged::begin(path, kind, force).map_err(file_failure)
}

/// Most seeds of a table.
const MAX_SEEDS: usize = 100_000;
/// Most ticks per stage of `bench`.
const MAX_BENCH_TICKS: u64 = 100_000_000;

pub fn dispatch(cli: Cli) -> Result<(), Failure> {
    match cli
        .command
        .unwrap_or_else(|| Command::Run(RunArgs::default()))
    {
        Command::CheckUrdf(args) => check_urdf(args),
        Command::GenArm(args) => gen_arm(args),
        Command::Simulate(args) => simulate(args),
        Command::Run(args) => run(args),
        Command::Table(args) => table(args),
        Command::Calibrate(args) => calibrate_cmd(args),
        Command::TrainGp(args) => train_gp(args),
        Command::Bench(args) => bench(args),
        Command::Init(args) => init(args),
        Command::Campaign(args) => campaign(args),
        Command::Merge(args) => merge(args),
        Command::Compare(args) => compare(args),
        Command::Replay(args) => replay(args),
        Command::Report(args) => {
            let (kind, path) = report::html::write_report(&args.dir).map_err(report_failure)?;
            if args.json {
                outln!(
                    "{}",
                    serde_json::json!({"kind": kind.name(), "report": path})
                );
            } else {
                outln!("wrote the {} report {}", kind.name(), path.display());
            }
            Ok(())
        }
        Command::Schema(args) => {
            if args.markdown {
                out!("{}", scenario::scenario_reference_markdown());
            } else {
                let schema = scenario::scenario_schema();
                outln!(
                    "{}",
                    serde_json::to_string_pretty(&schema).expect("a schema serialises")
                );
            }
            Ok(())
        }
        Command::Completions(args) => {
            use clap::CommandFactory;
            // Into memory first: clap_complete panics when its writer fails.
            let mut script = Vec::new();
            clap_complete::generate(args.shell, &mut Cli::command(), "aift", &mut script);
            crate::output::stdout_bytes(&script);
            Ok(())
        }
    }
}

/// The bundled default campaign, where this build of aift finds its repository.
fn default_campaign_path() -> PathBuf {
    aift::scenario::campaign::bundled_campaign_path()
}

fn campaign(args: CampaignArgs) -> Result<(), Failure> {
    use aift::scenario::campaign::{Journal, JournalMode, JournalStart, run_campaign_journaled};
    let start = std::time::Instant::now();
    let path = args.campaign.clone().unwrap_or_else(default_campaign_path);
    if args.campaign.is_none() && !path.is_file() {
        return Err(bad_input(anyhow!(
            "the bundled campaign {} is not here; pass a campaign file",
            path.display()
        )));
    }
    let shard = match &args.shard {
        Some(s) => Shard::parse(s).map_err(|e| bad_input(anyhow!("--shard: {e}")))?,
        None => Shard::WHOLE,
    };
    // Options that change the campaign's definition go into its configuration (and fingerprint).
    let mut config = aift::scenario::campaign::CampaignConfig::load(&path).map_err(bad_input)?;
    if let Some(s) = args.seeds {
        let max = aift::scenario::campaign::MAX_SEEDS;
        if !(1..=max).contains(&s) {
            return Err(bad_input(anyhow!("--seeds {s}: must be in 1..={max}")));
        }
        config.seeds = s;
    }
    if !args.methods.is_empty() {
        config.methods = Some(parse_methods(&args.methods)?);
    }
    if let Some(name) = config.external_methods.first() {
        return Err(bad_input(anyhow!(
            "{}: `external_methods` names {name:?}, a method of the caller's that the command \
             line cannot run: run the campaign from Python (aift.campaign(methods=[...])) or \
             Rust (campaign::run_campaign_with)",
            path.display()
        )));
    }
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("campaigns").join(&config.name));
    let staged = stage(&dir, OutputKind::Folder, args.force)?;
    errln!("preparing {} (arms, camera models)...", path.display());
    // --set applies to every arm's template last; the fingerprint covers each resolved
    // scenario, so shards with other overrides do not merge.
    let campaign = Campaign::from_config(config, &path, &args.set)
        .map_err(|e| scenario_failure(e, &args.set))?;
    describe_campaign(&campaign, shard);
    // Every finished job goes into a journal beside the output folder; a killed run's journal
    // is resumed by running the same command again.
    let journal_path = Journal::path_for(&dir);
    let mode = if args.resume {
        JournalMode::Require
    } else if args.fresh {
        JournalMode::Fresh
    } else {
        JournalMode::Resume
    };
    let (journal, started) = Journal::open(&journal_path, &campaign, shard, mode).map_err(|e| {
        if args.resume {
            bad_input(anyhow!("--resume: {e}"))
        } else {
            file_failure(e)
        }
    })?;
    match &started {
        JournalStart::New => {}
        JournalStart::Resumed { jobs, seconds } => {
            let all = campaign.jobs().len() + campaign.reaching_tasks().len();
            let mine = (0..all).filter(|j| shard.contains(*j)).count();
            errln!(
                "resuming from {}: {jobs} of {mine} jobs already done ({seconds:.1} s of work kept)",
                journal_path.display()
            )
        }
        JournalStart::Replaced(reason) => errln!(
            "starting afresh: the journal at {} was {reason}",
            journal_path.display()
        ),
    }
    let bar = progress_bar();
    let progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let dir_cache = cache_dir();
    let records = run_campaign_journaled(
        &campaign,
        shard,
        dir_cache.as_deref(),
        &progress,
        Some(&journal),
    )
    .map_err(bad_input)?;
    bar.finish_and_clear();
    if shard == Shard::WHOLE {
        report::campaign_files::write_campaign(staged.path(), &campaign, &records)
            .map_err(report_failure)?;
    } else {
        report::campaign_files::write_shard(staged.path(), &records).map_err(report_failure)?;
    }
    staged
        .commit()
        .map_err(|e| report_failure(ReportError::File(e)))?;
    if let Err(e) = journal.remove() {
        errln!("warning: {e}");
    }
    if shard == Shard::WHOLE && !campaign.cells.is_empty() {
        print_method_table(args.json, &campaign, &records.runs);
    }
    let kept = match started {
        JournalStart::Resumed { jobs, .. } => format!(" ({jobs} jobs' runs kept from the journal)"),
        _ => String::new(),
    };
    say!(
        args.json,
        "{} runs{kept} in {:.1} s on {} threads; wrote {}/",
        records.runs.len() + records.reaching.len(),
        start.elapsed().as_secs_f64(),
        rayon::current_num_threads(),
        dir.display()
    );
    if args.json {
        print_campaign_json(&dir, shard, &records)?;
    }
    Ok(())
}

/// What a campaign (or shard) will run, on stderr.
fn describe_campaign(campaign: &Campaign, shard: Shard) {
    // What `aift run` warns about a scenario (a target or fault after the run's end, as a
    // shorter `[defaults] duration` leaves them), for each arm's template as laid over.
    for (arm, setup) in campaign.config.arms.iter().zip(&campaign.arms) {
        for w in &setup.warnings {
            errln!(
                "warning: arm {} ({}): {w}",
                arm.name,
                setup.loaded.path.display()
            );
        }
    }
    let jobs = campaign.jobs().len() + campaign.reaching_tasks().len();
    errln!(
        "{} cells x {} methods x {} seeds = {} runs{}{}",
        campaign.cells.len(),
        campaign.methods.len(),
        campaign.config.seeds,
        campaign.jobs().len(),
        if campaign.config.reaching.is_some() {
            format!(", plus {} reaching tasks", campaign.reaching_tasks().len())
        } else {
            String::new()
        },
        if shard == Shard::WHOLE {
            String::new()
        } else {
            format!("; shard {}/{} of {jobs} jobs", shard.index, shard.count)
        }
    );
}

/// The campaign's progress bar on stderr (hidden when stderr is not a terminal).
fn progress_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} jobs, {elapsed} (time left {eta})",
        )
        .expect("valid template"),
    );
    bar
}

/// The per-method totals of a whole campaign, as a Markdown table.
fn print_method_table(json: bool, campaign: &Campaign, runs: &[CampaignRun]) {
    let (_, methods) = aift::scenario::campaign::summarise(campaign, runs);
    say!(
        json,
        "| method | recovered | degraded | failed | diverged | worse than no-FT | recovers where the oracle does |"
    );
    say!(json, "|---|---|---|---|---|---|---|");
    for m in methods {
        say!(
            json,
            "| {} | {} | {} | {} | {} | {} | {}/{} |",
            m.method,
            m.recovered,
            m.degraded,
            m.failed,
            m.diverged,
            m.worse_than_no_ft,
            m.recovers_where_oracle_does,
            m.oracle_recovers
        );
    }
}

/// The JSON document of `campaign --json`: campaign.json, or for a shard what it holds.
fn print_campaign_json(dir: &Path, shard: Shard, records: &CampaignRecords) -> Result<(), Failure> {
    if shard == Shard::WHOLE {
        print_json_file(&dir.join(report::campaign_files::CAMPAIGN_JSON))?;
    } else {
        let doc = serde_json::json!({
            "format_version": aift::scenario::campaign::CAMPAIGN_FORMAT,
            "campaign": records.campaign,
            "fingerprint": records.fingerprint,
            "shard": format!("{}/{}", shard.index, shard.count),
            "runs": records.runs.len() + records.reaching.len(),
            "records": dir.join(report::campaign_files::RECORDS),
        });
        outln!("{doc}");
    }
    Ok(())
}

/// `aift replay LOG --scenario S`: a method over a recorded log, into a run folder.
fn replay(args: ReplayArgs) -> Result<(), Failure> {
    let loaded = load(&ScenarioArgs {
        scenario: args.scenario.clone(),
        set: args.set.clone(),
    })?;
    let method = match &args.method {
        Some(m) => parse_method(m)?,
        None => loaded.scenario.precision.method,
    };
    let seed = args.seed.unwrap_or(loaded.scenario.seed);
    // The files named and the output, before the GP's fit.
    if !args.log.exists() {
        // A file or a rosbag2 folder: what is in it is read after the GP.
        return Err(bad_input(anyhow!(
            "LOG {}: no such file or folder",
            args.log.display()
        )));
    }
    check_input_file("--calib", args.calib.as_ref())?;
    let dir = args.out.clone().unwrap_or_else(|| {
        let stem = args
            .log
            .file_stem()
            .map_or("log".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from("runs").join(format!("replay-{stem}-{method}"))
    });
    let staged = stage(&dir, OutputKind::Folder, args.force)?;
    let mut setup = prepare_loaded(loaded, &args.set)?;
    let joint_names: Vec<String> = setup.model.joints.iter().map(|j| j.name.clone()).collect();
    let log = aift::logs::RecordedLog::read(
        &args.log,
        &setup.layout,
        &joint_names,
        &aift::logs::Topics {
            joint_states: args.topic.clone(),
            camera: args.camera_topic.clone(),
        },
    )
    .and_then(|log| aift::logs::replay::prepare(&mut setup, &log, method, seed).map(|()| log))
    .map_err(|e| {
        if e.is_input_error() {
            bad_input(e)
        } else {
            internal(e)
        }
    })?;
    let dt = setup.scenario().dt;
    let calibration = calibration_for(&setup, &[method], args.calib.as_ref(), &args.set)?;
    let (result, info) =
        run_files::replay_staged(&staged, &setup, method, seed, calibration.as_deref(), &log)
            .map_err(report_failure)?;
    staged.commit().map_err(file_failure)?;
    say!(
        args.json,
        "replayed {} ({}): {} samples over {} ticks of {} s ({} ticks without a sample, {} values superseded) | method {method}",
        info.source,
        info.described,
        info.samples,
        info.ticks,
        dt,
        info.empty_ticks,
        info.superseded
    );
    print_run_result(args.json, &setup, &result);
    say!(args.json, "wrote {}/", dir.display());
    if args.json {
        print_json_file(&dir.join(run_files::SUMMARY))?;
    }
    Ok(())
}

/// `aift compare DIR A B`: the paired comparison of two methods in every cell of a campaign.
fn compare(args: CompareArgs) -> Result<(), Failure> {
    use aift::scenario::campaign::{Better, Campaign, compare_pair};
    if !(args.alpha > 0.0 && args.alpha <= 0.5) {
        return Err(bad_input(anyhow::anyhow!(
            "--alpha {}: must be in (0, 0.5]",
            args.alpha
        )));
    }
    let records = report::campaign_files::read_records(&args.dir).map_err(report_failure)?;
    let campaign = Campaign::plan(records.config.clone());
    let method = |name: &str| -> Result<&aift::scenario::method::MethodId, Failure> {
        let Some(m) = campaign.methods.iter().find(|m| m.name() == name) else {
            return Err(bad_input(anyhow::anyhow!(
                "method {name}: not in campaign {} ({}; its methods: {})",
                records.campaign,
                args.dir.join(report::campaign_files::RECORDS).display(),
                campaign
                    .methods
                    .iter()
                    .map(|m| m.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        };
        Ok(m)
    };
    let (a, b) = (method(&args.a)?, method(&args.b)?);
    if a == b {
        return Err(bad_input(anyhow::anyhow!("methods A and B are both {a}")));
    }
    let pairs = compare_pair(&campaign, &records.runs, a, b, args.alpha);
    let count = |w: Better| pairs.iter().filter(|p| p.better == w).count();
    let (a_wins, b_wins) = (count(Better::A), count(Better::B));
    let label = |c: usize| {
        let cell = &campaign.cells[c];
        (
            campaign.config.arms[cell.arm].name.clone(),
            cell.label.clone(),
        )
    };
    if args.json {
        let doc = serde_json::json!({
            "campaign": records.campaign,
            "a": a.name(),
            "b": b.name(),
            "alpha": args.alpha,
            "a_better": a_wins,
            "b_better": b_wins,
            "cells": pairs.len(),
            "pairs": pairs.iter().map(|p| {
                let (arm, cell) = label(p.cell);
                let mut j = p.json();
                j["arm"] = serde_json::json!(arm);
                j["cell"] = serde_json::json!(cell);
                j
            }).collect::<Vec<_>>(),
        });
        outln!("{doc}");
        return Ok(());
    }
    outln!(
        "{a} vs {b} in campaign {} (Wilcoxon signed-rank over the seeds, log10 of the post-fault \
         MSE ratio {a}/{b}; two-sided, alpha {})",
        records.campaign,
        args.alpha
    );
    outln!(
        "{:<14} {:<40} {:>5} {:>12} {:>10}  better",
        "arm",
        "cell",
        "seeds",
        "med log10",
        "p"
    );
    for p in &pairs {
        let (arm, cell) = label(p.cell);
        outln!(
            "{arm:<14} {cell:<40} {:>5} {:>12.3} {:>10.3e}  {}",
            p.seeds,
            p.median_log10_ratio,
            p.test.p_value,
            match p.better {
                Better::Neither => "-",
                _ => p.better_name(),
            }
        );
    }
    outln!(
        "{a} better than {b} in {a_wins} cells, {b} better in {b_wins}, no difference at {} in {} \
         (of {} cells)",
        args.alpha,
        pairs.len() - a_wins - b_wins,
        pairs.len()
    );
    let least = aift::scenario::campaign::compare::smallest_p_value(records.config.seeds);
    if least >= args.alpha {
        outln!(
            "note: with {} seeds the smallest possible p-value is {least:.3}: no cell can reach \
             alpha {}",
            records.config.seeds,
            args.alpha
        );
    }
    Ok(())
}

fn merge(args: MergeArgs) -> Result<(), Failure> {
    let staged = stage(&args.out, OutputKind::Folder, args.force)?;
    let merged =
        report::campaign_files::merge_into(staged.path(), &args.shards).map_err(report_failure)?;
    staged
        .commit()
        .map_err(|e| report_failure(ReportError::File(e)))?;
    outln!(
        "merged {} shards ({} runs) of campaign {}; wrote {}/",
        args.shards.len(),
        merged.runs.len() + merged.reaching.len(),
        merged.campaign,
        args.out.display()
    );
    Ok(())
}

fn gen_arm(args: GenArmArgs) -> Result<(), Failure> {
    let text = aift::arm::generate_arm(&aift::arm::GenerateOptions {
        seed: args.seed,
        joints: args.joints,
    })
    .map_err(bad_input)?;
    let Some(out) = args.out else {
        out!("{text}");
        return Ok(());
    };
    // Refuses a folder, a device or a path ending in `/` before the question of --force.
    let staged = stage(&out, OutputKind::File, true)?;
    if out.exists() && !args.force {
        return Err(bad_input(anyhow!(
            "{} exists; pass --force to replace it",
            out.display()
        )));
    }
    staged.commit_bytes(text.as_bytes()).map_err(file_failure)?;
    errln!(
        "wrote {} (seed {}); next: `aift init --urdf {} --out SCENARIO.toml`",
        out.display(),
        args.seed,
        shell_quoted(&out)
    );
    Ok(())
}

fn init(args: InitArgs) -> Result<(), Failure> {
    // The scenario must not replace the URDF it is written for (with --force it would).
    if let (Ok(a), Ok(b)) = (args.out.canonicalize(), args.urdf.canonicalize())
        && a == b
    {
        return Err(bad_input(anyhow!(
            "--out {} is the URDF given (--urdf {}): the scenario would replace it",
            args.out.display(),
            args.urdf.display()
        )));
    }
    // Refuses a folder, a device or a path ending in `/` before the question of --force.
    let staged = stage(&args.out, OutputKind::File, true)?;
    if args.out.exists() && !args.force {
        return Err(bad_input(anyhow!(
            "{} exists; pass --force to replace it",
            args.out.display()
        )));
    }
    // The scenario names its URDF relative to its own folder.
    let out_dir = args
        .out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let urdf_in_scenario = relative_path(&args.urdf, out_dir);
    let name = args
        .out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scenario".into())
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "_-.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    // The loader's warnings (mimic joints ignored, limits missing, ...), as check-urdf and run
    // print them; a URDF that does not load is reported by init itself.
    if let Ok(model) = arm::load_urdf_with(
        &args.urdf,
        &arm::UrdfOptions {
            balance_inertia: args.balance_inertia,
        },
    ) {
        for w in &model.warnings {
            errln!("warning: {}: {w}", args.urdf.display());
        }
    }
    let init = scenario::init::init_scenario_noted(
        &args.urdf,
        &scenario::init::InitOptions {
            ee_link: args.ee.clone(),
            balance_inertia: args.balance_inertia,
            urdf_in_scenario,
            name,
        },
    )
    .map_err(bad_input)?;
    for joint in &init.camera_blind {
        errln!(
            "note: the camera cannot see joint '{joint}' (the end effector on its axis, or moved \
             along the line of sight): only its own encoder, tachometer and the dynamics check \
             it, and an encoder drift there looks like a tachometer bias (docs/method.md, \
             \"Sensors nobody else can check\")"
        );
    }
    let text = init.text;
    if !args.no_check {
        errln!("checking the scenario with one healthy run (no-ft, articulated engine)...");
        scenario::init::check_scenario(&text, &args.out).map_err(bad_input)?;
    }
    staged.commit_bytes(text.as_bytes()).map_err(file_failure)?;
    outln!(
        "wrote {} for {}; run it with `aift run {}`",
        args.out.display(),
        args.urdf.display(),
        shell_quoted(&args.out)
    );
    Ok(())
}

/// `path` as one shell word, for a command the user can paste (a path with spaces or quotes is
/// quoted; a path a shell cannot take, with a NUL, is shown as it is).
fn shell_quoted(path: &Path) -> String {
    let text = path.to_string_lossy();
    shlex::try_quote(&text)
        .map(|q| q.into_owned())
        .unwrap_or_else(|_| text.into_owned())
}

/// `path` relative to `base` where both resolve; else `path` made absolute.
fn relative_path(path: &Path, base: &Path) -> String {
    let (Ok(p), Ok(b)) = (path.canonicalize(), base.canonicalize()) else {
        return path.to_string_lossy().into_owned();
    };
    let pc: Vec<_> = p.components().collect();
    let bc: Vec<_> = b.components().collect();
    let common = pc.iter().zip(&bc).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..bc.len() {
        out.push("..");
    }
    for c in &pc[common..] {
        out.push(c);
    }
    out.to_string_lossy().into_owned()
}

/// Loads the scenario (file or embedded default) with overrides and checks it against its arm
/// (everything but the GP's model), before a command stages its output.
fn load(args: &ScenarioArgs) -> Result<LoadedScenario, Failure> {
    let loaded = match &args.scenario {
        Some(path) => LoadedScenario::from_file(path, &args.set),
        None => LoadedScenario::embedded_default(&args.set),
    }
    .map_err(|e| scenario_failure(e, &args.set))?;
    RunSetup::check(&loaded).map_err(|e| scenario_failure(e, &args.set))?;
    Ok(loaded)
}

/// A scenario error, exit 2; when the offending key was given by `--set`, the message says so.
fn scenario_failure(error: aift::scenario::ScenarioError, overrides: &[String]) -> Failure {
    match error.blamed_override(overrides) {
        Some(o) => {
            let o = o.to_string();
            bad_input(anyhow::Error::new(error).context(format!("--set {o}")))
        }
        None => bad_input(error),
    }
}

/// The arm and the GP of a loaded scenario; the arm's warnings go to stderr. Commands load
/// first, check their own inputs and stage their output, then call this (the GP's fit is the
/// first work).
fn prepare_loaded(loaded: LoadedScenario, overrides: &[String]) -> Result<RunSetup, Failure> {
    let setup = RunSetup::prepare(loaded).map_err(|e| scenario_failure(e, overrides))?;
    for w in &setup.model.warnings {
        errln!("warning: {}: {w}", setup.model.source.display());
    }
    for w in &setup.warnings {
        errln!("warning: {}: {w}", setup.loaded.path.display());
    }
    Ok(setup)
}

/// An input file named by a flag must exist before any work starts.
fn check_input_file(flag: &str, path: Option<&PathBuf>) -> Result<(), Failure> {
    match path {
        Some(p) if !p.exists() => Err(bad_input(anyhow!("{flag} {}: no such file", p.display()))),
        Some(p) if !p.is_file() => Err(bad_input(anyhow!(
            "{flag} {}: not a regular file",
            p.display()
        ))),
        _ => Ok(()),
    }
}

fn parse_method(name: &str) -> Result<Method, Failure> {
    name.parse::<Method>()
        .map_err(|e| bad_input(anyhow!("--method: {e}")))
}

fn cache_dir() -> Option<PathBuf> {
    calibrate::default_cache_dir()
}

/// The detector calibration the methods need: --calib, the scenario's file, or on the fly.
fn calibration_for(
    setup: &RunSetup,
    methods: &[Method],
    calib: Option<&PathBuf>,
    overrides: &[String],
) -> Result<Option<Arc<Calibration>>, Failure> {
    for &m in methods {
        setup.check_method(m).map_err(bad_input)?;
    }
    if let Some(path) = calib
        && !methods.iter().any(|m| m.needs_detector())
    {
        let names: Vec<String> = methods.iter().map(|m| m.to_string()).collect();
        errln!(
            "warning: --calib {} is not used: {} {} no detector calibration",
            path.display(),
            names.join(", "),
            if names.len() == 1 { "needs" } else { "need" }
        );
    }
    let dir = cache_dir();
    let found =
        calibrate::calibration_for(setup, methods, calib.map(PathBuf::as_path), dir.as_deref())
            .map_err(|e| scenario_failure(e, overrides))?;
    let runs = setup.scenario().detector.calibration_runs;
    Ok(found.map(|(cal, origin)| {
        match origin {
            calibrate::CalibrationOrigin::File(_) => {}
            calibrate::CalibrationOrigin::Cached(dir) => errln!(
                "detector calibration ({runs} healthy runs) read from the cache in {}",
                dir.display()
            ),
            calibrate::CalibrationOrigin::Computed { seconds } => {
                errln!("calibrated the detector on {runs} healthy runs in {seconds:.1} s")
            }
        }
        Arc::new(cal)
    }))
}

fn describe_gp(setup: &RunSetup) -> String {
    match &setup.gp_source {
        scenario::GpSource::Trained {
            points, seconds, ..
        } => {
            format!("trained on {points} points in {seconds:.2} s")
        }
        scenario::GpSource::Loaded(path) => format!("loaded from {}", path.display()),
    }
}

/// The files a finished output folder holds, sorted, for the "wrote" line (read back, so the
/// line names what is there: the report, the GP model and the arm's URDF too), without the
/// hidden marker that says aift wrote the folder.
fn folder_listing(dir: &Path) -> String {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|name| name != aift::fsio::OUTPUT_MARKER)
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names.join(", ")
}

fn run(args: RunArgs) -> Result<(), Failure> {
    let loaded = load(&args.scenario)?;
    let method = match &args.method {
        Some(m) => parse_method(m)?,
        None => loaded.scenario.precision.method,
    };
    let seed = args.seed.unwrap_or(loaded.scenario.seed);
    let dir = args.out.clone().unwrap_or_else(|| {
        PathBuf::from("runs").join(format!("{}-{}-{}", loaded.scenario.name, method, seed))
    });
    // Every input is checked and the output staged before any work (the GP's fit included);
    // the folder appears only when every file is written.
    check_input_file("--calib", args.calib.as_ref())?;
    let staged = stage(&dir, OutputKind::Folder, args.force)?;
    let mut setup = prepare_loaded(loaded, &args.scenario.set)?;
    setup.loaded.scenario.precision.method = method;
    setup.loaded.scenario.seed = seed;
    let calibration = calibration_for(&setup, &[method], args.calib.as_ref(), &args.scenario.set)?;
    let run = scenario::Run::new(&setup, method)
        .seed(seed)
        .calibration(calibration.as_deref());
    let options = run_files::RunFileOptions { mcap: args.mcap };
    let result = run_files::run_staged_with(&staged, run, &options).map_err(report_failure)?;
    staged.commit().map_err(file_failure)?;
    say!(
        args.json,
        "scenario {} | method {} | seed {} | GP {}",
        setup.scenario().name,
        method,
        seed,
        describe_gp(&setup)
    );
    print_run_result(args.json, &setup, &result);
    say!(
        args.json,
        "wrote {}/: {}",
        dir.display(),
        folder_listing(&dir)
    );
    if args.json {
        print_json_file(&dir.join(run_files::SUMMARY))?;
    }
    Ok(())
}

/// A run's outcome, errors, detections, faults and speed, for people.
fn print_run_result(json: bool, setup: &RunSetup, result: &aift::scenario::RunResult) {
    let fmt_opt = |v: Option<f64>| v.map_or("n/a".to_string(), |x| format!("{x:.3e}"));
    say!(json, "outcome: {}", result.outcome.name());
    if let Some((tick, reason)) = result.outcome.early_end() {
        say!(
            json,
            "  {} at t = {:.3} s: {reason}",
            result.outcome.name(),
            tick as f64 * setup.scenario().dt
        );
    }
    if let aift::scenario::Outcome::Chattering(c) = &result.outcome {
        say!(json, "  {}", c.describe());
    }
    say!(
        json,
        "belief MSE per joint: {}",
        result
            .mse_per_joint
            .iter()
            .map(|v| format!("{v:.3e}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    say!(
        json,
        "faulty-joint MSE: {} | healthy-joint MSE: {}",
        fmt_opt(result.mse_faulty),
        fmt_opt(result.mse_healthy)
    );
    say!(
        json,
        "final error per joint (rad): {}",
        result
            .final_error_per_joint
            .iter()
            .map(|v| format!("{v:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    match result.detected_at {
        Some(t) => say!(
            json,
            "detected at {t:.3} s ({}), isolated {}",
            result.detection_kind,
            result.isolated_channel.clone().unwrap_or_default()
        ),
        None => say!(json, "no detection"),
    }
    for (i, f) in result.faults.iter().enumerate() {
        say!(
            json,
            "fault {} ({} {} from {} s): {}",
            i + 1,
            f.label,
            f.kind,
            f.start,
            match (f.delay, &f.isolated) {
                (Some(d), Some(c)) => format!(
                    "detected after {d:.3} s, isolated {c} ({})",
                    if f.isolation_correct == Some(true) {
                        "correct"
                    } else {
                        "wrong"
                    }
                ),
                _ => "not detected".to_string(),
            }
        );
    }
    say!(
        json,
        "speed: {:.0} ticks/s ({:.1}x real time)",
        result.ticks_per_second(),
        result.ticks_per_second() * setup.scenario().dt
    );
}

/// Parses a method list; repeats are refused (each row would claim the seeds twice).
fn parse_methods(list: &[String]) -> Result<Vec<Method>, Failure> {
    if list.is_empty() {
        return Ok(Method::ALL.to_vec());
    }
    let mut methods = Vec::new();
    for m in list {
        let method = parse_method(m.trim())?;
        if methods.contains(&method) {
            return Err(bad_input(anyhow!("--methods: {method} is listed twice")));
        }
        methods.push(method);
    }
    Ok(methods)
}

fn table(args: TableArgs) -> Result<(), Failure> {
    let start = std::time::Instant::now();
    // Every input of the command is checked and the output staged before the GP's fit.
    let loaded = load(&args.scenario)?;
    let methods = parse_methods(&args.methods)?;
    if args.seeds == 0 || args.seeds > MAX_SEEDS {
        return Err(bad_input(anyhow!("--seeds must be in 1..={MAX_SEEDS}")));
    }
    let first = loaded.scenario.seed;
    let seeds: Vec<u64> = (0..args.seeds as u64)
        .map(|i| first.checked_add(i))
        .collect::<Option<_>>()
        .ok_or_else(|| bad_input(anyhow!("seed {first} + {} overflows", args.seeds)))?;
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("tables").join(&loaded.scenario.name));
    check_input_file("--calib", args.calib.as_ref())?;
    let staged = stage(&dir, OutputKind::Folder, args.force)?;
    let setup = prepare_loaded(loaded, &args.scenario.set)?;
    let calibration = calibration_for(&setup, &methods, args.calib.as_ref(), &args.scenario.set)?;
    let bar = indicatif::ProgressBar::new((methods.len() * seeds.len()) as u64);
    if !std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} runs, {elapsed} (eta {eta})")
            .expect("valid template"),
    );
    let tick = || bar.inc(1);
    let result = table::run_table(&setup, &methods, &seeds, calibration.as_deref(), &tick)
        .map_err(bad_input)?;
    bar.finish_and_clear();
    table_files::write_table(staged.path(), &setup, &result).map_err(report_failure)?;
    staged
        .commit()
        .map_err(|e| report_failure(ReportError::File(e)))?;
    say!(
        args.json,
        "{}",
        table_files::table_markdown(&setup, &result)
    );
    say!(
        args.json,
        "\n{} runs ({} methods x {} seeds) in {:.1} s (GP, calibration and runs) on {} threads; GP {}; wrote {}/table.csv, table.md, table.json, runs.csv",
        methods.len() * seeds.len(),
        methods.len(),
        seeds.len(),
        start.elapsed().as_secs_f64(),
        rayon::current_num_threads(),
        describe_gp(&setup),
        dir.display()
    );
    if args.json {
        print_json_file(&dir.join(table_files::TABLE_JSON))?;
    }
    Ok(())
}

fn calibrate_cmd(args: CalibrateArgs) -> Result<(), Failure> {
    let loaded = load(&args.scenario)?;
    let staged = stage(&args.out, OutputKind::File, true)?;
    let setup = prepare_loaded(loaded, &args.scenario.set)?;
    let runs = args
        .runs
        .unwrap_or(setup.scenario().detector.calibration_runs);
    calibrate::check_size(&setup, runs).map_err(bad_input)?;
    let start = std::time::Instant::now();
    let cal = calibrate::calibrate(&setup, runs).map_err(bad_input)?;
    staged
        .commit_bytes(cal.to_json().as_bytes())
        .map_err(file_failure)?;
    outln!(
        "calibrated {} on {runs} healthy runs ({} ticks) in {:.1} s; fingerprint {}; wrote {}",
        setup.scenario().name,
        cal.ticks,
        start.elapsed().as_secs_f64(),
        cal.fingerprint,
        args.out.display()
    );
    // The false-alarm rate on fresh healthy seeds (disjoint from the calibration's).
    let healthy = setup.healthy();
    let fresh: Vec<u64> = (0..20).map(|i| 1_000_000 + i).collect();
    let check = table::run_table(
        &healthy,
        &[Method::Deterministic],
        &fresh,
        Some(&cal),
        &|| {},
    )
    .map_err(bad_input)?;
    let alarms = check.runs.iter().filter(|r| r.false_alarm).count();
    outln!(
        "false alarms on {} fresh healthy seeds: {alarms} ({:.0} %)",
        fresh.len(),
        100.0 * alarms as f64 / fresh.len() as f64
    );
    Ok(())
}

fn train_gp(args: TrainGpArgs) -> Result<(), Failure> {
    // Trains from scratch even if the scenario names a saved model.
    let loaded = load(&args.scenario)?;
    let staged = stage(&args.out, OutputKind::File, true)?;
    let points = args.points.unwrap_or(loaded.scenario.gp.points);
    let start = std::time::Instant::now();
    let (gp, fit, held) = scenario::train_gp_fresh(&loaded, args.points).map_err(bad_input)?;
    let seconds = start.elapsed().as_secs_f64();
    staged
        .commit_bytes(gp.to_json().as_bytes())
        .map_err(file_failure)?;
    let h = &gp.hyperparameters;
    outln!(
        "trained the camera GP of {} on {points} points in {seconds:.2} s ({} likelihood evaluations)",
        loaded.scenario.name,
        fit.evaluations
    );
    outln!(
        "length scales (rad): {}",
        h.length_scales
            .iter()
            .map(|l| format!("{l:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    outln!(
        "signal std sf: {:.4} m, noise std sn: {:.5} m",
        h.signal_std,
        h.noise_std
    );
    outln!(
        "log marginal likelihood: {:.3}",
        fit.log_marginal_likelihood
    );
    outln!(
        "held-out error on {} configurations in the training box: RMS {:.2} mm, max {:.2} mm",
        held.points,
        held.rms * 1e3,
        held.max * 1e3
    );
    outln!("wrote {}", args.out.display());
    Ok(())
}

fn bench(args: BenchArgs) -> Result<(), Failure> {
    if args.ticks == 0 || args.ticks > MAX_BENCH_TICKS {
        return Err(bad_input(anyhow!(
            "--ticks must be in 1..={MAX_BENCH_TICKS}"
        )));
    }
    let loaded = load(&args.scenario)?;
    let method = match &args.method {
        Some(m) => parse_method(m)?,
        None => loaded.scenario.precision.method,
    };
    check_input_file("--calib", args.calib.as_ref())?;
    let setup = prepare_loaded(loaded, &args.scenario.set)?;
    let calibration = calibration_for(&setup, &[method], args.calib.as_ref(), &args.scenario.set)?;
    let figures = scenario::bench::bench(&setup, method, calibration.as_deref(), args.ticks)
        .map_err(bad_input)?;
    outln!("scenario: {}", setup.scenario().name);
    outln!("method: {method}");
    outln!("joints: {}", setup.model.joints.len());
    outln!("gp_points: {}", setup.gp.n_points());
    for f in figures {
        // Three decimals for timings; small figures (an MSE) in scientific notation.
        if f.value != 0.0 && f.value.abs() < 0.1 {
            outln!("{}: {:.4e}", f.name, f.value);
        } else {
            outln!("{}: {:.3}", f.name, f.value);
        }
    }
    Ok(())
}

/// A number for people: ten significant digits (no 32.699999999999996), and in exponent form
/// beyond 1e9 or below 1e-4 (no 309-digit limits).
fn human(v: f64) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    let r: f64 = format!("{v:.9e}").parse().unwrap_or(v);
    if r != 0.0 && (r.abs() >= 1e9 || r.abs() < 1e-4) {
        format!("{r:e}")
    } else {
        format!("{r}")
    }
}

fn check_urdf(args: CheckUrdfArgs) -> Result<(), Failure> {
    let model = arm::load_urdf_with(
        &args.path,
        &arm::UrdfOptions {
            balance_inertia: args.balance_inertia,
        },
    )
    .map_err(bad_input)?;
    if let Some(ee) = args.ee.as_deref().filter(|ee| model.link(ee).is_none()) {
        return Err(bad_input(model.unknown_link_error(ee)));
    }
    say!(
        args.json,
        "arm '{}' from {}",
        model.name,
        args.path.display()
    );
    say!(args.json, "movable joints: {}", model.joints.len());
    for (i, j) in model.joints.iter().enumerate() {
        let axis = j.axis.into_inner();
        let limits = match j.limits {
            Some((lo, hi)) => format!("[{}, {}]", human(lo), human(hi)),
            None => "none".into(),
        };
        let effort = j.effort.map_or("none".into(), human);
        say!(
            args.json,
            "  {}. {} ({}) parent '{}' child '{}' axis ({}, {}, {}) limits {} effort {} damping {} friction {}",
            i + 1,
            j.name,
            j.kind.name(),
            model.bodies[j.parent_body].link,
            model.bodies[j.child_body].link,
            human(axis.x),
            human(axis.y),
            human(axis.z),
            limits,
            effort,
            human(j.damping),
            human(j.friction)
        );
    }
    say!(args.json, "links:");
    for l in &model.links {
        let body = &model.bodies[l.body].link;
        if l.has_inertial {
            say!(
                args.json,
                "  {} mass {} kg (body '{}')",
                l.name,
                human(l.mass),
                body
            );
        } else {
            say!(args.json, "  {} massless frame (body '{}')", l.name, body);
        }
    }
    say!(args.json, "total mass: {} kg", human(model.total_mass()));
    match &args.ee {
        Some(ee) => say!(args.json, "end effector: {ee}"),
        None => match model.link("ee") {
            Some(_) => say!(args.json, "end effector: ee (default)"),
            None => say!(
                args.json,
                "end effector: none named 'ee'; `init` would put it on '{}' (pass --ee LINK to choose)",
                aift::scenario::init::default_ee(&model)
            ),
        },
    }
    for w in &model.warnings {
        say!(args.json, "warning: {w}");
    }
    if args.json {
        let doc = arm::describe_arm(&model, &args.path, args.ee.as_deref());
        outln!("{doc}");
    }
    Ok(())
}

fn check_positive(name: &str, value: f64) -> Result<(), Failure> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(bad_input(anyhow!(
            "--{name} = {value} must be finite and > 0"
        )))
    }
}

fn simulate(args: SimulateArgs) -> Result<(), Failure> {
    check_duration_and_dt(&args)?;
    let settings = simulate_settings(&args)?;
    let staged = stage(&args.out, OutputKind::File, true)?;
    let model = arm::load_urdf_with(
        &args.urdf,
        &arm::UrdfOptions {
            balance_inertia: args.balance_inertia,
        },
    )
    .map_err(bad_input)?;
    let ee = arm::EndEffector::new(&model, &args.ee, [0.0; 3]).map_err(bad_input)?;
    let joint_names: Vec<String> = model.joints.iter().map(|j| j.name.clone()).collect();
    let mut arm = plant::build(std::sync::Arc::new(model), [0.0, 0.0, -9.81], &settings)
        .map_err(bad_input)?;
    let n = arm.n_joints();
    let check_len = |name: &str, v: &[f64]| {
        if v.len() == n {
            Ok(())
        } else {
            Err(bad_input(anyhow!(
                "--{name} has {} values; {} has {n} movable joints ({})",
                v.len(),
                args.urdf.display(),
                joint_names.join(", ")
            )))
        }
    };
    let qd0 = args.qd0.map_or(vec![0.0; n], |l| l.0);
    let torque = args.torque.map_or(vec![0.0; n], |l| l.0);
    check_len("q0", &args.q0.0)?;
    check_len("qd0", &qd0)?;
    check_len("torque", &torque)?;
    // The file's size, bounded as a scenario's trajectory is (24 bytes per value estimated),
    // before any step; the rows are then written as they come, so memory does not grow with
    // the run.
    let header = plant::open_loop_header(n);
    let rows = (args.duration / args.dt).round() as u64 + 1;
    let limit = aift::scenario::MAX_TRAJECTORY_BYTES;
    if rows.saturating_mul(header.len() as u64).saturating_mul(24) > limit {
        return Err(bad_input(anyhow!(
            "--duration / --dt = {rows} rows of {} columns would exceed {} GiB; use a longer --dt \
             or a shorter --duration",
            header.len(),
            limit >> 30
        )));
    }
    let writing = |e: std::io::Error| {
        internal(anyhow::Error::new(e).context(format!("writing {}", args.out.display())))
    };
    // Written in blocks of about 64 KiB (the row text is buffered in `line`).
    let mut file = std::fs::File::create(staged.path()).map_err(writing)?;
    let mut line = header.join(",");
    line.push('\n');
    let mut row = Vec::with_capacity(header.len());
    plant::run_open_loop_with(
        arm.as_mut(),
        &ee,
        &args.q0.0,
        &qd0,
        &torque,
        args.duration,
        args.dt,
        |s| {
            open_loop_row(s, &mut row)?;
            aift::scenario::trajectory::format_csv_row(&row, &mut line);
            if line.len() >= 1 << 16 {
                file.write_all(line.as_bytes()).map_err(writing)?;
                line.clear();
            }
            Ok(())
        },
    )?;
    file.write_all(line.as_bytes()).map_err(writing)?;
    drop(file);
    // The commit syncs the staged file before it moves it into place.
    staged.commit().map_err(file_failure)?;
    outln!(
        "wrote {} rows ({} joints, {} s at dt {}) to {}",
        rows,
        n,
        args.duration,
        args.dt,
        args.out.display()
    );
    Ok(())
}

/// `simulate`'s duration and time step: positive, at most 0.1 s per step, a bounded number of
/// steps.
fn check_duration_and_dt(args: &SimulateArgs) -> Result<(), Failure> {
    check_positive("duration", args.duration)?;
    check_positive("dt", args.dt)?;
    if args.duration / args.dt > aift::scenario::MAX_TICKS as f64 {
        return Err(bad_input(anyhow!(
            "--duration / --dt = {} steps; more than {} is refused",
            args.duration / args.dt,
            aift::scenario::MAX_TICKS
        )));
    }
    if args.dt > 0.1 {
        return Err(bad_input(anyhow!("--dt = {} must be <= 0.1 s", args.dt)));
    }
    if args.dt > args.duration {
        return Err(bad_input(anyhow!(
            "--dt = {} is longer than --duration = {}",
            args.dt,
            args.duration
        )));
    }
    Ok(())
}

/// The plant settings `--engine` and `--iterations` ask for.
fn simulate_settings(args: &SimulateArgs) -> Result<PlantSettings, Failure> {
    let mut settings = PlantSettings::default();
    if let crate::args::EngineArg::Articulated = args.engine {
        settings.engine = Engine::Articulated;
    }
    if let Some(it) = args.iterations {
        let max = plant::MAX_SOLVER_ITERATIONS.min(plant::MAX_SUBSTEPS);
        if !(1..=max).contains(&it) {
            return Err(bad_input(anyhow!("--iterations must be in 1..={max}")));
        }
        settings.rapier.solver_iterations = it;
        settings.articulated.substeps = it;
        if settings.engine == Engine::Rapier {
            settings.articulated = Default::default();
        } else {
            settings.rapier = Default::default();
        }
    }
    Ok(settings)
}

/// The rows of `simulate`'s CSV (t, q, qd, end effector); an error if the state blew up.
/// One sample as a CSV row into `row`; a state beyond 1e6 (or not finite) stops the run.
fn open_loop_row(s: &plant::OpenLoopSample, row: &mut Vec<f64>) -> Result<(), Failure> {
    if s.q
        .iter()
        .chain(&s.qd)
        .any(|v| !v.is_finite() || v.abs() > 1e6)
    {
        return Err(bad_input(anyhow!(
            "the simulation blew up at t = {} s (a joint state beyond 1e6); nothing written. \
             Try a smaller --dt or more --iterations",
            s.t
        )));
    }
    row.clear();
    row.push(s.t);
    row.extend(&s.q);
    row.extend(&s.qd);
    row.extend(s.ee);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::human;

    #[test]
    fn numbers_for_people_have_ten_digits_and_no_long_tails() {
        assert_eq!(human(32.699999999999996), "32.7");
        assert_eq!(human(0.6320060009999999), "0.632006001");
        assert_eq!(human(1e308), "1e308");
        assert_eq!(human(1e-9), "1e-9");
        assert_eq!(human(0.0), "0");
        assert_eq!(human(-2.5), "-2.5");
        assert_eq!(human(f64::INFINITY), "inf");
    }
}
