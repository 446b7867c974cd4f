//! `aift._aift`: the aift library from Python (PyO3, abi3). A thin layer: every call goes to the
//! library function the CLI calls, so the numbers are the CLI's bit for bit; the Python package
//! (`python/aift/`) turns the plain values returned here into numpy arrays, dicts and pandas.
//!
//! Long calls (runs, tables, campaigns, calibration) release the GIL. Errors arrive as
//! `aift.BadInput` (what the CLI exits 2 for) or `aift.InternalError` (exit 1), with the message
//! the CLI prints after `error: `.

mod custom;

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use pyo3::exceptions::{PyException, PyKeyboardInterrupt};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyBytes, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use aift::fsio::{FsError, OutputKind, Staged};
use aift::precision::Calibration;
use aift::report::{ReportError, campaign_files, run_files, table_files};
use aift::scenario::calibrate;
use aift::scenario::campaign::{self, Campaign, CampaignConfig, Shard};
use aift::scenario::metrics::DivergenceGuard;
use aift::scenario::{
    LoadedScenario, Method, Observer, ObserverMode, Run, RunResult, RunSetup, ScenarioError,
    Simulation, StopReason, TickRecord, TrajectoryColumns, method::MethodParts, table,
};
use aift::sensors::Readings;

pyo3::create_exception!(
    _aift,
    AiftError,
    PyException,
    "Base of aift's errors; the message is the one the CLI prints."
);
pyo3::create_exception!(
    _aift,
    BadInput,
    AiftError,
    "The input is at fault (a file, a key, a value): what the CLI exits 2 for."
);
pyo3::create_exception!(
    _aift,
    InternalError,
    AiftError,
    "aift or the machine is at fault (an output could not be written): the CLI's exit 1."
);

fn bad(message: impl Into<String>) -> PyErr {
    BadInput::new_err(message.into())
}

fn scenario_err(error: ScenarioError, overrides: &[String]) -> PyErr {
    bad(error.message(overrides))
}

/// BadInput when the input is at fault, InternalError when the disk or aift is (as the CLI's
/// exit codes 2 and 1).
fn classified(error: &dyn std::error::Error, input: bool) -> PyErr {
    let message = aift::error_chain(error);
    if input {
        bad(message)
    } else {
        InternalError::new_err(message)
    }
}

fn file_err(error: FsError) -> PyErr {
    classified(&error, error.is_input_error())
}

fn report_err(error: ReportError) -> PyErr {
    classified(&error, error.is_input_error())
}

fn parse_method(name: &str, what: &str) -> PyResult<Method> {
    name.parse::<Method>()
        .map_err(|e| bad(format!("{what}: {e}")))
}

/// Where a scenario's text comes from, so that overrides can be re-applied to it.
#[derive(Clone, Debug)]
enum Source {
    Default,
    File(PathBuf),
    Text {
        text: String,
        label: PathBuf,
        base: PathBuf,
    },
}

/// A scenario: a file, the embedded default or TOML text, with the CLI's `--set` overrides.
/// Every change is checked at once (the key, the value's type); the arm, the camera and the
/// faults are checked against each other when a run prepares it.
#[pyclass(module = "aift._aift", name = "Scenario")]
#[derive(Clone)]
struct PyScenario {
    source: Source,
    overrides: Vec<String>,
    loaded: LoadedScenario,
    /// The prepared setup (arm, GP), made by the first run and reused by the next ones until
    /// the scenario changes: the CLI's table prepares once for all its seeds too. A GP trained
    /// from the scenario's own seed is the same however often it is trained.
    prepared: std::sync::Arc<std::sync::Mutex<Option<RunSetup>>>,
}

impl PyScenario {
    fn build(source: Source, overrides: Vec<String>) -> PyResult<Self> {
        let loaded = match &source {
            Source::Default => LoadedScenario::embedded_default(&overrides),
            Source::File(path) => LoadedScenario::from_file(path, &overrides),
            Source::Text { text, label, base } => {
                LoadedScenario::from_text(text, label, base, &overrides)
            }
        }
        .map_err(|e| scenario_err(e, &overrides))?;
        Ok(Self {
            source,
            overrides,
            loaded,
            prepared: Default::default(),
        })
    }

    /// The scenario prepared for runs (arm, layout, GP), with the GIL released.
    fn prepare(&self, py: Python<'_>) -> PyResult<RunSetup> {
        if let Some(setup) = self.prepared.lock().expect("not poisoned").as_ref() {
            return Ok(setup.clone());
        }
        let loaded = self.loaded.clone();
        let setup = py
            .detach(|| RunSetup::prepare(loaded))
            .map_err(|e| scenario_err(e, &self.overrides))?;
        *self.prepared.lock().expect("not poisoned") = Some(setup.clone());
        Ok(setup)
    }
}

/// A Python value as the text of a `--set KEY=VALUE` value, in TOML: booleans, integers and
/// floats as such, strings quoted (a Python str is text), lists and tuples as arrays.
fn value_text(value: &Bound<'_, PyAny>) -> PyResult<String> {
    if value.is_instance_of::<PyBool>() {
        return Ok(if value.extract::<bool>()? {
            "true".into()
        } else {
            "false".into()
        });
    }
    if value.is_instance_of::<PyInt>() {
        return Ok(value.str()?.to_string());
    }
    if value.is_instance_of::<PyFloat>() {
        let v: f64 = value.extract()?;
        return Ok(if v.is_nan() {
            "nan".into()
        } else if v.is_infinite() {
            if v > 0.0 { "inf".into() } else { "-inf".into() }
        } else {
            ryu::Buffer::new().format(v).to_string()
        });
    }
    if value.is_instance_of::<PyString>() {
        // Always a TOML string: a Python str is text, even when it reads as a number.
        let s: String = value.extract()?;
        return Ok(toml::Value::String(s).to_string());
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items = value
            .try_iter()?
            .map(|item| value_text(&item?))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(format!("[{}]", items.join(", ")));
    }
    if let Ok(v) = value.extract::<i64>() {
        // numpy integers and other objects with __index__.
        return Ok(v.to_string());
    }
    if let Ok(v) = value.extract::<f64>() {
        // numpy scalars and other numbers.
        return value_text(&PyFloat::new(value.py(), v).into_any());
    }
    Err(bad(format!(
        "a scenario value must be a bool, number, string or list, not {}",
        value.get_type().name()?
    )))
}

#[pymethods]
impl PyScenario {
    /// Reads a scenario file, with optional overrides (`["KEY=VALUE", ...]`).
    #[staticmethod]
    #[pyo3(signature = (path, overrides = Vec::new()))]
    fn load(path: PathBuf, overrides: Vec<String>) -> PyResult<Self> {
        Self::build(Source::File(path), overrides)
    }

    /// The embedded default scenario (the paper's arm, joint 1's encoder freezing at 8 s).
    #[staticmethod]
    #[pyo3(signature = (overrides = Vec::new()))]
    fn default(overrides: Vec<String>) -> PyResult<Self> {
        Self::build(Source::Default, overrides)
    }

    /// A scenario from TOML text; relative paths (the URDF) resolve against `base_dir`
    /// (default: the current folder).
    #[staticmethod]
    #[pyo3(signature = (text, base_dir = None, overrides = Vec::new()))]
    fn from_toml(
        text: String,
        base_dir: Option<PathBuf>,
        overrides: Vec<String>,
    ) -> PyResult<Self> {
        let base = base_dir.unwrap_or_else(|| PathBuf::from("."));
        let label = base.join("<string>");
        Self::build(Source::Text { text, label, base }, overrides)
    }

    /// Sets a key, as `--set KEY=VALUE` does (dotted keys, `[i]` indices); returns the
    /// scenario, so calls chain. The scenario is unchanged when the key or value is refused.
    fn set<'py>(
        slf: Bound<'py, Self>,
        key: &str,
        value: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, Self>> {
        let text = value_text(value)?;
        let next = {
            let this = slf.borrow();
            let mut overrides = this.overrides.clone();
            overrides.push(format!("{key}={text}"));
            Self::build(this.source.clone(), overrides)?
        };
        // A run in another thread holds the scenario: refuse rather than panic.
        *slf.try_borrow_mut().map_err(|_| {
            AiftError::new_err(
                "Scenario.set: a run in another thread is using this scenario; set() a copy() \
                 instead",
            )
        })? = next;
        Ok(slf)
    }

    /// The scenario as TOML (every default filled in): `Scenario.from_toml` reads it back.
    fn to_toml(&self) -> String {
        toml::to_string_pretty(&self.loaded.scenario).expect("a scenario always serialises")
    }

    /// A copy that later `set` calls do not share.
    fn copy(&self) -> Self {
        self.clone()
    }

    #[getter]
    fn name(&self) -> String {
        self.loaded.scenario.name.clone()
    }

    /// The file it came from (`<embedded>/...` for the default).
    #[getter]
    fn path(&self) -> String {
        self.loaded.path.display().to_string()
    }

    /// The overrides applied so far, as `KEY=VALUE`.
    #[getter]
    fn overrides(&self) -> Vec<String> {
        self.overrides.clone()
    }

    /// Seconds simulated, the tick (s) and the seed the scenario names.
    #[getter]
    fn duration(&self) -> f64 {
        self.loaded.scenario.duration
    }

    #[getter]
    fn dt(&self) -> f64 {
        self.loaded.scenario.dt
    }

    #[getter]
    fn seed(&self) -> u64 {
        self.loaded.scenario.seed
    }

    /// The method the scenario names.
    #[getter]
    fn method(&self) -> String {
        self.loaded.scenario.precision.method.name().to_string()
    }

    /// Checks the scenario against its arm (loads the URDF, trains or loads the GP): the checks
    /// a run makes before any work.
    fn validate(&self, py: Python<'_>) -> PyResult<()> {
        self.prepare(py).map(|_| ())
    }

    fn __repr__(&self) -> String {
        format!(
            "Scenario(name={:?}, path={:?}, overrides={:?})",
            self.loaded.scenario.name,
            self.loaded.path.display().to_string(),
            self.overrides
        )
    }
}

/// The calibration the methods need (file, scenario's, cache or computed), GIL released.
fn calibration(
    py: Python<'_>,
    setup: &RunSetup,
    methods: &[Method],
    calib: Option<&Path>,
) -> PyResult<Option<Calibration>> {
    let cache = calibrate::default_cache_dir();
    let found = interruptible(py, || {
        calibrate::calibration_for(setup, methods, calib, cache.as_deref())
    })?
    .map_err(|e| bad(aift::error_chain(&e)))?;
    Ok(found.map(|(cal, _)| cal))
}

/// Runs `work` on a helper thread with the GIL released while this (the calling) thread checks
/// for Python signals every 50 ms; on Ctrl-C every run of the process is asked to stop
/// (`runner::stop_all_runs`), the work finishes within milliseconds, its result is dropped and
/// KeyboardInterrupt is raised. A table, campaign or calibration stops within about 0.1 s.
fn interruptible<T: Send>(py: Python<'_>, work: impl FnOnce() -> T + Send) -> PyResult<T> {
    std::thread::scope(|scope| {
        let handle = scope.spawn(work);
        let mut signal = None;
        while !handle.is_finished() {
            if signal.is_none()
                && let Err(e) = py.check_signals()
            {
                aift::scenario::runner::stop_all_runs(true);
                signal = Some(e);
            }
            py.detach(|| std::thread::sleep(std::time::Duration::from_millis(50)));
        }
        let result = handle.join();
        if signal.is_some() {
            aift::scenario::runner::stop_all_runs(false);
        }
        match (signal, result) {
            (Some(e), _) => Err(e),
            (None, Ok(value)) => Ok(value),
            (None, Err(panic)) => std::panic::resume_unwind(panic),
        }
    })
}

/// Ticks between checks for a pending Python signal.
const INTERRUPT_TICKS: u64 = 4096;

/// Stops a run when Python has a signal pending (Ctrl-C), checked every [`INTERRUPT_TICKS`]
/// ticks (it is registered with `ObserverMode::Every`).
struct Interrupt {
    interrupted: Cell<bool>,
}

impl Observer for Interrupt {
    fn iter(&mut self, r: &TickRecord<'_>) {
        if r.tick > 0 && Python::attach(|py| py.check_signals()).is_err() {
            self.interrupted.set(true);
        }
    }
    fn stop(&self) -> Option<StopReason> {
        self.interrupted.get().then_some(StopReason::Interrupted)
    }
}

/// The summary (as summary.json's text), the trajectory's column names and its values as
/// little-endian f64 bytes, column after column.
type RunOutput<'py> = (String, Vec<String>, Bound<'py, PyBytes>);

fn columns_bytes<'py>(
    py: Python<'py>,
    columns: Option<&TrajectoryColumns>,
) -> PyResult<Bound<'py, PyBytes>> {
    let Some(columns) = columns else {
        return Ok(PyBytes::new(py, &[]));
    };
    let len = columns.rows() * columns.names().len() * 8;
    PyBytes::new_with(py, len, |buffer| {
        for (chunk, v) in buffer
            .chunks_exact_mut(8)
            .zip(columns.columns().iter().flatten())
        {
            chunk.copy_from_slice(&v.to_le_bytes());
        }
        Ok(())
    })
}

/// What `run` and `run_method` keep around a run: the trajectory in memory (unless
/// `trajectory = false`), the staged run folder (with `out`), the Ctrl-C check.
struct RunOutputs {
    columns: Option<TrajectoryColumns>,
    staged: Option<Staged>,
    interrupt: Interrupt,
    every: u64,
    mcap: bool,
}

impl RunOutputs {
    /// Checks the outputs before any work: the trajectory's size, the output folder.
    fn begin(
        setup: &RunSetup,
        out: Option<&Path>,
        force: bool,
        trajectory: bool,
        mcap: bool,
    ) -> PyResult<Self> {
        if mcap && out.is_none() {
            return Err(bad(
                "mcap=True writes run.mcap into the run folder: pass out=",
            ));
        }
        let sc = setup.scenario();
        let columns = if trajectory {
            Some(
                TrajectoryColumns::new(&setup.layout, sc.ticks(), sc.record_every).map_err(
                    |m| {
                        bad(format!(
                            "{}: `record_every`: {m} (or pass trajectory=False)",
                            setup.loaded.path.display()
                        ))
                    },
                )?,
            )
        } else {
            None
        };
        let staged = match out {
            Some(dir) => Some(Staged::begin(dir, OutputKind::Folder, force).map_err(file_err)?),
            None => None,
        };
        Ok(Self {
            columns,
            staged,
            interrupt: Interrupt {
                interrupted: Cell::new(false),
            },
            every: sc.record_every,
            mcap,
        })
    }

    /// Executes the run `build` makes (without the GIL: a run with observers is not `Send`, so
    /// it is built on the other side), into the staged folder or in memory.
    fn execute<'a>(
        &'a mut self,
        py: Python<'_>,
        build: impl FnOnce() -> Run<'a> + Send,
    ) -> PyResult<RunResult> {
        let Self {
            columns,
            staged,
            interrupt,
            every,
            mcap,
        } = self;
        let options = run_files::RunFileOptions { mcap: *mcap };
        py.detach(|| {
            let mut run = build().observe(interrupt, ObserverMode::Every(INTERRUPT_TICKS));
            if let Some(c) = columns.as_mut() {
                run = run.observe(c, ObserverMode::Every(*every));
            }
            match staged.as_ref() {
                Some(staged) => {
                    run_files::run_staged_with(staged, run, &options).map_err(report_err)
                }
                None => run.execute().map_err(|e| scenario_err(e, &[])),
            }
        })
    }

    /// After the run: an interrupted one raises KeyboardInterrupt (its folder dropped); else
    /// the folder is committed and the summary and trajectory returned.
    fn finish<'py>(
        self,
        py: Python<'py>,
        setup: &RunSetup,
        result: &RunResult,
    ) -> PyResult<RunOutput<'py>> {
        if self.interrupt.interrupted.get() {
            return Err(PyKeyboardInterrupt::new_err("aift.run interrupted"));
        }
        if let Some(staged) = self.staged {
            staged.commit().map_err(file_err)?;
        }
        let summary = serde_json::to_string(&run_files::summary_json(setup, result))
            .expect("a summary serialises");
        let names = self
            .columns
            .as_ref()
            .map(|c| c.names().to_vec())
            .unwrap_or_default();
        let bytes = columns_bytes(py, self.columns.as_ref())?;
        Ok((summary, names, bytes))
    }
}

/// Runs a scenario: in memory, or into the run folder `out` (the CLI's files, written whole
/// or not at all: an interrupted run leaves no folder). With `trajectory = false` nothing of
/// the trajectory is held in memory (with `out`, the file has it).
#[pyfunction]
#[pyo3(signature = (scenario, method = None, seed = None, out = None, force = false, calib = None, trajectory = true, mcap = false))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    scenario: &PyScenario,
    method: Option<&str>,
    seed: Option<u64>,
    out: Option<PathBuf>,
    force: bool,
    calib: Option<PathBuf>,
    trajectory: bool,
    mcap: bool,
) -> PyResult<RunOutput<'py>> {
    let mut setup = scenario.prepare(py)?;
    let method = match method {
        Some(m) => parse_method(m, "method")?,
        None => setup.scenario().precision.method,
    };
    let seed = seed.unwrap_or(setup.scenario().seed);
    setup.loaded.scenario.precision.method = method;
    setup.loaded.scenario.seed = seed;
    let mut outputs = RunOutputs::begin(&setup, out.as_deref(), force, trajectory, mcap)?;
    let cal = calibration(py, &setup, &[method], calib.as_deref())?;
    let result = outputs.execute(py, || {
        Run::new(&setup, method)
            .seed(seed)
            .calibration(cal.as_ref())
    })?;
    outputs.finish(py, &setup, &result)
}

/// A method written in Python (`custom.rs`) run on a scenario, as [`run`] runs a built-in one:
/// `method` is an object with `step(readings, applied, dt)` (an estimator) or `update(readings,
/// residuals, mu, mu_p, dt)` (a precision method driving the u-AIC). Same outputs as `run`.
#[pyfunction]
#[pyo3(signature = (scenario, method, seed = None, out = None, force = false, trajectory = true, mcap = false))]
#[allow(clippy::too_many_arguments)]
fn run_method<'py>(
    py: Python<'py>,
    scenario: &PyScenario,
    method: Bound<'py, PyAny>,
    seed: Option<u64>,
    out: Option<PathBuf>,
    force: bool,
    trajectory: bool,
    mcap: bool,
) -> PyResult<RunOutput<'py>> {
    let setup = scenario.prepare(py)?;
    let seed = seed.unwrap_or(setup.scenario().seed);
    let name = custom::method_name(&method)?;
    let sc = setup.scenario();
    custom::reset(
        &method,
        &setup.layout,
        sc.dt,
        &setup.nominal_precisions(),
        seed,
    )?;
    let failure: custom::Failure = Default::default();
    let parts = custom::build_parts(&method, &name, &setup, seed, &failure)?;
    let mut outputs = RunOutputs::begin(&setup, out.as_deref(), force, trajectory, mcap)?;
    let mut guard = custom::MethodGuard {
        failure: failure.clone(),
    };
    let result = outputs.execute(py, || {
        Run::with_parts(&setup, &name, parts)
            .seed(seed)
            .observe(&mut guard, ObserverMode::Always)
    })?;
    if let Some((tick, err)) = failure.lock().expect("not poisoned").take() {
        // The staged folder is dropped: nothing appears.
        return Err(custom::raise(py, &name, tick, err));
    }
    outputs.finish(py, &setup, &result)
}

/// `aift replay`: `method` over a recorded log (a rosbag2 bag folder, a .mcap or a .csv) into
/// the run folder `out`; returns summary.json's text.
#[pyfunction]
#[pyo3(signature = (log, scenario, out, method = None, seed = None, force = false, calib = None, topic = None, camera_topic = None))]
#[allow(clippy::too_many_arguments)]
fn replay(
    py: Python<'_>,
    log: PathBuf,
    scenario: &PyScenario,
    out: PathBuf,
    method: Option<&str>,
    seed: Option<u64>,
    force: bool,
    calib: Option<PathBuf>,
    topic: Option<String>,
    camera_topic: Option<String>,
) -> PyResult<String> {
    let mut setup = scenario.prepare(py)?;
    let method = match method {
        Some(m) => parse_method(m, "method")?,
        None => setup.scenario().precision.method,
    };
    let seed = seed.unwrap_or(setup.scenario().seed);
    let joint_names: Vec<String> = setup.model.joints.iter().map(|j| j.name.clone()).collect();
    let topics = aift::logs::Topics {
        joint_states: topic,
        camera: camera_topic,
    };
    let recorded = py
        .detach(|| aift::logs::RecordedLog::read(&log, &setup.layout, &joint_names, &topics))
        .and_then(|r| aift::logs::replay::prepare(&mut setup, &r, method, seed).map(|()| r))
        .map_err(|e| classified(&e, e.is_input_error()))?;
    let staged = Staged::begin(&out, OutputKind::Folder, force).map_err(file_err)?;
    let cal = calibration(py, &setup, &[method], calib.as_deref())?;
    py.detach(|| run_files::replay_staged(&staged, &setup, method, seed, cal.as_ref(), &recorded))
        .map_err(report_err)?;
    staged.commit().map_err(file_err)?;
    read_summary(&out)
}

/// A run folder's summary.json text.
fn read_summary(dir: &Path) -> PyResult<String> {
    aift::fsio::read_text(
        &dir.join(run_files::SUMMARY),
        aift::fsio::MAX_SCENARIO_BYTES,
    )
    .map_err(file_err)
}

/// Methods written in Python given to a table or a campaign: classes (or functions returning a
/// new method object), one instance per run, built from any worker thread with the GIL taken for
/// the call; each run's failure is kept and the first (in the order of method, place, seed) is
/// raised after all runs.
struct PyFactories {
    factories: Vec<(String, Py<PyAny>)>,
    /// Each run's failure slot, by (method, where (campaign cell), seed).
    failures: Mutex<Vec<(String, String, u64, custom::Failure)>>,
}

impl PyFactories {
    fn new(custom: &[Bound<'_, PyAny>], what: &str) -> PyResult<Self> {
        let mut factories = Vec::with_capacity(custom.len());
        for f in custom {
            if !f.is_callable() {
                return Err(bad(format!(
                    "a method written in Python in a {what} must be a class (or a function \
                     returning a new method object): each run gets its own instance; got {}",
                    f.repr()?
                )));
            }
            let name = custom::method_name(f)?;
            if let Err(e) = aift::scenario::method::check_external_name(&name) {
                return Err(bad(e));
            }
            if factories.iter().any(|(n, _)| *n == name) {
                return Err(bad(format!(
                    "method name {name:?} is taken by another given method: set a `name` \
                     attribute on the class"
                )));
            }
            factories.push((name, f.clone().unbind()));
        }
        Ok(Self {
            factories,
            failures: Mutex::new(Vec::new()),
        })
    }

    fn names(&self) -> Vec<String> {
        self.factories.iter().map(|(n, _)| n.clone()).collect()
    }

    /// Builds method `i`'s parts for a run; `place` says where the run is (a campaign cell).
    fn build(
        &self,
        i: usize,
        setup: &RunSetup,
        seed: u64,
        place: String,
    ) -> Result<MethodParts, ScenarioError> {
        let (name, factory) = &self.factories[i];
        let failure: custom::Failure = Default::default();
        self.failures.lock().expect("not poisoned").push((
            name.clone(),
            place,
            seed,
            failure.clone(),
        ));
        Python::attach(|py| {
            let obj = factory.bind(py).call0()?;
            custom::reset(
                &obj,
                &setup.layout,
                setup.scenario().dt,
                &setup.nominal_precisions(),
                seed,
            )?;
            custom::build_parts(&obj, name, setup, seed, &failure)
        })
        .map_err(|e| {
            let message = Python::attach(|py| e.value(py).to_string());
            custom::fail(&failure, 0, e);
            ScenarioError::Invalid {
                path: setup.loaded.path.clone(),
                field: "methods".into(),
                message: format!("method {name:?}: {message}"),
            }
        })
    }

    /// Whether a run of Python method `i` has failed (scans its runs' slots: called twice per
    /// job, a lock per run of it so far, so quadratic in its runs; not measured).
    fn failed(&self, i: usize) -> bool {
        let name = &self.factories[i].0;
        self.failures
            .lock()
            .expect("not poisoned")
            .iter()
            .filter(|(n, ..)| n == name)
            .any(|(.., slot)| slot.lock().expect("not poisoned").is_some())
    }

    /// Raises the first failure of a Python method, if one failed.
    fn raise_first(self, py: Python<'_>) -> PyResult<()> {
        let mut failures = self.failures.into_inner().expect("not poisoned");
        failures.sort_by(|a, b| (&a.0, &a.1, a.2).cmp(&(&b.0, &b.1, b.2)));
        for (name, place, seed, slot) in failures {
            if let Some((tick, err)) = slot.lock().expect("not poisoned").take() {
                let place = if place.is_empty() {
                    String::new()
                } else {
                    format!(", {place}")
                };
                return Err(custom::raise(
                    py,
                    &format!("{name}{place}, seed {seed}"),
                    tick,
                    err,
                ));
            }
        }
        Ok(())
    }
}

/// Every method over seeds `seed .. seed + seeds`; returns table.json's text. `out` writes the
/// table folder.
#[pyfunction]
#[pyo3(signature = (scenario, methods = None, seeds = 20, out = None, force = false, calib = None, custom = Vec::new()))]
#[allow(clippy::too_many_arguments)]
fn run_table(
    py: Python<'_>,
    scenario: &PyScenario,
    methods: Option<Vec<String>>,
    seeds: usize,
    out: Option<PathBuf>,
    force: bool,
    calib: Option<PathBuf>,
    custom: Vec<Bound<'_, PyAny>>,
) -> PyResult<String> {
    const MAX_SEEDS: usize = 100_000;
    let setup = scenario.prepare(py)?;
    let methods = match (&methods, custom.is_empty()) {
        (None, false) => Vec::new(),
        _ => parse_methods(methods)?,
    };
    // Methods written in Python: factories (classes), one instance per run.
    let factories = PyFactories::new(&custom, "table")?;
    if seeds == 0 || seeds > MAX_SEEDS {
        return Err(bad(format!("seeds must be in 1..={MAX_SEEDS}")));
    }
    let first = setup.scenario().seed;
    let seed_list: Vec<u64> = (0..seeds as u64)
        .map(|i| first.checked_add(i))
        .collect::<Option<_>>()
        .ok_or_else(|| bad(format!("seed {first} + {seeds} overflows")))?;
    let staged = match &out {
        Some(dir) => Some(Staged::begin(dir, OutputKind::Folder, force).map_err(file_err)?),
        None => None,
    };
    let cal = calibration(py, &setup, &methods, calib.as_deref())?;
    let builders: Vec<_> = (0..factories.factories.len())
        .map(|i| {
            let factories = &factories;
            move |setup: &RunSetup, seed: u64, _: &str| {
                factories.build(i, setup, seed, String::new())
            }
        })
        .collect();
    let external: Vec<table::ExternalMethod<'_>> = factories
        .names()
        .into_iter()
        .zip(&builders)
        .map(|(name, build)| table::ExternalMethod::new(name, build))
        .collect();
    let result = interruptible(py, || {
        table::run_table_with(
            &setup,
            &methods,
            &external,
            &seed_list,
            cal.as_ref(),
            &|| {},
        )
    })?;
    drop(external);
    drop(builders);
    factories.raise_first(py)?;
    let result = result.map_err(|e| scenario_err(e, &[]))?;
    if let Some(staged) = staged {
        table_files::write_table(staged.path(), &setup, &result).map_err(report_err)?;
        staged.commit().map_err(file_err)?;
    }
    Ok(table_files::table_json(&setup, &result).to_string())
}

fn parse_methods(methods: Option<Vec<String>>) -> PyResult<Vec<Method>> {
    let Some(list) = methods else {
        return Ok(Method::ALL.to_vec());
    };
    let mut out = Vec::new();
    for m in list {
        let method = parse_method(m.trim(), "methods")?;
        if out.contains(&method) {
            return Err(bad(format!("methods: {method} is listed twice")));
        }
        out.push(method);
    }
    if out.is_empty() {
        return Err(bad("methods: the list is empty"));
    }
    Ok(out)
}

/// Runs a campaign file (default: the bundled one); returns campaign.json's text. `out` writes
/// the campaign folder (or, for a shard, its records for `aift merge`), journaling each finished
/// job beside it as `aift campaign` does: an interrupted call (Ctrl-C, a killed process) is
/// resumed by calling it again with the same arguments; `fresh` discards such a journal.
#[pyfunction]
#[pyo3(signature = (path = None, seeds = None, methods = None, set = Vec::new(), shard = None, out = None, force = false, fresh = false, custom = Vec::new()))]
#[allow(clippy::too_many_arguments)]
fn run_campaign(
    py: Python<'_>,
    path: Option<PathBuf>,
    seeds: Option<usize>,
    methods: Option<Vec<String>>,
    set: Vec<String>,
    shard: Option<&str>,
    out: Option<PathBuf>,
    force: bool,
    fresh: bool,
    custom: Vec<Bound<'_, PyAny>>,
) -> PyResult<String> {
    let path = match path {
        Some(p) => p,
        None => {
            let p = campaign::bundled_campaign_path();
            if !p.is_file() {
                return Err(bad(format!(
                    "the bundled campaign {} is not here; pass a campaign file",
                    p.display()
                )));
            }
            p
        }
    };
    let shard = match shard {
        Some(s) => Shard::parse(s).map_err(|e| bad(format!("shard: {e}")))?,
        None => Shard::WHOLE,
    };
    if shard != Shard::WHOLE && out.is_none() {
        return Err(bad(
            "shard: a shard's records are for `aift merge`; give `out` to write them",
        ));
    }
    let mut config = CampaignConfig::load(&path).map_err(|e| scenario_err(e, &[]))?;
    if let Some(s) = seeds {
        config.seeds = s;
    }
    // Methods written in Python: named in the campaign (its records and tables), built per run.
    let factories = PyFactories::new(&custom, "campaign")?;
    match (methods.is_some(), custom.is_empty()) {
        (true, _) => config.methods = Some(parse_methods(methods)?),
        // Python methods alone: no built-in one.
        (false, false) => config.methods = Some(Vec::new()),
        (false, true) => {}
    }
    if !config.external_methods.is_empty() {
        return Err(bad(format!(
            "{}: external_methods is set by aift.campaign(methods=[...]), not in the file",
            path.display()
        )));
    }
    config.external_methods = factories.names();
    let staged = match &out {
        Some(dir) => Some(Staged::begin(dir, OutputKind::Folder, force).map_err(file_err)?),
        None => None,
    };
    let cache = calibrate::default_cache_dir();
    let mode = if fresh {
        campaign::JournalMode::Fresh
    } else {
        campaign::JournalMode::Resume
    };
    let (campaign, records, journal) = interruptible(py, || {
        let campaign = Campaign::from_config(config, &path, &set)?;
        let journal = match &out {
            Some(dir) => Some(
                campaign::Journal::open(&campaign::Journal::path_for(dir), &campaign, shard, mode)?
                    .0,
            ),
            None => None,
        };
        let failed: Vec<_> = (0..factories.factories.len())
            .map(|i| {
                let factories = &factories;
                move || factories.failed(i)
            })
            .collect();
        let builders: Vec<_> = (0..factories.factories.len())
            .map(|i| {
                let factories = &factories;
                move |setup: &RunSetup, seed: u64, place: &str| {
                    factories.build(i, setup, seed, place.to_string())
                }
            })
            .collect();
        let external: Vec<table::ExternalMethod<'_>> = factories
            .names()
            .into_iter()
            .zip(builders.iter().zip(&failed))
            .map(|(name, (build, failed))| table::ExternalMethod {
                name,
                build,
                failed: Some(failed),
            })
            .collect();
        let records = campaign::run_campaign_with(
            &campaign,
            shard,
            cache.as_deref(),
            &|_, _| {},
            journal.as_ref(),
            &external,
        );
        Ok::<_, ScenarioError>((campaign, records, journal))
    })?
    .map_err(|e| scenario_err(e, &[]))?;
    factories.raise_first(py)?;
    let records = records.map_err(|e| scenario_err(e, &[]))?;
    if let Some(staged) = staged {
        if shard == Shard::WHOLE {
            campaign_files::write_campaign(staged.path(), &campaign, &records)
                .map_err(report_err)?;
        } else {
            campaign_files::write_shard(staged.path(), &records).map_err(report_err)?;
        }
        staged.commit().map_err(file_err)?;
    }
    if let Some(j) = journal {
        j.remove().map_err(file_err)?;
    }
    let (cells, methods) = campaign::summarise(&campaign, &records.runs);
    let pairs = campaign::compare_all(&campaign, &records.runs, campaign::compare::ALPHA);
    Ok(campaign_files::campaign_json(&campaign, &records, &cells, &methods, &pairs).to_string())
}

/// The closed loop stepped from Python: `reset(seed)` senses, estimates and controls tick 0;
/// each `step()` applies the torques (the controller's, or the caller's), steps the plant one
/// tick and does the next tick's sensing, estimation and control. With nothing supplied, the
/// ticks are those of `run`, bit for bit.
#[pyclass(module = "aift._aift", name = "Sim")]
struct PySim {
    setup: RunSetup,
    method: Method,
    /// A method written in Python (its name and object, or class to instantiate on each
    /// reset), in place of `method`.
    custom: Option<(String, Py<PyAny>)>,
    /// Its failure, raised by the call that met it.
    failure: custom::Failure,
    calibration: Option<Calibration>,
    /// In a mutex only to make a `Sim` shareable between Python threads (a pyclass must be
    /// `Sync`); every access is through `&mut self`, which PyO3 guards (a second thread using
    /// the same `Sim` at once gets a RuntimeError), so the lock is never contended.
    sim: std::sync::Mutex<Option<Simulation>>,
    diverged: Option<(u64, String)>,
}

impl PySim {
    /// Raises a Python method's failure met by the last tick (the simulation is dropped:
    /// reset() to start over).
    fn raise_failure(&mut self, py: Python<'_>) -> PyResult<()> {
        let Some((tick, err)) = self.failure.lock().expect("not poisoned").take() else {
            return Ok(());
        };
        *self
            .sim
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = None;
        let name = self.custom.as_ref().map_or("", |(n, _)| n.as_str());
        Err(custom::raise(py, name, tick, err))
    }

    fn readings(&self, values: Option<Vec<Option<f64>>>) -> PyResult<Option<Readings>> {
        let Some(values) = values else {
            return Ok(None);
        };
        let n = self.setup.layout.len();
        if values.len() != n {
            return Err(bad(format!(
                "readings: {} values given, the arm has {n} channels ({})",
                values.len(),
                self.setup.layout.names().join(", ")
            )));
        }
        Ok(Some(Readings {
            values: values
                .into_iter()
                .map(|v| v.filter(|x| !x.is_nan()))
                .collect(),
        }))
    }

    fn observe<'py>(
        &mut self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
        let sim = self
            .sim
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_ref()
            .expect("reset before observe");
        let r = sim.record();
        if self.diverged.is_none()
            && let Some(reason) = DivergenceGuard::check(&r)
        {
            self.diverged = Some((r.tick, reason.describe().to_string()));
        }
        let obs = PyDict::new(py);
        obs.set_item("tick", r.tick)?;
        obs.set_item("t", r.t)?;
        obs.set_item("q", r.q.to_vec())?;
        obs.set_item("qd", r.qd.to_vec())?;
        obs.set_item("mu", r.mu.to_vec())?;
        obs.set_item("mu_p", r.mu_p.to_vec())?;
        obs.set_item("target", r.target.to_vec())?;
        obs.set_item("u", r.torques.to_vec())?;
        obs.set_item("applied", r.applied.to_vec())?;
        obs.set_item(
            "y",
            r.readings
                .values
                .iter()
                .map(|v| v.unwrap_or(f64::NAN))
                .collect::<Vec<_>>(),
        )?;
        obs.set_item("precision", r.precisions.to_vec())?;
        let info = PyDict::new(py);
        info.set_item("free_energy", r.free_energy)?;
        info.set_item("done", r.tick + 1 >= sim.ticks())?;
        let (alarm, isolated) = match r.detection {
            Some(d) => (
                d.fired(),
                d.isolated
                    .iter()
                    .map(|&c| self.setup.layout.name(c).to_string())
                    .collect::<Vec<_>>(),
            ),
            None => (false, Vec::new()),
        };
        info.set_item("alarm", alarm)?;
        info.set_item("isolated", isolated)?;
        // The method's own actuator alarms so far, as summary.json's `actuator_alarms.alarms`
        // (None for a method that infers no actuator health).
        let dt = self.setup.scenario().dt;
        match sim.actuator_alarms() {
            Some(alarms) => {
                let list = pyo3::types::PyList::empty(py);
                for &(tick, joint) in alarms {
                    let alarm = PyDict::new(py);
                    alarm.set_item("t", tick as f64 * dt)?;
                    alarm.set_item("joint", aift::plant::actuators::motor_name(joint))?;
                    list.append(alarm)?;
                }
                info.set_item("actuator_alarms", list)?;
            }
            None => info.set_item("actuator_alarms", py.None())?,
        }
        info.set_item(
            "diverged",
            self.diverged.as_ref().map(|(_, reason)| reason.clone()),
        )?;
        Ok((obs, info))
    }
}

#[pymethods]
impl PySim {
    #[new]
    #[pyo3(signature = (scenario, method = None, calib = None))]
    fn new(
        py: Python<'_>,
        scenario: &PyScenario,
        method: Option<Bound<'_, PyAny>>,
        calib: Option<PathBuf>,
    ) -> PyResult<Self> {
        let mut setup = scenario.prepare(py)?;
        let (method, custom) = match method {
            Some(m) if m.is_instance_of::<PyString>() => {
                (parse_method(&m.extract::<String>()?, "method")?, None)
            }
            Some(obj) => (
                Method::NoFt,
                Some((custom::method_name(&obj)?, obj.unbind())),
            ),
            None => (setup.scenario().precision.method, None),
        };
        setup.loaded.scenario.precision.method = method;
        let calibration = match custom {
            None => calibration(py, &setup, &[method], calib.as_deref())?,
            Some(_) => None,
        };
        Ok(Self {
            setup,
            method,
            custom,
            failure: Default::default(),
            calibration,
            sim: std::sync::Mutex::new(None),
            diverged: None,
        })
    }

    /// Starts over at tick 0 with sensor-noise seed `seed` (default: the scenario's); returns
    /// (observation, info) of tick 0. `readings` replace the sensors' at tick 0.
    #[pyo3(signature = (seed = None, readings = None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<u64>,
        readings: Option<Vec<Option<f64>>>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
        let readings = self.readings(readings)?;
        let seed = seed.unwrap_or(self.setup.scenario().seed);
        let run = match &self.custom {
            None => Run::new(&self.setup, self.method).calibration(self.calibration.as_ref()),
            Some((name, obj)) => {
                // A class: a new instance for each reset; an object: the same one, reset.
                let obj = obj.bind(py);
                let obj = if obj.is_instance_of::<pyo3::types::PyType>() {
                    obj.call0()?
                } else {
                    obj.clone()
                };
                let sc = self.setup.scenario();
                custom::reset(
                    &obj,
                    &self.setup.layout,
                    sc.dt,
                    &self.setup.nominal_precisions(),
                    seed,
                )?;
                self.failure = Default::default();
                let parts = custom::build_parts(&obj, name, &self.setup, seed, &self.failure)?;
                Run::with_parts(&self.setup, name, parts)
            }
        };
        let mut sim = run
            .seed(seed)
            .simulation()
            .map_err(|e| scenario_err(e, &[]))?;
        sim.decide(readings.as_ref());
        self.raise_failure(py)?;
        *self
            .sim
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(sim);
        self.diverged = None;
        self.observe(py)
    }

    /// Applies `torques` (default: the controller's for this tick, `obs["u"]`), steps the plant
    /// one tick, and senses (or takes `readings`), estimates and controls the next tick.
    #[pyo3(signature = (torques = None, readings = None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        torques: Option<Vec<f64>>,
        readings: Option<Vec<Option<f64>>>,
    ) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
        let readings = self.readings(readings)?;
        if let Some((tick, reason)) = &self.diverged {
            return Err(AiftError::new_err(format!(
                "the run diverged at tick {tick} ({reason}); reset() to start over"
            )));
        }
        let n = self.setup.layout.n_joints();
        if let Some(u) = &torques {
            if u.len() != n {
                return Err(bad(format!(
                    "torques: {} values given, the arm has {n} joints",
                    u.len()
                )));
            }
            if let Some(i) = u.iter().position(|v| !v.is_finite()) {
                return Err(bad(format!("torques[{i}] is not finite")));
            }
        }
        let sim = self
            .sim
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .as_mut()
            .ok_or_else(|| AiftError::new_err("reset() before step()"))?;
        if sim.tick() + 1 >= sim.ticks() {
            return Err(AiftError::new_err(format!(
                "the run has ended: tick {} was its last (info[\"done\"] was true); reset() to \
                 start over",
                sim.tick()
            )));
        }
        sim.actuate(torques.as_deref());
        sim.decide(readings.as_ref());
        self.raise_failure(py)?;
        self.observe(py)
    }

    /// Channel names, in the order of `obs["y"]` and `obs["precision"]`.
    #[getter]
    fn channels(&self) -> Vec<String> {
        self.setup
            .layout
            .names()
            .iter()
            .map(|s| s.to_string())
            .collect()
    }

    #[getter]
    fn n_joints(&self) -> usize {
        self.setup.layout.n_joints()
    }

    /// Ticks in the scenario (`info["done"]` turns true on the last).
    #[getter]
    fn ticks(&self) -> u64 {
        self.setup.scenario().ticks()
    }

    #[getter]
    fn dt(&self) -> f64 {
        self.setup.scenario().dt
    }

    #[getter]
    fn method(&self) -> String {
        match &self.custom {
            Some((name, _)) => name.clone(),
            None => self.method.name().to_string(),
        }
    }

    /// Each joint's effort limit from the URDF (None where it has none).
    #[getter]
    fn effort_limits(&self) -> Vec<Option<f64>> {
        self.setup.model.joints.iter().map(|j| j.effort).collect()
    }
}

/// Writes report.html into a run, table or campaign folder; returns (kind, path).
#[pyfunction]
fn report(py: Python<'_>, dir: PathBuf) -> PyResult<(String, String)> {
    let (kind, path) = py
        .detach(|| aift::report::html::write_report(&dir))
        .map_err(report_err)?;
    Ok((kind.name().to_string(), path.display().to_string()))
}

/// Merges campaign shards (their folders) into the campaign folder `out`, as `aift merge`;
/// returns campaign.json's text.
#[pyfunction]
#[pyo3(signature = (shards, out, force = false))]
fn merge(py: Python<'_>, shards: Vec<PathBuf>, out: PathBuf, force: bool) -> PyResult<String> {
    let staged = Staged::begin(&out, OutputKind::Folder, force).map_err(file_err)?;
    py.detach(|| campaign_files::merge_into(staged.path(), &shards))
        .map_err(report_err)?;
    staged.commit().map_err(file_err)?;
    let path = out.join(campaign_files::CAMPAIGN_JSON);
    aift::fsio::read_text(&path, aift::fsio::MAX_CALIBRATION_BYTES).map_err(file_err)
}

/// The arm of a URDF file as `aift check-urdf --json` prints it (JSON text).
#[pyfunction]
#[pyo3(signature = (path, ee = None, balance_inertia = false))]
fn check_urdf(path: PathBuf, ee: Option<String>, balance_inertia: bool) -> PyResult<String> {
    let model = aift::arm::load_urdf_with(&path, &aift::arm::UrdfOptions { balance_inertia })
        .map_err(|e| bad(aift::error_chain(&e)))?;
    if let Some(ee) = ee.as_deref().filter(|ee| model.link(ee).is_none()) {
        return Err(bad(aift::error_chain(&model.unknown_link_error(ee))));
    }
    Ok(aift::arm::describe_arm(&model, &path, ee.as_deref()).to_string())
}

/// A random serial arm drawn from `seed` with `min_joints..=max_joints` joints (as `aift
/// gen-arm`): the URDF text, the same bytes for the same seed.
#[pyfunction]
#[pyo3(signature = (seed, min_joints = 2, max_joints = 7))]
fn gen_arm(seed: u64, min_joints: usize, max_joints: usize) -> PyResult<String> {
    aift::arm::generate_arm(&aift::arm::GenerateOptions {
        seed,
        joints: (min_joints, max_joints),
    })
    .map_err(|e| bad(aift::error_chain(&e)))
}

/// A scenario derived from any URDF (as `aift init`): the TOML text, naming the URDF as
/// `urdf_in_scenario` (default: its path as given).
#[pyfunction]
#[pyo3(signature = (urdf, name = "scenario".to_string(), ee = None, balance_inertia = false, urdf_in_scenario = None))]
fn init_scenario(
    urdf: PathBuf,
    name: String,
    ee: Option<String>,
    balance_inertia: bool,
    urdf_in_scenario: Option<String>,
) -> PyResult<String> {
    let options = aift::scenario::init::InitOptions {
        ee_link: ee,
        balance_inertia,
        urdf_in_scenario: urdf_in_scenario.unwrap_or_else(|| urdf.display().to_string()),
        name,
    };
    aift::scenario::init::init_scenario(&urdf, &options).map_err(|e| scenario_err(e, &[]))
}

/// Writes the detector calibration of `runs` healthy runs to the file `out` (as `aift
/// calibrate`); returns {fingerprint, runs, ticks} as JSON text (the file itself can be large).
#[pyfunction]
#[pyo3(signature = (scenario, out, runs = None))]
fn calibrate_to(
    py: Python<'_>,
    scenario: &PyScenario,
    out: PathBuf,
    runs: Option<usize>,
) -> PyResult<String> {
    let setup = scenario.prepare(py)?;
    let runs = runs.unwrap_or(setup.scenario().detector.calibration_runs);
    calibrate::check_size(&setup, runs).map_err(|e| scenario_err(e, &[]))?;
    let staged = Staged::begin(&out, OutputKind::File, true).map_err(file_err)?;
    let cal = interruptible(py, || calibrate::calibrate(&setup, runs))?
        .map_err(|e| scenario_err(e, &[]))?;
    staged
        .commit_bytes(cal.to_json().as_bytes())
        .map_err(file_err)?;
    Ok(serde_json::json!({
        "fingerprint": cal.fingerprint,
        "runs": cal.runs,
        "ticks": cal.ticks,
    })
    .to_string())
}

/// Trains the camera GP of the scenario on `points` points (default: the scenario's) and writes
/// it to `out` (as `aift train-gp`); returns {points, length_scales, signal_std, noise_std,
/// log_marginal_likelihood, evaluations, held_out_rms, held_out_max, held_out_points} as JSON
/// text.
#[pyfunction]
#[pyo3(signature = (scenario, out, points = None))]
fn train_gp_to(
    py: Python<'_>,
    scenario: &PyScenario,
    out: PathBuf,
    points: Option<usize>,
) -> PyResult<String> {
    let points = points.unwrap_or(scenario.loaded.scenario.gp.points);
    let staged = Staged::begin(&out, OutputKind::File, true).map_err(file_err)?;
    let (gp, fit, held) = py
        .detach(|| aift::scenario::train_gp_fresh(&scenario.loaded, Some(points)))
        .map_err(|e| scenario_err(e, &[]))?;
    staged
        .commit_bytes(gp.to_json().as_bytes())
        .map_err(file_err)?;
    let h = &gp.hyperparameters;
    Ok(serde_json::json!({
        "points": points,
        "length_scales": h.length_scales,
        "signal_std": h.signal_std,
        "noise_std": h.noise_std,
        "log_marginal_likelihood": fit.log_marginal_likelihood,
        "evaluations": fit.evaluations,
        "held_out_rms": held.rms,
        "held_out_max": held.max,
        "held_out_points": held.points,
    })
    .to_string())
}

/// Method names, in the CLI's order.
#[pyfunction]
fn methods() -> Vec<String> {
    Method::ALL.iter().map(|m| m.name().to_string()).collect()
}

/// The scenario file's JSON Schema, as `aift schema` prints it.
#[pyfunction]
fn schema() -> String {
    serde_json::to_string_pretty(&aift::scenario::scenario_schema()).expect("serialises")
}

#[pymodule]
fn _aift(m: &Bound<'_, PyModule>) -> PyResult<()> {
    if let Some(warning) = aift::init_thread_pool() {
        let warnings = m.py().import("warnings")?;
        warnings.call_method1("warn", (warning,))?;
    }
    m.add("AiftError", m.py().get_type::<AiftError>())?;
    m.add("BadInput", m.py().get_type::<BadInput>())?;
    m.add("InternalError", m.py().get_type::<InternalError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<PyScenario>()?;
    m.add_class::<PySim>()?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(replay, m)?)?;
    m.add_function(wrap_pyfunction!(run_method, m)?)?;
    m.add_function(wrap_pyfunction!(run_table, m)?)?;
    m.add_function(wrap_pyfunction!(run_campaign, m)?)?;
    m.add_function(wrap_pyfunction!(report, m)?)?;
    m.add_function(wrap_pyfunction!(check_urdf, m)?)?;
    m.add_function(wrap_pyfunction!(init_scenario, m)?)?;
    m.add_function(wrap_pyfunction!(gen_arm, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_to, m)?)?;
    m.add_function(wrap_pyfunction!(train_gp_to, m)?)?;
    m.add_function(wrap_pyfunction!(merge, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(schema, m)?)?;
    Ok(())
}
