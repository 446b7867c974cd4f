//! Open-loop runs with constant joint torques (the `simulate` command).

use super::Plant;
use crate::arm::EndEffector;

/// One tick of an open-loop run.
#[derive(Clone, Debug, PartialEq)]
pub struct OpenLoopSample {
    pub t: f64,
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub ee: [f64; 3],
}

/// Runs the arm from (q0, qd0) with constant torques for `duration` seconds at step `dt`.
/// Returns one sample per tick, from t = 0 to the last tick (round(duration / dt) steps): the
/// whole run in memory (for a long run, [`run_open_loop_with`] hands each sample over instead).
///
/// # Panics
/// If a slice does not have one entry per joint.
pub fn run_open_loop(
    arm: &mut dyn Plant,
    ee: &EndEffector,
    q0: &[f64],
    qd0: &[f64],
    torque: &[f64],
    duration: f64,
    dt: f64,
) -> Vec<OpenLoopSample> {
    let mut out = Vec::new();
    let done: Result<(), std::convert::Infallible> =
        run_open_loop_with(arm, ee, q0, qd0, torque, duration, dt, |s| {
            out.push(s.clone());
            Ok(())
        });
    let Ok(()) = done;
    out
}

/// [`run_open_loop`] without keeping the run: `visit` gets each sample as it is made (memory
/// does not grow with the run's length) and stops the run with its first error.
///
/// # Panics
/// If a slice does not have one entry per joint.
#[allow(clippy::too_many_arguments)]
pub fn run_open_loop_with<E>(
    arm: &mut dyn Plant,
    ee: &EndEffector,
    q0: &[f64],
    qd0: &[f64],
    torque: &[f64],
    duration: f64,
    dt: f64,
    mut visit: impl FnMut(&OpenLoopSample) -> Result<(), E>,
) -> Result<(), E> {
    arm.set_state(q0, qd0);
    arm.set_torques(torque);
    let steps = (duration / dt).round() as usize;
    let sample = |arm: &dyn Plant, k: usize| {
        let (q, qd) = arm.state();
        let p = arm.ee_position(ee);
        OpenLoopSample {
            t: k as f64 * dt,
            q,
            qd,
            ee: [p.x, p.y, p.z],
        }
    };
    visit(&sample(arm, 0))?;
    for k in 1..=steps {
        arm.step(dt);
        visit(&sample(arm, k))?;
    }
    Ok(())
}

/// The CSV header of an open-loop run: `t,q1..qn,qd1..qdn,ee_x,ee_y,ee_z`.
pub fn open_loop_header(n: usize) -> Vec<String> {
    let mut h = vec!["t".to_string()];
    h.extend((1..=n).map(|i| format!("q{i}")));
    h.extend((1..=n).map(|i| format!("qd{i}")));
    h.extend(["ee_x", "ee_y", "ee_z"].map(String::from));
    h
}
