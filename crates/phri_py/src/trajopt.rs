//! `phri.TrajectoryOptimizer`: eq. 4, ξ_R = argmin w·Φ(ξ), released from the GIL while it runs.

use std::sync::Arc;
use std::time::Duration;

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use phri_core::collision::{CollisionChecker, SELF_MARGIN};
use phri_core::features::FeatureSet;
use phri_core::trajopt::{
    Clearance, CollisionParams, KinematicCurvature, PlanLevels, TrajectoryOptimizer, TrajoptInfo, TrajoptParams,
    CLEARANCE_TOLERANCE, DEFAULT_COLLISION_BUFFER, DEFAULT_COLLISION_SAMPLES, DEFAULT_COLLISION_WEIGHT, MAX_COLLISION_SAMPLES,
    MAX_ITERATIONS, MAX_TIME, MAX_WAYPOINTS, STEP_TOLERANCE,
};

// The signature spells the core's defaults out (so that Python's help shows numbers): they must agree.
const _: () = assert!(DEFAULT_COLLISION_WEIGHT == 1e4 && DEFAULT_COLLISION_BUFFER == 0.006 && DEFAULT_COLLISION_SAMPLES == 4);
use phri_core::{PhriError, RobotModel};
use pyo3::prelude::*;

use crate::arrays::{matrix, vector, ArrayIn};
use crate::errors::{error, to_py, IntoPy, Kind};
use crate::features::PyFeatures;
use crate::ints::{bounded, int, optional_int};

/// What a solve did (the core's `TrajoptInfo`, read-only).
#[pyclass(name = "TrajoptInfo", module = "phri._phri", frozen)]
#[derive(Clone)]
pub struct PyTrajoptInfo(pub TrajoptInfo);

impl From<TrajoptInfo> for PyTrajoptInfo {
    fn from(info: TrajoptInfo) -> Self {
        PyTrajoptInfo(info)
    }
}

#[pymethods]
impl PyTrajoptInfo {
    /// Newton iterations on the plan's waypoints [count].
    #[getter]
    fn iterations(&self) -> usize {
        self.0.iterations
    }

    /// Newton iterations on the coarse levels, all together (0 without multiresolution) [count].
    #[getter]
    fn coarse_iterations(&self) -> usize {
        self.0.coarse_iterations
    }

    /// Cost evaluations on the plan's waypoints, each one Φ, ∇Φ and ∇²Φ [count].
    #[getter]
    fn evaluations(&self) -> usize {
        self.0.evaluations
    }

    /// Final cost w·Φ + penalty of the plan [cost].
    #[getter]
    fn cost(&self) -> f64 {
        self.0.cost
    }

    /// Final penalty part of the cost (clearance, max_step and collisions) [cost].
    #[getter]
    fn penalty(&self) -> f64 {
        self.0.penalty
    }

    /// Largest violation of a clearance or a collision margin along the plan's executed curve [m]
    /// (0 when all are kept or none is set).
    #[getter]
    fn max_violation(&self) -> f64 {
        self.0.max_violation
    }

    /// Largest joint move per segment of the executed curve (the cubic's speed times the waypoint
    /// spacing) beyond `max_step` [rad] (0 without max_step); much more than the penalty's give,
    /// gradient/(2·step_weight), means the goal is too far for the duration.
    #[getter]
    fn max_step_excess(&self) -> f64 {
        self.0.max_step_excess
    }

    /// The largest such excess as a fraction of its joint's max_step [1]: above STEP_TOLERANCE the
    /// plan is infeasible.
    #[getter]
    fn step_excess_ratio(&self) -> f64 {
        self.0.step_excess_ratio
    }

    /// Whether the plan keeps every clearance and collision margin within CLEARANCE_TOLERANCE [m]
    /// and every joint within `max_step` by STEP_TOLERANCE [1] along its executed curve (whether
    /// or not the solve converged). An infeasible plan is not safe to execute.
    #[getter]
    fn feasible(&self) -> bool {
        self.0.feasible
    }

    /// Whether the solve met a tolerance (rather than an iteration or time cap).
    #[getter]
    fn converged(&self) -> bool {
        self.0.converged
    }

    /// Wall time of the solve [s].
    #[getter]
    fn seconds(&self) -> f64 {
        self.0.seconds
    }

    fn __repr__(&self) -> String {
        let i = &self.0;
        let py_bool = |b: bool| if b { "True" } else { "False" };
        format!(
            "TrajoptInfo(iterations={}, coarse_iterations={}, evaluations={}, cost={:.6}, penalty={:.3e}, max_violation={:.3e}, max_step_excess={:.3e}, feasible={}, converged={}, seconds={:.3e})",
            i.iterations,
            i.coarse_iterations,
            i.evaluations,
            i.cost,
            i.penalty,
            i.max_violation,
            i.max_step_excess,
            py_bool(i.feasible),
            py_bool(i.converged),
            i.seconds
        )
    }
}

/// Trajectory optimisation over `waypoints` rows (3 to `MAX_WAYPOINTS` = 10,000: memory and time
/// grow with them) with fixed start and goal and the joint limits as bounds, safe by default:
/// - Speed limits: `max_step` [rad] bounds each joint's move between waypoints. Without it, with
///   `speed_limits` (the default) it is `speed_fraction` × the robot's velocity limits × the
///   waypoint spacing `duration`/(waypoints − 1), so `duration` [s] (how long the plan is
///   executed) is needed; `speed_limits=False` plans without speed limits.
/// - Collisions: with `collisions` (the default) every collision body of the features' robot
///   (`Robot.collision_bodies`, the carried cup included) keeps each object's margin from the
///   features' `scene`, and, with `self_collision`, `SELF_MARGIN` from the bodies it can meet
///   (pairs in contact in every pose are left out: `excluded_pairs`), along the executed cubic
///   between waypoints. A quadratic penalty `collision_weight` [cost per m²] aims at each margin
///   plus `collision_buffer` [m] at `collision_samples` points per segment. A robot without a
///   complete collision model is a PlanningError; `collisions=False` plans without the checks.
/// - `clearance` = [(frame, min_z [m]), ...] keeps frame origins above a height.
///
/// The penalties are quadratic (weights `clearance_weight`, `step_weight`, `collision_weight`);
/// a solve's `TrajoptInfo.feasible` says whether its plan keeps them all (within
/// `CLEARANCE_TOLERANCE` [m] and `STEP_TOLERANCE` [1]) and `closest_pair` which pair came
/// nearest. The solver is projected Newton on the block-tridiagonal Hessian.
/// `kinematic_curvature` says how the Newton model treats the second derivatives of the
/// kinematics of the table, coffee and origin features and the clearance: "gauss-newton" leaves
/// them out, "exact" includes them, "settled" (the default) leaves them out until the model's
/// active set settles and includes them from then on. `coarsening` (default 3; 0 or 1 for none)
/// solves first on coarser copies of the problem with about 1/`coarsening` of the segments each,
/// down to `coarsest` waypoints (multiresolution: a cold plan starts from the coarse plan; see
/// `phri_core::trajopt`). `knots` = K plans as the original system did: every plan is piecewise
/// linear in joint space through K knots evenly spaced in time (K ≥ 3, every knot on a waypoint:
/// K − 1 divides waypoints − 1), found by optimising the features and penalties at the knots
/// (trajopt on 4 waypoints, upsampled to 31; the collision penalty along the chords between them,
/// `collision_samples` per waypoint segment, at most 64 per chord; the clearance at the knots
/// only), and checked for feasibility as sampled at the waypoints, as executed; `objective` is then
/// the knot problem's at a trajectory's knots, and a warm start `init` is read at the knots' times.
/// None or 0 (the default) optimises every waypoint.
#[pyclass(name = "TrajectoryOptimizer", module = "phri._phri")]
pub struct PyTrajectoryOptimizer {
    pub(crate) optimizer: TrajectoryOptimizer,
    pub(crate) features: FeatureSet,
}

impl PyTrajectoryOptimizer {
    /// The checked, owned (weights, start, goal) of a solve (owned: the solve runs without the GIL).
    fn problem(
        &self,
        weights: &ArrayIn<'_>,
        start: &ArrayIn<'_>,
        goal: &ArrayIn<'_>,
    ) -> PyResult<(Vec<f64>, Vec<f64>, Vec<f64>)> {
        let n = self.features.model().nq();
        Ok((
            vector("weights", weights, self.features.len())?.into_owned(),
            vector("start", start, n)?.into_owned(),
            vector("goal", goal, n)?.into_owned(),
        ))
    }
}

/// Largest `speed_fraction` [1]: the executed cubic runs up to 1 + STEP_TOLERANCE times faster
/// than the chords the step penalty holds, so this keeps it within the velocity limits.
fn max_speed_fraction() -> f64 {
    1.0 / (1.0 + STEP_TOLERANCE)
}

/// The per-joint step limit [rad]: `max_step` as given, or from the velocity limits and `duration`
/// (see the class docs); empty for none.
fn step_limits(
    model: &RobotModel,
    waypoints: usize,
    max_step: Option<&ArrayIn<'_>>,
    duration: Option<f64>,
    speed_fraction: f64,
    speed_limits: bool,
) -> PyResult<Vec<f64>> {
    let invalid = |m: String| Err(error(Kind::InvalidParameter, m));
    if let Some(d) = duration {
        phri_core::reference::check_duration(d, waypoints).py_err()?;
    }
    let top = max_speed_fraction();
    if !(speed_fraction > 0.0 && speed_fraction <= top) {
        return invalid(format!(
            "speed_fraction must be in (0, {top}] (above it the executed cubic can exceed the velocity limits), got {speed_fraction}"
        ));
    }
    match (max_step, duration, speed_limits) {
        (Some(_), Some(_), _) => invalid(
            "duration and max_step: give one (duration sets max_step from the velocity limits), not both".into(),
        ),
        (Some(_), None, false) => invalid("max_step is a speed limit: with speed_limits=False leave it out".into()),
        (Some(a), None, true) => Ok(vector("max_step", a, model.nq())?.into_owned()),
        (None, Some(d), true) => {
            let spacing = d / (waypoints.max(2) - 1) as f64;
            Ok(model.velocity_limits().iter().map(|v| speed_fraction * v * spacing).collect())
        }
        (None, None, true) => invalid(
            "duration: the plan's duration [s] is needed to keep the joints within their velocity limits; \
             pass duration= (e.g. task.duration), or max_step= [rad per waypoint], or speed_limits=False to plan without speed limits"
                .into(),
        ),
        (None, _, false) => Ok(Vec::new()),
    }
}

/// The collision checks for `features` (their robot against their scene), or None without.
fn collision_params(
    features: &PyFeatures,
    collisions: bool,
    self_collision: bool,
    weight: f64,
    buffer: f64,
    samples: usize,
) -> PyResult<Option<CollisionParams>> {
    if !collisions {
        return Ok(None);
    }
    let model = features.set.model();
    let scene = &features.scene.get().scene;
    let checker = CollisionChecker::new(model, scene, self_collision.then_some(SELF_MARGIN)).map_err(|e| match e {
        PhriError::Planning { reason } => {
            error(Kind::Planning, format!("collisions: {reason}; or pass collisions=False to plan without collision checks"))
        }
        other => to_py(other),
    })?;
    Ok(Some(CollisionParams { weight, buffer, samples, ..CollisionParams::new(Arc::new(checker)) }))
}

#[pymethods]
impl PyTrajectoryOptimizer {
    #[new]
    #[pyo3(signature = (
        features, waypoints = 31, *, duration = None, speed_fraction = 0.5, speed_limits = true,
        collisions = true, self_collision = true, collision_weight = 1e4,
        collision_buffer = 0.006, collision_samples = 4, clearance = None, clearance_weight = 1e3, max_iterations = 500,
        max_time = None, gradient_tolerance = 1e-6, relative_tolerance = 1e-9, smoothing = 0.05,
        max_step = None, step_weight = 1e3, kinematic_curvature = "settled", coarsening = 3, coarsest = 8,
        knots = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        features: PyRef<'_, PyFeatures>,
        #[pyo3(from_py_with = int)] waypoints: i128,
        duration: Option<f64>,
        speed_fraction: f64,
        speed_limits: bool,
        collisions: bool,
        self_collision: bool,
        collision_weight: f64,
        collision_buffer: f64,
        #[pyo3(from_py_with = int)] collision_samples: i128,
        clearance: Option<Vec<(String, f64)>>,
        clearance_weight: f64,
        #[pyo3(from_py_with = int)] max_iterations: i128,
        max_time: Option<f64>,
        gradient_tolerance: f64,
        relative_tolerance: f64,
        smoothing: f64,
        max_step: Option<ArrayIn<'_>>,
        step_weight: f64,
        kinematic_curvature: &str,
        #[pyo3(from_py_with = int)] coarsening: i128,
        #[pyo3(from_py_with = int)] coarsest: i128,
        #[pyo3(from_py_with = optional_int)] knots: Option<i128>,
    ) -> PyResult<Self> {
        let waypoints = bounded("waypoints", waypoints, 3..=MAX_WAYPOINTS, "(start, at least one free waypoint, goal)")?;
        let max_iterations = bounded("max_iterations", max_iterations, 1..=MAX_ITERATIONS, "Newton iterations")?;
        let coarsening = bounded("coarsening", coarsening, 0..=MAX_WAYPOINTS, "(segments per coarse segment; 0 or 1 for none)")?;
        let coarsest = bounded("coarsest", coarsest, 3..=MAX_WAYPOINTS, "waypoints")?;
        // 0 or None: every waypoint; the core checks the rest (a knot on every waypoint it names).
        let knots = match knots {
            None => 0,
            Some(k) => bounded("knots", k, 0..=MAX_WAYPOINTS, "(0 or None: plan every waypoint)")?,
        };
        let collision_samples = bounded("collision_samples", collision_samples, 1..=MAX_COLLISION_SAMPLES, "points per segment")?;
        let set = features.set.clone();
        let model = set.model().clone();
        let clearance = clearance
            .unwrap_or_default()
            .into_iter()
            .map(|(frame, min_z)| Ok(Clearance { frame: model.frame_id(&frame).py_err()?, min_z, weight: clearance_weight }))
            .collect::<PyResult<Vec<_>>>()?;
        let max_time = match max_time {
            None => None,
            Some(s) if s > 0.0 && s <= MAX_TIME => Some(Duration::from_secs_f64(s)),
            Some(s) => return Err(error(Kind::InvalidParameter, format!("max_time must be in (0, {MAX_TIME}] s, got {s}"))),
        };
        let max_step = step_limits(&model, waypoints, max_step.as_ref(), duration, speed_fraction, speed_limits)?;
        let kinematic_curvature = match kinematic_curvature {
            "gauss-newton" => KinematicCurvature::GaussNewton,
            "settled" => KinematicCurvature::Settled,
            "exact" => KinematicCurvature::Exact,
            other => {
                return Err(error(
                    Kind::InvalidParameter,
                    format!("kinematic_curvature must be 'gauss-newton', 'settled' or 'exact', got {other:?}"),
                ));
            }
        };
        let collision =
            collision_params(&features, collisions, self_collision, collision_weight, collision_buffer, collision_samples)?;
        let params = TrajoptParams {
            max_iterations,
            max_time,
            gradient_tolerance,
            relative_tolerance,
            smoothing,
            clearance,
            max_step,
            step_weight,
            collision,
            kinematic_curvature,
            coarsening,
            coarsest,
            knots,
        };
        let optimizer = TrajectoryOptimizer::new(&set, waypoints, params).py_err()?;
        Ok(PyTrajectoryOptimizer { optimizer, features: set })
    }

    /// A plan is feasible when no margin or clearance is violated by more than this along its
    /// executed curve [m].
    #[classattr]
    const CLEARANCE_TOLERANCE: f64 = CLEARANCE_TOLERANCE;

    /// ... and no joint moves faster along the executed cubic than its `max_step` allows by more
    /// than this fraction [1].
    #[classattr]
    const STEP_TOLERANCE: f64 = STEP_TOLERANCE;

    /// Most `waypoints` of a plan: what a plan costs in memory and time grows with them.
    #[classattr]
    const MAX_WAYPOINTS: usize = MAX_WAYPOINTS;

    /// Most `max_iterations` (Newton iterations per level).
    #[classattr]
    const MAX_ITERATIONS: usize = MAX_ITERATIONS;

    /// Longest `max_time` [s].
    #[classattr]
    const MAX_TIME: f64 = MAX_TIME;

    /// Clearance kept between two collision bodies of the robot with `self_collision` [m].
    #[classattr]
    const SELF_MARGIN: f64 = SELF_MARGIN;

    /// The per-joint step limit between consecutive waypoints the plans keep [rad] (given as
    /// `max_step` or set from `duration`), or None without speed limits.
    #[getter]
    fn max_step<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        let m = &self.optimizer.params().max_step;
        (!m.is_empty()).then(|| PyArray1::from_slice(py, m))
    }

    /// Whether plans are checked for collisions (`collisions=True`).
    #[getter]
    fn collisions(&self) -> bool {
        self.optimizer.params().collision.is_some()
    }

    /// The (body, object or body) pairs left out of the collision checks because they are within
    /// their margin in every sampled pose (a link and its neighbour at their joint, a base on its
    /// table); empty without collision checks.
    #[getter]
    fn excluded_pairs(&self) -> Vec<(String, String)> {
        self.optimizer.params().collision.as_ref().map(|c| c.checker.excluded().to_vec()).unwrap_or_default()
    }

    /// After a solve with collision checks: (body, object or body, distance [m], margin [m]) of the
    /// pair nearest to (or furthest into) its margin along the last plan's executed curve; None
    /// before a solve, without collision checks, or without any checked pair.
    #[getter]
    fn closest_pair(&self) -> Option<(String, String, f64, f64)> {
        self.optimizer.closest_pair().map(|v| (v.body.clone(), v.other.clone(), v.distance, v.margin))
    }

    /// Number of waypoints N of the plans.
    #[getter]
    fn waypoints(&self) -> usize {
        self.optimizer.waypoints()
    }

    /// Waypoints of each level, this optimiser's first, then its coarse levels'.
    #[getter]
    fn levels(&self) -> Vec<usize> {
        let levels = self.optimizer.plan_levels();
        (0..levels.len()).map(|k| levels.level(k).len() / self.features.model().nq()).collect()
    }

    /// The cost `solve` minimises at `xi` (N, n) for `weights`: w·Φ(ξ) with the kinked features
    /// Huber-smoothed by `smoothing`, plus the clearance and max_step penalties. Returns (cost,
    /// penalty, gradient (N, n)); the rows of the start and goal are included in the gradient.
    fn objective<'py>(
        &mut self,
        py: Python<'py>,
        xi: ArrayIn<'py>,
        weights: ArrayIn<'py>,
    ) -> PyResult<(f64, f64, Bound<'py, PyArray2<f64>>)> {
        let n = self.features.model().nq();
        let m = self.optimizer.waypoints();
        let weights = vector("weights", &weights, self.features.len())?.into_owned();
        let xi = matrix("xi", &xi, Some(m), n)?.0.into_owned();
        let mut grad = vec![0.0; m * n];
        let (cost, penalty) = self.optimizer.objective(&mut self.features, &weights, &xi, &mut grad).py_err()?;
        Ok((cost, penalty, PyArray1::from_vec(py, grad).reshape([m, n])?))
    }

    /// Plans from `start` to `goal` [rad] for cost weights `weights` (one per feature), warm-started
    /// from `init` (N, n) if given, else from the straight line. Returns (plan (N, n), TrajoptInfo).
    #[pyo3(signature = (weights, start, goal, init = None))]
    fn solve<'py>(
        &mut self,
        py: Python<'py>,
        weights: ArrayIn<'py>,
        start: ArrayIn<'py>,
        goal: ArrayIn<'py>,
        init: Option<ArrayIn<'py>>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, PyTrajoptInfo)> {
        let n = self.features.model().nq();
        let m = self.optimizer.waypoints();
        let (weights, start, goal) = self.problem(&weights, &start, &goal)?;
        let init = match &init {
            Some(x) => Some(matrix("init", x, Some(m), n)?.0.into_owned()),
            None => None,
        };
        let mut plan = vec![0.0; m * n];
        let (optimizer, features) = (&mut self.optimizer, &mut self.features);
        let info = py.detach(|| optimizer.solve(features, &weights, &start, &goal, init.as_deref(), &mut plan)).py_err()?;
        Ok((PyArray1::from_vec(py, plan).reshape([m, n])?, info.into()))
    }

    /// As `solve`, but warm-started from `init`, a `PlanLevels` that an earlier `solve_levels` of
    /// this optimiser returned: a plan and the coarse plans it came from. The coarse level replans
    /// from its own plan and hands its change down, so a large change of the weights is mostly
    /// worked out there (the learner replans this way); for the same weights, start and goal as
    /// `init` the solve goes on where that one stopped (e.g. after `max_iterations`).
    /// `init=None` plans from the straight line. Returns (PlanLevels, TrajoptInfo).
    #[pyo3(signature = (weights, start, goal, init = None))]
    fn solve_levels<'py>(
        &mut self,
        py: Python<'py>,
        weights: ArrayIn<'py>,
        start: ArrayIn<'py>,
        goal: ArrayIn<'py>,
        init: Option<PyRef<'py, PyPlanLevels>>,
    ) -> PyResult<(PyPlanLevels, PyTrajoptInfo)> {
        let n = self.features.model().nq();
        let (weights, start, goal) = self.problem(&weights, &start, &goal)?;
        let init = init.map(|l| l.levels.clone());
        let mut out = self.optimizer.plan_levels();
        let (optimizer, features) = (&mut self.optimizer, &mut self.features);
        let info = py.detach(|| optimizer.solve_levels(features, &weights, &start, &goal, init.as_ref(), &mut out)).py_err()?;
        Ok((PyPlanLevels { levels: out, n }, info.into()))
    }

    fn __repr__(&self) -> String {
        format!("TrajectoryOptimizer(waypoints={}, features={:?})", self.optimizer.waypoints(), self.features.names())
    }
}

/// A plan with the plans of its optimiser's coarse levels it came from (see
/// `TrajectoryOptimizer.solve_levels`): `plan` (N, n), `level(k)` for k in 0..len (0 is the plan).
#[pyclass(name = "PlanLevels", module = "phri._phri", frozen)]
pub struct PyPlanLevels {
    levels: PlanLevels,
    n: usize,
}

#[pymethods]
impl PyPlanLevels {
    /// The plan (N, n) [rad].
    #[getter]
    fn plan<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.level(py, 0)
    }

    /// Level `k` (waypoints, n) [rad]: 0 is the plan, then ever coarser.
    fn level<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = int)] k: i128) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let k = bounded("k", k, 0..=self.levels.len().saturating_sub(1), "(0 is the plan, then ever coarser levels)")?;
        let level = self.levels.level(k).to_vec();
        let rows = level.len() / self.n;
        PyArray1::from_vec(py, level).reshape([rows, self.n])
    }

    fn __len__(&self) -> usize {
        self.levels.len()
    }

    fn __repr__(&self) -> String {
        let rows: Vec<usize> = (0..self.levels.len()).map(|k| self.levels.level(k).len() / self.n).collect();
        format!("PlanLevels(waypoints={rows:?})")
    }
}
