//! Precision methods built from others: detector-driven methods, the oracle, and one method
//! per sensor group.

use super::{Detection, Detector, PrecisionInput, PrecisionMethod};
use crate::sensors::SensorGroup;

/// `deterministic`: nominal precisions, except that a channel the detector isolates gets
/// precision 0 until the detector re-admits it (the ECC baseline; docs/method.md, "The
/// detector").
pub struct Deterministic {
    detector: Detector,
    nominal: Vec<f64>,
    omega: Vec<f64>,
}

impl Deterministic {
    pub fn new(detector: Detector, nominal: &[f64]) -> Self {
        Self {
            detector,
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
        }
    }
}

impl PrecisionMethod for Deterministic {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
        let d = self.detector.check(input.tick, &input.estimate.innovations);
        self.omega.copy_from_slice(&self.nominal);
        for &c in &d.isolated {
            self.omega[c] = 0.0;
        }
    }
    fn detection(&self) -> Option<&Detection> {
        Some(self.detector.state())
    }
}

/// `pl-detect`: a learner that starts learning once the detector has raised its first alarm
/// (the seed paper's "PL + FD").
pub struct GatedLearning {
    detector: Detector,
    learner: Box<dyn PrecisionMethod>,
}

impl GatedLearning {
    pub fn new(detector: Detector, learner: Box<dyn PrecisionMethod>) -> Self {
        Self { detector, learner }
    }
}

impl PrecisionMethod for GatedLearning {
    fn precisions(&self) -> &[f64] {
        self.learner.precisions()
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
        let fired = self
            .detector
            .check(input.tick, &input.estimate.innovations)
            .fired();
        if fired {
            self.learner.update(input);
        }
    }
    fn detection(&self) -> Option<&Detection> {
        Some(self.detector.state())
    }
}

/// `oracle`: told each fault's channels and window, gives those channels precision 0 exactly
/// while their fault acts and nominal precision otherwise. Not a method a user could run: the
/// reference every method is measured against.
pub struct Oracle {
    nominal: Vec<f64>,
    omega: Vec<f64>,
    /// (channels, first tick, first tick after) per fault.
    windows: Vec<(Vec<usize>, u64, Option<u64>)>,
}

impl Oracle {
    pub fn new(nominal: &[f64], windows: Vec<(Vec<usize>, u64, Option<u64>)>) -> Self {
        Self {
            nominal: nominal.to_vec(),
            omega: nominal.to_vec(),
            windows,
        }
    }
}

impl PrecisionMethod for Oracle {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
        // Called after tick k: the precisions it leaves are used at tick k + 1.
        let next = input.tick + 1;
        self.omega.copy_from_slice(&self.nominal);
        for (channels, start, end) in &self.windows {
            if next >= *start && end.is_none_or(|e| next < e) {
                for &c in channels {
                    self.omega[c] = 0.0;
                }
            }
        }
    }
}

/// One method per sensor group: channel c's precision is that of the method given its group.
/// Every method sees every tick in full.
pub struct PerGroup {
    parts: Vec<(Vec<SensorGroup>, Box<dyn PrecisionMethod>)>,
    /// Which part serves each channel.
    owner: Vec<usize>,
    omega: Vec<f64>,
}

impl PerGroup {
    /// `parts` must cover every group of `layout` exactly once.
    ///
    /// # Panics
    /// If a group of the layout has no part.
    pub fn new(
        layout: &crate::sensors::ChannelLayout,
        parts: Vec<(Vec<SensorGroup>, Box<dyn PrecisionMethod>)>,
    ) -> Self {
        let owner: Vec<usize> = (0..layout.len())
            .map(|c| {
                let g = layout.group_of(c);
                parts
                    .iter()
                    .position(|(groups, _)| groups.contains(&g))
                    .expect("every group has a method")
            })
            .collect();
        let omega = (0..layout.len())
            .map(|c| parts[owner[c]].1.precisions()[c])
            .collect();
        Self {
            parts,
            owner,
            omega,
        }
    }
}

impl PrecisionMethod for PerGroup {
    fn precisions(&self) -> &[f64] {
        &self.omega
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
        for (_, part) in &mut self.parts {
            part.update(input);
        }
        for (c, w) in self.omega.iter_mut().enumerate() {
            *w = self.parts[self.owner[c]].1.precisions()[c];
        }
    }
    fn detection(&self) -> Option<&Detection> {
        self.parts.iter().find_map(|(_, p)| p.detection())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::precision::testing::{feed, layout};
    use crate::precision::{Calibration, DetectorConfig, Fixed, Gradient, PrecisionBounds};

    fn quiet_calibration() -> Calibration {
        let l = layout();
        let runs: Vec<Vec<Vec<Option<f64>>>> = (0..50)
            .map(|r| {
                (0..50)
                    .map(|t| {
                        (0..l.len())
                            .map(|c| Some(((r * 7 + t * 3 + c) % 5) as f64 - 2.0))
                            .collect()
                    })
                    .collect()
            })
            .collect();
        Calibration::from_runs(l, &runs, 1e-3, 2, "t".into())
    }

    #[test]
    fn the_oracle_follows_each_faults_window() {
        let mut oracle = Oracle::new(&[1.0; 4], vec![(vec![1], 5, Some(8)), (vec![2], 6, None)]);
        let mut seen = Vec::new();
        for tick in 0..10 {
            feed(&mut oracle, tick, &[None; 4], &[0.0; 4], &[None; 4]);
            seen.push(oracle.precisions().to_vec());
        }
        // After tick 3 the precisions for tick 4: nominal; for tick 5: channel 1 off.
        assert_eq!(seen[3], vec![1.0; 4]);
        assert_eq!(seen[4], vec![1.0, 0.0, 1.0, 1.0]);
        assert_eq!(seen[5], vec![1.0, 0.0, 0.0, 1.0]);
        // Channel 1's fault ends at tick 8: its precision is back for tick 8.
        assert_eq!(seen[7], vec![1.0, 1.0, 0.0, 1.0]);
        assert_eq!(seen[9], vec![1.0, 1.0, 0.0, 1.0]);
    }

    #[test]
    fn deterministic_zeroes_isolated_channels_and_restores_them() {
        let cal = quiet_calibration();
        let config = DetectorConfig {
            rearm_ticks: 3,
            ..DetectorConfig::default()
        };
        let det = Detector::new(&cal, &config, &layout());
        let mut m = Deterministic::new(det, &[1.0; 4]);
        let calm = [Some(0.0); 4];
        feed(&mut m, 10, &[None; 4], &[0.0; 4], &calm);
        assert_eq!(m.precisions(), &[1.0; 4]);
        feed(
            &mut m,
            11,
            &[None; 4],
            &[0.0; 4],
            &[Some(100.0), Some(0.0), Some(0.0), Some(0.0)],
        );
        assert_eq!(m.precisions(), &[0.0, 1.0, 1.0, 1.0]);
        for t in 12..15 {
            feed(&mut m, t, &[None; 4], &[0.0; 4], &calm);
        }
        assert_eq!(m.precisions(), &[1.0; 4]);
    }

    #[test]
    fn gated_learning_waits_for_the_detector() {
        let cal = quiet_calibration();
        let det = Detector::new(&cal, &DetectorConfig::default(), &layout());
        let learner = Gradient::new(&[1.0; 4], 10.0, false, PrecisionBounds::default());
        let mut m = GatedLearning::new(det, Box::new(learner));
        let big = [Some(10.0), None, None, None];
        feed(&mut m, 10, &big, &[0.0; 4], &[Some(0.0); 4]);
        assert_eq!(m.precisions()[0], 1.0);
        feed(
            &mut m,
            11,
            &big,
            &[0.0; 4],
            &[Some(100.0), Some(0.0), Some(0.0), Some(0.0)],
        );
        assert!(m.precisions()[0] < 1.0);
    }

    #[test]
    fn per_group_takes_each_channel_from_its_groups_method() {
        let l = layout();
        let learner = Gradient::new(&[1.0; 4], 10.0, false, PrecisionBounds::default());
        let mut m = PerGroup::new(
            &l,
            vec![
                (
                    vec![SensorGroup::Encoders, SensorGroup::Tachometers],
                    Box::new(Fixed::new(&[1.0; 4])),
                ),
                (vec![SensorGroup::Camera], Box::new(learner)),
            ],
        );
        feed(&mut m, 0, &[Some(10.0); 4], &[0.0; 4], &[None; 4]);
        let w = m.precisions();
        assert_eq!(&w[..2], &[1.0, 1.0]);
        assert!(w[2] < 1.0 && w[3] < 1.0);
    }
}
