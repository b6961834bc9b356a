//! `phri.Robot`: the robot model with its own workspace; numpy in, numpy out, batched over rows.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::{DMatrix, Matrix3, Matrix6xX, Vector3};
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods};
use phri_core::{FrameId, RobotData, RobotModel};
use pyo3::prelude::*;

use crate::arrays::{rows, same_batch, vector, ArrayIn, Rows};
use crate::errors::{error, IntoPy, Kind};

/// A serial-chain robot (kinematics and rigid-body dynamics), read from a URDF.
#[pyclass(name = "Robot", module = "phri._phri")]
pub struct PyRobot {
    pub model: Arc<RobotModel>,
    data: RobotData,
    /// The frames a robot description declares (None for a robot read from a bare URDF).
    pub frames: RobotFrames,
}

/// Frames phri uses, as a robot description beside the URDF names them.
#[derive(Clone, Default)]
pub struct RobotFrames {
    /// The point the features read by default.
    pub feature: Option<String>,
    /// The tool point, where the person pushes.
    pub hand: Option<String>,
    /// Where the robot holds the cup.
    pub cup: Option<String>,
}

impl PyRobot {
    pub fn new(model: RobotModel) -> Self {
        let data = model.data();
        PyRobot { model: Arc::new(model), data, frames: RobotFrames::default() }
    }

    fn frame(&self, name: &str) -> PyResult<FrameId> {
        self.model.frame_id(name).py_err()
    }
}

/// A fresh array with `shape`, optionally led by the batch size.
fn output<'py>(
    py: Python<'py>,
    values: Vec<f64>,
    batch: Option<usize>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let mut full: Vec<usize> = batch.into_iter().collect();
    full.extend_from_slice(shape);
    PyArray1::from_vec(py, values).reshape(full)
}

impl PyRobot {
    /// Applies `per_row` to every row of the inputs and stacks `width` outputs per row.
    fn map_rows<'py>(
        &mut self,
        py: Python<'py>,
        inputs: &[(&str, &Rows)],
        shape: &[usize],
        mut per_row: impl FnMut(&RobotModel, &mut RobotData, &[&[f64]], &mut [f64]) -> phri_core::Result<()>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let batch = same_batch(inputs)?;
        let width: usize = shape.iter().product();
        let count = batch.unwrap_or(1);
        let mut out = vec![0.0; count * width];
        let mut row_inputs: Vec<&[f64]> = Vec::with_capacity(inputs.len());
        for (k, chunk) in out.chunks_exact_mut(width).enumerate() {
            row_inputs.clear();
            row_inputs.extend(inputs.iter().map(|(_, r)| r.row(k)));
            per_row(&self.model, &mut self.data, &row_inputs, chunk).py_err()?;
        }
        output(py, out, batch, shape)
    }
}

#[pymethods]
impl PyRobot {
    /// Reads a URDF file; `base` defaults to the root link, `tip` to the last moving link.
    #[staticmethod]
    #[pyo3(signature = (path, base=None, tip=None))]
    fn from_urdf(path: PathBuf, base: Option<&str>, tip: Option<&str>) -> PyResult<Self> {
        Ok(PyRobot::new(RobotModel::from_urdf_file(path, base, tip).py_err()?))
    }

    /// Parses URDF text; see `from_urdf`.
    #[staticmethod]
    #[pyo3(signature = (urdf, base=None, tip=None))]
    fn from_urdf_string(urdf: &str, base: Option<&str>, tip: Option<&str>) -> PyResult<Self> {
        Ok(PyRobot::new(RobotModel::from_urdf_str(urdf, base, tip).py_err()?))
    }

    /// A robot from its description (`robot.toml` beside the URDF, read by `phri.robots.load`):
    /// a shipped robot's name ("jaco2") or a description file's path.
    #[staticmethod]
    fn from_description(py: Python<'_>, name_or_path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let d = py.import("phri.robots")?.call_method1("load", (name_or_path,))?;
        let text: String = d.call_method0("urdf_text")?.extract()?;
        let (base, tip): (String, String) = (d.getattr("base")?.extract()?, d.getattr("tip")?.extract()?);
        let source: String = d.getattr("source")?.extract()?;
        let model =
            RobotModel::from_urdf_str(&text, Some(&base), Some(&tip)).map_err(|e| error(Kind::Urdf, format!("{source}: {e}")))?;
        let mut frames = RobotFrames::default();
        for (key, slot) in
            [("feature_frame", &mut frames.feature), ("hand_frame", &mut frames.hand), ("cup_frame", &mut frames.cup)]
        {
            let name: Option<String> = d.getattr(key)?.extract()?;
            if let Some(n) = &name {
                model.frame_id(n).map_err(|e| error(Kind::UnknownName, format!("{source}: key '{key}': {e}")))?;
            }
            *slot = name;
        }
        let mut robot = PyRobot::new(model);
        robot.frames = frames;
        Ok(robot)
    }

    /// The Kinova JACO2 7-DoF arm of the study, from the description shipped with phri
    /// (`phri/robots/jaco2/robot.toml`).
    #[staticmethod]
    fn jaco2(py: Python<'_>) -> PyResult<Self> {
        Self::from_description(py, &"jaco2".into_pyobject(py)?.into_any())
    }

    /// The frame the features read unless told otherwise (None if the robot has no description).
    #[getter]
    fn feature_frame(&self) -> Option<&str> {
        self.frames.feature.as_deref()
    }

    /// The tool point, where the person pushes (None if the robot has no description).
    #[getter]
    fn hand_frame(&self) -> Option<&str> {
        self.frames.hand.as_deref()
    }

    /// The frame at which the robot holds the cup (None if the robot has no description).
    #[getter]
    fn cup_frame(&self) -> Option<&str> {
        self.frames.cup.as_deref()
    }

    /// A copy of this robot carrying a rigid payload at `frame`: `mass` [kg], `com` its centre of
    /// mass in that frame [m] (default the frame origin), `inertia` 3×3 about the com [kg·m²].
    #[pyo3(signature = (frame, mass, com=None, inertia=None))]
    fn with_payload(&self, frame: &str, mass: f64, com: Option<ArrayIn<'_>>, inertia: Option<ArrayIn<'_>>) -> PyResult<Self> {
        let id = self.frame(frame)?;
        let com = match &com {
            Some(c) => Vector3::from_column_slice(&vector("com", c, 3)?),
            None => Vector3::zeros(),
        };
        let inertia = match &inertia {
            Some(i) => Matrix3::from_row_slice(&crate::arrays::matrix("inertia", i, Some(3), 3)?.0),
            None => Matrix3::zeros(),
        };
        let model = (*self.model).clone().with_payload(id, mass, com, inertia).py_err()?;
        let mut robot = PyRobot::new(model);
        robot.frames = self.frames.clone();
        Ok(robot)
    }

    /// Robot name from the URDF.
    #[getter]
    fn name(&self) -> &str {
        &self.model.name
    }

    /// Number of movable joints.
    #[getter]
    fn nq(&self) -> usize {
        self.model.nq()
    }

    /// Names of the movable joints, base to tip.
    #[getter]
    fn joint_names(&self) -> Vec<String> {
        self.model.joints.iter().map(|j| j.name.clone()).collect()
    }

    /// Names of every frame (URDF link) the model keeps.
    #[getter]
    fn frame_names(&self) -> Vec<String> {
        self.model.frames.iter().map(|f| f.name.clone()).collect()
    }

    /// Lower position limits [rad] (−inf for continuous joints).
    #[getter]
    fn lower_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.model.lower_limits())
    }

    /// Upper position limits [rad] (+inf for continuous joints).
    #[getter]
    fn upper_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.model.upper_limits())
    }

    /// Velocity limits [rad/s].
    #[getter]
    fn velocity_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.model.velocity_limits())
    }

    /// Effort limits [N·m].
    #[getter]
    fn effort_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.model.effort_limits())
    }

    /// Raises InvalidParameterError naming the first joint of `q` outside its position limits.
    fn check_limits(&self, q: ArrayIn<'_>) -> PyResult<()> {
        let q = rows("q", &q, self.model.nq())?;
        for k in 0..q.count() {
            self.model.check_within_limits("q", q.row(k)).py_err()?;
        }
        Ok(())
    }

    /// Homogeneous 4×4 pose of `frame` in the base frame [m]; `q` (n,) → (4, 4), (N, n) → (N, 4, 4).
    fn frame_pose<'py>(&mut self, py: Python<'py>, frame: &str, q: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let id = self.frame(frame)?;
        let q = rows("q", &q, self.model.nq())?;
        self.map_rows(py, &[("q", &q)], &[4, 4], |m, d, x, out| {
            m.forward_kinematics(x[0], d)?;
            out.copy_from_slice(m.frame_pose(id, d).to_homogeneous().transpose().as_slice());
            Ok(())
        })
    }

    /// World-aligned 6×n Jacobian of `frame`'s origin, rows (vx, vy, vz, ωx, ωy, ωz) [m/s, rad/s per
    /// unit joint velocity]; `q` (n,) → (6, n), (N, n) → (N, 6, n).
    fn jacobian<'py>(&mut self, py: Python<'py>, frame: &str, q: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let id = self.frame(frame)?;
        let n = self.model.nq();
        let q = rows("q", &q, n)?;
        let mut jac = Matrix6xX::zeros(n);
        self.map_rows(py, &[("q", &q)], &[6, n], |m, d, x, out| {
            m.forward_kinematics(x[0], d)?;
            m.frame_jacobian(id, d, &mut jac)?;
            for r in 0..6 {
                for c in 0..n {
                    out[r * n + c] = jac[(r, c)];
                }
            }
            Ok(())
        })
    }

    /// Gravity torques g(q) [N·m]; `q` (n,) → (n,), (N, n) → (N, n).
    fn gravity<'py>(&mut self, py: Python<'py>, q: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.model.nq();
        let q = rows("q", &q, n)?;
        self.map_rows(py, &[("q", &q)], &[n], |m, d, x, out| m.gravity_torques(x[0], d, out))
    }

    /// Inverse dynamics τ = M(q)q̈ + C(q, q̇)q̇ + g(q) [N·m], single or batched rows.
    fn inverse_dynamics<'py>(
        &mut self,
        py: Python<'py>,
        q: ArrayIn<'py>,
        qd: ArrayIn<'py>,
        qdd: ArrayIn<'py>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.model.nq();
        let (q, qd, qdd) = (rows("q", &q, n)?, rows("qd", &qd, n)?, rows("qdd", &qdd, n)?);
        self.map_rows(py, &[("q", &q), ("qd", &qd), ("qdd", &qdd)], &[n], |m, d, x, out| {
            m.inverse_dynamics(x[0], x[1], x[2], d, out)
        })
    }

    /// Coriolis, centrifugal and gravity efforts C(q, q̇)q̇ + g(q) [N·m], single or batched rows.
    fn nonlinear_effects<'py>(
        &mut self,
        py: Python<'py>,
        q: ArrayIn<'py>,
        qd: ArrayIn<'py>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.model.nq();
        let (q, qd) = (rows("q", &q, n)?, rows("qd", &qd, n)?);
        self.map_rows(py, &[("q", &q), ("qd", &qd)], &[n], |m, d, x, out| m.nonlinear_effects(x[0], x[1], d, out))
    }

    /// Joint-space mass matrix M(q) [kg·m²]; `q` (n,) → (n, n), (N, n) → (N, n, n).
    fn mass_matrix<'py>(&mut self, py: Python<'py>, q: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.model.nq();
        let q = rows("q", &q, n)?;
        let mut mass = DMatrix::zeros(n, n);
        self.map_rows(py, &[("q", &q)], &[n, n], |m, d, x, out| {
            m.mass_matrix(x[0], d, &mut mass)?;
            out.copy_from_slice(mass.as_slice()); // symmetric: column-major equals row-major
            Ok(())
        })
    }

    fn __repr__(&self) -> String {
        format!("Robot(name={:?}, nq={})", self.model.name, self.model.nq())
    }
}
