//! Training data for the camera GP: configurations over a joint-space box, each with the
//! simulated camera's noisy, distorted reading; and the held-out check against the noise-free
//! camera.

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal, Uniform};

use super::{FitOptions, FitReport, GpError, GpModel};
use crate::arm::{EndEffector, Kinematics};
use crate::sensors::Camera;

/// Stream ids of the GP's random draws (apart from the sensors' streams).
const LHS_STREAM: u64 = 50_000;
const NOISE_STREAM: u64 = 50_001;
const HELD_OUT_STREAM: u64 = 50_002;

/// A training set: inputs (joint angles) and the camera's readings.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingSet {
    pub inputs: Vec<Vec<f64>>,
    /// One reading per input, one value per camera output.
    pub outputs: Vec<Vec<f64>>,
    pub training_box: Vec<[f64; 2]>,
    pub seed: u64,
    /// Configurations drawn but not seen by the camera (occluded or behind), skipped.
    pub skipped: usize,
}

/// The joint-space box spanned by `points` (start and targets), widened by `margin` (rad).
pub fn derive_box(points: &[Vec<f64>], margin: f64) -> Vec<[f64; 2]> {
    let n = points.first().map_or(0, Vec::len);
    (0..n)
        .map(|d| {
            let lo = points.iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
            let hi = points
                .iter()
                .map(|p| p[d])
                .fold(f64::NEG_INFINITY, f64::max);
            [lo - margin, hi + margin]
        })
        .collect()
}

/// `count` Latin-hypercube samples of a box: each axis cut into `count` strata, one sample per
/// stratum, strata shuffled independently per axis.
pub fn latin_hypercube(bounds: &[[f64; 2]], count: usize, rng: &mut ChaCha8Rng) -> Vec<Vec<f64>> {
    let unit = Uniform::new(0.0, 1.0).expect("valid range");
    let mut columns: Vec<Vec<f64>> = Vec::with_capacity(bounds.len());
    for &[lo, hi] in bounds {
        let mut strata: Vec<usize> = (0..count).collect();
        // Fisher-Yates with the seeded stream.
        for i in (1..count).rev() {
            let j = (unit.sample(rng) * (i + 1) as f64) as usize;
            strata.swap(i, j.min(i));
        }
        columns.push(
            strata
                .into_iter()
                .map(|s| lo + (hi - lo) * (s as f64 + unit.sample(rng)) / count as f64)
                .collect(),
        );
    }
    (0..count)
        .map(|i| columns.iter().map(|c| c[i]).collect())
        .collect()
}

/// Draws `count` configurations in `bounds` (Latin hypercube) and reads the camera at each:
/// the noise-free distorted image plus N(0, sigma^2) per coordinate. Configurations the camera
/// cannot see are skipped (and counted). The arm is placed by the model's kinematics.
pub fn sample_training_set(
    arm: &mut Kinematics,
    ee: &EndEffector,
    camera: &Camera,
    bounds: &[[f64; 2]],
    count: usize,
    seed: u64,
) -> TrainingSet {
    let mut lhs = ChaCha8Rng::seed_from_u64(seed);
    lhs.set_stream(LHS_STREAM);
    let mut noise = ChaCha8Rng::seed_from_u64(seed);
    noise.set_stream(NOISE_STREAM);
    let sigma = camera.config().sigma;
    let mut set = TrainingSet {
        inputs: Vec::with_capacity(count),
        outputs: Vec::with_capacity(count),
        training_box: bounds.to_vec(),
        seed,
        skipped: 0,
    };
    let mut z = vec![0.0; camera.outputs()];
    let mut image = vec![0.0; camera.outputs()];
    for q in latin_hypercube(bounds, count, &mut lhs) {
        arm.set(&q);
        for zr in z.iter_mut() {
            *zr = StandardNormal.sample(&mut noise);
        }
        match camera.observe(arm, ee, &mut image) {
            Ok(()) => {
                set.inputs.push(q);
                set.outputs
                    .push(image.iter().zip(&z).map(|(v, zr)| v + sigma * zr).collect());
            }
            Err(_) => set.skipped += 1,
        }
    }
    set
}

impl TrainingSet {
    /// Fits a GP to this set.
    pub fn fit(&self, options: &FitOptions) -> Result<(GpModel, FitReport), GpError> {
        let n = self.inputs.first().map_or(0, Vec::len);
        let x = DMatrix::from_fn(self.inputs.len(), n, |i, d| self.inputs[i][d]);
        let r = self.outputs.first().map_or(0, Vec::len);
        let y = DMatrix::from_fn(self.outputs.len(), r, |i, c| self.outputs[i][c]);
        super::fit::fit(&x, &y, self.training_box.clone(), self.seed, options)
    }
}

/// The GP's error on held-out configurations against the noise-free distorted camera.
#[derive(Clone, Debug, PartialEq)]
pub struct HeldOutError {
    /// Root mean square over points and every output (m).
    pub rms: f64,
    /// Largest distance between prediction and truth (m).
    pub max: f64,
    pub points: usize,
}

/// Evaluates `model` on `count` uniform configurations inside its training box.
pub fn evaluate_held_out(
    model: &GpModel,
    arm: &mut Kinematics,
    ee: &EndEffector,
    camera: &Camera,
    count: usize,
    seed: u64,
) -> HeldOutError {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(HELD_OUT_STREAM);
    let unit = Uniform::new(0.0, 1.0).expect("valid range");
    let (mut sum2, mut max, mut points) = (0.0, 0.0f64, 0);
    let r = camera.outputs();
    let mut g = vec![0.0; r];
    let mut truth = vec![0.0; r];
    for _ in 0..count {
        let q: Vec<f64> = model
            .training_box
            .iter()
            .map(|[lo, hi]| lo + (hi - lo) * unit.sample(&mut rng))
            .collect();
        arm.set(&q);
        if camera.observe(arm, ee, &mut truth).is_err() {
            continue;
        }
        model.predict_mean(&q, &mut g);
        let e2: f64 = g.iter().zip(&truth).map(|(a, b)| (a - b) * (a - b)).sum();
        sum2 += e2;
        max = max.max(e2.sqrt());
        points += 1;
    }
    HeldOutError {
        rms: (sum2 / (r * points.max(1)) as f64).sqrt(),
        max,
        points,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latin_hypercube_puts_one_sample_in_every_stratum() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let bounds = [[-1.0, 1.0], [0.0, 3.0]];
        let pts = latin_hypercube(&bounds, 50, &mut rng);
        for (d, [lo, hi]) in bounds.iter().enumerate() {
            let mut seen = [false; 50];
            for p in &pts {
                let s = ((p[d] - lo) / (hi - lo) * 50.0).floor() as usize;
                assert!(!seen[s], "stratum {s} twice");
                seen[s] = true;
            }
        }
    }

    #[test]
    fn derived_box_spans_the_points_with_a_margin() {
        let b = derive_box(&[vec![-1.57, 0.0], vec![-0.2, 0.5], vec![-0.6, 0.2]], 0.3);
        assert!((b[0][0] + 1.87).abs() < 1e-12 && (b[0][1] - 0.1).abs() < 1e-12);
        assert!((b[1][0] + 0.3).abs() < 1e-12 && (b[1][1] - 0.8).abs() < 1e-12);
    }
}
