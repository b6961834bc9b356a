//! `phri.InteractionDetector`: is a measured joint torque a person pushing?

use numpy::{PyArray1, PyUntypedArrayMethods};
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use pyo3::prelude::*;

use crate::arrays::{shape_str, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};

/// Per-joint thresholding of measured torques [N·m]: a sample is an interaction when any
/// |τ_j − bias_j| exceeds thresholds_j; joints below their threshold are zeroed in u_H.
/// Defaults: the original JACO2 thresholds (8, 8, 8, 2, 1, 1, 1) N·m and no bias.
#[pyclass(name = "InteractionDetector", module = "phri._phri", frozen)]
pub struct PyInteractionDetector {
    pub(crate) detector: InteractionDetector,
}

#[pymethods]
impl PyInteractionDetector {
    #[new]
    #[pyo3(signature = (thresholds = None, bias = None))]
    fn new(thresholds: Option<ArrayIn<'_>>, bias: Option<ArrayIn<'_>>) -> PyResult<Self> {
        let thresholds = match &thresholds {
            None => JACO2_THRESHOLDS.to_vec(),
            Some(t) => match t.shape() {
                [n] => vector("thresholds", t, *n)?.into_owned(),
                other => return Err(error(Kind::Shape, format!("thresholds must have shape (n,), got {}", shape_str(other)))),
            },
        };
        let bias = bias.as_ref().map(|b| vector("bias", b, thresholds.len()).map(|v| v.into_owned())).transpose()?;
        Ok(PyInteractionDetector { detector: InteractionDetector::new(thresholds, bias).py_err()? })
    }

    /// Per-joint thresholds [N·m].
    #[getter]
    fn thresholds<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.detector.thresholds())
    }

    /// Per-joint bias subtracted from the measurement [N·m].
    #[getter]
    fn bias<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.detector.bias())
    }

    /// (whether any joint exceeded its threshold, u_H (n,) [N·m] with bias removed and
    /// sub-threshold joints zeroed).
    fn detect<'py>(&self, py: Python<'py>, tau_measured: ArrayIn<'py>) -> PyResult<(bool, Bound<'py, PyArray1<f64>>)> {
        let n = self.detector.thresholds().len();
        let tau = vector("tau_measured", &tau_measured, n)?;
        let mut u_h = vec![0.0; n];
        let any = self.detector.detect(&tau, &mut u_h).py_err()?;
        Ok((any, PyArray1::from_vec(py, u_h)))
    }

    fn __repr__(&self) -> String {
        format!("InteractionDetector(thresholds={:?}, bias={:?})", self.detector.thresholds(), self.detector.bias())
    }
}
