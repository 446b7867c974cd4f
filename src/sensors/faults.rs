//! Sensor faults: plain data (serde) for scenario files, compiled into per-tick actions.
//!
//! A fault acts on the noisy reading of one channel (or both camera coordinates) from its start
//! time until its optional end time. Several faults on one channel apply in file order.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{Channel, ChannelLayout};

/// A fault as written in a scenario file.
///
/// ```toml
/// [[faults]]
/// channel = "enc1"   # enc<i>, tach<i>, cam_u, cam_v or cam (both camera coordinates)
/// kind = "freeze"    # freeze, bias, drift, gain, noise, dropout, stuck, spikes
/// start = 8.0        # s
/// # end = 12.0       # s, optional
/// # offset (bias), rate (drift), factor (gain, noise), value (stuck),
/// # probability and magnitude (spikes)
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultSpec {
    pub channel: String,
    pub kind: String,
    pub start: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub factor: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub probability: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub magnitude: Option<f64>,
}

/// What a fault does to a reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaultKind {
    /// The reading stays at its value at the fault's first tick (the paper's fault).
    Freeze,
    /// A constant offset is added (the ECC camera fault is +0.04 m).
    Bias { offset: f64 },
    /// An offset growing at `rate` per second from the start.
    Drift { rate: f64 },
    /// The reading is scaled.
    Gain { factor: f64 },
    /// The noise's standard deviation is multiplied.
    Noise { factor: f64 },
    /// The reading is missing.
    Dropout,
    /// The reading is a constant.
    Stuck { value: f64 },
    /// With `probability` per tick, an outlier of size `magnitude` (random sign) is added.
    Spikes { probability: f64, magnitude: f64 },
}

/// Which channels a fault hits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultTarget {
    One(Channel),
    /// Both camera coordinates.
    Camera,
}

/// A validated fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fault {
    pub target: FaultTarget,
    pub kind: FaultKind,
    pub start: f64,
    pub end: Option<f64>,
}

impl FaultSpec {
    /// Checks the spec against an arm with `n_joints` joints; on error returns the offending
    /// field and why.
    pub fn to_fault(&self, n_joints: usize) -> Result<Fault, (&'static str, String)> {
        let target = if self.channel == "cam" {
            FaultTarget::Camera
        } else {
            FaultTarget::One(Channel::parse(&self.channel, n_joints).ok_or((
                "channel",
                format!(
                    "{:?} is not a channel of this arm (enc1..enc{n_joints}, tach1..tach{n_joints}, cam_u, cam_v, cam)",
                    self.channel
                ),
            ))?)
        };
        if !self.start.is_finite() || self.start < 0.0 {
            return Err(("start", "must be finite and >= 0".into()));
        }
        if let Some(end) = self.end
            && (!end.is_finite() || end <= self.start)
        {
            return Err(("end", "must be finite and after start".into()));
        }
        let need = |name: &'static str, v: Option<f64>| match v {
            Some(x) if x.is_finite() => Ok(x),
            Some(_) => Err((name, "must be finite".to_string())),
            None => Err((name, format!("is required for kind = {:?}", self.kind))),
        };
        let kind = match self.kind.as_str() {
            "freeze" => FaultKind::Freeze,
            "bias" => FaultKind::Bias {
                offset: need("offset", self.offset)?,
            },
            "drift" => FaultKind::Drift {
                rate: need("rate", self.rate)?,
            },
            "gain" => FaultKind::Gain {
                factor: need("factor", self.factor)?,
            },
            "noise" => {
                let factor = need("factor", self.factor)?;
                if factor < 0.0 {
                    return Err(("factor", "must be >= 0".into()));
                }
                FaultKind::Noise { factor }
            }
            "dropout" => FaultKind::Dropout,
            "stuck" => FaultKind::Stuck {
                value: need("value", self.value)?,
            },
            "spikes" => {
                let probability = need("probability", self.probability)?;
                if !(0.0..=1.0).contains(&probability) {
                    return Err(("probability", "must be in [0, 1]".into()));
                }
                FaultKind::Spikes {
                    probability,
                    magnitude: need("magnitude", self.magnitude)?,
                }
            }
            other => {
                return Err((
                    "kind",
                    format!(
                        "{other:?} is not a fault kind (freeze, bias, drift, gain, noise, dropout, stuck, spikes)"
                    ),
                ));
            }
        };
        // Parameters that the kind does not use are refused: a typo'd kind would hide them.
        let used: &[&str] = match kind {
            FaultKind::Bias { .. } => &["offset"],
            FaultKind::Drift { .. } => &["rate"],
            FaultKind::Gain { .. } | FaultKind::Noise { .. } => &["factor"],
            FaultKind::Stuck { .. } => &["value"],
            FaultKind::Spikes { .. } => &["probability", "magnitude"],
            FaultKind::Freeze | FaultKind::Dropout => &[],
        };
        for (name, v) in [
            ("offset", self.offset),
            ("rate", self.rate),
            ("factor", self.factor),
            ("value", self.value),
            ("probability", self.probability),
            ("magnitude", self.magnitude),
        ] {
            if v.is_some() && !used.contains(&name) {
                return Err((name, format!("is not used by kind = {:?}", self.kind)));
            }
        }
        Ok(Fault {
            target,
            kind,
            start: self.start,
            end: self.end,
        })
    }
}

impl Fault {
    /// Whether the fault hits channel index `c` of `layout`.
    pub fn hits(&self, layout: &ChannelLayout, c: usize) -> bool {
        match self.target {
            FaultTarget::One(ch) => layout.index(ch) == c,
            FaultTarget::Camera => matches!(layout.channel(c), Channel::Camera(_)),
        }
    }
}

/// The first tick at or after time `t` (robust to rounding of `t / dt`).
pub(crate) fn tick_at(t: f64, dt: f64) -> u64 {
    (t / dt - 1e-6).ceil().max(0.0) as u64
}

/// A fault compiled for a run: ticks, and the state it carries.
#[derive(Clone, Debug)]
pub(crate) struct ActiveFault {
    pub fault: Fault,
    start_tick: u64,
    end_tick: Option<u64>,
    /// Held values per channel for `Freeze` (None: not yet captured, or missing when captured).
    held: Vec<Option<Option<f64>>>,
    rng: ChaCha8Rng,
}

/// Stream ids of spike generators: far from the noise streams.
const SPIKE_STREAM_BASE: u64 = 1 << 32;

impl ActiveFault {
    pub fn new(fault: Fault, index: usize, n_channels: usize, dt: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(SPIKE_STREAM_BASE + index as u64);
        Self {
            fault,
            start_tick: tick_at(fault.start, dt),
            end_tick: fault.end.map(|e| tick_at(e, dt)),
            held: vec![None; n_channels],
            rng,
        }
    }

    pub fn active(&self, tick: u64) -> bool {
        tick >= self.start_tick && self.end_tick.is_none_or(|e| tick < e)
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
        match self.fault.kind {
            FaultKind::Freeze => *self.held[c].get_or_insert(reading),
            FaultKind::Bias { offset } => reading.map(|r| r + offset),
            FaultKind::Drift { rate } => {
                let elapsed = (tick - self.start_tick) as f64 * dt;
                reading.map(|r| r + rate * elapsed)
            }
            FaultKind::Gain { factor } => reading.map(|r| r * factor),
            FaultKind::Noise { factor } => reading.map(|r| r - noise + noise * factor),
            FaultKind::Dropout => None,
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
        }
    }

    /// Forgets the held value once the fault has ended (a freeze releases).
    pub fn release(&mut self, c: usize) {
        self.held[c] = None;
    }
}
