//! `phri.Scene`, `phri.SceneObject`: named objects in the robot's base frame, read-only and
//! picklable (tasks carry their scene to process-pool and Ray workers).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use numpy::PyArray1;
use numpy::PyArrayDyn;
use phri_core::scene::{ObjectKind, Scene, SceneObject, Shape, DEFAULT_MARGIN, KIND_NAMES, SHAPE_NAMES};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::arrays::{vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};

/// One named object: `shape` "plane", "box" (`size` full extents x, y, z [m]), "cylinder"
/// (`radius`, `length` along its z [m]) or "sphere" (`radius` [m]), centred at `position` [m] in
/// the robot's base frame and turned by `rpy` [rad] (URDF roll-pitch-yaw); `margin` [m] is its
/// clearance, `kind` "furniture" or "person".
#[pyclass(name = "SceneObject", module = "phri._phri", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PySceneObject {
    pub(crate) object: SceneObject,
    /// As given, so that a pickled copy is bit-identical.
    rpy: [f64; 3],
}

/// What a shape needs: `given` pairs each parameter with whether it was passed.
fn check_parameters(shape: &str, given: &[(&str, bool)], needs: &[&str]) -> PyResult<()> {
    for (arg, present) in given {
        if *present && !needs.contains(arg) {
            let takes = if needs.is_empty() { "none".to_string() } else { needs.join(", ") };
            return Err(error(Kind::InvalidParameter, format!("{arg}: a {shape} takes no {arg} (it takes: {takes})")));
        }
        if !*present && needs.contains(arg) {
            return Err(error(Kind::InvalidParameter, format!("{arg}: a {shape} needs its {arg} [m]")));
        }
    }
    Ok(())
}

/// A parameter `check_parameters` found present; the same error as there if it is not.
fn required<T>(shape: &str, arg: &str, value: Option<T>) -> PyResult<T> {
    value.ok_or_else(|| error(Kind::InvalidParameter, format!("{arg}: a {shape} needs its {arg} [m]")))
}

fn array<'py>(py: Python<'py>, values: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, values)
}

#[pymethods]
impl PySceneObject {
    #[new]
    #[pyo3(signature = (name, shape, position, *, size = None, radius = None, length = None, rpy = None, margin = None, kind = "furniture"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        name: String,
        shape: &str,
        position: ArrayIn<'_>,
        size: Option<ArrayIn<'_>>,
        radius: Option<f64>,
        length: Option<f64>,
        rpy: Option<ArrayIn<'_>>,
        margin: Option<f64>,
        kind: &str,
    ) -> PyResult<Self> {
        let given = [("size", size.is_some()), ("radius", radius.is_some()), ("length", length.is_some())];
        let shape = match shape {
            "plane" => check_parameters(shape, &given, &[]).map(|_| Shape::Plane)?,
            "box" => {
                check_parameters(shape, &given, &["size"])?;
                let given = required(shape, "size", size)?;
                Shape::Box { size: Vector3::from_column_slice(&vector("size", &given, 3)?) }
            }
            "cylinder" => {
                check_parameters(shape, &given, &["radius", "length"])?;
                Shape::Cylinder { radius: required(shape, "radius", radius)?, length: required(shape, "length", length)? }
            }
            "sphere" => {
                check_parameters(shape, &given, &["radius"])?;
                Shape::Sphere { radius: required(shape, "radius", radius)? }
            }
            other => {
                return Err(error(
                    Kind::UnknownName,
                    format!("shape: unknown shape '{other}'; known: {}", SHAPE_NAMES.join(", ")),
                ))
            }
        };
        let position = vector("position", &position, 3)?;
        let rpy: [f64; 3] = match &rpy {
            Some(r) => {
                let r = vector("rpy", r, 3)?;
                [r[0], r[1], r[2]]
            }
            None => [0.0; 3],
        };
        let pose = Isometry3::from_parts(
            Translation3::new(position[0], position[1], position[2]),
            UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
        );
        let kind = ObjectKind::from_name(kind).py_err()?;
        let object = SceneObject::new(name, shape, pose, margin.unwrap_or(DEFAULT_MARGIN), kind).py_err()?;
        Ok(PySceneObject { object, rpy })
    }

    /// Names of the shapes.
    #[classattr]
    const SHAPES: [&'static str; 4] = SHAPE_NAMES;

    /// Names of the kinds.
    #[classattr]
    const KINDS: [&'static str; 2] = KIND_NAMES;

    /// Margin of an object that declares none [m].
    #[classattr]
    const DEFAULT_MARGIN: f64 = DEFAULT_MARGIN;

    /// The object's name (unique in its scene).
    #[getter]
    fn name(&self) -> &str {
        self.object.name()
    }

    /// "plane", "box", "cylinder" or "sphere".
    #[getter]
    fn shape(&self) -> &'static str {
        self.object.shape().name()
    }

    /// Full extents (x, y, z) of a box [m]; None for other shapes.
    #[getter]
    fn size<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        match self.object.shape() {
            Shape::Box { size } => Some(array(py, size.as_slice())),
            _ => None,
        }
    }

    /// Radius of a cylinder or sphere [m]; None for other shapes.
    #[getter]
    fn radius(&self) -> Option<f64> {
        match *self.object.shape() {
            Shape::Cylinder { radius, .. } | Shape::Sphere { radius } => Some(radius),
            _ => None,
        }
    }

    /// Length of a cylinder along its z axis [m]; None for other shapes.
    #[getter]
    fn length(&self) -> Option<f64> {
        match *self.object.shape() {
            Shape::Cylinder { length, .. } => Some(length),
            _ => None,
        }
    }

    /// The object frame's origin in the base frame [m] (the centre of a box, cylinder or ball).
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array(py, self.object.position().as_slice())
    }

    /// Roll, pitch, yaw of the object frame [rad], as given.
    #[getter]
    fn rpy<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array(py, &self.rpy)
    }

    /// The object frame in the base frame as a (4, 4) homogeneous transform [m].
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        use numpy::PyArrayMethods;
        let m = self.object.pose().to_homogeneous();
        PyArray1::from_vec(py, m.transpose().as_slice().to_vec()).reshape(vec![4, 4])
    }

    /// Clearance margin [m].
    #[getter]
    fn margin(&self) -> f64 {
        self.object.margin()
    }

    /// "furniture" or "person".
    #[getter]
    fn kind(&self) -> &'static str {
        self.object.kind().name()
    }

    /// Height of the object's highest point [m] (None for a plane that is not horizontal).
    #[getter]
    fn top(&self) -> Option<f64> {
        self.object.top()
    }

    fn __getnewargs_ex__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyTuple>, Bound<'py, PyDict>)> {
        let args = PyTuple::new(
            py,
            [self.name().into_pyobject(py)?.into_any(), self.shape().into_pyobject(py)?.into_any(), self.position(py).into_any()],
        )?;
        let kwargs = PyDict::new(py);
        kwargs.set_item("size", self.size(py))?;
        kwargs.set_item("radius", self.radius())?;
        kwargs.set_item("length", self.length())?;
        kwargs.set_item("rpy", self.rpy(py))?;
        kwargs.set_item("margin", self.margin())?;
        kwargs.set_item("kind", self.kind())?;
        Ok((args, kwargs))
    }

    fn __repr__(&self) -> String {
        let o = &self.object;
        let shape = match o.shape() {
            Shape::Plane => String::new(),
            Shape::Box { size } => format!(", size=[{}, {}, {}]", size.x, size.y, size.z),
            Shape::Cylinder { radius, length } => format!(", radius={radius}, length={length}"),
            Shape::Sphere { radius } => format!(", radius={radius}"),
        };
        let p = o.position();
        let rpy = if self.rpy == [0.0; 3] {
            String::new()
        } else {
            format!(", rpy=[{}, {}, {}]", self.rpy[0], self.rpy[1], self.rpy[2])
        };
        format!(
            "SceneObject({:?}, {:?}, [{}, {}, {}]{shape}{rpy}, margin={}, kind={:?})",
            o.name(),
            o.shape().name(),
            p.x,
            p.y,
            p.z,
            o.margin(),
            o.kind().name()
        )
    }
}

/// Named objects in the robot's base frame (names unique), e.g. a task's `[scene]`.
#[pyclass(name = "Scene", module = "phri._phri", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyScene {
    pub(crate) scene: Scene,
    objects: Vec<PySceneObject>,
}

#[pymethods]
impl PyScene {
    #[new]
    #[pyo3(signature = (objects = Vec::new()))]
    fn new(objects: Vec<PySceneObject>) -> PyResult<Self> {
        let scene = Scene::new(objects.iter().map(|o| o.object.clone()).collect()).py_err()?;
        Ok(PyScene { scene, objects })
    }

    /// The objects, in order.
    #[getter]
    fn objects(&self) -> Vec<PySceneObject> {
        self.objects.clone()
    }

    /// The objects' names, in order.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.scene.names().into_iter().map(String::from).collect()
    }

    /// The object named `name` (UnknownNameError listing the scene's objects otherwise).
    fn __getitem__(&self, name: &str) -> PyResult<PySceneObject> {
        self.scene.require("name", name).py_err()?;
        self.get(name).ok_or_else(|| error(Kind::UnknownName, format!("name: unknown object '{name}'")))
    }

    /// The object named `name`, or None.
    fn get(&self, name: &str) -> Option<PySceneObject> {
        self.objects.iter().find(|o| o.object.name() == name).cloned()
    }

    /// Whether the scene has an object named `name` (False for anything but a string).
    fn __contains__(&self, name: &Bound<'_, PyAny>) -> bool {
        name.extract::<&str>().is_ok_and(|n| self.scene.get(n).is_some())
    }

    /// The objects' names, in the scene's order.
    fn __iter__(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        Ok(pyo3::types::PyList::new(py, self.names())?.into_any().try_iter()?.into_any().unbind())
    }

    fn __len__(&self) -> usize {
        self.objects.len()
    }

    fn __getnewargs__(&self) -> (Vec<PySceneObject>,) {
        (self.objects.clone(),)
    }

    fn __repr__(&self) -> String {
        let objects: Vec<String> = self.objects.iter().map(PySceneObject::__repr__).collect();
        format!("Scene([{}])", objects.join(", "))
    }
}
