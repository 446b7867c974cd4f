//! One run of a scenario with one method and seed: the closed loop and its metrics.
//!
//! Per tick k (t = k dt): the sensors read the plant; the controller updates its belief with the
//! learner's precisions and computes the torques (its step is the simulation's step callback);
//! the detector tests the innovations; the learner learns from the residuals; observers see the
//! tick; the plant steps with the torques. Logging and plotting are observers, not part of the
//! loop.

use std::time::Instant;

use super::{Method, RunSetup, ScenarioError};
use crate::plant::Arm;
use crate::precision::{
    self, Bayes, Calibration, Detection, Detector, Deterministic, Fixed, Gradient, LearnerInput,
    Oracle, PrecisionLearner, Window,
};
use crate::sensors::{Camera, Channel, ChannelLayout, FaultTarget, Readings, SensorSuite};
use crate::uaic::Controller;

/// How a run ended. A diverged run is a result, not an error.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Completed,
    /// The state or belief left any sane range at `tick`.
    Diverged {
        tick: u64,
        reason: String,
    },
}

impl Outcome {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Completed => "completed",
            Self::Diverged { .. } => "diverged",
        }
    }
}

/// What observers see every tick.
#[derive(Debug)]
pub struct TickRecord<'a> {
    pub tick: u64,
    pub t: f64,
    pub q: &'a [f64],
    pub qd: &'a [f64],
    pub mu: &'a [f64],
    pub mu_p: &'a [f64],
    pub target: &'a [f64],
    pub torques: &'a [f64],
    pub readings: &'a Readings,
    /// Precisions used this tick.
    pub precisions: &'a [f64],
    pub nominal: &'a [f64],
    pub free_energy: f64,
    pub innovations: &'a [Option<f64>],
    pub detection: &'a Detection,
}

/// Watches a run tick by tick.
pub trait Observer {
    fn on_tick(&mut self, record: &TickRecord<'_>);
}

/// Observes nothing.
pub struct NoObserver;

impl Observer for NoObserver {
    fn on_tick(&mut self, _: &TickRecord<'_>) {}
}

/// Records every tick as a row of numbers (the trajectory file).
pub struct TrajectoryRecorder {
    pub header: Vec<String>,
    pub rows: Vec<Vec<f64>>,
    n_joints: usize,
}

impl TrajectoryRecorder {
    /// Columns: t, q_i, qd_i, mu_i, mu'_i, target_i, u_i, y_<channel> (NaN when missing),
    /// precision_<channel>, health_<channel>, F, alarm (0/1), d_enc, d_tach, d_cam (normalised
    /// detector distance, NaN when not evaluated).
    pub fn new(layout: ChannelLayout) -> Self {
        let n = layout.n_joints;
        let mut header = vec!["t".to_string()];
        for prefix in ["q", "qd", "mu", "mu_p", "target", "u"] {
            header.extend((1..=n).map(|i| format!("{prefix}{i}")));
        }
        for prefix in ["y", "precision", "health"] {
            header.extend(layout.channels().map(|c| format!("{prefix}_{}", c.name())));
        }
        header.extend(["F", "alarm", "d_enc", "d_tach", "d_cam"].map(String::from));
        Self {
            header,
            rows: Vec::new(),
            n_joints: n,
        }
    }

    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// Index of a column by name.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// A column's values.
    pub fn series(&self, name: &str) -> Option<Vec<f64>> {
        let c = self.column(name)?;
        Some(self.rows.iter().map(|r| r[c]).collect())
    }
}

impl Observer for TrajectoryRecorder {
    fn on_tick(&mut self, r: &TickRecord<'_>) {
        let mut row = Vec::with_capacity(self.header.len());
        row.push(r.t);
        for v in [r.q, r.qd, r.mu, r.mu_p, r.target, r.torques] {
            row.extend_from_slice(v);
        }
        row.extend(r.readings.values.iter().map(|v| v.unwrap_or(f64::NAN)));
        row.extend_from_slice(r.precisions);
        row.extend(
            r.precisions
                .iter()
                .zip(r.nominal)
                .map(|(w, n)| precision::health(*w, *n)),
        );
        row.push(r.free_energy);
        row.push(if r.detection.fired_tick.is_some() {
            1.0
        } else {
            0.0
        });
        row.extend(
            r.detection
                .normalised_distance
                .iter()
                .map(|d| d.unwrap_or(f64::NAN)),
        );
        self.rows.push(row);
    }
}

/// The numbers of one run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunResult {
    pub method: Method,
    pub seed: u64,
    pub outcome: Outcome,
    pub ticks_run: u64,
    /// MSE of (mu - q) per joint over the run.
    pub mse_per_joint: Vec<f64>,
    /// MSE per joint from the first fault's start (None without faults).
    pub mse_post_fault_per_joint: Option<Vec<f64>>,
    /// Joints whose encoder or tachometer has a fault.
    pub faulty_joints: Vec<usize>,
    /// Mean MSE over the faulty joints (None if none).
    pub mse_faulty: Option<f64>,
    /// Mean MSE over the other joints (None if none).
    pub mse_healthy: Option<f64>,
    /// |q(T) - final target| per joint.
    pub final_error_per_joint: Vec<f64>,
    pub max_final_error: f64,
    /// When the fault was detected (s): the detector's alarm, or for methods without a
    /// detector the first time a channel's health fell below 0.1.
    pub detected_at: Option<f64>,
    /// `detector` or `health<0.1` (how `detected_at` was found).
    pub detection_kind: &'static str,
    /// The channel found faulty (the detector's isolation, or the least healthy channel).
    pub isolated_channel: Option<String>,
    /// Whether the isolated channel is one a fault hit (None without faults or detection).
    pub isolation_correct: Option<bool>,
    /// A detection before any fault started (or in a run without faults).
    pub false_alarm: bool,
    /// Health per channel at the end.
    pub final_health: Vec<f64>,
    /// Lowest health per channel over the last 5 s.
    pub min_health_last_5s: Vec<f64>,
    /// Wall-clock time of the loop (s); the one non-deterministic number.
    pub wall_seconds: f64,
}

impl RunResult {
    pub fn ticks_per_second(&self) -> f64 {
        self.ticks_run as f64 / self.wall_seconds.max(1e-12)
    }
}

/// Nominal precision per channel: 1 / sigma^2 (0 for a noise-free channel is refused upstream:
/// such a channel gets a very large precision instead).
fn nominal_precisions(sigmas: &[f64]) -> Vec<f64> {
    sigmas
        .iter()
        .map(|s| if *s > 0.0 { 1.0 / (s * s) } else { 1e12 })
        .collect()
}

/// Channels hit by any fault, and the first fault's start tick.
fn fault_channels(setup: &RunSetup, layout: ChannelLayout) -> (Vec<usize>, Option<u64>) {
    let dt = setup.scenario().dt;
    let mut channels = Vec::new();
    let mut first: Option<u64> = None;
    for f in &setup.faults {
        for c in 0..layout.len() {
            if f.hits(&layout, c) && !channels.contains(&c) {
                channels.push(c);
            }
        }
        let tick = crate::sensors::faults::tick_at(f.start, dt);
        first = Some(first.map_or(tick, |t| t.min(tick)));
    }
    channels.sort_unstable();
    (channels, first)
}

fn make_learner(
    setup: &RunSetup,
    method: Method,
    nominal: &[f64],
    layout: ChannelLayout,
) -> Box<dyn PrecisionLearner> {
    let p = &setup.scenario().precision;
    let bounds = p.bounds();
    match method {
        Method::NoFt => Box::new(Fixed::new(nominal)),
        Method::PlAlways => Box::new(Gradient::new(
            nominal,
            p.kappa_zeta,
            p.correction,
            false,
            bounds,
        )),
        Method::PlDetect => Box::new(Gradient::new(
            nominal,
            p.kappa_zeta,
            p.correction,
            true,
            bounds,
        )),
        Method::Deterministic => Box::new(Deterministic::new(nominal)),
        Method::Bayes => Box::new(Bayes::new(nominal, p.rho, p.correction, bounds)),
        Method::Window => Box::new(Window::new(nominal, p.window, p.correction, bounds)),
        Method::Oracle => {
            let (channels, first) = fault_channels(setup, layout);
            Box::new(Oracle::new(nominal, channels, first.unwrap_or(u64::MAX)))
        }
    }
}

/// Runs `method` with sensor-noise seed `seed`. Methods with a detector need `calibration`.
pub fn run(
    setup: &RunSetup,
    method: Method,
    seed: u64,
    calibration: Option<&Calibration>,
    observer: &mut dyn Observer,
) -> Result<RunResult, ScenarioError> {
    let sc = setup.scenario();
    let mut arm = Arm::new((*setup.model).clone(), setup.arm_options())?;
    let n = arm.n_joints();
    let layout = ChannelLayout::new(n);
    let dt = sc.dt;
    let ticks = sc.ticks();

    let mut sensors = SensorSuite::new(
        layout,
        &sc.sensors,
        Camera::new(sc.camera.clone()),
        &setup.faults,
        dt,
        seed,
    );
    let nominal = sc
        .precision
        .nominal
        .clone()
        .unwrap_or_else(|| nominal_precisions(sensors.sigmas()));
    let mut controller = Controller::new(sc.controller.clone(), layout, setup.gp.clone(), dt);
    let mut learner = make_learner(setup, method, &nominal, layout);
    let mut detector = match (method.needs_detector(), calibration) {
        (false, _) => None,
        (true, Some(cal)) => {
            if cal.ticks < ticks as usize {
                return Err(ScenarioError::Calibration {
                    path: setup.loaded.path.clone(),
                    message: format!(
                        "the calibration covers {} ticks, the run has {ticks}",
                        cal.ticks
                    ),
                });
            }
            Some(Detector::new(cal, &sc.detector.config()))
        }
        (true, None) => {
            return Err(ScenarioError::Calibration {
                path: setup.loaded.path.clone(),
                message: format!("method {method} needs a detector calibration"),
            });
        }
    };
    let no_detection = Detection::default();

    let (faulty_channels, first_fault) = fault_channels(setup, layout);
    let faulty_joints: Vec<usize> = {
        let mut j: Vec<usize> = setup
            .faults
            .iter()
            .filter_map(|f| match f.target {
                FaultTarget::One(Channel::Encoder(i))
                | FaultTarget::One(Channel::Tachometer(i)) => Some(i),
                _ => None,
            })
            .collect();
        j.sort_unstable();
        j.dedup();
        j
    };

    let qd0 = sc.initial.qd.clone().unwrap_or_else(|| vec![0.0; n]);
    arm.set_state(&sc.initial.q, &qd0);
    let mut readings = Readings::missing(layout);
    let (mut q, mut qd) = (vec![0.0; n], vec![0.0; n]);
    let mut sq = vec![0.0; n];
    let mut sq_post = vec![0.0; n];
    let mut post_count = 0u64;
    let mut health_detect: Option<(u64, usize)> = None;
    let last_5s_from = ticks.saturating_sub((5.0 / dt).round() as u64);
    let mut min_health_last = vec![1.0f64; layout.len()];
    let mut precisions = nominal.clone();
    let mut outcome = Outcome::Completed;
    let mut ticks_run = 0;
    let start = Instant::now();

    for k in 0..ticks {
        let t = k as f64 * dt;
        let target = sc.target_at(t);
        sensors.read(&arm, k, &mut readings);
        precisions.copy_from_slice(learner.precisions());
        controller.step(&readings, target, &precisions);
        let report = controller.last_report();
        let detection = match detector.as_mut() {
            Some(d) => d.check(k, &report.innovations),
            None => &no_detection,
        };
        learner.update(&LearnerInput {
            tick: k,
            dt,
            residuals: &report.residuals,
            corrections: &report.corrections,
            detection,
        });
        arm.read_state(&mut q, &mut qd);
        let mu = controller.mu();
        let mu_p = controller.mu_p();
        observer.on_tick(&TickRecord {
            tick: k,
            t,
            q: &q,
            qd: &qd,
            mu,
            mu_p,
            target,
            torques: &report.torques,
            readings: &readings,
            precisions: &precisions,
            nominal: &nominal,
            free_energy: report.free_energy,
            innovations: &report.innovations,
            detection,
        });
        ticks_run = k + 1;
        for i in 0..n {
            let e = mu[i] - q[i];
            sq[i] += e * e;
            if first_fault.is_some_and(|f| k >= f) {
                sq_post[i] += e * e;
            }
        }
        if first_fault.is_some_and(|f| k >= f) {
            post_count += 1;
        }
        for (c, (w, nom)) in precisions.iter().zip(&nominal).enumerate() {
            let h = precision::health(*w, *nom);
            if health_detect.is_none() && h < 0.1 {
                health_detect = Some((k, c));
            }
            if k >= last_5s_from {
                min_health_last[c] = min_health_last[c].min(h);
            }
        }
        let insane = |v: &[f64], limit: f64| v.iter().any(|x| !x.is_finite() || x.abs() > limit);
        let diverged = if !report.finite {
            Some("the belief update became non-finite")
        } else if insane(&q, 1e3) || insane(&qd, 1e4) {
            Some("the arm's state left |q| <= 1e3 rad, |qd| <= 1e4 rad/s")
        } else if insane(mu, 1e3) || insane(mu_p, 1e4) {
            Some("the belief left |mu| <= 1e3 rad, |mu'| <= 1e4 rad/s")
        } else {
            None
        };
        if let Some(reason) = diverged {
            outcome = Outcome::Diverged {
                tick: k,
                reason: reason.to_string(),
            };
            break;
        }
        arm.set_torques(&report.torques);
        arm.step(dt);
    }
    let wall_seconds = start.elapsed().as_secs_f64();

    let count = ticks_run.max(1) as f64;
    let mse_per_joint: Vec<f64> = sq.iter().map(|s| s / count).collect();
    let mse_post_fault_per_joint = first_fault.map(|_| {
        sq_post
            .iter()
            .map(|s| {
                if post_count > 0 {
                    s / post_count as f64
                } else {
                    f64::NAN
                }
            })
            .collect()
    });
    let mean_over = |joints: &[usize]| {
        (!joints.is_empty())
            .then(|| joints.iter().map(|&j| mse_per_joint[j]).sum::<f64>() / joints.len() as f64)
    };
    let healthy_joints: Vec<usize> = (0..n).filter(|j| !faulty_joints.contains(j)).collect();
    arm.read_state(&mut q, &mut qd);
    let final_target = &sc.targets.last().expect("validated: one target at least").q;
    let final_error_per_joint: Vec<f64> = (0..n).map(|i| (q[i] - final_target[i]).abs()).collect();
    let max_final_error = final_error_per_joint
        .iter()
        .fold(0.0f64, |a, b| if b.is_nan() { f64::NAN } else { a.max(*b) });

    let detector_state = detector.as_ref().map(|d| d.state().clone());
    let (detected_at, detection_kind, isolated) = match &detector_state {
        Some(d) => (
            d.fired_tick.map(|k| k as f64 * dt),
            "detector",
            d.isolated.clone(),
        ),
        None => (
            health_detect.map(|(k, _)| k as f64 * dt),
            "health<0.1",
            health_detect.map(|(_, c)| vec![c]).unwrap_or_default(),
        ),
    };
    let detected_tick = detected_at.map(|t| (t / dt).round() as u64);
    let false_alarm = match (detected_tick, first_fault) {
        (Some(d), Some(f)) => d < f,
        (Some(_), None) => true,
        (None, _) => false,
    };
    let isolated_channel = (!isolated.is_empty()).then(|| {
        isolated
            .iter()
            .map(|&c| layout.channel(c).name())
            .collect::<Vec<_>>()
            .join("+")
    });
    let isolation_correct = (!isolated.is_empty() && !faulty_channels.is_empty())
        .then(|| isolated.iter().all(|c| faulty_channels.contains(c)));
    let final_health = precisions
        .iter()
        .zip(&nominal)
        .map(|(w, n)| precision::health(*w, *n))
        .collect();

    Ok(RunResult {
        method,
        seed,
        outcome,
        ticks_run,
        mse_faulty: mean_over(&faulty_joints),
        mse_healthy: mean_over(&healthy_joints),
        mse_per_joint,
        mse_post_fault_per_joint,
        faulty_joints,
        final_error_per_joint,
        max_final_error,
        detected_at,
        detection_kind,
        isolated_channel,
        isolation_correct,
        false_alarm,
        final_health,
        min_health_last_5s: min_health_last,
        wall_seconds,
    })
}
