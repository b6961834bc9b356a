//! Features written in Python (`phri.Feature`, `phri.feature`): the core's `BatchFunction` over a
//! Python object, called once per evaluation with every configuration of it, holding the GIL only
//! for that call (a replan on the learner's worker thread takes it per evaluation).

use std::sync::Arc;
use std::time::{Duration, Instant};

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use phri_core::features::{BatchFeature, BatchFunction};
use phri_core::{PhriError, Result};
use pyo3::prelude::*;
use pyo3::types::{PyString, PyTuple};

use crate::arrays::{shape_str, ArrayIn};
use crate::ints::int;

/// Default limit on one call of a Python feature [s] (its `timeout` attribute overrides it).
pub const DEFAULT_TIMEOUT: f64 = 1.0;

/// A Python feature object: `name`, `value(q)`, and optionally `gradient(q)`, `hessian(q)`,
/// `samples` (points per segment) and `timeout` [s].
struct PythonFunction {
    name: String,
    object: Py<PyAny>,
    has_gradient: bool,
    has_hessian: bool,
    timeout: Duration,
}

/// Whether `item` looks like a Python feature (has a callable `value` and is no str or mapping).
pub fn is_python_feature(item: &Bound<'_, PyAny>) -> bool {
    !item.is_instance_of::<PyString>()
        && item.cast::<pyo3::types::PyMapping>().is_err()
        && item.getattr("value").is_ok_and(|v| v.is_callable())
}

fn invalid(arg: &str, reason: impl Into<String>) -> PyErr {
    crate::errors::error(crate::errors::Kind::InvalidParameter, format!("{arg}: {}", reason.into()))
}

/// The feature of Python object `item` (item `arg` of a features list).
pub fn python_feature(arg: &str, item: &Bound<'_, PyAny>) -> PyResult<BatchFeature> {
    let name: String =
        item.getattr("name").and_then(|n| n.extract()).map_err(|_| invalid(arg, "a Python feature needs a `name` (a string)"))?;
    if name.is_empty() {
        return Err(invalid(arg, "a Python feature's `name` must not be empty"));
    }
    let callable = |attr: &str| item.getattr(attr).is_ok_and(|v| !v.is_none() && v.is_callable());
    let samples = match item.getattr("samples") {
        Ok(v) if !v.is_none() => {
            let k = int(&v).map_err(|_| invalid(&format!("{arg}.samples"), "must be an integer"))?;
            usize::try_from(k).map_err(|_| invalid(&format!("{arg}.samples"), format!("must be >= 1, got {k}")))?
        }
        _ => 1,
    };
    let timeout = match item.getattr("timeout") {
        Ok(v) if !v.is_none() => {
            let t: f64 = v.extract().map_err(|_| invalid(&format!("{arg}.timeout"), "must be a number of seconds"))?;
            if !(t.is_finite() && t > 0.0) {
                return Err(invalid(&format!("{arg}.timeout"), format!("must be finite and > 0 s, got {t}")));
            }
            t
        }
        _ => DEFAULT_TIMEOUT,
    };
    let function = PythonFunction {
        name,
        object: item.clone().unbind(),
        has_gradient: callable("gradient"),
        has_hessian: callable("hessian"),
        timeout: Duration::from_secs_f64(timeout),
    };
    BatchFeature::new(Arc::new(function), samples).map_err(|e| invalid(arg, e.to_string()))
}

impl PythonFunction {
    fn fail(&self, reason: impl Into<String>) -> PhriError {
        PhriError::Feature { feature: self.name.clone(), reason: reason.into() }
    }

    /// Calls `method(q)` with `q` as an (m, n) array and copies its result, of shape `shape`, into
    /// `out`.
    fn call(&self, method: &str, q: &[f64], n: usize, shape: &[usize], out: &mut [f64]) -> Result<()> {
        let m = q.len() / n;
        Python::attach(|py| {
            let array = PyArray1::from_slice(py, q).reshape([m, n]).map_err(|e| self.fail(e.to_string()))?;
            let began = Instant::now();
            let result =
                self.object.bind(py).call_method1(method, PyTuple::new(py, [array]).map_err(|e| self.fail(e.to_string()))?);
            let took = began.elapsed();
            let result = result.map_err(|e| self.fail(format!("{method}(q) raised {}", describe(py, &e))))?;
            if took > self.timeout {
                return Err(self.fail(format!(
                    "{method}(q) took {:.3} s for {m} configurations, over its limit of {} s (set the feature's `timeout` [s])",
                    took.as_secs_f64(),
                    self.timeout.as_secs_f64()
                )));
            }
            let values: ArrayIn<'_> = result
                .extract()
                .map_err(|e| self.fail(format!("{method}(q) must return an array of shape {}: {e}", shape_str(shape))))?;
            if values.shape() != shape {
                return Err(self.fail(format!(
                    "{method}(q) must return shape {} for q of shape ({m}, {n}), got {}",
                    shape_str(shape),
                    shape_str(values.shape())
                )));
            }
            for (o, v) in out.iter_mut().zip(values.as_array().iter()) {
                *o = *v;
            }
            Ok(())
        })
    }
}

/// "TypeName: message (file:line)" of a Python exception, for the error message.
fn describe(py: Python<'_>, e: &PyErr) -> String {
    let kind = e.get_type(py).name().map(|n| n.to_string()).unwrap_or_else(|_| "Exception".into());
    let mut text = format!("{kind}: {}", e.value(py));
    let mut tb = e.traceback(py);
    let mut last = None;
    while let Some(t) = tb {
        last = Some(t.clone());
        tb = t.getattr("tb_next").ok().and_then(|n| n.cast_into().ok());
    }
    if let Some(t) = last {
        let at = (|| -> PyResult<String> {
            let frame = t.getattr("tb_frame")?;
            let file: String = frame.getattr("f_code")?.getattr("co_filename")?.extract()?;
            let line: i64 = t.getattr("tb_lineno")?.extract()?;
            Ok(format!(" ({file}:{line})"))
        })();
        text.push_str(&at.unwrap_or_default());
    }
    text
}

impl BatchFunction for PythonFunction {
    fn name(&self) -> &str {
        &self.name
    }
    fn has_gradient(&self) -> bool {
        self.has_gradient
    }
    fn has_hessian(&self) -> bool {
        self.has_hessian
    }
    fn values(&self, q: &[f64], n: usize, values: &mut [f64]) -> Result<()> {
        self.call("value", q, n, &[q.len() / n], values)
    }
    fn gradients(&self, q: &[f64], n: usize, gradients: &mut [f64]) -> Result<()> {
        self.call("gradient", q, n, &[q.len() / n, n], gradients)
    }
    fn hessians(&self, q: &[f64], n: usize, hessians: &mut [f64]) -> Result<()> {
        self.call("hessian", q, n, &[q.len() / n, n, n], hessians)
    }
}
