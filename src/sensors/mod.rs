//! Sensors and sensor faults: what the controller is allowed to see.
//!
//! Every control tick the [`SensorSuite`] reads the plant: an encoder and a tachometer per joint
//! (true value + Gaussian noise) and a camera that sees the end effector (docs/method.md,
//! "Sensors"). Each channel draws from its own noise stream, derived from the scenario seed and
//! the channel's identity only (ChaCha8 with a stream id per channel), so adding a channel or a
//! fault never changes another channel's noise. Faults ([`faults`]) then act on the noisy
//! readings. A reading can be missing (camera occluded, dropout): that is explicit in
//! [`Readings`].
//!
//! The [`ChannelLayout`] is the one place that knows which channels and sensor groups an arm has
//! and what they are called; every later stage (estimators, learners, detector, trajectory
//! columns, plots) asks it instead of assuming three groups or a two-output camera.

pub mod camera;
pub mod faults;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::arm::EndEffector;
use crate::plant::Plant;
pub use camera::{Camera, CameraConfig, CameraModel, NotSeen};
pub use faults::{
    ChannelSelection, Fault, FaultKind, FaultSpec, MAX_DELAY, MAX_DELAY_TICKS, MAX_PERIOD,
};

/// One sensory channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Channel {
    /// Joint position encoder of joint i (0-based).
    Encoder(usize),
    /// Joint velocity tachometer of joint i (0-based).
    Tachometer(usize),
    /// Camera output r (0-based: u, v for an image; x, y, z for a position tracker).
    Camera(usize),
}

/// A group of channels of one kind (the detector works per group).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum SensorGroup {
    Encoders,
    Tachometers,
    Camera,
}

impl SensorGroup {
    /// Short name: `enc`, `tach`, `cam`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Encoders => "enc",
            Self::Tachometers => "tach",
            Self::Camera => "cam",
        }
    }

    /// The group of a short name.
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "enc" => Some(Self::Encoders),
            "tach" => Some(Self::Tachometers),
            "cam" => Some(Self::Camera),
            _ => None,
        }
    }
}

impl Channel {
    /// The group the channel belongs to.
    pub fn group(self) -> SensorGroup {
        match self {
            Self::Encoder(_) => SensorGroup::Encoders,
            Self::Tachometer(_) => SensorGroup::Tachometers,
            Self::Camera(_) => SensorGroup::Camera,
        }
    }

    /// The joint a joint sensor measures (`None` for the camera).
    pub fn joint(self) -> Option<usize> {
        match self {
            Self::Encoder(i) | Self::Tachometer(i) => Some(i),
            Self::Camera(_) => None,
        }
    }

    /// The id of this channel's noise stream: depends on the channel alone.
    fn stream(self) -> u64 {
        match self {
            Self::Encoder(i) => 1_000 + i as u64,
            Self::Tachometer(i) => 2_000 + i as u64,
            Self::Camera(i) => 3_000 + i as u64,
        }
    }
}

/// The channels of an arm, in a fixed order: encoders 0..n, tachometers n..2n, then the
/// camera's outputs (2 for an image, 3 for a position tracker).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelLayout {
    n_joints: usize,
    camera: CameraModel,
}

/// Every group, in layout order.
const GROUPS: [SensorGroup; 3] = [
    SensorGroup::Encoders,
    SensorGroup::Tachometers,
    SensorGroup::Camera,
];

impl ChannelLayout {
    /// The layout of an arm with `n_joints` joints seen by a camera of kind `camera`.
    pub fn new(n_joints: usize, camera: CameraModel) -> Self {
        Self { n_joints, camera }
    }

    /// Number of joints (one encoder and one tachometer each).
    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// The camera's kind.
    pub fn camera_model(&self) -> CameraModel {
        self.camera
    }

    /// Number of camera outputs.
    pub fn camera_outputs(&self) -> usize {
        self.camera.outputs()
    }

    /// Number of channels.
    pub fn len(&self) -> usize {
        2 * self.n_joints + self.camera_outputs()
    }

    /// Always false (an arm has at least one joint).
    pub fn is_empty(&self) -> bool {
        false
    }

    pub fn channel(&self, index: usize) -> Channel {
        let n = self.n_joints;
        match index {
            i if i < n => Channel::Encoder(i),
            i if i < 2 * n => Channel::Tachometer(i - n),
            i => Channel::Camera(i - 2 * n),
        }
    }

    pub fn index(&self, channel: Channel) -> usize {
        match channel {
            Channel::Encoder(i) => i,
            Channel::Tachometer(i) => self.n_joints + i,
            Channel::Camera(i) => 2 * self.n_joints + i,
        }
    }

    /// Every channel in order.
    pub fn channels(&self) -> impl Iterator<Item = Channel> + '_ {
        (0..self.len()).map(|i| self.channel(i))
    }

    /// The sensor groups, in layout order.
    pub fn groups(&self) -> &'static [SensorGroup] {
        &GROUPS
    }

    /// Position of a group in [`Self::groups`].
    pub fn group_index(&self, group: SensorGroup) -> usize {
        self.groups()
            .iter()
            .position(|g| *g == group)
            .expect("every group is in the layout")
    }

    /// Channel indices of a group.
    pub fn group_range(&self, group: SensorGroup) -> std::ops::Range<usize> {
        let n = self.n_joints;
        match group {
            SensorGroup::Encoders => 0..n,
            SensorGroup::Tachometers => n..2 * n,
            SensorGroup::Camera => 2 * n..2 * n + self.camera_outputs(),
        }
    }

    /// The group of channel index `c`.
    pub fn group_of(&self, c: usize) -> SensorGroup {
        self.channel(c).group()
    }

    /// Short name used in files: `enc1`, `tach2`, `cam_u`, `cam_v` (joints 1-based; a position
    /// tracker's outputs are `cam_x`, `cam_y`, `cam_z`).
    pub fn name(&self, c: usize) -> String {
        match self.channel(c) {
            Channel::Encoder(i) => format!("enc{}", i + 1),
            Channel::Tachometer(i) => format!("tach{}", i + 1),
            Channel::Camera(r) => format!("cam_{}", self.camera.output_names()[r]),
        }
    }

    /// Every channel's name, in order.
    pub fn names(&self) -> Vec<String> {
        (0..self.len()).map(|c| self.name(c)).collect()
    }

    /// The channel index of a short name.
    pub fn parse(&self, name: &str) -> Option<usize> {
        let joint = |digits: &str| {
            digits
                .parse::<usize>()
                .ok()
                .filter(|&i| i >= 1 && i <= self.n_joints && !digits.starts_with('0'))
                .map(|i| i - 1)
        };
        if let Some(out) = name.strip_prefix("cam_") {
            return self
                .camera
                .output_names()
                .iter()
                .position(|o| *o == out)
                .map(|r| self.index(Channel::Camera(r)));
        }
        if let Some(d) = name.strip_prefix("enc") {
            joint(d).map(|i| self.index(Channel::Encoder(i)))
        } else if let Some(d) = name.strip_prefix("tach") {
            joint(d).map(|i| self.index(Channel::Tachometer(i)))
        } else {
            None
        }
    }

    /// Channels named by a selector: a channel name, or a group name (`enc`, `tach`, `cam`)
    /// for every channel of that group.
    pub fn select(&self, selector: &str) -> Option<Vec<usize>> {
        match SensorGroup::parse(selector) {
            Some(g) => Some(self.group_range(g).collect()),
            None => self.parse(selector).map(|c| vec![c]),
        }
    }

    /// What a selector may be, for messages.
    pub fn selector_help(&self) -> String {
        let n = self.n_joints;
        let cams: Vec<String> = self
            .camera
            .output_names()
            .iter()
            .map(|o| format!("cam_{o}"))
            .collect();
        format!(
            "enc1..enc{n}, tach1..tach{n}, {}, or a group: enc, tach, cam",
            cams.join(", ")
        )
    }
}

/// The nominal precision given to a noise-free channel (sigma = 0) in place of 1 / 0.
pub const NOISE_FREE_PRECISION: f64 = 1e12;

/// One tick's readings, one per channel in [`ChannelLayout`] order; `None` is missing.
#[derive(Clone, Debug, PartialEq)]
pub struct Readings {
    pub values: Vec<Option<f64>>,
}

impl Readings {
    /// All channels missing.
    pub fn missing(layout: &ChannelLayout) -> Self {
        Self {
            values: vec![None; layout.len()],
        }
    }

    pub fn get(&self, channel: usize) -> Option<f64> {
        self.values[channel]
    }
}

/// Noise levels. Defaults are the paper's: 0.001 for encoders and tachometers (rad, rad/s),
/// the camera as in [`CameraConfig`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Encoder noise standard deviation (rad).
    pub encoder_sigma: f64,
    /// Tachometer noise standard deviation (rad/s).
    pub tachometer_sigma: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            encoder_sigma: 1e-3,
            tachometer_sigma: 1e-3,
        }
    }
}

impl SensorConfig {
    /// Checks the values; on error returns the offending field and why.
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        for (name, v) in [
            ("encoder_sigma", self.encoder_sigma),
            ("tachometer_sigma", self.tachometer_sigma),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::SettingError::new(name, "must be finite and >= 0"));
            }
            if v > 1e3 {
                return Err(crate::SettingError::new(name, "must be <= 1e3"));
            }
        }
        Ok(())
    }
}

/// Reads the plant every tick: noise per channel, camera with occlusion, faults.
pub struct SensorSuite {
    layout: ChannelLayout,
    camera: Camera,
    /// The point the camera sees.
    ee: EndEffector,
    sigmas: Vec<f64>,
    rngs: Vec<ChaCha8Rng>,
    faults: Vec<faults::ActiveFault>,
    dt: f64,
    q: Vec<f64>,
    qd: Vec<f64>,
    image: Vec<f64>,
    truth: Vec<Option<f64>>,
    noise: Vec<f64>,
    /// Why the camera missed this tick, if it did.
    camera_miss: Option<NotSeen>,
}

impl SensorSuite {
    /// A suite for an arm with `layout.n_joints()` joints, sampled every `dt` seconds.
    ///
    /// # Panics
    /// If the camera's kind is not the layout's.
    pub fn new(
        layout: ChannelLayout,
        config: &SensorConfig,
        camera: Camera,
        ee: EndEffector,
        faults: &[Fault],
        dt: f64,
        seed: u64,
    ) -> Self {
        assert_eq!(
            camera.config().model,
            layout.camera_model(),
            "the camera is the layout's"
        );
        let sigmas: Vec<f64> = layout
            .channels()
            .map(|c| match c {
                Channel::Encoder(_) => config.encoder_sigma,
                Channel::Tachometer(_) => config.tachometer_sigma,
                Channel::Camera(_) => camera.config().sigma,
            })
            .collect();
        let rngs = layout
            .channels()
            .map(|c| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(c.stream());
                rng
            })
            .collect();
        let faults = faults
            .iter()
            .enumerate()
            .map(|(i, f)| faults::ActiveFault::new(f.clone(), i, layout.len(), dt, seed))
            .collect();
        let n = layout.n_joints();
        Self {
            layout,
            sigmas,
            rngs,
            faults,
            dt,
            q: vec![0.0; n],
            qd: vec![0.0; n],
            image: vec![0.0; layout.camera_outputs()],
            truth: vec![None; layout.len()],
            noise: vec![0.0; layout.len()],
            camera_miss: None,
            camera,
            ee,
        }
    }

    pub fn layout(&self) -> ChannelLayout {
        self.layout
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Nominal noise standard deviation per channel.
    pub fn sigmas(&self) -> &[f64] {
        &self.sigmas
    }

    /// Why the camera reading of the last tick is missing, if it is (faults aside).
    pub fn camera_miss(&self) -> Option<NotSeen> {
        self.camera_miss
    }

    /// The noise-free values of the last tick (`None` where the camera could not see).
    pub fn truth(&self) -> &[Option<f64>] {
        &self.truth
    }

    /// The noise sample of each channel at the last tick (before faults).
    pub fn noise(&self) -> &[f64] {
        &self.noise
    }

    /// Reads the plant at tick `tick` (time `tick * dt`) into `out`, without allocating.
    pub fn read(&mut self, arm: &dyn Plant, tick: u64, out: &mut Readings) {
        let n = self.layout.n_joints();
        arm.read_state(&mut self.q, &mut self.qd);
        for i in 0..n {
            self.truth[i] = Some(self.q[i]);
            self.truth[n + i] = Some(self.qd[i]);
        }
        let cams = self.layout.group_range(SensorGroup::Camera);
        match self.camera.observe(arm, &self.ee, &mut self.image) {
            Ok(()) => {
                for (c, v) in cams.zip(&self.image) {
                    self.truth[c] = Some(*v);
                }
                self.camera_miss = None;
            }
            Err(why) => {
                for c in cams {
                    self.truth[c] = None;
                }
                self.camera_miss = Some(why);
            }
        }
        for c in 0..self.layout.len() {
            // One draw per channel and tick, always: streams stay aligned whatever happens.
            let z: f64 = StandardNormal.sample(&mut self.rngs[c]);
            self.noise[c] = self.sigmas[c] * z;
            out.values[c] = self.truth[c].map(|t| t + self.noise[c]);
        }
        for fault in &mut self.faults {
            let active = fault.active(tick);
            for i in 0..fault.fault.channels.len() {
                let c = fault.fault.channels[i];
                fault.remember(c, out.values[c]);
                if active {
                    out.values[c] = fault.apply(c, tick, self.dt, self.noise[c], out.values[c]);
                } else {
                    fault.release(c);
                }
            }
        }
    }
}
