//! What a run is measured by: an observer of the loop that gathers the belief error, the
//! detections and each fault's outcome, and the divergence guard.
//!
//! A *detection* is an alarm of the method's detector, or, for methods without one, the moment a
//! channel's health falls below 0.1 (a reporting convention, not a threshold any method uses;
//! the channel counts again once its health has come back above 0.5). Per fault: the first
//! detection from its start (and before its end) gives the delay and the isolated channels;
//! the post-fault MSE is that of its joints (every joint for a camera fault) from its start to
//! its end. A detection while no fault acts (or within a second after one ended) is a false
//! alarm.

use super::RunSetup;
use super::runner::{DivergenceReason, Observer, Outcome, StopReason, TickRecord};
use crate::precision::{self, Detection};
use crate::sensors::{ChannelLayout, Fault};

/// Health below which a channel counts as detected faulty (methods without a detector).
pub const DETECTION_HEALTH: f64 = 0.1;
/// How long health must stay below [`DETECTION_HEALTH`] to count (s): a gate that rejects one
/// reading is not an alarm; an exclusion of 20 ms (20 ticks at 1 kHz) is. The detection's time is
/// the first tick below.
pub const DETECTION_DWELL: f64 = 0.02;
/// Health above which such a channel counts as recovered and may be detected again.
pub const RECOVERY_HEALTH: f64 = 0.5;
/// Longest list of detections a run keeps.
pub const MAX_DETECTIONS: usize = 10_000;

/// Health events room is made for at the start of a run, so that the first ones do not
/// allocate inside the loop (more grow the list, up to [`MAX_DETECTIONS`]).
const HEALTH_EVENTS_RESERVED: usize = 64;
/// The same for a method's own actuator alarms (`Simulation::actuator_alarms`).
pub const ACTUATOR_ALARMS_RESERVED: usize = 16;

/// Grace after a fault ends during which a detection is not a false alarm (s).
pub const FALSE_ALARM_GRACE: f64 = 1.0;

/// A detection: its time and the channels found faulty.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectionEvent {
    pub t: f64,
    pub channels: Vec<usize>,
}

/// How one fault of the scenario went.
#[derive(Clone, Debug, PartialEq)]
pub struct FaultOutcome {
    /// The fault's channels as written (`enc1`, `cam`, ...).
    pub label: String,
    /// The kind (`freeze`, `bias`, ...).
    pub kind: &'static str,
    pub start: f64,
    pub end: Option<f64>,
    /// Joints whose encoder or tachometer the fault hits (0-based).
    pub joints: Vec<usize>,
    /// The first detection at or after the start (and before the end).
    pub detected_at: Option<f64>,
    pub delay: Option<f64>,
    /// Channels that detection named, joined by `+`.
    pub isolated: Option<String>,
    /// Whether those channels are all the fault's.
    pub isolation_correct: Option<bool>,
    /// MSE of (mu - q) over the fault's joints (every joint for a camera fault) during the fault.
    pub mse_during: Option<f64>,
}

/// How one actuator fault of the scenario went: the sensor alarms it drew (each one a
/// misattribution), the belief's error while it acted, and the first actuator alarm of the
/// momentum observer and of the method itself (each when it runs).
#[derive(Clone, Debug, PartialEq)]
pub struct ActuatorOutcome {
    /// `motor2`, `motor1+motor3`.
    pub label: String,
    /// The kind (`locked`, `effectiveness`, ...).
    pub kind: &'static str,
    pub start: f64,
    pub end: Option<f64>,
    /// The joints whose actuators fail (0-based).
    pub joints: Vec<usize>,
    /// Sensor detections from its start until [`FALSE_ALARM_GRACE`] after its end (no sensor
    /// is at fault for them unless a sensor fault acts too).
    pub sensor_alarms: usize,
    /// MSE of (mu - q) over its joints while it acts.
    pub mse_during: Option<f64>,
    /// The momentum observer's first alarm from its start (before its end), when it runs.
    pub momentum_detected_at: Option<f64>,
    pub momentum_delay: Option<f64>,
    /// The joint (0-based) that alarm named.
    pub momentum_joint: Option<usize>,
    /// Whether that joint is one of the fault's.
    pub momentum_isolation_correct: Option<bool>,
    /// The method's own first actuator alarm from its start (before its end), when the method
    /// infers actuator health (the hybrid with `hybrid.actuators`); the same four as above.
    pub method_detected_at: Option<f64>,
    /// Seconds from the fault's start to that alarm.
    pub method_delay: Option<f64>,
    /// The joint (0-based) that alarm named.
    pub method_joint: Option<usize>,
    /// Whether that joint is one of the fault's.
    pub method_isolation_correct: Option<bool>,
}

/// How one disturbance (payload, push) went: the alarms it drew. Neither a sensor nor an
/// actuator is at fault, so every sensor alarm is a false one; a momentum alarm is a true
/// detection of an unexplained torque, but not of an actuator fault.
#[derive(Clone, Debug, PartialEq)]
pub struct DisturbanceOutcome {
    /// `payload on ee`, `push on link4`.
    pub label: String,
    pub kind: &'static str,
    pub start: f64,
    pub end: Option<f64>,
    /// Sensor detections from its start until [`FALSE_ALARM_GRACE`] after its end.
    pub sensor_alarms: usize,
    /// Momentum alarms over the same window (when the observer runs).
    pub momentum_alarms: usize,
    /// The method's own actuator alarms over the same window (when it infers actuator health,
    /// the hybrid with `hybrid.actuators`): false ones, as no actuator is at fault.
    pub actuator_alarms: usize,
}

/// What the momentum observer found in a run (`[momentum] enabled`).
#[derive(Clone, Debug, PartialEq)]
pub struct MomentumSummary {
    /// Thresholds per joint (None in the calibration runs that set them).
    pub thresholds: Option<Vec<f64>>,
    /// The largest |r_j| per joint over the run.
    pub largest: Vec<f64>,
    /// Alarms: time (s) and joint (0-based), in time order.
    pub alarms: Vec<(f64, usize)>,
    /// Alarms while no actuator fault acted (nor within [`FALSE_ALARM_GRACE`] after one).
    pub false_alarms: usize,
}

/// What looked for faults during a run, for [`RunMetrics::finish`].
#[derive(Clone, Copy, Default)]
pub struct RunDetectors<'a> {
    /// The precision method's detector, when it runs one.
    pub detection: Option<&'a Detection>,
    /// The momentum observer, when the scenario runs it.
    pub momentum: Option<&'a crate::precision::MomentumMonitor>,
    /// The method's own actuator alarms (tick, joint), when it infers actuator health.
    pub actuator_alarms: Option<&'a [(u64, usize)]>,
}

/// The numbers of one run.
#[derive(Clone, Debug, PartialEq)]
pub struct RunResult {
    /// The method's name (`pl-always`, or a custom estimator's label).
    pub method: String,
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
    /// Joint positions at the end.
    pub q_final: Vec<f64>,
    /// |q(T) - final target| per joint.
    pub final_error_per_joint: Vec<f64>,
    pub max_final_error: f64,
    /// The first detection (s).
    pub detected_at: Option<f64>,
    /// `detector` or `health<0.1` (how detections were found).
    pub detection_kind: &'static str,
    /// The channels the first detection named.
    pub isolated_channel: Option<String>,
    /// Whether those are channels a fault hit (None without faults or detection).
    pub isolation_correct: Option<bool>,
    /// The first detection came before any fault started (or the run has no faults).
    pub false_alarm: bool,
    /// Detections while no fault acted.
    pub false_alarms: usize,
    /// Every detection (at most [`MAX_DETECTIONS`]).
    pub detections: Vec<DetectionEvent>,
    /// One entry per fault of the scenario, in file order.
    pub faults: Vec<FaultOutcome>,
    /// One entry per actuator fault of the scenario (those that act), in file order.
    pub actuator_faults: Vec<ActuatorOutcome>,
    /// One entry per disturbance of the scenario (those that act), in file order.
    pub disturbances: Vec<DisturbanceOutcome>,
    /// The momentum observer's findings, when it runs.
    pub momentum: Option<MomentumSummary>,
    /// The method's own actuator alarms (time in s, joint 0-based), when it infers actuator
    /// health (the hybrid with `hybrid.actuators`); `None` for every other method.
    pub actuator_alarms: Option<Vec<(f64, usize)>>,
    /// Those of them while no actuator fault acted (nor within [`FALSE_ALARM_GRACE`] after one).
    pub actuator_false_alarms: usize,
    /// The largest force the obstacles exerted on the arm (N; 0 without contact).
    pub max_contact_normal_force: f64,
    /// Health per channel at the end.
    pub final_health: Vec<f64>,
    /// Lowest health per channel over the last 5 s.
    pub min_health_last_5s: Vec<f64>,
    /// Channel names, in layout order.
    pub channels: Vec<String>,
    /// Wall-clock time of the loop (s); the one non-deterministic number.
    pub wall_seconds: f64,
}

impl RunResult {
    pub fn ticks_per_second(&self) -> f64 {
        self.ticks_run as f64 / self.wall_seconds.max(1e-12)
    }
}

/// Joints whose encoder or tachometer a fault hits.
pub fn fault_joints(layout: &ChannelLayout, fault: &Fault) -> Vec<usize> {
    let mut j: Vec<usize> = fault
        .channels
        .iter()
        .filter_map(|&c| layout.channel(c).joint())
        .collect();
    j.sort_unstable();
    j.dedup();
    j
}

/// Per-fault accumulation.
struct FaultWindow {
    start: u64,
    end: Option<u64>,
    joints: Vec<usize>,
    sq: f64,
    count: u64,
}

/// The observer that measures a run.
pub struct RunMetrics {
    layout: ChannelLayout,
    dt: f64,
    faults: Vec<Fault>,
    windows: Vec<FaultWindow>,
    actuator_faults: Vec<crate::plant::ActuatorFault>,
    actuator_windows: Vec<FaultWindow>,
    disturbances: Vec<crate::plant::Disturbance>,
    faulty_channels: Vec<usize>,
    faulty_joints: Vec<usize>,
    first_fault: Option<u64>,
    /// The target schedule: the final error is taken against the target in force at the last
    /// tick run (a target scheduled after the run's end never acts).
    targets: Vec<super::config::Target>,
    sq: Vec<f64>,
    sq_post: Vec<f64>,
    post_count: u64,
    last_5s_from: u64,
    min_health_last: Vec<f64>,
    health: Vec<f64>,
    /// Health-based detections (methods without a detector), with each channel's arming.
    health_events: Vec<(u64, usize)>,
    alarms: Vec<HealthAlarm>,
    ticks_run: u64,
}

impl RunMetrics {
    pub fn new(setup: &RunSetup, nominal: &[f64]) -> Self {
        let sc = setup.scenario();
        let layout = setup.layout;
        let dt = sc.dt;
        let n = layout.n_joints();
        let ticks = sc.ticks();
        // Faults that start before the run ends (later ones never act: warned at set-up).
        let acting: Vec<Fault> = setup
            .faults
            .iter()
            .filter(|f| f.acts_within(ticks, dt))
            .cloned()
            .collect();
        let mut faulty_channels: Vec<usize> = acting
            .iter()
            .flat_map(|f| f.channels.iter().copied())
            .collect();
        faulty_channels.sort_unstable();
        faulty_channels.dedup();
        let mut faulty_joints: Vec<usize> = acting
            .iter()
            .flat_map(|f| fault_joints(&layout, f))
            .collect();
        faulty_joints.sort_unstable();
        faulty_joints.dedup();
        let windows = acting
            .iter()
            .map(|f| {
                let joints = fault_joints(&layout, f);
                FaultWindow {
                    start: f.start_tick(dt),
                    end: f.end_tick(dt),
                    joints: if joints.is_empty() {
                        (0..n).collect()
                    } else {
                        joints
                    },
                    sq: 0.0,
                    count: 0,
                }
            })
            .collect();
        let actuator_faults: Vec<crate::plant::ActuatorFault> = setup
            .actuator_faults
            .iter()
            .filter(|f| f.start_tick(dt) < ticks)
            .cloned()
            .collect();
        let actuator_windows = actuator_faults
            .iter()
            .map(|f| FaultWindow {
                start: f.start_tick(dt),
                end: f.end_tick(dt),
                joints: f.joints.clone(),
                sq: 0.0,
                count: 0,
            })
            .collect();
        let disturbances = setup
            .disturbances
            .iter()
            .filter(|d| crate::tick_at(d.start, dt) < ticks)
            .cloned()
            .collect();
        Self {
            layout,
            dt,
            actuator_windows,
            disturbances,
            // Sensor or actuator: a disturbance is not a fault.
            first_fault: acting
                .iter()
                .map(|f| f.start_tick(dt))
                .chain(actuator_faults.iter().map(|f| f.start_tick(dt)))
                .min(),
            faults: acting,
            actuator_faults,
            windows,
            faulty_channels,
            faulty_joints,
            targets: sc.targets.clone(),
            sq: vec![0.0; n],
            sq_post: vec![0.0; n],
            post_count: 0,
            last_5s_from: ticks.saturating_sub((5.0 / dt).round() as u64),
            min_health_last: vec![1.0; layout.len()],
            health: nominal.iter().map(|_| 1.0).collect(),
            health_events: Vec::with_capacity(HEALTH_EVENTS_RESERVED),
            alarms: vec![HealthAlarm::new(dt); layout.len()],
            ticks_run: 0,
        }
    }

    /// The run's result, given how it ended, the final joint positions, and the detector's and
    /// the momentum observer's states.
    pub fn finish(
        self,
        method: &str,
        seed: u64,
        outcome: Outcome,
        q_final: &[f64],
        found: RunDetectors<'_>,
        wall_seconds: f64,
    ) -> RunResult {
        let RunDetectors {
            detection,
            momentum,
            actuator_alarms,
        } = found;
        let n = self.layout.n_joints();
        let dt = self.dt;
        let count = self.ticks_run.max(1) as f64;
        let mse_per_joint: Vec<f64> = self.sq.iter().map(|s| s / count).collect();
        let mse_post_fault_per_joint = self.mse_post_fault();
        let mean_over = |joints: &[usize]| {
            (!joints.is_empty()).then(|| {
                joints.iter().map(|&j| mse_per_joint[j]).sum::<f64>() / joints.len() as f64
            })
        };
        let healthy_joints: Vec<usize> =
            (0..n).filter(|j| !self.faulty_joints.contains(j)).collect();
        let last_tick = self.ticks_run.saturating_sub(1) as f64 * dt;
        let final_target = super::config::target_in_force(&self.targets, last_tick);
        let final_error_per_joint: Vec<f64> = (0..n)
            .map(|i| (q_final[i] - final_target[i]).abs())
            .collect();
        let max_final_error = final_error_per_joint
            .iter()
            .fold(0.0f64, |a, b| if b.is_nan() { f64::NAN } else { a.max(*b) });

        // Detections: the detector's alarms, or health crossings.
        let (detection_kind, events) = self.detection_events(detection);
        let first = events.first();
        let detected_at = first.map(|(k, _)| *k as f64 * dt);
        // Sensor alarms judged against the sensor faults alone (an actuator fault is no reason
        // for one).
        let first_sensor_fault = self.faults.iter().map(|f| f.start_tick(dt)).min();
        let false_alarm = match (first, first_sensor_fault) {
            (Some((d, _)), Some(f)) => *d < f,
            (Some(_), None) => true,
            (None, _) => false,
        };
        let isolated_channel = first.map(|(_, c)| self.names(c)).filter(|s| !s.is_empty());
        let isolation_correct = first
            .filter(|(_, c)| !c.is_empty() && !self.faulty_channels.is_empty())
            .map(|(_, c)| c.iter().all(|c| self.faulty_channels.contains(c)));
        let false_alarms = self.false_alarms(&events);
        let faults = self.fault_outcomes(&events);
        let momentum_alarms: Vec<(u64, usize)> = momentum
            .map(|m| m.alarms().iter().map(|a| (a.tick, a.joint)).collect())
            .unwrap_or_default();
        let actuator_faults =
            self.actuator_outcomes(&events, &momentum_alarms, actuator_alarms.unwrap_or(&[]));
        let within = |alarms: &mut dyn Iterator<Item = u64>, d: &crate::plant::Disturbance| {
            let grace = (FALSE_ALARM_GRACE / dt).round() as u64;
            let start = crate::tick_at(d.start, dt);
            let end = d.end.map(|e| crate::tick_at(e, dt) + grace);
            alarms
                .filter(|k| *k >= start && end.is_none_or(|e| *k < e))
                .count()
        };
        let disturbances = self
            .disturbances
            .iter()
            .map(|d| DisturbanceOutcome {
                label: d.label.clone(),
                kind: d.kind.name(),
                start: d.start,
                end: d.end,
                sensor_alarms: within(&mut events.iter().map(|(k, _)| *k), d),
                momentum_alarms: within(&mut momentum_alarms.iter().map(|(k, _)| *k), d),
                actuator_alarms: within(
                    &mut actuator_alarms.unwrap_or(&[]).iter().map(|(k, _)| *k),
                    d,
                ),
            })
            .collect();
        let actuator_false_alarms = actuator_alarms.map_or(0, |a| self.outside_actuator_faults(a));
        let momentum = momentum.map(|m| MomentumSummary {
            thresholds: m.thresholds().map(<[f64]>::to_vec),
            largest: m.largest().to_vec(),
            alarms: momentum_alarms
                .iter()
                .map(|&(k, j)| (k as f64 * dt, j))
                .collect(),
            false_alarms: self.outside_actuator_faults(&momentum_alarms),
        });
        let detections = events
            .iter()
            .take(MAX_DETECTIONS)
            .map(|(k, c)| DetectionEvent {
                t: *k as f64 * dt,
                channels: c.clone(),
            })
            .collect();
        RunResult {
            method: method.to_string(),
            seed,
            outcome,
            ticks_run: self.ticks_run,
            mse_faulty: mean_over(&self.faulty_joints),
            mse_healthy: mean_over(&healthy_joints),
            mse_per_joint,
            mse_post_fault_per_joint,
            faulty_joints: self.faulty_joints,
            q_final: q_final.to_vec(),
            final_error_per_joint,
            max_final_error,
            detected_at,
            detection_kind,
            isolated_channel,
            isolation_correct,
            false_alarm,
            false_alarms,
            detections,
            faults,
            actuator_faults,
            disturbances,
            momentum,
            actuator_false_alarms,
            actuator_alarms: actuator_alarms
                .map(|a| a.iter().map(|&(k, j)| (k as f64 * dt, j)).collect()),
            max_contact_normal_force: 0.0,
            final_health: self.health,
            min_health_last_5s: self.min_health_last,
            channels: self.layout.names(),
            wall_seconds,
        }
    }

    /// Each joint's MSE from the first fault's start (None without a fault; NaN when the run
    /// ended before it).
    fn mse_post_fault(&self) -> Option<Vec<f64>> {
        self.first_fault.map(|_| {
            self.sq_post
                .iter()
                .map(|s| {
                    if self.post_count > 0 {
                        s / self.post_count as f64
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        })
    }

    /// The detections: the detector's alarms, or health crossings (methods without a detector).
    fn detection_events(
        &self,
        detection: Option<&Detection>,
    ) -> (&'static str, Vec<(u64, Vec<usize>)>) {
        match detection {
            Some(d) => (
                "detector",
                d.alarms
                    .iter()
                    .map(|a| (a.tick, a.channels.clone()))
                    .collect(),
            ),
            None => (
                "health<0.1",
                self.health_events
                    .iter()
                    .map(|&(k, c)| (k, vec![c]))
                    .collect(),
            ),
        }
    }

    /// Channel names joined by `+`.
    fn names(&self, channels: &[usize]) -> String {
        channels
            .iter()
            .map(|&c| self.layout.name(c))
            .collect::<Vec<_>>()
            .join("+")
    }

    /// Detections while no fault acts (nor within [`FALSE_ALARM_GRACE`] after one ended).
    fn false_alarms(&self, events: &[(u64, Vec<usize>)]) -> usize {
        let dt = self.dt;
        let grace = (FALSE_ALARM_GRACE / dt).round() as u64;
        events
            .iter()
            .filter(|(k, _)| {
                !self.faults.iter().any(|f| {
                    *k >= f.start_tick(dt) && f.end_tick(dt).is_none_or(|e| *k < e + grace)
                })
            })
            .count()
    }

    /// How each actuator fault went: the sensor alarms within it (and the grace after), the
    /// belief's MSE on its joints, the first alarm of the momentum observer and of the method's
    /// own actuator hypotheses within it.
    fn actuator_outcomes(
        &self,
        events: &[(u64, Vec<usize>)],
        momentum: &[(u64, usize)],
        method: &[(u64, usize)],
    ) -> Vec<ActuatorOutcome> {
        let grace = (FALSE_ALARM_GRACE / self.dt).round() as u64;
        let dt = self.dt;
        let first_within = |alarms: &[(u64, usize)], w: &FaultWindow| {
            alarms
                .iter()
                .find(|(k, _)| *k >= w.start && w.end.is_none_or(|e| *k < e))
                .copied()
        };
        self.actuator_faults
            .iter()
            .zip(&self.actuator_windows)
            .map(|(f, w)| {
                let hit = first_within(momentum, w);
                let own = first_within(method, w);
                (f, w, hit, own)
            })
            .map(|(f, w, hit, own)| ActuatorOutcome {
                momentum_detected_at: hit.map(|(k, _)| k as f64 * dt),
                momentum_delay: hit.map(|(k, _)| (k - w.start) as f64 * dt),
                momentum_joint: hit.map(|(_, j)| j),
                momentum_isolation_correct: hit.map(|(_, j)| f.joints.contains(&j)),
                method_detected_at: own.map(|(k, _)| k as f64 * dt),
                method_delay: own.map(|(k, _)| (k - w.start) as f64 * dt),
                method_joint: own.map(|(_, j)| j),
                method_isolation_correct: own.map(|(_, j)| f.joints.contains(&j)),
                label: f.label.clone(),
                kind: f.kind.name(),
                start: f.start,
                end: f.end,
                joints: f.joints.clone(),
                sensor_alarms: events
                    .iter()
                    .filter(|(k, _)| *k >= w.start && w.end.is_none_or(|e| *k < e + grace))
                    .count(),
                mse_during: (w.count > 0).then(|| w.sq / (w.count as f64 * w.joints.len() as f64)),
            })
            .collect()
    }

    /// Actuator alarms (the momentum observer's or the method's) while no actuator fault acts
    /// (nor within the grace after one ended).
    fn outside_actuator_faults(&self, alarms: &[(u64, usize)]) -> usize {
        let grace = (FALSE_ALARM_GRACE / self.dt).round() as u64;
        alarms
            .iter()
            .filter(|(k, _)| {
                !self
                    .actuator_windows
                    .iter()
                    .any(|w| *k >= w.start && w.end.is_none_or(|e| *k < e + grace))
            })
            .count()
    }

    /// How each fault went: the first detection within it, its isolation, the MSE while it acts.
    fn fault_outcomes(&self, events: &[(u64, Vec<usize>)]) -> Vec<FaultOutcome> {
        let dt = self.dt;
        self.faults
            .iter()
            .zip(&self.windows)
            .map(|(f, w)| {
                let hit = events
                    .iter()
                    .find(|(k, _)| *k >= w.start && w.end.is_none_or(|e| *k < e));
                FaultOutcome {
                    label: f.label.clone(),
                    kind: f.kind.name(),
                    start: f.start,
                    end: f.end,
                    joints: fault_joints(&self.layout, f),
                    detected_at: hit.map(|(k, _)| *k as f64 * dt),
                    delay: hit.map(|(k, _)| (*k - w.start) as f64 * dt),
                    isolated: hit.map(|(_, c)| self.names(c)),
                    isolation_correct: hit.map(|(_, c)| c.iter().all(|c| f.hits(*c))),
                    mse_during: (w.count > 0)
                        .then(|| w.sq / (w.count as f64 * w.joints.len() as f64)),
                }
            })
            .collect()
    }
}

impl Observer for RunMetrics {
    fn iter(&mut self, r: &TickRecord<'_>) {
        let k = r.tick;
        self.ticks_run = k + 1;
        let post = self.first_fault.is_some_and(|f| k >= f);
        for i in 0..self.sq.len() {
            let e = r.mu[i] - r.q[i];
            self.sq[i] += e * e;
            if post {
                self.sq_post[i] += e * e;
            }
        }
        if post {
            self.post_count += 1;
        }
        for w in self.windows.iter_mut().chain(&mut self.actuator_windows) {
            if k >= w.start && w.end.is_none_or(|e| k < e) {
                for &j in &w.joints {
                    let e = r.mu[j] - r.q[j];
                    w.sq += e * e;
                }
                w.count += 1;
            }
        }
        for (c, (w, nom)) in r.precisions.iter().zip(r.nominal).enumerate() {
            let h = precision::health(*w, *nom);
            self.health[c] = h;
            if let Some(since) = self.alarms[c].update(k, h)
                && self.health_events.len() < MAX_DETECTIONS
            {
                self.health_events.push((since, c));
            }
            if k >= self.last_5s_from {
                self.min_health_last[c] = self.min_health_last[c].min(h);
            }
        }
    }
}

/// The alarm rule on a health in [0, 1] (a channel's precision over its nominal, or one minus a
/// method's probability that an actuator failed): an alarm once it stays below
/// [`DETECTION_HEALTH`] for [`DETECTION_DWELL`], dated at the first tick below; re-armed once it
/// rises above [`RECOVERY_HEALTH`].
#[derive(Clone, Debug)]
pub struct HealthAlarm {
    armed: bool,
    below_since: Option<u64>,
    dwell: u64,
}

impl HealthAlarm {
    /// Armed, for ticks of `dt` seconds.
    pub fn new(dt: f64) -> Self {
        Self {
            armed: true,
            below_since: None,
            dwell: ((DETECTION_DWELL / dt).round() as u64).max(1),
        }
    }

    /// Feeds tick `k`'s health; returns the alarm's tick when one completes.
    pub fn update(&mut self, k: u64, health: f64) -> Option<u64> {
        if self.armed {
            if health < DETECTION_HEALTH {
                let since = *self.below_since.get_or_insert(k);
                if k + 1 - since >= self.dwell {
                    self.armed = false;
                    return Some(since);
                }
            } else {
                self.below_since = None;
            }
        } else if health > RECOVERY_HEALTH {
            self.armed = true;
            self.below_since = None;
        }
        None
    }
}

/// A method's own actuator alarms, one [`HealthAlarm`] per joint on the health 1 - P(failed)
/// the estimator infers ([`crate::estimation::Estimator::actuator_failure_probability`]); at
/// most [`MAX_DETECTIONS`] kept.
pub struct ActuatorAlarms {
    health: Vec<HealthAlarm>,
    /// (tick the health fell, joint), in time order.
    alarms: Vec<(u64, usize)>,
    inferred: bool,
}

impl ActuatorAlarms {
    /// For `n` joints and ticks of `dt` seconds.
    pub fn new(n: usize, dt: f64) -> Self {
        Self {
            health: vec![HealthAlarm::new(dt); n],
            alarms: Vec::with_capacity(ACTUATOR_ALARMS_RESERVED),
            inferred: false,
        }
    }

    /// Feeds tick `k`'s actuator health from `estimator` (nothing when it infers none).
    pub fn update(&mut self, k: u64, estimator: &dyn crate::estimation::Estimator) {
        for (i, alarm) in self.health.iter_mut().enumerate() {
            let Some(failed) = estimator.actuator_failure_probability(i) else {
                break;
            };
            self.inferred = true;
            if let Some(since) = alarm.update(k, 1.0 - failed)
                && self.alarms.len() < MAX_DETECTIONS
            {
                self.alarms.push((since, i));
            }
        }
    }

    /// The alarms (tick, joint), or `None` when the estimator inferred no actuator health.
    pub fn alarms(&self) -> Option<&[(u64, usize)]> {
        self.inferred.then_some(self.alarms.as_slice())
    }
}

/// A joint that oscillated near the tick rate: where, how fast, how large, from when.
#[derive(Clone, Debug, PartialEq)]
pub struct Chattering {
    /// The joint (0-based).
    pub joint: usize,
    /// The oscillation's frequency, from the rate of sign changes of the joint's acceleration.
    pub frequency_hz: f64,
    /// Half the mean change of the joint's velocity per tick over the window (rad/s).
    pub amplitude: f64,
    /// Start of the first window found chattering (s).
    pub since: f64,
}

impl Chattering {
    pub fn describe(&self) -> String {
        format!(
            "joint {} chatters at {:.0} Hz (velocity amplitude {:.2} rad/s) from {:.3} s",
            self.joint + 1,
            self.frequency_hz,
            self.amplitude,
            self.since
        )
    }
}

/// Finds a joint whose true velocity oscillates near the tick rate (docs/method.md, "Metrics"):
/// over consecutive windows of [`ChatterMonitor::WINDOW`] seconds, the velocity's change per
/// tick flips sign on at least [`ChatterMonitor::FLIPS`] of the ticks with a mean size of at
/// least 2 x [`ChatterMonitor::AMPLITUDE`], for [`ChatterMonitor::SUSTAIN`] windows in a row.
/// Smooth motion changes sign rarely; noise-driven jitter is orders of magnitude smaller.
#[derive(Clone, Debug)]
pub struct ChatterMonitor {
    dt: f64,
    window: u64,
    last_qd: Vec<f64>,
    last_change: Vec<f64>,
    flips: Vec<u64>,
    size: Vec<f64>,
    run: Vec<u32>,
    window_start: Vec<f64>,
    seen: u64,
    found: Option<Chattering>,
}

impl ChatterMonitor {
    /// Window length (s).
    pub const WINDOW: f64 = 0.05;
    /// Share of ticks in a window on which the change of velocity flips sign.
    pub const FLIPS: f64 = 0.8;
    /// Least oscillation amplitude of the velocity (rad/s).
    pub const AMPLITUDE: f64 = 0.05;
    /// Windows in a row.
    pub const SUSTAIN: u32 = 2;

    pub fn new(dt: f64, n: usize) -> Self {
        Self {
            dt,
            window: ((Self::WINDOW / dt).round() as u64).max(10),
            last_qd: vec![0.0; n],
            last_change: vec![0.0; n],
            flips: vec![0; n],
            size: vec![0.0; n],
            run: vec![0; n],
            window_start: vec![0.0; n],
            seen: 0,
            found: None,
        }
    }

    /// The first chattering joint found, if any.
    pub fn found(&self) -> Option<Chattering> {
        self.found.clone()
    }
}

impl Observer for ChatterMonitor {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.observe(r.t, r.qd);
    }
}

impl ChatterMonitor {
    /// One tick: the time and the joints' true velocity.
    pub fn observe(&mut self, t: f64, qd: &[f64]) {
        if self.found.is_some() {
            return;
        }
        let w = self.window;
        for (i, &qd) in qd.iter().enumerate() {
            let change = qd - self.last_qd[i];
            if self.seen >= 2 && change * self.last_change[i] < 0.0 {
                self.flips[i] += 1;
            }
            if self.seen >= 1 {
                self.size[i] += change.abs();
            }
            self.last_qd[i] = qd;
            self.last_change[i] = change;
        }
        self.seen += 1;
        if !self.seen.is_multiple_of(w) {
            return;
        }
        for i in 0..qd.len() {
            let share = self.flips[i] as f64 / w as f64;
            let amplitude = 0.5 * self.size[i] / w as f64;
            if share >= Self::FLIPS && amplitude >= Self::AMPLITUDE {
                if self.run[i] == 0 {
                    self.window_start[i] = t - (w - 1) as f64 * self.dt;
                }
                self.run[i] += 1;
                if self.run[i] >= Self::SUSTAIN && self.found.is_none() {
                    self.found = Some(Chattering {
                        joint: i,
                        frequency_hz: share / (2.0 * self.dt),
                        amplitude,
                        since: self.window_start[i].max(0.0),
                    });
                }
            } else {
                self.run[i] = 0;
            }
            self.flips[i] = 0;
            self.size[i] = 0.0;
        }
    }
}

/// Whether any value is not finite or beyond `limit` in size.
fn insane(v: &[f64], limit: f64) -> bool {
    v.iter().any(|x| !x.is_finite() || x.abs() > limit)
}

/// Stops a run whose state or belief leaves any sane range: an observer of every tick.
#[derive(Clone, Debug, Default)]
pub struct DivergenceGuard {
    diverged: Option<DivergenceReason>,
}

impl DivergenceGuard {
    /// Why the run must stop at this tick, if it must.
    pub fn check(r: &TickRecord<'_>) -> Option<DivergenceReason> {
        if !r.estimate.finite {
            Some(DivergenceReason::BeliefNonFinite)
        } else if insane(r.q, 1e3) || insane(r.qd, 1e4) {
            Some(DivergenceReason::StateOutOfRange)
        } else {
            Self::check_belief(r)
        }
    }

    /// The belief's part of [`Self::check`] (for a replay, which has no plant state).
    pub fn check_belief(r: &TickRecord<'_>) -> Option<DivergenceReason> {
        if !r.estimate.finite {
            Some(DivergenceReason::BeliefNonFinite)
        } else if insane(r.mu, 1e3) || insane(r.mu_p, 1e4) {
            Some(DivergenceReason::BeliefOutOfRange)
        } else {
            None
        }
    }
}

impl Observer for DivergenceGuard {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.diverged = self.diverged.or(Self::check(r));
    }
    fn stop(&self) -> Option<StopReason> {
        self.diverged.map(StopReason::Diverged)
    }
}

/// Step-response characteristics of one sampled response, by MATLAB's documented definitions
/// (Control System Toolbox `stepinfo(y, t, yfinal)`, yinit = 0; docs/campaigns.md, "The
/// authors' protocol").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepInfo {
    /// 100 max(0, max_t s (y(t) - yfinal)) / |yfinal|, s the sign of the step (%).
    pub overshoot: f64,
    /// The first time after which |y - yfinal| stays within threshold |yfinal|, the crossing
    /// between the last sample outside and the next interpolated linearly; `None` if the last
    /// sample is outside.
    pub settling_time: Option<f64>,
}

/// [`StepInfo`] of samples `y` at times j dt (j = 0, 1, ...) toward `yfinal` from yinit = 0.
/// A response with a non-finite sample (or a non-finite `yfinal`) has no overshoot (NaN) and
/// never settles; a zero step has a zero band, so it settles only where y equals yfinal exactly.
pub fn step_info(y: &[f64], dt: f64, yfinal: f64, threshold: f64) -> StepInfo {
    if !yfinal.is_finite() || y.iter().any(|v| !v.is_finite()) {
        return StepInfo {
            overshoot: f64::NAN,
            settling_time: None,
        };
    }
    let step = yfinal.abs();
    let s = if yfinal < 0.0 { -1.0 } else { 1.0 };
    let peak = y
        .iter()
        .map(|v| s * (v - yfinal))
        .fold(f64::NEG_INFINITY, f64::max);
    let overshoot = if step > 0.0 {
        (100.0 * peak / step).max(0.0)
    } else {
        0.0
    };
    let tol = threshold * step;
    let err = |j: usize| (y[j] - yfinal).abs();
    let settling_time = match (0..y.len()).rev().find(|&j| err(j) > tol) {
        None => Some(0.0),
        Some(j) if j + 1 == y.len() => None,
        Some(j) => {
            let (e0, e1) = (err(j), err(j + 1));
            Some(dt * (j as f64 + (e0 - tol) / (e0 - e1)))
        }
    };
    StepInfo {
        overshoot,
        settling_time,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn step_info_follows_matlabs_definitions_on_a_sampled_second_order_response() {
        // y = 1 - e^(-t) (cos 3t + sin 3t / 3): overshoot e^(-pi/3) = 35.09 %, peak at pi/3.
        let dt = 1e-3;
        let y: Vec<f64> = (0..20_001)
            .map(|j| {
                let t = j as f64 * dt;
                1.0 - (-t).exp() * ((3.0 * t).cos() + (3.0 * t).sin() / 3.0)
            })
            .collect();
        let info = super::step_info(&y, dt, 1.0, 0.005);
        let peak = (-std::f64::consts::PI / 3.0).exp() * 100.0;
        assert!((info.overshoot - peak).abs() < 1e-4, "{}", info.overshoot);
        // Settled: the envelope e^(-t) sqrt(1 + 1/9) falls under 0.5 % near t = 5.35 s; the
        // response crosses the band's edge last somewhere before that.
        let ts = info.settling_time.unwrap();
        let envelope = (1.0f64 + 1.0 / 9.0).sqrt();
        let bound = (envelope / 0.005).ln();
        assert!(
            ts <= bound && ts > bound - std::f64::consts::PI / 3.0,
            "{ts} vs {bound}"
        );
        // The crossing is interpolated: within the last sample outside and the next.
        let j = (ts / dt).floor() as usize;
        assert!((y[j] - 1.0).abs() > 0.005 && (y[j + 1] - 1.0).abs() <= 0.005);
        // A negative step is measured as MATLAB does, by its sign.
        let neg: Vec<f64> = y.iter().map(|v| -2.0 * v).collect();
        let n = super::step_info(&neg, dt, -2.0, 0.005);
        assert!((n.overshoot - info.overshoot).abs() < 1e-9);
        assert!((n.settling_time.unwrap() - ts).abs() < 1e-9);
        // Never settles if the last sample is outside; settled from the start if none is.
        assert_eq!(
            super::step_info(&[0.0, 0.5, 0.9], dt, 1.0, 0.005).settling_time,
            None
        );
        assert_eq!(
            super::step_info(&[1.0, 1.001], dt, 1.0, 0.005).settling_time,
            Some(0.0)
        );
        // A diverged response never settles.
        let broken = super::step_info(&[0.0, 0.5, f64::NAN], dt, 1.0, 0.005);
        assert!(broken.overshoot.is_nan() && broken.settling_time.is_none());
        assert_eq!(
            super::step_info(&[0.0, 1.0], dt, f64::NAN, 0.005).settling_time,
            None
        );
        // No overshoot for a response that stays short of the target.
        assert_eq!(
            super::step_info(&[0.0, 0.5, 0.99], dt, 1.0, 0.02).overshoot,
            0.0
        );
    }

    use super::ChatterMonitor;
    use rand::{RngExt, SeedableRng};

    fn run(dt: f64, seconds: f64, qd: impl Fn(u64, f64) -> [f64; 2]) -> ChatterMonitor {
        let mut m = ChatterMonitor::new(dt, 2);
        let ticks = (seconds / dt).round() as u64;
        for k in 0..ticks {
            let t = k as f64 * dt;
            m.observe(t, &qd(k, t));
        }
        m
    }

    #[test]
    fn an_oscillation_at_the_tick_rate_is_found_with_its_joint_frequency_and_amplitude() {
        let dt = 1e-3;
        // Joint 2 alternates +-0.3 rad/s around a slow motion from t = 0.4 s: Nyquist, 500 Hz.
        let m = run(dt, 1.0, |k, t| {
            let wobble = if t >= 0.4 {
                0.3 * if k % 2 == 0 { 1.0 } else { -1.0 }
            } else {
                0.0
            };
            [0.5 * t.sin(), 0.2 * t.cos() + wobble]
        });
        let c = m.found().expect("chattering found");
        assert_eq!(c.joint, 1);
        assert!((c.frequency_hz - 500.0).abs() < 30.0, "{c:?}");
        // Velocity swings by 0.6 rad/s per tick: amplitude 0.3.
        assert!((c.amplitude - 0.3).abs() < 0.02, "{c:?}");
        assert!(c.since >= 0.35 && c.since <= 0.45, "{c:?}");
    }

    #[test]
    fn smooth_motion_steps_and_small_noise_are_not_chattering() {
        let dt = 1e-3;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise: Vec<f64> = (0..2000).map(|_| rng.random_range(-1e-3..1e-3)).collect();
        let m = run(dt, 2.0, |k, t| {
            // A fast damped oscillation at 20 Hz, a velocity step, and tick-rate noise.
            let ring = 2.0 * (-3.0 * t).exp() * (2.0 * std::f64::consts::PI * 20.0 * t).sin();
            let step = if t > 1.0 { 1.0 } else { 0.0 };
            [ring + step, noise[k as usize]]
        });
        assert_eq!(m.found(), None);
    }

    #[test]
    fn a_short_burst_is_not_sustained() {
        let dt = 1e-3;
        // One window's worth (40 ms) of a large tick-rate oscillation: not two windows in a row.
        let m = run(dt, 1.0, |k, t| {
            let on = (0.5..0.54).contains(&t);
            [if on && k % 2 == 0 { 1.0 } else { 0.0 }, 0.0]
        });
        assert_eq!(m.found(), None);
    }

    #[test]
    fn a_slower_oscillation_is_not_chattering_but_one_at_half_the_tick_rate_is() {
        // Period of 4 ticks (+, +, -, -): the change flips on half the ticks only: not found;
        // period 2 ticks is the discrete-time instability the monitor is for.
        let dt = 2e-3;
        let m = run(dt, 1.0, |k, _| {
            [if (k / 2) % 2 == 0 { 0.5 } else { -0.5 }, 0.0]
        });
        assert_eq!(m.found(), None);
        let m = run(dt, 1.0, |k, _| [0.0, if k % 2 == 0 { 0.5 } else { -0.5 }]);
        let c = m.found().expect("found");
        assert!((c.frequency_hz - 250.0).abs() < 15.0, "{c:?}");
    }
}
