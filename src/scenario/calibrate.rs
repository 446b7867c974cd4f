//! Detector calibration: healthy runs of the scenario (its faults removed, fixed precisions),
//! their innovations summed per tick (docs/method.md, "The detector").

use rayon::prelude::*;

use super::runner::{Observer, TickRecord};
use super::{Method, RunSetup, ScenarioError, fingerprint};
use crate::fsio;
use crate::precision::detector::calibration_size;
use crate::precision::{Calibration, CalibrationAccumulator};

/// Largest calibration, in stored numbers (per-tick means and covariances of every group):
/// 1e8, 0.8 GB.
pub const MAX_CALIBRATION_VALUES: usize = 100_000_000;

/// Seeds of calibration runs start here: far from any table's seeds.
pub const CALIBRATION_SEED_BASE: u64 = 1 << 40;

struct InnovationSums<'a>(&'a mut CalibrationAccumulator);

impl Observer for InnovationSums<'_> {
    fn iter(&mut self, r: &TickRecord<'_>) {
        self.0.add(r.tick as usize, &r.estimate.innovations);
    }
}

/// Runs `runs` healthy seeds (in parallel, reduced in seed order: the result does not depend on
/// the thread count) and returns the per-tick innovation statistics.
pub fn calibrate(setup: &RunSetup, runs: usize) -> Result<Calibration, ScenarioError> {
    let mut healthy = setup.healthy();
    // The detector's statistics do not need the momentum observer.
    healthy.loaded.scenario.momentum.enabled = false;
    let sc = setup.scenario();
    let layout = setup.layout;
    let ticks = sc.ticks() as usize;
    check_size(setup, runs)?;
    let parts: Vec<Result<CalibrationAccumulator, ScenarioError>> = (0..runs as u64)
        .into_par_iter()
        .map(|i| {
            let mut acc = CalibrationAccumulator::new(layout, ticks);
            let mut sums = InnovationSums(&mut acc);
            let result = super::runner::Run::new(&healthy, Method::NoFt)
                .seed(CALIBRATION_SEED_BASE + i)
                .observe(&mut sums, super::runner::ObserverMode::Always)
                .execute()?;
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
    let cal = total.finish(sc.dt, sc.detector.pool_ticks, fingerprint(setup));
    if let Some((tick, group)) = cal.degenerate_tick() {
        return Err(ScenarioError::Calibration {
            path: setup.loaded.path.clone(),
            message: format!(
                "the healthy {group} innovations at tick {tick} have a covariance that is not \
                 positive definite (a noise-free sensor?); the detector cannot test them"
            ),
        });
    }
    Ok(cal)
}

/// Refuses a calibration too large to hold (checked before any run).
pub fn check_size(setup: &RunSetup, runs: usize) -> Result<(), ScenarioError> {
    let values = calibration_size(&setup.layout, setup.scenario().ticks() as usize);
    if values > MAX_CALIBRATION_VALUES {
        return Err(ScenarioError::Invalid {
            path: setup.loaded.path.clone(),
            field: "duration".into(),
            message: format!(
                "a detector calibration of {} ticks would hold {values} numbers; at most \
                 {MAX_CALIBRATION_VALUES} (shorten the run or use a method without a detector)",
                setup.scenario().ticks()
            ),
        });
    }
    if !(2..=crate::precision::detector::MAX_CALIBRATION_RUNS).contains(&runs) {
        return Err(ScenarioError::Invalid {
            path: setup.loaded.path.clone(),
            field: "detector.calibration_runs".into(),
            message: format!(
                "{runs} runs; must be in 2..={}",
                crate::precision::detector::MAX_CALIBRATION_RUNS
            ),
        });
    }
    Ok(())
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
    let text = fsio::read_text(path, fsio::MAX_CALIBRATION_BYTES)
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
    if !cal.matches(&setup.layout) {
        return Err("its sensor groups do not match this arm's channels".into());
    }
    if let Some((tick, group)) = cal.degenerate_tick() {
        return Err(format!(
            "its {group} covariance at tick {tick} is not positive definite; the detector \
             could not test there (recalibrate with more runs)"
        ));
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
            "calibration-{}-{}-{}runs-pool{}.json",
            fingerprint(setup),
            crate::fsio::SOURCE_DIGEST,
            runs,
            setup.scenario().detector.pool_ticks
        ))
    });
    if let Some(file) = &file
        && let Ok(text) = fsio::read_text(file, fsio::MAX_CALIBRATION_BYTES)
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
        let _ = fsio::write_atomic(file, cal.to_json().as_bytes());
    }
    Ok((cal, false))
}

/// Where a detector calibration came from (for the messages of the CLI and Python).
#[derive(Clone, Debug, PartialEq)]
pub enum CalibrationOrigin {
    /// A file given by the caller or named by the scenario.
    File(std::path::PathBuf),
    /// Read from the cache folder.
    Cached(std::path::PathBuf),
    /// Computed now (and stored in the cache folder, when there is one).
    Computed { seconds: f64 },
}

/// The calibration the methods need, if any of them runs a detector: the file `explicit`, else
/// the scenario's `detector.calibration`, else `detector.calibration_runs` healthy runs computed
/// on the fly (through the cache in `cache_dir`). Every path to it gives the same bits.
pub fn calibration_for(
    setup: &RunSetup,
    methods: &[Method],
    explicit: Option<&std::path::Path>,
    cache_dir: Option<&std::path::Path>,
) -> Result<Option<(Calibration, CalibrationOrigin)>, ScenarioError> {
    if !methods.iter().any(|m| m.needs_detector()) {
        return Ok(None);
    }
    let path = explicit.map(std::path::Path::to_path_buf).or_else(|| {
        setup
            .scenario()
            .detector
            .calibration
            .as_ref()
            .map(|rel| setup.loaded.resolve(rel))
    });
    if let Some(path) = path {
        // A file the scenario names: the error names the scenario and its key as well.
        let cal = load_calibration(setup, &path).map_err(|e| match explicit {
            Some(_) => e,
            None => ScenarioError::Invalid {
                path: setup.loaded.path.clone(),
                field: "detector.calibration".into(),
                message: e.to_string(),
            },
        })?;
        return Ok(Some((cal, CalibrationOrigin::File(path))));
    }
    let runs = setup.scenario().detector.calibration_runs;
    let start = std::time::Instant::now();
    let (cal, cached) = cached_calibration(setup, runs, cache_dir)?;
    let origin = match (cached, cache_dir) {
        (true, Some(dir)) => CalibrationOrigin::Cached(dir.to_path_buf()),
        _ => CalibrationOrigin::Computed {
            seconds: start.elapsed().as_secs_f64(),
        },
    };
    Ok(Some((cal, origin)))
}

/// Where on-the-fly calibrations are cached: `$AIFT_CACHE_DIR` (`off` disables the cache),
/// else `$XDG_CACHE_HOME/aift`, else `$HOME/.cache/aift`. Only absolute paths count (the XDG
/// rule): an empty or relative value is skipped, so that no cache lands in the working folder;
/// with none left there is no cache.
pub fn default_cache_dir() -> Option<std::path::PathBuf> {
    cache_dir_from(|k| std::env::var_os(k))
}

fn cache_dir_from(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Option<std::path::PathBuf> {
    use std::path::PathBuf;
    let absolute = |k: &str| var(k).map(PathBuf::from).filter(|p| p.is_absolute());
    if var("AIFT_CACHE_DIR").is_some_and(|v| v == "off") {
        return None;
    }
    absolute("AIFT_CACHE_DIR")
        .or_else(|| absolute("XDG_CACHE_HOME").map(|d| d.join("aift")))
        .or_else(|| absolute("HOME").map(|h| h.join(".cache").join("aift")))
}

/// Seeds of the momentum observer's calibration runs start here (apart from the detector's).
pub const MOMENTUM_SEED_BASE: u64 = 1 << 41;

/// Smallest momentum threshold (N m): a noise-free run on the plant's own model shows residuals
/// of rounding size only.
pub const MOMENTUM_THRESHOLD_FLOOR: f64 = 1e-6;

/// The momentum observer's thresholds per joint: `[momentum] margin` x the largest |r_j| over
/// `calibration_runs` healthy runs (`no-ft`, the scenario without faults, each run's seed
/// drawing its own model error), at least [`MOMENTUM_THRESHOLD_FLOOR`]. In parallel, reduced
/// in seed order.
pub fn calibrate_momentum(setup: &RunSetup) -> Result<Vec<f64>, ScenarioError> {
    let mut healthy = setup.healthy();
    healthy.momentum_thresholds = None;
    let config = &setup.scenario().momentum;
    let ticks = setup.scenario().ticks();
    let runs: Vec<Result<Vec<f64>, ScenarioError>> = (0..config.calibration_runs as u64)
        .into_par_iter()
        .map(|i| {
            let result = super::runner::Run::new(&healthy, Method::NoFt)
                .seed(MOMENTUM_SEED_BASE + i)
                .execute()?;
            if result.ticks_run < ticks {
                return Err(ScenarioError::Calibration {
                    path: setup.loaded.path.clone(),
                    message: format!(
                        "healthy momentum calibration run {i} ended at tick {}; the scenario \
                         does not run healthy",
                        result.ticks_run
                    ),
                });
            }
            Ok(result
                .momentum
                .expect("the observer runs when enabled")
                .largest)
        })
        .collect();
    let n = setup.model.joints.len();
    let mut largest = vec![0.0f64; n];
    for run in runs {
        for (l, v) in largest.iter_mut().zip(run?) {
            *l = l.max(v);
        }
    }
    if let Some(j) = largest.iter().position(|v| !v.is_finite()) {
        return Err(ScenarioError::Calibration {
            path: setup.loaded.path.clone(),
            message: format!(
                "the healthy momentum residual of joint {} is not finite: the estimators' model \
                 cannot explain this arm's motion",
                j + 1
            ),
        });
    }
    Ok(largest
        .iter()
        .map(|l| (config.margin * l).max(MOMENTUM_THRESHOLD_FLOOR))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::cache_dir_from;
    use std::path::PathBuf;

    fn with(pairs: &[(&str, &str)]) -> Option<PathBuf> {
        cache_dir_from(|k| {
            pairs
                .iter()
                .find(|(n, _)| *n == k)
                .map(|(_, v)| std::ffi::OsString::from(v))
        })
    }

    #[test]
    fn the_cache_is_never_relative_to_the_working_folder() {
        assert_eq!(with(&[("AIFT_CACHE_DIR", "/c")]), Some(PathBuf::from("/c")));
        assert_eq!(with(&[("AIFT_CACHE_DIR", "off"), ("HOME", "/h")]), None);
        // Empty or relative values are skipped, down to none at all.
        let home = Some(PathBuf::from("/h/.cache/aift"));
        assert_eq!(with(&[("AIFT_CACHE_DIR", ""), ("HOME", "/h")]), home);
        assert_eq!(with(&[("XDG_CACHE_HOME", "rel"), ("HOME", "/h")]), home);
        assert_eq!(with(&[("XDG_CACHE_HOME", ""), ("HOME", "/h")]), home);
        assert_eq!(
            with(&[("XDG_CACHE_HOME", "/x"), ("HOME", "/h")]),
            Some(PathBuf::from("/x/aift"))
        );
        assert_eq!(with(&[("HOME", "")]), None);
        assert_eq!(with(&[("HOME", "h")]), None);
        assert_eq!(with(&[]), None);
    }
}
