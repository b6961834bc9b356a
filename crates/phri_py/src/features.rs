//! `phri.Features`: trajectory feature counts Φ(ξ) and their gradients, one native call per trajectory.

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods};
use phri_core::features::{FeatureSet, SceneParams};
use pyo3::prelude::*;

use crate::arrays::{matrix, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};
use crate::robot::PyRobot;

/// Task features of a trajectory (paper eq. 3 and the authors' definitions), evaluated at the origin
/// of `frame`. A trajectory `xi` is an (N, n) array, one waypoint per row; Φ(ξ) sums each feature
/// over the segments (q_{i-1}, q_i], i = 1..N-1, so waypoint 0 contributes only through segment 1.
#[pyclass(name = "Features", module = "phri._phri")]
pub struct PyFeatures {
    pub(crate) set: FeatureSet,
    n: usize,
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

#[pymethods]
impl PyFeatures {
    /// `names` from "efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin";
    /// scene numbers in metres (defaults: the original study); `ranges` divides each feature by
    /// its normalisation range (default 1).
    #[new]
    #[pyo3(signature = (
        robot, names, frame = "j2s7s300_link_7", *, table_height = 0.0, laptop_center = (-0.7929, -0.1),
        human_center = (0.0, 0.2), laptop_radius = 0.4, human_radius = 0.4, samples = 4, ranges = None
    ))]
    #[pyo3(text_signature = "(robot, names, frame='j2s7s300_link_7', *, table_height=0.0, \
                             laptop_center=(-0.7929, -0.1), human_center=(0.0, 0.2), laptop_radius=0.4, human_radius=0.4, \
                             samples=4, ranges=None)")]
    #[allow(clippy::too_many_arguments)]
    fn new(
        robot: PyRef<'_, PyRobot>,
        names: Vec<String>,
        frame: &str,
        table_height: f64,
        laptop_center: (f64, f64),
        human_center: (f64, f64),
        laptop_radius: f64,
        human_radius: f64,
        samples: i64,
        ranges: Option<ArrayIn<'_>>,
    ) -> PyResult<Self> {
        let samples = usize::try_from(samples)
            .map_err(|_| error(Kind::InvalidParameter, format!("samples must be at least 1 point per segment, got {samples}")))?;
        let scene = SceneParams {
            table_height,
            laptop_center: [laptop_center.0, laptop_center.1],
            human_center: [human_center.0, human_center.1],
            laptop_radius,
            human_radius,
            samples,
        };
        let model = robot.model.clone();
        let frame = model.frame_id(frame).py_err()?;
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let n = model.nq();
        let mut set = FeatureSet::from_names(model, frame, &names, &scene).py_err()?;
        if let Some(r) = &ranges {
            set.set_ranges(Some(&*vector("ranges", r, set.len())?)).py_err()?;
        }
        Ok(PyFeatures { set, n })
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
        from_waypoints: i64,
        to_waypoints: i64,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let count = |arg: &str, n: i64| {
            usize::try_from(n).map_err(|_| error(Kind::InvalidParameter, format!("{arg} must be >= 2, got {n}")))
        };
        let (from, to) = (count("from_waypoints", from_waypoints)?, count("to_waypoints", to_waypoints)?);
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
        let (mut phi, mut jac) = (vec![0.0; k], vec![0.0; k * xi.len()]);
        self.set.phi_gradient(&xi, &mut phi, &mut jac).py_err()?;
        Ok((PyArray1::from_vec(py, phi), output(py, jac, &[k, waypoints, self.n])?))
    }

    /// φ of every segment: (N, n) → (N−1, K); row i−1 is segment (q_{i-1}, q_i].
    fn per_segment<'py>(&mut self, py: Python<'py>, xi: ArrayIn<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let (xi, waypoints) = self.trajectory("xi", &xi)?;
        let k = self.set.len();
        let mut out = vec![0.0; (waypoints - 1) * k];
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
