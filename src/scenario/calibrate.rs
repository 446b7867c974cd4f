//! Detector calibration: healthy runs of the scenario (its faults removed, fixed precisions),
//! their innovations summed per tick (METHOD.md section 6).

use rayon::prelude::*;

use super::runner::{Observer, TickRecord};
use super::{Method, RunSetup, ScenarioError, fingerprint};
use crate::precision::{Calibration, CalibrationAccumulator};
use crate::sensors::{ChannelLayout, SensorGroup};

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
    Ok(total.finish(sc.dt, sc.detector.pool_ticks, fingerprint(setup)))
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
    check_calibration(setup, &cal).map_err(err)?;
    Ok(cal)
}

/// Whether a calibration belongs to this scenario (fingerprint) and this arm (channel layout).
fn check_calibration(setup: &RunSetup, cal: &Calibration) -> Result<(), String> {
    let expected = fingerprint(setup);
    if cal.fingerprint != expected {
        return Err(format!(
            "made for another scenario schedule, arm or camera model (fingerprint {} here {}); recalibrate with `aift calibrate`",
            cal.fingerprint, expected
        ));
    }
    let layout = ChannelLayout::new(setup.model.joints.len());
    let expected_groups: Vec<(&str, Vec<usize>)> = SensorGroup::ALL
        .iter()
        .map(|&g| (g.name(), layout.group_range(g).collect()))
        .collect();
    let groups_match = cal.groups.len() == expected_groups.len()
        && cal
            .groups
            .iter()
            .zip(&expected_groups)
            .all(|(g, (name, channels))| g.group == *name && &g.channels == channels);
    if !groups_match {
        return Err("its sensor groups do not match this arm's channels".into());
    }
    if cal.ticks < setup.scenario().ticks() as usize {
        return Err(format!(
            "it covers {} ticks, the scenario has {}",
            cal.ticks,
            setup.scenario().ticks()
        ));
    }
    Ok(())
}

/// The calibration of `runs` healthy runs, from `cache_dir` when a valid one is there, else
/// computed and stored there (best effort). Returns whether it came from the cache. Calibration
/// is deterministic, so a cached file equals a fresh one bit for bit.
pub fn cached_calibration(
    setup: &RunSetup,
    runs: usize,
    cache_dir: Option<&std::path::Path>,
) -> Result<(Calibration, bool), ScenarioError> {
    let file = cache_dir.map(|dir| {
        dir.join(format!(
            "calibration-{}-{}runs-pool{}.json",
            fingerprint(setup),
            runs,
            setup.scenario().detector.pool_ticks
        ))
    });
    if let Some(file) = &file
        && let Ok(text) = std::fs::read_to_string(file)
        && let Ok(cal) = Calibration::from_json(&text)
        && cal.runs == runs
        && check_calibration(setup, &cal).is_ok()
    {
        return Ok((cal, true));
    }
    let cal = calibrate(setup, runs)?;
    if let Some(file) = &file
        && let Some(dir) = file.parent()
        && std::fs::create_dir_all(dir).is_ok()
    {
        let _ = crate::report::write_atomic(file, cal.to_json().as_bytes());
    }
    Ok((cal, false))
}
