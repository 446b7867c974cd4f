//! The u-AIC on its own: F's gradient against finite differences, missing and zero-precision
//! channels left out, the belief update against its closed form.

mod common;

use std::sync::Arc;

use aift::control::{Control, ControlConfig};
use aift::estimation::Estimator;
use aift::estimation::uaic::{Prediction, Uaic, UaicConfig, UpdateScheme};
use aift::gp::{FitOptions, GpModel, derive_box, sample_training_set};
use aift::sensors::{Camera, CameraConfig, CameraModel, ChannelLayout, Readings};

fn layout() -> ChannelLayout {
    ChannelLayout::new(2, CameraModel::Pinhole)
}

fn observation(gp: Arc<GpModel>) -> Arc<dyn aift::estimation::models::ObservationModel> {
    aift::estimation::models::GpCamera::shared(layout(), gp)
}

fn gp() -> Arc<GpModel> {
    let model = common::model("urdf/planar_2dof.urdf");
    let ee = common::ee(&model);
    let mut arm = aift::arm::Kinematics::new(model);
    let camera = Camera::new(CameraConfig::default());
    let bounds = derive_box(&[vec![-1.57, 0.0], vec![-0.2, 0.5]], 0.3);
    let (gp, _) = sample_training_set(&mut arm, &ee, &camera, &bounds, 80, 3)
        .fit(&FitOptions::default())
        .unwrap();
    Arc::new(gp)
}

fn readings() -> Readings {
    Readings {
        values: vec![
            Some(-0.61),
            Some(0.22),
            Some(0.05),
            Some(-0.02),
            Some(1.62),
            Some(-0.35),
        ],
    }
}

const PRECISIONS: [f64; 6] = [1e6, 1e6, 1e6, 1e6, 1e4, 1e4];

#[test]
fn free_energy_gradient_equals_finite_differences() {
    let gp = gp();
    for prediction in [Prediction::Paper, Prediction::Coupled] {
        let config = UaicConfig {
            prediction,
            prior_warmup_ticks: 0,
            ..UaicConfig::default()
        };
        let c = Uaic::new(config, observation(gp.clone()), 1e-3);
        let x = [-0.6, 0.21, 0.04, -0.03];
        let prev = [-0.6001, 0.2102, 0.041, -0.029];
        let r = readings();
        let (_, grad) = c.free_energy(&x, &prev, &r, &PRECISIONS);
        for i in 0..4 {
            // Step sizes suited to each coordinate's curvature (P_mu = 1e8 on positions).
            let h = 1e-7;
            let (mut xp, mut xm) = (x, x);
            xp[i] += h;
            xm[i] -= h;
            let fd = (c.free_energy(&xp, &prev, &r, &PRECISIONS).0
                - c.free_energy(&xm, &prev, &r, &PRECISIONS).0)
                / (2.0 * h);
            let rel = (grad[i] - fd).abs() / fd.abs().max(1.0);
            assert!(
                rel < 1e-5,
                "{prediction:?} x[{i}]: analytic {} fd {fd}",
                grad[i]
            );
        }
    }
}

#[test]
fn missing_and_zero_precision_channels_are_left_out_of_f() {
    let c = Uaic::new(UaicConfig::default(), observation(gp()), 1e-3);
    let x = [-0.6, 0.21, 0.04, -0.03];
    let prev = x;
    let full = readings();
    let (f_full, _) = c.free_energy(&x, &prev, &full, &PRECISIONS);
    let mut missing = full.clone();
    missing.values[0] = None;
    let (f_missing, g_missing) = c.free_energy(&x, &prev, &missing, &PRECISIONS);
    let mut zero = PRECISIONS;
    zero[0] = 0.0;
    let (f_zero, g_zero) = c.free_energy(&x, &prev, &full, &zero);
    // Encoder 1's term is 1/2 (w e^2 - ln w) with e = -0.61 - (-0.6).
    let e: f64 = -0.61 + 0.6;
    let term = 0.5 * (1e6 * e * e - 1e6f64.ln());
    assert!((f_full - f_missing - term).abs() < 1e-6 * f_full.abs().max(1.0));
    assert_eq!(f_missing, f_zero);
    assert_eq!(g_missing, g_zero);
    assert!(f_zero.is_finite());
}

#[test]
fn the_belief_runs_on_readings_with_missing_channels() {
    let mut c = Uaic::new(UaicConfig::default(), observation(gp()), 1e-3);
    let mut control = Control::new(&ControlConfig::default());
    let mut r = readings();
    c.step(&r, &PRECISIONS);
    // Camera and encoder 1 gone for a while: the belief stays finite and keeps integrating.
    r.values[0] = None;
    r.values[4] = None;
    r.values[5] = None;
    for _ in 0..100 {
        let report = c.step(&r, &PRECISIONS).clone();
        assert!(report.finite && report.free_energy.is_some_and(f64::is_finite));
        let torques = control.step(c.mu(), c.mu_p(), &[-0.6, 0.2], 1e-3);
        assert!(torques.iter().all(|u| u.is_finite()));
        assert_eq!(report.residuals[0], None);
        assert_eq!(report.innovations[4], None);
    }
    assert!(c.mu().iter().chain(c.mu_p()).all(|v| v.is_finite()));
}

#[test]
fn gauss_newton_step_lands_on_the_quadratic_models_minimum() {
    // Encoders and tachometers only (camera weight 0): F is quadratic in x, so one GN step from
    // the prediction must zero the gradient.
    let mut c = Uaic::new(
        UaicConfig {
            update: UpdateScheme::GaussNewton,
            prior_warmup_ticks: 0,
            ..UaicConfig::default()
        },
        observation(gp()),
        1e-3,
    );
    let precisions = [1e6, 1e6, 1e6, 1e6, 0.0, 0.0];
    let r0 = readings();
    c.step(&r0, &precisions);
    let prev: Vec<f64> = c.mu().iter().chain(c.mu_p()).copied().collect();
    let mut r1 = r0.clone();
    r1.values[0] = Some(-0.605);
    r1.values[2] = Some(0.07);
    c.step(&r1, &precisions);
    let x: Vec<f64> = c.mu().iter().chain(c.mu_p()).copied().collect();
    let (_, grad) = c.free_energy(&x, &prev, &r1, &precisions);
    for g in grad {
        assert!(g.abs() < 1e-4, "gradient {g} after the GN step");
    }
}

/// The authors' MATLAB form (`prediction = "authors-matlab"`, a compatibility setting): two ticks
/// of the gradient update equal their `mu_dot` and `mu_dot_p` lines evaluated by hand, the extra
/// P_mu0 (mu(i) - mu(i-1)) term of the velocity update included; and it refuses Gauss-Newton.
#[test]
fn the_authors_matlab_form_is_their_update_line_by_line() {
    let (h, k) = (1e-3, 200.0);
    let config = UaicConfig {
        update: UpdateScheme::Gradient,
        kappa_mu: k,
        prediction: Prediction::AuthorsMatlab,
        prior_position_precision: Some(1.0),
        prior_velocity_precision: Some(1.0),
        prior_warmup_ticks: 0,
        ..UaicConfig::default()
    };
    config.validate(h).unwrap();
    let mut c = Uaic::new(config.clone(), observation(gp()), h);
    let precisions = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0];
    let r0 = readings();
    let mut r1 = readings();
    r1.values[0] = Some(-0.58);
    r1.values[1] = Some(0.25);
    r1.values[2] = Some(0.3);
    r1.values[3] = Some(-0.4);
    let y = |r: &Readings, i: usize| r.values[i].unwrap();
    c.step(&r0, &precisions);
    c.step(&r1, &precisions);
    for j in 0..2 {
        // Tick 1 starts at the readings with mu(i-1) = mu(i): mu1 = mu0 + h mu_p0, mu_p1 = mu_p0.
        let (mu0, v0) = (y(&r0, j), y(&r0, 2 + j));
        let mu1 = mu0 + h * (v0 - k * (-(y(&r0, j) - mu0) + (mu0 - mu0)));
        let v1 = v0 + h * (0.0 - k * (-(y(&r0, 2 + j) - v0) + (mu0 - mu0) + (v0 - v0)));
        let mu2 = mu1 + h * (v1 - k * (-(y(&r1, j) - mu1) + (mu1 - mu0)));
        let v2 = v1 + h * (0.0 - k * (-(y(&r1, 2 + j) - v1) + (mu1 - mu0) + (v1 - v0)));
        assert!(
            (c.mu()[j] - mu2).abs() < 1e-15,
            "mu{j}: {} vs {mu2}",
            c.mu()[j]
        );
        assert!(
            (c.mu_p()[j] - v2).abs() < 1e-15,
            "mu_p{j}: {} vs {v2}",
            c.mu_p()[j]
        );
    }
    let e = UaicConfig {
        update: UpdateScheme::GaussNewton,
        ..config
    }
    .validate(h)
    .unwrap_err();
    assert_eq!(e.field, "prediction");
}

/// `prior = "switched"` is the fixed prior while every tachometer reads and its precision is at
/// least the prior's P_mu', and the propagated prior from the first tick one is below it or its
/// reading is missing (the propagated
/// prior starts from the last posterior covariance, which the fixed prior's updates also
/// compute): bit for bit a fixed-prior belief switched by hand at that tick, and back once the
/// tachometer returns.
#[test]
fn the_switched_prior_is_fixed_until_a_tachometer_is_dropped_then_propagated() {
    use aift::estimation::uaic::PriorMode;
    let gp = gp();
    let switched = UaicConfig {
        prior: Some(PriorMode::Switched),
        ..UaicConfig::default()
    };
    let (_, pv) = switched.prior_precisions(1e-3);
    let mut a = Uaic::new(switched, observation(gp.clone()), 1e-3);
    let mut b = Uaic::new(UaicConfig::default(), observation(gp), 1e-3);
    let mut r = readings();
    for k in 0..500u32 {
        // Tachometer 2 (channel 3): nominal, then just below P_mu', then 0, then nominal but
        // missing (a dropout), then nominal again.
        let mut w = PRECISIONS;
        let expect = match k {
            0..100 => PriorMode::Fixed,
            100..200 => {
                w[3] = 0.999 * pv;
                PriorMode::Propagated
            }
            200..300 => {
                w[3] = 0.0;
                PriorMode::Propagated
            }
            300..400 => PriorMode::Propagated,
            _ => PriorMode::Fixed,
        };
        // At P_mu' exactly it stays fixed.
        if k == 50 {
            w[3] = pv;
        }
        b.set_prior(expect);
        // Readings that move: the joints turn at 0.5 and -0.3 rad/s.
        let t = f64::from(k) * 1e-3;
        r.values[0] = Some(-0.61 + 0.5 * t);
        r.values[1] = Some(0.22 - 0.3 * t);
        r.values[2] = Some(0.5);
        r.values[3] = if (300..400).contains(&k) {
            None
        } else {
            Some(-0.3)
        };
        a.step(&r, &w);
        b.step(&r, &w);
        assert_eq!(a.prior_in_force(), expect, "tick {k}");
        assert_eq!(a.belief(), b.belief(), "tick {k}");
    }
    // Without the Gauss-Newton update it is refused, naming the key.
    let bad = UaicConfig {
        prior: Some(PriorMode::Switched),
        update: UpdateScheme::Gradient,
        ..UaicConfig::default()
    };
    let e = bad.validate(1e-3).unwrap_err().to_string();
    assert!(e.contains("prior") && e.contains("switched"), "{e}");
    // Absent, the prior is `switched` with the Gauss-Newton update and `fixed` with the
    // gradient one, which has no posterior covariance to propagate; both validate.
    let default = UaicConfig::default();
    assert_eq!(default.prior, None);
    assert_eq!(default.prior_mode(), PriorMode::Switched);
    default.validate(1e-3).unwrap();
    let gradient = UaicConfig {
        update: UpdateScheme::Gradient,
        ..UaicConfig::default()
    };
    assert_eq!(gradient.prior_mode(), PriorMode::Fixed);
    gradient.validate(1e-3).unwrap();
}
