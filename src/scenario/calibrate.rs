//! Detector calibration: healthy runs of the scenario (its faults removed, fixed precisions),
//! their innovations summed per tick (METHOD.md section 6).

use rayon::prelude::*;

use super::runner::{Observer, TickRecord};
use super::{Method, RunSetup, ScenarioError, fingerprint};
use crate::precision::{Calibration, CalibrationAccumulator};
use crate::sensors::ChannelLayout;

/// Seeds of calibration runs start here: far from any table's seeds.
pub const CALIBRATION_SEED_BASE: u64 = 1 << 40;

struct InnovationSums<'a>(&'a mut CalibrationAccumulator);

impl Observer for InnovationSums<'_> {
    fn on_tick(&mut self, r: &TickRecord<'_>) {
        self.0.add(r.tick as usize, r.innovations);
    }
}

/// Runs `runs` healthy seeds (in parallel, reduced in seed order: the result does not depend on
/// the thread count) and returns the per-tick innovation statistics.
pub fn calibrate(setup: &RunSetup, runs: usize) -> Result<Calibration, ScenarioError> {
    let mut healthy = setup.clone();
    healthy.faults.clear();
    healthy.loaded.scenario.faults.clear();
    let sc = setup.scenario();
    let layout = ChannelLayout::new(setup.model.joints.len());
    let ticks = sc.ticks() as usize;
    let parts: Vec<Result<CalibrationAccumulator, ScenarioError>> = (0..runs as u64)
        .into_par_iter()
        .map(|i| {
            let mut acc = CalibrationAccumulator::new(layout, ticks);
            let result = super::run(
                &healthy,
                Method::NoFt,
                CALIBRATION_SEED_BASE + i,
                None,
                &mut InnovationSums(&mut acc),
            )?;
            if result.ticks_run < ticks as u64 {
                return Err(ScenarioError::Calibration {
                    path: setup.loaded.path.clone(),
                    message: format!(
                        "healthy calibration run {i} diverged at tick {}; the scenario does not run healthy",
                        result.ticks_run
                    ),
                });
            }
            acc.end_run();
            Ok(acc)
        })
        .collect();
    let mut total = CalibrationAccumulator::new(layout, ticks);
    for part in parts {
        total.merge(&part?);
    }
    Ok(total.finish(sc.dt, sc.detector.pool_ticks, fingerprint(sc)))
}

/// Loads a calibration file and checks it belongs to this scenario (exit 2 otherwise).
pub fn load_calibration(
    setup: &RunSetup,
    path: &std::path::Path,
) -> Result<Calibration, ScenarioError> {
    let err = |message: String| ScenarioError::Calibration {
        path: path.to_path_buf(),
        message,
    };
    let text = std::fs::read_to_string(path)
        .map_err(|e| err(format!("cannot read the calibration: {e}")))?;
    let cal = Calibration::from_json(&text).map_err(|m| err(format!("not a calibration: {m}")))?;
    let expected = fingerprint(setup.scenario());
    if cal.fingerprint != expected {
        return Err(err(format!(
            "made for another scenario schedule (fingerprint {} here {}); recalibrate with `aift calibrate`",
            cal.fingerprint, expected
        )));
    }
    let layout = ChannelLayout::new(setup.model.joints.len());
    if cal.groups.iter().map(|g| g.channels.len()).sum::<usize>() != layout.len() {
        return Err(err("made for an arm with another number of joints".into()));
    }
    Ok(cal)
}
