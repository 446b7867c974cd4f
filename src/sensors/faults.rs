//! Sensor faults: typed data for scenario files, compiled into per-tick actions.
//!
//! A fault acts on the noisy readings of its channels from its start time until its optional
//! end time; a run may have any number of faults, overlapping or not. Several faults on one
//! channel apply in file order.
//!
//! ```toml
//! [[faults]]
//! kind = "bias"            # freeze, bias, drift, gain, noise, dropout, stuck, spikes,
//!                          # delayed, slow, intermittent, garbage
//! channel = "enc1"         # a channel, a group (enc, tach, cam) or a list: ["enc1", "cam"]
//! start = 8.0              # s
//! end = 12.0               # s, optional
//! offset = 0.04            # the kind's own parameters
//! ```

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::ChannelLayout;

/// What a fault does to a reading, with its parameters (`kind = "..."` in a file).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum FaultKind {
    /// The reading stays at its value at the fault's first tick (the paper's fault).
    Freeze {},
    /// A constant offset is added (the ECC camera fault is +0.04 m).
    Bias {
        /// Offset added to the reading, in the channel's unit (rad, rad/s, m).
        offset: f64,
    },
    /// An offset growing at `rate` per second from the start.
    Drift {
        /// Growth of the offset, in the channel's unit per second.
        rate: f64,
    },
    /// The reading is scaled by `factor`.
    Gain {
        /// Factor the reading is multiplied by.
        factor: f64,
    },
    /// The noise's standard deviation is multiplied by `factor`.
    Noise {
        /// Factor (>= 0) the noise's standard deviation is multiplied by.
        factor: f64,
    },
    /// The reading is missing.
    Dropout {},
    /// The reading is the constant `value`.
    Stuck {
        /// The constant reading, in the channel's unit.
        value: f64,
    },
    /// With `probability` per tick, an outlier of size `magnitude` (random sign) is added.
    Spikes {
        /// Probability of an outlier per tick, in [0, 1].
        probability: f64,
        /// Size of an outlier, in the channel's unit.
        magnitude: f64,
    },
    /// The reading is the one of `delay` seconds before (rounded up to whole ticks; missing
    /// when the run is younger than that). Latency on joint feedback.
    Delayed {
        /// Age of the reading delivered (s), at most 10 s and 100 000 ticks.
        delay: f64,
    },
    /// The reading is sampled at the fault's first tick and every `period` seconds after, and
    /// held between (a sensor updating at a lower rate).
    Slow {
        /// Time between fresh readings (s), at least two ticks.
        period: f64,
    },
    /// Dropout bursts: in each `period` from the fault's start, the reading is missing for the
    /// first `duty` fraction (at least one tick) and present for the rest.
    Intermittent {
        /// Length of one burst cycle (s), at least two ticks.
        period: f64,
        /// Fraction of each cycle without reading, in (0, 1).
        duty: f64,
    },
    /// The reading is uniform in [`low`, `high`] every tick, whatever the truth.
    Garbage {
        /// Lower end, in the channel's unit.
        low: f64,
        /// Upper end, in the channel's unit (> low).
        high: f64,
    },
}

/// Most readings the delayed faults of one run keep in all (delay ticks x channels, summed).
pub const MAX_DELAY_READINGS: u64 = 10_000_000;

/// Longest [`FaultKind::Delayed`] delay (s).
pub const MAX_DELAY: f64 = 10.0;
/// Most ticks a [`FaultKind::Delayed`] fault keeps per channel (its memory bound).
pub const MAX_DELAY_TICKS: u64 = 100_000;
/// Longest period of a [`FaultKind::Slow`] or [`FaultKind::Intermittent`] fault (s).
pub const MAX_PERIOD: f64 = 1e4;

impl FaultKind {
    /// The kind's name as written in files.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Freeze {} => "freeze",
            Self::Bias { .. } => "bias",
            Self::Drift { .. } => "drift",
            Self::Gain { .. } => "gain",
            Self::Noise { .. } => "noise",
            Self::Dropout {} => "dropout",
            Self::Stuck { .. } => "stuck",
            Self::Spikes { .. } => "spikes",
            Self::Delayed { .. } => "delayed",
            Self::Slow { .. } => "slow",
            Self::Intermittent { .. } => "intermittent",
            Self::Garbage { .. } => "garbage",
        }
    }

    /// Checks the parameters; returns the offending one and why.
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        let finite = |name: &'static str, v: f64| {
            if v.is_finite() && v.abs() <= 1e6 {
                Ok(())
            } else {
                Err(crate::SettingError::new(
                    name,
                    format!("{v} must be finite and at most 1e6 in size"),
                ))
            }
        };
        match *self {
            Self::Freeze {} | Self::Dropout {} => Ok(()),
            Self::Bias { offset } => finite("offset", offset),
            Self::Drift { rate } => finite("rate", rate),
            Self::Gain { factor } => finite("factor", factor),
            Self::Noise { factor } => {
                finite("factor", factor)?;
                if factor < 0.0 {
                    return Err(crate::SettingError::new("factor", "must be >= 0"));
                }
                Ok(())
            }
            Self::Stuck { value } => finite("value", value),
            Self::Spikes {
                probability,
                magnitude,
            } => {
                if !(0.0..=1.0).contains(&probability) {
                    return Err(crate::SettingError::new("probability", "must be in [0, 1]"));
                }
                finite("magnitude", magnitude)
            }
            Self::Delayed { delay } => {
                if !(delay.is_finite() && delay > 0.0 && delay <= MAX_DELAY) {
                    return Err(crate::SettingError::new(
                        "delay",
                        format!("{delay} must be in (0, {MAX_DELAY}] s"),
                    ));
                }
                Ok(())
            }
            Self::Slow { period } => check_period(period),
            Self::Intermittent { period, duty } => {
                check_period(period)?;
                if !(duty > 0.0 && duty < 1.0) {
                    return Err(crate::SettingError::new(
                        "duty",
                        format!("{duty} must be in (0, 1)"),
                    ));
                }
                Ok(())
            }
            Self::Garbage { low, high } => {
                finite("low", low)?;
                finite("high", high)?;
                if high <= low {
                    return Err(crate::SettingError::new(
                        "high",
                        format!("{high} must be greater than low ({low})"),
                    ));
                }
                Ok(())
            }
        }
    }

    /// Checks what depends on the tick length: a delay within [`MAX_DELAY_TICKS`] ticks, periods
    /// of at least two ticks.
    pub fn validate_at(&self, dt: f64) -> Result<(), crate::SettingError> {
        match *self {
            Self::Delayed { delay } => {
                let ticks = tick_at(delay, dt);
                if ticks > MAX_DELAY_TICKS {
                    return Err(crate::SettingError::new(
                        "delay",
                        format!("{delay} s is {ticks} ticks of {dt} s; at most {MAX_DELAY_TICKS}"),
                    ));
                }
                Ok(())
            }
            Self::Slow { period } | Self::Intermittent { period, .. } => {
                if period_ticks(period, dt) < 2 {
                    return Err(crate::SettingError::new(
                        "period",
                        format!("{period} s must be at least two ticks of {dt} s"),
                    ));
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }
}

fn check_period(period: f64) -> Result<(), crate::SettingError> {
    if !(period.is_finite() && period > 0.0 && period <= MAX_PERIOD) {
        return Err(crate::SettingError::new(
            "period",
            format!("{period} must be in (0, {MAX_PERIOD}] s"),
        ));
    }
    Ok(())
}

/// A period in whole ticks (rounded to the nearest).
fn period_ticks(period: f64, dt: f64) -> u64 {
    (period / dt).round().max(0.0) as u64
}

/// Which channels a fault hits: one selector or a list (`"enc1"`, `"cam"`, `["enc1", "tach1"]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum ChannelSelection {
    One(String),
    Many(Vec<String>),
}

impl ChannelSelection {
    /// The selectors, in order.
    pub fn selectors(&self) -> Vec<&str> {
        match self {
            Self::One(s) => vec![s.as_str()],
            Self::Many(v) => v.iter().map(String::as_str).collect(),
        }
    }

    /// A readable form: `enc1` or `enc1+cam`.
    pub fn label(&self) -> String {
        self.selectors().join("+")
    }
}

impl From<&str> for ChannelSelection {
    fn from(s: &str) -> Self {
        Self::One(s.to_string())
    }
}

/// A fault as written in a scenario file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FaultSpec {
    /// The channels hit: a channel (`enc1`, `tach2`, `cam_u`), a group (`enc`, `tach`, `cam`)
    /// or a list of them.
    pub channel: ChannelSelection,
    /// Start time (s).
    pub start: f64,
    /// End time (s); absent: until the run ends.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end: Option<f64>,
    #[serde(flatten)]
    pub kind: FaultKind,
}

/// A fault checked against an arm's channels.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    /// Channel indices hit, sorted, without repeats.
    pub channels: Vec<usize>,
    pub kind: FaultKind,
    pub start: f64,
    pub end: Option<f64>,
    /// The selection as written (for reports).
    pub label: String,
}

impl FaultSpec {
    /// Checks the spec against a layout and the tick length `dt` (s); on error returns the
    /// offending field and why.
    pub fn to_fault(&self, layout: &ChannelLayout, dt: f64) -> Result<Fault, crate::SettingError> {
        let selectors = self.channel.selectors();
        if selectors.is_empty() {
            return Err(crate::SettingError::new("channel", "names no channel"));
        }
        if selectors.len() > layout.len() {
            return Err(crate::SettingError::new(
                "channel",
                format!(
                    "lists {} selectors; the arm has {} channels",
                    selectors.len(),
                    layout.len()
                ),
            ));
        }
        let mut channels = Vec::new();
        for s in selectors {
            let hit = layout.select(s).ok_or_else(|| {
                crate::SettingError::new(
                    "channel",
                    format!(
                        "{s:?} is not a channel of this arm ({})",
                        layout.selector_help()
                    ),
                )
            })?;
            channels.extend(hit);
        }
        channels.sort_unstable();
        channels.dedup();
        crate::check_window(self.start, self.end)?;
        self.kind.validate()?;
        self.kind.validate_at(dt)?;
        Ok(Fault {
            channels,
            kind: self.kind,
            start: self.start,
            end: self.end,
            label: self.channel.label(),
        })
    }
}

impl Fault {
    /// Readings a delayed fault keeps (delay ticks + 1 per channel hit; 0 for other kinds).
    pub fn delay_readings(&self, dt: f64) -> u64 {
        match self.kind {
            FaultKind::Delayed { delay } => (tick_at(delay, dt) + 1) * self.channels.len() as u64,
            _ => 0,
        }
    }

    /// Whether the fault hits channel index `c`.
    pub fn hits(&self, c: usize) -> bool {
        self.channels.binary_search(&c).is_ok()
    }

    /// First tick the fault acts at.
    pub fn start_tick(&self, dt: f64) -> u64 {
        tick_at(self.start, dt)
    }

    /// Whether the fault acts at all in a run of `ticks` ticks (it starts before the end).
    pub fn acts_within(&self, ticks: u64, dt: f64) -> bool {
        self.start_tick(dt) < ticks
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

pub use crate::tick_at;

/// A fault compiled for a run: ticks, and the state it carries.
#[derive(Clone, Debug)]
pub(crate) struct ActiveFault {
    pub fault: Fault,
    start_tick: u64,
    end_tick: Option<u64>,
    /// Held values per channel for `Freeze` and `Slow` (None: not yet captured; the inner
    /// None: missing when captured).
    held: Vec<Option<Option<f64>>>,
    /// `Delayed`: the readings entering the fault over the last `delay_ticks + 1` ticks, per
    /// channel hit (kept every tick, acting or not, so the first delayed reading exists).
    history: Vec<std::collections::VecDeque<Option<f64>>>,
    delay_ticks: usize,
    /// `Slow` and `Intermittent`: the cycle and, for `Intermittent`, its missing part, in ticks.
    period_ticks: u64,
    gap_ticks: u64,
    rng: ChaCha8Rng,
}

/// Stream ids of spike and garbage generators: far from the noise streams.
const SPIKE_STREAM_BASE: u64 = 1 << 32;

impl ActiveFault {
    pub fn new(fault: Fault, index: usize, n_channels: usize, dt: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(SPIKE_STREAM_BASE + index as u64);
        let (delay_ticks, period_ticks, gap_ticks) = match fault.kind {
            FaultKind::Delayed { delay } => (tick_at(delay, dt) as usize, 0, 0),
            FaultKind::Slow { period } => (0, period_ticks(period, dt).max(2), 0),
            FaultKind::Intermittent { period, duty } => {
                let p = period_ticks(period, dt).max(2);
                let gap = ((duty * p as f64).round() as u64).clamp(1, p - 1);
                (0, p, gap)
            }
            _ => (0, 0, 0),
        };
        // Each delay line grows to delay_ticks + 1 as the readings come (the scenario bounds the
        // total over its faults: MAX_DELAY_READINGS).
        let history = if matches!(fault.kind, FaultKind::Delayed { .. }) {
            vec![std::collections::VecDeque::new(); n_channels]
        } else {
            Vec::new()
        };
        Self {
            start_tick: fault.start_tick(dt),
            end_tick: fault.end_tick(dt),
            fault,
            held: vec![None; n_channels],
            history,
            delay_ticks,
            period_ticks,
            gap_ticks,
            rng,
        }
    }

    pub fn active(&self, tick: u64) -> bool {
        tick >= self.start_tick && self.end_tick.is_none_or(|e| tick < e)
    }

    /// Shows the fault channel `c`'s reading at a tick, acting or not (a delay line must
    /// know the readings from before it starts).
    pub fn remember(&mut self, c: usize, reading: Option<f64>) {
        if let Some(h) = self.history.get_mut(c) {
            if h.len() == self.delay_ticks + 1 {
                h.pop_front();
            }
            h.push_back(reading);
        }
    }

    /// Applies the fault to channel `c` at `tick`. `noise` is this tick's noise sample in the
    /// reading; `reading` is the reading so far (after earlier faults).
    pub fn apply(
        &mut self,
        c: usize,
        tick: u64,
        dt: f64,
        noise: f64,
        reading: Option<f64>,
    ) -> Option<f64> {
        use rand::RngExt;
        let since = tick - self.start_tick;
        match self.fault.kind {
            FaultKind::Freeze {} => *self.held[c].get_or_insert(reading),
            FaultKind::Bias { offset } => reading.map(|r| r + offset),
            FaultKind::Drift { rate } => {
                let elapsed = since as f64 * dt;
                reading.map(|r| r + rate * elapsed)
            }
            FaultKind::Gain { factor } => reading.map(|r| r * factor),
            FaultKind::Noise { factor } => reading.map(|r| r - noise + noise * factor),
            FaultKind::Dropout {} => None,
            FaultKind::Stuck { value } => Some(value),
            FaultKind::Spikes {
                probability,
                magnitude,
            } => {
                // Two draws every tick, whether or not a spike fires: the stream stays aligned.
                let fire = self.rng.random::<f64>() < probability;
                let sign = if self.rng.random::<bool>() { 1.0 } else { -1.0 };
                reading.map(|r| if fire { r + sign * magnitude } else { r })
            }
            FaultKind::Delayed { .. } => {
                let h = &self.history[c];
                if h.len() == self.delay_ticks + 1 {
                    h[0]
                } else {
                    None
                }
            }
            FaultKind::Slow { .. } => {
                if since.is_multiple_of(self.period_ticks) {
                    self.held[c] = Some(reading);
                }
                self.held[c].flatten()
            }
            FaultKind::Intermittent { .. } => {
                if since % self.period_ticks < self.gap_ticks {
                    None
                } else {
                    reading
                }
            }
            FaultKind::Garbage { low, high } => {
                // One draw every tick: the stream stays aligned.
                let u = self.rng.random::<f64>();
                Some(low + (high - low) * u)
            }
        }
    }

    /// Forgets the held value once the fault has ended (a freeze releases).
    pub fn release(&mut self, c: usize) {
        self.held[c] = None;
    }
}
