//! One run of a scenario with one method and seed: the closed loop, stepped by a
//! [`Simulation`] and watched by observers.
//!
//! Per tick k (t = k dt): the sensors read the plant; the estimator updates its belief with the
//! precisions the method left after tick k-1; f* and the action give the torques (this is the
//! simulation's step callback); the precision method learns from the tick (its detector, if it
//! has one, tests the innovations first); observers see the tick; the plant steps with the
//! torques. Metrics, divergence checks and trajectory recording are observers
//! ([`super::metrics`], [`super::trajectory`]), not part of the loop; [`Run`] builds a run and
//! its observers and executes it.

use std::time::Instant;

use super::method::MethodParts;
use super::metrics::{
    ActuatorAlarms, ChatterMonitor, DivergenceGuard, RunDetectors, RunMetrics, RunResult,
};
use super::{Method, RunSetup, ScenarioError};
use crate::control::{BeliefTiming, Control};
use crate::estimation::{Estimate, Estimator, EstimatorInput};
use crate::plant::Plant;
use crate::precision::Calibration;
use crate::precision::{Detection, PrecisionInput, PrecisionMethod};
use crate::sensors::{Camera, ChannelLayout, Readings, SensorSuite};

/// Why a run diverged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DivergenceReason {
    /// The estimator refused a non-finite update.
    BeliefNonFinite,
    /// The arm's state left |q| <= 1e3 rad, |qd| <= 1e4 rad/s.
    StateOutOfRange,
    /// The belief left |mu| <= 1e3 rad, |mu'| <= 1e4 rad/s.
    BeliefOutOfRange,
}

impl DivergenceReason {
    /// What happened, for messages and summary.json.
    pub fn describe(self) -> &'static str {
        match self {
            Self::BeliefNonFinite => "the belief update became non-finite",
            Self::StateOutOfRange => "the arm's state left |q| <= 1e3 rad, |qd| <= 1e4 rad/s",
            Self::BeliefOutOfRange => "the belief left |mu| <= 1e3 rad, |mu'| <= 1e4 rad/s",
        }
    }
}

/// Why an observer stopped a run.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// The state or belief left any sane range (the divergence guard).
    Diverged(DivergenceReason),
    /// The user asked (Ctrl-C in Python).
    Interrupted,
    /// An observer of the caller's, with its own words.
    Requested(String),
}

impl StopReason {
    pub fn describe(&self) -> String {
        match self {
            Self::Diverged(d) => d.describe().to_string(),
            Self::Interrupted => "interrupted".to_string(),
            Self::Requested(why) => why.clone(),
        }
    }
}

/// How a run ended. A diverged run is a result, not an error.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Completed,
    /// The state or belief left any sane range at `tick`.
    Diverged {
        tick: u64,
        reason: DivergenceReason,
    },
    /// An observer asked the run to stop at `tick`.
    Stopped {
        tick: u64,
        reason: StopReason,
    },
    /// The run reached its end, but a joint oscillated near the tick rate (a failure: the
    /// loop is unstable in discrete time; docs/method.md, "Metrics").
    Chattering(super::metrics::Chattering),
}

impl Outcome {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Completed => "completed",
            Self::Diverged { .. } => "diverged",
            Self::Stopped { .. } => "stopped",
            Self::Chattering(_) => "chattering",
        }
    }

    /// Where and why the run ended early, if it did.
    pub fn early_end(&self) -> Option<(u64, String)> {
        match self {
            Self::Completed => None,
            Self::Diverged { tick, reason } => Some((*tick, reason.describe().to_string())),
            Self::Stopped { tick, reason } => Some((*tick, reason.describe())),
            Self::Chattering(_) => None,
        }
    }
}

/// What observers see every tick.
#[derive(Debug)]
pub struct TickRecord<'a> {
    pub tick: u64,
    pub t: f64,
    pub layout: &'a ChannelLayout,
    pub q: &'a [f64],
    pub qd: &'a [f64],
    pub mu: &'a [f64],
    pub mu_p: &'a [f64],
    pub target: &'a [f64],
    /// The torques commanded this tick (before the plant's effort limits).
    pub torques: &'a [f64],
    /// The torques the joints receive this tick: the commanded ones after the effort limits
    /// and any actuator fault (what the plant steps with).
    pub applied: &'a [f64],
    pub readings: &'a Readings,
    /// The precision each channel entered this tick's update with.
    pub precisions: &'a [f64],
    pub nominal: &'a [f64],
    /// Free energy of the tick (belief and action), NaN where the estimator defines none.
    pub free_energy: f64,
    /// The estimator's report (innovations, residuals, corrections, likelihood).
    pub estimate: &'a Estimate,
    /// The detector's state, for methods that run one.
    pub detection: Option<&'a Detection>,
}

/// What observers are told before the first tick.
#[derive(Clone, Copy)]
pub struct RunStart<'a> {
    pub setup: &'a RunSetup,
    /// The method's name (or the caller's label for parts of its own).
    pub label: &'a str,
    pub seed: u64,
    pub ticks: u64,
}

/// Watches a run, as argmin's observers watch a solver: told when it starts, shown every tick
/// it is set to see ([`ObserverMode`]), told how it ended, and asked after every tick it saw
/// whether the run should stop. Metrics, the divergence guard, the trajectory writer and the
/// plots' recorder are observers.
pub trait Observer {
    /// Before the first tick.
    fn init(&mut self, _start: &RunStart<'_>) {}
    /// A tick (every tick, or every n-th: [`ObserverMode`]).
    fn iter(&mut self, record: &TickRecord<'_>);
    /// After the last tick, with how the run ended.
    fn finish(&mut self, _outcome: &Outcome) {}
    /// Asked after every tick it saw: a reason to stop the run here, if any.
    fn stop(&self) -> Option<StopReason> {
        None
    }
}

/// Which ticks an observer sees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ObserverMode {
    Always,
    /// Ticks 0, n, 2n, ...
    Every(u64),
    Never,
}

impl ObserverMode {
    fn sees(self, tick: u64) -> bool {
        match self {
            Self::Always => true,
            Self::Every(n) => tick.is_multiple_of(n.max(1)),
            Self::Never => false,
        }
    }
}

/// Observes nothing.
pub struct NoObserver;

impl Observer for NoObserver {
    fn iter(&mut self, _: &TickRecord<'_>) {}
}

/// Requests from [`stop_all_runs`] in force: while any is, every run of this process stops at
/// its next check.
static STOP_ALL: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Ticks between checks of [`stop_all_runs`]'s requests.
const STOP_CHECK_TICKS: u64 = 1024;

/// Asks every run in this process, on any thread, to stop within [`STOP_CHECK_TICKS`] ticks
/// (`true`), or withdraws one such request (`false`; each caller withdraws only its own, so runs
/// go on once every request is withdrawn). Stopped runs end `stopped` (interrupted); a table,
/// campaign or calibration they belong to finishes quickly with them. The Python package makes
/// a request on Ctrl-C while its long calls run, and withdraws it after.
pub fn stop_all_runs(stop: bool) {
    use std::sync::atomic::Ordering::SeqCst;
    if stop {
        STOP_ALL.fetch_add(1, SeqCst);
    } else {
        let _ = STOP_ALL.fetch_update(SeqCst, SeqCst, |n| n.checked_sub(1));
    }
}

/// Whether a [`stop_all_runs`] request is in force.
pub fn all_runs_stopping() -> bool {
    STOP_ALL.load(std::sync::atomic::Ordering::SeqCst) > 0
}

/// Several observers, each with its mode, called in order; itself an observer (of every tick).
#[derive(Default)]
pub struct Observers<'a>(pub Vec<(&'a mut dyn Observer, ObserverMode)>);

impl<'a> Observers<'a> {
    pub fn new() -> Self {
        Self(Vec::new())
    }

    pub fn push(&mut self, observer: &'a mut dyn Observer, mode: ObserverMode) {
        self.0.push((observer, mode));
    }
}

impl Observer for Observers<'_> {
    fn init(&mut self, start: &RunStart<'_>) {
        for (o, _) in &mut self.0 {
            o.init(start);
        }
    }
    fn iter(&mut self, record: &TickRecord<'_>) {
        for (o, mode) in &mut self.0 {
            if mode.sees(record.tick) {
                o.iter(record);
            }
        }
    }
    fn finish(&mut self, outcome: &Outcome) {
        for (o, _) in &mut self.0 {
            o.finish(outcome);
        }
    }
    fn stop(&self) -> Option<StopReason> {
        self.0.iter().find_map(|(o, _)| o.stop())
    }
}

/// Nominal precision per channel: 1 / sigma^2 (a noise-free channel gets a very large one).
pub fn nominal_precisions(sigmas: &[f64]) -> Vec<f64> {
    sigmas
        .iter()
        .map(|s| {
            if *s > 0.0 {
                1.0 / (s * s)
            } else {
                crate::sensors::NOISE_FREE_PRECISION
            }
        })
        .collect()
}

/// The closed loop of one (method, seed), stepped tick by tick: [`Simulation::decide`] senses,
/// estimates, controls and learns; [`Simulation::record`] shows the tick; [`Simulation::actuate`]
/// steps the plant. [`run`] drives it over the scenario with observers; the Python step API
/// drives it from a loop of its own.
pub struct Simulation {
    layout: ChannelLayout,
    dt: f64,
    ticks: u64,
    targets: Vec<(f64, Vec<f64>)>,
    target: usize,
    arm: Box<dyn Plant>,
    sensors: SensorSuite,
    estimator: Box<dyn Estimator>,
    precision: Box<dyn PrecisionMethod>,
    control: Control,
    nominal: Vec<f64>,
    readings: Readings,
    precisions: Vec<f64>,
    q: Vec<f64>,
    qd: Vec<f64>,
    /// Actuator faults between the commanded torques and the joints.
    actuators: crate::plant::Actuators,
    /// Payloads and pushes.
    disturbances: crate::plant::Disturbances,
    /// What the estimators take as applied over the last step: the commanded torques clamped to
    /// the effort limits (they do not know of actuator faults).
    believed_last: Vec<f64>,
    /// This tick's commanded torques clamped to the effort limits, and what the joints receive.
    believed: Vec<f64>,
    applied: Vec<f64>,
    /// The momentum observer beside the method (`[momentum] enabled`).
    momentum: Option<crate::precision::MomentumMonitor>,
    /// The largest normal contact force on the arm so far (N).
    max_contact_normal_force: f64,
    torques: Vec<f64>,
    free_energy: f64,
    /// The belief before this tick's update, for a law that reads it (`controller.belief =
    /// "previous"`).
    previous_mu: Vec<f64>,
    previous_mu_p: Vec<f64>,
    /// The alarm rule on each actuator's health under the method's actuator hypotheses (when
    /// it has any), and its alarms: tick and joint.
    actuator_alarms: ActuatorAlarms,
    tick: u64,
    decided: bool,
}

impl Simulation {
    /// A simulation of `method` with sensor-noise seed `seed`, at tick 0 with the scenario's
    /// initial state. Methods with a detector need `calibration`.
    pub fn new(
        setup: &RunSetup,
        method: Method,
        seed: u64,
        calibration: Option<&Calibration>,
    ) -> Result<Self, ScenarioError> {
        let nominal = setup.nominal_precisions();
        let parts = super::method::build(
            method,
            &super::method::MethodContext {
                setup,
                model: setup.estimator_model(seed),
                layout: &setup.layout,
                nominal: &nominal,
                calibration,
            },
        )?;
        Self::from_parts(setup, seed, parts)
    }

    /// A simulation of an estimator and a precision method of the caller's.
    pub fn from_parts(
        setup: &RunSetup,
        seed: u64,
        (estimator, precision): MethodParts,
    ) -> Result<Self, ScenarioError> {
        let sc = setup.scenario();
        let mut arm = setup.plant()?;
        let layout = setup.layout;
        let n = layout.n_joints();
        let dt = sc.dt;
        let sensors = SensorSuite::new(
            layout,
            &sc.sensors,
            Camera::new(sc.camera.clone()),
            setup.ee,
            &setup.faults,
            dt,
            seed,
        );
        let nominal = setup.nominal_precisions();
        assert_eq!(
            precision.precisions().len(),
            layout.len(),
            "one precision per channel"
        );
        let qd0 = sc.initial.qd.clone().unwrap_or_else(|| vec![0.0; n]);
        arm.set_state(&sc.initial.q, &qd0);
        Ok(Self {
            layout,
            dt,
            ticks: sc.ticks(),
            targets: sc.targets.iter().map(|t| (t.time, t.q.clone())).collect(),
            target: 0,
            arm,
            sensors,
            estimator,
            precision,
            control: Control::new(&sc.controller),
            readings: Readings::missing(&layout),
            precisions: nominal.clone(),
            nominal,
            q: vec![0.0; n],
            qd: vec![0.0; n],
            actuators: crate::plant::Actuators::new(&setup.actuator_faults, n, dt),
            disturbances: crate::plant::Disturbances::new(
                &setup.disturbances,
                setup.model.bodies.len(),
                dt,
            ),
            believed_last: vec![0.0; n],
            believed: vec![0.0; n],
            applied: vec![0.0; n],
            max_contact_normal_force: 0.0,
            momentum: sc.momentum.enabled.then(|| {
                crate::precision::MomentumMonitor::new(
                    crate::precision::MomentumObserver::new(
                        setup.estimator_model(seed),
                        sc.robot.gravity,
                        sc.momentum.gain,
                    ),
                    setup.momentum_thresholds.as_deref().cloned(),
                    (sc.momentum.dwell / dt).round() as u64,
                )
            }),
            torques: vec![0.0; n],
            free_energy: f64::NAN,
            previous_mu: vec![0.0; n],
            previous_mu_p: vec![0.0; n],
            actuator_alarms: ActuatorAlarms::new(n, setup.scenario().dt),
            tick: 0,
            decided: false,
        })
    }

    /// The tick about to be decided (or just decided).
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Ticks in the scenario.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    pub fn layout(&self) -> &ChannelLayout {
        &self.layout
    }

    pub fn arm(&self) -> &dyn Plant {
        self.arm.as_ref()
    }

    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }

    /// The readings of the current tick.
    pub fn readings(&self) -> &Readings {
        &self.readings
    }

    /// The torques commanded at the current tick.
    pub fn torques(&self) -> &[f64] {
        &self.torques
    }

    /// The torques the joints receive at the current tick (after effort limits and actuator
    /// faults).
    pub fn applied(&self) -> &[f64] {
        &self.applied
    }

    /// The control law's integral torque per joint after the last [`Self::decide`].
    pub fn integral(&self) -> &[f64] {
        self.control.integral()
    }

    /// Senses, estimates, controls and learns for the current tick. `readings`, when given,
    /// replace what the sensors read (one value or `None` per channel).
    ///
    /// # Panics
    /// If called twice without [`Self::actuate`] between, or with readings of the wrong length.
    pub fn decide(&mut self, readings: Option<&Readings>) {
        assert!(!self.decided, "decide() twice without actuate()");
        let k = self.tick;
        let t = k as f64 * self.dt;
        while self.target + 1 < self.targets.len() && self.targets[self.target + 1].0 <= t + 1e-9 {
            self.target += 1;
        }
        self.sensors.read(self.arm.as_ref(), k, &mut self.readings);
        if let Some(r) = readings {
            assert_eq!(r.values.len(), self.layout.len(), "one reading per channel");
            self.readings.values.copy_from_slice(&r.values);
        }
        self.precisions.copy_from_slice(self.precision.precisions());
        let previous = self.control.belief_timing() == BeliefTiming::Previous;
        if previous {
            let n = self.layout.n_joints();
            if k == 0 {
                // No update yet: the belief's initialisation, the first readings.
                for i in 0..n {
                    self.previous_mu[i] = self.readings.get(i).unwrap_or(0.0);
                    self.previous_mu_p[i] = self.readings.get(n + i).unwrap_or(0.0);
                }
            } else {
                self.previous_mu.copy_from_slice(self.estimator.mu());
                self.previous_mu_p.copy_from_slice(self.estimator.mu_p());
            }
        }
        let estimate = self.estimator.update(&EstimatorInput {
            tick: k,
            readings: &self.readings,
            precisions: &self.precisions,
            applied_torques: &self.believed_last,
        });
        let finite = estimate.finite;
        let belief_energy = estimate.free_energy;
        self.actuator_alarms.update(k, self.estimator.as_ref());
        let target = &self.targets[self.target].1;
        let (mu, mu_p) = if previous {
            (&self.previous_mu[..], &self.previous_mu_p[..])
        } else {
            (self.estimator.mu(), self.estimator.mu_p())
        };
        let torques = self.control.step(mu, mu_p, target, self.dt);
        self.torques.copy_from_slice(torques);
        if !finite {
            self.control.hold();
            self.torques.copy_from_slice(self.control.torques());
        }
        self.free_energy = belief_energy.map_or(f64::NAN, |f| f + self.control.free_energy());
        self.actuators.deliver(
            k,
            self.arm.model(),
            &self.torques,
            &mut self.believed,
            &mut self.applied,
        );
        self.precision.update(&PrecisionInput {
            tick: k,
            dt: self.dt,
            layout: &self.layout,
            readings: &self.readings,
            estimate: self.estimator.estimate(),
            mu: self.estimator.mu(),
            mu_p: self.estimator.mu_p(),
            covariance: self.estimator.covariance(),
            torques: &self.torques,
        });
        self.arm.read_state(&mut self.q, &mut self.qd);
        self.decided = true;
    }

    /// What the current tick looks like (after [`Self::decide`]).
    pub fn record(&self) -> TickRecord<'_> {
        let estimate = self.estimator.estimate();
        TickRecord {
            tick: self.tick,
            t: self.tick as f64 * self.dt,
            layout: &self.layout,
            q: &self.q,
            qd: &self.qd,
            mu: self.estimator.mu(),
            mu_p: self.estimator.mu_p(),
            target: &self.targets[self.target].1,
            torques: &self.torques,
            applied: &self.applied,
            readings: &self.readings,
            precisions: &estimate.precisions_used,
            nominal: &self.nominal,
            free_energy: self.free_energy,
            estimate,
            detection: self.precision.detection(),
        }
    }

    /// Steps the plant one tick with the decided torques, or with `torques` when given
    /// (clamped to the URDF's effort limits either way, and through the scenario's actuator
    /// faults).
    ///
    /// # Panics
    /// If [`Self::decide`] has not run for this tick, or `torques` has the wrong length.
    pub fn actuate(&mut self, torques: Option<&[f64]>) {
        assert!(self.decided, "actuate() before decide()");
        if let Some(u) = torques {
            self.actuators.deliver(
                self.tick,
                self.arm.model(),
                u,
                &mut self.believed,
                &mut self.applied,
            );
        }
        if let Some(m) = &mut self.momentum {
            m.update(
                self.tick,
                self.estimator.mu(),
                self.estimator.mu_p(),
                &self.believed,
                self.dt,
            );
        }
        self.actuators.set_brakes(self.tick, self.arm.as_mut());
        self.disturbances.apply(self.tick, self.arm.as_mut());
        self.arm.set_torques(&self.applied);
        self.arm.step(self.dt);
        self.max_contact_normal_force = self
            .max_contact_normal_force
            .max(self.arm.contact_normal_force().norm());
        self.believed_last.copy_from_slice(&self.believed);
        self.tick += 1;
        self.decided = false;
    }

    /// The detector's state, for methods that run one.
    pub fn detection(&self) -> Option<&Detection> {
        self.precision.detection()
    }

    /// The largest force the obstacles exerted on the arm so far (N; 0 without contact).
    pub fn max_contact_normal_force(&self) -> f64 {
        self.max_contact_normal_force
    }

    /// The momentum observer, when the scenario runs one.
    pub fn momentum(&self) -> Option<&crate::precision::MomentumMonitor> {
        self.momentum.as_ref()
    }

    /// The method's own actuator alarms (tick, joint: an actuator's health, one minus the
    /// method's probability that it failed, under the channels' alarm rule, `HealthAlarm`; at
    /// most [`MAX_DETECTIONS`]), or `None` when the method infers no actuator health.
    pub fn actuator_alarms(&self) -> Option<&[(u64, usize)]> {
        self.actuator_alarms.alarms()
    }
}

/// What a run runs: a method by name, or an estimator and precision method of the caller's.
enum What {
    Method(Method),
    Parts(String, MethodParts),
}

/// One run of a scenario, built and then executed: the method (or parts of the caller's), the
/// seed (default: the scenario's), the detector's calibration for methods that need one, and
/// observers with their modes. Metrics and the divergence guard always watch; tables,
/// campaigns, calibration, the run folders and the Python package compose this.
///
/// ```no_run
/// # use aift::scenario::{LoadedScenario, Method, RunSetup, runner::Run};
/// let setup = RunSetup::prepare(LoadedScenario::embedded_default(&[]).unwrap()).unwrap();
/// let result = Run::new(&setup, Method::NoFt).seed(3).execute().unwrap();
/// println!("{}: {}", result.method, result.outcome.name());
/// ```
pub struct Run<'a> {
    setup: &'a RunSetup,
    what: What,
    seed: u64,
    calibration: Option<&'a Calibration>,
    observers: Observers<'a>,
}

impl<'a> Run<'a> {
    /// `method` on the scenario with its own seed.
    pub fn new(setup: &'a RunSetup, method: Method) -> Self {
        Self {
            seed: setup.scenario().seed,
            setup,
            what: What::Method(method),
            calibration: None,
            observers: Observers::new(),
        }
    }

    /// An estimator and a precision method of the caller's, through the same loop; `label`
    /// names them in the result.
    pub fn with_parts(setup: &'a RunSetup, label: &str, parts: MethodParts) -> Self {
        Self {
            seed: setup.scenario().seed,
            setup,
            what: What::Parts(label.to_string(), parts),
            calibration: None,
            observers: Observers::new(),
        }
    }

    /// The sensor-noise (and model-error) seed.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// The detector's calibration (methods with a detector need one).
    pub fn calibration(mut self, calibration: Option<&'a Calibration>) -> Self {
        self.calibration = calibration;
        self
    }

    /// One more observer, seeing the ticks `mode` says.
    pub fn observe(mut self, observer: &'a mut dyn Observer, mode: ObserverMode) -> Self {
        self.observers.push(observer, mode);
        self
    }

    /// The label results carry.
    pub fn label(&self) -> &str {
        match &self.what {
            What::Method(m) => m.name(),
            What::Parts(label, _) => label,
        }
    }

    /// The method run (None for parts of the caller's).
    pub fn method(&self) -> Option<Method> {
        match &self.what {
            What::Method(m) => Some(*m),
            What::Parts(..) => None,
        }
    }

    pub fn setup(&self) -> &'a RunSetup {
        self.setup
    }

    /// The detector calibration given to the run.
    pub fn calibration_given(&self) -> Option<&'a Calibration> {
        self.calibration
    }

    /// The simulation at tick 0, to step by hand ([`Simulation::decide`], [`Simulation::actuate`]);
    /// the observers are not used.
    pub fn simulation(self) -> Result<Simulation, ScenarioError> {
        match self.what {
            What::Method(m) => Simulation::new(self.setup, m, self.seed, self.calibration),
            What::Parts(_, parts) => Simulation::from_parts(self.setup, self.seed, parts),
        }
    }

    /// Runs the scenario to its end (or until an observer stops it) and measures it.
    pub fn execute(self) -> Result<RunResult, ScenarioError> {
        self.execute_with(&mut Observers::new())
    }

    /// As [`Self::execute`], with more observers that need not outlive the run's builder
    /// (a caller's locals: a run folder's writers).
    pub fn execute_with(self, extra: &mut Observers<'_>) -> Result<RunResult, ScenarioError> {
        let setup = self.setup;
        let seed = self.seed;
        let label = self.label().to_string();
        let mut observers = self.observers;
        let mut sim = match self.what {
            What::Method(m) => Simulation::new(setup, m, seed, self.calibration)?,
            What::Parts(_, parts) => Simulation::from_parts(setup, seed, parts)?,
        };
        let mut metrics = RunMetrics::new(setup, sim.nominal());
        let mut guard = DivergenceGuard::default();
        let mut chatter = ChatterMonitor::new(setup.scenario().dt, setup.model.joints.len());
        let start = RunStart {
            setup,
            label: &label,
            seed,
            ticks: sim.ticks(),
        };
        observers.init(&start);
        extra.init(&start);
        let mut outcome = Outcome::Completed;
        let clock = Instant::now();
        for k in 0..sim.ticks() {
            sim.decide(None);
            let record = sim.record();
            observers.iter(&record);
            extra.iter(&record);
            metrics.iter(&record);
            guard.iter(&record);
            chatter.iter(&record);
            if let Some(StopReason::Diverged(reason)) = guard.stop() {
                outcome = Outcome::Diverged { tick: k, reason };
                break;
            }
            if let Some(reason) = observers.stop().or_else(|| extra.stop()) {
                outcome = Outcome::Stopped { tick: k, reason };
                break;
            }
            if k % STOP_CHECK_TICKS == 0 && all_runs_stopping() {
                outcome = Outcome::Stopped {
                    tick: k,
                    reason: StopReason::Interrupted,
                };
                break;
            }
            sim.actuate(None);
        }
        let wall_seconds = clock.elapsed().as_secs_f64();
        if let (Outcome::Completed, Some(c)) = (&outcome, chatter.found()) {
            outcome = Outcome::Chattering(c);
        }
        observers.finish(&outcome);
        extra.finish(&outcome);
        let (q, _) = sim.arm().state();
        let max_contact_normal_force = sim.max_contact_normal_force();
        let mut result = metrics.finish(
            &label,
            seed,
            outcome,
            &q,
            RunDetectors {
                detection: sim.detection(),
                momentum: sim.momentum(),
                actuator_alarms: sim.actuator_alarms(),
            },
            wall_seconds,
        );
        result.max_contact_normal_force = max_contact_normal_force;
        Ok(result)
    }
}
