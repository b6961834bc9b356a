//! `phri.Learner`: Algorithm 1, the online learner that owns the plan and the weights.

use std::sync::{Mutex, MutexGuard, TryLockError};

use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadwriteArray1, PyUntypedArrayMethods};
use phri_core::belief::DEFAULT_EFFORT;
use phri_core::learner::{
    History, Interaction, Learner, LearnerParams, ReplanLatency, DEFAULT_TRANSITION_SPEED, MAX_SEEDS, TIME_SLACK,
};
use phri_core::reference::Interpolation;
use pyo3::prelude::*;

use crate::arrays::{vector, ArrayIn};
use crate::deform::PyDeformation;
use crate::errors::{error, IntoPy, Kind};
use crate::features::PyFeatures;
use crate::interaction::PyInteractionDetector;
use crate::ints::count;
use crate::trajopt::{PyTrajectoryOptimizer, PyTrajoptInfo};
use crate::update::{PyUpdateInfo, PyWeightUpdate};

/// Algorithm 1: at every sampled interaction, deform the plan (eq. 7), update the weights (eq. 13)
/// and replan warm-started (eq. 4); `reference(t)` gives the control law its target. The components
/// are copied in, so the objects passed can be reused. `learning=False` is the impedance baseline.
/// After a replan the reference blends into the new plan with joint speeds of at most
/// `transition_speed` × the velocity limits (0: switch at once, as the original did; otherwise in
/// [0.001, 1]).
/// Replans start from the current plan and the optimiser's coarse plans that led to it (see
/// `TrajectoryOptimizer`'s `coarsening`), so a large change of the weights is mostly worked out
/// on the coarse level. `replan_iterations` caps the Newton iterations of an inline replan per
/// `observe` call on each level (0: to convergence at once); an unfinished replan goes on at the
/// next calls from where it stopped (`replan_pending`).
/// `seeds` plans s values of every learned weight between its bounds at construction (s^L plans,
/// at most 64) and starts each replan from whichever of the current plan and the seeds costs least
/// at the new weights.
///
/// `replan_latency` says where replans run and when their plans take effect:
/// - `0.0` (default): inline, inside `observe`, as Algorithm 1 is written.
/// - `L > 0` [s] (at most `duration`): on a worker thread, with a deterministic simulated latency:
///   the plan is adopted at the first `observe` with t ≥ t_push + L, which waits for the worker
///   (GIL released) if it has not finished, so simulations do not depend on the machine's load.
///   With L one tick of a loop that calls `observe` every tick, results are the inline ones.
/// - `None`: on a worker thread, adopted at the first `observe` after it finished (hardware: the
///   wall clock decides); `observe` then never waits.
///
/// `worker_spin` [s]: with a worker, how long it busy-waits for the next push after starting and
/// after each replan before it sleeps (0: it sleeps at once; `math.inf`: never). A sleeping worker
/// is woken by the next push, which takes tens of µs on an idle real-time kernel and up to
/// milliseconds on a loaded or virtual machine; spinning keeps one CPU core busy, so give the
/// worker a core the control loop does not need.
///
/// With a worker, `observe` detects and deforms (microseconds) and hands the correction over: the
/// worker learns from every correction in order (ΔΦ, β̂, the belief, the update), then replans for
/// the newest weights, which `weights` and `belief()` show once taken in (with the plan, at
/// t_push + `replan_latency`; on the wall clock, as soon as learned); a newer push supersedes a
/// replan still running. Adopted plans blend in from the reference at the
/// previous `observe`'s time. `observe(t, ...)` needs t in [0, duration + 0.01] s, never going back
/// (`reset()` starts again). The learner may be shared between threads: `reference` from another
/// thread waits for an `observe` in progress.
#[pyclass(name = "Learner", module = "phri._phri", frozen)]
pub struct PyLearner {
    learner: Mutex<Learner>,
    n: usize,
    /// `observe` may take long (inline replans, or waiting for a simulated latency): it releases
    /// the GIL then. With the wall clock it takes microseconds and keeps it.
    may_wait: bool,
}

/// `Learner.belief()`: the mean (K,) and the covariance (K, K).
type Belief<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

// The signature spells the default out so that Python's introspection shows it.
const _: () = assert!(DEFAULT_TRANSITION_SPEED == 0.8);
const _: () = assert!(DEFAULT_EFFORT == 0.02);

fn replan_iterations_arg(value: &Bound<'_, PyAny>) -> PyResult<usize> {
    count("replan_iterations", value, usize::MAX)
}

fn seeds_arg(value: &Bound<'_, PyAny>) -> PyResult<usize> {
    count("seeds", value, usize::MAX)
}

/// Locks `learner`, taking over a mutex poisoned by a panic (which phri's code does not make).
fn lock(learner: &Mutex<Learner>) -> MutexGuard<'_, Learner> {
    learner.lock().unwrap_or_else(|e| e.into_inner())
}

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

impl PyLearner {
    /// The learner, locked: at once if free, else once another thread's `observe` lets go of it,
    /// waiting with the GIL released (that `observe` may need it back to return).
    pub(crate) fn learner(&self, py: Python<'_>) -> MutexGuard<'_, Learner> {
        loop {
            match self.learner.try_lock() {
                Ok(guard) => return guard,
                Err(TryLockError::Poisoned(e)) => return e.into_inner(),
                Err(TryLockError::WouldBlock) => py.detach(|| drop(lock(&self.learner))),
            }
        }
    }
}

#[pymethods]
impl PyLearner {
    /// `observe` accepts times up to this long after the task's duration [s].
    #[classattr]
    const TIME_SLACK: f64 = TIME_SLACK;

    /// Most seed plans a learner keeps (`seeds` per learned weight, to the power of their number).
    #[classattr]
    const MAX_SEEDS: usize = MAX_SEEDS;

    #[new]
    #[pyo3(signature = (
        features, deformation, update, detector, optimizer, weights, start, goal, *,
        duration = 15.0, sample_period = 0.1, interpolation = "cubic", learning = true,
        transition_speed = 0.8, replan_iterations = 0, seeds = 0, replan_latency = Some(0.0), worker_spin = 0.0,
        effort = DEFAULT_EFFORT, risk = None
    ))]
    // Spelled out: the generated one would show `Some(0.0)` as `...`.
    #[pyo3(text_signature = "(features, deformation, update, detector, optimizer, weights, start, goal, *, \
        duration=15.0, sample_period=0.1, interpolation='cubic', learning=True, transition_speed=0.8, \
        replan_iterations=0, seeds=0, replan_latency=0.0, worker_spin=0.0, effort=0.02, risk=None)")]
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
        #[pyo3(from_py_with = replan_iterations_arg)] replan_iterations: usize,
        #[pyo3(from_py_with = seeds_arg)] seeds: usize,
        replan_latency: Option<f64>,
        worker_spin: f64,
        effort: f64,
        risk: Option<ArrayIn<'_>>,
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
        let replan_latency = replan_latency.map_or(ReplanLatency::WallClock, ReplanLatency::Fixed);
        let risk = match &risk {
            Some(r) => vector("risk", r, set.len())?.into_owned(),
            None => Vec::new(),
        };
        let params = LearnerParams {
            learning,
            sample_period,
            duration,
            interpolation,
            transition_speed,
            replan_iterations,
            seeds,
            replan_latency,
            worker_spin,
            effort,
            risk,
        };
        let (deformation, update, detector, optimizer) =
            (deformation.deformation.clone(), update.update.clone(), detector.detector.clone(), optimizer.optimizer.clone());
        let learner = py
            .detach(|| Learner::new(params, set, deformation, update, detector, optimizer, &weights, &start, &goal))
            .py_err()?;
        Ok(PyLearner { learner: Mutex::new(learner), n, may_wait: replan_latency != ReplanLatency::WallClock })
    }

    /// One tick at time `t` [s] (in [0, duration + 0.01], never going back) with the measured joint
    /// torque of the person [N·m]. Returns (sampled, interacted, replanned): the call fell on a
    /// sample instant; the sample was an interaction; a replan's outcome arrived — inline, the
    /// robot replanned at this push; with a worker (`replan_latency` not 0), a plan requested
    /// earlier was adopted or rejected at this call (`adopted` tells which). Between sample
    /// instants it returns at once (after adopting a finished replan that is due). A refused `t`
    /// or torque leaves the learner as it was; a failed replan worker raises ReplanWorkerError
    /// once, the arm keeping its plan.
    fn observe(&self, py: Python<'_>, t: f64, tau_measured: ArrayIn<'_>) -> PyResult<(bool, bool, bool)> {
        let tau = vector("tau_measured", &tau_measured, self.n)?;
        let obs = if self.may_wait {
            // An inline replan or a simulated latency may take milliseconds: let other threads run.
            py.detach(|| lock(&self.learner).observe(t, &tau))
        } else {
            self.learner(py).observe(t, &tau)
        }
        .py_err()?;
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
        let (q_out, qd_out, qdd_out) =
            (slice_mut("out[0]", &mut q)?, slice_mut("out[1]", &mut qd)?, slice_mut("out[2]", &mut qdd)?);
        self.learner(py).reference(t, q_out, qd_out, qdd_out);
        drop((q, qd, qdd));
        Ok(out)
    }

    /// Back to t = 0 with the initial plan and weights and an empty history (the initial plan
    /// only), as constructed; a replan under way is cancelled. Seed plans are kept.
    fn reset(&self, py: Python<'_>) {
        self.learner(py).reset();
    }

    /// Current cost weights w.
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.learner(py).weights())
    }

    /// The belief over the cost weights: (mean (K,), covariance (K, K) [weight²]). The mean is the
    /// estimate `weights` (the paper's MAP, eq. 13); the covariance is the Laplace posterior's of
    /// the paper's observation model (eq. 8-11) with its normaliser kept to second order: the prior
    /// diag(step) on the learned weights, shrunk by S Sᵀ/(2·effort) at every push with S = ∂ΔΦ/∂u_H.
    /// Weights that are not learned have no variance.
    fn belief<'py>(&self, py: Python<'py>) -> PyResult<Belief<'py>> {
        let learner = self.learner(py);
        let (mean, covariance) = learner.belief();
        let k = mean.len();
        Ok((PyArray1::from_slice(py, mean), PyArray1::from_slice(py, covariance).reshape([k, k])?))
    }

    /// The cost weights the planner plans with: `weights`, or with `risk` the risk-aware
    /// w + risk ⊙ σ clipped to the bounds (σ the belief's standard deviations).
    #[getter]
    fn plan_weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.learner(py).plan_weights())
    }

    /// Effort weight λ of the observation model (eq. 8) [1/(N·m)²], for the belief's covariance.
    #[getter]
    fn effort(&self, py: Python<'_>) -> f64 {
        self.learner(py).params().effort
    }

    /// Current plan ξ_R, (N, n) [rad].
    #[getter]
    fn plan<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let learner = self.learner(py);
        let plan = learner.plan();
        PyArray1::from_slice(py, plan.waypoints()).reshape([plan.len(), self.n])
    }

    /// Whether a replan is under way: inline, one cut short by `replan_iterations` is still
    /// converging; with a worker, one was requested and not yet adopted or rejected.
    #[getter]
    fn replan_pending(&self, py: Python<'_>) -> bool {
        self.learner(py).replan_pending()
    }

    /// Time [s] of the push whose replan is under way (requested, not yet adopted or rejected), or
    /// None: a watchdog compares it with the clock to see a stalled worker.
    #[getter]
    fn replan_running_since(&self, py: Python<'_>) -> Option<f64> {
        self.learner(py).replan_running_since()
    }

    /// Requested replans that a newer push superseded before they were adopted (since construction
    /// or `reset()`).
    #[getter]
    fn superseded_replans(&self, py: Python<'_>) -> u64 {
        self.learner(py).superseded_replans()
    }

    /// Whether the optimiser converged for the last plan adopted from a replan (None: none yet).
    #[getter]
    fn last_replan_converged(&self, py: Python<'_>) -> Option<bool> {
        self.learner(py).last_replan_converged()
    }

    /// Whether the last `observe` adopted a new plan (it blends in from that call on).
    #[getter]
    fn adopted(&self, py: Python<'_>) -> bool {
        self.learner(py).last_observation().adopted
    }

    /// Where replans run: 0.0 inline, L > 0 [s] a worker with that simulated latency, None a
    /// worker adopting as soon as it is done (wall clock).
    #[getter]
    fn replan_latency(&self, py: Python<'_>) -> Option<f64> {
        match self.learner(py).params().replan_latency {
            ReplanLatency::Fixed(latency) => Some(latency),
            ReplanLatency::WallClock => None,
        }
    }

    /// Whether the learner learns (False: the impedance baseline).
    #[getter]
    fn learning(&self, py: Python<'_>) -> bool {
        self.learner(py).params().learning
    }

    /// Testing only (fault injection): the replan worker's next replan first stalls for `seconds`
    /// [s] (at most 60). Needs a worker (`replan_latency` not 0).
    fn _debug_stall_worker(&self, py: Python<'_>, seconds: f64) -> PyResult<()> {
        self.learner(py).debug_stall_worker(seconds).py_err()
    }

    /// Testing only (fault injection): the replan worker's next replan panics; the next `observe`
    /// after it raises ReplanWorkerError. Needs a worker (`replan_latency` not 0).
    fn _debug_panic_worker(&self, py: Python<'_>) -> PyResult<()> {
        self.learner(py).debug_panic_worker().py_err()
    }

    /// What the learner recorded so far: every sampled interaction and every plan, as arrays.
    fn history(&self, py: Python<'_>) -> PyResult<PyLearnerHistory> {
        let learner = self.learner(py);
        PyLearnerHistory::new(py, learner.history(), self.n, learner.weights().len())
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let learner = self.learner(py);
        format!("Learner(learning={}, weights={:?})", learner.params().learning, learner.weights())
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
/// feasible plan) [s], and `rejected` (R,) why, naming the violated pair. `beta` and `explained`
/// (M,) how well the learned features explained each push (`phri.rationality`) and `covariance`
/// (M, K, K) the belief's covariance after it, NaN where no deformation was made.
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
    /// (M,) each push's rationality β̂ (`phri.rationality`); NaN where no deformation was made.
    beta: Py<PyArray1<f64>>,
    /// (M,) the fraction of each push's squared torque the learned features explain; NaN where none.
    explained: Py<PyArray1<f64>>,
    /// (M, K, K) the belief's covariance after each push [weight²]; NaN where no deformation was made.
    covariance: Py<PyArray3<f64>>,
}

impl PyLearnerHistory {
    fn new(py: Python<'_>, history: &History, n: usize, k: usize) -> PyResult<Self> {
        let records = &history.interactions;
        let m = records.len();
        // Only ΔΦ and the covariance may be missing from a record (no deformation was made): NaN
        // marks them there.
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
            beta: PyArray1::from_iter(py, records.iter().map(|r| r.rationality.map_or(f64::NAN, |b| b.beta))).unbind(),
            explained: PyArray1::from_iter(py, records.iter().map(|r| r.rationality.map_or(f64::NAN, |b| b.explained))).unbind(),
            covariance: rows(k * k, &|r| &r.covariance, true)?.bind(py).reshape([m, k, k])?.unbind(),
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
