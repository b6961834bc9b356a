//! `phri.SimulatedArm` and `phri.SimulatedLoop`: the native simulation of an episode.

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use phri_core::sim::{LoopSettings, SimulatedArm, SimulatedLoop, Stop};
use pyo3::prelude::*;

use crate::arrays::{matrix, vector, ArrayIn};
use crate::errors::IntoPy;
use crate::impedance::PyImpedanceController;
use crate::learner::PyLearner;
use crate::robot::PyRobot;
use crate::safety::{PySafetyLayer, PySafetyViolation};

/// The arm of `robot` without contacts or joint limits, integrated with time step `dt` [s] as
/// PyBullet steps it (semi-implicit Euler: q̇ += dt·q̈, then q += dt·q̇, with
/// q̈ = M(q)⁻¹(τ + τ_ext − d·q̇ − C(q, q̇)q̇ − g(q))), under `gravity` [m/s², along −z, in
/// [0, 100]] and viscous `damping` [N·m·s/rad] per joint (a number for every joint, or one each).
/// Starts at rest at q = 0. Allocates nothing per step.
#[pyclass(name = "SimulatedArm", module = "phri._phri")]
#[derive(Clone)]
pub struct PySimulatedArm {
    arm: SimulatedArm,
}

fn per_joint(arg: &str, value: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<f64>> {
    if let Ok(x) = value.extract::<f64>() {
        return Ok(vec![x; n]);
    }
    let a: ArrayIn<'_> = value.extract()?;
    Ok(vector(arg, &a, n)?.into_owned())
}

#[pymethods]
impl PySimulatedArm {
    #[new]
    #[pyo3(signature = (robot, *, dt = 1e-3, gravity = 9.81, damping = None))]
    fn new(robot: PyRef<'_, PyRobot>, dt: f64, gravity: f64, damping: Option<Bound<'_, PyAny>>) -> PyResult<Self> {
        let n = robot.model.nq();
        let damping = match damping {
            Some(d) => per_joint("damping", &d, n)?,
            None => vec![0.0; n],
        };
        Ok(PySimulatedArm { arm: SimulatedArm::new(robot.model.clone(), dt, gravity, &damping).py_err()? })
    }

    /// Joint positions [rad].
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.arm.q())
    }

    /// Joint velocities [rad/s].
    #[getter]
    fn qd<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.arm.qd())
    }

    /// The time step [s].
    #[getter]
    fn dt(&self) -> f64 {
        self.arm.dt()
    }

    /// Places the arm at rest at `q` [rad].
    fn reset(&mut self, q: ArrayIn<'_>) -> PyResult<()> {
        let n = self.arm.model().nq();
        self.arm.reset(&vector("q", &q, n)?).py_err()
    }

    /// One time step under joint torques `tau` [N·m] and external joint torques `tau_ext` [N·m]
    /// (None: none). A step that would leave a non-finite state is a SimulationError and leaves
    /// the state as it was.
    #[pyo3(signature = (tau, tau_ext = None))]
    fn step(&mut self, tau: ArrayIn<'_>, tau_ext: Option<ArrayIn<'_>>) -> PyResult<()> {
        let n = self.arm.model().nq();
        let tau = vector("tau", &tau, n)?;
        let ext = tau_ext.as_ref().map(|e| vector("tau_ext", e, n)).transpose()?;
        self.arm.step(&tau, ext.as_deref()).py_err()
    }

    fn __repr__(&self) -> String {
        format!("SimulatedArm('{}', dt={})", self.arm.model().name, self.arm.dt())
    }
}

/// One motion of a copy of `arm` from `q_start` [rad] for `duration` [s] under `learner`,
/// `controller` (its implicit law, with its wall) and `safety`, the ticks of
/// `phri.control.ControlLoop` one for one: check the state, observe, reference, torque, limit, log
/// every `log_period` [s], step; a stop holds the position for `hold_time` [s] unless the state
/// cannot be trusted. The person pushes `hand`; the joint-torque sensor samples every
/// `sample_every` ticks. Starting resets `safety` (the first command's rate from g(q_start)).
/// Run it in chunks with `advance`; the same learner, controller and layer must be passed to each.
#[pyclass(name = "SimulatedLoop", module = "phri._phri")]
pub struct PySimulatedLoop {
    inner: SimulatedLoop,
}

fn stop_tuple<'py>(py: Python<'py>, s: &Stop) -> StopTuple<'py> {
    (
        PySafetyViolation::from(s.violation),
        s.tick,
        s.t,
        PyArray1::from_slice(py, &s.q),
        PyArray1::from_slice(py, &s.qd),
        PyArray1::from_slice(py, &s.tau),
        PyArray1::from_slice(py, &s.tau_ext),
        s.hold,
    )
}

type Arr<'py> = Bound<'py, PyArray1<f64>>;
type StopTuple<'py> = (PySafetyViolation, u64, f64, Arr<'py>, Arr<'py>, Arr<'py>, Arr<'py>, bool);

fn rows<'py>(py: Python<'py>, values: &[f64], cols: usize) -> PyResult<Bound<'py, PyArray2<f64>>> {
    PyArray1::from_slice(py, values).reshape([values.len() / cols, cols])
}

#[pymethods]
impl PySimulatedLoop {
    #[new]
    #[pyo3(signature = (arm, q_start, safety, *, duration, hand, hold_time = 0.5, log_period = 0.01, sample_every = 100))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        arm: PyRef<'_, PySimulatedArm>,
        q_start: ArrayIn<'_>,
        mut safety: PyRefMut<'_, PySafetyLayer>,
        duration: f64,
        hand: &str,
        hold_time: f64,
        log_period: f64,
        sample_every: u64,
    ) -> PyResult<Self> {
        let n = arm.arm.model().nq();
        let q_start = vector("q_start", &q_start, n)?;
        let hand = arm.arm.model().frame_id(hand).py_err()?;
        let settings = LoopSettings { duration, hold_time, log_period, sample_every, hand };
        Ok(PySimulatedLoop { inner: SimulatedLoop::new(arm.arm.clone(), settings, &q_start, &mut safety.layer).py_err()? })
    }

    /// Runs the ticks up to tick `until` (exclusive) or the motion's end with the person's wrench
    /// `push` (6,) at the hand (force [N], torque [N·m], base frame; None: nobody touches it)
    /// held throughout. `offsets` (samples_before(until), n) [N·m]: the sensor's bias and noise
    /// at each sample instant among those ticks. The GIL is released meanwhile. An error of the
    /// learner (a failed replan worker only counts, `replan_failures`), the law or the step ends
    /// the motion and is raised.
    #[pyo3(signature = (until, push, offsets, learner, controller, safety))]
    #[allow(clippy::too_many_arguments)]
    fn advance(
        &mut self,
        py: Python<'_>,
        until: u64,
        push: Option<ArrayIn<'_>>,
        offsets: ArrayIn<'_>,
        learner: PyRef<'_, PyLearner>,
        mut controller: PyRefMut<'_, PyImpedanceController>,
        mut safety: PyRefMut<'_, PySafetyLayer>,
    ) -> PyResult<()> {
        let n = self.inner.arm().model().nq();
        let push = push.as_ref().map(|p| vector("push", p, 6).map(|v| [v[0], v[1], v[2], v[3], v[4], v[5]])).transpose()?;
        let (offsets, _) = matrix("offsets", &offsets, None, n)?;
        let mut guard = learner.learner(py);
        let (inner, learner, controller, safety) = (&mut self.inner, &mut *guard, &mut controller.controller, &mut safety.layer);
        py.detach(|| inner.advance(until, push.as_ref(), &offsets, learner, controller, safety)).py_err()
    }

    /// The sensor samples among the ticks from the next one up to `until` (exclusive).
    fn samples_before(&self, until: u64) -> u64 {
        self.inner.samples_before(until)
    }

    /// The index of the next tick to run; its state is the arm's now.
    #[getter]
    fn tick(&self) -> u64 {
        self.inner.tick()
    }

    /// The next tick's robot time [s].
    #[getter]
    fn t(&self) -> f64 {
        self.inner.t()
    }

    /// The next tick's joint positions [rad].
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.inner.arm().q())
    }

    /// The next tick's joint velocities [rad/s].
    #[getter]
    fn qd<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.inner.arm().qd())
    }

    /// Whether the motion has ended.
    #[getter]
    fn done(&self) -> bool {
        self.inner.done()
    }

    /// Ticks run, including those holding after a stop.
    #[getter]
    fn ticks(&self) -> u64 {
        self.inner.ticks()
    }

    /// How long the arm held its position after the stop [s of robot time].
    #[getter]
    fn held(&self) -> f64 {
        self.inner.held()
    }

    /// Ticks at which the virtual wall acted.
    #[getter]
    fn wall_ticks(&self) -> u64 {
        self.inner.wall_ticks()
    }

    /// The wall's largest total force [N].
    #[getter]
    fn wall_peak_force(&self) -> f64 {
        self.inner.wall_peak_force()
    }

    /// Replans the learner's worker failed (the arm kept its plan).
    #[getter]
    fn replan_failures(&self) -> u64 {
        self.inner.replan_failures()
    }

    /// The last failed replan's message (None: none failed).
    #[getter]
    fn replan_error(&self) -> Option<&str> {
        self.inner.replan_error()
    }

    /// The stop, or None: (violation, tick, t [s], q [rad], qd [rad/s], tau [N·m], tau_ext [N·m],
    /// whether the arm held).
    #[getter]
    fn stop<'py>(&self, py: Python<'py>) -> Option<StopTuple<'py>> {
        self.inner.stop().map(|s| stop_tuple(py, s))
    }

    /// The log so far: t (rows,) [s]; q, qd, q_ref, tau, tau_ext (rows, n); wall_force (rows,)
    /// [N]; push (rows, 6) (force [N], torque [N·m]); touched (rows,) bool.
    fn log<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let log = self.inner.log();
        let n = self.inner.arm().model().nq();
        let d = pyo3::types::PyDict::new(py);
        d.set_item("t", PyArray1::from_slice(py, &log.t))?;
        for (key, values) in [("q", &log.q), ("qd", &log.qd), ("q_ref", &log.q_ref), ("tau", &log.tau), ("tau_ext", &log.tau_ext)]
        {
            d.set_item(key, rows(py, values, n)?)?;
        }
        d.set_item("wall_force", PyArray1::from_slice(py, &log.wall_force))?;
        d.set_item("push", rows(py, &log.push, 6)?)?;
        d.set_item("touched", PyArray1::from_slice(py, &log.touched))?;
        Ok(d)
    }
}
