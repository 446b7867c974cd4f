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

    /// The switching prior's better predecessor for each hypothesis, taken as its mean: before
    /// the prior moves probability, hypothesis j is either j all along (weight (1 - s) p_j) or
    /// the most probable hypothesis w switched to j now (weight leave p_w, leave = s / (m - 1));
    /// where the switch weighs more and `eligible(j, w)`, j restarts from w's mean and keeps its
    /// own covariance (a Kalman filter's covariance follows its noise model, not the data). A
    /// hypothesis the data have ruled out since its last restart (p_j below leave p_w / (1 - s))
    /// therefore cannot carry a mean that absorbed the evidence against it, and one that has
    /// beaten the winner since keeps its own (the Viterbi choice of predecessor of a switching
    /// Kalman filter; docs/method.md, "The hybrid"). Returns how many restarted.
    pub fn restart_from_most_probable(
        &mut self,
        s: f64,
        eligible: impl Fn(usize, usize) -> bool,
    ) -> usize {
        let m = self.active_count();
        if m < 2 || s <= 0.0 {
            return 0;
        }
        let leave = s / (m - 1) as f64;
        let w = self.most_probable();
        let jump = leave * self.probability[w];
        let mut restarted = 0;
        for j in 0..self.len() {
            if j == w
                || !self.active[j]
                || (1.0 - s) * self.probability[j] >= jump
                || !eligible(j, w)
            {
                continue;
            }
            let (source, target) = if j < w {
                let (lo, hi) = self.filters.split_at_mut(w);
                (&hi[0], &mut lo[j])
            } else {
                let (lo, hi) = self.filters.split_at_mut(j);
                (&lo[w], &mut hi[0])
            };
            target.x.copy_from(&source.x);
            restarted += 1;
        }
        restarted
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

    /// With s = 3e-3 over four hypotheses (leave = 1e-3) and the winner at 0.9: a hypothesis
    /// below leave p_w / (1 - s) = 9.027e-4 restarts from the winner's state, one above keeps
    /// its own, the winner keeps its own; a restart takes the mean and keeps the covariance; one
    /// not eligible stays; without switching nothing moves.
    #[test]
    fn a_hypothesis_below_the_switching_inflow_restarts_from_the_winner() {
        let p = vec![9.0e-4, 0.9, 9.1e-4, 0.0981];
        let before = bank(p.clone());
        let mut after = before.clone();
        assert_eq!(after.restart_from_most_probable(3e-3, |_, _| true), 1);
        assert_eq!(after.filters[0].x, before.filters[1].x);
        assert_eq!(after.filters[0].p, before.filters[0].p);
        let mut none = before.clone();
        assert_eq!(
            none.restart_from_most_probable(3e-3, |j, w| j != 0 || w != 1),
            0
        );
        assert_eq!(none.filters[0].x, before.filters[0].x);
        for j in 1..4 {
            assert_eq!(after.filters[j].x, before.filters[j].x, "{j}");
            assert_eq!(after.filters[j].p, before.filters[j].p, "{j}");
        }
        assert_eq!(after.probability, p);
        let mut still = before.clone();
        assert_eq!(still.restart_from_most_probable(0.0, |_, _| true), 0);
        assert_eq!(still.filters[0].x, before.filters[0].x);
    }
}
