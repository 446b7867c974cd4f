//! The grid: a campaign file expanded into cells (arm x channel x kind x onset, pairs, healthy;
//! arm x joint x actuator kind x onset; disturbance cells).

use super::{CampaignConfig, ContactEntry, Onset, OnsetConfig};
use crate::plant::{ActuatorFaultSpec, DisturbanceSpec, JointSelection};
use crate::sensors::{ChannelSelection, FaultSpec};

/// One cell of the grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    /// Index into the campaign's arms.
    pub arm: usize,
    /// `healthy`, `enc1 freeze moving`, or a pair's label.
    pub label: String,
    /// The channel(s) at fault (empty for healthy cells).
    pub channel: String,
    /// The fault kind (`healthy`, `pair` for two-fault cells).
    pub kind: String,
    pub onset: Option<Onset>,
    /// Whether the second target is removed (the arm rests).
    pub rest: bool,
    pub faults: Vec<FaultSpec>,
    pub actuator_faults: Vec<ActuatorFaultSpec>,
    pub disturbances: Vec<DisturbanceSpec>,
    /// A table to touch (the cell runs on rapier).
    pub contact: Option<ContactEntry>,
}

impl Cell {
    /// No sensor fault, actuator fault, disturbance or contact.
    pub fn is_healthy(&self) -> bool {
        self.faults.is_empty()
            && self.actuator_faults.is_empty()
            && self.disturbances.is_empty()
            && self.contact.is_none()
    }

    /// A cell of sensor faults only (none of actuators or disturbances), or the healthy cell.
    fn sensor_cell(arm: usize, label: String, channel: String, kind: String) -> Self {
        Self {
            arm,
            label,
            channel,
            kind,
            onset: None,
            rest: false,
            faults: vec![],
            actuator_faults: vec![],
            disturbances: vec![],
            contact: None,
        }
    }
}

/// Expands the grid of `config` for arms with the given joint counts (validated against each
/// arm's layout by [`Campaign::load`]).
pub fn expand(config: &CampaignConfig, onsets: &OnsetConfig) -> Vec<Cell> {
    let mut cells = Vec::new();
    for (a, arm) in config.arms.iter().enumerate() {
        if config.healthy {
            cells.push(Cell::sensor_cell(
                a,
                "healthy".into(),
                String::new(),
                "healthy".into(),
            ));
        }
        let mut channels = Vec::new();
        for c in &config.channels {
            match c.as_str() {
                "enc*" => channels.extend(arm.joints.iter().map(|j| format!("enc{j}"))),
                "tach*" => channels.extend(arm.joints.iter().map(|j| format!("tach{j}"))),
                other => channels.push(other.to_string()),
            }
        }
        for kind in &config.kinds {
            for channel in &channels {
                for &onset in kind.onsets() {
                    let start = match onset {
                        Onset::Moving => onsets.moving,
                        Onset::Rest | Onset::RestThenMotion => onsets.rest,
                    };
                    let fault = FaultSpec {
                        channel: ChannelSelection::One(channel.clone()),
                        start,
                        end: None,
                        kind: kind.fault_kind(channel),
                    };
                    cells.push(Cell {
                        onset: Some(onset),
                        rest: onset == Onset::Rest,
                        faults: vec![fault.clone()],
                        ..Cell::sensor_cell(
                            a,
                            format!("{channel} {} {}", fault.kind.name(), onset.name()),
                            channel.clone(),
                            fault.kind.name().into(),
                        )
                    });
                }
            }
        }
        let first = arm.joints.first().copied().unwrap_or(1);
        for pair in &config.pairs {
            let faults: Vec<FaultSpec> = pair
                .faults
                .iter()
                .map(|f| {
                    let mut f = f.clone();
                    let sel: Vec<String> = f
                        .channel
                        .selectors()
                        .iter()
                        .map(|s| match *s {
                            "enc*" => format!("enc{first}"),
                            "tach*" => format!("tach{first}"),
                            other => other.to_string(),
                        })
                        .collect();
                    f.channel = if sel.len() == 1 {
                        ChannelSelection::One(sel[0].clone())
                    } else {
                        ChannelSelection::Many(sel)
                    };
                    f
                })
                .collect();
            let channel = faults
                .iter()
                .map(|f| f.channel.label())
                .collect::<Vec<_>>()
                .join(" then ");
            cells.push(Cell {
                faults,
                ..Cell::sensor_cell(a, pair.label.clone(), channel, "pair".into())
            });
        }
        for kind in &config.actuator_kinds {
            for &joint in &arm.joints {
                for &onset in &config.actuator_onsets {
                    let start = match onset {
                        Onset::Moving => onsets.moving,
                        Onset::Rest | Onset::RestThenMotion => onsets.rest,
                    };
                    let channel = format!("motor{joint}");
                    cells.push(Cell {
                        onset: Some(onset),
                        rest: onset == Onset::Rest,
                        actuator_faults: vec![ActuatorFaultSpec {
                            joint: JointSelection::One(joint),
                            start,
                            end: None,
                            kind: *kind,
                        }],
                        ..Cell::sensor_cell(
                            a,
                            format!("{channel} {} {}", kind.name(), onset.name()),
                            channel,
                            format!("actuator-{}", kind.name()),
                        )
                    });
                }
            }
        }
        for d in &config.disturbance_cells {
            cells.push(Cell {
                disturbances: d.disturbances.clone(),
                contact: d.contact.clone(),
                ..Cell::sensor_cell(a, d.label.clone(), String::new(), "disturbance".into())
            });
        }
    }
    cells
}
