//! The grid: a campaign file expanded into cells (arm x channel x kind x onset, pairs, healthy).

use super::{CampaignConfig, Onset, OnsetConfig};
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
}

impl Cell {
    pub fn is_healthy(&self) -> bool {
        self.faults.is_empty()
    }
}

/// Expands the grid of `config` for arms with the given joint counts (validated against each
/// arm's layout by [`Campaign::load`]).
pub fn expand(config: &CampaignConfig, onsets: &OnsetConfig) -> Vec<Cell> {
    let mut cells = Vec::new();
    for (a, arm) in config.arms.iter().enumerate() {
        if config.healthy {
            cells.push(Cell {
                arm: a,
                label: "healthy".into(),
                channel: String::new(),
                kind: "healthy".into(),
                onset: None,
                rest: false,
                faults: vec![],
            });
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
                        arm: a,
                        label: format!("{channel} {} {}", fault.kind.name(), onset.name()),
                        channel: channel.clone(),
                        kind: fault.kind.name().into(),
                        onset: Some(onset),
                        rest: onset == Onset::Rest,
                        faults: vec![fault],
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
                arm: a,
                label: pair.label.clone(),
                channel,
                kind: "pair".into(),
                onset: None,
                rest: false,
                faults,
            });
        }
    }
    cells
}
