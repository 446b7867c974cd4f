//! `imm`: the interacting-multiple-model estimator (Blom and Bar-Shalom 1988) over sensor-fault
//! hypotheses: H_0 with every channel's nominal noise, and one hypothesis per channel in which
//! that channel's noise standard deviation is `imm_broad` times its nominal (a failed sensor). Each
//! hypothesis is an extended Kalman filter ([`super::kalman::Ekf`]); every tick the filters are
//! mixed with a Markov switching matrix (stay with probability 1 - p, leave to each other with
//! p / (M - 1)), predicted, updated, and weighed by their innovation likelihoods; the belief is the
//! probability-weighted mixture (docs/method.md, "Classical baselines"). A channel's reported
//! precision is its nominal precision times the probability that it is not the failed one. A
//! manoeuvre hypothesis (every sensor nominal, `imm_manoeuvre` times the acceleration noise, the
//! classical IMM's second motion model) takes the common-mode residual of a hard acceleration the
//! constant-velocity model misses, so that it is not read as one sensor failing.

use nalgebra::{DMatrix, DVector};

use super::kalman::{Ekf, KalmanConfig, ModelPrediction, linearise_bank};
use super::{Estimate, Estimator, EstimatorInput};

/// The multiple-model estimator.
pub struct Imm {
    filters: Vec<Ekf>,
    /// Per hypothesis: each channel's noise variance (infinite: left out by the caller).
    variances: Vec<Vec<f64>>,
    probability: Vec<f64>,
    switch: f64,
    model: Option<ModelPrediction>,
    /// The manoeuvre hypothesis' index and its noise multiple (with the arm model, each joint's
    /// process noise is scaled by it).
    manoeuvre: Option<(usize, f64)>,
    /// Scratch: the manoeuvre hypothesis' process noise.
    manoeuvre_noise: Vec<f64>,
    nominal: Vec<f64>,
    x: DVector<f64>,
    p: DMatrix<f64>,
    mixed_x: Vec<DVector<f64>>,
    mixed_p: Vec<DMatrix<f64>>,
    initialised: bool,
    n: usize,
    mu: Vec<f64>,
    mu_p: Vec<f64>,
    report: Estimate,
    used: Vec<f64>,
    /// The mixture as a filter, for the posterior residuals.
    combined: Ekf,
    scratch: Vec<f64>,
    log_like: Vec<f64>,
}

impl Imm {
    /// A bank built from `template` (an EKF with the model's noise), one hypothesis per channel.
    pub fn new(
        template: Ekf,
        config: &KalmanConfig,
        model: Option<ModelPrediction>,
        nominal: &[f64],
    ) -> Self {
        let m = nominal.len();
        let manoeuvre = config.imm_manoeuvre > 0.0;
        let hypotheses = m + 1 + usize::from(manoeuvre);
        let base: Vec<f64> = nominal.iter().map(|w| 1.0 / w).collect();
        let mut variances = vec![base.clone()];
        for c in 0..m {
            let mut v = base.clone();
            v[c] *= config.imm_broad * config.imm_broad;
            variances.push(v);
        }
        let mut filters = vec![template.clone(); hypotheses];
        if manoeuvre {
            variances.push(base.clone());
            let s = template.acceleration_noise() * config.imm_manoeuvre;
            filters[m + 1].set_acceleration_noise(s);
        }
        let mut probability = vec![(1e-3) / (hypotheses - 1) as f64; hypotheses];
        probability[0] = 1.0 - 1e-3;
        let d = template.x.len();
        let n = d / 2;
        let mut report = Estimate::new(&template.layout());
        report.precisions_used = nominal.to_vec();
        Self {
            combined: template.clone(),
            scratch: vec![0.0; m],
            log_like: vec![0.0; hypotheses],
            filters,
            variances,
            probability,
            switch: config.imm_switch,
            model,
            manoeuvre: manoeuvre.then_some((m + 1, config.imm_manoeuvre)),
            manoeuvre_noise: vec![0.0; n],
            nominal: nominal.to_vec(),
            x: DVector::zeros(d),
            p: DMatrix::zeros(d, d),
            mixed_x: vec![DVector::zeros(d); hypotheses],
            mixed_p: vec![DMatrix::zeros(d, d); hypotheses],
            initialised: false,
            n,
            mu: vec![0.0; n],
            mu_p: vec![0.0; n],
            report,
            used: nominal.to_vec(),
        }
    }

    /// Predicts every hypothesis one tick: with the arm model, one model acceleration and
    /// process noise at the combined belief (the manoeuvre hypothesis' noise scaled by its
    /// multiple); without one, or where the model is singular, at constant velocity.
    fn predict_bank(&mut self, torques: &[f64]) {
        match self
            .model
            .as_mut()
            .and_then(|m| m.at(self.x.as_slice(), torques))
        {
            Some((acc, noise)) => {
                for (j, f) in self.filters.iter_mut().enumerate() {
                    match self.manoeuvre {
                        Some((k, scale)) if k == j => {
                            for (s, v) in self.manoeuvre_noise.iter_mut().zip(noise) {
                                *s = scale * v;
                            }
                            f.predict_with_noise(Some(acc), Some(&self.manoeuvre_noise));
                        }
                        _ => f.predict_with_noise(Some(acc), Some(noise)),
                    }
                }
            }
            None => {
                for f in &mut self.filters {
                    f.predict(None);
                }
            }
        }
    }

    /// Each hypothesis' probability: H_0 first, then one per channel.
    pub fn probabilities(&self) -> &[f64] {
        &self.probability
    }

    /// The hypotheses' mixture of means and covariances into (x, p).
    fn combine(&mut self) {
        self.x.fill(0.0);
        for (f, w) in self.filters.iter().zip(&self.probability) {
            self.x.axpy(*w, &f.x, 1.0);
        }
        self.p.fill(0.0);
        for (f, w) in self.filters.iter().zip(&self.probability) {
            add_spread(&mut self.p, *w, &f.p, &f.x, &self.x);
        }
    }
}

/// Mixing weights below this are left out (their share of a mean or covariance is below
/// rounding).
const MIX_FLOOR: f64 = 1e-15;

/// target += w (p + (x - mean)(x - mean)'), without temporaries.
fn add_spread(
    target: &mut DMatrix<f64>,
    w: f64,
    p: &DMatrix<f64>,
    x: &DVector<f64>,
    mean: &DVector<f64>,
) {
    let d = x.len();
    for b in 0..d {
        let db = x[b] - mean[b];
        for a in 0..d {
            target[(a, b)] += w * (p[(a, b)] + (x[a] - mean[a]) * db);
        }
    }
}

impl Estimator for Imm {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        let h = self.filters.len();
        let m = self.nominal.len();
        // Channels the caller leaves out (precision 0) are left out of every hypothesis.
        let precisions = input.precisions;
        let off = |c: usize| precisions[c] <= 0.0;
        let variance = |hyp: &[f64], c: usize| if off(c) { f64::INFINITY } else { hyp[c] };
        if !self.initialised {
            for (f, v) in self.filters.iter_mut().zip(&self.variances) {
                let vv: Vec<f64> = (0..m).map(|c| variance(v, c)).collect();
                f.initialise(input.readings, &vv);
            }
            self.initialised = true;
        } else {
            // Mixing: c_j = sum_i pi_ij p_i; each filter restarts from the mixture conditioned on j.
            let stay = 1.0 - self.switch;
            let leave = self.switch / (h - 1) as f64;
            let pi = |i: usize, j: usize| if i == j { stay } else { leave };
            for j in 0..h {
                let cj: f64 = (0..h).map(|i| pi(i, j) * self.probability[i]).sum();
                // Weights below 1e-15 move the mixture by less than rounding: skipped.
                self.mixed_x[j].fill(0.0);
                for i in 0..h {
                    let w = pi(i, j) * self.probability[i] / cj;
                    if w >= MIX_FLOOR {
                        self.mixed_x[j].axpy(w, &self.filters[i].x, 1.0);
                    }
                }
                self.mixed_p[j].fill(0.0);
                for i in 0..h {
                    let w = pi(i, j) * self.probability[i] / cj;
                    if w >= MIX_FLOOR {
                        let f = &self.filters[i];
                        add_spread(&mut self.mixed_p[j], w, &f.p, &f.x, &self.mixed_x[j]);
                    }
                }
            }
            for j in 0..h {
                self.filters[j].x.copy_from(&self.mixed_x[j]);
                self.filters[j].p.copy_from(&self.mixed_p[j]);
            }
            // With a symmetric switching matrix, sum_i pi_ij p_i = stay p_j + leave (1 - p_j).
            let total: f64 = self.probability.iter().sum();
            for p in &mut self.probability {
                *p = stay * *p + leave * (total - *p);
            }
            self.predict_bank(input.applied_torques);
        }
        linearise_bank(&mut self.filters, None);
        for (j, f) in self.filters.iter_mut().enumerate() {
            for c in 0..m {
                self.scratch[c] = variance(&self.variances[j], c);
            }
            if j == 0 {
                f.record_innovations(input.readings, &self.scratch);
            }
            self.log_like[j] = f.update(input.readings, &self.scratch);
        }
        let log_like = &self.log_like;
        let best = log_like.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut total = 0.0;
        for j in 0..h {
            self.probability[j] *= (log_like[j] - best).exp();
            total += self.probability[j];
        }
        for p in &mut self.probability {
            *p = (*p / total).max(1e-12);
        }
        let sum: f64 = self.probability.iter().sum();
        for p in &mut self.probability {
            *p /= sum;
        }
        self.combine();
        // Report: innovations of H_0's prediction; residuals at the combined belief.
        self.report
            .innovations
            .clone_from(&self.filters[0].innovation);
        self.report
            .innovation_variances
            .clone_from(&self.filters[0].innovation_variance);
        self.combined.x.copy_from(&self.x);
        self.combined.p.copy_from(&self.p);
        self.combined.linearise();
        self.combined
            .report_posterior(input.readings, &mut self.report);
        for c in 0..m {
            self.used[c] = if off(c) {
                0.0
            } else {
                self.nominal[c] * (1.0 - self.probability[c + 1])
            };
        }
        self.report.precisions_used.copy_from_slice(&self.used);
        self.report.log_likelihood = Some(best + total.ln());
        self.report.free_energy = None;
        self.report.finite = self.x.iter().all(|v| v.is_finite());
        let n = self.n;
        if self.report.finite {
            self.mu.copy_from_slice(&self.x.as_slice()[..n]);
            self.mu_p.copy_from_slice(&self.x.as_slice()[n..]);
        }
        &self.report
    }

    fn estimate(&self) -> &Estimate {
        &self.report
    }
    fn mu(&self) -> &[f64] {
        &self.mu
    }
    fn mu_p(&self) -> &[f64] {
        &self.mu_p
    }
    fn covariance(&self) -> Option<&DMatrix<f64>> {
        Some(&self.p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::kalman::ProcessModel;
    use crate::sensors::{CameraModel, ChannelLayout};
    use std::sync::Arc;

    /// With the arm model every hypothesis predicts with the model's acceleration at the
    /// combined belief, and the manoeuvre hypothesis' process noise is the model's times
    /// `imm_manoeuvre`: from equal states, its velocity variance grows by imm_manoeuvre^2 times
    /// the others' growth, s^2 dt^2 with s = max(2, 0.1 |qdd|) (docs/method.md, "Classical
    /// baselines").
    #[test]
    fn the_bank_predicts_with_the_arm_model_and_scales_the_manoeuvre_noise() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
        let model = crate::plant::load_urdf(&path).unwrap();
        let g = [0.0, 0.0, -9.81];
        let config = KalmanConfig {
            process_model: ProcessModel::Dynamics,
            ..KalmanConfig::default()
        };
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let dt = 1e-3;
        let template = Ekf::new(layout, Arc::new(crate::gp::GpModel::toy()), dt, 200.0);
        let nominal = vec![1e6; layout.len()];
        let prediction = ModelPrediction::from_config(&config, &model, g);
        let mut imm = Imm::new(template, &config, prediction, &nominal);
        let x = [0.3, -0.7, 0.5, -1.0];
        let u = [40.0, -3.0];
        imm.x.copy_from_slice(&x);
        for f in &mut imm.filters {
            f.x.copy_from_slice(&x);
            f.p.fill_with_identity();
        }
        imm.predict_bank(&u);
        let mut direct = crate::estimation::kalman::ArmDynamics::new(&model, g, 1.0);
        let acc = direct.acceleration(&x[..2], &x[2..], &u).unwrap().to_vec();
        let (k, scale) = imm.manoeuvre.expect("a manoeuvre hypothesis by default");
        assert_eq!(k, imm.filters.len() - 1);
        for (j, f) in imm.filters.iter().enumerate() {
            for i in 0..2 {
                let v = x[2 + i] + dt * acc[i];
                assert!(
                    (f.x[2 + i] - v).abs() < 1e-15,
                    "hypothesis {j}: {} {v}",
                    f.x[2 + i]
                );
                let s = f64::max(2.0, 0.1 * acc[i].abs()) * if j == k { scale } else { 1.0 };
                let growth = f.p[(2 + i, 2 + i)] - 1.0;
                let want = s * s * dt * dt;
                assert!(
                    (growth - want).abs() < 1e-9 * want.max(1e-12),
                    "hypothesis {j}, joint {i}: {growth} against {want}"
                );
            }
        }
    }
}
