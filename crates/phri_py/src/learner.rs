//! `phri.Learner`: Algorithm 1, the online learner that owns the plan and the weights.

use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadwriteArray1, PyUntypedArrayMethods};
use phri_core::learner::{History, Interaction, Learner, LearnerParams, DEFAULT_TRANSITION_SPEED};
use phri_core::reference::Interpolation;
use pyo3::prelude::*;

use crate::arrays::{vector, ArrayIn};
use crate::deform::PyDeformation;
use crate::errors::{error, IntoPy, Kind};
use crate::features::PyFeatures;
use crate::interaction::PyInteractionDetector;
use crate::trajopt::{PyTrajectoryOptimizer, PyTrajoptInfo};
use crate::update::{PyUpdateInfo, PyWeightUpdate};

/// Algorithm 1: at every sampled interaction, deform the plan (eq. 7), update the weights (eq. 13)
/// and replan warm-started (eq. 4); `reference(t)` gives the control law its target. The components
/// are copied in, so the objects passed can be reused. `learning=False` is the impedance baseline.
/// After a replan the reference blends into the new plan with joint speeds of at most
/// `transition_speed` × the velocity limits (0: switch at once, as the original did).
/// Replans start from the current plan and the optimiser's coarse plans that led to it (see
/// `TrajectoryOptimizer`'s `coarsening`), so a large change of the weights is mostly worked out
/// on the coarse level. `replan_iterations` caps the Newton iterations of a replan per `observe`
/// call on each level (0: to convergence at once); an unfinished replan goes on at the next calls
/// from where it stopped (`replan_pending`).
/// `seeds` plans s values of every learned weight between its bounds at construction (s^L plans,
/// at most 64) and starts each replan from the better of the current plan and the nearest seed.
#[pyclass(name = "Learner", module = "phri._phri")]
pub struct PyLearner {
    learner: Learner,
    n: usize,
}

// The signature spells the default out so that Python's introspection shows it.
const _: () = assert!(DEFAULT_TRANSITION_SPEED == 0.8);

/// `a` as an exclusive view for writing n values: C-contiguous, writable, not aliasing another.
fn writable<'py>(arg: &str, a: &Bound<'py, PyArray1<f64>>, n: usize) -> PyResult<PyReadwriteArray1<'py, f64>> {
    if a.len() != n || !a.is_c_contiguous() {
        return Err(error(Kind::Shape, format!("{arg} must be a C-contiguous float64 array of shape ({n},)")));
    }
    a.try_readwrite()
        .map_err(|e| error(Kind::InvalidParameter, format!("{arg} must be a writable array distinct from the others ({e})")))
}

fn slice_mut<'a>(arg: &str, a: &'a mut PyReadwriteArray1<'_, f64>) -> PyResult<&'a mut [f64]> {
    a.as_slice_mut().map_err(|_| error(Kind::Shape, format!("{arg} must be C-contiguous")))
}

/// `out` as three float64 arrays, or a ShapeError naming the one that is not.
fn buffers<'py>(out: &Bound<'py, PyAny>) -> PyResult<Triple<'py>> {
    let items: Vec<Bound<'py, PyAny>> = match out.extract() {
        Ok(items) if !out.is_instance_of::<pyo3::types::PyString>() => items,
        _ => return Err(error(Kind::Shape, "out must be a tuple of three float64 arrays (q, qd, qdd)")),
    };
    if items.len() != 3 {
        return Err(error(Kind::Shape, format!("out must hold three arrays (q, qd, qdd), got {}", items.len())));
    }
    let array = |i: usize| {
        items[i]
            .cast::<PyArray1<f64>>()
            .cloned()
            .map_err(|_| error(Kind::Shape, format!("out[{i}] must be a one-dimensional float64 numpy array")))
    };
    Ok((array(0)?, array(1)?, array(2)?))
}

type Triple<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

#[pymethods]
impl PyLearner {
    #[new]
    #[pyo3(signature = (
        features, deformation, update, detector, optimizer, weights, start, goal, *,
        duration = 15.0, sample_period = 0.1, interpolation = "cubic", learning = true,
        transition_speed = 0.8, replan_iterations = 0, seeds = 0
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        features: PyRef<'_, PyFeatures>,
        deformation: PyRef<'_, PyDeformation>,
        update: PyRef<'_, PyWeightUpdate>,
        detector: PyRef<'_, PyInteractionDetector>,
        optimizer: PyRef<'_, PyTrajectoryOptimizer>,
        weights: ArrayIn<'_>,
        start: ArrayIn<'_>,
        goal: ArrayIn<'_>,
        duration: f64,
        sample_period: f64,
        interpolation: &str,
        learning: bool,
        transition_speed: f64,
        replan_iterations: usize,
        seeds: usize,
    ) -> PyResult<Self> {
        let interpolation = match interpolation {
            "cubic" => Interpolation::Cubic,
            "linear" => Interpolation::Linear,
            other => {
                return Err(error(Kind::InvalidParameter, format!("interpolation must be 'cubic' or 'linear', got '{other}'")))
            }
        };
        let set = features.set.clone();
        let n = set.model().nq();
        let weights = vector("weights", &weights, set.len())?.into_owned();
        let start = vector("start", &start, n)?.into_owned();
        let goal = vector("goal", &goal, n)?.into_owned();
        let params =
            LearnerParams { learning, sample_period, duration, interpolation, transition_speed, replan_iterations, seeds };
        let (deformation, update, detector, optimizer) =
            (deformation.deformation.clone(), update.update.clone(), detector.detector.clone(), optimizer.optimizer.clone());
        let learner = py
            .detach(|| Learner::new(params, set, deformation, update, detector, optimizer, &weights, &start, &goal))
            .py_err()?;
        Ok(PyLearner { learner, n })
    }

    /// One tick at time `t` [s] with the measured joint torque of the person [N·m]. Returns
    /// (sampled, interacted, replanned). Between sample instants it returns at once.
    fn observe(&mut self, py: Python<'_>, t: f64, tau_measured: ArrayIn<'_>) -> PyResult<(bool, bool, bool)> {
        let tau = vector("tau_measured", &tau_measured, self.n)?;
        let learner = &mut self.learner;
        // Replanning takes a millisecond or more: let other Python threads run meanwhile.
        let obs = py.detach(|| learner.observe(t, &tau)).py_err()?;
        Ok((obs.sampled, obs.interacted, obs.replanned))
    }

    /// The reference (q_R [rad], q̇_R [rad/s], q̈_R [rad/s²]) at time `t` [s]. With `out=(q, qd,
    /// qdd)`, three writable float64 arrays of shape (n,), it writes into them and returns them, so
    /// a 1 kHz loop allocates nothing per tick.
    #[pyo3(signature = (t, *, out = None))]
    fn reference<'py>(&self, py: Python<'py>, t: f64, out: Option<Bound<'py, PyAny>>) -> PyResult<Triple<'py>> {
        if !t.is_finite() {
            return Err(error(Kind::NonFinite, format!("t must be finite, got {t}")));
        }
        let out = match out {
            Some(out) => buffers(&out)?,
            None => (PyArray1::zeros(py, self.n, false), PyArray1::zeros(py, self.n, false), PyArray1::zeros(py, self.n, false)),
        };
        let (mut q, mut qd, mut qdd) =
            (writable("out[0]", &out.0, self.n)?, writable("out[1]", &out.1, self.n)?, writable("out[2]", &out.2, self.n)?);
        self.learner.reference(t, slice_mut("out[0]", &mut q)?, slice_mut("out[1]", &mut qd)?, slice_mut("out[2]", &mut qdd)?);
        drop((q, qd, qdd));
        Ok(out)
    }

    /// Current cost weights w.
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.learner.weights())
    }

    /// Current plan ξ_R, (N, n).
    #[getter]
    fn plan<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let plan = self.learner.plan();
        PyArray1::from_slice(py, plan.waypoints()).reshape([plan.len(), self.n])
    }

    /// Whether a replan cut short by `replan_iterations` is still converging.
    #[getter]
    fn replan_pending(&self) -> bool {
        self.learner.replan_pending()
    }

    /// Whether the learner learns (False: the impedance baseline).
    #[getter]
    fn learning(&self) -> bool {
        self.learner.params().learning
    }

    /// What the learner recorded so far: every sampled interaction and every plan, as arrays.
    fn history(&self, py: Python<'_>) -> PyResult<PyLearnerHistory> {
        PyLearnerHistory::new(py, self.learner.history(), self.n, self.learner.weights().len())
    }

    fn __repr__(&self) -> String {
        format!("Learner(learning={}, weights={:?})", self.learner.params().learning, self.learner.weights())
    }
}

/// A learner's record, as arrays with one row per sampled interaction (M) or per plan (P).
///
/// `t` (M,) the interaction's time [s]; `u_h` (M, n) the thresholded interaction torque u_H [N·m];
/// `delta_phi` (M, K) Φ(ξ_H) − Φ(ξ_R), NaN where no deformation was made (`moved` = 0: not learning,
/// or too close to the end); `weights` (M, K) the cost weights after the update; `moved` (M,) the
/// waypoints the deformation moved; `updates` and `replans` (M,) what the update and the replan did
/// (None where there was none). `plan_t` (P,) the time each plan took effect [s] and `plans`
/// (P, N, n) the plans [rad]; the first is the initial plan at t = 0. `rejected_t` (R,) the times of
/// replans that were not adopted because they were infeasible (the robot kept tracking its last
/// feasible plan) [s], and `rejected` (R,) why, naming the violated pair.
#[pyclass(name = "LearnerHistory", module = "phri._phri", frozen, get_all)]
pub struct PyLearnerHistory {
    /// (M,) each sampled interaction's time [s].
    t: Py<PyArray1<f64>>,
    /// (M, n) the thresholded interaction torque u_H [N·m].
    u_h: Py<PyArray2<f64>>,
    /// (M, K) Φ(ξ_H) − Φ(ξ_R); NaN where no deformation was made (`moved` = 0).
    delta_phi: Py<PyArray2<f64>>,
    /// (M, K) the cost weights after each update.
    weights: Py<PyArray2<f64>>,
    /// (M,) how many waypoints each deformation moved (0: none).
    moved: Py<PyArray1<usize>>,
    /// (M,) what each weight update did (None where there was none).
    updates: Vec<Option<PyUpdateInfo>>,
    /// (M,) what each replan did (None where there was none).
    replans: Vec<Option<PyTrajoptInfo>>,
    /// (P,) the time each plan took effect [s]; the first is the initial plan's, 0.
    plan_t: Py<PyArray1<f64>>,
    /// (P, N, n) the plans [rad], the initial one first.
    plans: Py<PyArray3<f64>>,
    /// (R,) the times of replans that were not adopted because they were infeasible [s].
    rejected_t: Py<PyArray1<f64>>,
    /// (R,) why each of those replans was rejected, naming the violated pair.
    rejected: Vec<String>,
}

impl PyLearnerHistory {
    fn new(py: Python<'_>, history: &History, n: usize, k: usize) -> PyResult<Self> {
        let records = &history.interactions;
        let m = records.len();
        // Only ΔΦ may be missing from a record (no deformation was made): NaN marks it there.
        let rows = |width: usize, row: &dyn Fn(&Interaction) -> &[f64], may_be_empty: bool| -> PyResult<Py<PyArray2<f64>>> {
            let mut values = Vec::with_capacity(m * width);
            for r in records {
                match row(r) {
                    v if v.len() == width => values.extend_from_slice(v),
                    v if v.is_empty() && may_be_empty => values.extend(std::iter::repeat_n(f64::NAN, width)),
                    v => {
                        return Err(error(
                            Kind::Shape,
                            format!("a history record has {} values where {width} were expected", v.len()),
                        ))
                    }
                }
            }
            Ok(PyArray1::from_vec(py, values).reshape([m, width])?.unbind())
        };
        let plans = &history.plans;
        let waypoints = plans.first().map_or(0, |(_, w)| w.len() / n);
        let plan_values: Vec<f64> = plans.iter().flat_map(|(_, w)| w.iter().copied()).collect();
        Ok(PyLearnerHistory {
            t: PyArray1::from_iter(py, records.iter().map(|r| r.t)).unbind(),
            u_h: rows(n, &|r| &r.u_h, false)?,
            delta_phi: rows(k, &|r| &r.delta_phi, true)?,
            weights: rows(k, &|r| &r.weights, false)?,
            moved: PyArray1::from_iter(py, records.iter().map(|r| r.moved)).unbind(),
            updates: records.iter().map(|r| r.update.map(PyUpdateInfo::from)).collect(),
            replans: records.iter().map(|r| r.replan.map(PyTrajoptInfo::from)).collect(),
            plan_t: PyArray1::from_iter(py, plans.iter().map(|(t, _)| *t)).unbind(),
            plans: PyArray1::from_vec(py, plan_values).reshape([plans.len(), waypoints, n])?.unbind(),
            rejected_t: PyArray1::from_iter(py, history.rejected.iter().map(|r| r.t)).unbind(),
            rejected: history.rejected.iter().map(|r| r.reason.clone()).collect(),
        })
    }
}

#[pymethods]
impl PyLearnerHistory {
    fn __len__(&self) -> usize {
        self.updates.len()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!("LearnerHistory(interactions={}, plans={})", self.updates.len(), self.plan_t.bind(py).len())
    }
}
