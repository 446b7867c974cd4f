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
/// Returns one sample per tick, from t = 0 to the last tick (round(duration / dt) steps).
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
    arm.set_state(q0, qd0);
    arm.set_torques(torque);
    let steps = (duration / dt).round() as usize;
    let mut out = Vec::with_capacity(steps + 1);
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
    out.push(sample(arm, 0));
    for k in 1..=steps {
        arm.step(dt);
        out.push(sample(arm, k));
    }
    out
}

/// The CSV header of an open-loop run: `t,q1..qn,qd1..qdn,ee_x,ee_y,ee_z`.
pub fn open_loop_header(n: usize) -> Vec<String> {
    let mut h = vec!["t".to_string()];
    h.extend((1..=n).map(|i| format!("q{i}")));
    h.extend((1..=n).map(|i| format!("qd{i}")));
    h.extend(["ee_x", "ee_y", "ee_z"].map(String::from));
    h
}
