//! `phri.ImpedanceController`: the impedance law (paper eqs. 5 and 6) for a 1 kHz loop.
//!
//! A control step is a few microseconds, so the joint-vector arguments take a fast path: a
//! float64 1-D ndarray is borrowed as it is (the core checks its length and values, naming the
//! argument); anything else goes through the array-like conversion. The GIL is kept: releasing
//! and re-acquiring it would cost more than the step.

use std::borrow::Cow;

use nalgebra::DMatrix;
use numpy::{PyArray1, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyReadonlyArray1, PyUntypedArray, PyUntypedArrayMethods};
use phri_core::impedance::{ControlStatus, Gain, ImpedanceController, ImpedanceParams};
use phri_core::wall::{VirtualWall, WallParams, DEFAULT_WALL};

// The signature spells the core's wall defaults out (so that Python's help shows numbers).
const _: () = assert!(
    DEFAULT_WALL.margin == 0.005
        && DEFAULT_WALL.band == 0.01
        && DEFAULT_WALL.stiffness == 8000.0
        && DEFAULT_WALL.damping == 200.0
);
use pyo3::prelude::*;
use pyo3::Borrowed;

use crate::arrays::{check_finite, shape_str, vector, ArrayIn};
use crate::errors::{error, to_py, IntoPy, Kind};
use crate::robot::PyRobot;
use crate::scene::PyScene;

/// A joint vector argument: borrowed when it already is a float64 1-D ndarray, converted otherwise.
pub enum Joints<'py> {
    Fast(PyReadonlyArray1<'py, f64>),
    Any(ArrayIn<'py>),
}

impl<'a, 'py> FromPyObject<'a, 'py> for Joints<'py> {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if let Ok(a) = obj.cast::<PyArray1<f64>>() {
            if let Ok(r) = a.try_readonly() {
                return Ok(Joints::Fast(r));
            }
        }
        Ok(Joints::Any(obj.extract()?))
    }
}

impl Joints<'_> {
    /// The values, finite and within ±MAX_MAGNITUDE; a fast-path slice's length is checked by the
    /// core, which names `arg`.
    pub(crate) fn values(&self, arg: &str, n: usize) -> PyResult<Cow<'_, [f64]>> {
        match self {
            Joints::Fast(a) => {
                let values = match a.as_slice() {
                    Ok(s) => Cow::Borrowed(s),
                    Err(_) => Cow::Owned(a.as_array().to_vec()),
                };
                check_finite(arg, &values, n, false)?;
                Ok(values)
            }
            Joints::Any(a) => vector(arg, a, n),
        }
    }

    /// The values as given, only their number checked (by the core for a fast-path slice): for
    /// the safety layer, which must report a non-finite or huge reading as a violation (a stop),
    /// not refuse the call.
    pub(crate) fn unchecked(&self, arg: &str, n: usize) -> PyResult<Cow<'_, [f64]>> {
        match self {
            Joints::Fast(a) => Ok(match a.as_slice() {
                Ok(s) => Cow::Borrowed(s),
                Err(_) => Cow::Owned(a.as_array().to_vec()),
            }),
            Joints::Any(a) if a.shape() == [n] => Ok(Cow::Owned(a.as_array().iter().copied().collect())),
            Joints::Any(a) => Err(error(Kind::Shape, format!("{arg} must have shape ({n},), got {}", shape_str(a.shape())))),
        }
    }
}

/// Why `out` cannot be written (only called once the direct write failed).
fn out_error(out: &Bound<'_, PyAny>, n: usize) -> PyErr {
    let expected = format!("a writable, contiguous float64 ndarray of shape ({n},)");
    let Ok(array) = out.cast::<PyUntypedArray>() else {
        let kind = out.get_type().name().map_or_else(|_| "?".to_string(), |t| t.to_string());
        return error(Kind::InvalidParameter, format!("out must be {expected}, got {kind}"));
    };
    if array.shape() != [n] {
        return error(Kind::Shape, format!("out must have shape ({n},), got {}", shape_str(array.shape())));
    }
    let dtype = array.dtype();
    if !dtype.is_equiv_to(&numpy::dtype::<f64>(out.py())) {
        return error(Kind::InvalidParameter, format!("out must be {expected}, got dtype {dtype}"));
    }
    if !array.is_contiguous() {
        return error(Kind::InvalidParameter, format!("out must be {expected}, got a non-contiguous view"));
    }
    error(Kind::InvalidParameter, "out must be writable and must not be one of the inputs")
}

/// Runs `step` writing into `out` (if given, returned as is) or into `scratch` copied to a fresh array.
fn write_out<'py>(
    py: Python<'py>,
    out: Option<&Bound<'py, PyAny>>,
    scratch: &mut [f64],
    step: impl FnOnce(&mut [f64]) -> PyResult<()>,
) -> PyResult<Bound<'py, PyAny>> {
    let Some(obj) = out else {
        step(scratch)?;
        return Ok(PyArray1::from_slice(py, scratch).into_any());
    };
    if let Ok(array) = obj.cast::<PyArray1<f64>>() {
        if let Ok(mut rw) = array.try_readwrite() {
            if let Ok(slice) = rw.as_slice_mut() {
                if slice.len() == scratch.len() {
                    step(slice)?;
                    return Ok(obj.clone());
                }
            }
        }
    }
    Err(out_error(obj, scratch.len()))
}

fn gain(arg: &str, g: Option<ArrayIn<'_>>, n: usize, default: Gain) -> PyResult<Gain> {
    let Some(g) = g else { return Ok(default) };
    match g.shape() {
        [m] if *m == n => Ok(Gain::Diagonal(vector(arg, &g, n)?.into_owned())),
        [r, c] if *r == n && *c == n => {
            let (values, _) = crate::arrays::matrix(arg, &g, Some(n), n)?;
            Ok(Gain::Full(DMatrix::from_row_slice(n, n, &values)))
        }
        other => Err(error(Kind::Shape, format!("{arg} must have shape ({n},) or ({n}, {n}), got {}", shape_str(other)))),
    }
}

fn gain_array<'py>(py: Python<'py>, g: &Gain) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    match g {
        Gain::Diagonal(d) => Ok(PyArray1::from_slice(py, d).to_dyn().clone()),
        Gain::Full(m) => {
            let n = m.nrows();
            // nalgebra is column-major; the transpose's column-major data is the row-major matrix.
            Ok(PyArray1::from_slice(py, m.transpose().as_slice()).reshape([n, n])?.to_dyn().clone())
        }
    }
}

/// The impedance law τ = g(q) + K(q_R − q) + B(q̇_R − q̇) (eq. 6, `torque`) or, with a desired
/// inertia M_R, the full law of eq. 5 by feedback linearisation (`torque_full`), saturated to the
/// effort limits [N·m]. Gains are 1-D (diagonal, (n,)) or 2-D ((n, n)) arrays: stiffness K
/// [N·m/rad], damping B [N·m·s/rad], inertia M_R [kg·m²]; full matrices must be symmetric positive
/// semidefinite (M_R definite). K and B default to the JACO2 gains (20, 30, 15, 15, 10, 10, 6)
/// and (40, 60, 30, 30, 15, 15, 10), as compliant as the study's arm. `gravity_compensation` adds g(q) to eq. 6 (`torque`,
/// `torque_implicit`); eq. 5 always includes it (feedback linearisation cancels all the dynamics).
/// With a `scene`, a virtual wall (on unless `wall=False`) adds a repulsive torque that keeps every
/// collision body at least `wall_margin` [m] from the scene's furniture, whatever the reference and
/// the person's push: a normal force `wall_stiffness`·x plus `wall_damping`·min(1, x / `wall_band`)
/// times the approach speed [N, N/m, N·s/m, m], x = `wall_margin` + `wall_band` − d (damping that
/// grows across the band, so the force starts from zero), at the closest spheres of each
/// body–furniture pair within reach (`wall_force`, `wall_distance` tell what it did in the last
/// step). The person is not a wall. `wall_margin` and `wall_band` lie in [0, 1] m,
/// `wall_stiffness` in [0, 10⁶] N/m, `wall_damping` in [0, 10⁵] N·s/m (checked with or without a
/// scene).
#[pyclass(name = "ImpedanceController", module = "phri._phri")]
pub struct PyImpedanceController {
    pub(crate) controller: ImpedanceController,
    status: ControlStatus,
    tau: Vec<f64>,
}

#[pymethods]
impl PyImpedanceController {
    #[new]
    #[pyo3(signature = (
        robot, *, stiffness = None, damping = None, inertia = None, gravity_compensation = true, scene = None,
        wall = true, wall_margin = 0.005, wall_band = 0.01, wall_stiffness = 8000.0, wall_damping = 200.0
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        robot: PyRef<'_, PyRobot>,
        stiffness: Option<ArrayIn<'_>>,
        damping: Option<ArrayIn<'_>>,
        inertia: Option<ArrayIn<'_>>,
        gravity_compensation: bool,
        scene: Option<PyRef<'_, PyScene>>,
        wall: bool,
        wall_margin: f64,
        wall_band: f64,
        wall_stiffness: f64,
        wall_damping: f64,
    ) -> PyResult<Self> {
        let model = robot.model.clone();
        let n = model.nq();
        let defaults = ImpedanceParams::jaco2_default();
        for (arg, given, default) in [("stiffness", &stiffness, &defaults.stiffness), ("damping", &damping, &defaults.damping)] {
            if given.is_none() && !matches!(default, Gain::Diagonal(d) if d.len() == n) {
                return Err(error(
                    Kind::InvalidParameter,
                    format!("{arg} must be given for a robot with {n} joints (the default gains are the JACO2's, 7 joints)"),
                ));
            }
        }
        let params = ImpedanceParams {
            stiffness: gain("stiffness", stiffness, n, defaults.stiffness)?,
            damping: gain("damping", damping, n, defaults.damping)?,
            inertia: inertia.map(|g| gain("inertia", Some(g), n, Gain::Diagonal(vec![]))).transpose()?,
            gravity_compensation,
        };
        let mut controller = ImpedanceController::new(model.clone(), params).py_err()?;
        // Checked with or without a scene: a wrong value is a mistake either way.
        let params = WallParams { margin: wall_margin, band: wall_band, stiffness: wall_stiffness, damping: wall_damping };
        params.check().py_err()?;
        if let (Some(scene), true) = (&scene, wall) {
            let wall = VirtualWall::new(&model, &scene.scene, params).map_err(|e| match e {
                phri_core::PhriError::Planning { reason } => {
                    error(Kind::Planning, format!("{reason}; pass wall=False to run without the virtual wall"))
                }
                other => to_py(other),
            })?;
            controller.set_wall(Some(wall)).py_err()?;
        }
        Ok(PyImpedanceController { controller, status: ControlStatus::default(), tau: vec![0.0; n] })
    }

    /// Eq. 6: τ = g(q) (if gravity_compensation) + K(q_R − q) + B(q̇_R − q̇) [N·m], saturated;
    /// all arguments (n,). Writes into `out` (a writable float64 (n,) array) and returns it if given.
    #[pyo3(signature = (q, qd, q_ref, qd_ref, out = None))]
    fn torque<'py>(
        &mut self,
        py: Python<'py>,
        q: Joints<'py>,
        qd: Joints<'py>,
        q_ref: Joints<'py>,
        qd_ref: Joints<'py>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let n = self.tau.len();
        let (q, qd) = (q.values("q", n)?, qd.values("qd", n)?);
        let (q_ref, qd_ref) = (q_ref.values("q_ref", n)?, qd_ref.values("qd_ref", n)?);
        let (controller, status) = (&mut self.controller, &mut self.status);
        write_out(py, out, &mut self.tau, |tau| {
            *status = controller.torque(&q, &qd, &q_ref, &qd_ref, tau).py_err()?;
            Ok(())
        })
    }

    /// Eq. 6 discretised implicitly for a simulator stepping explicitly by `dt` [s] ("stable PD"):
    /// spring and damper act on the state predicted one step ahead, using the model's M and C.
    /// Same law in continuous time; stable at 1 kHz near singular poses. Returns τ [N·m].
    #[pyo3(signature = (q, qd, q_ref, qd_ref, dt, out = None))]
    #[allow(clippy::too_many_arguments)]
    fn torque_implicit<'py>(
        &mut self,
        py: Python<'py>,
        q: Joints<'py>,
        qd: Joints<'py>,
        q_ref: Joints<'py>,
        qd_ref: Joints<'py>,
        dt: f64,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let n = self.tau.len();
        let (q, qd) = (q.values("q", n)?, qd.values("qd", n)?);
        let (q_ref, qd_ref) = (q_ref.values("q_ref", n)?, qd_ref.values("qd_ref", n)?);
        let (controller, status) = (&mut self.controller, &mut self.status);
        write_out(py, out, &mut self.tau, |tau| {
            *status = controller.torque_implicit(&q, &qd, &q_ref, &qd_ref, dt, tau).py_err()?;
            Ok(())
        })
    }

    /// Eq. 5 (needs `inertia`): commands M_R(q̈ − q̈_R) + B(q̇ − q̇_R) + K(q − q_R) = u_H through
    /// τ = M(q)q̈* + C(q, q̇)q̇ + g(q) − u_H, saturated [N·m]; all arguments (n,).
    #[pyo3(signature = (q, qd, q_ref, qd_ref, qdd_ref, u_h, out = None))]
    #[allow(clippy::too_many_arguments)]
    fn torque_full<'py>(
        &mut self,
        py: Python<'py>,
        q: Joints<'py>,
        qd: Joints<'py>,
        q_ref: Joints<'py>,
        qd_ref: Joints<'py>,
        qdd_ref: Joints<'py>,
        u_h: Joints<'py>,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let n = self.tau.len();
        let (q, qd) = (q.values("q", n)?, qd.values("qd", n)?);
        let (q_ref, qd_ref) = (q_ref.values("q_ref", n)?, qd_ref.values("qd_ref", n)?);
        let (qdd_ref, u_h) = (qdd_ref.values("qdd_ref", n)?, u_h.values("u_h", n)?);
        let (controller, status) = (&mut self.controller, &mut self.status);
        write_out(py, out, &mut self.tau, |tau| {
            *status = controller.torque_full(&q, &qd, &q_ref, &qd_ref, &qdd_ref, &u_h, tau).py_err()?;
            Ok(())
        })
    }

    /// Sum of the virtual wall's normal forces in the last step [N] (0: it did not act, or no wall).
    #[getter]
    fn wall_force(&self) -> f64 {
        self.status.wall.force
    }

    /// Smallest distance of a collision body to the furniture within the wall's reach in the last
    /// step [m] (inf beyond it, or without a wall).
    #[getter]
    fn wall_distance(&self) -> f64 {
        self.status.wall.distance
    }

    /// The wall's margin [m], or None without a wall.
    #[getter]
    fn wall_margin(&self) -> Option<f64> {
        self.controller.wall().map(|w| w.params().margin)
    }

    /// Bit j set when joint j was clipped to its effort limit in the last successful step.
    #[getter]
    fn saturated(&self) -> u64 {
        self.status.saturated
    }

    /// Effort limits applied by saturation [N·m].
    #[getter]
    fn effort_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.controller.effort_limits())
    }

    /// Stiffness K [N·m/rad]: (n,) if diagonal, else (n, n).
    #[getter]
    fn stiffness<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        gain_array(py, &self.controller.params().stiffness)
    }

    /// Damping B [N·m·s/rad]: (n,) if diagonal, else (n, n).
    #[getter]
    fn damping<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        gain_array(py, &self.controller.params().damping)
    }

    /// Desired inertia M_R [kg·m²] of eq. 5, or None.
    #[getter]
    fn inertia<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.controller.params().inertia.as_ref().map(|g| gain_array(py, g)).transpose()
    }

    /// Whether eq. 6 adds the model's gravity torques g(q).
    #[getter]
    fn gravity_compensation(&self) -> bool {
        self.controller.params().gravity_compensation
    }

    fn __repr__(&self) -> String {
        let p = self.controller.params();
        format!(
            "ImpedanceController(nq={}, inertia={}, gravity_compensation={})",
            self.tau.len(),
            if p.inertia.is_some() { "set" } else { "None" },
            if p.gravity_compensation { "True" } else { "False" }
        )
    }
}
