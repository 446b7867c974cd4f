//! The paper's precision learners, each per channel on post-update residuals (docs/method.md,
//! "Precision learning"): the gradient rule of the seed paper, and its future work, a Gamma
//! posterior with forgetting and a window of recent residuals. Each finds omega = 1/E[e^2 + c]
//! at its fixed point (tested below against residuals of known variance).

use super::{PrecisionBounds, PrecisionInput, PrecisionMethod};

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

impl PrecisionMethod for Fixed {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, _: &PrecisionInput<'_>) {}
}

/// `gradient`: the paper's rule, omega = exp(zeta), zeta_dot = -kappa_zeta dF/dzeta with
/// dF/dzeta = 1/2 (omega (e^2 + c) - 1), Euler at dt (seed paper eq. 7; docs/method.md,
/// "Gradient rule"). Its fixed point is omega = 1 / (e^2 + c) on average.
pub struct Gradient {
    nominal: Vec<f64>,
    omega: Vec<f64>,
    kappa_zeta: f64,
    correct: bool,
    bounds: PrecisionBounds,
}

impl Gradient {
    pub fn new(nominal: &[f64], kappa_zeta: f64, correct: bool, bounds: PrecisionBounds) -> Self {
        Self {
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
            kappa_zeta,
            correct,
            bounds,
        }
    }
}

impl PrecisionMethod for Gradient {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
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

/// `bayes`: a Gamma posterior per channel with forgetting (the seed's future work, sec. 5; the
/// scalar core of Sarkka & Nummenmaa 2009; docs/method.md, "Bayesian precision"): a <- rho a + 1/2, b <- rho b + (e^2 + c)/2,
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

impl PrecisionMethod for Bayes {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
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

impl PrecisionMethod for Window {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::precision::testing::feed;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn feed_noise(learner: &mut dyn PrecisionMethod, sigma: f64, c: f64, ticks: u64, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for tick in 0..ticks {
            let z: f64 = StandardNormal.sample(&mut rng);
            feed(learner, tick, &[Some(sigma * z)], &[c], &[None]);
        }
    }

    fn open() -> PrecisionBounds {
        PrecisionBounds {
            min_ratio: 1e-9,
            max_ratio: 1e9,
        }
    }

    /// Residuals of known variance sigma^2 (nominal 1, clamp open): omega -> 1/sigma^2, each
    /// learner's fixed point.
    #[test]
    fn every_learner_finds_the_precision_of_residuals_of_known_variance() {
        let sigma: f64 = 0.5; // true precision 4
        let learners: Vec<(&str, Box<dyn PrecisionMethod>)> = vec![
            (
                "gradient",
                Box::new(Gradient::new(&[1.0], 10.0, false, open())),
            ),
            ("bayes", Box::new(Bayes::new(&[1.0], 0.999, false, open()))),
            ("window", Box::new(Window::new(&[1.0], 1000, false, open()))),
        ];
        for (name, mut learner) in learners {
            // Average the precision over a long run.
            let mut sum = 0.0;
            let rounds = 200;
            for round in 0..rounds {
                feed_noise(learner.as_mut(), sigma, 0.0, 1000, 1 + round);
                sum += learner.precisions()[0];
            }
            let mean = sum / rounds as f64;
            assert!((mean - 4.0).abs() < 0.4, "{name}: {mean}");
        }
    }

    /// Post-update residuals shrink toward the belief; the correction c restores the variance.
    #[test]
    fn the_correction_removes_the_over_confidence() {
        // Two equal sensors of sigma = 1 averaged: residual variance 1/2, posterior variance 1/2.
        let shrunk = 0.5f64.sqrt();
        for correct in [false, true] {
            let learners: Vec<(&str, Box<dyn PrecisionMethod>)> = vec![
                (
                    "gradient",
                    Box::new(Gradient::new(&[1.0], 10.0, correct, open())),
                ),
                (
                    "bayes",
                    Box::new(Bayes::new(&[1.0], 0.999, correct, open())),
                ),
                (
                    "window",
                    Box::new(Window::new(&[1.0], 1000, correct, open())),
                ),
            ];
            for (name, mut learner) in learners {
                let mut sum = 0.0;
                for round in 0..200 {
                    feed_noise(learner.as_mut(), shrunk, 0.5, 1000, round);
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
        let mut learners: Vec<Box<dyn PrecisionMethod>> = vec![
            Box::new(Gradient::new(&[1e6], 10.0, true, bounds)),
            Box::new(Bayes::new(&[1e6], 0.999, true, bounds)),
            Box::new(Window::new(&[1e6], 100, true, bounds)),
        ];
        for learner in &mut learners {
            // Tiny residuals: the precision may not rise above nominal.
            for tick in 0..5000 {
                feed(learner.as_mut(), tick, &[Some(1e-7)], &[0.0], &[None]);
                assert!(learner.precisions()[0] <= 1e6);
            }
            // A frozen sensor's residual of 0.1 (100 sigma): the precision collapses to the floor.
            for tick in 0..5000 {
                feed(learner.as_mut(), tick, &[Some(0.1)], &[0.0], &[None]);
            }
            let w = learner.precisions()[0];
            assert!((1.0 - 1e-9..1e3).contains(&w), "{w}");
        }
    }

    #[test]
    fn missing_residuals_leave_the_precision_alone() {
        let mut learner = Window::new(&[1.0], 10, false, PrecisionBounds::default());
        feed(&mut learner, 0, &[None], &[0.0], &[None]);
        assert_eq!(learner.precisions()[0], 1.0);
    }
}
