//! The deterministic fault detector of the ECC paper (METHOD.md section 6), the baseline.
//!
//! Per sensor group (encoders, tachometers, camera) the innovation r (readings against the
//! prediction, before the tick's belief update) is compared with its healthy distribution,
//! calibrated per time step from healthy runs of the same scenario:
//! `d_M = sqrt((r - r_mean)' C^-1 (r - r_mean))`, alarm when `d_M > sqrt(n / alpha)` (the
//! multivariate Chebyshev bound, n the group's dimension). Then isolation: the channel with the
//! largest normalised residual in the alarmed group (default), or the whole group (the ECC
//! paper's recovery). The alarm is latched: the first one isolates, later ticks only report
//! distances. A missing reading neither raises nor clears an alarm.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::sensors::{ChannelLayout, SensorGroup};

/// How an alarm is isolated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Isolation {
    /// The channel with the largest normalised residual in the alarmed group.
    Channel,
    /// Every channel of the alarmed group.
    Group,
}

/// Detector settings: alpha = 0.01 (Chebyshev false-alarm bound), channel isolation, moments
/// pooled over +-5 ticks around each step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    pub alpha: f64,
    pub isolation: Isolation,
    /// Half-width (ticks) of the window the per-step moments are pooled over.
    pub pool_ticks: usize,
    /// Number of healthy runs for calibration.
    pub calibration_runs: usize,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            alpha: 0.01,
            isolation: Isolation::Channel,
            pool_ticks: 5,
            calibration_runs: 50,
        }
    }
}

impl DetectorConfig {
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return Err(("alpha", "must be in (0, 1)".into()));
        }
        if self.calibration_runs < 2 {
            return Err(("calibration_runs", "must be >= 2".into()));
        }
        Ok(())
    }
}

/// Healthy innovation statistics of one group, per tick.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupCalibration {
    /// `enc`, `tach` or `cam`.
    pub group: String,
    /// Channel indices of the group (in [`ChannelLayout`] order).
    pub channels: Vec<usize>,
    /// Mean per tick, ticks x dim, row-major.
    pub mean: Vec<f64>,
    /// Covariance per tick, ticks x dim x dim, row-major.
    pub covariance: Vec<f64>,
}

/// Healthy residual statistics of a scenario, from `runs` healthy runs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Fingerprint of the scenario's schedule it was made for.
    pub fingerprint: String,
    pub dt: f64,
    pub ticks: usize,
    pub runs: usize,
    pub pool_ticks: usize,
    pub groups: Vec<GroupCalibration>,
}

/// Sums of healthy innovations per tick and group, filled run by run.
#[derive(Clone, Debug)]
pub struct CalibrationAccumulator {
    layout: ChannelLayout,
    ticks: usize,
    runs: usize,
    /// Per group: count per tick, sums (ticks x dim), sums of outer products (ticks x dim x dim).
    counts: Vec<Vec<f64>>,
    sums: Vec<Vec<f64>>,
    outer: Vec<Vec<f64>>,
}

impl CalibrationAccumulator {
    pub fn new(layout: ChannelLayout, ticks: usize) -> Self {
        let dims: Vec<usize> = SensorGroup::ALL
            .iter()
            .map(|&g| layout.group_range(g).len())
            .collect();
        Self {
            layout,
            ticks,
            runs: 0,
            counts: dims.iter().map(|_| vec![0.0; ticks]).collect(),
            sums: dims.iter().map(|d| vec![0.0; ticks * d]).collect(),
            outer: dims.iter().map(|d| vec![0.0; ticks * d * d]).collect(),
        }
    }

    /// Adds one tick of one run (a group with a missing channel is skipped).
    pub fn add(&mut self, tick: usize, innovations: &[Option<f64>]) {
        if tick >= self.ticks {
            return;
        }
        for (gi, &group) in SensorGroup::ALL.iter().enumerate() {
            let range = self.layout.group_range(group);
            let dim = range.len();
            if range.clone().any(|c| innovations[c].is_none()) {
                continue;
            }
            self.counts[gi][tick] += 1.0;
            for (a, ca) in range.clone().enumerate() {
                let va = innovations[ca].unwrap_or(0.0);
                self.sums[gi][tick * dim + a] += va;
                for (b, cb) in range.clone().enumerate() {
                    self.outer[gi][(tick * dim + a) * dim + b] +=
                        va * innovations[cb].unwrap_or(0.0);
                }
            }
        }
    }

    /// Marks the end of a run.
    pub fn end_run(&mut self) {
        self.runs += 1;
    }

    /// Adds another accumulator (the runs of a parallel batch), element by element.
    pub fn merge(&mut self, other: &Self) {
        for (a, b) in [
            (&mut self.counts, &other.counts),
            (&mut self.sums, &other.sums),
            (&mut self.outer, &other.outer),
        ] {
            for (x, y) in a.iter_mut().zip(b) {
                for (u, v) in x.iter_mut().zip(y) {
                    *u += v;
                }
            }
        }
        self.runs += other.runs;
    }

    /// Per-tick moments pooled over +-`pool_ticks`.
    pub fn finish(&self, dt: f64, pool_ticks: usize, fingerprint: String) -> Calibration {
        let ticks = self.ticks;
        let groups = SensorGroup::ALL
            .iter()
            .enumerate()
            .map(|(gi, &group)| {
                let channels: Vec<usize> = self.layout.group_range(group).collect();
                let dim = channels.len();
                let mut mean = vec![0.0; ticks * dim];
                let mut covariance = vec![0.0; ticks * dim * dim];
                for t in 0..ticks {
                    let lo = t.saturating_sub(pool_ticks);
                    let hi = (t + pool_ticks).min(ticks.saturating_sub(1));
                    let count: f64 = self.counts[gi][lo..=hi].iter().sum();
                    if count < 2.0 {
                        continue;
                    }
                    let mut m = vec![0.0; dim];
                    for (a, m_a) in m.iter_mut().enumerate() {
                        *m_a = (lo..=hi).map(|u| self.sums[gi][u * dim + a]).sum::<f64>() / count;
                    }
                    for a in 0..dim {
                        for b in 0..dim {
                            let s: f64 = (lo..=hi)
                                .map(|u| self.outer[gi][(u * dim + a) * dim + b])
                                .sum();
                            covariance[(t * dim + a) * dim + b] =
                                (s - count * m[a] * m[b]) / (count - 1.0);
                        }
                    }
                    mean[t * dim..(t + 1) * dim].copy_from_slice(&m);
                }
                GroupCalibration {
                    group: group.name().to_string(),
                    channels,
                    mean,
                    covariance,
                }
            })
            .collect();
        Calibration {
            fingerprint,
            dt,
            ticks,
            runs: self.runs,
            pool_ticks,
            groups,
        }
    }
}

impl Calibration {
    /// Per-tick moments of innovation series `runs[r][tick][channel]` (missing values skipped),
    /// pooled over +-`pool_ticks`.
    pub fn from_runs(
        layout: ChannelLayout,
        runs: &[Vec<Vec<Option<f64>>>],
        dt: f64,
        pool_ticks: usize,
        fingerprint: String,
    ) -> Self {
        let ticks = runs.iter().map(Vec::len).min().unwrap_or(0);
        let mut acc = CalibrationAccumulator::new(layout, ticks);
        for run in runs {
            for (t, row) in run.iter().enumerate() {
                acc.add(t, row);
            }
            acc.end_run();
        }
        acc.finish(dt, pool_ticks, fingerprint)
    }

    /// The calibration as JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a calibration always serialises")
    }

    /// Reads a calibration from JSON; checks its shape.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let c: Calibration = serde_json::from_str(text).map_err(|e| e.to_string())?;
        for g in &c.groups {
            let dim = g.channels.len();
            if g.mean.len() != c.ticks * dim || g.covariance.len() != c.ticks * dim * dim {
                return Err(format!("group {} has the wrong number of values", g.group));
            }
        }
        if c.groups.len() != 3 {
            return Err("expected the enc, tach and cam groups".into());
        }
        Ok(c)
    }
}

/// The detector's state after a tick.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Detection {
    /// The tick of the (latched) alarm.
    pub fired_tick: Option<u64>,
    /// The alarmed group.
    pub group: Option<SensorGroup>,
    /// Channels isolated as faulty.
    pub isolated: Vec<usize>,
    /// d_M / threshold per group in [`SensorGroup::ALL`] order (None: not evaluated this tick).
    pub normalised_distance: [Option<f64>; 3],
}

/// Per-tick precomputed inverse covariances of one group.
struct GroupTest {
    group: SensorGroup,
    channels: Vec<usize>,
    dim: usize,
    threshold: f64,
    mean: Vec<f64>,
    /// Inverse covariance per tick (None where the calibration had no data).
    inverse: Vec<Option<DMatrix<f64>>>,
    std: Vec<f64>,
}

/// The detector, ready to run.
pub struct Detector {
    tests: Vec<GroupTest>,
    isolation: Isolation,
    state: Detection,
    scratch: DVector<f64>,
}

impl Detector {
    pub fn new(calibration: &Calibration, config: &DetectorConfig) -> Self {
        let tests = calibration
            .groups
            .iter()
            .zip(SensorGroup::ALL)
            .map(|(g, group)| {
                let dim = g.channels.len();
                let mut inverse = Vec::with_capacity(calibration.ticks);
                let mut std = vec![0.0; calibration.ticks * dim];
                for t in 0..calibration.ticks {
                    let c = DMatrix::from_row_slice(
                        dim,
                        dim,
                        &g.covariance[t * dim * dim..(t + 1) * dim * dim],
                    );
                    for a in 0..dim {
                        std[t * dim + a] = c[(a, a)].max(0.0).sqrt();
                    }
                    // A tiny ridge keeps a degenerate covariance invertible.
                    let ridge = 1e-12 * c.diagonal().max().max(1e-300);
                    let c = c + DMatrix::identity(dim, dim) * ridge;
                    inverse.push(if std[t * dim..(t + 1) * dim].iter().all(|s| *s > 0.0) {
                        c.cholesky().map(|ch| ch.inverse())
                    } else {
                        None
                    });
                }
                GroupTest {
                    group,
                    channels: g.channels.clone(),
                    dim,
                    threshold: (dim as f64 / config.alpha).sqrt(),
                    mean: g.mean.clone(),
                    inverse,
                    std,
                }
            })
            .collect();
        Self {
            tests,
            isolation: config.isolation,
            state: Detection::default(),
            scratch: DVector::zeros(0),
        }
    }

    /// The state after the last tick.
    pub fn state(&self) -> &Detection {
        &self.state
    }

    /// Tests this tick's innovations (`None`: missing).
    pub fn check(&mut self, tick: u64, innovations: &[Option<f64>]) -> &Detection {
        let t = tick as usize;
        for (gi, test) in self.tests.iter().enumerate() {
            self.state.normalised_distance[gi] = None;
            let Some(Some(inv)) = test.inverse.get(t) else {
                continue;
            };
            if test.channels.iter().any(|&c| innovations[c].is_none()) {
                continue;
            }
            let dim = test.dim;
            if self.scratch.len() != dim {
                self.scratch = DVector::zeros(dim);
            }
            for (j, &c) in test.channels.iter().enumerate() {
                self.scratch[j] = innovations[c].unwrap_or(0.0) - test.mean[t * dim + j];
            }
            let d2 = (inv * &self.scratch).dot(&self.scratch);
            let d = d2.max(0.0).sqrt();
            self.state.normalised_distance[gi] = Some(d / test.threshold);
            if self.state.fired_tick.is_none() && d > test.threshold {
                self.state.fired_tick = Some(tick);
                self.state.group = Some(test.group);
                self.state.isolated = match self.isolation {
                    Isolation::Group => test.channels.clone(),
                    Isolation::Channel => {
                        let worst = (0..dim)
                            .max_by(|&a, &b| {
                                let na = self.scratch[a].abs() / test.std[t * dim + a];
                                let nb = self.scratch[b].abs() / test.std[t * dim + b];
                                na.total_cmp(&nb)
                            })
                            .unwrap_or(0);
                        vec![test.channels[worst]]
                    }
                };
            }
        }
        &self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two-channel healthy runs: independent N(0, 1) innovations, 200 runs x 100 ticks.
    fn calibration() -> Calibration {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let layout = ChannelLayout::new(1);
        let runs: Vec<Vec<Vec<Option<f64>>>> = (0..200)
            .map(|_| {
                (0..100)
                    .map(|_| {
                        (0..layout.len())
                            .map(|_| Some(StandardNormal.sample(&mut rng)))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        Calibration::from_runs(layout, &runs, 1e-3, 2, "test".into())
    }

    #[test]
    fn calibrated_moments_match_the_generator() {
        let cal = calibration();
        for g in &cal.groups {
            let dim = g.channels.len();
            for t in 0..cal.ticks {
                for a in 0..dim {
                    assert!(g.mean[t * dim + a].abs() < 0.2);
                    for b in 0..dim {
                        let c = g.covariance[(t * dim + a) * dim + b];
                        let expected = if a == b { 1.0 } else { 0.0 };
                        assert!((c - expected).abs() < 0.25, "{c}");
                    }
                }
            }
        }
    }

    #[test]
    fn an_outlier_fires_and_isolates_its_channel_and_the_alarm_latches() {
        let cal = calibration();
        let mut det = Detector::new(&cal, &DetectorConfig::default());
        // Encoder (channel 0) at 3 sigma: below sqrt(1 / 0.01) = 10.
        let d = det.check(10, &[Some(3.0), Some(0.0), Some(0.0), Some(0.0)]);
        assert!(d.fired_tick.is_none());
        // Camera u (channel 2) at 20 sigma: fires in the camera group, isolates channel 2.
        let d = det
            .check(11, &[Some(0.0), Some(0.0), Some(20.0), Some(0.5)])
            .clone();
        assert_eq!(d.fired_tick, Some(11));
        assert_eq!(d.group, Some(SensorGroup::Camera));
        assert_eq!(d.isolated, vec![2]);
        // Latched: a later, larger alarm elsewhere does not change it.
        let d = det.check(12, &[Some(50.0), Some(0.0), Some(0.0), Some(0.0)]);
        assert_eq!(d.fired_tick, Some(11));
        assert_eq!(d.isolated, vec![2]);
    }

    #[test]
    fn missing_readings_neither_raise_nor_clear() {
        let cal = calibration();
        let mut det = Detector::new(&cal, &DetectorConfig::default());
        let d = det.check(5, &[None, Some(0.0), Some(0.0), Some(0.0)]);
        assert!(d.fired_tick.is_none());
        assert_eq!(d.normalised_distance[0], None);
        let config = DetectorConfig {
            isolation: Isolation::Group,
            ..DetectorConfig::default()
        };
        let mut det = Detector::new(&cal, &config);
        det.check(6, &[Some(0.0), Some(0.0), Some(40.0), Some(0.0)]);
        let d = det.check(7, &[Some(0.0), Some(0.0), None, None]);
        assert_eq!(d.isolated, vec![2, 3], "group isolation, still latched");
    }
}
