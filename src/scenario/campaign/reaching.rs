//! The healthy reaching benchmark: random targets per arm, every method on each (what fault
//! tolerance costs when nothing fails).

use std::path::Path;

use rand::SeedableRng;
use rand_distr::{Distribution, Uniform};
use serde::{Deserialize, Serialize};

use super::{Campaign, ReachingProtocol};
use crate::scenario::ScenarioError;
use crate::scenario::calibrate;
use crate::scenario::method::{ExternalMethod, MethodId};
use crate::scenario::runner::{Observer, ObserverMode, TickRecord};

/// One task of the reaching benchmark.
#[derive(Clone, Debug, PartialEq)]
pub struct ReachingTask {
    pub arm: usize,
    pub task: usize,
    pub target: Vec<f64>,
}

fn completed() -> String {
    "completed".into()
}

/// One method on one reaching task.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachingRun {
    pub job: usize,
    pub arm: usize,
    pub task: usize,
    pub method: MethodId,
    /// How the run ended (`completed`, `diverged`, `chattering`, `stopped`): the measures of a
    /// run that did not complete describe only the ticks it ran.
    #[serde(default = "completed")]
    pub outcome: String,
    #[serde(deserialize_with = "super::run::number_or_null")]
    pub belief_rmse: f64,
    /// Largest overshoot beyond the target along the step, over joints (% of the step).
    #[serde(deserialize_with = "super::run::number_or_null")]
    pub overshoot: f64,
    /// Time after which every joint stays within 0.5 % of its step of the target (s; None: never).
    pub settling_time: Option<f64>,
    #[serde(deserialize_with = "super::run::number_or_null")]
    pub steady_state_error: f64,
    /// Sensor alarms plus the method's own actuator alarms (none is at fault in a healthy
    /// reaching task), as the fault cells count them.
    pub false_alarms: usize,
}

impl Campaign {
    /// The reaching tasks: per arm, the targets file's first `tasks` targets, or targets drawn
    /// uniformly per joint in `target_range`, else in the arm's camera-model box (its GP's
    /// training box) clipped 10 % inside the joint limits.
    pub fn reaching_tasks(&self) -> Vec<ReachingTask> {
        let Some(rc) = &self.config.reaching else {
            return vec![];
        };
        let mut tasks = Vec::new();
        for (a, setup) in self.arms.iter().enumerate() {
            if let Some(targets) = &self.reaching_targets {
                for (t, target) in targets.iter().enumerate() {
                    tasks.push(ReachingTask {
                        arm: a,
                        task: t,
                        target: target.clone(),
                    });
                }
                continue;
            }
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(rc.seed);
            rng.set_stream(a as u64);
            let boxes: Vec<(f64, f64)> = match rc.target_range.as_deref() {
                // The range on every joint, clipped to the joint's limits.
                Some(&[lo, hi]) => setup
                    .model
                    .joints
                    .iter()
                    .map(|j| match j.limits {
                        Some((llo, lhi)) => (lo.max(llo), hi.min(lhi)),
                        None => (lo, hi),
                    })
                    .collect(),
                _ => setup
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
                    .collect(),
            };
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

/// What the authors' protocol keeps of a run (`matlab/statistical_analysis.m`): their arrays hold
/// the initial state and belief as sample 1, then one sample per tick, the state q(i) at the
/// tick's start beside mu(i), the belief before the tick's readings.
struct AuthorsSeries {
    joint: usize,
    /// q of the measured joint, sample by sample (sample 1 the initial state).
    q: Vec<f64>,
    /// Per joint, the sum of (q(i) - mu(i))^2 and the number of samples.
    lagged_sq: Vec<f64>,
    samples: u64,
    /// The belief after the last tick's update (mu(i + 1) for the next sample).
    last_mu: Vec<f64>,
    final_q: Vec<f64>,
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
    authors: Option<AuthorsSeries>,
}

impl Observer for ReachingObserver {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.last_tick = r.tick;
        if let Some(a) = &mut self.authors {
            let n = self.target.len();
            if r.tick == 0 {
                // Sample 1: the initial state and the belief's initialisation (the first
                // readings); their script starts both at q(:,1), a zero residual.
                a.q.push(r.q[a.joint]);
                for j in 0..n {
                    a.last_mu[j] = r.readings.get(j).unwrap_or(0.0);
                }
                a.samples += 1;
            }
            a.q.push(r.q[a.joint]);
            for j in 0..n {
                let e = r.q[j] - a.last_mu[j];
                a.lagged_sq[j] += e * e;
            }
            a.samples += 1;
            a.last_mu.copy_from_slice(r.mu);
            a.final_q.copy_from_slice(r.q);
        }
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
    external: &[ExternalMethod<'_>],
) -> Result<Vec<ReachingRun>, ScenarioError> {
    let rc = campaign
        .config
        .reaching
        .as_ref()
        .expect("reaching configured");
    let mut setup = campaign.arms[task.arm].healthy();
    let sc = &mut setup.loaded.scenario;
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
    let ticks = sc.ticks().min(crate::scenario::MAX_TICKS);
    let calibration = if campaign.methods.iter().any(|m| m.needs_detector()) {
        Some(calibrate::cached_calibration(&setup, rc.calibration_runs, cache)?.0)
    } else {
        None
    };
    let n = start.len();
    let mut out = Vec::new();
    for m in &campaign.methods {
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
            authors: (rc.protocol == ReachingProtocol::Authors).then(|| AuthorsSeries {
                joint: rc.step_joint - 1,
                q: Vec::with_capacity(ticks as usize + 1),
                lagged_sq: vec![0.0; n],
                samples: 0,
                last_mu: vec![0.0; n],
                final_q: start.clone(),
            }),
        };
        let place = format!(
            "arm {}, reaching task {}",
            campaign.config.arms[task.arm].name,
            task.task + 1
        );
        let r = super::run::begin_run(
            &setup,
            m,
            1,
            calibration.as_ref(),
            external,
            (&place, &campaign.path),
        )?
        .observe(&mut obs, ObserverMode::Always)
        .execute()?;
        let run = match &obs.authors {
            None => ReachingRun {
                job,
                arm: task.arm,
                task: task.task,
                method: m.clone(),
                outcome: r.outcome.name().to_string(),
                belief_rmse: (obs.sq / obs.count.max(1) as f64).sqrt(),
                overshoot: obs.overshoot.max(0.0),
                settling_time: match obs.last_outside {
                    None => Some(0.0),
                    Some(k) if k >= obs.last_tick => None,
                    Some(k) => Some((k + 1) as f64 * obs.dt),
                },
                steady_state_error: r.max_final_error,
                false_alarms: r.false_alarms + r.actuator_false_alarms,
            },
            Some(a) => {
                let measures = authors_measures(a, &task.target, &start, dt);
                ReachingRun {
                    job,
                    arm: task.arm,
                    task: task.task,
                    method: m.clone(),
                    outcome: r.outcome.name().to_string(),
                    belief_rmse: measures.belief_rmse,
                    overshoot: measures.overshoot,
                    settling_time: measures.settling_time,
                    steady_state_error: measures.steady_state_error,
                    false_alarms: r.false_alarms + r.actuator_false_alarms,
                }
            }
        };
        out.push(run);
    }
    Ok(out)
}

/// The authors' four measures of one task.
struct AuthorsMeasures {
    overshoot: f64,
    settling_time: Option<f64>,
    steady_state_error: f64,
    belief_rmse: f64,
}

/// `stepinfo(q(j,:) - q(j,1), time_vec, mu_d(j) - q(j,1), 'SettlingTimeThreshold', 0.005)` on the
/// measured joint, `sum(abs(mu_d - q(:,end)))/n` and the mean over joints of
/// `sqrt(mean((q(j,:) - mu(j,:)).^2))` (matlab/statistical_analysis.m).
fn authors_measures(a: &AuthorsSeries, target: &[f64], start: &[f64], dt: f64) -> AuthorsMeasures {
    let j = a.joint;
    let q0 = a.q.first().copied().unwrap_or(start[j]);
    let y: Vec<f64> = a.q.iter().map(|v| v - q0).collect();
    let info = crate::scenario::step_info(&y, dt, target[j] - q0, 0.005);
    let n = target.len() as f64;
    AuthorsMeasures {
        overshoot: info.overshoot,
        settling_time: info.settling_time,
        steady_state_error: target
            .iter()
            .zip(&a.final_q)
            .map(|(t, q)| (t - q).abs())
            .sum::<f64>()
            / n,
        belief_rmse: a
            .lagged_sq
            .iter()
            .map(|s| (s / a.samples.max(1) as f64).sqrt())
            .sum::<f64>()
            / n,
    }
}
