//! Hyperparameter fit: maximise the log marginal likelihood with its analytic gradient
//! (Rasmussen & Williams eqs. 5.8-5.9) using argmin's L-BFGS, from a few starting points.
//!
//! Parameters are optimised in log space, theta = [ln l_1..ln l_n, ln sf, ln sn]. The noise
//! variance has a smooth floor, sn^2 = exp(2 ln sn) + `min_noise_std`^2, which keeps K well
//! conditioned whatever the optimiser tries.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use argmin::core::{CostFunction, Error as ArgminError, Executor, Gradient};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use nalgebra::DMatrix;

use super::{GpError, GpModel, Hyperparameters};

/// Settings of the hyperparameter fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FitOptions {
    /// Number of starting points (the best optimum is kept).
    pub restarts: usize,
    /// L-BFGS iterations per start.
    pub max_iters: u64,
    /// Floor of the noise standard deviation (m).
    pub min_noise_std: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            restarts: 3,
            max_iters: 100,
            min_noise_std: 1e-4,
        }
    }
}

/// What the fit did.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    /// Log marginal likelihood at the kept optimum.
    pub log_marginal_likelihood: f64,
    /// The optimum reached from each start.
    pub per_start: Vec<f64>,
    /// Marginal-likelihood evaluations over all starts.
    pub evaluations: usize,
}

/// A cached evaluation: parameters, negative LML and its gradient.
type Evaluation = (Vec<f64>, f64, Vec<f64>);

/// The negative log marginal likelihood of a data set, as argmin's problem.
pub(crate) struct MarginalLikelihood<'a> {
    /// N x n inputs.
    x: &'a DMatrix<f64>,
    /// N x R centred outputs.
    y: &'a DMatrix<f64>,
    min_noise_var: f64,
    cache: Mutex<Option<Evaluation>>,
    evaluations: &'a AtomicUsize,
}

impl<'a> MarginalLikelihood<'a> {
    pub(crate) fn new(
        x: &'a DMatrix<f64>,
        y: &'a DMatrix<f64>,
        min_noise_std: f64,
        evaluations: &'a AtomicUsize,
    ) -> Self {
        Self {
            x,
            y,
            min_noise_var: min_noise_std * min_noise_std,
            cache: Mutex::new(None),
            evaluations,
        }
    }

    fn noise_var(&self, theta: &[f64]) -> f64 {
        (2.0 * theta[theta.len() - 1]).exp() + self.min_noise_var
    }

    /// The noise-free kernel matrix and K = K_f + sn^2 I.
    fn kernel(&self, theta: &[f64]) -> (DMatrix<f64>, DMatrix<f64>) {
        let n = self.x.ncols();
        let big_n = self.x.nrows();
        let inv_l2: Vec<f64> = theta[..n].iter().map(|t| (-2.0 * t).exp()).collect();
        let sf2 = (2.0 * theta[n]).exp();
        let mut kf = DMatrix::zeros(big_n, big_n);
        for i in 0..big_n {
            for j in 0..=i {
                let mut s = 0.0;
                for d in 0..n {
                    let diff = self.x[(i, d)] - self.x[(j, d)];
                    s += diff * diff * inv_l2[d];
                }
                let k = sf2 * (-0.5 * s).exp();
                kf[(i, j)] = k;
                kf[(j, i)] = k;
            }
        }
        let mut k = kf.clone();
        let nv = self.noise_var(theta);
        for i in 0..big_n {
            k[(i, i)] += nv;
        }
        (kf, k)
    }

    /// Log marginal likelihood and its gradient with respect to theta.
    pub(crate) fn value_and_gradient(&self, theta: &[f64]) -> Option<(f64, Vec<f64>)> {
        let n = self.x.ncols();
        let big_n = self.x.nrows();
        let r = self.y.ncols() as f64;
        let (kf, k) = self.kernel(theta);
        let chol = k.cholesky()?;
        let alpha = chol.solve(self.y);
        let log_det: f64 = 2.0
            * chol
                .l_dirty()
                .diagonal()
                .iter()
                .map(|v| v.ln())
                .sum::<f64>();
        let fit_term: f64 = self.y.component_mul(&alpha).sum();
        let lml = -0.5 * fit_term
            - 0.5 * r * log_det
            - 0.5 * r * big_n as f64 * (2.0 * std::f64::consts::PI).ln();
        // W = alpha alpha' - R K^-1; dLML/dtheta_j = 1/2 sum_ij W_ij dK_ij/dtheta_j.
        let mut w = chol.inverse() * (-r);
        w.gemm(1.0, &alpha, &alpha.transpose(), 1.0);
        let mut grad = vec![0.0; n + 2];
        let inv_l2: Vec<f64> = theta[..n].iter().map(|t| (-2.0 * t).exp()).collect();
        for i in 0..big_n {
            for j in 0..big_n {
                let wk = w[(i, j)] * kf[(i, j)];
                grad[n] += wk; // d/d ln sf: 2 K_f, times the 1/2.
                for d in 0..n {
                    let diff = self.x[(i, d)] - self.x[(j, d)];
                    grad[d] += 0.5 * wk * diff * diff * inv_l2[d];
                }
            }
        }
        // d/d ln sn: d(sn^2)/d ln sn = 2 exp(2 theta), times the 1/2 tr(W).
        grad[n + 1] = (2.0 * theta[n + 1]).exp() * w.trace();
        if lml.is_finite() && grad.iter().all(|g| g.is_finite()) {
            Some((lml, grad))
        } else {
            None
        }
    }

    fn cached(&self, theta: &[f64]) -> (f64, Vec<f64>) {
        let mut cache = self
            .cache
            .lock()
            .expect("no poisoning: single-threaded use");
        if let Some((p, v, g)) = cache.as_ref()
            && p.as_slice() == theta
        {
            return (*v, g.clone());
        }
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        // Minimised: the negative log marginal likelihood; a failed factorisation is +inf-like.
        let (v, g) = match self.value_and_gradient(theta) {
            Some((lml, grad)) => (-lml, grad.into_iter().map(|g| -g).collect()),
            None => (1e300, vec![0.0; theta.len()]),
        };
        *cache = Some((theta.to_vec(), v, g.clone()));
        (v, g)
    }

    /// Alpha = K^-1 Y at theta.
    pub(crate) fn alpha(&self, theta: &[f64]) -> Option<DMatrix<f64>> {
        let (_, k) = self.kernel(theta);
        Some(k.cholesky()?.solve(self.y))
    }
}

impl CostFunction for MarginalLikelihood<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, p: &Self::Param) -> Result<f64, ArgminError> {
        Ok(self.cached(p).0)
    }
}

impl Gradient for MarginalLikelihood<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, p: &Self::Param) -> Result<Vec<f64>, ArgminError> {
        Ok(self.cached(p).1)
    }
}

/// Fits a GP to `inputs` (N x n) and `outputs` (N x R).
pub(crate) fn fit(
    inputs: &DMatrix<f64>,
    outputs: &DMatrix<f64>,
    training_box: Vec<[f64; 2]>,
    seed: u64,
    options: &FitOptions,
) -> Result<(GpModel, FitReport), GpError> {
    let big_n = inputs.nrows();
    let n = inputs.ncols();
    let r = outputs.ncols();
    if big_n < 2 * n + 2 {
        return Err(GpError::TooFewPoints {
            min: 2 * n + 2,
            got: big_n,
        });
    }
    if outputs.nrows() != big_n {
        return Err(GpError::BadData(
            "inputs and outputs differ in length".into(),
        ));
    }
    if !inputs.iter().chain(outputs.iter()).all(|v| v.is_finite()) {
        return Err(GpError::BadData("a training value is not finite".into()));
    }
    let mean: Vec<f64> = (0..r).map(|c| outputs.column(c).mean()).collect();
    let mut y = outputs.clone();
    for c in 0..r {
        y.column_mut(c).add_scalar_mut(-mean[c]);
    }
    let sf0 = (0..r)
        .map(|c| y.column(c).norm() / (big_n as f64).sqrt())
        .fold(0.0, f64::max)
        .max(1e-6);
    let widths: Vec<f64> = (0..n)
        .map(|d| {
            let col = inputs.column(d);
            (col.max() - col.min()).max(1e-3)
        })
        .collect();
    let starts: Vec<Vec<f64>> = [(0.5, 1.0, 0.05), (1.0, 2.0, 0.02), (0.25, 1.0, 0.1)]
        .iter()
        .cycle()
        .take(options.restarts.max(1))
        .enumerate()
        .map(|(i, &(lw, sf, sn))| {
            // Later cycles through the list start a little further out.
            let spread = 1.5f64.powi((i / 3) as i32);
            let mut t: Vec<f64> = widths.iter().map(|w| (w * lw * spread).ln()).collect();
            t.push((sf0 * sf).ln());
            t.push((sf0 * sn).ln());
            t
        })
        .collect();

    let evaluations = AtomicUsize::new(0);
    let problem = MarginalLikelihood::new(inputs, &y, options.min_noise_std, &evaluations);
    let mut best: Option<(f64, Vec<f64>)> = None;
    let mut per_start = Vec::new();
    for start in starts {
        let linesearch = MoreThuenteLineSearch::new();
        let solver = LBFGS::new(linesearch, 7)
            .with_tolerance_grad(1e-4 * big_n as f64)
            .and_then(|s| s.with_tolerance_cost(1e-9))
            .map_err(|e| GpError::Optimiser(e.to_string()))?;
        let start_problem =
            MarginalLikelihood::new(inputs, &y, options.min_noise_std, &evaluations);
        let result = Executor::new(start_problem, solver)
            .configure(|state| state.param(start.clone()).max_iters(options.max_iters))
            .run();
        let theta = match result {
            Ok(mut res) => res.state.take_best_param().unwrap_or(start),
            // A failed line search still leaves the start as a candidate.
            Err(_) => start,
        };
        let Some((lml, _)) = problem.value_and_gradient(&theta) else {
            continue;
        };
        per_start.push(lml);
        if best.as_ref().is_none_or(|(b, _)| lml > *b) {
            best = Some((lml, theta));
        }
    }
    let (lml, theta) = best.ok_or(GpError::NotPositiveDefinite)?;
    let alpha = problem.alpha(&theta).ok_or(GpError::NotPositiveDefinite)?;
    let hyperparameters = Hyperparameters {
        length_scales: theta[..n].iter().map(|t| t.exp()).collect(),
        signal_std: theta[n].exp(),
        noise_std: problem.noise_var(&theta).sqrt(),
    };
    let flat_inputs: Vec<f64> = (0..big_n)
        .flat_map(|i| (0..n).map(move |d| (i, d)))
        .map(|(i, d)| inputs[(i, d)])
        .collect();
    let flat_alpha: Vec<f64> = (0..big_n)
        .flat_map(|i| (0..r).map(move |c| (i, c)))
        .map(|(i, c)| alpha[(i, c)])
        .collect();
    let model = GpModel::assemble(
        n,
        r,
        flat_inputs,
        flat_alpha,
        mean,
        hyperparameters,
        training_box,
        seed,
        lml,
    );
    Ok((
        model,
        FitReport {
            log_marginal_likelihood: lml,
            per_start,
            evaluations: evaluations.load(Ordering::Relaxed),
        },
    ))
}

/// Convenience for tests: the negative-LML problem's value and gradient at theta.
#[cfg(test)]
pub(crate) fn lml_and_gradient(
    x: &DMatrix<f64>,
    y: &DMatrix<f64>,
    theta: &[f64],
) -> Option<(f64, Vec<f64>)> {
    let counter = AtomicUsize::new(0);
    MarginalLikelihood::new(x, y, 1e-4, &counter).value_and_gradient(theta)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data() -> (DMatrix<f64>, DMatrix<f64>) {
        let x = DMatrix::from_fn(25, 2, |i, d| ((i * 7 + d * 3) % 11) as f64 / 5.0 - 1.0);
        let y = DMatrix::from_fn(25, 2, |i, c| {
            let (a, b) = (x[(i, 0)], x[(i, 1)]);
            if c == 0 {
                a.cos() + 0.3 * b + 0.01 * ((i * 13) % 7) as f64
            } else {
                a.sin() * b - 0.01 * ((i * 5) % 3) as f64
            }
        });
        (x, y)
    }

    #[test]
    fn marginal_likelihood_gradient_matches_finite_differences() {
        let (x, y) = data();
        let theta = vec![0.1, -0.3, 0.2, -3.0];
        let (_, grad) = lml_and_gradient(&x, &y, &theta).unwrap();
        let h = 1e-6;
        for j in 0..theta.len() {
            let (mut tp, mut tm) = (theta.clone(), theta.clone());
            tp[j] += h;
            tm[j] -= h;
            let fd = (lml_and_gradient(&x, &y, &tp).unwrap().0
                - lml_and_gradient(&x, &y, &tm).unwrap().0)
                / (2.0 * h);
            let rel = (grad[j] - fd).abs() / fd.abs().max(1e-8);
            assert!(rel < 1e-5, "theta[{j}]: analytic {} vs fd {fd}", grad[j]);
        }
    }

    #[test]
    fn fit_beats_its_starting_point_and_finds_the_data_noise() {
        let (x, y) = data();
        let (model, report) = fit(&x, &y, vec![[-1.0, 1.0]; 2], 0, &FitOptions::default()).unwrap();
        // The first start: length scales half the input widths, sf and sn from the outputs.
        let centred = {
            let mut c = y.clone();
            for k in 0..2 {
                let m = c.column(k).mean();
                c.column_mut(k).add_scalar_mut(-m);
            }
            c
        };
        let sf0 = (0..2)
            .map(|k| centred.column(k).norm() / 5.0)
            .fold(0.0, f64::max);
        let start = [0.9f64.ln(), 0.9f64.ln(), sf0.ln(), (0.05 * sf0).ln()];
        let (lml_start, _) = lml_and_gradient(&x, &centred, &start).unwrap();
        assert!(
            report.log_marginal_likelihood > lml_start + 1.0,
            "{} vs start {lml_start}",
            report.log_marginal_likelihood
        );
        // The data carry deterministic wiggles of about 0.01: the fitted noise is of that order.
        let sn = model.hyperparameters.noise_std;
        assert!(sn > 1e-3 && sn < 0.05, "noise std {sn}");
    }
}
