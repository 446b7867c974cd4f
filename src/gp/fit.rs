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
use rayon::prelude::*;

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
        let mut w = cholesky_inverse(chol.l_dirty()) * (-r);
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

/// K^-1 from the Cholesky factor L of K (the lower triangle of `l`; what lies above it is not
/// read), bit for bit what nalgebra's `Cholesky::inverse` returns, at a third of its cost: each
/// column of the identity is solved as nalgebra solves it, L y = e_c by column sweeps (axpy)
/// then L' x = y by dot products summed in nalgebra's order (eight accumulators, then the
/// tail), but the forward sweep starts at row c, where nalgebra adds exact zeros to exact
/// zeros, eight columns share each read of L, and blocks of columns are solved in parallel
/// (each column's operations are the same whatever the blocks or threads, so are its bits). Written by hand because the fit's log-likelihood
/// gradient needs K^-1, and for the 600-point Panda camera model nalgebra's generic inverse was
/// three quarters of `aift run`'s time; a faster library (faer) picks SIMD kernels at run time,
/// so the fitted model, and every trajectory after it, would depend on the machine, and campaign
/// shards on different machines must agree.
fn cholesky_inverse(l: &DMatrix<f64>) -> DMatrix<f64> {
    // Columns solved together: each column of L is read once for the block (the factor of a
    // 600-point model is 2.9 MB, and one column at a time was bound by reading it).
    const BLOCK: usize = 8;
    let n = l.nrows();
    let factor = l.as_slice();
    let mut inverse = DMatrix::<f64>::zeros(n, n);
    if n == 0 {
        return inverse;
    }
    inverse
        .as_mut_slice()
        .par_chunks_mut(n * BLOCK)
        .enumerate()
        .for_each(|(block, columns)| {
            let first = block * BLOCK;
            let mut rhs: Vec<&mut [f64]> = columns.chunks_mut(n).collect();
            // Forward: L y = e_c; rows above c stay exactly zero.
            for (k, b) in rhs.iter_mut().enumerate() {
                b[first + k] = 1.0;
            }
            for i in first..n {
                let column = &factor[i * n..(i + 1) * n];
                for (k, b) in rhs.iter_mut().enumerate() {
                    if i < first + k {
                        continue;
                    }
                    let coeff = b[i] / column[i];
                    b[i] = coeff;
                    let a = -coeff;
                    for (y, x) in b[i + 1..].iter_mut().zip(&column[i + 1..]) {
                        *y += a * x;
                    }
                }
            }
            // Backward: L' x = y.
            for i in (0..n).rev() {
                let column = &factor[i * n..(i + 1) * n];
                for b in rhs.iter_mut() {
                    let dot = nalgebra_dot(&column[i + 1..], &b[i + 1..]);
                    b[i] = (b[i] - dot) / column[i];
                }
            }
        });
    inverse
}

/// The dot product in nalgebra's summation order (`Matrix::dot` on dynamically sized vectors):
/// eight accumulators over blocks of eight, folded as (0 + 4), (1 + 5), (2 + 6), (3 + 7) into
/// the result, then the remaining products one by one.
fn nalgebra_dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (xs, ys) = (a.chunks_exact(8), b.chunks_exact(8));
    let (x_tail, y_tail) = (xs.remainder(), ys.remainder());
    for (x, y) in xs.zip(ys) {
        for j in 0..8 {
            acc[j] += x[j] * y[j];
        }
    }
    let mut res = 0.0;
    res += acc[0] + acc[4];
    res += acc[1] + acc[5];
    res += acc[2] + acc[6];
    res += acc[3] + acc[7];
    for (x, y) in x_tail.iter().zip(y_tail) {
        res += x * y;
    }
    res
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
    check_data(inputs, outputs)?;
    let mean: Vec<f64> = (0..r).map(|c| outputs.column(c).mean()).collect();
    let mut y = outputs.clone();
    for c in 0..r {
        y.column_mut(c).add_scalar_mut(-mean[c]);
    }
    let starts = starting_points(inputs, &y, options);

    let evaluations = AtomicUsize::new(0);
    let problem = MarginalLikelihood::new(inputs, &y, options.min_noise_std, &evaluations);
    // The starts run in parallel; each is the same computation whatever the thread, and the
    // best is taken in the starts' order.
    let optima: Vec<Result<Vec<f64>, GpError>> = starts
        .into_par_iter()
        .map(|start| optimise(start, inputs, &y, options, &evaluations))
        .collect();
    let mut best: Option<(f64, Vec<f64>)> = None;
    let mut per_start = Vec::new();
    for theta in optima {
        let theta = theta?;
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

/// The training data: enough points for the hyperparameters, inputs and outputs alike long, all
/// finite.
fn check_data(inputs: &DMatrix<f64>, outputs: &DMatrix<f64>) -> Result<(), GpError> {
    let big_n = inputs.nrows();
    let n = inputs.ncols();
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
    Ok(())
}

/// The optimiser's starting points (log length scales, log signal std, log noise std), scaled
/// by the inputs' widths and the centred outputs' spread.
fn starting_points(inputs: &DMatrix<f64>, y: &DMatrix<f64>, options: &FitOptions) -> Vec<Vec<f64>> {
    let big_n = inputs.nrows();
    let n = inputs.ncols();
    let r = y.ncols();
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
    [(0.5, 1.0, 0.05), (1.0, 2.0, 0.02), (0.25, 1.0, 0.1)]
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
        .collect()
}

/// One L-BFGS run of the negative log marginal likelihood from `start`; its best point, or the
/// start itself when the line search fails.
fn optimise(
    start: Vec<f64>,
    inputs: &DMatrix<f64>,
    y: &DMatrix<f64>,
    options: &FitOptions,
    evaluations: &AtomicUsize,
) -> Result<Vec<f64>, GpError> {
    let big_n = inputs.nrows();
    let linesearch = MoreThuenteLineSearch::new();
    let solver = LBFGS::new(linesearch, 7)
        .with_tolerance_grad(1e-4 * big_n as f64)
        .and_then(|s| s.with_tolerance_cost(1e-9))
        .map_err(|e| GpError::Optimiser(e.to_string()))?;
    let start_problem = MarginalLikelihood::new(inputs, y, options.min_noise_std, evaluations);
    let result = Executor::new(start_problem, solver)
        .configure(|state| state.param(start.clone()).max_iters(options.max_iters))
        .run();
    Ok(match result {
        Ok(mut res) => res.state.take_best_param().unwrap_or(start),
        // A failed line search still leaves the start as a candidate.
        Err(_) => start,
    })
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
    fn the_hand_written_inverse_is_nalgebras_bit_for_bit() {
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for n in [1, 2, 7, 8, 9, 16, 17, 63, 100] {
            let a = DMatrix::from_fn(n, n, |_, _| next());
            let k = &a * a.transpose() + DMatrix::identity(n, n) * 0.1;
            let chol = k.cholesky().unwrap();
            let reference = chol.inverse();
            let ours = cholesky_inverse(chol.l_dirty());
            let bits = |m: &DMatrix<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&ours), bits(&reference), "n = {n}");
        }
    }

    #[test]
    fn the_fit_is_the_same_on_one_thread_and_on_several() {
        let (x, y) = data();
        let options = FitOptions {
            restarts: 4,
            ..FitOptions::default()
        };
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| fit(&x, &y, vec![[-1.0, 1.0]; 2], 0, &options).unwrap().0)
        };
        assert_eq!(on(1).to_json(), on(3).to_json());
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
