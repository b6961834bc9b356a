//! `phri.Deformation`: the intended trajectory of a push, ξ_H = ξ_R + μ·A⁻¹·U_H (paper eq. 7).

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use phri_core::deform::{DeformParams, Deformation, EndRule, Norm, MAX_WINDOW};
use pyo3::prelude::*;

use crate::arrays::{matrix, shape_str, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};
use crate::ints::{bounded, int};

const NORMS: [(&str, Norm); 2] = [("acceleration", Norm::Acceleration), ("jerk", Norm::Jerk)];
const END_RULES: [(&str, EndRule); 2] = [("skip", EndRule::Skip), ("shrink", EndRule::Shrink)];

/// The value named `name` in `table`, or InvalidParameterError listing the allowed names.
fn lookup<T: Copy>(arg: &str, table: &[(&str, T)], name: &str) -> PyResult<T> {
    table.iter().find(|(n, _)| *n == name).map(|(_, v)| *v).ok_or_else(|| {
        let allowed = table.iter().map(|(n, _)| format!("'{n}'")).collect::<Vec<_>>().join(" or ");
        error(Kind::InvalidParameter, format!("{arg} must be {allowed}, got '{name}'"))
    })
}

fn name_of<T: Copy + PartialEq>(table: &[(&'static str, T)], value: T) -> &'static str {
    table.iter().find(|(_, v)| *v == value).map_or("?", |(n, _)| n)
}

/// A Python int as a waypoint count or index.
fn non_negative(arg: &str, value: i128) -> PyResult<usize> {
    bounded(arg, value, 0..=usize::MAX, "")
}

/// ξ_H = ξ_R + μ·A⁻¹·U_H: a push u_H [N·m] at waypoint `index` moves the next `window` waypoints,
/// joint j of the k-th by μ·H[k]·u_H[j], H = R⁻¹e₁ (R = AᵀA) scaled to ‖H‖ = √window. `norm`:
/// "acceleration" (the paper; second differences) or "jerk" (third differences). `mu` [rad/(N·m)]
/// > 0 moves the trajectory the way the person pushes (the original used −0.01 with its arm's
/// measured-torque sign). `end_rule` within `window` waypoints of the goal, which never moves:
/// "skip" (the original) moves nothing, "shrink" moves the waypoints left with the shorter window's
/// shape. Waypoints outside the window are untouched. The first and last moved waypoints step by
/// 0.75 and 0.25 of the peak for the 5-waypoint window (a kink at the push); the steps vanish as the
/// window lengthens, fastest for "jerk" (see phri_core::deform).
#[pyclass(name = "Deformation", module = "phri._phri", frozen)]
pub struct PyDeformation {
    pub(crate) deformation: Deformation,
}

#[pymethods]
impl PyDeformation {
    #[new]
    #[pyo3(signature = (*, window = 5, mu = 0.01, norm = "acceleration", end_rule = "skip"))]
    fn new(#[pyo3(from_py_with = int)] window: i128, mu: f64, norm: &str, end_rule: &str) -> PyResult<Self> {
        let params = DeformParams {
            window: bounded("window", window, 1..=MAX_WINDOW, "waypoints")?,
            mu,
            norm: lookup("norm", &NORMS, norm)?,
            end_rule: lookup("end_rule", &END_RULES, end_rule)?,
        };
        Ok(PyDeformation { deformation: Deformation::new(params).py_err()? })
    }

    /// The deformed copy of `trajectory` (N, dof) [rad] for the push `u_h` (dof,) [N·m] at
    /// waypoint `index` (0 ≤ index < N). Unchanged near the goal under "skip" (see `window_at`).
    fn deform<'py>(
        &self,
        py: Python<'py>,
        trajectory: ArrayIn<'py>,
        #[pyo3(from_py_with = int)] index: i128,
        u_h: ArrayIn<'py>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let dof = match trajectory.shape() {
            [_, dof] => *dof,
            other => return Err(error(Kind::Shape, format!("trajectory must have shape (N, dof), got {}", shape_str(other)))),
        };
        let (values, n_waypoints) = matrix("trajectory", &trajectory, None, dof)?;
        let u_h = vector("u_h", &u_h, dof)?;
        let mut out = values.into_owned();
        self.deformation.deform_in_place(&mut out, dof, non_negative("index", index)?, &u_h).py_err()?;
        Ok(PyArray1::from_vec(py, out).reshape([n_waypoints, dof])?.to_dyn().clone())
    }

    /// How many waypoints a push at `index` of an `n_waypoints` trajectory moves (0: none).
    fn window_at(
        &self,
        #[pyo3(from_py_with = int)] index: i128,
        #[pyo3(from_py_with = int)] n_waypoints: i128,
    ) -> PyResult<usize> {
        let n_waypoints = non_negative("n_waypoints", n_waypoints)?;
        self.deformation.window_at(non_negative("index", index)?, n_waypoints).py_err()
    }

    /// Waypoints n moved by a full window.
    #[getter]
    fn window(&self) -> usize {
        self.deformation.params().window
    }

    /// Gain μ [rad/(N·m)].
    #[getter]
    fn mu(&self) -> f64 {
        self.deformation.params().mu
    }

    /// "acceleration" or "jerk".
    #[getter]
    fn norm(&self) -> &'static str {
        name_of(&NORMS, self.deformation.params().norm)
    }

    /// "skip" or "shrink".
    #[getter]
    fn end_rule(&self) -> &'static str {
        name_of(&END_RULES, self.deformation.params().end_rule)
    }

    /// A copy of the full-window shape H (window,), ‖H‖ = √window.
    #[getter]
    fn shape<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.deformation.shape())
    }

    fn __repr__(&self) -> String {
        let p = self.deformation.params();
        format!("Deformation(window={}, mu={:?}, norm='{}', end_rule='{}')", p.window, p.mu, self.norm(), self.end_rule())
    }
}
