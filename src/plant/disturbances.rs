//! Disturbances that are not faults: a payload picked up or dropped, a push on a link. The
//! correct verdict for them is "no sensor or actuator fault" (docs/method.md, "Disturbances").
//!
//! ```toml
//! [[disturbances]]
//! kind = "payload"         # payload (mass, offset), push (force, offset)
//! link = "ee"              # the URDF link it acts on
//! start = 8.0              # s
//! end = 12.0               # s, optional (a payload dropped, a push released)
//! mass = 1.5               # kg
//! offset = [0.0, 0.0, 0.05]  # m, in the link's frame
//! ```

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::{ExternalForce, Plant};
use crate::SettingError;
use crate::arm::ArmModel;
use crate::tick_at;

/// Largest payload (kg) and push (N).
pub const MAX_PAYLOAD: f64 = 1e4;
pub const MAX_PUSH: f64 = 1e6;

/// What a disturbance does, with its parameters (`kind = "..."` in a file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum DisturbanceKind {
    /// A point mass attached to the link (picked up at `start`, dropped at `end`).
    Payload {
        /// Mass (kg), in (0, 1e4].
        mass: f64,
    },
    /// A constant force on the link from `start` to `end` (a push by a person, a pull).
    Push {
        /// Force (N) in the world frame: [x, y, z].
        force: Vec<f64>,
    },
}

impl DisturbanceKind {
    pub fn name(&self) -> &'static str {
        match self {
            Self::Payload { .. } => "payload",
            Self::Push { .. } => "push",
        }
    }

    fn validate(&self) -> Result<(), SettingError> {
        match self {
            &Self::Payload { mass } => {
                if !(mass.is_finite() && mass > 0.0 && mass <= MAX_PAYLOAD) {
                    return Err(SettingError::new(
                        "mass",
                        format!("{mass} must be in (0, {MAX_PAYLOAD}] kg"),
                    ));
                }
            }
            Self::Push { force } => {
                if force.len() != 3 {
                    return Err(SettingError::new(
                        "force",
                        format!("has {} components; give [x, y, z] (N)", force.len()),
                    ));
                }
                if !force.iter().all(|f| f.is_finite() && f.abs() <= MAX_PUSH) {
                    return Err(SettingError::new(
                        "force",
                        format!("{force:?}: each component finite and at most {MAX_PUSH} N"),
                    ));
                }
            }
        }
        Ok(())
    }
}

fn origin() -> Vec<f64> {
    vec![0.0; 3]
}

/// A disturbance as written in a scenario file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DisturbanceSpec {
    /// The URDF link it acts on (a link merged into its parent by a fixed joint is fine).
    pub link: String,
    /// Where on the link (m, in the link's frame): [x, y, z].
    #[serde(default = "origin")]
    pub offset: Vec<f64>,
    /// Start time (s).
    pub start: f64,
    /// End time (s); absent: until the run ends.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end: Option<f64>,
    #[serde(flatten)]
    pub kind: DisturbanceKind,
}

/// A disturbance checked against an arm: the body it acts on and the point in that body's frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Disturbance {
    pub body: usize,
    pub point: Vector3<f64>,
    pub kind: DisturbanceKind,
    pub start: f64,
    pub end: Option<f64>,
    /// `payload on ee`, for reports.
    pub label: String,
}

impl DisturbanceSpec {
    /// Checks the spec against an arm; on error returns the offending field and why.
    pub fn to_disturbance(&self, model: &ArmModel) -> Result<Disturbance, SettingError> {
        let frame = model.link(&self.link).ok_or_else(|| {
            SettingError::new("link", format!("{:?} is not a link of this arm", self.link))
        })?;
        if frame.body == 0 {
            return Err(SettingError::new(
                "link",
                format!("{:?} is fixed to the world: nothing moves", self.link),
            ));
        }
        if self.offset.len() != 3 {
            return Err(SettingError::new(
                "offset",
                format!("has {} components; give [x, y, z] (m)", self.offset.len()),
            ));
        }
        if !self.offset.iter().all(|v| v.is_finite() && v.abs() <= 1e3) {
            return Err(SettingError::new(
                "offset",
                "each component must be finite and at most 1e3 m",
            ));
        }
        crate::check_window(self.start, self.end)?;
        self.kind.validate()?;
        let point = frame
            .pose
            .transform_point(&Vector3::from_column_slice(&self.offset).into())
            .coords;
        Ok(Disturbance {
            body: frame.body,
            point,
            kind: self.kind.clone(),
            start: self.start,
            end: self.end,
            label: format!("{} on {}", self.kind.name(), self.link),
        })
    }
}

impl Disturbance {
    /// Whether it acts at `tick`.
    pub fn active_at(&self, tick: u64, dt: f64) -> bool {
        tick >= tick_at(self.start, dt) && self.end.is_none_or(|e| tick < tick_at(e, dt))
    }
}

/// Whether `tick` is in the window [start, end).
fn acts(&(start, end): &(u64, Option<u64>), tick: u64) -> bool {
    tick >= start && end.is_none_or(|e| tick < e)
}

/// The disturbances of a run, applied to the plant tick by tick.
#[derive(Clone, Debug)]
pub struct Disturbances {
    items: Vec<Disturbance>,
    /// Each item's first tick and first tick after it (None: until the end).
    windows: Vec<(u64, Option<u64>)>,
    /// Per body: the payload (mass, centroid) last set on the plant.
    payloads: Vec<Option<(f64, Vector3<f64>)>>,
    forces: Vec<ExternalForce>,
    pushing: bool,
}

impl Disturbances {
    pub fn new(items: &[Disturbance], bodies: usize, dt: f64) -> Self {
        Self {
            windows: items
                .iter()
                .map(|d| (tick_at(d.start, dt), d.end.map(|e| tick_at(e, dt))))
                .collect(),
            items: items.to_vec(),
            payloads: vec![None; bodies],
            forces: Vec::new(),
            pushing: false,
        }
    }

    /// Sets on the plant what acts at `tick`: every body's payloads (several on one body become
    /// one point mass at their centroid), and the pushes.
    pub fn apply(&mut self, tick: u64, plant: &mut dyn Plant) {
        if self.items.is_empty() {
            return;
        }
        for b in 1..self.payloads.len() {
            let mut mass = 0.0;
            let mut moment = Vector3::zeros();
            for (d, w) in self.items.iter().zip(&self.windows) {
                if let DisturbanceKind::Payload { mass: m } = d.kind
                    && d.body == b
                    && acts(w, tick)
                {
                    mass += m;
                    moment += d.point * m;
                }
            }
            let want = (mass > 0.0).then(|| (mass, moment / mass));
            if want != self.payloads[b] {
                plant.set_payload(b, want);
                self.payloads[b] = want;
            }
        }
        self.forces.clear();
        for (d, w) in self.items.iter().zip(&self.windows) {
            if let DisturbanceKind::Push { force } = &d.kind
                && acts(w, tick)
            {
                self.forces.push(ExternalForce {
                    body: d.body,
                    point: d.point,
                    force: Vector3::from_column_slice(force),
                });
            }
        }
        if !self.forces.is_empty() || self.pushing {
            plant.set_external_forces(&self.forces);
            self.pushing = !self.forces.is_empty();
        }
    }
}
