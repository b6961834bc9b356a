//! `phri.Learner`: Algorithm 1, the online learner that owns the plan and the weights.

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use phri_core::learner::{Learner, LearnerParams, DEFAULT_TRANSITION_SPEED};
use phri_core::reference::Interpolation;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

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

    /// The reference (q_R [rad], q̇_R [rad/s], q̈_R [rad/s²]) at time `t` [s].
    fn reference<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Triple<'py>> {
        if !t.is_finite() {
            return Err(error(Kind::NonFinite, format!("t must be finite, got {t}")));
        }
        let (mut q, mut qd, mut qdd) = (vec![0.0; self.n], vec![0.0; self.n], vec![0.0; self.n]);
        self.learner.reference(t, &mut q, &mut qd, &mut qdd);
        Ok((PyArray1::from_vec(py, q), PyArray1::from_vec(py, qd), PyArray1::from_vec(py, qdd)))
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

    /// Every recorded interaction, as dicts with keys t, u_h, delta_phi, weights, moved, update, replan.
    fn interactions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for i in &self.learner.history().interactions {
            let d = PyDict::new(py);
            d.set_item("t", i.t)?;
            d.set_item("u_h", PyArray1::from_slice(py, &i.u_h))?;
            d.set_item("delta_phi", PyArray1::from_slice(py, &i.delta_phi))?;
            d.set_item("weights", PyArray1::from_slice(py, &i.weights))?;
            d.set_item("moved", i.moved)?;
            d.set_item("update", i.update.map(PyUpdateInfo::from))?;
            d.set_item("replan", i.replan.map(PyTrajoptInfo::from))?;
            list.append(d)?;
        }
        Ok(list)
    }

    /// Every plan with the time it took effect [s]: a list of (t, plan (N, n)); the first is the
    /// initial plan at t = 0.
    fn plans<'py>(&self, py: Python<'py>) -> PyResult<Vec<(f64, Bound<'py, PyArray2<f64>>)>> {
        self.learner
            .history()
            .plans
            .iter()
            .map(|(t, w)| Ok((*t, PyArray1::from_slice(py, w).reshape([w.len() / self.n, self.n])?)))
            .collect()
    }

    fn __repr__(&self) -> String {
        format!("Learner(learning={}, weights={:?})", self.learner.params().learning, self.learner.weights())
    }
}
