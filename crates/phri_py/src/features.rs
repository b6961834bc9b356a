//! `phri.Features`: trajectory feature counts Φ(ξ) and their gradients, one native call per trajectory.

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods};
use phri_core::features::{
    declared_parameters, feature_parameters, DeclaredSpec, Feature, FeatureParams, FeatureSet, FeatureSpec, KeepoutSpec,
    BUILTIN_FEATURES, DECLARED_KINDS, DEFAULT_SAMPLES, MAX_SAMPLES,
};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyMapping, PyString, PyTuple};

use crate::arrays::{matrix, vector, zeros, ArrayIn};
use crate::errors::{error, IntoPy, Kind};
use crate::ints::{bounded, int};
use crate::python_feature::{is_python_feature, python_feature};
use crate::robot::PyRobot;
use crate::scene::PyScene;

/// Task features of a trajectory (paper eq. 3 and the authors' definitions), evaluated at the origin
/// of `frame`. A trajectory `xi` is an (N, n) array, one waypoint per row; Φ(ξ) sums each feature
/// over the segments (q_{i-1}, q_i], i = 1..N-1, so waypoint 0 contributes only through segment 1.
#[pyclass(name = "Features", module = "phri._phri")]
pub struct PyFeatures {
    pub(crate) set: FeatureSet,
    n: usize,
    frame: String,
    /// Per keep-out feature: its name, circle centre (x, y) [m] and radius [m].
    circles: Vec<(String, (f64, f64), f64)>,
    /// The scene the features were made with (empty if none): the one plans keep clear of.
    pub(crate) scene: Py<PyScene>,
}

fn output<'py>(py: Python<'py>, values: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    PyArray1::from_vec(py, values).reshape(shape)
}

impl PyFeatures {
    /// Row-major values and the number of waypoints N ≥ 2 of a trajectory argument.
    fn trajectory<'a>(&self, arg: &str, xi: &'a ArrayIn<'_>) -> PyResult<(std::borrow::Cow<'a, [f64]>, usize)> {
        let (values, waypoints) = matrix(arg, xi, None, self.n)?;
        if waypoints < 2 {
            return Err(error(
                Kind::Shape,
                format!("{arg} must have shape (N, {}) with N >= 2, got ({waypoints}, {})", self.n, self.n),
            ));
        }
        Ok((values, waypoints))
    }
}

/// The specification of item `i` of the `features` argument: a built-in name, or a mapping with
/// "name" and that feature's parameters.
fn spec(i: usize, item: &Bound<'_, PyAny>) -> PyResult<FeatureSpec> {
    let arg = format!("features[{i}]");
    if let Ok(name) = item.extract::<String>() {
        return Ok(FeatureSpec { name, params: FeatureParams::None });
    }
    let map = item.cast::<PyMapping>().map_err(|_| {
        PyTypeError::new_err(format!("{arg} must be a feature name or a mapping with \"name\" and its parameters"))
    })?;
    let name: String = match map.get_item("name") {
        Ok(v) => v.extract().map_err(|_| PyTypeError::new_err(format!("{arg}[\"name\"] must be a string")))?,
        Err(_) => return Err(error(Kind::InvalidParameter, format!("{arg} needs a \"name\""))),
    };
    let kind: Option<String> = match map.get_item("kind") {
        Ok(v) => Some(v.extract().map_err(|_| PyTypeError::new_err(format!("{arg}[\"kind\"] must be a string")))?),
        Err(_) => None,
    };
    if let Some(kind) = &kind {
        if !DECLARED_KINDS.contains(&kind.as_str()) {
            return Err(error(
                Kind::UnknownName,
                format!("{arg}.kind: unknown feature kind '{kind}'; known: {}", DECLARED_KINDS.join(", ")),
            ));
        }
    }
    let takes = match &kind {
        Some(kind) => declared_parameters(kind),
        None => feature_parameters(&name),
    };
    let mut given = Given::new();
    for key in map.keys()?.iter() {
        let key: String = key.extract().map_err(|_| PyTypeError::new_err(format!("{arg}: keys must be strings")))?;
        if key == "name" || (key == "kind" && kind.is_some()) {
            continue;
        }
        if !takes.contains(&key.as_str()) {
            let list = if takes.is_empty() { "none".to_string() } else { takes.join(", ") };
            if let Some(kind) = &kind {
                return Err(error(
                    Kind::InvalidParameter,
                    format!("{arg}.{key}: a '{kind}' feature takes no parameter '{key}' (it takes: {list})"),
                ));
            }
            return Err(error(
                Kind::InvalidParameter,
                format!("{arg}.{key}: feature '{name}' takes no parameter '{key}' (it takes: {list})"),
            ));
        }
        given.insert(key.clone(), map.get_item(&key)?);
    }
    if let Some(kind) = &kind {
        return Ok(FeatureSpec { name, params: FeatureParams::Declared(declared_params(&arg, kind, &given)?) });
    }
    let params = if takes.contains(&"keep_out") {
        FeatureParams::Keepout(keepout_params(&arg, &name, &given)?)
    } else if takes.contains(&"height") {
        FeatureParams::Table { height: number(&arg, &given, "height")?.unwrap_or(0.0) }
    } else {
        FeatureParams::None
    };
    Ok(FeatureSpec { name, params })
}

type Given<'py> = std::collections::HashMap<String, Bound<'py, PyAny>>;

/// Parameter `key` of feature item `arg` as a number, if given.
fn number(arg: &str, given: &Given<'_>, key: &str) -> PyResult<Option<f64>> {
    given
        .get(key)
        .map(|v| v.extract::<f64>().map_err(|_| PyTypeError::new_err(format!("{arg}.{key} must be a number"))))
        .transpose()
}

/// The keep-out parameters of feature item `arg` (named `name`): the object and radius it needs,
/// the offset and samples it may have.
fn keepout_params(arg: &str, name: &str, given: &Given<'_>) -> PyResult<KeepoutSpec> {
    let keep_out: String = match given.get("keep_out") {
        Some(v) => v.extract().map_err(|_| PyTypeError::new_err(format!("{arg}.keep_out must be a scene object's name")))?,
        None => {
            return Err(error(
                Kind::InvalidParameter,
                format!("{arg}.keep_out: feature '{name}' needs the scene object it keeps away from"),
            ))
        }
    };
    let radius = number(arg, given, "radius")?
        .ok_or_else(|| error(Kind::InvalidParameter, format!("{arg}.radius: feature '{name}' needs its keep-out radius [m]")))?;
    let offset = match given.get("offset") {
        Some(v) => {
            let a: ArrayIn<'_> = v.extract().map_err(|e| PyTypeError::new_err(format!("{arg}.offset: {e}")))?;
            let o = vector(&format!("{arg}.offset"), &a, 2)?;
            [o[0], o[1]]
        }
        None => [0.0, 0.0],
    };
    let samples = match given.get("samples") {
        Some(v) => {
            let n = int(v).map_err(|_| PyTypeError::new_err(format!("{arg}.samples must be an integer")))?;
            bounded(&format!("{arg}.samples"), n, 1..=MAX_SAMPLES, "points per segment")?
        }
        None => DEFAULT_SAMPLES,
    };
    Ok(KeepoutSpec { keep_out, radius, offset, samples })
}

/// Parameter `key` of feature item `arg` as a string, if given.
fn text(arg: &str, given: &Given<'_>, key: &str) -> PyResult<Option<String>> {
    given
        .get(key)
        .map(|v| v.extract::<String>().map_err(|_| PyTypeError::new_err(format!("{arg}.{key} must be a string"))))
        .transpose()
}

/// Parameter `key` of feature item `arg` as a vector of `len` numbers (any length if None).
fn numbers(arg: &str, given: &Given<'_>, key: &str, len: Option<usize>) -> PyResult<Option<Vec<f64>>> {
    let Some(v) = given.get(key) else { return Ok(None) };
    let a: ArrayIn<'_> = v.extract().map_err(|e| PyTypeError::new_err(format!("{arg}.{key}: {e}")))?;
    let len = len.unwrap_or_else(|| a.len().unwrap_or(0));
    Ok(Some(vector(&format!("{arg}.{key}"), &a, len)?.into_owned()))
}

/// The parameters of declared feature item `arg` of kind `kind` (one of `DECLARED_KINDS`).
fn declared_params(arg: &str, kind: &str, given: &Given<'_>) -> PyResult<DeclaredSpec> {
    let frame = text(arg, given, "frame")?;
    let need = |key: &str, what: &str| error(Kind::InvalidParameter, format!("{arg}.{key}: a '{kind}' feature needs {what}"));
    Ok(match kind {
        "height" => DeclaredSpec::Height {
            frame,
            object: text(arg, given, "object")?,
            offset: number(arg, given, "offset")?.unwrap_or(0.0),
        },
        "distance" => {
            let shape = text(arg, given, "shape")?.unwrap_or_else(|| "cylinder".into());
            if shape != "cylinder" && shape != "sphere" {
                return Err(error(Kind::InvalidParameter, format!("{arg}.shape must be 'cylinder' or 'sphere', got '{shape}'")));
            }
            let samples = match given.get("samples") {
                Some(v) => {
                    let n = int(v).map_err(|_| PyTypeError::new_err(format!("{arg}.samples must be an integer")))?;
                    bounded(&format!("{arg}.samples"), n, 1..=MAX_SAMPLES, "points per segment")?
                }
                None => DEFAULT_SAMPLES,
            };
            let offset = numbers(arg, given, "offset", Some(3))?.map_or([0.0; 3], |o| [o[0], o[1], o[2]]);
            DeclaredSpec::Distance {
                frame,
                object: text(arg, given, "object")?.ok_or_else(|| need("object", "the scene object it keeps away from"))?,
                radius: number(arg, given, "radius")?.ok_or_else(|| need("radius", "its radius [m]"))?,
                offset,
                samples,
                sphere: shape == "sphere",
            }
        }
        "alignment" => {
            let axis = match text(arg, given, "axis")?.as_deref() {
                None | Some("x") => 0,
                Some("y") => 1,
                Some("z") => 2,
                Some(other) => {
                    return Err(error(Kind::InvalidParameter, format!("{arg}.axis must be 'x', 'y' or 'z', got '{other}'")))
                }
            };
            let d = numbers(arg, given, "direction", Some(3))?.ok_or_else(|| need("direction", "a world direction (x, y, z)"))?;
            DeclaredSpec::Alignment { frame, axis, direction: [d[0], d[1], d[2]] }
        }
        "joint_distance" => DeclaredSpec::JointDistance {
            pose: numbers(arg, given, "pose", None)?.ok_or_else(|| need("pose", "a pose (one angle per joint) [rad]"))?,
        },
        _ => DeclaredSpec::Speed { frame },
    })
}

/// Per declared kind, the names of its parameters (`phri._phri.DECLARED_PARAMETERS`).
pub fn declared(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let out = PyDict::new(py);
    for kind in DECLARED_KINDS {
        out.set_item(kind, PyTuple::new(py, declared_parameters(kind))?)?;
    }
    Ok(out)
}

/// Per built-in feature, the names of its parameters (`phri._phri.FEATURE_PARAMETERS`).
pub fn parameters(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let out = PyDict::new(py);
    for name in BUILTIN_FEATURES {
        out.set_item(name, PyTuple::new(py, feature_parameters(name))?)?;
    }
    Ok(out)
}

#[pymethods]
impl PyFeatures {
    /// `features`: per feature a built-in name (see `FEATURE_NAMES`) or a mapping with "name" and
    /// that feature's parameters: "table" takes `height` [m] (default 0, the authors' raw z);
    /// "laptop" and "human" take `keep_out` (the `scene` object they keep away from), `radius` [m],
    /// `offset` (x, y) of the circle's centre from the object [m] (default 0, 0) and `samples`
    /// per segment (default 4). `frame` defaults to the robot's feature frame; `ranges` divides
    /// each feature by its normalisation range (default 1).
    #[new]
    #[pyo3(signature = (robot, features, *, scene = None, frame = None, ranges = None))]
    fn new(
        py: Python<'_>,
        robot: PyRef<'_, PyRobot>,
        features: &Bound<'_, PyAny>,
        scene: Option<PyRef<'_, PyScene>>,
        frame: Option<&str>,
        ranges: Option<ArrayIn<'_>>,
    ) -> PyResult<Self> {
        if features.is_instance_of::<PyString>() {
            return Err(PyTypeError::new_err("features must be a list of feature names or mappings, not a string"));
        }
        // Per item: a built-in or declared specification, or a Python feature.
        let items = features
            .try_iter()?
            .enumerate()
            .map(|(i, item)| {
                let item = item?;
                if is_python_feature(&item) {
                    Ok(Err(python_feature(&format!("features[{i}]"), &item)?))
                } else {
                    spec(i, &item).map(Ok)
                }
            })
            .collect::<PyResult<Vec<_>>>()?;
        let frame = match frame {
            Some(f) => f.to_string(),
            None => robot.frames.feature.clone().ok_or_else(|| {
                error(
                    Kind::InvalidParameter,
                    format!("frame: robot '{}' declares no feature frame (no robot description); pass frame=", robot.model.name),
                )
            })?,
        };
        let model = robot.model.clone();
        let frame_id = model.frame_id(&frame).py_err()?;
        let n = model.nq();
        let on_scene = scene.as_ref().map(|s| &s.scene);
        let built = items
            .iter()
            .enumerate()
            .map(|(i, item)| match item {
                Ok(spec) => spec.build(&format!("features[{i}]"), on_scene, &model),
                Err(python) => Ok(Box::new(python.clone()) as Box<dyn Feature>),
            })
            .collect::<phri_core::Result<Vec<_>>>()
            .py_err()?;
        let mut set = FeatureSet::new(model, frame_id, built).py_err()?;
        let specs: Vec<&FeatureSpec> = items.iter().filter_map(|i| i.as_ref().ok()).collect();
        if let Some(r) = &ranges {
            set.set_ranges(Some(&*vector("ranges", r, set.len())?)).py_err()?;
        }
        let mut circles = Vec::new();
        for (i, spec) in specs.iter().enumerate() {
            match (&spec.params, &scene) {
                (FeatureParams::Keepout(k), Some(scene)) => {
                    let c = k.center(&format!("features[{i}]"), &scene.scene).py_err()?;
                    circles.push((spec.name.clone(), (c.x, c.y), k.radius));
                }
                // A declared distance on the feature frame, as a cylinder, is a keep-out circle too.
                (
                    FeatureParams::Declared(DeclaredSpec::Distance {
                        frame: None, object, radius, offset, sphere: false, ..
                    }),
                    Some(scene),
                ) => {
                    let p = scene.scene.require(&format!("features[{i}].object"), object).py_err()?.position();
                    circles.push((spec.name.clone(), (p.x + offset[0], p.y + offset[1]), *radius));
                }
                _ => {}
            }
        }
        let scene = match scene {
            Some(s) => s.into(),
            None => py.get_type::<PyScene>().call0()?.cast_into::<PyScene>()?.unbind(),
        };
        Ok(PyFeatures { set, n, frame, circles, scene })
    }

    /// The scene the features were made with (an empty Scene if none was given): the objects a
    /// `TrajectoryOptimizer` for these features keeps the robot clear of.
    #[getter]
    fn scene(&self, py: Python<'_>) -> Py<PyScene> {
        self.scene.clone_ref(py)
    }

    /// Each keep-out feature's circle (and each declared `distance` on the feature frame, as a
    /// cylinder): {name: ((x, y) centre [m], radius [m])}, placed by the scene.
    #[getter]
    fn keep_out_circles<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for (name, center, radius) in &self.circles {
            out.set_item(name, (*center, *radius))?;
        }
        Ok(out)
    }

    /// The frame whose origin the features read.
    #[getter]
    fn frame(&self) -> &str {
        &self.frame
    }

    /// Feature names, in the order of every output.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.set.names().into_iter().map(String::from).collect()
    }

    /// Normalisation range of each feature (1 where not normalised).
    #[getter]
    fn ranges<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.set.ranges())
    }

    /// The weights (K,) that pose on a path of `to_waypoints` waypoints the trade-off `weights` pose
    /// on `from_waypoints`: each w_k times r^(1+e_k), r = (from − 1)/(to − 1), e_k = −1 for
    /// efficiency (a sum of squared steps) and 1 for the per-waypoint features. Φ sums over
    /// waypoints, so weights learnt on 31 waypoints weigh the task 11 times more on 100 unless
    /// rescaled. The optimiser's clearance penalty sums over waypoints too but is not a feature:
    /// for the same trade-off scale `clearance_weight` by r² as well.
    fn rescale_weights<'py>(
        &self,
        py: Python<'py>,
        weights: ArrayIn<'py>,
        #[pyo3(from_py_with = int)] from_waypoints: i128,
        #[pyo3(from_py_with = int)] to_waypoints: i128,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let from = bounded("from_waypoints", from_waypoints, 2..=usize::MAX, "waypoints")?;
        let to = bounded("to_waypoints", to_waypoints, 2..=usize::MAX, "waypoints")?;
        let weights = vector("weights", &weights, self.set.len())?;
        Ok(PyArray1::from_vec(py, self.set.rescale_weights(&weights, from, to).py_err()?))
    }

    /// Position of feature `name` in `names`.
    fn index(&self, name: &str) -> PyResult<usize> {
        self.set.index_of(name).py_err()
    }

    /// Φ(ξ): (N, n) → (K,).
    fn phi<'py>(&mut self, py: Python<'py>, xi: ArrayIn<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (xi, _) = self.trajectory("xi", &xi)?;
        let mut phi = vec![0.0; self.set.len()];
        self.set.phi(&xi, &mut phi).py_err()?;
        Ok(PyArray1::from_vec(py, phi))
    }

    /// Φ(ξ) and its Jacobian ∂Φ_k/∂ξ: (N, n) → ((K,), (K, N, n)).
    #[allow(clippy::type_complexity)]
    fn phi_gradient<'py>(
        &mut self,
        py: Python<'py>,
        xi: ArrayIn<'py>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let (xi, waypoints) = self.trajectory("xi", &xi)?;
        let k = self.set.len();
        let len = k.checked_mul(xi.len()).ok_or_else(|| error(Kind::InvalidParameter, "xi is too large"))?;
        let (mut phi, mut jac) = (vec![0.0; k], zeros("xi", len)?);
        self.set.phi_gradient(&xi, &mut phi, &mut jac).py_err()?;
        Ok((PyArray1::from_vec(py, phi), output(py, jac, &[k, waypoints, self.n])?))
    }

    /// φ of every segment: (N, n) → (N−1, K); row i−1 is segment (q_{i-1}, q_i].
    fn per_segment<'py>(&mut self, py: Python<'py>, xi: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let (xi, waypoints) = self.trajectory("xi", &xi)?;
        let k = self.set.len();
        let mut out = zeros("xi", (waypoints - 1) * k)?;
        self.set.per_segment(&xi, &mut out).py_err()?;
        output(py, out, &[waypoints - 1, k])
    }

    /// The weighted cost c = Σ_k w_k Φ_k(ξ) and its gradient ∂c/∂ξ: ((N, n), (K,)) → (float, (N, n)).
    fn weighted_cost<'py>(
        &mut self,
        py: Python<'py>,
        xi: ArrayIn<'py>,
        weights: ArrayIn<'py>,
    ) -> PyResult<(f64, Bound<'py, PyArrayDyn<f64>>)> {
        let (xi, waypoints) = self.trajectory("xi", &xi)?;
        let weights = vector("weights", &weights, self.set.len())?;
        let mut grad = vec![0.0; xi.len()];
        let cost = self.set.weighted_cost_gradient(&xi, &weights, &mut grad).py_err()?;
        Ok((cost, output(py, grad, &[waypoints, self.n])?))
    }

    fn __len__(&self) -> usize {
        self.set.len()
    }

    fn __repr__(&self) -> String {
        format!("Features({:?})", self.set.names())
    }
}
