//! The estimator seam: an estimator written outside the library (a plain linear Kalman filter on
//! the encoders and tachometers, here) plugs into the same closed loop as the u-AIC without any
//! change to the runner, and reaches the set-point of the healthy paper scenario.

mod common;

use aift::estimation::{Estimate, Estimator, EstimatorInput};
use aift::precision::Fixed;
use aift::scenario::Run;
use aift::sensors::{Channel, ChannelLayout};
use nalgebra::{Matrix2, Vector2};

/// A constant-velocity Kalman filter per joint on its encoder and tachometer; the camera is
/// ignored. Written here from the textbook equations, independent of the library's filters.
struct LinearKalman {
    layout: ChannelLayout,
    dt: f64,
    /// Per joint: state [q, qd] and covariance.
    x: Vec<Vector2<f64>>,
    p: Vec<Matrix2<f64>>,
    q_noise: Matrix2<f64>,
    mu: Vec<f64>,
    mu_p: Vec<f64>,
    estimate: Estimate,
    started: bool,
}

impl LinearKalman {
    fn new(layout: ChannelLayout, dt: f64) -> Self {
        let n = layout.n_joints();
        // Process noise: accelerations up to about 50 rad/s^2 over a tick.
        let a = 50.0 * dt;
        Self {
            dt,
            x: vec![Vector2::zeros(); n],
            p: vec![Matrix2::identity() * 1e-2; n],
            q_noise: Matrix2::new(1e-12, 0.0, 0.0, a * a),
            mu: vec![0.0; n],
            mu_p: vec![0.0; n],
            estimate: Estimate::new(&layout),
            started: false,
            layout,
        }
    }
}

impl Estimator for LinearKalman {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        let n = self.layout.n_joints();
        let f = Matrix2::new(1.0, self.dt, 0.0, 1.0);
        self.estimate
            .precisions_used
            .copy_from_slice(input.precisions);
        for j in 0..n {
            let enc = self.layout.index(Channel::Encoder(j));
            let tach = self.layout.index(Channel::Tachometer(j));
            if !self.started {
                self.x[j] = Vector2::new(
                    input.readings.get(enc).unwrap_or(0.0),
                    input.readings.get(tach).unwrap_or(0.0),
                );
            }
            // Predict.
            let mut x = f * self.x[j];
            let mut p = f * self.p[j] * f.transpose() + self.q_noise;
            // Sequential scalar updates, one per sensor (H = e_0 or e_1).
            for (c, row) in [(enc, 0usize), (tach, 1usize)] {
                let w = input.precisions[c];
                let innovation = input.readings.get(c).map(|y| y - x[row]);
                self.estimate.innovations[c] = innovation;
                self.estimate.innovation_variances[c] = (w > 0.0).then(|| p[(row, row)] + 1.0 / w);
                if let (Some(nu), true) = (innovation, w > 0.0) {
                    let s = p[(row, row)] + 1.0 / w;
                    let k = p.column(row) / s;
                    x += k * nu;
                    p -= k * p.row(row);
                }
            }
            for (c, row) in [(enc, 0usize), (tach, 1usize)] {
                self.estimate.residuals[c] = input.readings.get(c).map(|y| y - x[row]);
                self.estimate.corrections[c] = p[(row, row)];
            }
            self.x[j] = x;
            self.p[j] = p;
            self.mu[j] = x[0];
            self.mu_p[j] = x[1];
        }
        self.started = true;
        self.estimate.finite = self.mu.iter().chain(&self.mu_p).all(|v| v.is_finite());
        &self.estimate
    }

    fn estimate(&self) -> &Estimate {
        &self.estimate
    }

    fn mu(&self) -> &[f64] {
        &self.mu
    }

    fn mu_p(&self) -> &[f64] {
        &self.mu_p
    }
}

#[test]
fn a_linear_kalman_filter_plugs_in_and_reaches_the_set_point() {
    let setup = common::setup("paper_healthy.toml", &[]);
    let nominal = setup.nominal_precisions();
    let estimator = LinearKalman::new(setup.layout, setup.scenario().dt);
    let parts = (
        Box::new(estimator) as Box<dyn aift::estimation::Estimator>,
        Box::new(Fixed::new(&nominal)) as Box<dyn aift::precision::PrecisionMethod>,
    );
    let result = Run::with_parts(&setup, "linear-kf", parts)
        .seed(1)
        .execute()
        .expect("run");
    eprintln!(
        "linear KF on the healthy paper scenario: outcome {}, belief MSE {:?}, final error {:.2e}",
        result.outcome.name(),
        result.mse_per_joint,
        result.max_final_error
    );
    assert_eq!(result.method, "linear-kf");
    assert_eq!(result.outcome.name(), "completed");
    assert!(result.max_final_error <= 0.01, "{}", result.max_final_error);
    assert!(result.mse_per_joint.iter().all(|m| *m < 1e-6), "{result:?}");
}
