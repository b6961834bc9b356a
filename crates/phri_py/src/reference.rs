//! `phri.TimedTrajectory`: a plan in time, sampled for the reference (q_R, q̇_R, q̈_R).

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use phri_core::reference::{Interpolation, TimedTrajectory};
use pyo3::prelude::*;

use crate::arrays::{matrix, shape_str, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};

const INTERPOLATIONS: [(&str, Interpolation); 2] = [("cubic", Interpolation::Cubic), ("linear", Interpolation::Linear)];

type Triple<'py, A> = (Bound<'py, A>, Bound<'py, A>, Bound<'py, A>);

fn check_time(arg: &str, t: f64) -> PyResult<()> {
    if !t.is_finite() {
        return Err(error(Kind::NonFinite, format!("{arg} must be finite, got {t}")));
    }
    Ok(())
}

/// N waypoints (N, n) evenly spaced over [0, duration] seconds. "cubic" joins them by cubic
/// Hermite segments with central-difference tangents and zero velocity at both ends (C¹);
/// "linear" is piecewise linear (the original's reference). Before 0 the start is held, after
/// `duration` the goal, both at rest. `duration` lies in [10⁻⁴·(N − 1), 10⁶] s (at least
/// 0.1 ms between waypoints: shorter gave infinite accelerations).
#[pyclass(name = "TimedTrajectory", module = "phri._phri")]
pub struct PyTimedTrajectory {
    traj: TimedTrajectory,
}

type Sampler = fn(&TimedTrajectory, f64, &mut [f64], &mut [f64], &mut [f64]);

impl PyTimedTrajectory {
    /// (q, q̇, q̈) at `t` from `sample` (with or without the blend) as fresh arrays.
    fn sampled<'py>(&self, py: Python<'py>, t: f64, sample: Sampler) -> PyResult<Triple<'py, PyArray1<f64>>> {
        check_time("t", t)?;
        let n = self.traj.dof();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        sample(&self.traj, t, &mut q, &mut qd, &mut qdd);
        Ok((PyArray1::from_vec(py, q), PyArray1::from_vec(py, qd), PyArray1::from_vec(py, qdd)))
    }
}

#[pymethods]
impl PyTimedTrajectory {
    #[new]
    #[pyo3(signature = (waypoints, duration, interpolation = "cubic"))]
    fn new(waypoints: ArrayIn<'_>, duration: f64, interpolation: &str) -> PyResult<Self> {
        let interp = INTERPOLATIONS.iter().find(|(name, _)| *name == interpolation).map(|(_, i)| *i).ok_or_else(|| {
            error(Kind::InvalidParameter, format!("interpolation must be 'cubic' or 'linear', got '{interpolation}'"))
        })?;
        let n = match waypoints.shape() {
            [_, n] => *n,
            other => return Err(error(Kind::Shape, format!("waypoints must have shape (N, n), got {}", shape_str(other)))),
        };
        let (values, _) = matrix("waypoints", &waypoints, None, n)?;
        Ok(PyTimedTrajectory { traj: TimedTrajectory::new(values.into_owned(), n, duration, interp).py_err()? })
    }

    /// (q [rad], q̇ [rad/s], q̈ [rad/s²]) at time `t` [s], each (n,).
    fn sample<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Triple<'py, PyArray1<f64>>> {
        self.sampled(py, t, TimedTrajectory::sample)
    }

    /// `sample` at every time of `times` (T,) [s] in one call: three (T, n) arrays.
    fn sample_many<'py>(&self, py: Python<'py>, times: ArrayIn<'py>) -> PyResult<Triple<'py, PyArrayDyn<f64>>> {
        let times = match times.shape() {
            [len] => vector("times", &times, *len)?,
            other => return Err(error(Kind::Shape, format!("times must have shape (T,), got {}", shape_str(other)))),
        };
        let n = self.traj.dof();
        let len = times.len();
        let (mut q, mut qd, mut qdd) = (vec![0.0; len * n], vec![0.0; len * n], vec![0.0; len * n]);
        for (k, t) in times.iter().enumerate() {
            let rows = k * n..(k + 1) * n;
            self.traj.sample(*t, &mut q[rows.clone()], &mut qd[rows.clone()], &mut qdd[rows]);
        }
        let shape = [len, n];
        Ok((
            PyArray1::from_vec(py, q).reshape(shape)?.to_dyn().clone(),
            PyArray1::from_vec(py, qd).reshape(shape)?.to_dyn().clone(),
            PyArray1::from_vec(py, qdd).reshape(shape)?.to_dyn().clone(),
        ))
    }

    /// Index of the last waypoint at or before `t` [s], clamped to [0, N−1].
    fn index_at(&self, t: f64) -> PyResult<usize> {
        check_time("t", t)?;
        Ok(self.traj.index_at(t))
    }

    /// Replaces the waypoints (same shape (N, n)), e.g. after a replan, at once.
    fn set_waypoints(&mut self, waypoints: ArrayIn<'_>) -> PyResult<()> {
        let (values, _) = matrix("waypoints", &waypoints, Some(self.traj.len()), self.traj.dof())?;
        self.traj.set_waypoints(&values).py_err()
    }

    /// Switches to new waypoints (N, n) at time `t` [s] without a jump: the reference keeps its
    /// position and velocity at `t` and blends into the new plan with every joint's speed within
    /// `speed_limits` (n,) [rad/s] (None: at once). Returns the blend time [s].
    #[pyo3(signature = (waypoints, t, speed_limits = None))]
    fn switch_to(&mut self, waypoints: ArrayIn<'_>, t: f64, speed_limits: Option<ArrayIn<'_>>) -> PyResult<f64> {
        check_time("t", t)?;
        let (values, _) = matrix("waypoints", &waypoints, Some(self.traj.len()), self.traj.dof())?;
        let limits = match &speed_limits {
            Some(l) => vector("speed_limits", l, self.traj.dof())?.into_owned(),
            None => Vec::new(),
        };
        self.traj.switch_to(&values, t, &limits).py_err()
    }

    /// The current plan alone at `t` [s], without the blend from a previous one: (q, q̇, q̈).
    fn sample_plan<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Triple<'py, PyArray1<f64>>> {
        self.sampled(py, t, TimedTrajectory::sample_plan)
    }

    /// Time [s] at which the blend into the current plan ends (0.0 when there is none).
    #[getter]
    fn blend_end(&self) -> f64 {
        self.traj.blend_end()
    }

    /// A copy of the waypoints (N, n) [rad].
    #[getter]
    fn waypoints<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        Ok(PyArray1::from_slice(py, self.traj.waypoints()).reshape([self.traj.len(), self.traj.dof()])?.to_dyn().clone())
    }

    /// Duration T [s].
    #[getter]
    fn duration(&self) -> f64 {
        self.traj.duration()
    }

    /// Time between waypoints [s].
    #[getter]
    fn dt(&self) -> f64 {
        self.traj.dt()
    }

    /// Number of joints n.
    #[getter]
    fn dof(&self) -> usize {
        self.traj.dof()
    }

    /// "cubic" or "linear".
    #[getter]
    fn interpolation(&self) -> &'static str {
        INTERPOLATIONS.iter().find(|(_, i)| *i == self.traj.interpolation()).map_or("cubic", |(name, _)| name)
    }

    /// Number of waypoints N.
    fn __len__(&self) -> usize {
        self.traj.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "TimedTrajectory(waypoints=({}, {}), duration={}, interpolation='{}')",
            self.traj.len(),
            self.traj.dof(),
            self.traj.duration(),
            self.interpolation()
        )
    }
}
