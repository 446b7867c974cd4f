//! The camera's generative model g_v: Gaussian-process regression from joint angles to the
//! camera's outputs, with a closed-form Jacobian (docs/method.md, "Camera model"; after the
//! ECC paper's eqs. 13-14).
//!
//! Kernel: squared-exponential with one length scale per joint (ARD), shared by both outputs,
//! `k(a, b) = sf^2 exp(-1/2 sum_d (a_d - b_d)^2 / l_d^2)`, plus `sn^2` on the diagonal of K.
//! Mean `g_r(q) = m_r + sum_i k(q, Q_i) alpha_{r,i}` with `alpha_r = K^-1 (Y_r - m_r)`; Jacobian
//! `dg_r/dq_d = -sum_i ((q_d - Q_{i,d}) / l_d^2) k(q, Q_i) alpha_{r,i}`. Hyperparameters maximise
//! the log marginal likelihood (Rasmussen & Williams eqs. 5.8-5.9) with argmin's L-BFGS.

mod fit;
mod training;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use fit::{FitOptions, FitReport};
pub use training::{
    HeldOutError, TrainingSet, derive_box, evaluate_held_out, latin_hypercube, sample_training_set,
};

/// Errors of the GP stage.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpError {
    #[error("GP training needs at least {min} points, got {got}")]
    TooFewPoints { min: usize, got: usize },
    #[error("GP training data: {0}")]
    BadData(String),
    #[error("the GP kernel matrix is not positive definite even with jitter")]
    NotPositiveDefinite,
    #[error("GP hyperparameter optimisation failed: {0}")]
    Optimiser(String),
    #[error("cannot read the GP model")]
    Read(#[from] crate::fsio::FsError),
    #[error("{path}: not a valid GP model: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: the GP model takes {model} joint angles, the arm has {arm} joints")]
    WrongInputs {
        path: PathBuf,
        model: usize,
        arm: usize,
    },
}

/// Kernel hyperparameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hyperparameters {
    /// One length scale per input (rad).
    pub length_scales: Vec<f64>,
    /// Signal standard deviation sf (m).
    pub signal_std: f64,
    /// Noise standard deviation sn (m).
    pub noise_std: f64,
}

/// A trained GP: training inputs, weights and hyperparameters. Predicts without allocating.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpModel {
    /// Number of inputs (joints).
    pub n_inputs: usize,
    /// Number of outputs (2 for the camera).
    pub n_outputs: usize,
    /// Training inputs, N x n_inputs, row-major.
    pub inputs: Vec<f64>,
    /// Weights alpha = K^-1 (Y - mean), N x n_outputs, row-major.
    pub alpha: Vec<f64>,
    /// Mean of each output over the training set (subtracted before the fit).
    pub output_mean: Vec<f64>,
    pub hyperparameters: Hyperparameters,
    /// The joint-space box the training inputs were drawn from, [lower, upper] per joint.
    pub training_box: Vec<[f64; 2]>,
    /// Seed the training set was drawn with (informative).
    pub seed: u64,
    /// Log marginal likelihood at the optimum (informative).
    pub log_marginal_likelihood: f64,
    /// 1 / l_d^2, derived from the hyperparameters.
    #[serde(skip)]
    inv_l2: Vec<f64>,
    /// sf^2, derived.
    #[serde(skip)]
    sf2: f64,
    /// The kernel factor for slope variances, built once on first use ([`Self::slope_factor`]).
    #[serde(skip)]
    factor: FactorCache,
}

/// [`GpModel::slope_factor`]'s cache: derived from the model, so it takes no part in equality,
/// and a clone starts with the factor already built if it was.
#[derive(Clone, Debug, Default)]
struct FactorCache(std::sync::OnceLock<Option<nalgebra::DMatrix<f64>>>);

impl PartialEq for FactorCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl GpModel {
    /// Assembles a model and derives its cached quantities.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn assemble(
        n_inputs: usize,
        n_outputs: usize,
        inputs: Vec<f64>,
        alpha: Vec<f64>,
        output_mean: Vec<f64>,
        hyperparameters: Hyperparameters,
        training_box: Vec<[f64; 2]>,
        seed: u64,
        log_marginal_likelihood: f64,
    ) -> Self {
        let mut m = Self {
            n_inputs,
            n_outputs,
            inputs,
            alpha,
            output_mean,
            hyperparameters,
            training_box,
            seed,
            log_marginal_likelihood,
            inv_l2: Vec::new(),
            sf2: 0.0,
            factor: FactorCache::default(),
        };
        m.derive();
        m
    }

    fn derive(&mut self) {
        self.inv_l2 = self
            .hyperparameters
            .length_scales
            .iter()
            .map(|l| 1.0 / (l * l))
            .collect();
        self.sf2 = self.hyperparameters.signal_std * self.hyperparameters.signal_std;
    }

    /// Number of training points.
    pub fn n_points(&self) -> usize {
        self.alpha.len() / self.n_outputs.max(1)
    }

    /// Predicts the mean `out` (n_outputs) at `q`.
    pub fn predict_mean(&self, q: &[f64], out: &mut [f64]) {
        debug_assert_eq!(q.len(), self.n_inputs);
        let n = self.n_inputs;
        let r = self.n_outputs;
        out.copy_from_slice(&self.output_mean);
        for (x, a) in self.inputs.chunks_exact(n).zip(self.alpha.chunks_exact(r)) {
            let mut s = 0.0;
            for d in 0..n {
                let diff = q[d] - x[d];
                s += diff * diff * self.inv_l2[d];
            }
            let k = self.sf2 * (-0.5 * s).exp();
            for (o, ai) in out.iter_mut().zip(a) {
                *o += k * ai;
            }
        }
    }

    /// Predicts the mean `out` (n_outputs) and the Jacobian `jac` (n_outputs x n_inputs,
    /// row-major: `jac[r * n + d] = dg_r / dq_d`) at `q`, without allocating.
    pub fn predict(&self, q: &[f64], out: &mut [f64], jac: &mut [f64]) {
        debug_assert_eq!(q.len(), self.n_inputs);
        debug_assert_eq!(out.len(), self.n_outputs);
        debug_assert_eq!(jac.len(), self.n_outputs * self.n_inputs);
        // The camera's two outputs with small joint counts get a kernel the compiler can unroll.
        match (self.n_outputs, self.n_inputs) {
            (2, 1) => self.predict_fixed::<1>(q, out, jac),
            (2, 2) => self.predict_fixed::<2>(q, out, jac),
            (2, 3) => self.predict_fixed::<3>(q, out, jac),
            (2, 4) => self.predict_fixed::<4>(q, out, jac),
            (2, 5) => self.predict_fixed::<5>(q, out, jac),
            (2, 6) => self.predict_fixed::<6>(q, out, jac),
            (2, 7) => self.predict_fixed::<7>(q, out, jac),
            _ => self.predict_general(q, out, jac),
        }
    }

    fn predict_fixed<const N: usize>(&self, q: &[f64], out: &mut [f64], jac: &mut [f64]) {
        let q: [f64; N] = q.try_into().expect("q has n_inputs entries");
        let inv_l2: [f64; N] = self.inv_l2[..].try_into().expect("one scale per input");
        let (mut g0, mut g1) = (self.output_mean[0], self.output_mean[1]);
        let (mut j0, mut j1) = ([0.0; N], [0.0; N]);
        for (x, a) in self.inputs.chunks_exact(N).zip(self.alpha.chunks_exact(2)) {
            let mut scaled = [0.0; N];
            let mut s = 0.0;
            for d in 0..N {
                let diff = q[d] - x[d];
                scaled[d] = diff * inv_l2[d];
                s += diff * scaled[d];
            }
            let k = self.sf2 * (-0.5 * s).exp();
            let (k0, k1) = (k * a[0], k * a[1]);
            g0 += k0;
            g1 += k1;
            for d in 0..N {
                j0[d] -= k0 * scaled[d];
                j1[d] -= k1 * scaled[d];
            }
        }
        out[0] = g0;
        out[1] = g1;
        jac[..N].copy_from_slice(&j0);
        jac[N..2 * N].copy_from_slice(&j1);
    }

    fn predict_general(&self, q: &[f64], out: &mut [f64], jac: &mut [f64]) {
        let n = self.n_inputs;
        let r = self.n_outputs;
        out.copy_from_slice(&self.output_mean);
        jac.fill(0.0);
        for (x, a) in self.inputs.chunks_exact(n).zip(self.alpha.chunks_exact(r)) {
            let s: f64 = (0..n)
                .map(|d| (q[d] - x[d]) * (q[d] - x[d]) * self.inv_l2[d])
                .sum();
            let k = self.sf2 * (-0.5 * s).exp();
            for (ro, ai) in a.iter().enumerate() {
                let ka = k * ai;
                out[ro] += ka;
                for d in 0..n {
                    jac[ro * n + d] -= ka * (q[d] - x[d]) * self.inv_l2[d];
                }
            }
        }
    }

    /// The Cholesky factor L of K = K_f + sn^2 I over the training inputs (as the fit built
    /// it), for posterior variances; `None` if K is not positive definite.
    pub fn kernel_factor(&self) -> Option<nalgebra::DMatrix<f64>> {
        let n = self.n_inputs;
        let points = self.n_points();
        let sn2 = self.hyperparameters.noise_std * self.hyperparameters.noise_std;
        let mut k = nalgebra::DMatrix::zeros(points, points);
        for a in 0..points {
            for b in 0..=a {
                let (xa, xb) = (
                    &self.inputs[a * n..(a + 1) * n],
                    &self.inputs[b * n..(b + 1) * n],
                );
                let s: f64 = (0..n)
                    .map(|d| (xa[d] - xb[d]) * (xa[d] - xb[d]) * self.inv_l2[d])
                    .sum();
                let v = self.sf2 * (-0.5 * s).exp();
                k[(a, b)] = v;
                k[(b, a)] = v;
            }
            k[(a, a)] += sn2;
        }
        nalgebra::linalg::Cholesky::new(k).map(|c| c.unpack())
    }

    /// [`Self::kernel_factor`], built the first time it is asked for and kept (the model is
    /// shared by the runs of a setup: built once for all of them).
    pub fn slope_factor(&self) -> Option<&nalgebra::DMatrix<f64>> {
        self.factor.0.get_or_init(|| self.kernel_factor()).as_ref()
    }

    /// The posterior variance of the latent camera function's slope d g_r / d q_d at `q` (the
    /// same for every output: they share the kernel), sf^2 / l_d^2 - k_d' K^-1 k_d with
    /// k_d = dk(q, Q_j) / dq_d (Rasmussen & Williams sec. 9.4; docs/method.md, "Pair
    /// evidence"): how far the model's slope may be off where it has data. `factor` is
    /// [`Self::kernel_factor`]; without one, the prior's sf^2 / l_d^2 (the data taken to say
    /// nothing). `scratch` holds one entry per training point.
    pub fn slope_variance(
        &self,
        factor: Option<&nalgebra::DMatrix<f64>>,
        q: &[f64],
        d: usize,
        scratch: &mut Vec<f64>,
    ) -> f64 {
        let prior = self.sf2 * self.inv_l2[d];
        let Some(l) = factor else {
            return prior;
        };
        let n = self.n_inputs;
        let points = self.n_points();
        scratch.clear();
        for x in self.inputs.chunks_exact(n) {
            let s: f64 = (0..n)
                .map(|e| (q[e] - x[e]) * (q[e] - x[e]) * self.inv_l2[e])
                .sum();
            scratch.push(-(q[d] - x[d]) * self.inv_l2[d] * self.sf2 * (-0.5 * s).exp());
        }
        // Forward substitution L y = k_d; the explained variance is |y|^2.
        let mut explained = 0.0;
        for a in 0..points {
            let mut v = scratch[a];
            for b in 0..a {
                v -= l[(a, b)] * scratch[b];
            }
            v /= l[(a, a)];
            scratch[a] = v;
            explained += v * v;
        }
        (prior - explained).max(0.0)
    }

    /// The model as JSON (numbers round-trip exactly).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a GP model always serialises")
    }

    /// Reads a model from JSON text; `path` names the source in errors.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, GpError> {
        let parse = |message: String| GpError::Parse {
            path: path.to_path_buf(),
            message,
        };
        let mut m: GpModel = serde_json::from_str(text).map_err(|e| parse(e.to_string()))?;
        let h = &m.hyperparameters;
        if m.n_inputs == 0 || m.n_outputs == 0 {
            return Err(parse("n_inputs and n_outputs must be >= 1".into()));
        }
        if !m.inputs.len().is_multiple_of(m.n_inputs)
            || !m.alpha.len().is_multiple_of(m.n_outputs)
            || m.inputs.len() / m.n_inputs != m.alpha.len() / m.n_outputs
            || m.alpha.is_empty()
        {
            return Err(parse(
                "inputs and alpha do not describe the same points".into(),
            ));
        }
        if m.output_mean.len() != m.n_outputs
            || h.length_scales.len() != m.n_inputs
            || m.training_box.len() != m.n_inputs
        {
            return Err(parse(
                "output_mean, length_scales or training_box has the wrong length".into(),
            ));
        }
        let all_finite = m
            .inputs
            .iter()
            .chain(&m.alpha)
            .chain(&m.output_mean)
            .chain(&h.length_scales)
            .chain([&h.signal_std, &h.noise_std])
            .all(|v| v.is_finite());
        if !all_finite {
            return Err(parse("a number is not finite".into()));
        }
        if h.length_scales.iter().any(|l| *l <= 0.0) || h.signal_std <= 0.0 {
            return Err(parse("length scales and signal_std must be > 0".into()));
        }
        m.derive();
        Ok(m)
    }

    /// Loads a model from a JSON file.
    pub fn load(path: &Path) -> Result<Self, GpError> {
        let text = crate::fsio::read_text(path, crate::fsio::MAX_GP_BYTES)?;
        Self::from_json(&text, path)
    }
}

impl GpModel {
    /// A fixed 3-point, 2-input, 2-output model for unit tests (GP and Kalman filters).
    #[cfg(test)]
    pub(crate) fn toy() -> Self {
        Self::assemble(
            2,
            2,
            vec![0.0, 0.0, 1.0, 0.5, -0.5, 1.0],
            vec![0.3, -0.2, 1.1, 0.4, -0.7, 0.9],
            vec![0.1, -0.1],
            Hyperparameters {
                length_scales: vec![0.8, 1.3],
                signal_std: 1.5,
                noise_std: 0.01,
            },
            vec![[-1.0, 1.0], [-1.0, 1.0]],
            0,
            0.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The posterior variance of the slope is the limit of the posterior variance of central
    /// differences, (V(a, a) + V(b, b) - 2 V(a, b)) / (2h)^2 with V(a, b) = k(a, b) - k_a' K^-1
    /// k_b solved by nalgebra (an independent reference); far from the data it is the prior's
    /// sf^2 / l_d^2, and without a factor the prior too.
    #[test]
    fn slope_variance_matches_the_posterior_of_central_differences() {
        let m = GpModel::toy();
        let factor = m
            .kernel_factor()
            .expect("the toy kernel is positive definite");
        let n = m.n_inputs;
        let kern = |a: &[f64], b: &[f64]| {
            let s: f64 = (0..n).map(|d| (a[d] - b[d]).powi(2) * m.inv_l2[d]).sum();
            m.sf2 * (-0.5 * s).exp()
        };
        let points: Vec<&[f64]> = m.inputs.chunks_exact(n).collect();
        let sn2 = m.hyperparameters.noise_std.powi(2);
        let k = nalgebra::DMatrix::from_fn(points.len(), points.len(), |a, b| {
            kern(points[a], points[b]) + if a == b { sn2 } else { 0.0 }
        });
        let chol = nalgebra::linalg::Cholesky::new(k).unwrap();
        let posterior = |a: &[f64], b: &[f64]| {
            let ka =
                nalgebra::DVector::from_iterator(points.len(), points.iter().map(|x| kern(a, x)));
            let kb =
                nalgebra::DVector::from_iterator(points.len(), points.iter().map(|x| kern(b, x)));
            kern(a, b) - ka.dot(&chol.solve(&kb))
        };
        let mut scratch = Vec::new();
        for q in [[0.31, -0.47], [0.0, 0.1], [0.9, 0.6]] {
            for d in 0..n {
                let h = 1e-3;
                let (mut a, mut b) = (q, q);
                a[d] += h;
                b[d] -= h;
                let fd = (posterior(&a, &a) + posterior(&b, &b) - 2.0 * posterior(&a, &b))
                    / (4.0 * h * h);
                let v = m.slope_variance(Some(&factor), &q, d, &mut scratch);
                assert!(
                    (v - fd).abs() <= 1e-4 * fd.abs().max(1e-3),
                    "q {q:?} d {d}: {v} against {fd}"
                );
                assert!(
                    v < m.sf2 * m.inv_l2[d],
                    "the data must tell something near them"
                );
            }
        }
        let far = [40.0, -40.0];
        for d in 0..n {
            let prior = m.sf2 * m.inv_l2[d];
            let v = m.slope_variance(Some(&factor), &far, d, &mut scratch);
            assert!((v - prior).abs() <= 1e-12 * prior, "{v} against {prior}");
            assert_eq!(m.slope_variance(None, &[0.3, 0.2], d, &mut scratch), prior);
        }
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let m = GpModel::toy();
        let q = [0.31, -0.47];
        let (mut g, mut jac) = ([0.0; 2], [0.0; 4]);
        m.predict(&q, &mut g, &mut jac);
        let h = 1e-6;
        for d in 0..2 {
            let (mut qp, mut qm) = (q, q);
            qp[d] += h;
            qm[d] -= h;
            let (mut gp, mut gm) = ([0.0; 2], [0.0; 2]);
            m.predict_mean(&qp, &mut gp);
            m.predict_mean(&qm, &mut gm);
            for r in 0..2 {
                let fd = (gp[r] - gm[r]) / (2.0 * h);
                let rel = (jac[r * 2 + d] - fd).abs() / fd.abs().max(1e-12);
                assert!(rel < 1e-6, "r {r} d {d}: {} vs {fd}", jac[r * 2 + d]);
            }
        }
        let mut g2 = [0.0; 2];
        m.predict_mean(&q, &mut g2);
        assert_eq!(g, g2);
    }

    #[test]
    fn unrolled_and_general_kernels_agree() {
        let m = GpModel::assemble(
            3,
            2,
            vec![0.0, 0.1, 0.2, 1.0, 0.5, -0.3, -0.5, 1.0, 0.7],
            vec![0.3, -0.2, 1.1, 0.4, -0.7, 0.9],
            vec![0.1, -0.1],
            Hyperparameters {
                length_scales: vec![0.8, 1.3, 0.6],
                signal_std: 1.5,
                noise_std: 0.01,
            },
            vec![[-1.0, 1.0]; 3],
            0,
            0.0,
        );
        let q = [0.2, -0.1, 0.4];
        let (mut a, mut ja, mut b, mut jb) = ([0.0; 2], [0.0; 6], [0.0; 2], [0.0; 6]);
        m.predict(&q, &mut a, &mut ja);
        m.predict_general(&q, &mut b, &mut jb);
        for i in 0..2 {
            assert!((a[i] - b[i]).abs() < 1e-14);
        }
        for i in 0..6 {
            assert!((ja[i] - jb[i]).abs() < 1e-14);
        }
    }

    #[test]
    fn json_round_trip_predicts_bit_for_bit() {
        let m = GpModel::toy();
        let back = GpModel::from_json(&m.to_json(), Path::new("toy.json")).unwrap();
        let q = [0.123456789, -0.987654321];
        let (mut a, mut ja, mut b, mut jb) = ([0.0; 2], [0.0; 4], [0.0; 2], [0.0; 4]);
        m.predict(&q, &mut a, &mut ja);
        back.predict(&q, &mut b, &mut jb);
        assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
        assert_eq!(ja.map(f64::to_bits), jb.map(f64::to_bits));
    }

    #[test]
    fn malformed_models_are_refused() {
        let m = GpModel::toy();
        let bad = m
            .to_json()
            .replacen("\"n_inputs\": 2", "\"n_inputs\": 3", 1);
        assert!(matches!(
            GpModel::from_json(&bad, Path::new("m.json")),
            Err(GpError::Parse { .. })
        ));
        assert!(GpModel::from_json("{", Path::new("m.json")).is_err());
    }
}
