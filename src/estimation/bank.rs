//! A bank of hypotheses about which sensors have failed, each a Kalman filter on the same models,
//! weighed by Bayesian model comparison: the core the IMM ([`super::imm`]) and the hybrid
//! ([`super::hybrid`]) share.
//!
//! Every tick: the switching prior moves probability between the active hypotheses (stay with
//! 1 - s, leave to each other with s / (m - 1)); every active hypothesis predicts with one
//! evaluation of the transition model (each may scale its process noise: the IMM's manoeuvre
//! hypothesis); the camera is linearised once for hypotheses whose positions agree
//! ([`super::kalman::linearise_bank`]); each updates with its own noise variances and its log
//! evidence (the innovation log-likelihood) weighs it, p_j <- p_j exp(ll_j) / sum.
//!
//! What stays with each estimator: the IMM mixes the states before predicting (its interaction
//! step) and reports the mixture; the hybrid rebases its bank on accepted failures, restarts
//! hypotheses at resyncs, adds the evidence of a stuck reading, and drives the u-AIC's
//! precisions from it. Their probability floors differ for a reason of their own
//! ([`Floor`]).

use super::kalman::{Ekf, linearise_bank};
use super::models::Transition;

/// The least probability a hypothesis keeps after an update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    pub value: f64,
    /// Divide by the new total after flooring (the IMM's probabilities stay a distribution
    /// exactly); without, the floor only guards against underflow (the hybrid's 1e-300, where the
    /// switching prior already keeps every hypothesis revivable).
    pub renormalise: bool,
}

/// The hypotheses: their filters, probabilities and whether each is in play.
#[derive(Clone)]
pub struct HypothesisBank {
    pub filters: Vec<Ekf>,
    pub probability: Vec<f64>,
    /// Which slots are in play (the hybrid's swap slots only while a failure is accepted; the
    /// IMM's always).
    pub active: Vec<bool>,
    /// Each hypothesis' log evidence this tick (NEG_INFINITY for inactive slots).
    pub log_evidence: Vec<f64>,
}

impl HypothesisBank {
    /// `count` copies of `template` with probabilities `prior`, the first `active` of them in
    /// play.
    pub fn new(template: Ekf, prior: Vec<f64>, active: usize) -> Self {
        let count = prior.len();
        let mut flags = vec![false; count];
        flags[..active].fill(true);
        Self {
            filters: vec![template; count],
            probability: prior,
            active: flags,
            log_evidence: vec![0.0; count],
        }
    }

    pub fn len(&self) -> usize {
        self.filters.len()
    }

    pub fn is_empty(&self) -> bool {
        self.filters.is_empty()
    }

    /// Active hypotheses.
    pub fn active_count(&self) -> usize {
        self.active.iter().filter(|&&a| a).count()
    }

    /// The switching prior: p_j <- (1 - s) p_j + s / (m - 1) (total - p_j) over the m active
    /// hypotheses (a symmetric Markov chain: sum_i pi_ij p_i).
    pub fn switch(&mut self, s: f64) {
        let m = self.active_count();
        let leave = s / (m - 1) as f64;
        let total: f64 = self.probability.iter().sum();
        for (p, _) in self
            .probability
            .iter_mut()
            .zip(&self.active)
            .filter(|(_, a)| **a)
        {
            *p = (1.0 - s) * *p + leave * (total - *p);
        }
    }

    /// Predicts every active hypothesis one tick with the transition, hypothesis j's process
    /// noise scaled by `scale(j)`.
    pub fn predict(&mut self, transition: &Transition<'_>, scale: impl Fn(usize) -> f64) {
        self.predict_per_joint(transition, |j, _| scale(j));
    }

    /// [`Self::predict`] with hypothesis j's process noise on joint i scaled by `scale(j, i)`
    /// (the hybrid's actuator hypotheses: a joint whose torque is not the commanded one).
    pub fn predict_per_joint(
        &mut self,
        transition: &Transition<'_>,
        scale: impl Fn(usize, usize) -> f64,
    ) {
        for (j, (f, _)) in self
            .filters
            .iter_mut()
            .zip(&self.active)
            .enumerate()
            .filter(|(_, (_, a))| **a)
        {
            f.predict_scaled(transition, |i| scale(j, i));
        }
    }

    /// Linearises the camera of every active hypothesis, sharing evaluations.
    pub fn linearise(&mut self) {
        linearise_bank(&mut self.filters, Some(&self.active));
    }

    /// Bayes' rule with this tick's log evidence: p_j <- p_j exp(ll_j - max) / total over the
    /// active hypotheses, then the floor. Returns the total (sum_j p_j exp(ll_j - max) before
    /// the division: with the largest log evidence it is this tick's evidence of the bank).
    pub fn weigh(&mut self, floor: Floor) -> f64 {
        let best = self
            .log_evidence
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for j in 0..self.len() {
            if self.active[j] {
                self.probability[j] *= (self.log_evidence[j] - best).exp();
                total += self.probability[j];
            }
        }
        for (p, _) in self
            .probability
            .iter_mut()
            .zip(&self.active)
            .filter(|(_, a)| **a)
        {
            *p = (*p / total).max(floor.value);
        }
        if floor.renormalise {
            let sum: f64 = self.probability.iter().sum();
            for p in &mut self.probability {
                *p /= sum;
            }
        }
        total
    }

    /// The largest log evidence of this tick.
    pub fn best_log_evidence(&self) -> f64 {
        self.log_evidence
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// The most probable hypothesis (the last of equals).
    pub fn most_probable(&self) -> usize {
        (0..self.len())
            .max_by(|&a, &b| self.probability[a].total_cmp(&self.probability[b]))
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::{CameraModel, ChannelLayout};
    use nalgebra::{DMatrix, DVector};
    use std::sync::Arc;

    /// Four hypotheses with distinct states (hypothesis j's mean and covariance scale with j + 1).
    fn bank(probability: Vec<f64>) -> HypothesisBank {
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let observation = crate::estimation::models::GpCamera::shared(
            layout,
            Arc::new(crate::gp::GpModel::toy()),
        );
        let h = probability.len();
        let mut b = HypothesisBank::new(Ekf::new(observation, 1e-3), probability, h);
        for (j, f) in b.filters.iter_mut().enumerate() {
            let s = j as f64 + 1.0;
            f.x = DVector::from_fn(4, |r, _| s * (0.1 + 0.05 * r as f64));
            f.p = DMatrix::identity(4, 4) * (1e-4 * s);
        }
        b
    }
    /// The switching prior is the symmetric Markov chain over the active hypotheses: it keeps
    /// the total, moves p_j to (1 - s) p_j + s / (m - 1) (total - p_j), leaves inactive slots
    /// alone, and its fixed point is the uniform distribution.
    #[test]
    fn the_switching_prior_is_a_symmetric_markov_chain() {
        let mut b = bank(vec![0.7, 0.2, 0.1, 0.0]);
        b.active[3] = false;
        b.switch(0.3);
        let expect = [
            0.7 * 0.7 + 0.15 * 0.3,
            0.7 * 0.2 + 0.15 * 0.8,
            0.7 * 0.1 + 0.15 * 0.9,
        ];
        for (p, e) in b.probability.iter().zip(expect) {
            assert!((p - e).abs() < 1e-15, "{p} {e}");
        }
        assert_eq!(b.probability[3], 0.0);
        assert!((b.probability.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        let mut u = bank(vec![0.25; 4]);
        u.switch(0.3);
        assert!(u.probability.iter().all(|p| (p - 0.25).abs() < 1e-15));
    }
}
