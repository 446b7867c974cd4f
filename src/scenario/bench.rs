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

/// Times each stage over `ticks` ticks and the closed loop over one run of the scenario
/// (`pl-always`, the scenario's seed).
pub fn bench(setup: &RunSetup, ticks: u64) -> Result<Vec<Figure>, ScenarioError> {
    let sc = setup.scenario();
    let dt = sc.dt;
    let ticks = ticks.max(1);
    let per_tick = |start: Instant| start.elapsed().as_secs_f64() * 1e6 / ticks as f64;

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
    let physics_us = per_tick(start);

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
    let sensors_us = per_tick(start);

    // GP: mean and Jacobian.
    let r = layout.camera_outputs();
    let mut g = vec![0.0; r];
    let mut jac = vec![0.0; r * n];
    let start = Instant::now();
    for _ in 0..ticks {
        setup.gp.predict(black_box(&target), &mut g, &mut jac);
    }
    let gp_us = per_tick(start);

    // Controller: one belief update (GP included) and f*, on fixed readings.
    let nominal: Vec<f64> = super::runner::nominal_precisions(sensors.sigmas());
    let observation = crate::estimation::models::GpCamera::shared(layout, setup.gp.clone());
    let mut belief = Uaic::new(sc.belief.clone(), observation, dt);
    let mut control = crate::control::Control::new(&sc.controller);
    let zeros = vec![0.0; n];
    let start = Instant::now();
    for k in 0..ticks {
        belief.update(&EstimatorInput {
            tick: k,
            readings: black_box(&readings),
            precisions: &nominal,
            applied_torques: &zeros,
        });
        control.step(belief.mu(), belief.mu_p(), &target, dt);
    }
    let controller_us = per_tick(start);

    // Learner: the paper's gradient rule on every channel.
    let mut learner = Gradient::new(
        &nominal,
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
            readings: &readings,
            estimate: black_box(&estimate),
            mu: &target,
            mu_p: &zeros,
            covariance: None,
            torques: &zeros,
        });
    }
    let learner_us = per_tick(start);

    // The closed loop: one whole run.
    let result = Run::new(setup, Method::PlAlways).seed(sc.seed).execute()?;
    let closed_loop = result.ticks_per_second();
    let closed_us = 1e6 / closed_loop;

    Ok(vec![
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
    ])
}
