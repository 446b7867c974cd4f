//! Methods written in Python, run through the same loop as the built-in ones
//! (`Run::with_parts`): an estimator (`step(readings, applied, dt) -> (mu, mu_p, precisions)`)
//! or a precision method that drives the built-in u-AIC (`update(readings, residuals, mu, mu_p,
//! dt) -> precisions`), each with an optional `reset(...)` before the first tick
//! (docs/python.md, "Bring your own method").
//!
//! The GIL is taken for each call only. The first exception raised by the user's code, or the
//! first value of the wrong shape or not finite, is kept with its tick; the method then reports a
//! non-finite update and [`MethodGuard`] stops the run, and the caller raises it.

use std::sync::{Arc, Mutex};

use pyo3::prelude::*;
use pyo3::types::PyList;

use aift::estimation::{Estimate, Estimator, EstimatorInput};
use aift::precision::{PrecisionInput, PrecisionMethod};
use aift::scenario::{Observer, StopReason, TickRecord};
use aift::sensors::{ChannelLayout, Readings};

/// The first failure of a Python method: its tick and the error to raise.
pub type Failure = Arc<Mutex<Option<(u64, PyErr)>>>;

pub fn fail(slot: &Failure, tick: u64, err: PyErr) {
    let mut s = slot.lock().expect("not poisoned");
    if s.is_none() {
        *s = Some((tick, err));
    }
}

fn failed(slot: &Failure) -> bool {
    slot.lock().expect("not poisoned").is_some()
}

/// Readings as a Python list (NaN: missing).
fn readings_list<'py>(py: Python<'py>, r: &Readings) -> PyResult<Bound<'py, PyList>> {
    PyList::new(py, r.values.iter().map(|v| v.unwrap_or(f64::NAN)))
}

/// A returned sequence of `len` finite numbers (non-negative when `non_negative`), or an error
/// naming `what`.
fn values(
    obj: &Bound<'_, PyAny>,
    what: &str,
    len: usize,
    non_negative: bool,
) -> Result<Vec<f64>, String> {
    let v: Vec<f64> = obj
        .extract()
        .map_err(|_| format!("`{what}` is not a sequence of numbers"))?;
    if v.len() != len {
        return Err(format!("`{what}` has {} values; {len} expected", v.len()));
    }
    if let Some(i) = v
        .iter()
        .position(|x| !x.is_finite() || (non_negative && *x < 0.0))
    {
        return Err(format!(
            "`{what}`[{i}] is {}; {} expected",
            v[i],
            if non_negative {
                "a finite number >= 0"
            } else {
                "a finite number"
            }
        ));
    }
    Ok(v)
}

/// The method's name: its `name` attribute, else its class's name.
pub fn method_name(obj: &Bound<'_, PyAny>) -> PyResult<String> {
    match obj.getattr("name") {
        Ok(n) => n.extract::<String>(),
        Err(_) => obj.get_type().name()?.extract::<String>(),
    }
}

/// Calls `reset(n_joints=, channels=, dt=, nominal=, seed=)` when the object has one.
pub fn reset(
    obj: &Bound<'_, PyAny>,
    layout: &ChannelLayout,
    dt: f64,
    nominal: &[f64],
    seed: u64,
) -> PyResult<()> {
    if !obj.hasattr("reset")? {
        return Ok(());
    }
    let py = obj.py();
    let kwargs = pyo3::types::PyDict::new(py);
    kwargs.set_item("n_joints", layout.n_joints())?;
    kwargs.set_item("channels", layout.names())?;
    kwargs.set_item("dt", dt)?;
    kwargs.set_item("nominal", nominal.to_vec())?;
    kwargs.set_item("seed", seed)?;
    obj.call_method("reset", (), Some(&kwargs)).map(|_| ())
}

/// The estimator and precision method of a method written in Python (`obj`, already reset):
/// an estimator (`step`) with [`Reported`], or the built-in u-AIC with a precision method
/// (`update`).
pub fn build_parts(
    obj: &Bound<'_, PyAny>,
    name: &str,
    setup: &aift::scenario::RunSetup,
    seed: u64,
    failure: &Failure,
) -> PyResult<aift::scenario::method::MethodParts> {
    let nominal = setup.nominal_precisions();
    let dt = setup.scenario().dt;
    if obj.hasattr("step")? {
        return Ok((
            Box::new(PyEstimator::new(
                obj.clone().unbind(),
                name.to_string(),
                &setup.layout,
                dt,
                &nominal,
                failure.clone(),
            )),
            Box::new(Reported::new(&nominal)),
        ));
    }
    if !obj.hasattr("update")? {
        return Err(crate::bad(format!(
            "method {name:?}: has neither step(readings, applied, dt) (an estimator) nor \
             update(readings, residuals, mu, mu_p, dt) (a precision method)"
        )));
    }
    let (uaic, _) = aift::scenario::method::build(
        aift::scenario::Method::NoFt,
        &aift::scenario::method::MethodContext {
            setup,
            model: setup.estimator_model(seed),
            layout: &setup.layout,
            nominal: &nominal,
            calibration: None,
        },
    )
    .map_err(|e| crate::bad(e.to_string()))?;
    Ok((
        uaic,
        Box::new(PyPrecision::new(
            obj.clone().unbind(),
            name.to_string(),
            &nominal,
            failure.clone(),
        )),
    ))
}

/// An estimator written in Python.
pub struct PyEstimator {
    obj: Py<PyAny>,
    name: String,
    n: usize,
    dt: f64,
    mu: Vec<f64>,
    mu_p: Vec<f64>,
    estimate: Estimate,
    failure: Failure,
}

impl PyEstimator {
    pub fn new(
        obj: Py<PyAny>,
        name: String,
        layout: &ChannelLayout,
        dt: f64,
        nominal: &[f64],
        failure: Failure,
    ) -> Self {
        let mut estimate = Estimate::new(layout);
        estimate.precisions_used.copy_from_slice(nominal);
        Self {
            obj,
            name,
            n: layout.n_joints(),
            dt,
            mu: vec![0.0; layout.n_joints()],
            mu_p: vec![0.0; layout.n_joints()],
            estimate,
            failure,
        }
    }
}

impl Estimator for PyEstimator {
    fn update(&mut self, input: &EstimatorInput<'_>) -> &Estimate {
        if failed(&self.failure) {
            self.estimate.finite = false;
            return &self.estimate;
        }
        let m = self.estimate.precisions_used.len();
        let result = Python::attach(|py| -> PyResult<Result<[Vec<f64>; 3], String>> {
            let out = self.obj.bind(py).call_method1(
                "step",
                (
                    readings_list(py, input.readings)?,
                    PyList::new(py, input.applied_torques)?,
                    self.dt,
                ),
            )?;
            let parts: Vec<Bound<'_, PyAny>> = match out.extract() {
                Ok(p) => p,
                Err(_) => {
                    return Ok(Err(
                        "step() must return (mu, mu_p, precisions): a sequence of three".into(),
                    ));
                }
            };
            if parts.len() != 3 {
                return Ok(Err(format!(
                    "step() returned {} values; (mu, mu_p, precisions) expected",
                    parts.len()
                )));
            }
            Ok((|| {
                Ok([
                    values(&parts[0], "mu", self.n, false)?,
                    values(&parts[1], "mu_p", self.n, false)?,
                    values(&parts[2], "precisions", m, true)?,
                ])
            })())
        });
        match result {
            Ok(Ok([mu, mu_p, precisions])) => {
                self.mu = mu;
                self.mu_p = mu_p;
                self.estimate.precisions_used = precisions;
                self.estimate.finite = true;
            }
            Ok(Err(message)) => {
                let err = crate::bad(format!(
                    "method {:?} at tick {}: {message}",
                    self.name, input.tick
                ));
                fail(&self.failure, input.tick, err);
                self.estimate.finite = false;
            }
            Err(err) => {
                fail(&self.failure, input.tick, err);
                self.estimate.finite = false;
            }
        }
        &self.estimate
    }

    fn estimate(&self) -> &Estimate {
        &self.estimate
    }

    fn mu(&self) -> &[f64] {
        &self.mu
    }

    fn mu_p(&self) -> &[f64] {
        &self.mu_p
    }
}

/// The precisions a Python estimator returned, handed back as the next tick's (it keeps its own
/// weighting: they are what it reports).
pub struct Reported {
    precisions: Vec<f64>,
}

impl Reported {
    pub fn new(nominal: &[f64]) -> Self {
        Self {
            precisions: nominal.to_vec(),
        }
    }
}

impl PrecisionMethod for Reported {
    fn precisions(&self) -> &[f64] {
        &self.precisions
    }
    fn update(&mut self, input: &PrecisionInput<'_>) {
        self.precisions
            .copy_from_slice(&input.estimate.precisions_used);
    }
}

/// A precision method written in Python, driving the built-in u-AIC.
pub struct PyPrecision {
    obj: Py<PyAny>,
    name: String,
    precisions: Vec<f64>,
    failure: Failure,
}

impl PyPrecision {
    pub fn new(obj: Py<PyAny>, name: String, nominal: &[f64], failure: Failure) -> Self {
        Self {
            obj,
            name,
            precisions: nominal.to_vec(),
            failure,
        }
    }
}

impl PrecisionMethod for PyPrecision {
    fn precisions(&self) -> &[f64] {
        &self.precisions
    }

    fn update(&mut self, input: &PrecisionInput<'_>) {
        if failed(&self.failure) {
            return;
        }
        let m = self.precisions.len();
        let result = Python::attach(|py| -> PyResult<Result<Vec<f64>, String>> {
            let residuals = PyList::new(
                py,
                input
                    .estimate
                    .residuals
                    .iter()
                    .map(|r| r.unwrap_or(f64::NAN)),
            )?;
            let out = self.obj.bind(py).call_method1(
                "update",
                (
                    readings_list(py, input.readings)?,
                    residuals,
                    PyList::new(py, input.mu)?,
                    PyList::new(py, input.mu_p)?,
                    input.dt,
                ),
            )?;
            Ok(values(&out, "precisions", m, true))
        });
        match result {
            Ok(Ok(p)) => self.precisions = p,
            Ok(Err(message)) => fail(
                &self.failure,
                input.tick,
                crate::bad(format!(
                    "method {:?} at tick {}: update() returned {message}",
                    self.name, input.tick
                )),
            ),
            Err(err) => fail(&self.failure, input.tick, err),
        }
    }
}

/// Stops the run once a Python method has failed.
pub struct MethodGuard {
    pub failure: Failure,
}

impl Observer for MethodGuard {
    fn iter(&mut self, _r: &TickRecord<'_>) {}
    fn stop(&self) -> Option<StopReason> {
        failed(&self.failure).then(|| StopReason::Requested("the Python method failed".into()))
    }
}

/// The error to raise for a failure: the user's own exception (its type kept) with a note
/// naming the method and the tick (Python 3.11+ `add_note`; else the message is chained).
pub fn raise(py: Python<'_>, name: &str, tick: u64, err: PyErr) -> PyErr {
    let note = format!("raised by method {name:?} at tick {tick}");
    let value = err.value(py);
    if value.hasattr("add_note").unwrap_or(false)
        && value.call_method1("add_note", (note.clone(),)).is_ok()
    {
        return err;
    }
    let wrapped = pyo3::exceptions::PyRuntimeError::new_err(format!("{note}: {value}"));
    wrapped.set_cause(py, Some(err));
    wrapped
}
