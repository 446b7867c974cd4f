//! The deterministic fault detector of the ECC paper (docs/method.md, "The detector"), the
//! baseline.
//!
//! Per sensor group of the layout, the innovation r (readings against the prediction, before
//! the tick's belief update) is compared with its healthy distribution, calibrated per time step
//! from healthy runs of the same scenario: `d_M = sqrt((r - r_mean)' C^-1 (r - r_mean))` over the
//! group's channels not already isolated, alarm when `d_M > sqrt(n / alpha)` (the multivariate
//! Chebyshev bound, n those channels' count). Then isolation: the channel with the largest
//! normalised residual in the alarmed group (default), or every such channel of the group (the
//! ECC paper's recovery).
//!
//! Or, with `test = "cusum"`, a two-sided CUSUM (Page 1954) per channel on the same normalised
//! innovation z = (r - r_mean) / r_std: `S+ = max(0, S+ + z - k)`, `S- = max(0, S- - z - k)`,
//! alarm when either exceeds h, isolating that channel. A step of size delta (in healthy
//! standard deviations) is found after about h / (delta - k) ticks, so a slow drift that never
//! crosses the Chebyshev bound in one tick still accumulates to an alarm.
//!
//! A run may raise many alarms: every group is tested every tick, and an isolated channel is
//! re-admitted once its own normalised innovation has stayed within the one-dimensional bound
//! `sqrt(1 / alpha)` for `rearm_ticks` ticks (0: never; the ECC paper latches). A missing
//! reading neither raises nor clears an alarm.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::sensors::{ChannelLayout, SensorGroup};

/// How an alarm is isolated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Isolation {
    /// The channel with the largest normalised residual in the alarmed group.
    Channel,
    /// Every channel of the alarmed group.
    Group,
}

/// The detector's test.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum DetectorTest {
    /// The ECC paper's per-tick multivariate Chebyshev bound per sensor group.
    Chebyshev,
    /// A two-sided CUSUM per channel on the normalised innovation.
    Cusum,
}

/// Largest number of alarms a run keeps (later ones are counted, not kept).
pub const MAX_ALARMS: usize = 10_000;

/// Detector settings: alpha = 0.01 (Chebyshev false-alarm bound), channel isolation, moments
/// pooled over +-5 ticks around each step, an isolated channel re-admitted after 1000 quiet
/// ticks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Chebyshev false-alarm bound per test: the threshold is sqrt(n / alpha) healthy spreads.
    pub alpha: f64,
    /// Which channels an alarm drops: the largest normalised residual, or its whole group.
    pub isolation: Isolation,
    /// Half-width (ticks) of the window the per-step moments are pooled over.
    pub pool_ticks: usize,
    /// Number of healthy runs for calibration.
    #[schemars(range(min = 2, max = 10000))]
    pub calibration_runs: usize,
    /// Ticks an isolated channel's innovation must stay within sqrt(1 / alpha) of its healthy
    /// spread before it is re-admitted; 0 never re-admits (the ECC paper's latch).
    pub rearm_ticks: u64,
    /// `chebyshev` (the ECC paper's) or `cusum`.
    pub test: DetectorTest,
    /// CUSUM drift allowance k (healthy standard deviations per tick).
    pub cusum_drift: f64,
    /// CUSUM alarm threshold h (healthy standard deviations).
    pub cusum_threshold: f64,
    /// A calibration file (relative to the scenario file); default: calibrate on the fly.
    pub calibration: Option<std::path::PathBuf>,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            alpha: 0.01,
            isolation: Isolation::Channel,
            pool_ticks: 5,
            calibration_runs: 50,
            rearm_ticks: 1000,
            test: DetectorTest::Chebyshev,
            cusum_drift: 1.0,
            cusum_threshold: 200.0,
            calibration: None,
        }
    }
}

/// Most healthy calibration runs.
pub const MAX_CALIBRATION_RUNS: usize = 10_000;

impl DetectorConfig {
    pub fn validate(&self) -> Result<(), crate::SettingError> {
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return Err(crate::SettingError::new("alpha", "must be in (0, 1)"));
        }
        if !(2..=MAX_CALIBRATION_RUNS).contains(&self.calibration_runs) {
            return Err(crate::SettingError::new(
                "calibration_runs",
                format!("must be in 2..={MAX_CALIBRATION_RUNS}"),
            ));
        }
        if self.pool_ticks > 10_000 {
            return Err(crate::SettingError::new("pool_ticks", "must be <= 10000"));
        }
        if self.rearm_ticks > 1_000_000_000 {
            return Err(crate::SettingError::new("rearm_ticks", "must be <= 1e9"));
        }
        if !(self.cusum_drift.is_finite() && self.cusum_drift >= 0.0 && self.cusum_drift <= 1e3) {
            return Err(crate::SettingError::new(
                "cusum_drift",
                "must be in [0, 1e3]",
            ));
        }
        if !(self.cusum_threshold.is_finite()
            && self.cusum_threshold > 0.0
            && self.cusum_threshold <= 1e9)
        {
            return Err(crate::SettingError::new(
                "cusum_threshold",
                "must be in (0, 1e9]",
            ));
        }
        Ok(())
    }
}

/// Healthy innovation statistics of one group, per tick.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupCalibration {
    /// The group's short name (`enc`, `tach`, `cam`).
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

/// Numbers a calibration of `ticks` ticks holds for `layout` (its memory, in f64s, is about
/// three times that while it is accumulated).
pub fn calibration_size(layout: &ChannelLayout, ticks: usize) -> usize {
    layout
        .groups()
        .iter()
        .map(|&g| {
            let d = layout.group_range(g).len();
            ticks.saturating_mul(d + d * d)
        })
        .fold(0usize, usize::saturating_add)
}

impl CalibrationAccumulator {
    pub fn new(layout: ChannelLayout, ticks: usize) -> Self {
        let dims: Vec<usize> = layout
            .groups()
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
        for (gi, &group) in self.layout.groups().iter().enumerate() {
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
        let groups = self
            .layout
            .groups()
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
        if c.groups.is_empty() {
            return Err("it has no sensor groups".into());
        }
        for g in &c.groups {
            let dim = g.channels.len();
            if dim == 0 {
                return Err(format!("group {} has no channels", g.group));
            }
            let expected = c.ticks.checked_mul(dim).and_then(|v| v.checked_mul(dim));
            if c.ticks.checked_mul(dim) != Some(g.mean.len())
                || expected != Some(g.covariance.len())
            {
                return Err(format!("group {} has the wrong number of values", g.group));
            }
            if !g.mean.iter().chain(&g.covariance).all(|v| v.is_finite()) {
                return Err(format!("group {} holds a non-finite value", g.group));
            }
        }
        Ok(c)
    }

    /// Whether the calibration's groups are `layout`'s.
    pub fn matches(&self, layout: &ChannelLayout) -> bool {
        self.groups.len() == layout.groups().len()
            && self.groups.iter().zip(layout.groups()).all(|(g, &lg)| {
                g.group == lg.name() && g.channels == layout.group_range(lg).collect::<Vec<_>>()
            })
    }

    /// The first tick whose covariance of some group is not positive definite although it has
    /// data, with the group's name (a calibration that would silently disable the detector).
    pub fn degenerate_tick(&self) -> Option<(usize, String)> {
        for g in &self.groups {
            let dim = g.channels.len();
            for t in 0..self.ticks {
                let cov = &g.covariance[t * dim * dim..(t + 1) * dim * dim];
                if cov.iter().all(|v| *v == 0.0) {
                    // No data at this tick (fewer than two samples): not tested, by design.
                    if g.mean[t * dim..(t + 1) * dim].iter().all(|v| *v == 0.0) {
                        continue;
                    }
                    return Some((t, g.group.clone()));
                }
                let c = DMatrix::from_row_slice(dim, dim, cov);
                if c.cholesky().is_none() {
                    return Some((t, g.group.clone()));
                }
            }
        }
        None
    }
}

/// One alarm: when, in which group, the channels it isolated, and when they were re-admitted.
#[derive(Clone, Debug, PartialEq)]
pub struct Alarm {
    pub tick: u64,
    pub group: SensorGroup,
    pub channels: Vec<usize>,
    /// When the last of its channels was re-admitted (`None`: still isolated).
    pub cleared: Option<u64>,
}

/// The detector's state after a tick.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Detection {
    /// Every alarm so far, in order (at most [`MAX_ALARMS`]).
    pub alarms: Vec<Alarm>,
    /// Alarms raised beyond [`MAX_ALARMS`] (counted, not kept).
    pub dropped_alarms: u64,
    /// Channels isolated now, sorted.
    pub isolated: Vec<usize>,
    /// d_M / threshold per group of the layout (None: not evaluated this tick).
    pub normalised_distance: Vec<Option<f64>>,
}

impl Detection {
    /// The first alarm of the run.
    pub fn first(&self) -> Option<&Alarm> {
        self.alarms.first()
    }

    /// Whether any alarm has been raised.
    pub fn fired(&self) -> bool {
        !self.alarms.is_empty() || self.dropped_alarms > 0
    }

    /// Whether a channel is isolated now.
    pub fn active(&self) -> bool {
        !self.isolated.is_empty()
    }
}

/// Per-tick precomputed inverse covariances of one group.
struct GroupTest {
    group: SensorGroup,
    channels: Vec<usize>,
    dim: usize,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    /// Inverse covariance per tick (None where the calibration had no data).
    inverse: Vec<Option<DMatrix<f64>>>,
    std: Vec<f64>,
}

/// The detector, ready to run.
pub struct Detector {
    tests: Vec<GroupTest>,
    alpha: f64,
    isolation: Isolation,
    rearm_ticks: u64,
    test: DetectorTest,
    cusum_drift: f64,
    cusum_threshold: f64,
    /// Per channel: the CUSUM sums (S+, S-).
    cusum: Vec<(f64, f64)>,
    /// Scratch: the tested group's channels not isolated.
    active: Vec<usize>,
    state: Detection,
    /// Per channel: consecutive quiet ticks while isolated.
    quiet: Vec<u64>,
    /// Per channel: the alarm that isolated it.
    isolated_by: Vec<Option<usize>>,
    scratch: Vec<f64>,
    /// Scratch of the test over a group's channels not isolated: the Cholesky factor of their
    /// covariance (row-major, k x k) and the forward substitution.
    factor: Vec<f64>,
    solved: Vec<f64>,
}

/// r' C_A^-1 r for the sub-covariance C_A of `covariance` (dim x dim, row-major) on the indices
/// `active`, r = `x` on them: C_A = L L' factorised in `factor` (Cholesky-Banachiewicz), then
/// L y = r solved in `solved`, and the form is y'y. Works in the caller's storage (no
/// allocation); None when C_A is not positive definite.
fn sub_quadratic_form(
    covariance: &[f64],
    dim: usize,
    active: &[usize],
    x: &[f64],
    factor: &mut [f64],
    solved: &mut [f64],
) -> Option<f64> {
    let k = active.len();
    let l = &mut factor[..k * k];
    for i in 0..k {
        for j in 0..=i {
            let mut s = covariance[active[i] * dim + active[j]];
            for m in 0..j {
                s -= l[i * k + m] * l[j * k + m];
            }
            if i == j {
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                l[i * k + i] = s.sqrt();
            } else {
                l[i * k + j] = s / l[j * k + j];
            }
        }
    }
    let mut q = 0.0;
    for i in 0..k {
        let mut s = x[active[i]];
        for m in 0..i {
            s -= l[i * k + m] * solved[m];
        }
        solved[i] = s / l[i * k + i];
        q += solved[i] * solved[i];
    }
    Some(q)
}

impl Detector {
    /// A detector on a calibration whose groups match the layout ([`Calibration::matches`]).
    pub fn new(calibration: &Calibration, config: &DetectorConfig, layout: &ChannelLayout) -> Self {
        let tests = calibration
            .groups
            .iter()
            .zip(layout.groups())
            .map(|(g, &group)| {
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
                    mean: g.mean.clone(),
                    covariance: g.covariance.clone(),
                    inverse,
                    std,
                }
            })
            .collect();
        Self {
            tests,
            alpha: config.alpha,
            isolation: config.isolation,
            rearm_ticks: config.rearm_ticks,
            test: config.test,
            cusum_drift: config.cusum_drift,
            cusum_threshold: config.cusum_threshold,
            cusum: vec![(0.0, 0.0); layout.len()],
            active: Vec::with_capacity(layout.len()),
            // Room for the first 64 alarms and every channel isolated at once: raising one of
            // those allocates only its own channel list (later alarms may grow the list).
            state: Detection {
                alarms: Vec::with_capacity(64),
                isolated: Vec::with_capacity(layout.len()),
                normalised_distance: vec![None; layout.groups().len()],
                ..Detection::default()
            },
            quiet: vec![0; layout.len()],
            isolated_by: vec![None; layout.len()],
            scratch: vec![0.0; layout.len()],
            factor: vec![0.0; layout.len() * layout.len()],
            solved: vec![0.0; layout.len()],
        }
    }

    /// The state after the last tick.
    pub fn state(&self) -> &Detection {
        &self.state
    }

    /// Tests this tick's innovations (`None`: missing).
    pub fn check(&mut self, tick: u64, innovations: &[Option<f64>]) -> &Detection {
        let t = tick as usize;
        let one_d_bound = (1.0 / self.alpha).sqrt();
        let mut active = std::mem::take(&mut self.active);
        for gi in 0..self.tests.len() {
            self.state.normalised_distance[gi] = None;
            let test = &self.tests[gi];
            let Some(Some(_)) = test.inverse.get(t) else {
                continue;
            };
            if test.channels.iter().any(|&c| innovations[c].is_none()) {
                continue;
            }
            let dim = test.dim;
            for (j, &c) in test.channels.iter().enumerate() {
                self.scratch[j] = innovations[c].unwrap_or(0.0) - test.mean[t * dim + j];
            }
            self.readmit(gi, t, tick, one_d_bound);
            // The test over the channels not isolated.
            let test = &self.tests[gi];
            active.clear();
            active.extend((0..dim).filter(|&j| self.isolated_by[test.channels[j]].is_none()));
            if active.is_empty() {
                continue;
            }
            if self.test == DetectorTest::Cusum {
                self.cusum_test(gi, t, tick, &active);
            } else {
                self.distance_test(gi, t, tick, &active);
            }
        }
        self.active = active;
        &self.state
    }

    /// Re-admits group `gi`'s isolated channels that stayed within the one-dimensional bound for
    /// the re-arm time (their alarm cleared when it isolates nothing more).
    fn readmit(&mut self, gi: usize, t: usize, tick: u64, one_d_bound: f64) {
        let test = &self.tests[gi];
        let dim = test.dim;
        let mut readmitted = false;
        for (j, &c) in test.channels.iter().enumerate() {
            let Some(alarm) = self.isolated_by[c] else {
                continue;
            };
            let z = self.scratch[j].abs() / test.std[t * dim + j];
            self.quiet[c] = if z <= one_d_bound {
                self.quiet[c] + 1
            } else {
                0
            };
            if self.rearm_ticks > 0 && self.quiet[c] >= self.rearm_ticks {
                self.isolated_by[c] = None;
                self.quiet[c] = 0;
                self.cusum[c] = (0.0, 0.0);
                readmitted = true;
                let still = self.isolated_by.contains(&Some(alarm));
                if !still && let Some(a) = self.state.alarms.get_mut(alarm) {
                    a.cleared = Some(tick);
                }
            }
        }
        if readmitted {
            self.state
                .isolated
                .retain(|&c| self.isolated_by[c].is_some());
        }
    }

    /// The CUSUM test of group `gi` over its `active` channels (two-sided, per channel).
    fn cusum_test(&mut self, gi: usize, t: usize, tick: u64, active: &[usize]) {
        let test = &self.tests[gi];
        let dim = test.dim;
        let (k, h) = (self.cusum_drift, self.cusum_threshold);
        let mut worst: Option<(usize, f64)> = None;
        let mut largest = 0.0f64;
        for &j in active {
            let c = test.channels[j];
            let z = self.scratch[j] / test.std[t * dim + j];
            let (up, down) = &mut self.cusum[c];
            *up = (*up + z - k).max(0.0);
            *down = (*down - z - k).max(0.0);
            let s = up.max(*down);
            largest = largest.max(s);
            if s > h && worst.is_none_or(|(_, w)| s > w) {
                worst = Some((j, s));
            }
        }
        self.state.normalised_distance[gi] = Some(largest / h);
        if let Some((j, _)) = worst {
            let channels: Vec<usize> = match self.isolation {
                Isolation::Group => active.iter().map(|&j| test.channels[j]).collect(),
                Isolation::Channel => vec![test.channels[j]],
            };
            for &c in &channels {
                self.cusum[c] = (0.0, 0.0);
            }
            let group = test.group;
            self.raise(tick, group, channels);
        }
    }

    /// The Chebyshev test of group `gi` over its `active` channels: the Mahalanobis distance of
    /// their innovations against sqrt(channels / alpha).
    fn distance_test(&mut self, gi: usize, t: usize, tick: u64, active: &[usize]) {
        let test = &self.tests[gi];
        let dim = test.dim;
        let Some(Some(inv)) = test.inverse.get(t) else {
            return;
        };
        let d2 = if active.len() == dim {
            // r' C^-1 r without a temporary.
            let r = &self.scratch[..dim];
            let mut q = 0.0;
            for b in 0..dim {
                let mut row = 0.0;
                for a in 0..dim {
                    row += inv[(a, b)] * r[a];
                }
                q += row * r[b];
            }
            q
        } else {
            let covariance = &test.covariance[t * dim * dim..(t + 1) * dim * dim];
            match sub_quadratic_form(
                covariance,
                dim,
                active,
                &self.scratch,
                &mut self.factor,
                &mut self.solved,
            ) {
                Some(q) => q,
                None => return,
            }
        };
        let threshold = (active.len() as f64 / self.alpha).sqrt();
        let d = d2.max(0.0).sqrt();
        self.state.normalised_distance[gi] = Some(d / threshold);
        if d > threshold {
            let channels = match self.isolation {
                Isolation::Group => active.iter().map(|&j| test.channels[j]).collect(),
                Isolation::Channel => {
                    let worst = active
                        .iter()
                        .copied()
                        .max_by(|&a, &b| {
                            let na = self.scratch[a].abs() / test.std[t * dim + a];
                            let nb = self.scratch[b].abs() / test.std[t * dim + b];
                            na.total_cmp(&nb)
                        })
                        .unwrap_or(0);
                    vec![test.channels[worst]]
                }
            };
            let group = test.group;
            self.raise(tick, group, channels);
        }
    }

    fn raise(&mut self, tick: u64, group: SensorGroup, channels: Vec<usize>) {
        let index = self.state.alarms.len();
        for &c in &channels {
            self.isolated_by[c] = Some(index);
            self.quiet[c] = 0;
            if let Err(pos) = self.state.isolated.binary_search(&c) {
                self.state.isolated.insert(pos, c);
            }
        }
        if index < MAX_ALARMS {
            self.state.alarms.push(Alarm {
                tick,
                group,
                channels,
                cleared: None,
            });
        } else {
            self.state.dropped_alarms += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::CameraModel;
    use nalgebra::DVector;

    fn layout() -> ChannelLayout {
        ChannelLayout::new(1, CameraModel::Pinhole)
    }

    /// One-joint healthy runs: independent N(0, 1) innovations, 200 runs x 100 ticks.
    fn calibration() -> Calibration {
        calibration_of(200, 100)
    }

    fn calibration_of(n_runs: usize, ticks: usize) -> Calibration {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let layout = layout();
        let runs: Vec<Vec<Vec<Option<f64>>>> = (0..n_runs)
            .map(|_| {
                (0..ticks)
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

    /// The in-place quadratic form over a sub-covariance against nalgebra's Cholesky solve,
    /// and None for a sub-covariance that is not positive definite.
    #[test]
    fn the_sub_covariance_form_matches_a_cholesky_solve() {
        let dim = 4;
        let a = DMatrix::from_fn(dim, dim, |i, j| ((i * 7 + j * 3) % 5) as f64 - 2.0);
        let c = &a * a.transpose() + DMatrix::identity(dim, dim) * 0.5;
        let row_major: Vec<f64> = (0..dim * dim).map(|i| c[(i / dim, i % dim)]).collect();
        let x = [0.3, -1.2, 0.7, 2.0];
        let (mut factor, mut solved) = (vec![0.0; 16], vec![0.0; 4]);
        for active in [vec![0, 1, 2, 3], vec![0, 2, 3], vec![1, 3], vec![2]] {
            let k = active.len();
            let sub = DMatrix::from_fn(k, k, |i, j| c[(active[i], active[j])]);
            let r = DVector::from_fn(k, |i, _| x[active[i]]);
            let reference = sub.cholesky().unwrap().solve(&r).dot(&r);
            let q =
                sub_quadratic_form(&row_major, dim, &active, &x, &mut factor, &mut solved).unwrap();
            assert!(
                (q - reference).abs() <= 1e-12 * reference,
                "{active:?}: {q} vs {reference}"
            );
        }
        let singular = vec![1.0, 1.0, 1.0, 1.0];
        assert!(sub_quadratic_form(&singular, 2, &[0, 1], &x, &mut factor, &mut solved).is_none());
    }

    /// The calibrated per-tick covariance against the generator's, a Monte Carlo check.
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
        assert!(cal.matches(&layout()));
        assert_eq!(cal.degenerate_tick(), None);
    }

    fn latched() -> DetectorConfig {
        DetectorConfig {
            rearm_ticks: 0,
            ..DetectorConfig::default()
        }
    }

    #[test]
    fn an_outlier_fires_and_isolates_its_channel_and_other_groups_still_alarm() {
        let cal = calibration();
        let mut det = Detector::new(&cal, &latched(), &layout());
        // Encoder (channel 0) at 3 sigma: below sqrt(1 / 0.01) = 10.
        let d = det.check(10, &[Some(3.0), Some(0.0), Some(0.0), Some(0.0)]);
        assert!(!d.fired());
        // Camera u (channel 2) at 20 sigma: fires in the camera group, isolates channel 2.
        let d = det
            .check(11, &[Some(0.0), Some(0.0), Some(20.0), Some(0.5)])
            .clone();
        assert_eq!(d.first().map(|a| a.tick), Some(11));
        assert_eq!(d.first().map(|a| a.group), Some(SensorGroup::Camera));
        assert_eq!(d.isolated, vec![2]);
        // The camera's other channel is tested alone; a later alarm in another group is raised.
        let d = det.check(12, &[Some(50.0), Some(0.0), Some(20.0), Some(0.0)]);
        assert_eq!(d.alarms.len(), 2);
        assert_eq!(d.alarms[1].group, SensorGroup::Encoders);
        assert_eq!(d.isolated, vec![0, 2]);
    }

    #[test]
    fn an_isolated_channel_is_readmitted_after_quiet_ticks_and_can_alarm_again() {
        let cal = calibration();
        let config = DetectorConfig {
            rearm_ticks: 5,
            ..DetectorConfig::default()
        };
        let mut det = Detector::new(&cal, &config, &layout());
        det.check(10, &[Some(40.0), Some(0.0), Some(0.0), Some(0.0)]);
        assert_eq!(det.state().isolated, vec![0]);
        for t in 11..15 {
            det.check(t, &[Some(0.5), Some(0.0), Some(0.0), Some(0.0)]);
            assert_eq!(det.state().isolated, vec![0], "tick {t}");
        }
        det.check(15, &[Some(0.5), Some(0.0), Some(0.0), Some(0.0)]);
        assert!(det.state().isolated.is_empty());
        assert_eq!(det.state().alarms[0].cleared, Some(15));
        det.check(20, &[Some(40.0), Some(0.0), Some(0.0), Some(0.0)]);
        assert_eq!(det.state().alarms.len(), 2);
        assert_eq!(det.state().isolated, vec![0]);
    }

    #[test]
    fn missing_readings_neither_raise_nor_clear() {
        let cal = calibration();
        let mut det = Detector::new(&cal, &latched(), &layout());
        let d = det.check(5, &[None, Some(0.0), Some(0.0), Some(0.0)]);
        assert!(!d.fired());
        assert_eq!(d.normalised_distance[0], None);
        let config = DetectorConfig {
            isolation: Isolation::Group,
            ..latched()
        };
        let mut det = Detector::new(&cal, &config, &layout());
        det.check(6, &[Some(0.0), Some(0.0), Some(40.0), Some(0.0)]);
        let d = det.check(7, &[Some(0.0), Some(0.0), None, None]);
        assert_eq!(d.isolated, vec![2, 3], "group isolation, still isolated");
    }

    /// A ramp of 0.01 sigma per tick on the encoder: the per-tick Chebyshev bound (10 sigma at
    /// alpha = 0.01) is crossed only near tick 1000; the CUSUM (k = 1, h = 200) from tick 100 on
    /// sums 0.01 (t - 100) - ... and crosses h at t = 100 + sqrt(2 h / 0.01) = 300.
    #[test]
    fn cusum_finds_a_slow_ramp_long_before_the_chebyshev_bound_and_isolates_it() {
        let cal = calibration_of(40, 1500);
        let first = |test: DetectorTest| {
            let config = DetectorConfig { test, ..latched() };
            let mut det = Detector::new(&cal, &config, &layout());
            for t in 0..1500u64 {
                let z = 0.01 * t as f64;
                let d = det.check(t, &[Some(z), Some(0.0), Some(0.0), Some(0.0)]);
                if let Some(a) = d.first() {
                    return Some((a.tick, a.channels.clone()));
                }
            }
            None
        };
        let (cheb, cheb_channels) = first(DetectorTest::Chebyshev).expect("chebyshev fires");
        let (cusum, cusum_channels) = first(DetectorTest::Cusum).expect("cusum fires");
        assert_eq!(cheb_channels, vec![0]);
        assert_eq!(cusum_channels, vec![0]);
        // The calibrated spread is near 1 (not exactly), so the crossings are near, not at,
        // their nominal ticks.
        assert!((850..1200).contains(&cheb), "chebyshev at {cheb}");
        assert!((250..350).contains(&cusum), "cusum at {cusum}");
    }

    /// Healthy N(0, 1) innovations: 20 000 ticks x 4 channels raise no CUSUM alarm (with k = 1
    /// each tick's expected increment is below -1, so the sums stay near 0).
    #[test]
    fn cusum_is_quiet_on_healthy_innovations() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let cal = calibration();
        let config = DetectorConfig {
            test: DetectorTest::Cusum,
            ..latched()
        };
        let mut det = Detector::new(&cal, &config, &layout());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut largest = 0.0f64;
        for rep in 0..200 {
            for t in 0..100u64 {
                let r: Vec<Option<f64>> = (0..4)
                    .map(|_| Some(StandardNormal.sample(&mut rng)))
                    .collect();
                let d = det.check(t, &r);
                assert!(!d.fired(), "rep {rep} tick {t}");
                largest = largest.max(d.normalised_distance[0].unwrap_or(0.0));
            }
        }
        assert!(largest < 0.1, "largest S / h {largest}");
    }

    #[test]
    fn cusum_settings_are_validated() {
        let bad = DetectorConfig {
            cusum_threshold: 0.0,
            ..DetectorConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().field, "cusum_threshold");
        let bad = DetectorConfig {
            cusum_drift: f64::NAN,
            ..DetectorConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().field, "cusum_drift");
    }
}
