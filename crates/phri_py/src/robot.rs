//! `phri.Robot`: the robot model with its own workspace; numpy in, numpy out, batched over rows.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::{DMatrix, Matrix3, Matrix6xX, Vector3};
use numpy::{PyArray1, PyArray2, PyArrayDyn, PyArrayMethods};
use phri_core::collision::Sphere;
use phri_core::{FrameId, PhriError, RobotData, RobotModel};
use pyo3::prelude::*;

use crate::arrays::{matrix, rows, same_batch, vector, zeros, ArrayIn, Rows};
use crate::errors::{error, IntoPy, Kind};
use crate::scene::PyScene;

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

    pub(crate) fn frame(&self, name: &str) -> PyResult<FrameId> {
        self.model.frame_id(name).py_err()
    }

    /// A robot with `model` and this robot's frames.
    fn derived(&self, model: RobotModel) -> Self {
        let mut robot = PyRobot::new(model);
        robot.frames = self.frames.clone();
        robot
    }
}

/// The model carrying the collision geometry of the URDF at `path` as body `name` at `frame`;
/// errors in the file name the path.
fn attach_urdf_file(model: RobotModel, name: &str, frame: FrameId, path: &std::path::Path) -> phri_core::Result<RobotModel> {
    let text = phri_core::model::read_urdf_file("path", path)?;
    model.with_attached_urdf(name, frame, &text).map_err(|e| match e {
        PhriError::Urdf { arg, reason } if arg == "urdf" => {
            PhriError::Urdf { arg: "path".into(), reason: format!("'{}': {reason}", path.display()) }
        }
        other => other,
    })
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
        let len = count.checked_mul(width).ok_or_else(|| error(Kind::InvalidParameter, "the batch is too large"))?;
        let mut out = zeros(inputs[0].0, len)?;
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
    fn from_urdf(py: Python<'_>, path: PathBuf, base: Option<&str>, tip: Option<&str>) -> PyResult<Self> {
        // Without the GIL: other threads run while the file is read and parsed.
        Ok(PyRobot::new(py.detach(|| RobotModel::from_urdf_file(path, base, tip)).py_err()?))
    }

    /// Parses URDF text; see `from_urdf`.
    #[staticmethod]
    #[pyo3(signature = (urdf, base=None, tip=None))]
    fn from_urdf_string(py: Python<'_>, urdf: &str, base: Option<&str>, tip: Option<&str>) -> PyResult<Self> {
        Ok(PyRobot::new(py.detach(|| RobotModel::from_urdf_str(urdf, base, tip)).py_err()?))
    }

    /// A robot from its description (`robot.toml` beside the URDF, read by `phri.robots.load`):
    /// a shipped robot's name ("jaco2") or a description file's path.
    #[staticmethod]
    fn from_description(py: Python<'_>, name_or_path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let d = py.import("phri.robots")?.call_method1("load", (name_or_path,))?;
        let text: String = d.call_method0("urdf_text")?.extract()?;
        let (base, tip): (String, String) = (d.getattr("base")?.extract()?, d.getattr("tip")?.extract()?);
        let source: String = d.getattr("source")?.extract()?;
        let mut model =
            RobotModel::from_urdf_str(&text, Some(&base), Some(&tip)).map_err(|e| error(Kind::Urdf, format!("{source}: {e}")))?;
        // What the robot carries (the JACO2's cup): its collision geometry joins the model's.
        for carried in d.getattr("carried")?.try_iter()? {
            let carried = carried?;
            let name: String = carried.getattr("name")?.extract()?;
            let frame: String = carried.getattr("frame")?.extract()?;
            let key = format!("carried.{name}");
            let id = model.frame_id(&frame).map_err(|e| error(Kind::UnknownName, format!("{source}: key '{key}.frame': {e}")))?;
            let text: String = carried.call_method0("urdf_text")?.extract()?;
            model = model.with_attached_urdf(&name, id, &text).map_err(|e| {
                let why = match e {
                    PhriError::Urdf { reason, .. } => reason,
                    other => other.to_string(),
                };
                error(Kind::Urdf, format!("{source}: key '{key}.urdf': {why}"))
            })?;
        }
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

    /// The Franka Research 3 (FR3) 7-DoF arm with the Franka Hand, from the description shipped
    /// with phri (`phri/robots/fr3/robot.toml`).
    #[staticmethod]
    fn fr3(py: Python<'_>) -> PyResult<Self> {
        Self::from_description(py, &"fr3".into_pyobject(py)?.into_any())
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

    /// A copy of this robot carrying a rigid payload at `frame`: `mass` [kg] in [0, 1000], `com`
    /// its centre of mass in that frame [m], within ±10 m per axis (default the frame origin),
    /// `inertia` 3×3 about the com [kg·m²].
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
        Ok(self.derived(model))
    }

    /// Names of the collision bodies, in the order of `scene_distances`' rows: the links with
    /// collision geometry (a union of spheres fitted to their URDF's boxes, cylinders, capsules
    /// and spheres, which covers them) and what was added (`with_collision_spheres`, a carried
    /// object such as the cup).
    #[getter]
    fn collision_bodies(&self) -> Vec<String> {
        self.model.collision().bodies().iter().map(|b| b.name.clone()).collect()
    }

    /// Whether planning can check collisions: the robot has collision bodies and every link with
    /// collision geometry has spheres (a mesh has none until given by `with_collision_spheres`).
    #[getter]
    fn collision_complete(&self) -> bool {
        self.model.collision().is_complete()
    }

    /// Why collisions cannot be checked (a link with a mesh, no collision geometry at all), or
    /// None when `collision_complete`.
    #[getter]
    fn collision_incomplete_reason(&self) -> Option<String> {
        self.model.collision().incomplete_reason(&self.model.name)
    }

    /// Body `name`'s spheres: (centres (k, 3) in the body's frame [m], radii (k,) [m], that frame's
    /// name).
    #[allow(clippy::type_complexity)]
    fn collision_spheres<'py>(
        &self,
        py: Python<'py>,
        name: &str,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>, String)> {
        let bodies = self.model.collision().bodies();
        let body = bodies.iter().find(|b| b.name == name).ok_or_else(|| {
            let known: Vec<&str> = bodies.iter().map(|b| b.name.as_str()).collect();
            let known = if known.is_empty() { "none (the robot has no collision model)".to_string() } else { known.join(", ") };
            error(Kind::UnknownName, format!("name: unknown collision body '{name}'; known: {known}"))
        })?;
        let centers: Vec<f64> = body.spheres.iter().flat_map(|s| s.center.iter().copied()).collect();
        let radii: Vec<f64> = body.spheres.iter().map(|s| s.radius).collect();
        let frame = self.model.frames[body.frame.0].name.clone();
        Ok((PyArray1::from_vec(py, centers).reshape([body.spheres.len(), 3])?, PyArray1::from_vec(py, radii), frame))
    }

    /// A copy of this robot whose collision body `name` is the union of spheres at `centers`
    /// (k, 3) in `frame` [m] with `radii` (k,) [m]: a link's fitted spheres replaced (e.g. for a
    /// link whose collision geometry is a mesh), or a new body (a tool, a carried object) added.
    fn with_collision_spheres(&self, name: &str, frame: &str, centers: ArrayIn<'_>, radii: ArrayIn<'_>) -> PyResult<Self> {
        let id = self.frame(frame)?;
        let (centers, k) = matrix("centers", &centers, None, 3)?;
        if k == 0 {
            return Err(error(Kind::Shape, "centers must have shape (N, 3) with N >= 1 (at least one sphere), got (0, 3)"));
        }
        let radii = vector("radii", &radii, k)?;
        if let Some(r) = radii.iter().find(|r| **r <= 0.0) {
            return Err(error(Kind::InvalidParameter, format!("radii must be distances > 0 m, got {r}")));
        }
        let spheres =
            centers.chunks_exact(3).zip(radii.iter()).map(|(c, &r)| Sphere::new(Vector3::from_column_slice(c), r)).collect();
        let model = (*self.model).clone().with_collision_spheres(name, id, spheres).py_err()?;
        Ok(self.derived(model))
    }

    /// A copy of this robot carrying the object the URDF at `path` describes (e.g. a cup): the
    /// collision geometry of its links (joined to its root by fixed joints) as body `name`,
    /// attached at `frame` (the URDF's root frame is `frame`). Only the geometry: a carried
    /// object's mass is `with_payload`'s.
    fn with_attached_urdf(&self, py: Python<'_>, name: &str, frame: &str, path: PathBuf) -> PyResult<Self> {
        let id = self.frame(frame)?;
        let model = (*self.model).clone();
        Ok(self.derived(py.detach(|| attach_urdf_file(model, name, id, &path)).py_err()?))
    }

    /// The smallest signed distance [m] of each collision body (`collision_bodies`) to each object
    /// of `scene` (its `names`), negative where they overlap, without leaving any pair out; `q`
    /// (n,) → (bodies, objects), (N, n) → (N, bodies, objects). Measured on the bodies' spheres,
    /// which cover the links: never more than a link's own distance.
    fn scene_distances<'py>(
        &mut self,
        py: Python<'py>,
        q: ArrayIn<'py>,
        scene: PyRef<'py, PyScene>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = rows("q", &q, self.model.nq())?;
        let shape = [self.model.collision().bodies().len(), scene.scene.objects().len()];
        if shape[0] * shape[1] == 0 {
            return output(py, Vec::new(), q.batch, &shape); // no bodies or no objects: nothing to measure
        }
        self.map_rows(py, &[("q", &q)], &shape, |m, d, x, out| {
            m.forward_kinematics(x[0], d)?;
            m.collision().scene_distances(m, d, &scene.scene, out)
        })
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

    /// Forward dynamics q̈ = M(q)⁻¹(τ − C(q, q̇)q̇ − g(q)) [rad/s²] for efforts `tau` [N·m],
    /// single or batched rows.
    fn forward_dynamics<'py>(
        &mut self,
        py: Python<'py>,
        q: ArrayIn<'py>,
        qd: ArrayIn<'py>,
        tau: ArrayIn<'py>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let n = self.model.nq();
        let (q, qd, tau) = (rows("q", &q, n)?, rows("qd", &qd, n)?, rows("tau", &tau, n)?);
        let mut work = DMatrix::zeros(n, n);
        self.map_rows(py, &[("q", &q), ("qd", &qd), ("tau", &tau)], &[n], |m, d, x, out| {
            m.forward_dynamics(x[0], x[1], x[2], d, &mut work, out)
        })
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
