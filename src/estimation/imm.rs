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

use super::bank::{Floor, HypothesisBank};
use super::kalman::{Ekf, KalmanConfig};
use super::models::TransitionModel;
use super::{Estimate, Estimator, EstimatorInput};

/// The IMM's probability floor: 1e-12, renormalised, so that a hypothesis is never lost to
/// rounding and the probabilities stay a distribution (Blom and Bar-Shalom 1988).
const FLOOR: Floor = Floor {
    value: 1e-12,
    renormalise: true,
};

/// The multiple-model estimator.
pub struct Imm {
    bank: HypothesisBank,
    /// Per hypothesis: each channel's noise variance (infinite: left out by the caller).
    variances: Vec<Vec<f64>>,
    switch: f64,
    model: Box<dyn TransitionModel>,
    /// The manoeuvre hypothesis' index and its process-noise multiple.
    manoeuvre: Option<(usize, f64)>,
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
}

impl Imm {
    /// A bank built from `template`, one hypothesis per channel, predicting with `model`.
    pub fn new(
        template: Ekf,
        config: &KalmanConfig,
        model: Box<dyn TransitionModel>,
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
        if manoeuvre {
            variances.push(base.clone());
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
            bank: HypothesisBank::new(template, probability, hypotheses),
            variances,
            switch: config.imm_switch,
            model,
            manoeuvre: manoeuvre.then_some((m + 1, config.imm_manoeuvre)),
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

    /// Predicts every hypothesis one tick with one evaluation of the transition model at the
    /// combined belief, the manoeuvre hypothesis' process noise scaled by its multiple.
    fn predict_bank(&mut self, torques: &[f64]) {
        let transition = self.model.evaluate(self.x.as_slice(), torques);
        let manoeuvre = self.manoeuvre;
        self.bank.predict(&transition, |j| match manoeuvre {
            Some((k, scale)) if k == j => scale,
            _ => 1.0,
        });
    }

    /// Each hypothesis' probability: H_0 first, then one per channel.
    pub fn probabilities(&self) -> &[f64] {
        &self.bank.probability
    }

    /// The hypotheses' mixture of means and covariances into (x, p).
    fn combine(&mut self) {
        let bank = &self.bank;
        self.x.fill(0.0);
        for (f, w) in bank.filters.iter().zip(&bank.probability) {
            self.x.axpy(*w, &f.x, 1.0);
        }
        self.p.fill(0.0);
        for (f, w) in bank.filters.iter().zip(&bank.probability) {
            add_spread(&mut self.p, *w, &f.p, &f.x, &self.x);
        }
    }
}

/// Mixing weights below this are left out (their share of a mean or covariance is below
/// rounding).
const MIX_FLOOR: f64 = 1e-15;

/// target += w (p + (x - mean)(x - mean)'), without temporaries. Compiled a second time for
/// AVX2 and chosen at run time, as `kalman`'s downdate: every entry is the same rounded
/// operations in the same order, so the result is bit for bit the same on every x86-64 machine.
fn add_spread(
    target: &mut DMatrix<f64>,
    w: f64,
    p: &DMatrix<f64>,
    x: &DVector<f64>,
    mean: &DVector<f64>,
) {
    let d = x.len();
    let (target, p) = (target.as_mut_slice(), p.as_slice());
    let (x, mean) = (x.as_slice(), mean.as_slice());
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2 (checked just above).
        unsafe { add_spread_avx2(target, w, p, x, mean, d) };
        return;
    }
    add_spread_portable(target, w, p, x, mean, d);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn add_spread_avx2(target: &mut [f64], w: f64, p: &[f64], x: &[f64], mean: &[f64], d: usize) {
    add_spread_portable(target, w, p, x, mean, d);
}

/// Column-major d x d `target` and `p`.
#[inline(always)]
fn add_spread_portable(target: &mut [f64], w: f64, p: &[f64], x: &[f64], mean: &[f64], d: usize) {
    for ((t, pc), (xb, mb)) in target
        .chunks_exact_mut(d)
        .zip(p.chunks_exact(d))
        .zip(x.iter().zip(mean))
    {
        let db = xb - mb;
        for (((t, pv), xa), ma) in t.iter_mut().zip(pc).zip(x).zip(mean) {
            *t += w * (pv + (xa - ma) * db);
        }
    }
}

impl Estimator for Imm {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        let h = self.bank.len();
        let m = self.nominal.len();
        // Channels the caller leaves out (precision 0) are left out of every hypothesis.
        let precisions = input.precisions;
        let off = |c: usize| precisions[c] <= 0.0;
        let variance = |hyp: &[f64], c: usize| if off(c) { f64::INFINITY } else { hyp[c] };
        if !self.initialised {
            for (f, v) in self.bank.filters.iter_mut().zip(&self.variances) {
                let vv: Vec<f64> = (0..m).map(|c| variance(v, c)).collect();
                f.initialise(input.readings, &vv);
            }
            self.initialised = true;
        } else {
            // Mixing: c_j = sum_i pi_ij p_i; each filter restarts from the mixture conditioned on j.
            let stay = 1.0 - self.switch;
            let leave = self.switch / (h - 1) as f64;
            let pi = |i: usize, j: usize| if i == j { stay } else { leave };
            let bank = &mut self.bank;
            for j in 0..h {
                let cj: f64 = (0..h).map(|i| pi(i, j) * bank.probability[i]).sum();
                // Weights below 1e-15 move the mixture by less than rounding: skipped.
                self.mixed_x[j].fill(0.0);
                for i in 0..h {
                    let w = pi(i, j) * bank.probability[i] / cj;
                    if w >= MIX_FLOOR {
                        self.mixed_x[j].axpy(w, &bank.filters[i].x, 1.0);
                    }
                }
                self.mixed_p[j].fill(0.0);
                for i in 0..h {
                    let w = pi(i, j) * bank.probability[i] / cj;
                    if w >= MIX_FLOOR {
                        let f = &bank.filters[i];
                        add_spread(&mut self.mixed_p[j], w, &f.p, &f.x, &self.mixed_x[j]);
                    }
                }
            }
            for j in 0..h {
                bank.filters[j].x.copy_from(&self.mixed_x[j]);
                bank.filters[j].p.copy_from(&self.mixed_p[j]);
            }
            // With a symmetric switching matrix, sum_i pi_ij p_i = stay p_j + leave (1 - p_j).
            bank.switch(self.switch);
            self.predict_bank(input.applied_torques);
        }
        self.bank.linearise();
        let bank = &mut self.bank;
        for (j, f) in bank.filters.iter_mut().enumerate() {
            for c in 0..m {
                self.scratch[c] = variance(&self.variances[j], c);
            }
            if j == 0 {
                f.record_innovations(input.readings, &self.scratch);
            }
            bank.log_evidence[j] = f.update(input.readings, &self.scratch);
        }
        let best = bank.best_log_evidence();
        let total = bank.weigh(FLOOR);
        self.combine();
        // Report: innovations of H_0's prediction; residuals at the combined belief.
        self.report
            .innovations
            .clone_from(&self.bank.filters[0].innovation);
        self.report
            .innovation_variances
            .clone_from(&self.bank.filters[0].innovation_variance);
        self.combined.x.copy_from(&self.x);
        self.combined.p.copy_from(&self.p);
        self.combined.linearise();
        self.combined
            .report_posterior(input.readings, &mut self.report);
        for c in 0..m {
            self.used[c] = if off(c) {
                0.0
            } else {
                self.nominal[c] * (1.0 - self.bank.probability[c + 1])
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

    /// The mixing's spread, as chosen at run time (AVX2 where the processor has it), is bit for
    /// bit the entry-by-entry formula on the sizes the banks use.
    #[test]
    fn the_spread_is_the_entrywise_formula_bit_for_bit() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand::rngs::StdRng::seed_from_u64(43);
        let normal = Normal::new(0.0, 1.0).unwrap();
        for d in [2, 3, 4, 6, 9, 14, 21] {
            let mut draw =
                |r: usize, c: usize| DMatrix::from_fn(r, c, |_, _| normal.sample(&mut rng));
            let (t0, p) = (draw(d, d), draw(d, d));
            let (x, mean) = (
                DVector::from(draw(d, 1).column(0)),
                DVector::from(draw(d, 1).column(0)),
            );
            let w = 0.37;
            let mut expected = t0.clone();
            for b in 0..d {
                let db = std::hint::black_box(x[b] - mean[b]);
                for a in 0..d {
                    let spread = std::hint::black_box((x[a] - mean[a]) * db);
                    expected[(a, b)] += std::hint::black_box(w * (p[(a, b)] + spread));
                }
            }
            let mut fast = t0.clone();
            add_spread(&mut fast, w, &p, &x, &mean);
            for (u, v) in fast.iter().zip(expected.iter()) {
                assert_eq!(u.to_bits(), v.to_bits(), "d = {d}");
            }
        }
    }

    /// With the arm model every hypothesis predicts with the model's acceleration at the
    /// combined belief, and the manoeuvre hypothesis' process noise is the model's times
    /// `imm_manoeuvre`: from equal states, its velocity variance grows by imm_manoeuvre^2 times
    /// the others' growth, s^2 dt^2 with s = max(2, 0.1 |qdd|) (docs/method.md, "Classical
    /// baselines").
    #[test]
    fn the_bank_predicts_with_the_arm_model_and_scales_the_manoeuvre_noise() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/planar_2dof.urdf");
        let model = crate::arm::load_urdf(&path).unwrap();
        let g = [0.0, 0.0, -9.81];
        let config = KalmanConfig {
            process_model: ProcessModel::Dynamics,
            ..KalmanConfig::default()
        };
        let layout = ChannelLayout::new(2, CameraModel::Pinhole);
        let dt = 1e-3;
        let observation = crate::estimation::models::GpCamera::shared(
            layout,
            Arc::new(crate::gp::GpModel::toy()),
        );
        let template = Ekf::new(observation, dt);
        let nominal = vec![1e6; layout.len()];
        let model = Arc::new(model);
        let noise = crate::arm::ModelConfig::perfect();
        let prediction = crate::estimation::kalman::transition_model(
            ProcessModel::Dynamics,
            model.clone(),
            g,
            &noise,
            200.0,
            1e-3,
        );
        let mut imm = Imm::new(template, &config, prediction, &nominal);
        let x = [0.3, -0.7, 0.5, -1.0];
        let u = [40.0, -3.0];
        imm.x.copy_from_slice(&x);
        for f in &mut imm.bank.filters {
            f.x.copy_from_slice(&x);
            f.p.fill_with_identity();
        }
        imm.predict_bank(&u);
        let mut direct = crate::arm::Dynamics::new(model, g);
        let mut acc = vec![0.0; 2];
        // The default step (`model.step = "implicit"`): damping at the tick's end.
        assert!(direct.forward_dynamics_implicit(&x[..2], &x[2..], &u, dt, &mut acc));
        let (k, scale) = imm.manoeuvre.expect("a manoeuvre hypothesis by default");
        assert_eq!(k, imm.bank.len() - 1);
        for (j, f) in imm.bank.filters.iter().enumerate() {
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
