//! `hybrid`: the active-inference method meant to hold at every fault site (docs/method.md,
//! "The hybrid").
//!
//! The belief is the u-AIC's: Gauss-Newton descent on F with the paper's state prior (or, with
//! `hybrid.prior = "propagated"`, the state prior's precision propagated as a Kalman filter's
//! would be). When a hypothesis that drops a channel the belief has been using becomes the most
//! probable, the belief is re-anchored on that hypothesis' estimate, which never used it.
//!
//! The precisions are beliefs too. Each sensor's precision is a discrete latent state, healthy
//! (nominal) or failed (nominal / broad^2), inferred by Bayesian model comparison over a bank of
//! hypotheses about which channels have failed, each a Kalman filter on the same generative
//! model, scored every tick by its log evidence (the innovation log-likelihood, -F of its Laplace
//! model), with a Markov switching prior between hypotheses; a channel's precision is the
//! posterior expectation nominal x P(channel healthy). The camera fails as one (every output
//! `camera_broad` times its noise); `hybrid.camera = "gradient"` learns the camera's precision by
//! the seed paper's gradient rule instead and feeds it back into the bank.
//!
//! The bank is relative to a base hypothesis B (at first: nothing failed): B itself, B with one
//! channel's state toggled (one more failure, or the end of one) and, while B holds a failure, B
//! with its last-accepted failure swapped for another channel (a wrong first blame). When a
//! hypothesis has been the most probable for `resync_ticks`, the bank is rebased on it; so
//! several faults, starting and ending, are followed one decision at a time with 1 + 2K filters
//! at most (K channels that can fail).
//!
//! The bank's transition is the arm's own dynamics driven by the applied torques (default), or
//! the constant-velocity model (`hybrid.bank_model = "constant-velocity"`); the dynamics separate
//! a frozen encoder from a frozen tachometer on arms without heavy damping. Its process noise per
//! joint is max(`model_acceleration_noise`, `model_relative_error` x |predicted acceleration|), so
//! a hard acceleration the model gets slightly wrong is not read as every sensor failing, and the
//! masses can be scaled (`mass_scale`) to test model error; the model is evaluated at the most
//! probable hypothesis' estimate, for the first `resync_ticks` at the belief. A failed channel's
//! reading model is broad noise or, with weight `stuck_weight`, its last reading again: a frozen
//! or stuck sensor repeats its reading exactly and is dropped within a few ticks, also at rest.
//! When another hypothesis that holds failed a channel the last winner trusted becomes the
//! most probable and the belief lies outside its 3-sigma ellipsoid, the belief is re-anchored on
//! that hypothesis' estimate. Every `resync_ticks` the other hypotheses restart from the base,
//! except those the data favour (probability above what the switching prior alone gives them)
//! while nothing has failed, and the swaps the data favour while a failure is accepted (a swap
//! is the rival explanation of the accepted failure, and restarting it from the base, which has
//! followed the blamed channel's rival, would throw away the state that can win): so a failure
//! hypothesis that wins carries a recent estimate, and while a failure is accepted "is the
//! channel healthy from now on?" stays a live question (docs/method.md, "The hybrid").

use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::bank::{Floor, HypothesisBank};
use super::kalman::{CameraReference, Ekf};
use super::models::{ArmTransition, ConstantVelocity, ObservationModel, TransitionModel};
use super::uaic::{PriorMode, Uaic, UpdateScheme};
use super::{Estimate, Estimator, EstimatorInput};
use crate::sensors::{Channel, ChannelLayout, NOISE_FREE_PRECISION};

/// The bank's transition model.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum BankModel {
    /// Constant velocity with white acceleration noise (no model of the arm).
    ConstantVelocity,
    /// The arm's dynamics (the estimators' model, `[model]`) and applied torques.
    #[default]
    Dynamics,
}

/// The hybrid's state prior (`hybrid.prior`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum HybridPrior {
    /// The paper's fixed P_mu, P_mu'.
    #[default]
    Fixed,
    /// The propagated prior throughout.
    Propagated,
    /// Fixed while the winning hypothesis trusts every tachometer, propagated while it holds one
    /// failed.
    FixedUntilTachometerFails,
}

impl HybridPrior {
    /// The name a scenario gives it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Fixed => "fixed",
            Self::Propagated => "propagated",
            Self::FixedUntilTachometerFails => "fixed-until-tachometer-fails",
        }
    }

    /// Whether the u-AIC's propagated prior is ever used (it needs the Gauss-Newton update).
    pub fn may_propagate(self) -> bool {
        self != Self::Fixed
    }

    /// The u-AIC's prior at the start of a run.
    pub fn initial(self) -> PriorMode {
        match self {
            Self::Propagated => PriorMode::Propagated,
            Self::Fixed | Self::FixedUntilTachometerFails => PriorMode::Fixed,
        }
    }
}

/// How the hybrid sets the camera's precisions.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum CameraPrecision {
    /// A camera hypothesis in the bank (every output failed together, `camera_broad` times its
    /// noise); the camera's precision is nominal x P(not failed), like the joint sensors'.
    #[default]
    Bank,
    /// The seed paper's gradient rule on the u-AIC's camera residuals, fed back into the bank.
    Gradient,
}

/// Settings of `hybrid` (the `[hybrid]` section).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HybridConfig {
    /// The bank's transition: the arm's dynamics on the estimators' model with the process
    /// noise of `[model]` (default), or constant velocity at `belief.acceleration_bound`.
    pub bank_model: BankModel,
    /// Per-tick probability of leaving a hypothesis.
    pub switch: f64,
    /// A failed channel's noise standard deviation, as a multiple of its nominal.
    pub broad: f64,
    /// The bank's camera noise as a multiple of the camera's (room for the GP's own error).
    pub camera_inflation: f64,
    /// How the camera's precision is set.
    pub camera: CameraPrecision,
    /// The camera hypothesis' noise as a multiple of the camera's.
    pub camera_broad: f64,
    /// Re-anchor the belief when another hypothesis wins that holds failed a channel the last
    /// winner trusted, and the belief lies outside its 3-sigma ellipsoid.
    pub reanchor: bool,
    /// The belief's state prior (the hybrid's own; `belief.prior` sets the other u-AIC
    /// methods'): the u-AIC's fixed P_mu, P_mu' (the paper's), or the propagated prior
    /// (a Kalman filter's covariance; needs `belief.update = "gauss-newton"`). Measured in
    /// docs/method.md, "The hybrid": the propagated prior lowers the belief error of healthy
    /// runs by about a fifth, but it integrates a tachometer's scale error into the position,
    /// and once an encoder is dropped it leans on the camera model's bias. A third choice,
    /// `fixed-until-tachometer-fails`: the fixed prior while the bank's most probable hypothesis
    /// trusts every tachometer and every tachometer reads, the propagated one while it holds a
    /// tachometer failed or a tachometer's reading is missing (a dropout is no evidence against
    /// the sensor, so no hypothesis blames it, but the joint is as blind to velocity) (without
    /// its tachometer a joint's velocity comes from differences of encoder readings, which the
    /// fixed prior turns into a noisy mu' the PID's damping term amplifies on an undamped arm;
    /// measured in docs/method.md, "The hybrid"). Absent: `fixed-until-tachometer-fails` with
    /// `belief.update = "gauss-newton"`, `fixed` with the gradient update.
    pub prior: Option<HybridPrior>,
    /// The weight of "stuck at its last reading" in a failed channel's reading model: a failed
    /// reading is, with this probability, the last one again (to within `stuck_width`), else
    /// broad noise. A frozen or stuck sensor repeats its reading exactly, which healthy noise
    /// never does, so the failure is seen at once, also at rest where the reading is right;
    /// any other failure pays ln(1 - this) per tick. 0: broad noise only.
    pub stuck_weight: f64,
    /// The width of the stuck component, as a multiple of the channel's noise standard deviation
    /// (a quantised sensor needs at least its quantum). A noise-free channel (sigma = 0) has no
    /// stuck component: its healthy readings at rest repeat too.
    pub stuck_width: f64,
    /// A hypothesis that stays the most probable this many ticks becomes the bank's base; every
    /// this many ticks the other hypotheses restart from the base (while it holds a failure, so
    /// that they ask "is the channel healthy from now on?" and a fault that ends is seen to end;
    /// while nothing has failed, those the data do not favour); 0: never (the bank keeps H_0 and
    /// the one-channel failures, each from the start). For the first this many ticks the bank's
    /// model acceleration is taken at the u-AIC's belief (with 0: never).
    pub resync_ticks: u64,
    /// Actuator hypotheses in the bank (docs/method.md, "The hybrid", "Actuators and external
    /// torques"): beside the sensors, each joint's torque can be "not the commanded one" (its
    /// process noise `actuator_broad` times the model's), and one hypothesis holds an external
    /// torque on every joint at once (a push, a payload, a contact), so that an unexpected
    /// acceleration is explained as a torque, not as sensors failing. Off by default: measured
    /// in docs/method.md, it helps actuator faults and hurts tachometer spikes. Needs
    /// `model_error_state = false` (the state would explain a lasting torque error); measured
    /// with `model.inertial_budget = "shared-cosine"`, whose narrower budget at a target step
    /// detects a dead wrist motor in more seeds than `per-joint` (docs/method.md). (This and
    /// `actuator_broad` are written only when not the default, so that fingerprints of
    /// scenarios that do not set them stay as they were.)
    #[serde(skip_serializing_if = "is_false")]
    pub actuators: bool,
    /// An actuator hypothesis' process noise (standard deviation) as a multiple of the model's.
    #[serde(skip_serializing_if = "is_default_actuator_broad")]
    pub actuator_broad: f64,
    /// Every tick, the hypotheses the data have ruled out since their last restart and that
    /// trust a channel the most probable hypothesis holds failed are also run restarted from
    /// its mean, and the state this tick's readings favour is kept (the switching prior's
    /// better predecessor, judged with the data; docs/method.md, "The hybrid", revived
    /// hypotheses): a hypothesis revived by the switching prior cannot carry a mean that
    /// absorbed the fault it lost to (an encoder bias read as a tachometer failure), and one
    /// that is right where the winner is wrong keeps its own. On by default since 2026-12-06
    /// (measured in docs/method.md: 139 of 241 encoder-screen cells recovered where the oracle
    /// recovers against 39, no runaway where a restart on the probabilities alone ran the arm
    /// away); `false` is the earlier default. (Always written, so that a scenario's
    /// fingerprint says which.)
    pub restart_ruled_out: bool,
    /// The bank's filters carry each joint's model-error acceleration as a state (docs/method.md,
    /// "Model error as a state"): the estimators' model is wrong by fixed parameter errors, so its
    /// error over the ticks of a motion is one error, not fresh noise every tick; as a state it
    /// is learned from the first ticks and a trusted channel is then predicted sharply. Needs
    /// the dynamics bank model and model error (`[model]`); otherwise the state stays 0 (the
    /// position's integration noise still applies). On by default since 2026-12-05 (measured in
    /// docs/method.md: fewer false alarms on healthy runs of arms nobody tuned for, more
    /// recoveries); `false` is the white model error of the earlier default. (Always written,
    /// so that a scenario's fingerprint says which.)
    pub model_error_state: bool,
    /// Pair evidence (docs/method.md, "Pair evidence"): while the most probable hypothesis
    /// holds exactly one of a joint's two sensors failed (its encoder or its tachometer), a
    /// contest between "the encoder failed", "the tachometer failed" and "neither" (all else
    /// as the winner) runs three filters of its own, never restarted from the winner, and keeps
    /// the camera's evidence between them over the ticks both sensors speak: only what the camera
    /// model's column of that joint says, with its constant offset and its own slope
    /// uncertainty marginalised out, and never more than the camera could resolve between the
    /// sides; the hybrid decides with the bank's probabilities of the three times that
    /// evidence, which for a drift grows with the cube of the time where the bank's per-tick
    /// odds stay bounded. The contest decides which sensor failed, not whether one still has:
    /// "neither" includes "failed and recovered now", priced at one switch and at what this
    /// tick's reading says against a sensor healthy from now on (never more than one switch:
    /// a reading can lift the penalty on "neither", never outbid the bank), so a fault that
    /// ends is seen to end. On by default since 2026-12-08 (measured in docs/method.md: better
    /// on encoder drifts the camera sees and on faults that end; its first version, scored on
    /// the sides' whole residuals, ran a tachometer bias on a joint the camera cannot see away;
    /// its second kept an encoder whose bias had ended dropped for the rest of the run; its
    /// third, uncapped, readmitted a garbage encoder whenever a value landed near the joint).
    /// `false` gives the bank's probabilities alone. (Written only when turned off, so that
    /// fingerprints of scenarios that do not name it stay as they were.)
    #[serde(skip_serializing_if = "is_true")]
    pub pair_evidence: bool,
}

impl Default for HybridConfig {
    fn default() -> Self {
        Self {
            bank_model: BankModel::Dynamics,
            switch: 1e-6,
            broad: 1000.0,
            camera_inflation: 1.2,
            camera: CameraPrecision::Bank,
            camera_broad: 10.0,
            reanchor: true,
            prior: None,
            stuck_weight: 0.01,
            stuck_width: 1e-3,
            resync_ticks: 500,
            actuators: false,
            actuator_broad: 100.0,
            restart_ruled_out: true,
            model_error_state: true,
            pair_evidence: true,
        }
    }
}

impl HybridConfig {
    /// The state prior a run uses: `prior`, or when it is absent
    /// `fixed-until-tachometer-fails` with the Gauss-Newton update and `fixed` with the
    /// gradient one.
    pub fn prior_mode(&self, update: UpdateScheme) -> HybridPrior {
        self.prior.unwrap_or(match update {
            UpdateScheme::GaussNewton => HybridPrior::FixedUntilTachometerFails,
            UpdateScheme::Gradient => HybridPrior::Fixed,
        })
    }

    pub fn validate(&self) -> Result<(), crate::SettingError> {
        if !(self.switch > 0.0 && self.switch < 0.5) {
            return Err(crate::SettingError::new("switch", "must be in (0, 0.5)"));
        }
        if !(self.broad.is_finite() && self.broad > 1.0 && self.broad <= 1e9) {
            return Err(crate::SettingError::new("broad", "must be in (1, 1e9]"));
        }
        if !(self.camera_inflation.is_finite()
            && self.camera_inflation >= 1.0
            && self.camera_inflation <= 1e3)
        {
            return Err(crate::SettingError::new(
                "camera_inflation",
                "must be in [1, 1e3]",
            ));
        }
        if !(self.camera_broad.is_finite() && self.camera_broad > 1.0 && self.camera_broad <= 1e9) {
            return Err(crate::SettingError::new(
                "camera_broad",
                "must be in (1, 1e9]",
            ));
        }
        if !(0.0..1.0).contains(&self.stuck_weight) {
            return Err(crate::SettingError::new(
                "stuck_weight",
                "must be in [0, 1)",
            ));
        }
        if !(self.actuator_broad.is_finite()
            && self.actuator_broad > 1.0
            && self.actuator_broad <= 1e6)
        {
            return Err(crate::SettingError::new(
                "actuator_broad",
                "must be in (1, 1e6]",
            ));
        }
        if !(self.stuck_width.is_finite() && self.stuck_width > 0.0 && self.stuck_width <= 100.0) {
            return Err(crate::SettingError::new(
                "stuck_width",
                "must be in (0, 100]",
            ));
        }
        if self.actuators && self.model_error_state {
            return Err(crate::SettingError::new(
                "actuators",
                "needs `hybrid.model_error_state = false`: the model-error state explains a \
                 lasting torque error (a locked joint) as model error, so the actuator \
                 hypotheses never win (docs/method.md, \"Model error as a state\")",
            ));
        }
        Ok(())
    }
}

fn is_false(v: &bool) -> bool {
    !*v
}

fn is_true(v: &bool) -> bool {
    *v
}

fn is_default_actuator_broad(v: &f64) -> bool {
    *v == HybridConfig::default().actuator_broad
}

/// The hybrid's probability floor: 1e-300, against underflow only (the switching prior keeps
/// every hypothesis revivable), not renormalised.
/// Numbers a contest keeps per joint and camera output (`Hybrid::contest_sums`).
const CONTEST_SUMS: usize = 16;

/// The pairs of a contest's sides (0: the encoder failed, 1: the tachometer failed, 2: neither).
const CONTEST_PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

/// The log marginal likelihood (up to terms equal for every side) of normalised residuals r_t
/// = b + eps w_t + e_t, e_t ~ N(0, 1), with an offset b ~ N(0, kappa) and a slope error eps ~
/// N(0, v) marginalised, from the sums [r, r^2, w, w^2, w r] and the count (docs/method.md,
/// "Pair evidence"): -1/2 (sum r^2 - c' A^-1 c) - 1/2 ln det(I + L0 X'X), X = [1, w],
/// L0 = diag(kappa, v), A = L0^-1 + X'X, c = X' r; written with B = I + X'X L0 so that v = 0
/// (a slope taken as exact) needs no division.
fn contest_log_likelihood(sums: &[f64], count: f64, kappa: f64, v: f64) -> f64 {
    let [sr, srr, sw, sww, swr] = [sums[0], sums[1], sums[2], sums[3], sums[4]];
    let (b00, b01, b10, b11) = (1.0 + count * kappa, sw * v, sw * kappa, 1.0 + sww * v);
    let det = b00 * b11 - b01 * b10;
    let y0 = (b11 * sr - b01 * swr) / det;
    let y1 = (b00 * swr - b10 * sr) / det;
    let explained = sr * kappa * y0 + swr * v * y1;
    -0.5 * (srr - explained) - 0.5 * det.ln()
}

const FLOOR: Floor = Floor {
    value: 1e-300,
    renormalise: false,
};

/// A slot of the bank, relative to the base hypothesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Slot {
    Base,
    /// The base with this key's state flipped.
    Toggle(usize),
    /// The base with its last-added failure replaced by this key.
    Swap(usize),
}

/// The hybrid's belief and its bank of hypotheses.
pub struct Hybrid {
    uaic: Uaic,
    layout: ChannelLayout,
    /// The hypotheses (slots relative to the base, see [`Slot`]), their probabilities and
    /// which are in play (swap slots only while the base holds a failure).
    bank: HypothesisBank,
    /// What a hypothesis can hold failed: each encoder and tachometer, the camera as its first
    /// output (with `camera = "bank"`) and, with `actuators`, each joint's actuator (key
    /// `channels + joint`) and the external torque on every joint (key `channels + joints`).
    keys: Vec<usize>,
    /// The keys the base hypothesis (slot 0) holds failed, by channel index (then actuators).
    base_failed: Vec<bool>,
    /// Scratch: each active hypothesis' process-noise scale per joint (h x n, row-major).
    joint_scale: Vec<f64>,
    /// The base's failed keys in the order they were added (the last is the least established).
    order: Vec<usize>,
    /// The all-healthy hypothesis' covariance when the first failure was accepted: a restarted
    /// hypothesis that trusts a channel the base holds failed starts with it.
    healthy_p: DMatrix<f64>,
    /// The most probable hypothesis, and since when (the resync clock).
    winner: usize,
    winner_since: u64,
    model: Box<dyn TransitionModel>,
    config: HybridConfig,
    nominal: Vec<f64>,
    precisions: Vec<f64>,
    variances: Vec<f64>,
    floor: f64,
    initialised: bool,
    ticks: u64,
    // Scratch of a rebase or restart: the slots that keep their states, the new probabilities.
    kept: Vec<bool>,
    /// Scratch: per hypothesis, whether it holds failed every key the most probable one does.
    extends_winner: Vec<bool>,
    /// `restart_ruled_out`: per slot, the hypothesis restarted from the winner's mean this tick
    /// (its own covariance), predicted and updated beside its own state; the one this tick's
    /// readings favour is kept ([`Hybrid::restart_ruled_out`]).
    restarted: Vec<Ekf>,
    /// Per slot: whether `restarted` holds a candidate this tick, and ln(leave p_w) - ln((1 - s)
    /// p_j), the prior log odds of the switch from the winner against j all along.
    restart_candidate: Vec<bool>,
    restart_prior: Vec<f64>,
    scratch_p: Vec<f64>,
    /// The last tick's readings (the stuck component's prediction).
    last: Vec<Option<f64>>,
    // Scratch of the re-anchoring test: belief minus estimate, its solve, the factor.
    gap: DVector<f64>,
    solved: DVector<f64>,
    factor: DMatrix<f64>,
    /// Scratch: a hypothesis' covariance of [q, qd] (the re-anchored belief's).
    anchor_p: DMatrix<f64>,
    /// Scratch: the velocity spread of the state the model is evaluated at.
    velocity_spread: Vec<f64>,
    /// The lead filter's model-error estimate, handed to the model with the velocity spread.
    model_error: Vec<f64>,
    /// `pair_evidence`: per joint, whether a contest is open and, if so, for how many ticks
    /// the winner has held neither of the joint's sensors failed (or both).
    contests: Vec<Option<u64>>,
    /// Per joint and camera output: the open contest's sums over its ticks, for each of its
    /// three sides, of r, r^2, w, w^2 and w r (r: the side's normalised camera residual, w: its
    /// regressor on the camera model's slope error), and the count (16 numbers).
    contest_sums: Vec<f64>,
    /// Per joint: the posterior variance of the camera model's slope along the joint where the
    /// open contest is, and the ticks since it was taken.
    slope_variance: Vec<f64>,
    /// Working space of the camera model's slope variance (reserved once).
    slope_scratch: Vec<f64>,
    slope_age: Vec<u64>,
    /// Per joint: the "neither" side's position of the joint when the contest opened (where
    /// the slope error's contribution is taken as zero; the offset absorbs the rest).
    slope_anchor: Vec<f64>,
    /// Per joint: for each pair of sides (E-T, E-N, T-N), the sum over the contest's ticks and
    /// camera outputs of the squared difference of their camera predictions in camera sigmas,
    /// by joint i's column: the separation the camera could resolve.
    contest_reach: Vec<f64>,
    /// Per joint, this tick's bank slots of the open contest's three sides (the encoder
    /// failed, the tachometer failed, neither).
    pair_slots: Vec<Option<[usize; 3]>>,
    /// Per joint, the open contest's own three filters, never restarted from the winner, and
    /// their normalised camera residuals of this tick (3n x channels).
    contest_filters: Vec<Ekf>,
    pair_z: Vec<f64>,
    /// Per side: sqrt(s) per channel (as `pair_z`); per joint: the winner's camera Jacobian
    /// column of the joint per camera output, and each side's predicted position of it.
    pair_spread: Vec<f64>,
    pair_column: Vec<f64>,
    pair_q: Vec<f64>,
    /// Per joint, for its encoder and its tachometer: this tick's log-likelihood of the
    /// reading under the contest's side that holds the sensor failed, restarted now as
    /// healthy (its prediction, with the sensor's noise), less that under the bank's
    /// "neither" hypothesis (NaN without a reading): what the reading says about "the sensor
    /// failed and has recovered" against the bank's "healthy" (`weigh_contests`).
    recovery_fit: Vec<f64>,
    /// Per joint: whether both of its sensors gave a reading this tick (a contest gathers
    /// camera evidence only then: `weigh_contests`).
    pair_heard: Vec<bool>,
    /// Scratch: the winner's camera linearisation (outputs, Jacobian, positions), which every
    /// side of a contest is scored against with its own position of the contest's joint.
    reference_g: Vec<f64>,
    reference_jac: Vec<f64>,
    reference_q: Vec<f64>,
    /// The bank's probabilities with the contests' camera evidence (`pair_evidence`; otherwise
    /// a copy): what the winner, the precisions and the re-anchoring are decided with.
    view: Vec<f64>,
}

impl Hybrid {
    /// `ekf` is the bank's template, `model` its transition.
    pub fn new(
        uaic: Uaic,
        ekf: Ekf,
        model: Box<dyn TransitionModel>,
        config: HybridConfig,
        nominal: &[f64],
        floor: f64,
    ) -> Self {
        let layout = ekf.layout();
        // Hypotheses: H_0; each encoder and tachometer; the camera as one (index = first output).
        let mut keys = Vec::new();
        for c in 0..layout.len() {
            if !matches!(layout.channel(c), Channel::Camera(_)) {
                keys.push(c);
            }
        }
        if config.camera == CameraPrecision::Bank {
            keys.push(
                layout
                    .group_range(crate::sensors::SensorGroup::Camera)
                    .start,
            );
        }
        let n = layout.n_joints();
        if config.actuators {
            // Each joint's actuator, then the external torque on every joint.
            keys.extend((0..=n).map(|i| layout.len() + i));
        }
        let k = keys.len();
        let dim = 2 * n;
        // Slots: the base, a toggle per key, a swap per key.
        let h = 1 + 2 * k;
        let mut probability = vec![0.0; h];
        probability[0] = 1.0 - 1e-3;
        for p in &mut probability[1..=k] {
            *p = 1e-3 / k as f64;
        }
        let restarted = vec![ekf.clone(); h];
        let probability_view = probability.clone();
        let (contest_filters, slope_scratch) = if config.pair_evidence {
            ekf.observation().prepare_slope_variance();
            (
                vec![ekf.clone(); 3 * n],
                Vec::with_capacity(ekf.observation().slope_scratch_len()),
            )
        } else {
            (Vec::new(), Vec::new())
        };
        Self {
            uaic,
            layout,
            healthy_p: ekf.p.clone(),
            bank: HypothesisBank::new(ekf, probability, 1 + k),
            keys,
            base_failed: vec![false; layout.len() + n + 1],
            joint_scale: vec![1.0; h * n],
            order: Vec::with_capacity(k),
            winner: 0,
            winner_since: 0,
            model,
            config,
            nominal: nominal.to_vec(),
            precisions: nominal.to_vec(),
            variances: vec![0.0; nominal.len()],
            floor,
            initialised: false,
            ticks: 0,
            kept: vec![false; h],
            extends_winner: vec![false; h],
            restarted,
            restart_candidate: vec![false; h],
            restart_prior: vec![0.0; h],
            scratch_p: vec![0.0; h],
            last: vec![None; layout.len()],
            gap: DVector::zeros(dim),
            solved: DVector::zeros(dim),
            factor: DMatrix::zeros(dim, dim),
            anchor_p: DMatrix::zeros(dim, dim),
            velocity_spread: vec![0.0; n],
            model_error: vec![0.0; n],
            contests: vec![None; n],
            pair_slots: vec![None; n],
            contest_sums: vec![0.0; n * layout.camera_outputs() * CONTEST_SUMS],
            slope_variance: vec![0.0; n],
            slope_scratch,
            slope_age: vec![0; n],
            slope_anchor: vec![0.0; n],
            contest_reach: vec![0.0; 3 * n],
            contest_filters,
            pair_z: vec![f64::NAN; 3 * n * layout.len()],
            pair_spread: vec![f64::NAN; 3 * n * layout.len()],
            pair_column: vec![0.0; n * layout.camera_outputs()],
            pair_q: vec![f64::NAN; 3 * n],
            recovery_fit: vec![f64::NAN; 2 * n],
            pair_heard: vec![false; n],
            reference_g: vec![0.0; layout.camera_outputs()],
            reference_jac: vec![0.0; layout.camera_outputs() * n],
            reference_q: vec![0.0; n],
            view: probability_view,
        }
    }

    /// The active slot that holds failed what hypothesis `w` does apart from joint sensors `e`
    /// and `t`, and of those two only `add` (none: neither).
    fn pair_slot(&self, w: usize, e: usize, t: usize, add: Option<usize>) -> Option<usize> {
        let keys = self.base_failed.len();
        (0..self.bank.len()).find(|&j| {
            self.bank.active[j]
                && (0..keys).all(|k| {
                    let want = if k == e || k == t {
                        add == Some(k)
                    } else {
                        self.holds_failed(w, k)
                    };
                    self.holds_failed(j, k) == want
                })
        })
    }

    /// `pair_evidence`: a contest between "joint i's encoder failed", "its tachometer failed"
    /// and "neither" (all else as the most probable hypothesis) opens, its filters started
    /// from the bank's, when the most probable hypothesis holds one of the two failed and not
    /// the other, and closes once it has held neither (or both) for `resync_ticks`: the bank's
    /// winner
    /// flickers between "healthy" and a failure while a fault is young, and the contest must
    /// not forget its evidence each time. Fills this tick's slots of the open contests.
    fn find_pairs(&mut self) {
        let w = self.view_winner();
        let n = self.layout.n_joints();
        let patience = self.config.resync_ticks.max(1);
        for i in 0..n {
            let (e, t) = (i, n + i);
            let one = self.holds_failed(w, e) != self.holds_failed(w, t);
            match self.contests[i].as_mut() {
                None if !one => {
                    self.pair_slots[i] = None;
                    continue;
                }
                Some(idle) if !one => {
                    *idle += 1;
                    if *idle >= patience {
                        self.contests[i] = None;
                        self.pair_slots[i] = None;
                        continue;
                    }
                }
                Some(idle) => *idle = 0,
                None => {}
            }
            let slots = match (
                self.pair_slot(w, e, t, Some(e)),
                self.pair_slot(w, e, t, Some(t)),
                self.pair_slot(w, e, t, None),
            ) {
                (Some(a), Some(b), Some(c)) => Some([a, b, c]),
                _ => None,
            };
            self.pair_slots[i] = slots;
            if self.contests[i].is_none()
                && let Some(js) = slots
            {
                self.contests[i] = Some(0);
                for (side, j) in js.iter().enumerate() {
                    let f = &mut self.contest_filters[3 * i + side];
                    f.x.copy_from(&self.bank.filters[*j].x);
                    f.p.copy_from(&self.bank.filters[*j].p);
                }
                let r = self.layout.camera_outputs() * CONTEST_SUMS;
                self.contest_sums[i * r..(i + 1) * r].fill(0.0);
                self.slope_age[i] = 0;
                self.slope_anchor[i] = self.contest_filters[3 * i + 2].x[i];
                self.contest_reach[3 * i..3 * i + 3].fill(0.0);
            }
        }
    }

    /// The open contest and side (0: the encoder failed, 1: the tachometer failed, 2:
    /// neither) whose hypothesis is slot j this tick.
    fn contest_side(&self, j: usize) -> Option<(usize, usize)> {
        (0..self.layout.n_joints()).find_map(|i| match (self.pair_slots[i], self.contests[i]) {
            (Some(js), Some(_)) => js.iter().position(|&k| k == j).map(|side| (i, side)),
            _ => None,
        })
    }

    /// Updates each open contest's three filters with this tick's readings, at the variances of
    /// their hypotheses in the bank, recording their normalised camera residuals.
    fn update_contests(&mut self, input: &EstimatorInput<'_>) {
        let m = self.layout.len();
        let camera = self.layout.group_range(crate::sensors::SensorGroup::Camera);
        // Every side is scored against the winner's camera linearisation with its own position
        // of joint i: the contest is about joint i, and what the sides' filters make of the
        // other joints (or the camera model's curvature between their poses) is not its question.
        let w = self.view_winner();
        let n = self.layout.n_joints();
        let (g, jac, at) = self.bank.filters[w].camera_linearisation();
        self.reference_g.copy_from_slice(g);
        self.reference_jac.copy_from_slice(jac);
        self.reference_q.copy_from_slice(&at[..n]);
        for i in 0..n {
            let Some(js) = self.pair_slots[i] else {
                self.pair_z[3 * i * m..(3 * i + 3) * m].fill(f64::NAN);
                continue;
            };
            if self.contests[i].is_none() {
                continue;
            }
            let r = self.layout.camera_outputs();
            for o in 0..r {
                self.pair_column[i * r + o] = self.reference_jac[o * n + i];
            }
            let period = self.config.resync_ticks.max(1);
            if self.slope_age[i].is_multiple_of(period) {
                self.slope_variance[i] = self.bank.filters[w].observation().slope_variance(
                    &self.reference_q,
                    i,
                    &mut self.slope_scratch,
                );
            }
            self.slope_age[i] += 1;
            // Does the encoder's (the tachometer's) reading fit the side that holds it failed,
            // as if it had recovered now (its prediction, before it sees this tick's
            // readings), as well as it fits the bank's "neither" after this tick's update (the
            // hypothesis the view weighs: restarted from the winner, judged with the
            // readings)? Both at the sensor's nominal noise. Not the contest's own "neither"
            // filter: it has absorbed the faulty readings, so a frozen reading the joint passes
            // would fit "recovered" far better than it, and "neither" would win while the
            // sensor is still frozen.
            for (pair, side) in [(0, 0), (1, 1)] {
                let c = if pair == 0 {
                    self.layout.index(Channel::Encoder(i))
                } else {
                    self.layout.index(Channel::Tachometer(i))
                };
                // The sensor's nominal variance (what `hypothesis_variances` gives "neither").
                let noise = if input.precisions[c] > 0.0 {
                    1.0 / self.nominal[c]
                } else {
                    f64::INFINITY
                };
                let fit = |f: &Ekf, y: f64| {
                    let s = f.projected_variance(c) + noise;
                    let nu = y - f.predicted(c);
                    -0.5 * (nu * nu / s + s.ln())
                };
                self.recovery_fit[2 * i + pair] = match input.readings.get(c) {
                    Some(y) if noise.is_finite() && noise > 0.0 => {
                        fit(&self.contest_filters[3 * i + side], y)
                            - fit(&self.bank.filters[js[2]], y)
                    }
                    _ => f64::NAN,
                };
            }
            let heard = |c: Channel| {
                let c = self.layout.index(c);
                input.precisions[c] > 0.0 && input.readings.get(c).is_some()
            };
            self.pair_heard[i] = heard(Channel::Encoder(i)) && heard(Channel::Tachometer(i));
            // Taken out while the sides' filters are updated (no allocation).
            let (g, columns) = (
                std::mem::take(&mut self.reference_g),
                std::mem::take(&mut self.pair_column),
            );
            let reference = CameraReference {
                joint: i,
                g: &g,
                column: &columns[i * r..(i + 1) * r],
                position: self.reference_q[i],
            };
            for (side, j) in js.into_iter().enumerate() {
                self.hypothesis_variances(j, input);
                let f = &mut self.contest_filters[3 * i + side];
                f.linearise();
                self.pair_q[3 * i + side] = f.x[i];
                let at = (3 * i + side) * m..(3 * i + side + 1) * m;
                f.update_scored(
                    input.readings,
                    &self.variances,
                    |c| camera.contains(&c),
                    Some(&reference),
                    &mut self.pair_z[at.clone()],
                    &mut self.pair_spread[at],
                );
            }
            self.reference_g = g;
            self.pair_column = columns;
        }
    }

    /// The contests' camera evidence after this tick and the view of the bank's probabilities
    /// the hybrid decides with: the bank's own, with each open contest's three hypotheses
    /// sharing their total in proportion to their bank probabilities times their camera
    /// likelihoods over the contest's life (docs/method.md, "Pair evidence"). Only what
    /// joint i's column of the camera model says counts: every side's residual is taken against
    /// the winner's camera linearisation moved by the column times the side's position of the
    /// joint (`update_contests`); per camera
    /// output a constant offset b ~ N(0, kappa) (kappa = camera_inflation^2 - 1 in units of
    /// the bank's camera variance) and an error of the column eps ~ N(0, v) (the GP's own
    /// posterior variance of its slope) are marginalised out ([`contest_log_likelihood`]); and
    /// no side trails the best by more than the camera could have resolved between their
    /// positions. The bank's per-tick odds keep what the pair's readings say, a stuck reading
    /// among them; the contest adds what the camera has said over its life, which the
    /// switching prior would forget.
    fn weigh_contests(&mut self) {
        self.view.copy_from_slice(&self.bank.probability);
        if !self.config.pair_evidence {
            return;
        }
        let m = self.layout.len();
        let r = self.layout.camera_outputs();
        let kappa = (self.config.camera_inflation * self.config.camera_inflation - 1.0).max(1e-12);
        let cam = self.layout.group_range(crate::sensors::SensorGroup::Camera);
        for i in 0..self.layout.n_joints() {
            let (Some(js), Some(_)) = (self.pair_slots[i], self.contests[i]) else {
                continue;
            };
            let mut ll = [0.0f64; 3];
            let v = self.slope_variance[i];
            let q = &self.pair_q[3 * i..3 * i + 3];
            for (o, c) in cam.clone().enumerate() {
                let sums = &mut self.contest_sums
                    [(i * r + o) * CONTEST_SUMS..(i * r + o + 1) * CONTEST_SUMS];
                // Each side's residual against the winner's linearisation with its own position of
                // the joint, and the slope error's regressor, its distance from the anchor,
                // w = (q_k - anchor) / sqrt(s).
                let z: [f64; 3] = std::array::from_fn(|k| self.pair_z[(3 * i + k) * m + c]);
                let spread: [f64; 3] =
                    std::array::from_fn(|k| self.pair_spread[(3 * i + k) * m + c]);
                let column = self.pair_column[i * r + o];
                // Only while both of the joint's sensors speak: the contest weighs two
                // explanations of a disagreement between them. With one silent there is none;
                // the sides' camera residuals then only say how far their filters have drifted
                // apart, which favours the side with the freer velocity (docs/method.md, "Pair
                // evidence", a silent sensor).
                if self.pair_heard[i] && z.iter().chain(&spread).chain(q).all(|x| x.is_finite()) {
                    let anchor = self.slope_anchor[i];
                    for k in 0..3 {
                        let res = z[k];
                        let w = (q[k] - anchor) / spread[k];
                        let side = &mut sums[5 * k..5 * k + 5];
                        side[0] += res;
                        side[1] += res * res;
                        side[2] += w;
                        side[3] += w * w;
                        side[4] += w * res;
                    }
                    sums[15] += 1.0;
                    // The column the camera model is sure of: shrunk by the share of its
                    // squared slope that is not its own uncertainty, m^2 / (m^2 + v).
                    let credible =
                        column * column * column / (column * column + v).max(f64::MIN_POSITIVE);
                    let reach = &mut self.contest_reach[3 * i..3 * i + 3];
                    for (p, (a, b)) in CONTEST_PAIRS.iter().enumerate() {
                        let d = credible * (q[*a] - q[*b]) / spread[2];
                        reach[p] += d * d;
                    }
                }
                for k in 0..3 {
                    ll[k] += contest_log_likelihood(&sums[5 * k..5 * k + 5], sums[15], kappa, v);
                }
            }
            let best = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            // No side trails the best by more than the camera could have resolved between
            // them: D / 2 + 3 sqrt(D) for a separation D (the log odds' mean and three of its
            // standard deviations were the camera model exact); more is the model's error.
            let lead = (0..3).find(|&k| ll[k] == best).unwrap_or(0);
            for k in 0..3 {
                if k == lead {
                    continue;
                }
                let p = CONTEST_PAIRS
                    .iter()
                    .position(|&(a, b)| (a, b) == (k.min(lead), k.max(lead)))
                    .unwrap_or(0);
                let reach = self.contest_reach[3 * i + p];
                ll[k] = ll[k].max(best - (0.5 * reach + 3.0 * reach.sqrt()));
            }
            // "Neither" includes "the sensor the leading side blames failed and has
            // recovered now": the leader's camera evidence so far, one switch (the switching
            // prior), and what this tick's reading says against a sensor healthy from now on.
            // The contest decides which sensor failed; whether one still has failed, once the
            // readings agree again, is the bank's (docs/method.md, "Pair evidence"): the
            // reading can take the contest's evidence against "neither" down to one switch,
            // never below it (a reading that fits the leader better than the bank's
            // "neither", which has absorbed faulty readings, is one garbage value that landed
            // near the joint, not a recovery; only the bank's own odds may readmit).
            let lead = if ll[1] > ll[0] { 1 } else { 0 };
            let fit = self.recovery_fit[2 * i + lead];
            if fit.is_finite() {
                let recovered = ll[lead] + self.config.switch.ln() + fit.min(0.0);
                let (hi, lo) = (ll[2].max(recovered), ll[2].min(recovered));
                ll[2] = hi + (lo - hi).exp().ln_1p();
            }
            let best = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let v = &mut self.view;
            let total: f64 = js.iter().map(|&j| v[j]).sum();
            let w: [f64; 3] =
                std::array::from_fn(|k| v[js[k]] * (ll[k] - best).clamp(-700.0, 0.0).exp());
            let sw: f64 = w.iter().sum();
            for k in 0..3 {
                v[js[k]] = (total * w[k] / sw).max(FLOOR.value);
            }
        }
    }

    /// The most probable hypothesis of the view (the last of equals; without contests the
    /// bank's own).
    fn view_winner(&self) -> usize {
        (0..self.view.len())
            .max_by(|&a, &b| self.view[a].total_cmp(&self.view[b]))
            .unwrap_or(0)
    }

    /// Whether the belief lies outside hypothesis j's 3-sigma ellipsoid (with the belief's own
    /// covariance added). Works in the preallocated `gap`, `solved` and `factor` (a degenerate
    /// covariance, the failure path, allocates a new factor).
    fn outside(&mut self, j: usize) -> bool {
        let f = &self.bank.filters[j];
        let b = self.uaic.belief();
        let x = f.joint_state();
        if b.len() != x.len() {
            return false;
        }
        for ((g, a), c) in self.gap.iter_mut().zip(b).zip(x) {
            *g = a - c;
        }
        let mut s = std::mem::replace(&mut self.factor, DMatrix::zeros(0, 0));
        let d = x.len();
        s.copy_from(&f.p.view((0, 0), (d, d)));
        if let Some(c) = self.uaic.covariance() {
            s += c;
        }
        let dim = s.nrows();
        match nalgebra::linalg::Cholesky::new(s) {
            Some(ch) => {
                self.solved.copy_from(&self.gap);
                ch.solve_mut(&mut self.solved);
                self.factor = ch.unpack_dirty();
                self.solved.dot(&self.gap) > 9.0 * b.len() as f64
            }
            None => {
                self.factor = DMatrix::zeros(dim, dim);
                false
            }
        }
    }

    /// The hypotheses' probabilities by slot: the base (slot 0), the base with key k toggled
    /// (slot 1 + k; the keys are each encoder and tachometer, then the camera with
    /// `camera = "bank"`, then with `actuators` each joint's actuator and the external torque), the base with its last failure swapped for key k (slot 1 + K + k; 0
    /// while inactive). `failed_channels` says what the base holds. With `pair_evidence`, the
    /// view the hybrid decides with (the bank's, with the open contests' camera evidence).
    pub fn probabilities(&self) -> &[f64] {
        &self.view
    }

    /// The channels the base hypothesis holds failed, the failures the bank has accepted
    /// (channel indices; the camera as its first output).
    pub fn failed_channels(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.layout.len()).filter(|&c| self.base_failed[c])
    }

    /// The joints whose actuator the base hypothesis holds failed, and whether it holds an
    /// external torque (with `actuators`).
    pub fn failed_actuators(&self) -> (Vec<usize>, bool) {
        let (c, n) = (self.layout.len(), self.layout.n_joints());
        (
            (0..n).filter(|&i| self.base_failed[c + i]).collect(),
            self.base_failed[c + n],
        )
    }

    /// Whether hypothesis j holds joint i's torque unknown: its actuator, or the external
    /// torque.
    fn holds_torque_unknown(&self, j: usize, i: usize) -> bool {
        let (c, n) = (self.layout.len(), self.layout.n_joints());
        self.holds_failed(j, c + i) || self.holds_failed(j, c + n)
    }

    /// What slot j holds: the base, the base with one key toggled, or the base with its last
    /// failure swapped for another key.
    fn slot(&self, j: usize) -> Slot {
        let k = self.keys.len();
        match j {
            0 => Slot::Base,
            j if j <= k => Slot::Toggle(self.keys[j - 1]),
            j => Slot::Swap(self.keys[j - 1 - k]),
        }
    }

    /// The bank's key for channel c: the channel itself, the camera's first output for every
    /// camera output (the camera fails as one).
    fn key(&self, c: usize) -> usize {
        match self.layout.channel(c) {
            Channel::Camera(_) => {
                self.layout
                    .group_range(crate::sensors::SensorGroup::Camera)
                    .start
            }
            _ => c,
        }
    }

    /// The bank's probability that `key` failed: the sum over the active hypotheses that hold
    /// it failed.
    fn failure_probability(&self, key: usize) -> f64 {
        (0..self.bank.len())
            .filter(|&j| self.bank.active[j] && self.holds_failed(j, key))
            .map(|j| self.view[j])
            .sum()
    }

    /// Whether hypothesis j holds channel `key` failed.
    fn holds_failed(&self, j: usize, key: usize) -> bool {
        let base = self.base_failed[key];
        match self.slot(j) {
            Slot::Base => base,
            Slot::Toggle(t) => base ^ (key == t),
            Slot::Swap(t) => key == t || (base && self.order.last() != Some(&key)),
        }
    }

    /// Whether hypothesis j holds failed every channel the base does (it knows no more).
    fn extends_base(&self, j: usize) -> bool {
        self.keys
            .iter()
            .all(|&key| !self.base_failed[key] || self.holds_failed(j, key))
    }

    /// Whether hypothesis `new` holds failed a channel that hypothesis `old` trusts: only then
    /// has the belief used readings that the new winner says are wrong, and only then is it
    /// re-anchored. A winner that trusts more (a failure that ended, a false blame withdrawn)
    /// lets the belief take the channel back through its precision.
    fn distrusts_more(&self, new: usize, old: usize) -> bool {
        self.keys.iter().any(|&key| {
            key < self.layout.len() && self.holds_failed(new, key) && !self.holds_failed(old, key)
        })
    }

    /// Makes hypothesis `w` the base (docs/method.md, "The hybrid"). The bank is always the base,
    /// the base with one key toggled (a second fault, or the end of one, is a toggle away) and,
    /// while the base holds a failure, the base with its last failure swapped for another key (a
    /// wrong first blame, an encoder drift taken for a tachometer bias, is a swap away). The
    /// filters whose hypotheses survive the move keep their states (the winner's, the old
    /// base's, and on a new failure the old toggles, which become the swaps); the others restart
    /// from the new base at the switching prior.
    fn rebase(&mut self, w: usize) {
        if self.slot(w) == Slot::Base {
            return;
        }
        let k = self.keys.len();
        let h = self.bank.len();
        let mut p = std::mem::take(&mut self.scratch_p);
        p.fill(0.0);
        p[0] = self.bank.probability[w];
        let old_base = self.bank.probability[0];
        // Slots whose filters keep their states.
        let mut kept = std::mem::take(&mut self.kept);
        kept.fill(false);
        kept[0] = true;
        match self.slot(w) {
            Slot::Base => unreachable!("checked above"),
            Slot::Toggle(t) if !self.base_failed[t] => {
                // A new failure: the old base is "t came back", the old toggles of other keys
                // (base + t') are the new swaps (new base - t + t').
                if self.order.is_empty() {
                    self.healthy_p.copy_from(&self.bank.filters[0].p);
                }
                self.base_failed[t] = true;
                self.order.push(t);
                self.bank.filters.swap(0, w);
                p[w] = old_base;
                kept[w] = true;
                for i in 0..k {
                    if !self.base_failed[self.keys[i]] {
                        self.bank.filters.swap(1 + i, 1 + k + i);
                        p[1 + k + i] = self.bank.probability[1 + i];
                        kept[1 + k + i] = true;
                    }
                }
            }
            Slot::Toggle(t) => {
                // A fault that ended: the old base is "t failed after all".
                self.base_failed[t] = false;
                self.order.retain(|&c| c != t);
                self.bank.filters.swap(0, w);
                p[w] = old_base;
                kept[w] = true;
            }
            Slot::Swap(t) => {
                // The last failure was the wrong one: t instead of b. The old base is the swap
                // back to b.
                let b = *self.order.last().expect("swaps exist only with a failure");
                self.base_failed[b] = false;
                self.base_failed[t] = true;
                self.order.pop();
                self.order.push(t);
                let back = 1 + k + self.keys.iter().position(|&c| c == b).expect("a key");
                self.bank.filters.swap(0, w);
                self.bank.filters.swap(w, back);
                p[back] = old_base;
                kept[back] = true;
            }
        }
        for j in 1..h {
            self.bank.active[j] = match self.slot(j) {
                Slot::Base | Slot::Toggle(_) => true,
                Slot::Swap(t) => !self.order.is_empty() && !self.base_failed[t],
            };
        }
        let m = self.bank.active_count();
        let floor = self.config.switch / (m - 1) as f64;
        for j in 1..h {
            if !self.bank.active[j] {
                p[j] = 0.0;
                kept[j] = true;
            } else if !kept[j] {
                p[j] = floor;
            }
        }
        let total: f64 = p.iter().sum();
        for (q, v) in self.bank.probability.iter_mut().zip(&p) {
            *q = v / total;
        }
        self.kept = kept;
        self.scratch_p = p;
        self.restart_from_base();
        // The slots have moved: the view is the bank's until the next weighing, and the open
        // contests find their slots again.
        self.view.copy_from_slice(&self.bank.probability);
        self.pair_slots.fill(None);
    }

    /// A resync while the winner stays, every `resync_ticks`. The hypotheses the data do not
    /// favour (probability at or below what the switching prior alone gives them) restart from
    /// the base, so that a failure hypothesis that wins later carries the estimate of the last
    /// resync, not one that has never used its channel (which carries the camera model's bias).
    /// While the base holds a failure, the toggles restart whatever their probability ("is the
    /// channel healthy from now on?"); a favoured swap keeps its state: it is the rival
    /// explanation of the accepted failure, and the base has followed the blamed channel's
    /// rival (the Panda shoulder's encoder drift, first blamed on its tachometer, ended 0.02 rad
    /// off when the encoder swap restarted from that base).
    fn resync(&mut self) {
        let m = self.bank.active_count();
        let floor = self.config.switch / (m - 1) as f64;
        let failed = !self.order.is_empty();
        for j in 0..self.bank.len() {
            let favoured = self.bank.probability[j] > floor;
            let swap = matches!(self.slot(j), Slot::Swap(_));
            self.kept[j] = j == 0 || ((!failed || swap) && favoured);
        }
        self.restart_from_base();
    }

    /// Every active hypothesis not marked in `self.kept` restarts from the base's mean. One that holds
    /// failed every channel the base does takes the base's covariance too (it knows no more);
    /// one that trusts a channel the base holds failed takes the all-healthy covariance, so that
    /// it asks whether that channel agrees with the base's estimate to within its nominal
    /// noise: with the base's broader uncertainty a constant offset would be absorbed in one
    /// tick, and an encoder bias pass for a healthy encoder.
    fn restart_from_base(&mut self) {
        for j in 1..self.bank.len() {
            if self.kept[j] || !self.bank.active[j] {
                continue;
            }
            let extends = self.extends_base(j);
            let (base, rest) = self.bank.filters.split_at_mut(1);
            let f = &mut rest[j - 1];
            f.x.copy_from(&base[0].x);
            if extends {
                f.p.copy_from(&base[0].p);
            } else {
                f.p.copy_from(&self.healthy_p);
            }
        }
    }

    /// The log evidence that hypothesis j's failed channels add for being possibly stuck: per
    /// failed channel with a reading now and at the last tick, ln((1 - w) + w N_stuck / N_broad),
    /// N_stuck = N(y; y_last, (width sigma)^2), N_broad the broad innovation density the filter
    /// scores it with (docs/method.md, "The hybrid"), taken at the prediction (the sequential
    /// update scores it after the channels before it; with broad noise the two differ in the
    /// last digits). Uses `self.variances` of hypothesis j and its state `f` (its own, or the
    /// restarted one).
    fn stuck_evidence(&self, j: usize, f: &Ekf, input: &EstimatorInput<'_>) -> f64 {
        let w = self.config.stuck_weight;
        if w <= 0.0 {
            return 0.0;
        }
        let (ln_healthy, ln_w) = ((1.0 - w).ln(), w.ln());
        let mut total = 0.0;
        for c in 0..self.layout.len() {
            let r = self.variances[c];
            let (Some(y), Some(last)) = (input.readings.get(c), self.last[c]) else {
                continue;
            };
            if !r.is_finite()
                || self.nominal[c] >= NOISE_FREE_PRECISION
                || !self.holds_failed(j, self.key(c))
            {
                continue;
            }
            let nu = y - f.predicted(c);
            let s = f.projected_variance(c) + r;
            let ln_broad = -0.5 * (nu * nu / s + s.ln());
            let width = self.config.stuck_width * self.config.stuck_width / self.nominal[c];
            let d = y - last;
            let ln_stuck = -0.5 * (d * d / width + width.ln());
            // ln((1 - w) + w e^x), x = ln_stuck - ln_broad, without overflow.
            let a = ln_healthy;
            let b = ln_w + ln_stuck - ln_broad;
            let m = a.max(b);
            total += m + ((a - m).exp() + (b - m).exp()).ln();
        }
        total
    }

    /// The bank's variances for hypothesis j, given the camera precisions in force.
    fn hypothesis_variances(&mut self, j: usize, input: &EstimatorInput<'_>) {
        for c in 0..self.layout.len() {
            let w = input.precisions[c];
            self.variances[c] = match self.layout.channel(c) {
                _ if w <= 0.0 => f64::INFINITY,
                Channel::Camera(_) => {
                    let inflate = self.config.camera_inflation * self.config.camera_inflation;
                    match self.config.camera {
                        // The learned camera precision, and room for the GP's error.
                        CameraPrecision::Gradient => {
                            inflate / self.nominal[c] * (self.nominal[c] / w).max(1.0)
                        }
                        CameraPrecision::Bank => {
                            let broad = if self.holds_failed(j, self.key(c)) {
                                self.config.camera_broad * self.config.camera_broad
                            } else {
                                1.0
                            };
                            inflate / self.nominal[c] * broad
                        }
                    }
                }
                _ => {
                    let v = 1.0 / self.nominal[c];
                    if self.holds_failed(j, c) {
                        v * self.config.broad * self.config.broad
                    } else {
                        v
                    }
                }
            };
        }
    }

    /// `restart_ruled_out`: every hypothesis the data have ruled out since its last restart
    /// (its probability below the switching prior's inflow from the most probable hypothesis,
    /// (1 - s) p_j < leave p_w) and that trusts a channel the winner holds failed is also run
    /// restarted from the winner's mean, keeping its own covariance; after this tick's update
    /// the state with the larger posterior weight is kept: the restart where ln(leave p_w) +
    /// ll(restarted) > ln((1 - s) p_j) + ll(own) (the Viterbi choice of predecessor of a
    /// switching Kalman filter, judged with this tick's readings; docs/method.md, "The hybrid",
    /// revived hypotheses). p_j is the bank's probability, floored at 1e-300, so the prior odds
    /// for the restart reach about 670 nats. Only such a hypothesis can absorb the winner's
    /// fault into its state (an encoder bias the winner blames, absorbed as motion by "the
    /// tachometer failed"); having lost hundreds of nats at the fault's onset it restarts unless
    /// its own state explains this tick better by more than those odds. Where the winner is the
    /// one that is wrong (a second fault while the first is not yet the base: the winner has
    /// followed a frozen tachometer), the restarted state contradicts the channel the
    /// hypothesis trusts by more, and it keeps its own. One that holds failed everything the
    /// winner does keeps its state until the resync. This picks the candidates and their
    /// restarted states (before the prediction).
    fn restart_ruled_out(&mut self) {
        let w = self.bank.most_probable();
        let keys = self.base_failed.len();
        for j in 0..self.bank.len() {
            self.extends_winner[j] =
                (0..keys).all(|k| !self.holds_failed(w, k) || self.holds_failed(j, k));
        }
        let m = self.bank.active_count();
        let s = self.config.switch;
        self.restart_candidate.fill(false);
        if m < 2 {
            return;
        }
        let leave = s / (m - 1) as f64;
        let jump = leave * self.bank.probability[w];
        for j in 0..self.bank.len() {
            let own = (1.0 - s) * self.bank.probability[j];
            if j == w || !self.bank.active[j] || own >= jump || self.extends_winner[j] {
                continue;
            }
            let r = &mut self.restarted[j];
            r.x.copy_from(&self.bank.filters[w].x);
            r.p.copy_from(&self.bank.filters[j].p);
            self.restart_candidate[j] = true;
            self.restart_prior[j] = jump.ln() - own.max(f64::MIN_POSITIVE).ln();
        }
    }

    fn step_bank(&mut self, input: &EstimatorInput<'_>) {
        let h = self.bank.len();
        if !self.initialised {
            // Every slot gets a state, the inactive swaps too (they restart from the base
            // when they enter the bank, keeping this covariance).
            for j in 0..h {
                self.hypothesis_variances(j, input);
                let v = self.variances.clone();
                self.bank.filters[j].initialise(input.readings, &v);
            }
            self.initialised = true;
        } else {
            if self.config.pair_evidence {
                self.find_pairs();
            }
            if self.config.restart_ruled_out {
                self.restart_ruled_out();
            }
            // The model's transition at the most probable hypothesis' estimate (which uses the
            // model; the u-AIC's belief has only the acceleration-bound prior, and without a
            // tachometer its velocity can be off by 0.1 rad/s, which on a damped arm is a wrong
            // acceleration on every joint). For the first `resync_ticks` the belief's instead:
            // every hypothesis starts from one reading, and a failure hypothesis that leads for
            // a tick would otherwise make the model predict from its own estimate and stay
            // ahead (start-up false alarms).
            // The same start-up rule picks whose velocity spread the model's friction band
            // sees: the healthy hypothesis' while the belief leads, then the winner's.
            let starting = self.ticks < self.config.resync_ticks;
            let lead = if starting { 0 } else { self.winner };
            let x = if starting {
                self.uaic.belief()
            } else {
                self.bank.filters[lead].joint_state()
            };
            if self.config.actuators {
                let n = self.layout.n_joints();
                let broad = self.config.actuator_broad;
                for j in 0..h {
                    for i in 0..n {
                        self.joint_scale[j * n + i] = if self.holds_torque_unknown(j, i) {
                            broad
                        } else {
                            1.0
                        };
                    }
                }
            }
            if self.config.model_error_state {
                let n = self.layout.n_joints();
                let f = &self.bank.filters[lead];
                for i in 0..n {
                    self.velocity_spread[i] = f.p[(n + i, n + i)].max(0.0).sqrt();
                }
                self.model.set_velocity_spread(&self.velocity_spread);
                // The lead's model-error estimate (none without the state: 0).
                for i in 0..n {
                    self.model_error[i] = f.x.get(2 * n + i).copied().unwrap_or(0.0);
                }
                self.model.set_model_error(&self.model_error);
            }
            let transition = self.model.evaluate(x, input.applied_torques);
            let (scale, n) = (&self.joint_scale, self.layout.n_joints());
            self.bank
                .predict_per_joint(&transition, |j, i| scale[j * n + i]);
            for i in 0..n {
                if self.contests[i].is_some() {
                    for side in 0..3 {
                        let slot = self.pair_slots[i].map(|js| js[side]);
                        let f = &mut self.contest_filters[3 * i + side];
                        f.predict_scaled(&transition, |k| slot.map_or(1.0, |j| scale[j * n + k]));
                    }
                }
            }
            for (j, r) in self.restarted.iter_mut().enumerate() {
                if self.restart_candidate[j] {
                    r.predict_scaled(&transition, |i| scale[j * n + i]);
                }
            }
            self.bank.switch(self.config.switch);
        }
        self.bank.linearise();
        // A restart starts from the winner's mean, so every candidate's (and the winner's)
        // joint positions are the same after the prediction: one GP evaluation serves them all.
        for j in 0..h {
            if self.restart_candidate[j] {
                let (done, rest) = self.restarted.split_at_mut(j);
                let (filters, active, candidate) = (
                    &self.bank.filters,
                    &self.bank.active,
                    &self.restart_candidate,
                );
                let sources = (0..h)
                    .filter(|&k| active[k])
                    .map(|k| &filters[k])
                    .chain((0..j).filter(|&k| candidate[k]).map(|k| &done[k]));
                rest[0].linearise_from(sources);
            }
        }
        for j in 0..h {
            if self.bank.active[j] {
                self.hypothesis_variances(j, input);
                let stuck = self.stuck_evidence(j, &self.bank.filters[j], input);
                let own = self.bank.filters[j].update(input.readings, &self.variances) + stuck;
                self.bank.log_evidence[j] = own;
                if self.restart_candidate[j] {
                    let stuck = self.stuck_evidence(j, &self.restarted[j], input);
                    let restarted =
                        self.restarted[j].update(input.readings, &self.variances) + stuck;
                    if restarted + self.restart_prior[j] > own {
                        std::mem::swap(&mut self.bank.filters[j], &mut self.restarted[j]);
                        self.bank.log_evidence[j] = restarted;
                    }
                }
            } else {
                self.bank.log_evidence[j] = f64::NEG_INFINITY;
            }
        }
        if self.config.pair_evidence && self.initialised {
            self.update_contests(input);
        }
        self.last.copy_from_slice(&input.readings.values);
        self.ticks += 1;
        self.bank.weigh(FLOOR);
        self.weigh_contests();
    }
}

impl Estimator for Hybrid {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        self.step_bank(input);
        // With `fixed-until-tachometer-fails`, the belief's prior follows the most probable
        // hypothesis; while it is the propagated prior, a channel's precision is nominal x
        // P(healthy) without the floor: the propagated prior's velocity belief is loose enough
        // that a frozen tachometer at the floor precision would bias mu'.
        let winner = self.view_winner();
        let mut floor = self.floor;
        if self.config.prior_mode(self.uaic.config().update)
            == HybridPrior::FixedUntilTachometerFails
        {
            let tachometer_failed = self
                .layout
                .group_range(crate::sensors::SensorGroup::Tachometers)
                .any(|c| self.holds_failed(winner, c) || input.readings.get(c).is_none());
            if tachometer_failed {
                self.uaic.set_prior(PriorMode::Propagated);
                floor = 0.0;
            } else {
                self.uaic.set_prior(PriorMode::Fixed);
            }
        }
        // Channel precisions: the bank's posterior expectation for encoders and tachometers,
        // the learned precision for the camera.
        for c in 0..self.layout.len() {
            let key = self.key(c);
            self.precisions[c] = match self.layout.channel(c) {
                Channel::Camera(_) if self.config.camera == CameraPrecision::Gradient => {
                    input.precisions[c]
                }
                _ if input.precisions[c] <= 0.0 => 0.0,
                _ => self.nominal[c] * (1.0 - self.failure_probability(key)).max(floor),
            };
        }
        // When another hypothesis becomes the most probable, the belief is re-anchored on it
        // (if it drops a channel the last winner trusted and the belief lies outside its
        // 3-sigma ellipsoid); once it has stayed the most probable for `resync_ticks`, the bank
        // is rebased on it.
        let tick = self.ticks;
        let period = self.config.resync_ticks;
        let due = period > 0
            && tick > self.winner_since
            && (tick - self.winner_since).is_multiple_of(period);
        if winner != self.winner {
            // A contest's side that becomes the winner brings its own state: the bank's copy of
            // the hypothesis may have been restarted from the old winner's mean, which followed
            // the faulty channel.
            if self.config.pair_evidence
                && let Some((i, side)) = self.contest_side(winner)
            {
                let f = &self.contest_filters[3 * i + side];
                self.bank.filters[winner].x.copy_from(&f.x);
                self.bank.filters[winner].p.copy_from(&f.p);
            }
            if self.config.reanchor
                && self.distrusts_more(winner, self.winner)
                && self.outside(winner)
            {
                let f = &self.bank.filters[winner];
                let d = self.anchor_p.nrows();
                self.anchor_p.copy_from(&f.p.view((0, 0), (d, d)));
                self.uaic.reanchor(f.joint_state(), Some(&self.anchor_p));
            }
            self.winner = winner;
            self.winner_since = tick;
        } else if due && winner != 0 {
            self.rebase(winner);
            self.winner = 0;
        } else if due {
            self.resync();
        }
        self.uaic.step(input.readings, &self.precisions)
    }

    fn estimate(&self) -> &Estimate {
        self.uaic.estimate()
    }
    fn mu(&self) -> &[f64] {
        self.uaic.mu()
    }
    fn mu_p(&self) -> &[f64] {
        self.uaic.mu_p()
    }
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        self.uaic.covariance()
    }
    fn actuator_failure_probability(&self, joint: usize) -> Option<f64> {
        self.config
            .actuators
            .then(|| self.failure_probability(self.layout.len() + joint))
    }
}

/// The hybrid's bank transition: the arm's dynamics on `model` (the estimators' copy of the
/// arm) with the process noise of `noise` (`[model]`; its floor also where the mass matrix is
/// singular), or constant velocity at the acceleration bound.
pub fn bank_transition(
    config: &HybridConfig,
    model: Arc<crate::arm::ArmModel>,
    gravity: [f64; 3],
    noise: &crate::arm::ModelConfig,
    acceleration_bound: f64,
    dt: f64,
) -> Box<dyn TransitionModel> {
    let n = model.joints.len();
    match config.bank_model {
        BankModel::ConstantVelocity => Box::new(ConstantVelocity::new(n, acceleration_bound)),
        BankModel::Dynamics => Box::new(
            ArmTransition::new(
                model,
                gravity,
                noise.acceleration_noise,
                noise.relative_error,
                noise.acceleration_noise,
            )
            .with_uncertainty(noise.uncertainty())
            .with_step(noise.step, dt),
        ),
    }
}

/// Builds the hybrid: the u-AIC's belief, a bank on `observation` predicting with `transition`.
pub fn build(
    uaic: Uaic,
    observation: Arc<dyn ObservationModel>,
    dt: f64,
    transition: Box<dyn TransitionModel>,
    config: &HybridConfig,
    nominal: &[f64],
    floor: f64,
) -> Hybrid {
    let mut ekf = Ekf::new(observation, dt);
    if config.model_error_state {
        ekf = ekf.with_model_error_state();
    }
    Hybrid::new(uaic, ekf, transition, config.clone(), nominal, floor)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::uaic::UaicConfig;
    use crate::gp::GpModel;
    use crate::sensors::{CameraModel, Readings};

    /// The contest's marginal likelihood is the Gaussian density of the residuals with the
    /// offset and the slope error integrated out, N(0, I + kappa 1 1' + v w w'), evaluated
    /// directly with nalgebra's Cholesky (up to the constant n/2 ln 2 pi), v = 0 included.
    #[test]
    fn the_contests_likelihood_is_the_marginal_gaussian_density() {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for (count, kappa, v) in [
            (1, 0.44, 0.3),
            (4, 0.44, 0.0),
            (7, 2.0, 5.0),
            (12, 0.1, 1e-3),
        ] {
            let r: Vec<f64> = (0..count).map(|_| 2.0 * uniform()).collect();
            let w: Vec<f64> = (0..count).map(|_| 3.0 * uniform()).collect();
            let mut sums = [0.0; 5];
            for t in 0..count {
                sums[0] += r[t];
                sums[1] += r[t] * r[t];
                sums[2] += w[t];
                sums[3] += w[t] * w[t];
                sums[4] += w[t] * r[t];
            }
            let got = contest_log_likelihood(&sums, count as f64, kappa, v);
            let sigma = DMatrix::from_fn(count, count, |a, b| {
                (if a == b { 1.0 } else { 0.0 }) + kappa + v * w[a] * w[b]
            });
            let chol = nalgebra::linalg::Cholesky::new(sigma).unwrap();
            let rv = nalgebra::DVector::from_vec(r.clone());
            let log_det: f64 = chol.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum();
            let want = -0.5 * rv.dot(&chol.solve(&rv)) - 0.5 * log_det;
            assert!(
                (got - want).abs() <= 1e-10 * want.abs().max(1.0),
                "n {count} kappa {kappa} v {v}: {got} against {want}"
            );
        }
    }

    /// The toy arm's nominal precisions: enc1, enc2, tach1, tach2, cam_u, cam_v.
    const TOY_NOMINAL: [f64; 6] = [1e6, 1e6, 1e6, 1e6, 1e4, 1e4];

    fn toy_hybrid_with(config: HybridConfig) -> Hybrid {
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let observation =
            crate::estimation::models::GpCamera::shared(layout, Arc::new(GpModel::toy()));
        let uaic = Uaic::new(UaicConfig::default(), observation.clone(), 1e-3);
        let ekf = Ekf::new(observation, 1e-3);
        let cv = Box::new(ConstantVelocity::new(2, 2.0));
        Hybrid::new(uaic, ekf, cv, config, &TOY_NOMINAL, 1e-6)
    }

    fn toy_hybrid() -> Hybrid {
        toy_hybrid_with(HybridConfig::default())
    }

    /// The toy arm's readings while joint 1 accelerates at `a` rad/s^2 from 0.6 s on (a torque
    /// the constant-velocity bank does not know), the camera missing; returns the hybrid after
    /// 1.6 s and the least precision of each channel after the first 0.1 s.
    fn accelerate(actuators: bool, a: f64) -> (Hybrid, Vec<f64>) {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let nominal = TOY_NOMINAL;
        let mut h = toy_hybrid_with(HybridConfig {
            actuators,
            ..HybridConfig::default()
        });
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let noise = Normal::new(0.0, 1e-3).unwrap();
        let mut least = nominal.to_vec();
        for k in 0..1600u64 {
            let t = k as f64 * 1e-3;
            let s = (t - 0.6).max(0.0);
            let (q, v) = (0.5 * a * s * s, a * s);
            let mut readings = Readings::missing(&layout);
            readings.values[0] = Some(q + noise.sample(&mut rng));
            readings.values[1] = Some(noise.sample(&mut rng));
            readings.values[2] = Some(v + noise.sample(&mut rng));
            readings.values[3] = Some(noise.sample(&mut rng));
            let input = EstimatorInput {
                tick: k,
                readings: &readings,
                precisions: &nominal,
                applied_torques: &[0.0, 0.0],
            };
            h.update(&input);
            if k >= 100 {
                for (l, p) in least.iter_mut().zip(&h.precisions) {
                    *l = l.min(*p);
                }
            }
        }
        (h, least)
    }

    /// An unexpected torque on joint 1 (its encoder and tachometer agree with each other, not
    /// with the bank's prediction): with actuator hypotheses the bank blames joint 1's torque
    /// and keeps both sensors at their nominal precision; without, it blames a sensor.
    #[test]
    fn an_unexpected_torque_is_blamed_on_the_actuator_not_the_sensors() {
        let (h, least) = accelerate(true, 200.0);
        assert_eq!(h.failed_channels().count(), 0, "{:?}", h.failed_actuators());
        let (joints, external) = h.failed_actuators();
        assert!(joints == vec![0] || external, "{joints:?} {external}");
        let (_, without) = accelerate(false, 200.0);
        // Measured: tachometer 1's least precision 0.80 of nominal with, the floor without.
        for c in 0..4 {
            assert!(least[c] > 0.75 * 1e6, "channel {c}: {}", least[c]);
        }
        assert!(
            without[2] < 0.1 * 1e6,
            "without actuator hypotheses tachometer 1 takes the blame: {without:?}"
        );
        // Nothing unexpected: nothing blamed, with or without.
        for actuators in [true, false] {
            let (h, _) = accelerate(actuators, 0.0);
            assert_eq!(h.failed_channels().count(), 0);
            assert_eq!(h.failed_actuators(), (vec![], false));
        }
    }

    /// The failed sets of the active hypotheses, as (slot, channel list).
    fn sets(h: &Hybrid) -> Vec<(usize, Vec<usize>)> {
        (0..h.bank.len())
            .filter(|&j| h.bank.active[j])
            .map(|j| (j, (0..6).filter(|&k| h.holds_failed(j, k)).collect()))
            .collect()
    }

    #[test]
    fn the_bank_is_the_base_its_toggles_and_the_swaps_of_its_last_failure() {
        let mut h = toy_hybrid();
        // Keys: enc1, enc2, tach1, tach2 (channels 0-3), the camera (its first output, 4).
        // Slots: the base (0), a toggle per key (1-5), a swap per key (6-10).
        assert_eq!(
            sets(&h),
            vec![
                (0, vec![]),
                (1, vec![0]),
                (2, vec![1]),
                (3, vec![2]),
                (4, vec![3]),
                (5, vec![4])
            ]
        );
        h.bank.filters[3].x[0] = 0.25;
        h.bank.filters[2].x[0] = 0.5;
        h.bank.probability = vec![0.1, 0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        h.rebase(3);
        // tach1 failed is the base; its toggle asks whether tach1 came back; the other toggles
        // add a second failure (restarted from the base); the swaps (tach1 was the wrong blame)
        // are the old one-failure hypotheses, states kept.
        assert_eq!(
            sets(&h),
            vec![
                (0, vec![2]),
                (1, vec![0, 2]),
                (2, vec![1, 2]),
                (3, vec![]),
                (4, vec![2, 3]),
                (5, vec![2, 4]),
                (6, vec![0]),
                (7, vec![1]),
                (9, vec![3]),
                (10, vec![4])
            ]
        );
        assert_eq!(h.failed_channels().collect::<Vec<_>>(), vec![2]);
        assert_eq!(
            h.bank.filters[0].x[0], 0.25,
            "the winner's filter is the base"
        );
        assert_eq!(
            h.bank.filters[7].x[0], 0.5,
            "the old enc2 hypothesis is the enc2 swap"
        );
        for j in [1, 2, 4, 5] {
            assert_eq!(
                h.bank.filters[j].x[0], 0.25,
                "slot {j} restarts from the base"
            );
        }
        // The winner's probability moves to slot 0 and the old base's to the tach1 toggle; the
        // old one-failure hypotheses keep theirs, the new two-failure ones start at the
        // switching prior.
        let floor = h.config.switch / 9.0;
        let total = 1.0 + 4.0 * floor;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b;
        assert!(close(h.bank.probability[0], 0.9 / total));
        assert!(close(h.bank.probability[3], 0.1 / total));
        assert!(close(h.bank.probability[1], floor / total));
        assert_eq!(h.bank.probability[8], 0.0);
        // A swap: encoder 1, not tachometer 1, failed. The old base becomes the tach1 swap.
        h.rebase(6);
        assert_eq!(h.failed_channels().collect::<Vec<_>>(), vec![0]);
        assert_eq!(
            h.bank.filters[8].x[0], 0.25,
            "the old base is the swap back to tach1"
        );
        assert!(!h.bank.active[6] && h.bank.active[8]);
        // A second failure on top (the camera), then the end of the first: the sets stay the
        // base, its toggles and the swaps of its last failure.
        h.rebase(5);
        assert_eq!(h.failed_channels().collect::<Vec<_>>(), vec![0, 4]);
        h.rebase(1);
        assert_eq!(h.failed_channels().collect::<Vec<_>>(), vec![4]);
        assert_eq!(
            sets(&h),
            vec![
                (0, vec![4]),
                (1, vec![0, 4]),
                (2, vec![1, 4]),
                (3, vec![2, 4]),
                (4, vec![3, 4]),
                (5, vec![]),
                (6, vec![0]),
                (7, vec![1]),
                (8, vec![2]),
                (9, vec![3])
            ]
        );
        let total: f64 = h.bank.probability.iter().sum();
        assert!((total - 1.0).abs() < 1e-12);
    }

    /// A resync while a failure is accepted restarts every toggle from the base, and a swap
    /// only when the data do not favour it: a favoured swap is the rival explanation of the
    /// accepted failure and keeps the state it gathered.
    #[test]
    fn a_resync_keeps_the_favoured_swaps_and_restarts_the_rest() {
        let mut h = toy_hybrid();
        h.bank.probability = vec![0.1, 0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        h.rebase(3);
        // The base holds tach1 (channel 2) failed; slot 7 is "enc2 failed instead", slot 9
        // "tach2 failed instead", slot 2 the toggle "enc2 failed too".
        h.bank.filters[0].x[0] = 0.25;
        for j in [2, 7, 9] {
            h.bank.filters[j].x[0] = 0.5;
        }
        let floor = h.config.switch / 9.0;
        h.bank.probability[7] = 100.0 * floor;
        h.bank.probability[2] = 100.0 * floor;
        h.bank.probability[9] = floor;
        h.resync();
        assert_eq!(
            h.bank.filters[7].x[0], 0.5,
            "a favoured swap keeps its state"
        );
        assert_eq!(
            h.bank.filters[2].x[0], 0.25,
            "a toggle restarts, favoured or not"
        );
        assert_eq!(
            h.bank.filters[9].x[0], 0.25,
            "a swap the data do not favour restarts"
        );
    }

    /// The rule behind re-anchoring (`distrusts_more`, the belief is re-anchored only on a
    /// winner that drops a channel the last winner trusted): a swap or a new failure does, a
    /// failure that ended or a withdrawn blame does not. This tests the rule, not its call in
    /// `update`.
    #[test]
    fn the_re_anchoring_rule_only_takes_a_winner_that_drops_a_trusted_channel() {
        let mut h = toy_hybrid();
        // Slots 0 (nothing failed) and 3 (tach1 failed).
        assert!(h.distrusts_more(3, 0));
        assert!(!h.distrusts_more(0, 3));
        h.bank.probability = vec![0.1, 0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        h.rebase(3);
        // Base {tach1}; slot 3 is "tach1 came back", slot 6 "enc1 instead of tach1", slot 1
        // "enc1 failed too".
        assert!(!h.distrusts_more(3, 0), "a failure that ended");
        assert!(h.distrusts_more(6, 0), "a swap drops enc1");
        assert!(h.distrusts_more(1, 0), "a second failure");
        assert!(!h.distrusts_more(0, 1), "back from a second failure");
    }

    /// The stuck component's evidence against a direct evaluation of
    /// ln((1 - w) + w N(y; y_last, (width sigma)^2) / N(y; prediction, S)) with full Gaussian
    /// densities: a repeated reading favours "failed" by many nats, a reading that moved by one
    /// sigma costs ln(1 - w), and a hypothesis that trusts the channel adds nothing.
    #[test]
    fn a_repeated_reading_is_evidence_that_the_channel_is_stuck() {
        let mut h = toy_hybrid();
        let readings = Readings {
            values: vec![
                Some(0.1),
                Some(0.2),
                Some(0.01),
                Some(0.0),
                Some(0.3),
                Some(0.4),
            ],
        };
        let precisions = h.nominal.clone();
        let input = EstimatorInput {
            tick: 1,
            readings: &readings,
            precisions: &precisions,
            applied_torques: &[0.0, 0.0],
        };
        for f in &mut h.bank.filters {
            f.initialise(&readings, &[1e-6, 1e-6, 1e-6, 1e-6, 1e-4, 1e-4]);
        }
        h.bank.linearise();
        // Slot 3 holds tachometer 1 (channel 2) failed; slot 0 trusts it.
        h.hypothesis_variances(3, &input);
        assert_eq!(
            h.stuck_evidence(3, &h.bank.filters[3], &input),
            0.0,
            "no last reading yet"
        );
        let sigma = 1e-3;
        let w = h.config.stuck_weight;
        let direct = |h: &Hybrid, y: f64, last: f64| {
            let gauss = |x: f64, m: f64, v: f64| {
                (-(x - m) * (x - m) / (2.0 * v)).exp() / (2.0 * std::f64::consts::PI * v).sqrt()
            };
            let f = &h.bank.filters[3];
            let s = f.projected_variance(2) + h.variances[2];
            let width = (h.config.stuck_width * sigma).powi(2);
            ((1.0 - w) + w * gauss(y, last, width) / gauss(y, f.predicted(2), s)).ln()
        };
        h.last.copy_from_slice(&readings.values);
        let repeated = h.stuck_evidence(3, &h.bank.filters[3], &input);
        assert!((repeated - direct(&h, 0.01, 0.01)).abs() < 1e-9 * repeated.abs());
        assert!(repeated > 9.0, "{repeated}");
        h.last[2] = Some(0.01 - sigma);
        let moved = h.stuck_evidence(3, &h.bank.filters[3], &input);
        assert!((moved - (1.0 - w).ln()).abs() < 1e-12, "{moved}");
        assert!((moved - direct(&h, 0.01, 0.01 - sigma)).abs() < 1e-12);
        h.last.copy_from_slice(&readings.values);
        h.hypothesis_variances(0, &input);
        assert_eq!(
            h.stuck_evidence(0, &h.bank.filters[0], &input),
            0.0,
            "H_0 trusts every channel"
        );
    }
}
