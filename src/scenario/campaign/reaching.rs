//! The healthy reaching benchmark: random targets per arm, every method on each (what fault
//! tolerance costs when nothing fails).

use std::path::Path;

use rand::SeedableRng;
use rand_distr::{Distribution, Uniform};
use serde::{Deserialize, Serialize};

use super::Campaign;
use crate::scenario::calibrate;
use crate::scenario::runner::{Observer, ObserverMode, Run, TickRecord};
use crate::scenario::{Method, ScenarioError};

/// One task of the reaching benchmark.
#[derive(Clone, Debug, PartialEq)]
pub struct ReachingTask {
    pub arm: usize,
    pub task: usize,
    pub target: Vec<f64>,
}

/// One method on one reaching task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachingRun {
    pub job: usize,
    pub arm: usize,
    pub task: usize,
    pub method: Method,
    pub belief_rmse: f64,
    /// Largest overshoot beyond the target along the step, over joints (% of the step).
    pub overshoot: f64,
    /// Time after which every joint stays within 0.5 % of its step of the target (s; None: never).
    pub settling_time: Option<f64>,
    pub steady_state_error: f64,
    pub false_alarms: usize,
}

impl Campaign {
    /// The reaching tasks: per arm, targets uniform in the arm's camera-model box (its GP's
    /// training box) clipped 10 % inside the joint limits.
    pub fn reaching_tasks(&self) -> Vec<ReachingTask> {
        let Some(rc) = &self.config.reaching else {
            return vec![];
        };
        let mut tasks = Vec::new();
        for (a, setup) in self.arms.iter().enumerate() {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(rc.seed);
            rng.set_stream(a as u64);
            let boxes: Vec<(f64, f64)> = setup
                .gp
                .training_box
                .iter()
                .zip(&setup.model.joints)
                .map(|([lo, hi], j)| match j.limits {
                    Some((llo, lhi)) => {
                        let m = 0.1 * (lhi - llo);
                        (lo.max(llo + m), hi.min(lhi - m))
                    }
                    None => (*lo, *hi),
                })
                .collect();
            for t in 0..rc.tasks {
                let target = boxes
                    .iter()
                    .map(|&(lo, hi)| {
                        if hi > lo {
                            Uniform::new(lo, hi).expect("lo < hi").sample(&mut rng)
                        } else {
                            0.5 * (lo + hi)
                        }
                    })
                    .collect();
                tasks.push(ReachingTask {
                    arm: a,
                    task: t,
                    target,
                });
            }
        }
        tasks
    }
}

/// Records what the reaching metrics need.
struct ReachingObserver {
    start: Vec<f64>,
    target: Vec<f64>,
    dt: f64,
    sq: f64,
    count: u64,
    overshoot: f64,
    last_outside: Option<u64>,
    last_tick: u64,
    band: Vec<f64>,
}

impl Observer for ReachingObserver {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.last_tick = r.tick;
        for j in 0..self.target.len() {
            let e = r.mu[j] - r.q[j];
            self.sq += e * e;
            let step = self.target[j] - self.start[j];
            if step.abs() > 1e-9 {
                let beyond = (r.q[j] - self.target[j]) * step.signum() / step.abs() * 100.0;
                self.overshoot = self.overshoot.max(beyond);
            }
            if (r.q[j] - self.target[j]).abs() > self.band[j] {
                self.last_outside = Some(r.tick);
            }
        }
        self.count += self.target.len() as u64;
    }
}

pub(super) fn run_reaching(
    campaign: &Campaign,
    task: &ReachingTask,
    job: usize,
    cache: Option<&Path>,
) -> Result<Vec<ReachingRun>, ScenarioError> {
    let rc = campaign
        .config
        .reaching
        .as_ref()
        .expect("reaching configured");
    let mut setup = campaign.arms[task.arm].clone();
    let sc = &mut setup.loaded.scenario;
    sc.faults.clear();
    setup.faults.clear();
    sc.duration = rc.duration;
    sc.targets = vec![crate::scenario::Target {
        time: 0.0,
        q: task.target.clone(),
    }];
    let start = sc.initial.q.clone();
    let largest = task
        .target
        .iter()
        .zip(&start)
        .map(|(t, s)| (t - s).abs())
        .fold(0.0, f64::max);
    let band: Vec<f64> = task
        .target
        .iter()
        .zip(&start)
        .map(|(t, s)| 0.005 * (t - s).abs().max(0.01 * largest).max(1e-4))
        .collect();
    let dt = sc.dt;
    let calibration = if campaign.methods.iter().any(|m| m.needs_detector()) {
        Some(calibrate::cached_calibration(&setup, rc.calibration_runs, cache)?.0)
    } else {
        None
    };
    let mut out = Vec::new();
    for &m in &campaign.methods {
        let mut obs = ReachingObserver {
            start: start.clone(),
            target: task.target.clone(),
            dt,
            sq: 0.0,
            count: 0,
            overshoot: 0.0,
            last_outside: None,
            last_tick: 0,
            band: band.clone(),
        };
        let r = Run::new(&setup, m)
            .seed(1)
            .calibration(calibration.as_ref())
            .observe(&mut obs, ObserverMode::Always)
            .execute()?;
        let settling_time = match obs.last_outside {
            None => Some(0.0),
            Some(k) if k >= obs.last_tick => None,
            Some(k) => Some((k + 1) as f64 * obs.dt),
        };
        out.push(ReachingRun {
            job,
            arm: task.arm,
            task: task.task,
            method: m,
            belief_rmse: (obs.sq / obs.count.max(1) as f64).sqrt(),
            overshoot: obs.overshoot.max(0.0),
            settling_time,
            steady_state_error: r.max_final_error,
            false_alarms: r.false_alarms,
        });
    }
    Ok(out)
}
