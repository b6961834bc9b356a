//! `phri.WeightUpdate`, `phri.UpdateInfo` and `phri.relevance`: the online weight update (paper
//! eq. 13, in cost form) and its published variants.

use numpy::{PyArray1, PyUntypedArrayMethods};
use phri_core::update::{self, UpdateParams, UpdateRule, WeightUpdate};
use pyo3::prelude::*;

use crate::arrays::{matrix, shape_str, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};

/// A 1-D array (the core checks that the lengths agree); ±inf allowed (bounds), NaN left to the core.
fn floats(arg: &str, a: &ArrayIn<'_>) -> PyResult<Vec<f64>> {
    if a.ndim() != 1 {
        return Err(error(Kind::Shape, format!("{arg} must have shape (K,), got {}", shape_str(a.shape()))));
    }
    Ok(a.as_array().iter().copied().collect())
}

/// What one update did.
#[pyclass(name = "UpdateInfo", module = "phri._phri", frozen, eq)]
#[derive(PartialEq, Clone)]
pub struct PyUpdateInfo {
    info: update::UpdateInfo,
}

impl From<update::UpdateInfo> for PyUpdateInfo {
    fn from(info: update::UpdateInfo) -> Self {
        PyUpdateInfo { info }
    }
}

#[pymethods]
impl PyUpdateInfo {
    /// The feature the "max" rule moved (None for the other rules, or if nothing is learned).
    #[getter]
    fn chosen(&self) -> Option<usize> {
        self.info.chosen
    }

    /// Whether any weight hit a bound.
    #[getter]
    fn clipped(&self) -> bool {
        self.info.clipped
    }

    /// The largest |change| of a weight.
    #[getter]
    fn max_change(&self) -> f64 {
        self.info.max_change
    }

    fn __repr__(&self) -> String {
        let chosen = self.info.chosen.map_or("None".to_string(), |c| c.to_string());
        let clipped = if self.info.clipped { "True" } else { "False" };
        format!("UpdateInfo(chosen={chosen}, clipped={clipped}, max_change={})", self.info.max_change)
    }
}

/// The weight update w ← clip(w − α ⊙ ΔΦ, lower, upper) with ΔΦ = Φ(ξ_H) − Φ(ξ_R), one entry per
/// feature (cost weights: the paper's reward weights are θ = −w).
///
/// `rule`: "all" moves every learned weight (the paper); "max" only the learned feature with the
/// largest |ΔΦ_k| / ranges_k (HRI 2018); "confidence" scales each step by a relevance in [0, 1]
/// (after CoRL 2018) that `apply` then requires.
#[pyclass(name = "WeightUpdate", module = "phri._phri", frozen)]
pub struct PyWeightUpdate {
    pub(crate) update: WeightUpdate,
}

#[pymethods]
impl PyWeightUpdate {
    #[new]
    #[pyo3(signature = (step, lower, upper, *, learned = None, ranges = None, rule = "all"))]
    fn new(
        step: ArrayIn<'_>,
        lower: ArrayIn<'_>,
        upper: ArrayIn<'_>,
        learned: Option<Vec<bool>>,
        ranges: Option<ArrayIn<'_>>,
        rule: &str,
    ) -> PyResult<Self> {
        let rule = UpdateRule::from_name("rule", rule).py_err()?;
        let step = floats("step", &step)?;
        let k = step.len();
        let params = UpdateParams {
            lower: floats("lower", &lower)?,
            upper: floats("upper", &upper)?,
            learned: learned.unwrap_or_else(|| vec![true; k]),
            ranges: match &ranges {
                Some(r) => floats("ranges", r)?,
                None => vec![1.0; k],
            },
            step,
            rule,
        };
        Ok(PyWeightUpdate { update: WeightUpdate::new(params).py_err()? })
    }

    /// Step α_k per feature.
    #[getter]
    fn step<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.update.params().step)
    }

    /// Lower bound of each weight.
    #[getter]
    fn lower<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.update.params().lower)
    }

    /// Upper bound of each weight.
    #[getter]
    fn upper<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.update.params().upper)
    }

    /// Whether each weight is learned.
    #[getter]
    fn learned<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        PyArray1::from_slice(py, &self.update.params().learned)
    }

    /// Range of each feature for the "max" rule's normalisation (1 = none).
    #[getter]
    fn ranges<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.update.params().ranges)
    }

    /// "all", "max" or "confidence".
    #[getter]
    fn rule(&self) -> &'static str {
        self.update.params().rule.name()
    }

    /// One update: returns the new weights (a fresh array) and what the update did. `relevance`
    /// (K,) in [0, 1] is required by the "confidence" rule and ignored by the others.
    #[pyo3(signature = (weights, delta_phi, relevance = None))]
    fn apply<'py>(
        &self,
        py: Python<'py>,
        weights: ArrayIn<'py>,
        delta_phi: ArrayIn<'py>,
        relevance: Option<ArrayIn<'py>>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, PyUpdateInfo)> {
        let k = self.update.len();
        let mut w = vector("weights", &weights, k)?.into_owned();
        let delta_phi = vector("delta_phi", &delta_phi, k)?;
        let relevance = relevance.as_ref().map(|r| vector("relevance", r, k)).transpose()?;
        let info = self.update.apply(&mut w, &delta_phi, relevance.as_deref()).py_err()?;
        Ok((PyArray1::from_vec(py, w), PyUpdateInfo { info }))
    }

    /// `weights` clipped into [lower, upper] (a fresh array), e.g. initial weights from a task file.
    fn clip<'py>(&self, py: Python<'py>, weights: ArrayIn<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let mut w = vector("weights", &weights, self.update.len())?.into_owned();
        self.update.clip(&mut w);
        Ok(PyArray1::from_vec(py, w))
    }

    fn __len__(&self) -> usize {
        self.update.len()
    }

    fn __repr__(&self) -> String {
        let p = self.update.params();
        format!("WeightUpdate(step={:?}, lower={:?}, upper={:?}, rule='{}')", p.step, p.lower, p.upper, p.rule.name())
    }
}

/// Relevance of each feature to a push u_H (K,), given the linearised sensitivity S = ∂ΔΦ/∂u_H
/// (K, n): relevance_k = min(1, ΔΦ_k² / (‖S_k‖² ‖u_H‖²)), the squared fraction of the push that the
/// smallest torque producing the same change of feature k would need; 0 for a zero push or row.
#[pyfunction]
pub fn relevance<'py>(
    py: Python<'py>,
    delta_phi: ArrayIn<'py>,
    sensitivity: ArrayIn<'py>,
    u_h: ArrayIn<'py>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let delta_phi = match delta_phi.shape() {
        [k] => vector("delta_phi", &delta_phi, *k)?,
        other => return Err(error(Kind::Shape, format!("delta_phi must have shape (K,), got {}", shape_str(other)))),
    };
    let u_h = match u_h.shape() {
        [n] => vector("u_h", &u_h, *n)?,
        other => return Err(error(Kind::Shape, format!("u_h must have shape (n,), got {}", shape_str(other)))),
    };
    let (sensitivity, _) = matrix("sensitivity", &sensitivity, Some(delta_phi.len()), u_h.len())?;
    let mut out = vec![0.0; delta_phi.len()];
    update::relevance(&delta_phi, &sensitivity, &u_h, &mut out).py_err()?;
    Ok(PyArray1::from_vec(py, out))
}
