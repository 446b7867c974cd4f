//! One run of a scenario with one method and seed: the closed loop, stepped by a
//! [`Simulation`] and watched by observers.
//!
//! Per tick k (t = k dt): the sensors read the plant; the estimator updates its belief with the
//! precisions the method left after tick k-1; f* and the action give the torques (this is the
//! simulation's step callback); the precision method learns from the tick (its detector, if it
//! has one, tests the innovations first); observers see the tick; the plant steps with the
//! torques. Metrics, divergence checks and trajectory recording are observers
//! ([`super::metrics`], [`super::trajectory`]), not part of the loop.

use std::time::Instant;

use super::method::MethodParts;
use super::metrics::{DivergenceGuard, RunMetrics, RunResult};
use super::{Method, RunSetup, ScenarioError};
use crate::control::Control;
use crate::estimation::{Estimate, Estimator, EstimatorInput};
use crate::plant::Plant;
use crate::precision::{Calibration, Detection, PrecisionInput, PrecisionMethod};
use crate::sensors::{Camera, ChannelLayout, Readings, SensorSuite};

/// How a run ended. A diverged run is a result, not an error.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Completed,
    /// The state or belief left any sane range at `tick`.
    Diverged {
        tick: u64,
        reason: String,
    },
    /// An observer asked the run to stop at `tick`.
    Stopped {
        tick: u64,
        reason: String,
    },
}

impl Outcome {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Completed => "completed",
            Self::Diverged { .. } => "diverged",
            Self::Stopped { .. } => "stopped",
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

/// Watches a run tick by tick.
pub trait Observer {
    fn on_tick(&mut self, record: &TickRecord<'_>);
    /// Asked after every tick: a reason to stop the run here, if any.
    fn stop(&self) -> Option<String> {
        None
    }
}

/// Observes nothing.
pub struct NoObserver;

impl Observer for NoObserver {
    fn on_tick(&mut self, _: &TickRecord<'_>) {}
}

/// Several observers, called in order.
pub struct Observers<'a>(pub Vec<&'a mut dyn Observer>);

impl Observer for Observers<'_> {
    fn on_tick(&mut self, record: &TickRecord<'_>) {
        for o in &mut self.0 {
            o.on_tick(record);
        }
    }
    fn stop(&self) -> Option<String> {
        self.0.iter().find_map(|o| o.stop())
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
    applied: Vec<f64>,
    torques: Vec<f64>,
    free_energy: f64,
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
            control: Control::new(&sc.controller.control()),
            readings: Readings::missing(&layout),
            precisions: nominal.clone(),
            nominal,
            q: vec![0.0; n],
            qd: vec![0.0; n],
            applied: vec![0.0; n],
            torques: vec![0.0; n],
            free_energy: f64::NAN,
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
        let estimate = self.estimator.update(&EstimatorInput {
            tick: k,
            readings: &self.readings,
            precisions: &self.precisions,
            applied_torques: &self.applied,
        });
        let finite = estimate.finite;
        let belief_energy = estimate.free_energy;
        let target = &self.targets[self.target].1;
        let torques =
            self.control
                .step(self.estimator.mu(), self.estimator.mu_p(), target, self.dt);
        self.torques.copy_from_slice(torques);
        if !finite {
            self.control.hold();
            self.torques.fill(0.0);
        }
        self.free_energy = belief_energy.map_or(f64::NAN, |f| f + self.control.free_energy());
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
            readings: &self.readings,
            precisions: &estimate.precisions_used,
            nominal: &self.nominal,
            free_energy: self.free_energy,
            estimate,
            detection: self.precision.detection(),
        }
    }

    /// Steps the plant one tick with the decided torques, or with `torques` when given
    /// (clamped to the URDF's effort limits either way).
    ///
    /// # Panics
    /// If [`Self::decide`] has not run for this tick, or `torques` has the wrong length.
    pub fn actuate(&mut self, torques: Option<&[f64]>) {
        assert!(self.decided, "actuate() before decide()");
        match torques {
            Some(u) => self.arm.set_torques(u),
            None => self.arm.set_torques(&self.torques),
        }
        self.arm.step(self.dt);
        self.applied.copy_from_slice(self.arm.torques());
        self.tick += 1;
        self.decided = false;
    }

    /// The detector's state, for methods that run one.
    pub fn detection(&self) -> Option<&Detection> {
        self.precision.detection()
    }
}

/// Runs `method` with sensor-noise seed `seed` over the scenario. Methods with a detector need
/// `calibration`.
pub fn run(
    setup: &RunSetup,
    method: Method,
    seed: u64,
    calibration: Option<&Calibration>,
    observer: &mut dyn Observer,
) -> Result<RunResult, ScenarioError> {
    let sim = Simulation::new(setup, method, seed, calibration)?;
    drive(setup, sim, method.name(), seed, observer)
}

/// Runs an estimator and a precision method of the caller's over the scenario, through the
/// same loop as [`run`]; `label` names them in the result.
pub fn run_parts(
    setup: &RunSetup,
    label: &str,
    seed: u64,
    parts: MethodParts,
    observer: &mut dyn Observer,
) -> Result<RunResult, ScenarioError> {
    let sim = Simulation::from_parts(setup, seed, parts)?;
    drive(setup, sim, label, seed, observer)
}

fn drive(
    setup: &RunSetup,
    mut sim: Simulation,
    label: &str,
    seed: u64,
    observer: &mut dyn Observer,
) -> Result<RunResult, ScenarioError> {
    let mut metrics = RunMetrics::new(setup, sim.nominal());
    let guard = DivergenceGuard;
    let mut outcome = Outcome::Completed;
    let start = Instant::now();
    for k in 0..sim.ticks() {
        sim.decide(None);
        let record = sim.record();
        observer.on_tick(&record);
        metrics.on_tick(&record);
        if let Some(reason) = guard.check(&record) {
            outcome = Outcome::Diverged { tick: k, reason };
            break;
        }
        if let Some(reason) = observer.stop() {
            outcome = Outcome::Stopped { tick: k, reason };
            break;
        }
        sim.actuate(None);
    }
    let wall_seconds = start.elapsed().as_secs_f64();
    let (mut q, mut qd) = (vec![0.0; setup.layout.n_joints()], vec![0.0; 0]);
    qd.resize(q.len(), 0.0);
    sim.arm().read_state(&mut q, &mut qd);
    Ok(metrics.finish(label, seed, outcome, &q, sim.detection(), wall_seconds))
}
