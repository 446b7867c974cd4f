//! Actuator faults: what stands between the torque the controller commands and the torque the
//! joint receives.
//!
//! Per tick the commanded torques are clamped to the model's effort limits (what the controller
//! and every estimator believe was applied), then each acting actuator fault transforms its
//! joints' torques in file order; the plant clamps the result to the effort limits again. A
//! locked joint is held by a brake in the plant ([`super::Plant::set_brake`]) from the fault's
//! first tick until its end. docs/method.md, "Actuator faults".
//!
//! ```toml
//! [[actuator_faults]]
//! kind = "effectiveness"   # effectiveness, bias, dead, locked, saturation, intermittent
//! joint = 2                # 1-based; or a list: [1, 3]
//! start = 8.0              # s
//! end = 12.0               # s, optional
//! factor = 0.3             # the kind's own parameters
//! ```

use serde::{Deserialize, Serialize};

use super::Plant;
use crate::SettingError;
use crate::tick_at;

/// Longest period of an [`ActuatorFaultKind::Intermittent`] fault (s).
pub const MAX_ACTUATOR_PERIOD: f64 = 1e4;

/// What a fault does to a joint's torque, with its parameters (`kind = "..."` in a file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ActuatorFaultKind {
    /// Loss of effectiveness: the joint receives `factor` x the commanded torque.
    Effectiveness {
        /// Fraction of the commanded torque delivered, in [0, 1].
        factor: f64,
    },
    /// A constant torque (N m; N for a prismatic joint) added to the commanded one.
    Bias {
        /// The added torque.
        torque: f64,
    },
    /// A dead motor: the joint receives no torque.
    Dead {},
    /// A locked joint: a brake holds it where it is at the fault's first tick (the motor's
    /// torque is lost in the brake) until the fault ends.
    Locked {},
    /// Lowered saturation: the torque is clamped to +-`limit`.
    Saturation {
        /// The lowered limit (>= 0), in N m (N for a prismatic joint).
        limit: f64,
    },
    /// The motor cuts out: no torque for the first `duty` fraction of every `period` from the
    /// fault's start (at least one tick), the commanded torque for the rest.
    Intermittent {
        /// Length of one cycle (s), at least two ticks.
        period: f64,
        /// Fraction of each cycle without torque, in (0, 1).
        duty: f64,
    },
}

impl ActuatorFaultKind {
    /// The kind's name as written in files.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Effectiveness { .. } => "effectiveness",
            Self::Bias { .. } => "bias",
            Self::Dead {} => "dead",
            Self::Locked {} => "locked",
            Self::Saturation { .. } => "saturation",
            Self::Intermittent { .. } => "intermittent",
        }
    }

    /// Checks the parameters against the tick length `dt`; returns the offending one and why.
    pub fn validate(&self, dt: f64) -> Result<(), SettingError> {
        match *self {
            Self::Dead {} | Self::Locked {} => Ok(()),
            Self::Effectiveness { factor } => {
                if !(0.0..=1.0).contains(&factor) {
                    return Err(SettingError::new(
                        "factor",
                        format!("{factor} must be in [0, 1]"),
                    ));
                }
                Ok(())
            }
            Self::Bias { torque } => {
                if !(torque.is_finite() && torque.abs() <= 1e6) {
                    return Err(SettingError::new(
                        "torque",
                        format!("{torque} must be finite and at most 1e6 in size"),
                    ));
                }
                Ok(())
            }
            Self::Saturation { limit } => {
                if !(limit.is_finite() && (0.0..=1e6).contains(&limit)) {
                    return Err(SettingError::new(
                        "limit",
                        format!("{limit} must be in [0, 1e6]"),
                    ));
                }
                Ok(())
            }
            Self::Intermittent { period, duty } => {
                if !(period.is_finite() && period > 0.0 && period <= MAX_ACTUATOR_PERIOD) {
                    return Err(SettingError::new(
                        "period",
                        format!("{period} must be in (0, {MAX_ACTUATOR_PERIOD}] s"),
                    ));
                }
                if (period / dt).round() < 2.0 {
                    return Err(SettingError::new(
                        "period",
                        format!("{period} s must be at least two ticks of {dt} s"),
                    ));
                }
                if !(duty > 0.0 && duty < 1.0) {
                    return Err(SettingError::new(
                        "duty",
                        format!("{duty} must be in (0, 1)"),
                    ));
                }
                Ok(())
            }
        }
    }
}

/// Which joints a fault hits: one (1-based) or a list.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum JointSelection {
    One(usize),
    Many(Vec<usize>),
}

impl JointSelection {
    /// The joints as written (1-based), in order.
    pub fn joints(&self) -> Vec<usize> {
        match self {
            Self::One(j) => vec![*j],
            Self::Many(v) => v.clone(),
        }
    }
}

/// An actuator fault as written in a scenario file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ActuatorFaultSpec {
    /// The joint (1-based) whose actuator fails, or a list of them.
    pub joint: JointSelection,
    /// Start time (s).
    pub start: f64,
    /// End time (s); absent: until the run ends.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end: Option<f64>,
    #[serde(flatten)]
    pub kind: ActuatorFaultKind,
}

/// An actuator fault checked against an arm.
#[derive(Clone, Debug, PartialEq)]
pub struct ActuatorFault {
    /// Joints hit (0-based), sorted, without repeats.
    pub joints: Vec<usize>,
    pub kind: ActuatorFaultKind,
    pub start: f64,
    pub end: Option<f64>,
    /// `motor2`, `motor1+motor3`: for reports.
    pub label: String,
}

impl ActuatorFaultSpec {
    /// Checks the spec against an arm of `n_joints` joints and the tick length `dt` (s); on
    /// error returns the offending field and why.
    pub fn to_fault(&self, n_joints: usize, dt: f64) -> Result<ActuatorFault, SettingError> {
        let written = self.joint.joints();
        if written.is_empty() {
            return Err(SettingError::new("joint", "names no joint"));
        }
        if written.len() > 10_000 {
            return Err(SettingError::new("joint", "lists more than 10 000 joints"));
        }
        let mut joints = Vec::with_capacity(written.len());
        for &j in &written {
            if !(1..=n_joints).contains(&j) {
                return Err(SettingError::new(
                    "joint",
                    format!("{j} is not a joint of this arm (1..={n_joints}, 1-based)"),
                ));
            }
            joints.push(j - 1);
        }
        joints.sort_unstable();
        joints.dedup();
        crate::check_window(self.start, self.end)?;
        self.kind.validate(dt)?;
        let label = joints
            .iter()
            .map(|&j| motor_name(j))
            .collect::<Vec<_>>()
            .join("+");
        Ok(ActuatorFault {
            joints,
            kind: self.kind,
            start: self.start,
            end: self.end,
            label,
        })
    }
}

impl ActuatorFault {
    /// First tick the fault acts at.
    pub fn start_tick(&self, dt: f64) -> u64 {
        tick_at(self.start, dt)
    }

    /// First tick the fault no longer acts at (`None`: never ends).
    pub fn end_tick(&self, dt: f64) -> Option<u64> {
        self.end.map(|e| tick_at(e, dt))
    }

    /// Whether the fault acts at `tick`.
    pub fn active_at(&self, tick: u64, dt: f64) -> bool {
        tick >= self.start_tick(dt) && self.end_tick(dt).is_none_or(|e| tick < e)
    }
}

/// The actuator faults of a run, compiled: per tick, the torque each joint receives, and the
/// brakes of locked joints.
#[derive(Clone, Debug)]
pub struct Actuators {
    faults: Vec<(ActuatorFault, u64, Option<u64>, u64, u64)>,
    /// Whether each joint's brake is engaged (as last set on the plant).
    braked: Vec<bool>,
    want: Vec<bool>,
}

impl Actuators {
    /// The faults of a run of `n_joints` joints at tick length `dt`.
    pub fn new(faults: &[ActuatorFault], n_joints: usize, dt: f64) -> Self {
        let faults = faults
            .iter()
            .map(|f| {
                let (period, gap) = match f.kind {
                    ActuatorFaultKind::Intermittent { period, duty } => {
                        let p = ((period / dt).round() as u64).max(2);
                        (p, ((duty * p as f64).round() as u64).clamp(1, p - 1))
                    }
                    _ => (0, 0),
                };
                (f.clone(), f.start_tick(dt), f.end_tick(dt), period, gap)
            })
            .collect();
        Self {
            faults,
            braked: vec![false; n_joints],
            want: vec![false; n_joints],
        }
    }

    /// Whether the run has no actuator fault at all.
    pub fn is_empty(&self) -> bool {
        self.faults.is_empty()
    }

    /// The torque each joint receives at `tick` for the commanded torques `commanded`: into
    /// `believed` what the controller and the estimators take as applied (the commanded torques
    /// clamped to the model's effort limits), into `out` what the joint gets (the faults
    /// applied to that, clamped to the effort limits again).
    ///
    /// # Panics
    /// If a slice does not have one entry per joint.
    pub fn deliver(
        &self,
        tick: u64,
        model: &crate::arm::ArmModel,
        commanded: &[f64],
        believed: &mut [f64],
        out: &mut [f64],
    ) {
        super::clamp_to_effort(model, commanded, believed);
        out.copy_from_slice(believed);
        if self.faults.is_empty() {
            return;
        }
        for (f, start, end, period, gap) in &self.faults {
            if tick < *start || end.is_some_and(|e| tick >= e) {
                continue;
            }
            let since = tick - start;
            for &j in &f.joints {
                out[j] = match f.kind {
                    ActuatorFaultKind::Effectiveness { factor } => out[j] * factor,
                    ActuatorFaultKind::Bias { torque } => out[j] + torque,
                    ActuatorFaultKind::Dead {} => 0.0,
                    // The brake takes the torque; what the motor still does is recorded.
                    ActuatorFaultKind::Locked {} => out[j],
                    ActuatorFaultKind::Saturation { limit } => out[j].clamp(-limit, limit),
                    ActuatorFaultKind::Intermittent { .. } => {
                        if since % period < *gap {
                            0.0
                        } else {
                            out[j]
                        }
                    }
                };
            }
        }
        for (t, joint) in out.iter_mut().zip(&model.joints) {
            if let Some(e) = joint.effort {
                *t = t.clamp(-e, e);
            }
        }
    }

    /// Engages the brakes of joints locked at `tick` and releases the others' on the plant
    /// (a brake engages at the joint's position when it is set).
    pub fn set_brakes(&mut self, tick: u64, plant: &mut dyn Plant) {
        if self.faults.is_empty() {
            return;
        }
        self.want.fill(false);
        for (f, start, end, _, _) in &self.faults {
            if matches!(f.kind, ActuatorFaultKind::Locked {})
                && tick >= *start
                && end.is_none_or(|e| tick < e)
            {
                for &j in &f.joints {
                    self.want[j] = true;
                }
            }
        }
        for j in 0..self.braked.len() {
            if self.want[j] != self.braked[j] {
                plant.set_brake(j, self.want[j]);
                self.braked[j] = self.want[j];
            }
        }
    }
}

/// A joint's motor as summaries, trajectories and the Python API name it: `motor1` for joint 0.
pub fn motor_name(joint: usize) -> String {
    format!("motor{}", joint + 1)
}
