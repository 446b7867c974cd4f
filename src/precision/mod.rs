//! Precision learners: one precision (inverse variance) per sensory channel, learned online so
//! that a failing sensor loses its weight in the free energy (METHOD.md section 5).
//!
//! Every learner starts at the nominal precision 1/sigma^2 of each channel and clamps to
//! [omega_min, omega_max] = [1e-6, 1] x nominal by default: a sensor is never trusted beyond its
//! datasheet (without the upper clamp the tachometers' precisions drift up forever, because
//! their post-update residual is far below their noise), and learning can only take weight
//! away. Precisions set to exactly 0 (deterministic recovery, the oracle) leave the channel out
//! of the free energy. A channel's health is omega / omega_nominal, in [0, 1].

pub mod detector;

use serde::{Deserialize, Serialize};

pub use detector::{
    Calibration, CalibrationAccumulator, Detection, Detector, DetectorConfig, Isolation,
};

/// What a learner sees after each tick's belief update.
#[derive(Clone, Copy, Debug)]
pub struct LearnerInput<'a> {
    pub tick: u64,
    pub dt: f64,
    /// Post-update residual per channel (`None`: missing this tick, no update).
    pub residuals: &'a [Option<f64>],
    /// Posterior-variance correction c_i = (J H^-1 J')_ii per channel.
    pub corrections: &'a [f64],
    /// The fault detector's state (alarm, isolated channels).
    pub detection: &'a Detection,
}

impl LearnerInput<'_> {
    /// (channel, e^2 [+ c]) for every channel with a residual this tick; the posterior-variance
    /// correction c is added when `correct` is set.
    pub fn squared_residuals(&self, correct: bool) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.residuals
            .iter()
            .zip(self.corrections)
            .enumerate()
            .filter_map(move |(c, (e, corr))| {
                e.map(|e| (c, e * e + if correct { *corr } else { 0.0 }))
            })
    }
}

/// A precision learner: one scalar precision per channel.
pub trait PrecisionLearner: Send {
    /// The precisions to use for the next tick.
    fn precisions(&self) -> &[f64];
    /// Learns from the tick's residuals.
    fn update(&mut self, input: &LearnerInput<'_>);
}

/// Clamp of every learner, as multiples of the nominal precision.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PrecisionBounds {
    pub min_ratio: f64,
    pub max_ratio: f64,
}

impl Default for PrecisionBounds {
    fn default() -> Self {
        Self {
            min_ratio: 1e-6,
            max_ratio: 1.0,
        }
    }
}

impl PrecisionBounds {
    fn clamp(&self, omega: f64, nominal: f64) -> f64 {
        omega.clamp(self.min_ratio * nominal, self.max_ratio * nominal)
    }
}

/// Health of a channel: omega / omega_nominal clamped to [0, 1].
pub fn health(omega: f64, nominal: f64) -> f64 {
    (omega / nominal).clamp(0.0, 1.0)
}

/// `fixed`: the nominal precisions, always (no fault tolerance).
pub struct Fixed {
    omega: Vec<f64>,
}

impl Fixed {
    pub fn new(nominal: &[f64]) -> Self {
        Self {
            omega: nominal.to_vec(),
        }
    }
}

impl PrecisionLearner for Fixed {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, _: &LearnerInput<'_>) {}
}

/// `gradient`: the paper's rule, omega = exp(zeta), zeta_dot = -kappa_zeta dF/dzeta with
/// dF/dzeta = 1/2 (omega (e^2 + c) - 1), Euler at dt (seed paper eq. 7). `gated`: only once
/// the detector has fired (the paper's "PL + FD").
pub struct Gradient {
    nominal: Vec<f64>,
    omega: Vec<f64>,
    kappa_zeta: f64,
    correct: bool,
    gated: bool,
    bounds: PrecisionBounds,
}

impl Gradient {
    pub fn new(
        nominal: &[f64],
        kappa_zeta: f64,
        correct: bool,
        gated: bool,
        bounds: PrecisionBounds,
    ) -> Self {
        Self {
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
            kappa_zeta,
            correct,
            gated,
            bounds,
        }
    }
}

impl PrecisionLearner for Gradient {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &LearnerInput<'_>) {
        if self.gated && input.detection.fired_tick.is_none() {
            return;
        }
        for (c, v) in input.squared_residuals(self.correct) {
            let w = self.omega[c];
            let grad = 0.5 * (w * v - 1.0);
            // The step in zeta is bounded so one outlier cannot overflow exp.
            let step = (input.dt * self.kappa_zeta * grad).clamp(-50.0, 50.0);
            let zeta = w.ln() - step;
            self.omega[c] = self.bounds.clamp(zeta.exp(), self.nominal[c]);
        }
    }
}

/// `deterministic`: nominal precisions until the detector isolates a channel, whose precision
/// then goes to 0 (the ECC baseline).
pub struct Deterministic {
    omega: Vec<f64>,
}

impl Deterministic {
    pub fn new(nominal: &[f64]) -> Self {
        Self {
            omega: nominal.to_vec(),
        }
    }
}

impl PrecisionLearner for Deterministic {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &LearnerInput<'_>) {
        for &c in &input.detection.isolated {
            self.omega[c] = 0.0;
        }
    }
}

/// `bayes`: a Gamma posterior per channel with forgetting (the seed's future work, sec. 5; the
/// scalar core of Sarkka & Nummenmaa 2009): a <- rho a + 1/2, b <- rho b + (e^2 + c)/2,
/// omega = E[omega] = a / b. Starts at the healthy steady state a0 = 1/(2(1 - rho)),
/// b0 = a0 / omega_nominal.
pub struct Bayes {
    nominal: Vec<f64>,
    omega: Vec<f64>,
    a: Vec<f64>,
    b: Vec<f64>,
    rho: f64,
    correct: bool,
    bounds: PrecisionBounds,
}

impl Bayes {
    pub fn new(nominal: &[f64], rho: f64, correct: bool, bounds: PrecisionBounds) -> Self {
        let a0 = 0.5 / (1.0 - rho);
        Self {
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
            a: vec![a0; nominal.len()],
            b: nominal.iter().map(|w| a0 / w).collect(),
            rho,
            correct,
            bounds,
        }
    }
}

impl PrecisionLearner for Bayes {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &LearnerInput<'_>) {
        for (c, v) in input.squared_residuals(self.correct) {
            self.a[c] = self.rho * self.a[c] + 0.5;
            self.b[c] = self.rho * self.b[c] + 0.5 * v;
            self.omega[c] = self.bounds.clamp(self.a[c] / self.b[c], self.nominal[c]);
        }
    }
}

/// `window`: omega = k / sum of the last k (e^2 + c), a ring buffer with a running sum,
/// prefilled with 1 / omega_nominal (the seed's "last k observations").
pub struct Window {
    nominal: Vec<f64>,
    omega: Vec<f64>,
    k: usize,
    buffers: Vec<Vec<f64>>,
    sums: Vec<f64>,
    heads: Vec<usize>,
    correct: bool,
    bounds: PrecisionBounds,
}

impl Window {
    pub fn new(nominal: &[f64], k: usize, correct: bool, bounds: PrecisionBounds) -> Self {
        let k = k.max(1);
        Self {
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
            k,
            buffers: nominal.iter().map(|w| vec![1.0 / w; k]).collect(),
            sums: nominal.iter().map(|w| k as f64 / w).collect(),
            heads: vec![0; nominal.len()],
            correct,
            bounds,
        }
    }
}

impl PrecisionLearner for Window {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &LearnerInput<'_>) {
        for (c, v) in input.squared_residuals(self.correct) {
            let head = self.heads[c];
            self.sums[c] += v - self.buffers[c][head];
            self.buffers[c][head] = v;
            self.heads[c] = (head + 1) % self.k;
            if self.heads[c] == 0 {
                // Re-sum once per lap: the running sum never drifts by rounding.
                self.sums[c] = self.buffers[c].iter().sum();
            }
            self.omega[c] = self
                .bounds
                .clamp(self.k as f64 / self.sums[c], self.nominal[c]);
        }
    }
}

/// `oracle`: told the faulty channels and the fault's first tick, sets their precision to 0
/// exactly then. Not a method a user could run: the reference every method is measured against.
pub struct Oracle {
    omega: Vec<f64>,
    channels: Vec<usize>,
    tick: u64,
}

impl Oracle {
    pub fn new(nominal: &[f64], channels: Vec<usize>, tick: u64) -> Self {
        Self {
            omega: nominal.to_vec(),
            channels,
            tick,
        }
    }
}

impl PrecisionLearner for Oracle {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &LearnerInput<'_>) {
        // Called after tick k: the precisions it leaves are used from tick k + 1 on.
        if input.tick + 1 >= self.tick {
            for &c in &self.channels {
                self.omega[c] = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn feed(learner: &mut dyn PrecisionLearner, sigma: f64, c: f64, ticks: u64, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let detection = Detection::default();
        for tick in 0..ticks {
            let z: f64 = StandardNormal.sample(&mut rng);
            let residuals = [Some(sigma * z)];
            learner.update(&LearnerInput {
                tick,
                dt: 1e-3,
                residuals: &residuals,
                corrections: &[c],
                detection: &detection,
            });
        }
    }

    /// Residuals of known variance sigma^2 (nominal 1, clamp open): omega -> 1/sigma^2.
    #[test]
    fn every_learner_finds_the_precision_of_residuals_of_known_variance() {
        let open = PrecisionBounds {
            min_ratio: 1e-9,
            max_ratio: 1e9,
        };
        let sigma: f64 = 0.5; // true precision 4
        let learners: Vec<(&str, Box<dyn PrecisionLearner>)> = vec![
            (
                "gradient",
                Box::new(Gradient::new(&[1.0], 10.0, false, false, open)),
            ),
            ("bayes", Box::new(Bayes::new(&[1.0], 0.999, false, open))),
            ("window", Box::new(Window::new(&[1.0], 1000, false, open))),
        ];
        for (name, mut learner) in learners {
            // Average the precision over the second half of a long run.
            let mut sum = 0.0;
            let rounds = 200;
            for round in 0..rounds {
                feed(learner.as_mut(), sigma, 0.0, 1000, 1 + round);
                sum += learner.precisions()[0];
            }
            let mean = sum / rounds as f64;
            assert!((mean - 4.0).abs() < 0.4, "{name}: {mean}");
        }
    }

    /// Post-update residuals shrink toward the belief; the correction c restores the variance.
    #[test]
    fn the_correction_removes_the_over_confidence() {
        let open = PrecisionBounds {
            min_ratio: 1e-9,
            max_ratio: 1e9,
        };
        // Two equal sensors of sigma = 1 averaged: residual variance 1/2, posterior variance 1/2.
        let shrunk = 0.5f64.sqrt();
        for correct in [false, true] {
            let learners: Vec<(&str, Box<dyn PrecisionLearner>)> = vec![
                (
                    "gradient",
                    Box::new(Gradient::new(&[1.0], 10.0, correct, false, open)),
                ),
                ("bayes", Box::new(Bayes::new(&[1.0], 0.999, correct, open))),
                ("window", Box::new(Window::new(&[1.0], 1000, correct, open))),
            ];
            for (name, mut learner) in learners {
                let mut sum = 0.0;
                for round in 0..200 {
                    feed(learner.as_mut(), shrunk, 0.5, 1000, round);
                    sum += learner.precisions()[0];
                }
                let mean = sum / 200.0;
                if correct {
                    assert!((mean - 1.0).abs() < 0.1, "{name} corrected: {mean}");
                } else {
                    assert!((mean - 2.0).abs() < 0.2, "{name} uncorrected: {mean}");
                }
            }
        }
    }

    #[test]
    fn precisions_stay_inside_the_bounds_and_a_large_residual_collapses_them() {
        let bounds = PrecisionBounds::default();
        let mut learners: Vec<Box<dyn PrecisionLearner>> = vec![
            Box::new(Gradient::new(&[1e6], 10.0, true, false, bounds)),
            Box::new(Bayes::new(&[1e6], 0.999, true, bounds)),
            Box::new(Window::new(&[1e6], 100, true, bounds)),
        ];
        let detection = Detection::default();
        for learner in &mut learners {
            // Tiny residuals: the precision may not rise above nominal.
            for tick in 0..5000 {
                learner.update(&LearnerInput {
                    tick,
                    dt: 1e-3,
                    residuals: &[Some(1e-7)],
                    corrections: &[0.0],
                    detection: &detection,
                });
                assert!(learner.precisions()[0] <= 1e6);
            }
            // A frozen sensor's residual of 0.1 (100 sigma): the precision collapses to the floor.
            for tick in 0..5000 {
                learner.update(&LearnerInput {
                    tick,
                    dt: 1e-3,
                    residuals: &[Some(0.1)],
                    corrections: &[0.0],
                    detection: &detection,
                });
            }
            let w = learner.precisions()[0];
            assert!((1.0 - 1e-9..1e3).contains(&w), "{w}");
        }
    }

    #[test]
    fn gated_gradient_waits_for_the_detector() {
        let mut learner = Gradient::new(&[1.0], 10.0, false, true, PrecisionBounds::default());
        let quiet = Detection::default();
        let input = |d| LearnerInput {
            tick: 0,
            dt: 1e-3,
            residuals: &[Some(10.0)],
            corrections: &[0.0],
            detection: d,
        };
        learner.update(&input(&quiet));
        assert_eq!(learner.precisions()[0], 1.0);
        let fired = Detection {
            fired_tick: Some(0),
            ..Detection::default()
        };
        learner.update(&input(&fired));
        assert!(learner.precisions()[0] < 1.0);
    }

    #[test]
    fn missing_residuals_leave_the_precision_alone() {
        let mut learner = Window::new(&[1.0], 10, false, PrecisionBounds::default());
        let d = Detection::default();
        learner.update(&LearnerInput {
            tick: 0,
            dt: 1e-3,
            residuals: &[None],
            corrections: &[0.0],
            detection: &d,
        });
        assert_eq!(learner.precisions()[0], 1.0);
    }

    #[test]
    fn oracle_and_deterministic_zero_their_channels() {
        let d = Detection::default();
        let mut oracle = Oracle::new(&[1.0, 1.0], vec![1], 5);
        for tick in 0..4 {
            oracle.update(&LearnerInput {
                tick,
                dt: 1e-3,
                residuals: &[None, None],
                corrections: &[0.0, 0.0],
                detection: &d,
            });
        }
        assert_eq!(oracle.precisions(), &[1.0, 1.0]);
        oracle.update(&LearnerInput {
            tick: 4,
            dt: 1e-3,
            residuals: &[None, None],
            corrections: &[0.0, 0.0],
            detection: &d,
        });
        assert_eq!(oracle.precisions(), &[1.0, 0.0]);
        let mut det = Deterministic::new(&[1.0, 1.0]);
        let fired = Detection {
            fired_tick: Some(3),
            isolated: vec![0],
            ..Detection::default()
        };
        det.update(&LearnerInput {
            tick: 3,
            dt: 1e-3,
            residuals: &[None, None],
            corrections: &[0.0, 0.0],
            detection: &fired,
        });
        assert_eq!(det.precisions(), &[0.0, 1.0]);
    }
}
