//! Per-stage cost of a scenario's closed loop (the `bench` command): each stage timed alone over
//! many ticks, then the whole loop. Timings only; nothing here is asserted in tests.

use std::hint::black_box;
use std::time::Instant;

use super::runner::Run;
use super::{Method, RunSetup, ScenarioError};
use crate::estimation::uaic::Uaic;
use crate::estimation::{Estimate, Estimator, EstimatorInput};
use crate::precision::{Gradient, PrecisionInput, PrecisionMethod};
use crate::sensors::{Camera, Readings, SensorSuite};

/// One measured figure.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub name: &'static str,
    pub value: f64,
    pub unit: &'static str,
}

/// Times each stage over `ticks` ticks and the closed loop over one run of the scenario with
/// `method` (the scenario's seed; methods with a detector need its `calibration`). The stages
/// are the u-AIC's and the gradient learner's whatever the method; the closed loop is the
/// method's own.
pub fn bench(
    setup: &RunSetup,
    method: Method,
    calibration: Option<&crate::precision::detector::Calibration>,
    ticks: u64,
) -> Result<Vec<Figure>, ScenarioError> {
    let sc = setup.scenario();
    let dt = sc.dt;
    let ticks = ticks.max(1);

    let mut arm = setup.plant()?;
    let n = arm.n_joints();
    let layout = setup.layout;
    let qd0 = sc.initial.qd.clone().unwrap_or_else(|| vec![0.0; n]);
    let target = sc.targets[0].q.clone();

    // Physics: steps under a constant torque from the start.
    arm.set_state(&sc.initial.q, &qd0);
    arm.set_torques(&vec![1.0; n]);
    let start = Instant::now();
    for _ in 0..ticks {
        arm.step(dt);
    }
    let physics_us = per_tick(start, ticks);

    // Sensors: every channel, camera with occlusion.
    arm.set_state(&target, &vec![0.0; n]);
    let mut sensors = SensorSuite::new(
        layout,
        &sc.sensors,
        Camera::new(sc.camera.clone()),
        setup.ee,
        &[],
        dt,
        sc.seed,
    );
    let mut readings = Readings::missing(&layout);
    let start = Instant::now();
    for k in 0..ticks {
        sensors.read(arm.as_ref(), k, &mut readings);
    }
    let sensors_us = per_tick(start, ticks);

    // GP: mean and Jacobian.
    let r = layout.camera_outputs();
    let mut g = vec![0.0; r];
    let mut jac = vec![0.0; r * n];
    let start = Instant::now();
    for _ in 0..ticks {
        setup.gp.predict(black_box(&target), &mut g, &mut jac);
    }
    let gp_us = per_tick(start, ticks);

    // Controller and learner, on fixed readings.
    let nominal: Vec<f64> = super::runner::nominal_precisions(sensors.sigmas());
    let zeros = vec![0.0; n];
    let controller_us = time_controller(setup, &readings, &nominal, &target, &zeros, ticks);
    let learner_us = time_learner(setup, &readings, &nominal, &target, &zeros, ticks);

    // The closed loop: one whole run.
    let result = Run::new(setup, method)
        .seed(sc.seed)
        .calibration(calibration)
        .execute()?;
    let closed_loop = result.ticks_per_second();
    let closed_us = 1e6 / closed_loop;
    // Not a timing: what the timed run computed, so a reader can tell which method ran.
    let belief_mse =
        result.mse_per_joint.iter().sum::<f64>() / result.mse_per_joint.len().max(1) as f64;

    Ok(figures(&Timings {
        physics_us,
        sensors_us,
        gp_us,
        controller_us,
        learner_us,
        closed_loop,
        closed_us,
        dt,
        belief_mse,
    }))
}

/// The controller stage: one belief update (GP included) and f* per tick, on fixed readings
/// (us per tick).
fn time_controller(
    setup: &RunSetup,
    readings: &Readings,
    nominal: &[f64],
    target: &[f64],
    zeros: &[f64],
    ticks: u64,
) -> f64 {
    let sc = setup.scenario();
    let dt = sc.dt;
    let layout = setup.layout;
    let observation = crate::estimation::models::GpCamera::shared(layout, setup.gp.clone());
    let mut belief = Uaic::new(sc.belief.clone(), observation, dt);
    let mut control = crate::control::Control::new(&sc.controller);
    let start = Instant::now();
    for k in 0..ticks {
        belief.update(&EstimatorInput {
            tick: k,
            readings: black_box(readings),
            precisions: nominal,
            applied_torques: zeros,
        });
        control.step(belief.mu(), belief.mu_p(), target, dt);
    }
    per_tick(start, ticks)
}

/// The learner stage: the paper's gradient rule on every channel (us per tick).
fn time_learner(
    setup: &RunSetup,
    readings: &Readings,
    nominal: &[f64],
    target: &[f64],
    zeros: &[f64],
    ticks: u64,
) -> f64 {
    let sc = setup.scenario();
    let dt = sc.dt;
    let layout = setup.layout;
    let mut learner = Gradient::new(
        nominal,
        sc.precision.kappa_zeta,
        true,
        sc.precision.bounds(),
    );
    let mut estimate = Estimate::new(&layout);
    estimate.residuals = nominal.iter().map(|w| Some(0.5 / w.sqrt())).collect();
    let start = Instant::now();
    for k in 0..ticks {
        learner.update(&PrecisionInput {
            tick: k,
            dt,
            layout: &layout,
            readings,
            estimate: black_box(&estimate),
            mu: target,
            mu_p: zeros,
            covariance: None,
            torques: zeros,
        });
    }
    per_tick(start, ticks)
}

/// What [`bench`] measured: per-tick times (us) of each stage and of the closed loop, and the
/// closed loop's ticks per second.
struct Timings {
    physics_us: f64,
    sensors_us: f64,
    gp_us: f64,
    controller_us: f64,
    learner_us: f64,
    closed_loop: f64,
    closed_us: f64,
    dt: f64,
    belief_mse: f64,
}

/// The figures [`bench`] reports.
fn figures(t: &Timings) -> Vec<Figure> {
    let Timings {
        physics_us,
        sensors_us,
        gp_us,
        controller_us,
        learner_us,
        closed_loop,
        closed_us,
        dt,
        belief_mse,
    } = *t;
    vec![
        Figure {
            name: "physics_tick_us",
            value: physics_us,
            unit: "us",
        },
        Figure {
            name: "sensors_tick_us",
            value: sensors_us,
            unit: "us",
        },
        Figure {
            name: "gp_predict_us",
            value: gp_us,
            unit: "us",
        },
        Figure {
            name: "controller_tick_us",
            value: controller_us,
            unit: "us",
        },
        Figure {
            name: "learner_tick_us",
            value: learner_us,
            unit: "us",
        },
        Figure {
            name: "closed_loop_tick_us",
            value: closed_us,
            unit: "us",
        },
        Figure {
            name: "physics_ticks_per_s",
            value: 1e6 / physics_us,
            unit: "1/s",
        },
        Figure {
            name: "closed_loop_ticks_per_s",
            value: closed_loop,
            unit: "1/s",
        },
        Figure {
            name: "closed_loop_over_physics",
            value: closed_us / physics_us,
            unit: "x",
        },
        Figure {
            name: "real_time_factor",
            value: closed_loop * dt,
            unit: "x",
        },
        Figure {
            name: "closed_loop_belief_mse",
            value: belief_mse,
            unit: "rad^2",
        },
    ]
}

/// Microseconds per tick since `start`, over `ticks` ticks.
fn per_tick(start: Instant, ticks: u64) -> f64 {
    start.elapsed().as_secs_f64() * 1e6 / ticks as f64
}
