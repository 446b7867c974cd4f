//! The fault-tolerance methods: their names (used everywhere: CLI, files, tables), what each is,
//! and how each is built from a scenario. A method is an estimator (the belief source) and a
//! precision method (what sets each channel's precision); every method drives the same f*.
//!
//! Adding a method: a variant here with its [`Method::info`] entry, its construction in
//! [`build`], and its settings (if any) in the scenario's `[precision]` section.

use std::fmt;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::{RunSetup, ScenarioError};
use crate::estimation::Estimator;
use crate::estimation::imm::Imm;
use crate::estimation::kalman::{Ekf, EkfGate, VbAkf, transition_model};
use crate::estimation::models::GpCamera;
use crate::estimation::uaic::Uaic;
use crate::precision::{
    Bayes, Calibration, Detector, Deterministic, Fixed, GatedLearning, Gradient, Oracle, PerGroup,
    PrecisionMethod, Window,
};
use crate::sensors::{ChannelLayout, SensorGroup};

/// A fault-tolerance method.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Hash,
    Serialize,
    Deserialize,
    PartialOrd,
    Ord,
    schemars::JsonSchema,
)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Fixed nominal precisions: no fault tolerance.
    NoFt,
    /// The paper's gradient precision learning at all times.
    PlAlways,
    /// Gradient precision learning once the detector fires (the paper's "PL + FD").
    PlDetect,
    /// The detector fires and the isolated channel's precision goes to 0 (ECC).
    Deterministic,
    /// Gamma posterior precision with forgetting (the paper's future work).
    Bayes,
    /// Precision from the last k residuals (the paper's future work).
    Window,
    /// Told each fault's channels and window: the reference, not a usable method.
    Oracle,
    /// Extended Kalman filter with chi-square gating, exclusion and re-admission per channel.
    EkfGate,
    /// The variational-Bayes adaptive Kalman filter (Sarkka and Nummenmaa 2009).
    VbAkf,
    /// Interacting multiple models: one hypothesis per channel failing, and the nominal one.
    Imm,
    /// Active inference at every fault site: the u-AIC's belief, every sensor's precision from a
    /// bank of failure hypotheses, the belief re-anchored on a winner that drops a channel.
    Hybrid,
}

/// What a method is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MethodInfo {
    pub name: &'static str,
    /// One line for help texts and reports.
    pub summary: &'static str,
    /// Whether it needs the calibrated detector.
    pub needs_detector: bool,
    /// The seed paper's Table 1 row (faulty joint, healthy joint MSE), if it has one.
    pub paper_table1: Option<(f64, f64)>,
}

impl Method {
    /// Every method, in table order.
    pub const ALL: [Method; 11] = [
        Method::NoFt,
        Method::PlAlways,
        Method::PlDetect,
        Method::Deterministic,
        Method::Bayes,
        Method::Window,
        Method::Hybrid,
        Method::EkfGate,
        Method::VbAkf,
        Method::Imm,
        Method::Oracle,
    ];

    pub fn info(self) -> MethodInfo {
        let (name, summary, needs_detector, paper_table1) = match self {
            Self::NoFt => (
                "no-ft",
                "u-AIC, fixed nominal precisions (no fault tolerance)",
                false,
                Some((0.0036, 0.0020)),
            ),
            Self::PlAlways => (
                "pl-always",
                "u-AIC, the paper's gradient precision learning at all times",
                false,
                Some((5.422e-5, 4.527e-5)),
            ),
            Self::PlDetect => (
                "pl-detect",
                "u-AIC, gradient precision learning once the detector fires (PL + FD)",
                true,
                Some((6.097e-5, 4.134e-5)),
            ),
            Self::Deterministic => (
                "deterministic",
                "u-AIC, the detector's isolated channel set to precision 0 (ECC)",
                true,
                Some((0.5946e-5, 0.3579e-5)),
            ),
            Self::Bayes => (
                "bayes",
                "u-AIC, Gamma-posterior precision with forgetting",
                false,
                None,
            ),
            Self::Window => (
                "window",
                "u-AIC, precision from the last k residuals",
                false,
                None,
            ),
            Self::Oracle => (
                "oracle",
                "u-AIC told each fault's channels and window (the reference)",
                false,
                None,
            ),
            Self::EkfGate => (
                "ekf-gate",
                "extended Kalman filter, chi-square gating with exclusion and re-admission",
                false,
                None,
            ),
            Self::VbAkf => (
                "vb-akf",
                "variational-Bayes adaptive Kalman filter (Sarkka and Nummenmaa 2009)",
                false,
                None,
            ),
            Self::Imm => (
                "imm",
                "interacting multiple models, a hypothesis per failing channel",
                false,
                None,
            ),
            Self::Hybrid => (
                "hybrid",
                "u-AIC; precisions of encoders, tachometers and camera from a bank of failure hypotheses; re-anchored belief",
                false,
                None,
            ),
        };
        MethodInfo {
            name,
            summary,
            needs_detector,
            paper_table1,
        }
    }

    pub fn name(self) -> &'static str {
        self.info().name
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the method needs the calibrated detector.
    pub fn needs_detector(self) -> bool {
        self.info().needs_detector
    }

    /// The seed paper's Table 1 row for this method (faulty joint, healthy joint MSE), if any.
    pub fn paper_table1(self) -> Option<(f64, f64)> {
        self.info().paper_table1
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s).ok_or_else(|| {
            format!(
                "unknown method {s:?} (methods: {})",
                Self::ALL.map(Method::name).join(", ")
            )
        })
    }
}

/// Which method a campaign run (or table row) belongs to: a built-in [`Method`], or one the
/// caller supplied (a Python class, a Rust [`ExternalMethod`]) known by its name. Written in
/// files as the name alone; a name that is no built-in method's reads back as external.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MethodId {
    Builtin(Method),
    External(String),
}

impl MethodId {
    pub fn name(&self) -> &str {
        match self {
            Self::Builtin(m) => m.name(),
            Self::External(name) => name,
        }
    }

    /// The built-in method (None for an external one).
    pub fn builtin(&self) -> Option<Method> {
        match self {
            Self::Builtin(m) => Some(*m),
            Self::External(_) => None,
        }
    }

    /// Whether the method needs the calibrated detector (external methods bring their own).
    pub fn needs_detector(&self) -> bool {
        self.builtin().is_some_and(Method::needs_detector)
    }

    /// The built-in method of that name, else an external one.
    pub fn from_name(name: &str) -> Self {
        Method::parse(name).map_or_else(|| Self::External(name.to_string()), Self::Builtin)
    }
}

impl From<Method> for MethodId {
    fn from(m: Method) -> Self {
        Self::Builtin(m)
    }
}

impl PartialEq<Method> for MethodId {
    fn eq(&self, other: &Method) -> bool {
        *self == Self::Builtin(*other)
    }
}

impl fmt::Display for MethodId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for MethodId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for MethodId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        if let Some(m) = Method::parse(&name) {
            return Ok(Self::Builtin(m));
        }
        check_external_name(&name).map_err(serde::de::Error::custom)?;
        Ok(Self::External(name))
    }
}

/// Longest name of a method the caller supplies.
pub const MAX_EXTERNAL_NAME: usize = 64;

/// Whether `name` can name a method the caller supplies: 1 to 64 characters, letters, digits,
/// `-`, `_`, `.` (it becomes a column, a key and a label), and no built-in method's name.
pub fn check_external_name(name: &str) -> Result<(), String> {
    if Method::parse(name).is_some() {
        return Err(format!(
            "{name:?} is a built-in method's name: give the method another"
        ));
    }
    if name.is_empty() || name.chars().count() > MAX_EXTERNAL_NAME {
        return Err(format!(
            "method name {name:?} must have 1 to {MAX_EXTERNAL_NAME} characters"
        ));
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_alphanumeric() || matches!(c, '-' | '_' | '.')))
    {
        return Err(format!(
            "method name {name:?} has {c:?}: use letters, digits, '-', '_' or '.'"
        ));
    }
    Ok(())
}

/// A method of the caller's (defined outside the library), run beside the built-in ones by
/// [`crate::scenario::table::run_table_with`] and
/// [`crate::scenario::campaign::run_campaign_with`]: `build(setup, seed, place)` makes its parts
/// for one run (a fresh estimator and precision method each time); `place` says where the run
/// is, for messages (a campaign's arm and cell, `""` in a table).
pub struct ExternalMethod<'a> {
    pub name: String,
    pub build: &'a (dyn Fn(&RunSetup, u64, &str) -> Result<MethodParts, ScenarioError> + Sync),
    /// Whether one of its runs failed in a way the parts cannot return (a Python exception in
    /// `step`: the run goes on to its end with non-finite updates). A campaign asks before each
    /// job and before journaling each run: once true, no run is journaled or started and the
    /// campaign returns an error (so that a resumed campaign never keeps a failed run).
    pub failed: Option<&'a (dyn Fn() -> bool + Sync)>,
}

impl<'a> ExternalMethod<'a> {
    /// A method whose runs fail only by `build`'s errors.
    pub fn new(
        name: impl Into<String>,
        build: &'a (dyn Fn(&RunSetup, u64, &str) -> Result<MethodParts, ScenarioError> + Sync),
    ) -> Self {
        Self {
            name: name.into(),
            build,
            failed: None,
        }
    }

    fn has_failed(&self) -> bool {
        self.failed.is_some_and(|f| f())
    }
}

/// Whether one of `external`'s runs failed (see [`ExternalMethod::failed`]); its name.
pub fn failed_external<'e>(external: &'e [ExternalMethod<'_>]) -> Option<&'e str> {
    external
        .iter()
        .find(|e| e.has_failed())
        .map(|e| e.name.as_str())
}

/// What building a method needs.
pub struct MethodContext<'a> {
    pub setup: &'a RunSetup,
    /// The estimators' arm model for this run (the plant's with the scenario's model error).
    pub model: Arc<crate::arm::ArmModel>,
    pub layout: &'a ChannelLayout,
    /// Nominal precision per channel.
    pub nominal: &'a [f64],
    /// The detector's calibration (methods with a detector).
    pub calibration: Option<&'a Calibration>,
}

/// A method's parts.
pub type MethodParts = (Box<dyn Estimator>, Box<dyn PrecisionMethod>);

/// Builds `method` for a run.
pub fn build(method: Method, ctx: &MethodContext<'_>) -> Result<MethodParts, ScenarioError> {
    let sc = ctx.setup.scenario();
    let p = &sc.precision;
    let nominal = ctx.nominal;
    ctx.setup.check_method(method)?;
    let bounds = p.bounds();
    let observation = GpCamera::shared(*ctx.layout, ctx.setup.gp.clone());
    let uaic = || -> Box<dyn Estimator> {
        Box::new(Uaic::new(sc.belief.clone(), observation.clone(), sc.dt))
    };
    let gradient = || Gradient::new(nominal, p.kappa_zeta, p.correction, bounds);
    let kc = &sc.kalman;
    let ekf = || Ekf::new(observation.clone(), sc.dt);
    let fixed = || -> Box<dyn PrecisionMethod> { Box::new(Fixed::new(nominal)) };
    let acceleration_noise = kc
        .acceleration_noise
        .unwrap_or(sc.belief.acceleration_bound);
    let model = &ctx.model;
    let process = || {
        transition_model(
            kc.process_model,
            model.clone(),
            sc.robot.gravity,
            &sc.model,
            acceleration_noise,
            sc.dt,
        )
    };
    match method {
        Method::EkfGate => {
            return Ok((
                Box::new(EkfGate::new(ekf(), kc.clone(), process())),
                fixed(),
            ));
        }
        Method::VbAkf => {
            return Ok((
                Box::new(VbAkf::new(ekf(), kc, process(), nominal, bounds.min_ratio)),
                fixed(),
            ));
        }
        Method::Imm => {
            return Ok((Box::new(Imm::new(ekf(), kc, process(), nominal)), fixed()));
        }
        Method::Hybrid => {
            let mut belief = sc.belief.clone();
            belief.prior = Some(sc.hybrid.prior_mode(sc.belief.update).initial());
            let uaic = Uaic::new(belief, observation.clone(), sc.dt);
            let transition = crate::estimation::hybrid::bank_transition(
                &sc.hybrid,
                model.clone(),
                sc.robot.gravity,
                &sc.model,
                sc.belief.acceleration_bound,
                sc.dt,
            );
            let hybrid = crate::estimation::hybrid::build(
                uaic,
                observation.clone(),
                sc.dt,
                transition,
                &sc.hybrid,
                nominal,
                bounds.min_ratio,
            );
            let camera = PerGroup::new(
                ctx.layout,
                vec![
                    (
                        vec![SensorGroup::Encoders, SensorGroup::Tachometers],
                        fixed(),
                    ),
                    (vec![SensorGroup::Camera], Box::new(gradient())),
                ],
            );
            return Ok((Box::new(hybrid), Box::new(camera)));
        }
        _ => {}
    }
    let precision: Box<dyn PrecisionMethod> = match method {
        Method::NoFt => Box::new(Fixed::new(nominal)),
        Method::PlAlways => Box::new(gradient()),
        Method::PlDetect => Box::new(GatedLearning::new(detector(ctx)?, Box::new(gradient()))),
        Method::Deterministic => Box::new(Deterministic::new(detector(ctx)?, nominal)),
        Method::Bayes => Box::new(Bayes::new(nominal, p.rho, p.correction, bounds)),
        Method::Window => Box::new(Window::new(nominal, p.window, p.correction, bounds)),
        Method::Oracle => {
            let dt = sc.dt;
            let windows = ctx
                .setup
                .faults
                .iter()
                .map(|f| (f.channels.clone(), f.start_tick(dt), f.end_tick(dt)))
                .collect();
            Box::new(Oracle::new(nominal, windows))
        }
        Method::EkfGate | Method::VbAkf | Method::Imm | Method::Hybrid => {
            unreachable!("built above")
        }
    };
    Ok((uaic(), precision))
}

/// The calibrated detector of a run, checked against its length.
fn detector(ctx: &MethodContext<'_>) -> Result<Detector, ScenarioError> {
    let sc = ctx.setup.scenario();
    let cal = ctx.calibration.ok_or_else(|| ScenarioError::Calibration {
        path: ctx.setup.loaded.path.clone(),
        message: "this method needs a detector calibration".into(),
    })?;
    let ticks = sc.ticks();
    if (cal.ticks as u64) < ticks {
        return Err(ScenarioError::Calibration {
            path: ctx.setup.loaded.path.clone(),
            message: format!(
                "the calibration covers {} ticks, the run has {ticks}",
                cal.ticks
            ),
        });
    }
    if !cal.matches(ctx.layout) {
        return Err(ScenarioError::Calibration {
            path: ctx.setup.loaded.path.clone(),
            message: "the calibration's sensor groups are not this arm's".into(),
        });
    }
    Ok(Detector::new(cal, &sc.detector, ctx.layout))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn method_ids_are_written_as_their_names_and_read_back() {
        for m in Method::ALL {
            let id = MethodId::from(m);
            let text = serde_json::to_string(&id).unwrap();
            assert_eq!(text, serde_json::to_string(&m).unwrap());
            assert_eq!(serde_json::from_str::<MethodId>(&text).unwrap(), id);
        }
        let mine: MethodId = serde_json::from_str("\"numpy-kf\"").unwrap();
        assert_eq!(mine, MethodId::External("numpy-kf".into()));
        assert!(!mine.needs_detector() && mine.builtin().is_none());
        assert!(serde_json::from_str::<MethodId>("\"a b\"").is_err());
        assert!(serde_json::from_str::<MethodId>("\"\"").is_err());
        assert!(check_external_name(&"x".repeat(65)).is_err());
        assert!(check_external_name("my_kf.v2-1").is_ok());
        assert!(
            check_external_name("hybrid")
                .unwrap_err()
                .contains("built-in")
        );
    }
}
