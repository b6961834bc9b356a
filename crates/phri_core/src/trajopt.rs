//! Gradient trajectory optimisation of eq. 4: ξ_R = argmin_ξ w·Φ(ξ) over N waypoints with the start
//! and goal fixed and the joint position limits as bounds.
//!
//! Solver ([`TrajoptMethod::Newton`], the default): a projected, damped Newton method on a model
//! that keeps the kinks piecewise. Every feature and penalty couples at most two consecutive
//! waypoints, so the Hessian is block tridiagonal (one n × n block per waypoint and per neighbouring
//! pair) and every linear system is solved by a block Cholesky factorisation (block Thomas
//! algorithm) in O(N·n³).
//!
//! - The smooth part is modelled by its second derivatives: the efficiency term's
//!   2·w·tridiag(−1, 2, −1) ⊗ I, the exact Hessians of the kinematic features from their Jacobians
//!   (`kinematics::position_hessian`, `direction_hessian`), and on the linear side of a hinge the
//!   secant curvature 1/|f| (the IRLS weight of |·|, a convex majoriser) so that steps aim at the kink.
//! - The kinked terms that a step can switch on — every clearance penalty ρ·max(0, z_min − z)², both
//!   sides of every max_step penalty, and the keep-out samples just outside their circle — are
//!   modelled as pieces ½c·max(0, f0 + a·d)², linearised at the current plan (max_step exactly). The
//!   model's minimiser is found by a damped semismooth Newton iteration (solve with the pieces that
//!   are on, minimise the convex piecewise-quadratic model exactly along the way to that solution,
//!   re-mark the pieces, until they agree; refactoring only from the first changed block), so a step
//!   never runs blindly into a penalty or back into a keep-out circle it could not see.
//! - Damping λ·(I + κT), T = tridiag(−1, 2, −1) ⊗ I the smoothness metric (κ = 100), keeps the
//!   model positive definite where the Hessian is not (λ is quartered every step and quadrupled
//!   while the factorisation fails): a heavily damped step is a smooth, covariant deformation of
//!   the path (as in CHOMP) rather than a jagged gradient step; a backtracking line search with
//!   quadratic interpolation on the true cost makes every step a descent step.
//! - Convergence: the projected gradient below `gradient_tolerance`, or the model predicting a
//!   decrease below `relative_tolerance`·|cost| with its pieces consistent (quadratic convergence
//!   near the optimum makes this cheap), or a full step lowering the cost by less than that.
//! - Joint limits: variables at a bound whose gradient pushes outward, or that the step would push
//!   further out, are held fixed (projected Newton); the line search follows the projected path
//!   clip(x + α·d) and asks for a fraction of the decrease the gradient predicts for the move
//!   actually made.
//! - Kinematic curvature: Gauss–Newton for the table, coffee and origin features and the clearance
//!   until the active set settles, exact from then on ([`KinematicCurvature`]).
//!
//! Typical counts on the study's tasks (N = 31, from the straight line, one level): 10–27
//! iterations with about one cost evaluation each, against 100–500 for the L-BFGS solver.
//!
//! Multiresolution (`TrajoptParams::coarsening`, default 3). Most of a solve's iterations find
//! where the path goes (around a keep-out circle, down to the table); the waypoints' count only
//! sets how finely. So each optimiser keeps a coarser copy of its problem with about a third of
//! the segments (31 → 11 waypoints; 100 → 34 → 12), the same features with each weight scaled so
//! that the coarse cost of a path approximates the fine one (a feature whose total grows like S^e
//! with the number of segments S weighs r^(1+e) as much, r the ratio of segments; see
//! [`crate::features::Feature::resolution_exponent`]; the same rule as
//! [`crate::features::FeatureSet::rescale_weights`]), the clearance weight r² and the step limits r.
//! - A cold solve plans the coarse level first (recursively), interpolates its plan (linearly in
//!   time, which keeps straight lines) and finishes on the given waypoints: 3–8 iterations there
//!   instead of 10–27 at N = 31, and 3–8 instead of 9–53 at N = 100 (the study's weights for 31
//!   unscaled; see [`crate::features::FeatureSet::rescale_weights`]), each level's iteration
//!   costing about in proportion to its waypoints.
//! - A warm start from a plan alone ([`TrajectoryOptimizer::solve`] with `init`) stays on the given
//!   waypoints. [`TrajectoryOptimizer::solve_levels`] warm-starts from a plan *and* the coarse plans
//!   that led to it ([`PlanLevels`]): the coarse level replans from its own plan, and the change of
//!   the coarse plan, interpolated, is added to the fine one, which the fine level then finishes. A
//!   weight change that moves the path far (0 → 10 on the keep-out tasks: 19–20 fine iterations from
//!   the plan alone) is then worked out on the coarse level (14 iterations there, then 5–6 fine
//!   ones), while a small one costs a few coarse iterations more than it would alone. Adding the
//!   coarse *change* rather than taking the coarse plan keeps what the fine level had already
//!   resolved: a plan optimal for the weights stays put. The learner replans this way.
//!
//! [`TrajoptMethod::Lbfgs`] keeps the earlier solver: projected L-BFGS whose initial inverse Hessian
//! is the banded smoothness metric (a CHOMP-style covariant first step).
//!
//! The hinge features (laptop, human, |·| of coffee) are used with their subgradients (zero on the
//! flat side and at the kink; see `features.rs`), Huber-smoothed with width `smoothing` during the
//! optimisation so that the cost is C¹ (and piecewise C²). The table clearance is a quadratic
//! penalty ρ·Σ max(0, z_min − z)² on each clearance frame's height at every waypoint; with ρ = 10³
//! per m² the optimum violates it by about w_table/(2ρ) = 5·10⁻⁴ m per unit weight (the documented
//! tolerance is 10⁻³ m), and the reported `max_violation` is the check.

use std::time::{Duration, Instant};

use nalgebra::Matrix6xX;

use crate::block_tridiagonal::{BlockCholesky, BlockTridiagonal, Damping};
use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::features::{FeatureSet, Pieces, SecondOrder};
use crate::kinematics::position_hessian;
use crate::model::FrameId;

/// Keep a frame's origin above a height (the hand above the table top plus a clearance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clearance {
    pub frame: FrameId,
    /// Lowest allowed z of the frame origin [m] (table top + clearance).
    pub min_z: f64,
    /// Penalty weight ρ [cost per m²].
    pub weight: f64,
}

/// The algorithm that minimises the cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TrajoptMethod {
    /// Projected Newton with Levenberg–Marquardt damping on the exact block-tridiagonal Hessian.
    #[default]
    Newton,
    /// Projected L-BFGS with the smoothness metric as initial inverse Hessian (the earlier solver).
    Lbfgs,
}

/// The Newton model's share of the kinematics' second derivatives (see
/// `TrajoptParams::kinematic_curvature`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KinematicCurvature {
    /// Leave them out: the Gauss–Newton part only. Far from the optimum it models these features
    /// better than the exact Hessian, which is indefinite along much of the path and forces heavy
    /// damping (measured: table 29 → 20 iterations at N = 31 against `Exact`, coffee 18 → 9 at
    /// N = 100 with the study's weights for 31); near it, convergence is only linear where they
    /// matter (table: the clearance holds the hand down and the table feature's curvature decides
    /// the rest).
    GaussNewton,
    /// Gauss–Newton until the model's pieces agree with its step (the active set has settled) and
    /// it predicts little more decrease, exact from then on, for a quadratic end (measured on the
    /// study's tasks from the levels' warm starts: coffee 4 → 2–3 fine iterations, table 9–14 →
    /// 4–10; the switch comes once a step predicts less than 10⁻³ of the cost).
    #[default]
    Settled,
    /// Include them from the start.
    Exact,
}

/// Tuning of the optimiser; `Default` gives the documented defaults.
///
/// With `max_time` unset every solve is deterministic: the same inputs give bit-identical plans.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajoptParams {
    /// Iteration cap (Newton: factorised steps tried; L-BFGS: directions).
    pub max_iterations: usize,
    /// Wall-time cap; `None` (the default) keeps results deterministic.
    pub max_time: Option<Duration>,
    /// Stop when the largest projected-gradient entry is below this [cost per rad].
    pub gradient_tolerance: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction of it.
    pub relative_tolerance: f64,
    /// L-BFGS history length (L-BFGS only).
    pub memory: usize,
    /// Huber width δ of the kinked features during optimisation (hinges in m, |·| unitless);
    /// the plan's optimum moves by at most about δ. 0 optimises the exact subgradient form.
    pub smoothing: f64,
    /// Frames kept above the table (e.g. link_7 and the hand's tool point).
    pub clearance: Vec<Clearance>,
    /// Largest joint move between consecutive waypoints [rad] (velocity limit × waypoint spacing),
    /// one per joint; empty for none. A quadratic penalty with `step_weight`.
    pub max_step: Vec<f64>,
    /// Penalty weight of `max_step` [cost per rad²].
    pub step_weight: f64,
    /// The algorithm (default [`TrajoptMethod::Newton`]).
    pub method: TrajoptMethod,
    /// Newton: how the model treats the second derivatives of the kinematics in the features that
    /// act at every waypoint (table, coffee, origin) and in the clearance penalty (default
    /// [`KinematicCurvature::Settled`]). See `features::SegmentHessian::kinematic`.
    pub kinematic_curvature: KinematicCurvature,
    /// Multiresolution (see the module docs): a coarser copy of the problem with about
    /// 1/`coarsening` of the segments, recursively, on which cold solves and `solve_levels` warm
    /// starts begin; 0 or 1 solves on the given waypoints only. Default 3.
    pub coarsening: usize,
    /// Fewest waypoints of a coarse level (default 8): a level that would have fewer is not built.
    pub coarsest: usize,
}

impl Default for TrajoptParams {
    fn default() -> Self {
        TrajoptParams {
            max_iterations: 500,
            max_time: None,
            gradient_tolerance: 1e-6,
            relative_tolerance: 1e-9,
            memory: 20,
            smoothing: 0.05,
            clearance: Vec::new(),
            max_step: Vec::new(),
            step_weight: 1e3,
            method: TrajoptMethod::Newton,
            kinematic_curvature: KinematicCurvature::Settled,
            coarsening: 3,
            coarsest: 8,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajoptInfo {
    /// Iterations on the given waypoints.
    pub iterations: usize,
    /// Iterations on the coarse levels, all together (0 without multiresolution).
    pub coarse_iterations: usize,
    /// Cost evaluations on the given waypoints (each one Φ and ∇Φ, and for Newton ∇²Φ).
    pub evaluations: usize,
    /// Final cost w·Φ + penalty.
    pub cost: f64,
    /// Final penalty part of the cost.
    pub penalty: f64,
    /// Largest clearance violation at the solution [m] (0 when satisfied or unused).
    pub max_violation: f64,
    /// Largest joint step beyond `max_step` between consecutive waypoints [rad] (0 without
    /// max_step): the quadratic penalty leaves about gradient/(2·step_weight); much more means
    /// the goal is too far for the duration.
    pub max_step_excess: f64,
    /// Met a tolerance (rather than an iteration or time cap).
    pub converged: bool,
    /// Wall time [s].
    pub seconds: f64,
}

/// Semismooth re-solves per Newton step at most, up to 45 waypoints. Each costs a factorisation
/// from the first changed block; beyond three the steps get more exact but not cheaper overall
/// (measured on the study's tasks: 12 → 3 cut the N = 31 cold solves by a fifth, N = 100 by a
/// sixth, both with the study's weights for 31; the outer line search keeps a step that stops
/// short a descent step).
const MAX_INNER: usize = 3;

/// Semismooth re-solves per Newton step at most for `m` waypoints: [`MAX_INNER`], or one per 15
/// waypoints if more (more waypoints, more pieces that switch together: measured at N = 100 with
/// the study's weights for 31, 6 re-solves take the fine level of the table, laptop and human
/// tasks from 15, 6, 5 iterations to 8, 4, 3 and a quarter fewer instructions on the table task).
fn max_inner(m: usize) -> usize {
    MAX_INNER.max(m / 15)
}

/// Weight κ of the smoothness metric in the Newton damping λ·(I + κT), T = tridiag(−1, 2, −1) ⊗ I
/// over the interior waypoints: a heavily damped step is then a smooth (covariant, CHOMP-like)
/// deformation of the whole path rather than a jagged gradient step at a few waypoints (measured
/// on the study's tasks: 82 → 71 iterations for the four cold N = 31 solves, 151 → 122 at N = 100
/// with the study's weights for 31; 30 to 1000 do about as well).
const DAMPING_METRIC: f64 = 100.0;

/// Least damping, relative to the curvature scale, once a factorisation has failed (then ×4 until
/// one succeeds). Measured on the study's tasks against 10⁻⁴: the replans after the first push on
/// the keep-out tasks take 8–17% fewer instructions, the others as many.
const INDEFINITE_DAMPING: f64 = 1e-5;

/// Damping, relative to the curvature scale, at or below which a step counts as a Newton step: a
/// small predicted or actual decrease means convergence only then (a heavily damped step is short
/// whatever is left to gain), and damping harder starts from at least this.
const LOW_DAMPING: f64 = 1e-4;

/// The Newton damping for λ (see [`DAMPING_METRIC`]).
fn damping(lambda: f64) -> Damping {
    Damping { diagonal: lambda, difference: DAMPING_METRIC * lambda }
}

/// [`KinematicCurvature::Settled`] switches to the exact curvature once a step's pieces agree with
/// it and it predicts a decrease below this fraction of the cost (measured on the study's tasks:
/// 10⁻³ takes 11% fewer instructions than Gauss–Newton throughout, ∞ — at the first consistent
/// step — 6%, 10⁻⁴ 10%).
const SETTLED_DECREASE: f64 = 1e-3;

/// Line-search trials per Newton step at most (α shrinks at least tenfold every two).
const MAX_BACKTRACKS: usize = 12;

/// How much of the cost an evaluation computes.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Derivatives {
    Gradient,
    Hessian,
}

/// A plan with the plans of the optimiser's coarse levels it came from (multiresolution; see the
/// module docs), finest first: the warm start of [`TrajectoryOptimizer::solve_levels`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlanLevels {
    levels: Vec<Vec<f64>>,
    /// Where each level's solver left off, and the problem it solved (weights, start, goal): a
    /// solve of the same problem goes on from there (a replan cut short by an iteration cap).
    states: Vec<SolverState>,
    problem: Vec<f64>,
    dof: usize,
}

impl PlanLevels {
    /// The plan itself (N × n row-major).
    pub fn plan(&self) -> &[f64] {
        &self.levels[0]
    }

    /// Number of levels (1 + the optimiser's coarse levels).
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Always false: a plan has at least its own level.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k` (0 = the plan, then ever coarser), waypoints × n row-major.
    pub fn level(&self, k: usize) -> &[f64] {
        &self.levels[k]
    }

    /// Level `k`, to write (e.g. plans stored earlier); the solvers' states are forgotten.
    pub fn level_mut(&mut self, k: usize) -> &mut [f64] {
        self.problem.clear();
        &mut self.levels[k]
    }
}

/// A reusable optimiser for trajectories of `waypoints` × `dof` (workspaces sized once).
#[derive(Clone)]
pub struct TrajectoryOptimizer {
    params: TrajoptParams,
    waypoints: usize,
    dof: usize,
    lower: Vec<f64>,
    upper: Vec<f64>,
    // Thomas-algorithm factors of the interior second-difference metric tridiag(−1, 2, −1).
    metric_c: Vec<f64>,
    metric_d: Vec<f64>,
    traj: Vec<f64>,
    trial: Vec<f64>,
    grad: Vec<f64>,
    trial_grad: Vec<f64>,
    direction: Vec<f64>,
    candidate: Vec<f64>,
    /// (H_s + D_λ)·direction, (H_s + D_λ)·v, and the smooth part of the gradient.
    hd: Vec<f64>,
    hv: Vec<f64>,
    smooth_grad: Vec<f64>,
    /// Per model piece: curvature, lowest waypoint, value at `direction`, slope along the step.
    piece_c: Vec<f64>,
    piece_w: Vec<usize>,
    line_f: Vec<f64>,
    line_g: Vec<f64>,
    relevant: Vec<usize>,
    /// Second-order data of `traj` and `trial` (Newton only).
    model: Model,
    trial_model: Model,
    /// The Newton system of the current inner iteration.
    system: BlockTridiagonal,
    rhs: Vec<f64>,
    cholesky: BlockCholesky,
    fixed: Vec<bool>,
    /// Which pieces the Newton model has on: the model's [`Pieces`], then max_step (segment,
    /// joint, side).
    active: Vec<bool>,
    s_hist: Vec<Vec<f64>>,
    y_hist: Vec<Vec<f64>>,
    rho_hist: Vec<f64>,
    alpha: Vec<f64>,
    data: RobotData,
    jacobian: Matrix6xX<f64>,
    hz: Vec<f64>,
    /// The next coarser level, if multiresolution builds one.
    coarse: Option<Box<Coarse>>,
    /// The Newton model includes the kinematics' second derivatives now (see
    /// [`KinematicCurvature`]).
    exact_curvature: bool,
    /// The solver state the next Newton solve resumes from (set per solve), and the last one's.
    resume: Option<SolverState>,
    state: SolverState,
    /// Whether the coarse levels of the last solve all converged (true without any).
    coarse_converged: bool,
}

impl TrajectoryOptimizer {
    /// For trajectories of `waypoints` (≥ 3) rows of the model's joints, within `lower`/`upper`.
    pub fn new(features: &FeatureSet, waypoints: usize, params: TrajoptParams) -> Result<Self> {
        let model = features.model();
        let dof = model.nq();
        if waypoints < 3 {
            return Err(PhriError::invalid("waypoints", format!("must be at least 3 (start, one free, goal), got {waypoints}")));
        }
        if params.memory == 0 || params.max_iterations == 0 {
            return Err(PhriError::invalid("memory", "and max_iterations must be at least 1"));
        }
        if !(params.smoothing >= 0.0 && params.smoothing.is_finite()) {
            return Err(PhriError::invalid("smoothing", format!("must be finite and >= 0, got {}", params.smoothing)));
        }
        if !(params.gradient_tolerance >= 0.0 && params.relative_tolerance >= 0.0) {
            return Err(PhriError::invalid("gradient_tolerance", "and relative_tolerance must be >= 0"));
        }
        for c in &params.clearance {
            if c.frame.0 >= model.frames.len() {
                return Err(PhriError::invalid("clearance", "frame is not a frame of this robot"));
            }
            if !(c.min_z.is_finite() && c.weight.is_finite() && c.weight > 0.0) {
                return Err(PhriError::invalid("clearance", "min_z must be finite and weight finite and > 0"));
            }
        }
        if params.coarsest < 3 {
            return Err(PhriError::invalid("coarsest", format!("must be at least 3 waypoints, got {}", params.coarsest)));
        }
        if !params.max_step.is_empty() {
            check_vector("max_step", &params.max_step, dof)?;
            if params.max_step.iter().any(|v| *v <= 0.0) || !(params.step_weight.is_finite() && params.step_weight > 0.0) {
                return Err(PhriError::invalid("max_step", "entries and step_weight must be > 0"));
            }
        }
        let interior = waypoints - 2;
        // Factor tridiag(−1, 2, −1) of size `interior` once (Thomas algorithm).
        let mut metric_c = vec![0.0; interior];
        let mut metric_d = vec![0.0; interior];
        metric_d[0] = 2.0;
        for i in 1..interior {
            metric_c[i] = -1.0 / metric_d[i - 1];
            metric_d[i] = 2.0 + metric_c[i]; // 2 − 1/d_{i−1}
        }
        let len = waypoints * dof;
        let dim = interior * dof;
        let memory = if params.method == TrajoptMethod::Lbfgs { params.memory } else { 0 };
        let coarse = Coarse::build(features, waypoints, &params)?;
        Ok(TrajectoryOptimizer {
            coarse,
            exact_curvature: false,
            resume: None,
            state: SolverState::default(),
            coarse_converged: true,
            lower: model.lower_limits(),
            upper: model.upper_limits(),
            data: model.data(),
            jacobian: Matrix6xX::zeros(dof),
            hz: vec![0.0; dof * dof],
            s_hist: vec![vec![0.0; dim]; memory],
            y_hist: vec![vec![0.0; dim]; memory],
            rho_hist: vec![0.0; memory],
            alpha: vec![0.0; memory],
            model: Model::new(dof, waypoints),
            trial_model: Model::new(dof, waypoints),
            system: BlockTridiagonal::new(dof, waypoints),
            rhs: vec![0.0; len],
            active: Vec::new(),
            cholesky: BlockCholesky::new(dof, interior),
            fixed: vec![false; len],
            params,
            waypoints,
            dof,
            metric_c,
            metric_d,
            traj: vec![0.0; len],
            trial: vec![0.0; len],
            grad: vec![0.0; len],
            trial_grad: vec![0.0; len],
            direction: vec![0.0; len],
            candidate: vec![0.0; len],
            hd: vec![0.0; len],
            hv: vec![0.0; len],
            smooth_grad: vec![0.0; len],
            piece_c: Vec::new(),
            piece_w: Vec::new(),
            line_f: Vec::new(),
            line_g: Vec::new(),
            relevant: Vec::new(),
        })
    }

    /// Sets the iteration cap of later solves (e.g. a per-tick budget; see `LearnerParams`).
    pub fn set_max_iterations(&mut self, cap: usize) -> Result<()> {
        if cap == 0 {
            return Err(PhriError::invalid("max_iterations", "must be at least 1"));
        }
        self.params.max_iterations = cap;
        if let Some(c) = self.coarse.as_mut() {
            c.optimizer.set_max_iterations(cap)?;
        }
        Ok(())
    }

    pub fn params(&self) -> &TrajoptParams {
        &self.params
    }

    pub fn waypoints(&self) -> usize {
        self.waypoints
    }

    /// The straight line in joint space from `start` to `goal`, row-major (the cold start).
    pub fn straight_line(&self, start: &[f64], goal: &[f64], out: &mut [f64]) {
        let (n, m) = (self.dof, self.waypoints);
        for i in 0..m {
            let s = i as f64 / (m - 1) as f64;
            for j in 0..n {
                out[i * n + j] = start[j] + s * (goal[j] - start[j]);
            }
        }
    }

    /// The cost the solver minimises — w·Φ(ξ) with the kinked features smoothed by `smoothing`,
    /// plus the clearance and max_step penalties — at `trajectory` (N × n), and its gradient into
    /// `grad` (N × n; the rows of the fixed start and goal included). Returns (cost, penalty).
    pub fn objective(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        trajectory: &[f64],
        grad: &mut [f64],
    ) -> Result<(f64, f64)> {
        let (n, m) = (self.dof, self.waypoints);
        if features.model().nq() != n {
            return Err(PhriError::invalid("features", "belong to a robot with a different number of joints"));
        }
        check_vector("weights", weights, features.len())?;
        for (arg, len) in [("trajectory", trajectory.len()), ("grad", grad.len())] {
            if len != m * n {
                return Err(PhriError::shape(arg, format!("({m}, {n})"), format!("{len} values")));
            }
        }
        check_finite("trajectory", trajectory)?;
        self.trial.copy_from_slice(trajectory);
        let result = self.evaluate(features, weights, Buffer::Trial, Derivatives::Gradient);
        grad.copy_from_slice(&self.trial_grad);
        Ok(result)
    }

    /// Cost (and derivatives, per `level`) of a buffer; the gradient covers all N × n entries.
    /// With `Derivatives::Hessian` the buffer's [`Model`] receives the smooth part's Hessian, the
    /// penalties' gradient, and every clearance's linearisation (active or not).
    fn evaluate(&mut self, features: &mut FeatureSet, weights: &[f64], which: Buffer, level: Derivatives) -> (f64, f64) {
        let (traj, grad, model) = match which {
            Buffer::Current => (&self.traj, &mut self.grad, &mut self.model),
            Buffer::Trial => (&self.trial, &mut self.trial_grad, &mut self.trial_model),
        };
        let with_hessian = level == Derivatives::Hessian;
        features.set_kinematic_curvature(self.exact_curvature);
        if with_hessian {
            model.exact = self.exact_curvature;
        }
        let mut cost = if with_hessian {
            model.hess.clear();
            let hess = &mut model.hess;
            let second_order =
                SecondOrder { segment_hessian: &mut |i, h| hess.add_segment(i, h.matrix()), pieces: Some(&mut model.pieces) };
            features.weighted_cost_unchecked(traj, self.waypoints, weights, Some(grad), Some(second_order), self.params.smoothing)
        } else {
            features.weighted_cost_unchecked(traj, self.waypoints, weights, Some(grad), None, self.params.smoothing)
        };
        if with_hessian {
            model.pen_grad.fill(0.0);
        }
        let mut penalty = 0.0;
        let n = self.dof;
        if !self.params.clearance.is_empty() {
            let robot = features.model().clone();
            for i in 1..self.waypoints - 1 {
                let data = features.waypoint_data(traj, i);
                for c in &self.params.clearance {
                    let gap = c.min_z - robot.frame_pose(c.frame, data).translation.z;
                    if !(gap > 0.0 || with_hessian) {
                        continue;
                    }
                    robot.frame_jacobian_unchecked(c.frame, data, &mut self.jacobian);
                    if with_hessian {
                        // ρ·gap² = ½·2ρ·gap², gap varying as gap − ∂z/∂q·Δq.
                        let jac = &self.jacobian;
                        model.pieces.set_segment(i);
                        model.pieces.push(1.0, gap, 2.0 * c.weight, |j| -jac[(2, j)]);
                    }
                    if gap > 0.0 {
                        penalty += c.weight * gap * gap;
                        for j in 0..n {
                            let g = -2.0 * c.weight * gap * self.jacobian[(2, j)];
                            grad[i * n + j] += g;
                            if with_hessian {
                                model.pen_grad[i * n + j] += g;
                            }
                        }
                        if with_hessian && self.exact_curvature {
                            // The curvature part of ∂²(ρ·gap²) = 2ρ·∇z·∇zᵀ − 2ρ·gap·∂²z; the
                            // Gauss–Newton part enters the Newton model with the active set.
                            position_hessian(&self.jacobian, &nalgebra::Vector3::z(), &mut self.hz);
                            let block = model.hess.diag_mut(i);
                            for (b, h) in block.iter_mut().zip(&self.hz) {
                                *b -= 2.0 * c.weight * gap * h;
                            }
                        }
                    }
                }
            }
            cost += penalty;
        }
        if !self.params.max_step.is_empty() {
            let w = self.params.step_weight;
            let mut step_penalty = 0.0;
            for i in 1..self.waypoints {
                for (j, limit) in self.params.max_step.iter().enumerate() {
                    let d = traj[i * n + j] - traj[(i - 1) * n + j];
                    let excess = d.abs() - limit;
                    if excess > 0.0 {
                        step_penalty += w * excess * excess;
                        let g = 2.0 * w * excess * d.signum();
                        grad[i * n + j] += g;
                        grad[(i - 1) * n + j] -= g;
                        if with_hessian {
                            model.pen_grad[i * n + j] += g;
                            model.pen_grad[(i - 1) * n + j] -= g;
                        }
                    }
                }
            }
            penalty += step_penalty;
            cost += step_penalty;
        }
        (cost, penalty)
    }

    /// Largest clearance violation of a trajectory [m].
    fn violation(&mut self, features: &FeatureSet, traj: &[f64]) -> f64 {
        let model = features.model();
        let n = self.dof;
        let mut worst: f64 = 0.0;
        if self.params.clearance.is_empty() {
            return worst;
        }
        for i in 0..self.waypoints {
            model.forward_kinematics_unchecked(&traj[i * n..(i + 1) * n], &mut self.data);
            for c in &self.params.clearance {
                worst = worst.max(c.min_z - model.frame_pose(c.frame, &self.data).translation.z);
            }
        }
        worst
    }

    /// Largest |q_i,j − q_{i−1},j| − max_step_j of a trajectory [rad], at least 0.
    fn step_excess(&self, traj: &[f64]) -> f64 {
        let n = self.dof;
        let mut worst: f64 = 0.0;
        for i in 1..self.waypoints {
            for (j, limit) in self.params.max_step.iter().enumerate() {
                worst = worst.max((traj[i * n + j] - traj[(i - 1) * n + j]).abs() - limit);
            }
        }
        worst
    }

    /// Applies the inverse smoothness metric to the interior of `v` in place (per joint, O(N)).
    fn apply_metric_inverse(&self, v: &mut [f64]) {
        let (n, interior) = (self.dof, self.waypoints - 2);
        for j in 0..n {
            // Forward elimination then back substitution; rows are waypoints 1..N−2.
            for i in 1..interior {
                let prev = v[i * n + j];
                v[(i + 1) * n + j] -= self.metric_c[i] * prev;
            }
            v[interior * n + j] /= self.metric_d[interior - 1];
            for i in (0..interior - 1).rev() {
                let next = v[(i + 2) * n + j];
                v[(i + 1) * n + j] = (v[(i + 1) * n + j] + next) / self.metric_d[i];
            }
        }
    }

    /// Zeroes gradient entries that push into an active bound (so they do not steer the step).
    fn project_gradient(&self, traj: &[f64], grad: &mut [f64]) -> f64 {
        let n = self.dof;
        let mut largest: f64 = 0.0;
        for i in 1..self.waypoints - 1 {
            for j in 0..n {
                let k = i * n + j;
                let at_lower = traj[k] <= self.lower[j] && grad[k] > 0.0;
                let at_upper = traj[k] >= self.upper[j] && grad[k] < 0.0;
                if at_lower || at_upper {
                    grad[k] = 0.0;
                }
                largest = largest.max(grad[k].abs());
            }
        }
        largest
    }

    /// Minimises w·Φ(ξ) (+ clearance penalty) from `init` (warm start on these waypoints only;
    /// `None` = the straight line, coarse to fine), with `start` and `goal` fixed, writing the plan
    /// into `out` (N × n row-major). To warm-start through the coarse levels, see
    /// [`TrajectoryOptimizer::solve_levels`].
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        start: &[f64],
        goal: &[f64],
        init: Option<&[f64]>,
        out: &mut [f64],
    ) -> Result<TrajoptInfo> {
        let (n, m) = (self.dof, self.waypoints);
        if out.len() != m * n {
            return Err(PhriError::shape("out", format!("({m}, {n})"), format!("{} values", out.len())));
        }
        if let Some(x) = init {
            if x.len() != m * n {
                return Err(PhriError::shape("init", format!("({m}, {n})"), format!("{} values", x.len())));
            }
            check_finite("init", x)?;
        }
        self.resume = None;
        let info = self.solve_checked(features, weights, start, goal, init.map(|x| (x, Start::Plan)), None)?;
        out.copy_from_slice(&self.traj);
        Ok(info)
    }

    /// Empty [`PlanLevels`] shaped for this optimiser (its waypoints, then each coarse level's).
    pub fn plan_levels(&self) -> PlanLevels {
        let mut levels = vec![vec![0.0; self.waypoints * self.dof]];
        let mut next = self.coarse.as_deref();
        while let Some(c) = next {
            levels.push(vec![0.0; c.optimizer.waypoints * self.dof]);
            next = c.optimizer.coarse.as_deref();
        }
        PlanLevels { states: vec![SolverState::default(); levels.len()], levels, problem: Vec::new(), dof: self.dof }
    }

    /// As [`TrajectoryOptimizer::solve`], but warm-starting from a plan *and* the coarse plans it
    /// came from (`init`, as an earlier `solve_levels` wrote them), and writing all levels to
    /// `out` (from [`TrajectoryOptimizer::plan_levels`]). Each coarse level replans from its own
    /// earlier plan and the finer level adds the interpolated change, so a large change of the
    /// weights is mostly worked out on the coarse levels (module docs). For the same weights,
    /// start and goal as `init`, every level goes on where that solve stopped (its damping and
    /// curvature mode: a replan cut short by `max_iterations` continues rather than restarts), so
    /// the result depends on `init`'s plans and on that; a level written with
    /// [`PlanLevels::level_mut`] starts afresh. `init = None` plans from the straight line.
    #[allow(clippy::too_many_arguments)]
    pub fn solve_levels(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        start: &[f64],
        goal: &[f64],
        init: Option<&PlanLevels>,
        out: &mut PlanLevels,
    ) -> Result<TrajoptInfo> {
        self.check_levels("out", out)?;
        if let Some(levels) = init {
            self.check_levels("init", levels)?;
            for level in &levels.levels {
                check_finite("init", level)?;
            }
        }
        // The same problem (weights, start, goal): the solve goes on where the one that wrote
        // `init` left off.
        let resume = init.is_some_and(|l| {
            l.problem.len() == weights.len() + 2 * self.dof && {
                let (w, ends) = l.problem.split_at(weights.len());
                w == weights && ends[..self.dof] == *start && ends[self.dof..] == *goal
            }
        });
        let from = init.map(|l| {
            let states = if resume { Some(&l.states[1..]) } else { None };
            (&l.levels[0][..], Start::Levels { plans: &l.levels[1..], states })
        });
        self.resume = if resume { init.map(|l| l.states[0]) } else { None };
        let below = LevelsOut { plans: &mut out.levels[1..], states: &mut out.states[1..] };
        let info = self.solve_checked(features, weights, start, goal, from, Some(below))?;
        out.levels[0].copy_from_slice(&self.traj);
        out.states[0] = self.state;
        out.problem.clear();
        out.problem.extend_from_slice(weights);
        out.problem.extend_from_slice(start);
        out.problem.extend_from_slice(goal);
        // A coarse level cut short by a cap still has work to hand down: a later solve_levels for
        // the same problem goes on with it, so the solve is not done.
        Ok(TrajoptInfo { converged: info.converged && self.coarse_converged, ..info })
    }

    fn check_levels(&self, arg: &str, levels: &PlanLevels) -> Result<()> {
        // Walk the coarse chain alongside the given levels (no allocation: this runs every tick of
        // a budgeted replan).
        let mut fits = levels.dof == self.dof && !levels.levels.is_empty();
        let (mut optimizer, mut k) = (Some(self), 0);
        while let Some(o) = optimizer {
            fits &= levels.levels.get(k).is_some_and(|l| l.len() == o.waypoints * o.dof);
            optimizer = o.coarse.as_deref().map(|c| &c.optimizer);
            k += 1;
        }
        if fits && levels.levels.len() == k && levels.states.len() == k {
            return Ok(());
        }
        let want = self.plan_levels();
        let shapes = |l: &PlanLevels| l.levels.iter().map(|v| v.len() / l.dof.max(1)).collect::<Vec<_>>();
        Err(PhriError::shape(
            arg,
            format!("plan levels of {:?} waypoints × {}", shapes(&want), self.dof),
            format!("{:?} × {}", shapes(levels), levels.dof),
        ))
    }

    /// The common part of the solves: checks the problem, sets `traj` (from `init`, or the
    /// straight line), solves, and reports.
    fn solve_checked(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        start: &[f64],
        goal: &[f64],
        init: Option<(&[f64], Start<'_>)>,
        levels: Option<LevelsOut<'_>>,
    ) -> Result<TrajoptInfo> {
        let (n, m) = (self.dof, self.waypoints);
        if features.model().nq() != n {
            return Err(PhriError::invalid("features", "belong to a robot with a different number of joints"));
        }
        check_vector("weights", weights, features.len())?;
        check_vector("start", start, n)?;
        check_vector("goal", goal, n)?;
        for (arg, q) in [("start", start), ("goal", goal)] {
            features.model().check_within_limits(arg, q)?;
        }
        let start_mode = match init {
            Some((x, mode)) => {
                self.traj.copy_from_slice(x);
                mode
            }
            None => {
                let mut line = std::mem::take(&mut self.traj);
                self.straight_line(start, goal, &mut line);
                self.traj = line;
                Start::Line
            }
        };
        self.traj[..n].copy_from_slice(start);
        self.traj[(m - 1) * n..].copy_from_slice(goal);
        for i in 1..m - 1 {
            for j in 0..n {
                let k = i * n + j;
                self.traj[k] = self.traj[k].clamp(self.lower[j], self.upper[j]);
            }
        }
        let began = Instant::now();
        let deadline = self.params.max_time.map(|t| began + t);
        let (iterations, coarse_iterations, evaluations, cost, penalty, converged) =
            self.solve_prepared(features, weights, deadline, start_mode, levels);
        let traj = std::mem::take(&mut self.traj);
        let max_violation = self.violation(features, &traj);
        let max_step_excess = self.step_excess(&traj);
        self.traj = traj;
        Ok(TrajoptInfo {
            iterations,
            coarse_iterations,
            evaluations,
            cost,
            penalty,
            max_violation,
            max_step_excess,
            converged,
            seconds: began.elapsed().as_secs_f64(),
        })
    }

    /// Minimises from `traj` (checked, within the limits, start and goal in place): first the
    /// coarse levels as `start` says, then the method on these waypoints; with `levels`, writes
    /// the coarse levels' plans to `levels[1..]`. Returns (iterations, coarse iterations,
    /// evaluations, cost, penalty, converged).
    fn solve_prepared(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, usize, usize, f64, f64, bool) {
        let (coarse_iterations, coarse_converged) = match start {
            Start::Plan => (0, true),
            _ => self.coarse_correction(features, weights, deadline, start, levels),
        };
        let (iterations, evaluations, cost, penalty, converged) = match self.params.method {
            TrajoptMethod::Newton => self.run_newton(features, weights, deadline),
            TrajoptMethod::Lbfgs => self.run_lbfgs(features, weights, deadline),
        };
        self.coarse_converged = coarse_converged;
        (iterations, coarse_iterations, evaluations, cost, penalty, converged)
    }

    /// The multiresolution start (module docs): solves the coarse level — from its straight line
    /// (`Start::Line`), or from the coarse plan that goes with `traj` (`Start::Levels`) — and sets
    /// `traj` to the interpolated coarse plan, or adds the interpolated change of the coarse plan
    /// to it. Writes the coarse plans to `levels[1..]`. Returns the coarse levels' iterations and
    /// whether they all converged.
    fn coarse_correction(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, bool) {
        let Some(mut coarse) = self.coarse.take() else { return (0, true) };
        let (n, m) = (self.dof, self.waypoints);
        let c = &mut *coarse;
        for (k, w) in weights.iter().enumerate() {
            c.weights[k] = w * c.weight_scale[k];
        }
        let co = &mut c.optimizer;
        let cm = co.waypoints;
        let (first, last) = (&self.traj[..n], &self.traj[(m - 1) * n..]);
        co.resume = None;
        let below = match start {
            Start::Levels { plans, states } => {
                co.resume = states.map(|s| s[0]);
                co.traj.copy_from_slice(&plans[0]);
                co.traj[..n].copy_from_slice(first);
                co.traj[(cm - 1) * n..].copy_from_slice(last);
                for i in 1..cm - 1 {
                    for j in 0..n {
                        let k = i * n + j;
                        co.traj[k] = co.traj[k].clamp(self.lower[j], self.upper[j]);
                    }
                }
                c.start.copy_from_slice(&co.traj);
                Start::Levels { plans: &plans[1..], states: states.map(|s| &s[1..]) }
            }
            _ => {
                let mut line = std::mem::take(&mut co.traj);
                co.straight_line(first, last, &mut line);
                co.traj = line;
                Start::Line
            }
        };
        let (iterations, coarse_iterations, _, _, _, level_converged) = match levels {
            Some(out) => {
                let (plan, plans) = out.plans.split_first_mut().expect("one plan per level");
                let (state, states) = out.states.split_first_mut().expect("one state per level");
                let result = co.solve_prepared(features, &c.weights, deadline, below, Some(LevelsOut { plans, states }));
                plan.copy_from_slice(&co.traj);
                *state = co.state;
                result
            }
            None => co.solve_prepared(features, &c.weights, deadline, below, None),
        };
        let correct = matches!(start, Start::Levels { .. });
        for (i, taps) in c.up.iter().enumerate().take(m - 1).skip(1) {
            for j in 0..n {
                let k = i * n + j;
                let q = if correct {
                    self.traj[k] + taps.iter().map(|&(ci, w)| w * (co.traj[ci * n + j] - c.start[ci * n + j])).sum::<f64>()
                } else {
                    taps.iter().map(|&(ci, w)| w * co.traj[ci * n + j]).sum::<f64>()
                };
                self.traj[k] = q.clamp(self.lower[j], self.upper[j]);
            }
        }
        let converged = level_converged && c.optimizer.coarse_converged;
        self.coarse = Some(coarse);
        (iterations + coarse_iterations, converged)
    }

    /// Marks the interior variables held at a bound (gradient pushing outward) and returns the
    /// largest remaining gradient entry.
    fn mark_fixed(&mut self) -> f64 {
        let n = self.dof;
        let mut largest: f64 = 0.0;
        self.fixed.fill(true);
        for i in 1..self.waypoints - 1 {
            for j in 0..n {
                let k = i * n + j;
                let g = self.grad[k];
                let fixed = (self.traj[k] <= self.lower[j] && g > 0.0) || (self.traj[k] >= self.upper[j] && g < 0.0);
                self.fixed[k] = fixed;
                if !fixed {
                    largest = largest.max(g.abs());
                }
            }
        }
        largest
    }

    /// Sets up the model's pieces for one Newton step: the model's [`Pieces`], then both sides of
    /// every max_step pair (½·2ρ·max(0, ±diff − limit)², exact since linear), with their curvature
    /// `piece_c`, their lowest waypoint `piece_w`, their values at d = 0 in `line_f`, and marks
    /// those on at d = 0.
    fn prepare_pieces(&mut self) {
        let (n, m) = (self.dof, self.waypoints);
        let pieces = &self.model.pieces;
        let steps = if self.params.max_step.is_empty() { 0 } else { 2 * m * n };
        let count = pieces.len() + steps;
        for v in [&mut self.piece_c, &mut self.line_f, &mut self.line_g] {
            v.clear();
            v.resize(count, 0.0);
        }
        self.piece_w.clear();
        self.piece_w.resize(count, 0);
        self.active.clear();
        self.active.resize(count, false);
        for (k, p) in pieces.list.iter().enumerate() {
            self.piece_c[k] = p.c;
            self.line_f[k] = p.f0;
            self.piece_w[k] = if p.s < 1.0 { p.segment - 1 } else { p.segment };
        }
        if steps > 0 {
            let (base, rho) = (pieces.len(), self.params.step_weight);
            for i in 1..m {
                for (j, limit) in self.params.max_step.iter().enumerate() {
                    let diff = self.traj[i * n + j] - self.traj[(i - 1) * n + j];
                    for (side, sign) in [(0, 1.0), (1, -1.0)] {
                        let k = base + (i * n + j) * 2 + side;
                        self.piece_c[k] = 2.0 * rho;
                        self.line_f[k] = sign * diff - limit;
                        self.piece_w[k] = i - 1;
                    }
                }
            }
        }
        for k in 0..count {
            self.active[k] = self.line_f[k] > 0.0;
        }
    }

    /// The slopes a_k·v of every piece along a model step v, into `line_g`.
    fn piece_slopes(&mut self, v: &[f64]) {
        let (n, m) = (self.dof, self.waypoints);
        let pieces = &self.model.pieces;
        for (k, p) in pieces.list.iter().enumerate() {
            self.line_g[k] = piece_dot(&pieces.a[k * n..(k + 1) * n], v, p.segment, p.s, n);
        }
        if !self.params.max_step.is_empty() {
            let base = pieces.len();
            for i in 1..m {
                for j in 0..n {
                    let dv = v[i * n + j] - v[(i - 1) * n + j];
                    let k = base + (i * n + j) * 2;
                    self.line_g[k] = dv;
                    self.line_g[k + 1] = -dv;
                }
            }
        }
    }

    /// Minimises the model along d + t·v, t ∈ [0, 1]: φ(t) = A·t + ½B·t² + Σ_k ½c_k·max(0, f_k +
    /// t·g_k)², convex and piecewise quadratic (safeguarded Newton on φ', exact on each piece).
    /// Returns (t, φ(0) − φ(t)); t = 0 when v is not a descent direction.
    fn line_minimum(&mut self, a: f64, b: f64) -> (f64, f64) {
        // Only pieces that are on somewhere in [0, 1] matter.
        self.relevant.clear();
        for k in 0..self.line_f.len() {
            let (f, g) = (self.line_f[k], self.line_g[k]);
            if f > 0.0 || f + g > 0.0 {
                self.relevant.push(k);
            }
        }
        let derivative = |t: f64| {
            let (mut d1, mut d2) = (a + b * t, b);
            for &k in &self.relevant {
                let (f, g, c) = (self.line_f[k], self.line_g[k], self.piece_c[k]);
                let x = f + t * g;
                if x > 0.0 {
                    d1 += c * x * g;
                    d2 += c * g * g;
                }
            }
            (d1, d2)
        };
        let (slope, _) = derivative(0.0);
        if !(slope < 0.0) {
            return (0.0, 0.0);
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        let (mut t, (mut d1, mut d2)) = (1.0, derivative(1.0));
        if d1 > 0.0 {
            for _ in 0..40 {
                let newton = t - d1 / d2;
                let next = if newton > lo && newton < hi && d2 > 0.0 { newton } else { 0.5 * (lo + hi) };
                let (n1, n2) = derivative(next);
                if n1 > 0.0 {
                    hi = next;
                } else {
                    lo = next;
                }
                let done = (next - t).abs() <= 1e-14 * t.max(1e-300) || n1 == 0.0;
                (t, d1, d2) = (next, n1, n2);
                if done || hi - lo <= 1e-15 {
                    break;
                }
            }
        }
        let mut drop = -(a * t + 0.5 * b * t * t);
        for &k in &self.relevant {
            let (f, g, c) = (self.line_f[k], self.line_g[k], self.piece_c[k]);
            let (x0, x1) = (f.max(0.0), (f + t * g).max(0.0));
            drop -= 0.5 * c * (x1 * x1 - x0 * x0);
        }
        (t, drop)
    }

    /// After a step t along the line: updates `line_f`, marks the pieces on, and returns the
    /// lowest waypoint whose system blocks changed, if any did.
    fn advance_pieces(&mut self, t: f64) -> Option<usize> {
        let mut lowest: Option<usize> = None;
        for k in 0..self.line_f.len() {
            self.line_f[k] += t * self.line_g[k];
            let on = self.line_f[k] > 0.0;
            if on != self.active[k] {
                self.active[k] = on;
                let w = self.piece_w[k];
                lowest = Some(lowest.map_or(w, |l| l.min(w)));
            }
        }
        lowest
    }

    /// The Newton system for the pieces that are on: `system` = smooth Hessian + their Gauss–Newton
    /// terms, `rhs` = −(smooth gradient + their linearised gradients).
    fn assemble(&mut self) {
        let (n, m) = (self.dof, self.waypoints);
        let nn = n * n;
        self.system.diag.copy_from_slice(&self.model.hess.diag);
        self.system.off.copy_from_slice(&self.model.hess.off);
        for k in 0..m * n {
            self.rhs[k] = self.model.pen_grad[k] - self.grad[k];
        }
        let pieces = &self.model.pieces;
        for (k, p) in pieces.list.iter().enumerate() {
            if !self.active[k] {
                continue;
            }
            // ½c·(f0 + a·Δq(s))², Δq(s) = (1−s)·Δ_{i−1} + s·Δ_i: gradient c·f0·a, Hessian c·a·aᵀ.
            let a = &pieces.a[k * n..(k + 1) * n];
            let (i, s, c, f0) = (p.segment, p.s, p.c, p.f0);
            let weights = [(i - 1, 1.0 - s), (i, s)];
            for (w, ws) in weights {
                if ws == 0.0 || w == 0 || w == m - 1 {
                    continue;
                }
                axpy(-c * f0 * ws, a, &mut self.rhs[w * n..(w + 1) * n]);
                add_outer(&mut self.system.diag[w * nn..(w + 1) * nn], a, c * ws * ws);
            }
            if s > 0.0 && s < 1.0 && i >= 2 && i < m - 1 {
                add_outer(&mut self.system.off[(i - 1) * nn..i * nn], a, c * s * (1.0 - s));
            }
        }
        if !self.params.max_step.is_empty() {
            let (base, rho) = (pieces.len(), self.params.step_weight);
            for i in 1..m {
                for (j, limit) in self.params.max_step.iter().enumerate() {
                    let diff = self.traj[i * n + j] - self.traj[(i - 1) * n + j];
                    for (side, sign) in [(0, 1.0), (1, -1.0)] {
                        if !self.active[base + (i * n + j) * 2 + side] {
                            continue;
                        }
                        // ρ·(sign·(diff + Δ_i − Δ_{i−1}) − limit)².
                        let c0 = sign * diff - limit;
                        self.rhs[i * n + j] -= 2.0 * rho * c0 * sign;
                        self.rhs[(i - 1) * n + j] += 2.0 * rho * c0 * sign;
                        self.system.diag[(i * n + j) * n + j] += 2.0 * rho;
                        self.system.diag[((i - 1) * n + j) * n + j] += 2.0 * rho;
                        self.system.off[((i - 1) * n + j) * n + j] -= 2.0 * rho;
                    }
                }
            }
        }
    }

    /// Factors `system` + λ·(I + κT) ([`damping`]), from block `from` on (earlier blocks kept from
    /// the last factorisation with the same λ), raising λ until it is positive definite. False if
    /// no λ ≤ `lambda_max` is.
    fn factor_system(&mut self, lambda: &mut f64, from: usize, scale: f64, lambda_max: f64) -> bool {
        let mut from = from;
        while *lambda <= lambda_max {
            if self.cholesky.factor_from(&self.system, 1, damping(*lambda), &self.fixed, from) {
                return true;
            }
            *lambda = (*lambda * 4.0).max(INDEFINITE_DAMPING * scale);
            from = 0;
        }
        false
    }

    /// Solves the factored system for the current `rhs` into `candidate` (free interior variables).
    fn solve_system(&mut self) {
        let (n, m) = (self.dof, self.waypoints);
        for k in 0..m * n {
            let interior = k >= n && k < (m - 1) * n;
            self.candidate[k] = if interior && !self.fixed[k] { self.rhs[k] } else { 0.0 };
        }
        let mut x = std::mem::take(&mut self.candidate);
        self.cholesky.solve(&mut x, 1);
        self.candidate = x;
    }

    /// y = (H_s + D_λ)·x over the interior waypoints (H_s the smooth Hessian of the model, D_λ the
    /// damping of [`damping`]).
    fn smooth_times(&self, x: &[f64], y: &mut [f64], lambda: f64) {
        let (n, m) = (self.dof, self.waypoints);
        self.model.hess.product(x, y, 1, m - 2);
        // + λ·(I + κT)·x: T couples neighbouring interior waypoints.
        let d = damping(lambda);
        for i in 1..m - 1 {
            for r in 0..n {
                let k = i * n + r;
                let mut acc = (d.diagonal + 2.0 * d.difference) * x[k];
                if i + 1 < m - 1 {
                    acc -= d.difference * x[k + n];
                }
                if i > 1 {
                    acc -= d.difference * x[k - n];
                }
                y[k] += acc;
            }
        }
    }

    /// The Newton step of one outer iteration into `direction`: the minimiser of the model
    /// m(d) = g_sᵀd + ½dᵀ(H_s + D_λ)d + Σ_k ½c_k·max(0, f_k + a_k·d)² (smooth part, plus the pieces)
    /// found by a damped semismooth Newton iteration: solve with the pieces that are on, minimise
    /// the model exactly along the way to that solution, re-mark the pieces; stop when they agree.
    /// Returns the model decrease m(0) − m(d) and whether the pieces agree with d, or None if no
    /// damping makes the system positive definite.
    fn newton_step(&mut self, lambda: &mut f64, scale: f64, lambda_max: f64) -> Option<(f64, bool)> {
        let (n, m) = (self.dof, self.waypoints);
        let len = n * m;
        for k in 0..len {
            self.smooth_grad[k] = self.grad[k] - self.model.pen_grad[k];
        }
        'restart: loop {
            self.prepare_pieces();
            self.direction.fill(0.0);
            self.hd.fill(0.0);
            let mut decrease = 0.0;
            let mut changed_from: Option<usize> = Some(0);
            let mut factored_lambda = f64::NAN;
            let mut consistent = false;
            for _ in 0..max_inner(m) {
                let Some(lowest) = changed_from else {
                    consistent = true;
                    break;
                };
                let from = if factored_lambda == *lambda { lowest.saturating_sub(1) } else { 0 };
                self.assemble();
                let before = *lambda;
                if !self.factor_system(lambda, from, scale, lambda_max) {
                    return None;
                }
                if *lambda != before && !factored_lambda.is_nan() {
                    // λ rose after a step was taken: the model changed; start over.
                    continue 'restart;
                }
                factored_lambda = *lambda;
                self.solve_system();
                // v = d* − d, A = ∇m_s(d)·v, B = vᵀ(H_s + D_λ)v.
                for k in 0..len {
                    self.candidate[k] -= self.direction[k];
                }
                let mut hv = std::mem::take(&mut self.hv);
                self.smooth_times(&self.candidate, &mut hv, *lambda);
                let (mut a, mut b) = (0.0, 0.0);
                for k in n..len - n {
                    let v = self.candidate[k];
                    a += (self.smooth_grad[k] + self.hd[k]) * v;
                    b += hv[k] * v;
                }
                let v = std::mem::take(&mut self.candidate);
                self.piece_slopes(&v);
                self.candidate = v;
                let (t, drop) = self.line_minimum(a, b);
                if t == 0.0 {
                    // d already minimises the model.
                    consistent = true;
                    self.hv = hv;
                    break;
                }
                for k in n..len - n {
                    self.direction[k] += t * self.candidate[k];
                    self.hd[k] += t * hv[k];
                }
                self.hv = hv;
                decrease += drop;
                changed_from = self.advance_pieces(t);
                if changed_from.is_none() && t < 1.0 - 1e-9 {
                    // Stopped short without a piece changing: rounding; d is as good as it gets.
                    consistent = t > 0.999;
                    break;
                }
            }
            return Some((decrease, consistent));
        }
    }

    /// Projected Newton on a model that keeps the kinked terms piecewise: the smooth part is
    /// quadratic (its damped Hessian), each penalty or hinge piece is ½c·max(0, f0 + a·d)² with f
    /// linearised at the current plan (max_step exactly), minimised by [`newton_step`]; then an
    /// interpolating backtracking line search on the true cost. Returns (iterations, evaluations,
    /// cost, penalty, converged).
    ///
    /// [`newton_step`]: TrajectoryOptimizer::newton_step
    fn run_newton(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
    ) -> (usize, usize, f64, f64, bool) {
        let (n, m) = (self.dof, self.waypoints);
        let (lo, hi) = (n, (m - 1) * n); // interior range
        let resume = self.resume.take();
        self.exact_curvature = self.params.kinematic_curvature == KinematicCurvature::Exact || resume.is_some_and(|r| r.exact);
        let (mut cost, mut penalty) = self.evaluate(features, weights, Buffer::Current, Derivatives::Hessian);
        let mut evaluations = 1;
        let mut iterations = 0;
        let mut converged = false;
        // Damping relative to the mean curvature on the diagonal.
        let scale = (1..m - 1).map(|i| (0..n).map(|j| self.model.hess.diag(i)[j * n + j].abs()).sum::<f64>()).sum::<f64>()
            / ((m - 2) * n) as f64;
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { 1.0 };
        let (lambda_min, lambda_max) = (1e-8 * scale, 1e12 * scale);
        let mut lambda = resume.map_or(lambda_min, |r| (r.lambda * scale).clamp(lambda_min, lambda_max));
        let mut largest = self.mark_fixed();
        let mut fell_back = false;
        while iterations < self.params.max_iterations {
            if largest <= self.params.gradient_tolerance {
                converged = true;
                break;
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                break;
            }
            iterations += 1;
            lambda = (lambda * 0.25).max(lambda_min);
            let Some((mut predicted, mut consistent)) = self.newton_step(&mut lambda, scale, lambda_max) else { break };
            if self.hold_variables_the_step_pushes_out() {
                // Held at their bound too (the gradient alone let the step leave the box there,
                // and clipped it would not be a descent direction): step again without them.
                let Some(step) = self.newton_step(&mut lambda, scale, lambda_max) else { break };
                (predicted, consistent) = step;
            }
            let settled = consistent && predicted <= SETTLED_DECREASE * cost.abs() && !fell_back;
            if settled && self.params.kinematic_curvature == KinematicCurvature::Settled {
                // The next models (from the trial points on) include the kinematic curvature.
                self.exact_curvature = true;
            }
            // The slope of the projected path clip(x + α·d) at α = 0: the variables strictly inside
            // the box move along d, and those at a bound that d pushes out are held (above).
            let slope = dot(&self.grad[lo..hi], &self.direction[lo..hi]);
            if consistent && predicted <= self.params.relative_tolerance * cost.abs().max(1e-300) && lambda <= LOW_DAMPING * scale
            {
                // The model predicts no further decrease worth a step: converged.
                converged = true;
                break;
            }
            if !(slope < 0.0) {
                // Not a descent direction (the pieces' model is only linearised): damp harder, or
                // first drop a kinematic curvature taken on too early.
                if !self.drop_settled_curvature(features, weights, &mut fell_back) {
                    lambda = (lambda * 16.0).max(LOW_DAMPING * scale);
                }
                continue;
            }
            // Backtracking along the projected path x(α) = clip(x + α·d), α from 1, with a
            // quadratic interpolation of the cost for the next α (kept within [0.1, 0.5]·α).
            let mut alpha = 1.0;
            let mut accepted = false;
            let (mut new_cost, mut new_penalty) = (cost, penalty);
            for _ in 0..MAX_BACKTRACKS {
                for i in 1..m - 1 {
                    for j in 0..n {
                        let k = i * n + j;
                        self.trial[k] = (self.traj[k] + alpha * self.direction[k]).clamp(self.lower[j], self.upper[j]);
                    }
                }
                self.trial[..lo].copy_from_slice(&self.traj[..lo]);
                self.trial[hi..].copy_from_slice(&self.traj[hi..]);
                (new_cost, new_penalty) = self.evaluate(features, weights, Buffer::Trial, Derivatives::Hessian);
                evaluations += 1;
                // Armijo along the projected path: a fraction of the decrease the gradient predicts
                // for the move actually made (shorter than α·d where the box cuts it).
                let moved: f64 = (lo..hi).map(|k| self.grad[k] * (self.trial[k] - self.traj[k])).sum();
                if new_cost.is_finite() && new_cost <= cost + 1e-4 * moved.min(0.0) {
                    accepted = true;
                    break;
                }
                let next = if new_cost.is_finite() {
                    let curvature = new_cost - cost - slope * alpha;
                    if curvature > 0.0 {
                        -slope * alpha * alpha / (2.0 * curvature)
                    } else {
                        0.5 * alpha
                    }
                } else {
                    0.1 * alpha
                };
                alpha = next.clamp(0.1 * alpha, 0.5 * alpha);
            }
            if !accepted {
                // The model misleads at this damping: if it took on the kinematic curvature when the
                // active set seemed settled, that was too early (the exact Hessian can be indefinite
                // away from the optimum and mislead at any damping): go back to Gauss–Newton for
                // the rest of the solve. Otherwise damp harder and try again.
                if self.drop_settled_curvature(features, weights, &mut fell_back) {
                    continue;
                }
                lambda = (lambda * 16.0).max(LOW_DAMPING * scale);
                if lambda > lambda_max {
                    converged = cost.is_finite(); // no step of any length helps: stationary
                    break;
                }
                continue;
            }
            std::mem::swap(&mut self.traj, &mut self.trial);
            std::mem::swap(&mut self.grad, &mut self.trial_grad);
            std::mem::swap(&mut self.model, &mut self.trial_model);
            let decrease = cost - new_cost;
            cost = new_cost;
            penalty = new_penalty;
            largest = self.mark_fixed();
            if alpha == 1.0
                && decrease <= self.params.relative_tolerance * cost.abs().max(1e-300)
                && lambda <= LOW_DAMPING * scale
            {
                // (A heavily damped step is short whatever is left to gain: not a sign of the end.)
                converged = true;
                break;
            }
        }
        self.state = SolverState { lambda: lambda / scale, exact: self.exact_curvature };
        (iterations, evaluations, cost, penalty, converged)
    }

    /// Marks as fixed the free interior variables at a bound that `direction` pushes further out;
    /// returns whether there were any.
    fn hold_variables_the_step_pushes_out(&mut self) -> bool {
        let n = self.dof;
        let mut any = false;
        for i in 1..self.waypoints - 1 {
            for j in 0..n {
                let k = i * n + j;
                let (x, d) = (self.traj[k], self.direction[k]);
                if !self.fixed[k] && ((x <= self.lower[j] && d < 0.0) || (x >= self.upper[j] && d > 0.0)) {
                    self.fixed[k] = true;
                    any = true;
                }
            }
        }
        any
    }

    /// With [`KinematicCurvature::Settled`] and a current model that has the kinematic curvature
    /// (the one whose step just failed): turns it off for the rest of the solve (`fell_back`) and
    /// rebuilds the current model without it. Returns whether it did.
    fn drop_settled_curvature(&mut self, features: &mut FeatureSet, weights: &[f64], fell_back: &mut bool) -> bool {
        if !(self.model.exact && self.params.kinematic_curvature == KinematicCurvature::Settled) {
            return false;
        }
        self.exact_curvature = false;
        *fell_back = true;
        self.evaluate(features, weights, Buffer::Current, Derivatives::Hessian);
        true
    }

    /// Projected L-BFGS with H0 = γ·metric⁻¹; returns (iterations, evaluations, cost, penalty,
    /// converged).
    fn run_lbfgs(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
    ) -> (usize, usize, f64, f64, bool) {
        let (n, m) = (self.dof, self.waypoints);
        let (lo, hi) = (n, (m - 1) * n); // interior range
        let (mut cost, mut penalty) = self.evaluate(features, weights, Buffer::Current, Derivatives::Gradient);
        let mut evaluations = 1;
        let mut stored = 0usize; // history entries in use
        let mut newest = 0usize;
        let mut iterations = 0;
        let mut converged = false;
        let mut gamma = 0.5; // the efficiency term (weight 1) has Hessian 2·metric
        let mut proj = std::mem::take(&mut self.grad);
        let mut largest = self.project_gradient(&self.traj, &mut proj);
        self.grad = proj;
        while iterations < self.params.max_iterations {
            if largest <= self.params.gradient_tolerance {
                converged = true;
                break;
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                break;
            }
            iterations += 1;
            // Two-loop recursion with H0 = γ·metric⁻¹.
            self.direction[lo..hi].copy_from_slice(&self.grad[lo..hi]);
            let mem = self.params.memory;
            for k in 0..stored {
                let idx = (newest + mem - k) % mem;
                let a = self.rho_hist[idx] * dot(&self.s_hist[idx], &self.direction[lo..hi]);
                self.alpha[idx] = a;
                axpy(-a, &self.y_hist[idx], &mut self.direction[lo..hi]);
            }
            let mut dir = std::mem::take(&mut self.direction);
            self.apply_metric_inverse(&mut dir);
            dir[lo..hi].iter_mut().for_each(|v| *v *= gamma);
            self.direction = dir;
            for k in (0..stored).rev() {
                let idx = (newest + mem - k) % mem;
                let b = self.rho_hist[idx] * dot(&self.y_hist[idx], &self.direction[lo..hi]);
                axpy(self.alpha[idx] - b, &self.s_hist[idx], &mut self.direction[lo..hi]);
            }
            // d = −H g; fall back to steepest descent in the metric if not a descent direction.
            let mut slope = -dot(&self.direction[lo..hi], &self.grad[lo..hi]);
            if !(slope < 0.0) {
                self.direction[lo..hi].copy_from_slice(&self.grad[lo..hi]);
                let mut dir = std::mem::take(&mut self.direction);
                self.apply_metric_inverse(&mut dir);
                self.direction = dir;
                slope = -dot(&self.direction[lo..hi], &self.grad[lo..hi]);
                stored = 0;
                if !(slope < 0.0) {
                    converged = true;
                    break;
                }
            }
            // Projected backtracking (Armijo) line search along −direction.
            let mut step = 1.0;
            let mut accepted = false;
            let (mut new_cost, mut new_penalty) = (cost, penalty);
            for _ in 0..30 {
                self.trial.copy_from_slice(&self.traj);
                for i in 1..m - 1 {
                    for j in 0..n {
                        let k = i * n + j;
                        self.trial[k] = (self.traj[k] - step * self.direction[k]).clamp(self.lower[j], self.upper[j]);
                    }
                }
                (new_cost, new_penalty) = self.evaluate(features, weights, Buffer::Trial, Derivatives::Gradient);
                evaluations += 1;
                let moved: f64 = (lo..hi).map(|k| self.grad[k] * (self.trial[k] - self.traj[k])).sum();
                if new_cost.is_finite() && new_cost <= cost + 1e-4 * moved.min(0.0) {
                    accepted = true;
                    break;
                }
                step *= 0.5;
            }
            if !accepted {
                converged = stored == 0; // no progress even along the metric gradient: stationary
                if stored == 0 {
                    break;
                }
                stored = 0; // drop curvature history and retry along the metric gradient
                continue;
            }
            // Curvature pair.
            let mut trial_grad = std::mem::take(&mut self.trial_grad);
            let next_largest = self.project_gradient(&self.trial, &mut trial_grad);
            self.trial_grad = trial_grad;
            let slot = if stored == 0 { 0 } else { (newest + 1) % self.params.memory };
            for k in lo..hi {
                self.s_hist[slot][k - lo] = self.trial[k] - self.traj[k];
                self.y_hist[slot][k - lo] = self.trial_grad[k] - self.grad[k];
            }
            let sy = dot(&self.s_hist[slot], &self.y_hist[slot]);
            if sy > 1e-12 {
                let yy = dot(&self.y_hist[slot], &self.y_hist[slot]);
                self.rho_hist[slot] = 1.0 / sy;
                newest = slot;
                stored = (stored + 1).min(self.params.memory);
                // Scale of H0 from the newest pair: γ = sᵀy / yᵀ M⁻¹ y.
                let mut tmp = std::mem::take(&mut self.direction);
                tmp[lo..hi].copy_from_slice(&self.y_hist[slot]);
                self.apply_metric_inverse(&mut tmp);
                let ymy = dot(&tmp[lo..hi], &self.y_hist[slot]);
                self.direction = tmp;
                gamma = if ymy > 0.0 { sy / ymy } else { sy / yy.max(1e-300) };
            }
            std::mem::swap(&mut self.traj, &mut self.trial);
            std::mem::swap(&mut self.grad, &mut self.trial_grad);
            let decrease = cost - new_cost;
            cost = new_cost;
            penalty = new_penalty;
            largest = next_largest;
            if decrease <= self.params.relative_tolerance * cost.abs().max(1e-12) {
                converged = true;
                break;
            }
        }
        (iterations, evaluations, cost, penalty, converged)
    }
}

/// Relative tolerance of the coarse levels at least: they only give the next level its start.
const COARSE_TOLERANCE: f64 = 1e-6;

/// A coarser copy of the problem (multiresolution; see the module docs).
#[derive(Clone)]
struct Coarse {
    optimizer: TrajectoryOptimizer,
    /// Coarse weight per unit fine weight, ratio^(1 + e) for a feature of resolution exponent e:
    /// then the coarse cost of a path approximates `ratio` times the fine cost of it.
    weight_scale: Vec<f64>,
    weights: Vec<f64>,
    /// Interpolation taps (see [`interpolation_taps`]): every fine waypoint from the coarse ones.
    up: Vec<[(usize, f64); 2]>,
    /// The coarse plan a warm start began from (coarse N × n).
    start: Vec<f64>,
}

impl Coarse {
    /// The coarse level below a problem of `waypoints`, if `params` asks for one that has at least
    /// `params.coarsest` waypoints and fewer than `waypoints`.
    fn build(features: &FeatureSet, waypoints: usize, params: &TrajoptParams) -> Result<Option<Box<Coarse>>> {
        if params.coarsening < 2 {
            return Ok(None);
        }
        let segments = waypoints - 1;
        let coarse_segments = segments.div_ceil(params.coarsening);
        let m = coarse_segments + 1;
        if m < params.coarsest || m >= waypoints {
            return Ok(None);
        }
        let ratio = segments as f64 / coarse_segments as f64;
        // The same problem on longer segments: per-waypoint penalties weigh ratio² as much (like
        // per-waypoint features), the step limit grows with the segment, and the step penalty,
        // a sum of squares of differences, keeps its weight (as efficiency does).
        let mut coarse_params = params.clone();
        for c in &mut coarse_params.clearance {
            c.weight *= ratio * ratio;
        }
        for v in &mut coarse_params.max_step {
            *v *= ratio;
        }
        coarse_params.relative_tolerance = coarse_params.relative_tolerance.max(COARSE_TOLERANCE);
        coarse_params.gradient_tolerance *= ratio;
        let optimizer = TrajectoryOptimizer::new(features, m, coarse_params)?;
        let weight_scale = features.resolution_scales(ratio).collect();
        let n = features.model().nq();
        Ok(Some(Box::new(Coarse {
            optimizer,
            weight_scale,
            weights: vec![0.0; features.len()],
            up: interpolation_taps(coarse_segments, segments),
            start: vec![0.0; m * n],
        })))
    }
}

/// Taps of the linear interpolation in time of a trajectory of `from` segments at the waypoints of
/// one of `to` segments over the same time: each output waypoint from the two inputs around it
/// (end points and straight lines exactly). Measured against a Catmull–Rom spline through the
/// waypoints: the fine level then needs as many iterations or fewer, and 4% fewer instructions
/// over the study's cold and warm solves (13% on the human task's first push); a spline overshoots
/// where the path bends hardest, which is where it presses against a clearance or a keep-out.
fn interpolation_taps(from: usize, to: usize) -> Vec<[(usize, f64); 2]> {
    (0..=to)
        .map(|i| {
            let u = i as f64 * from as f64 / to as f64;
            let a = (u.floor() as usize).min(from - 1);
            let s = u - a as f64;
            [(a, 1.0 - s), (a + 1, s)]
        })
        .collect()
}

/// Second-order data of one trajectory for the Newton model.
#[derive(Debug, Clone)]
struct Model {
    /// Hessian of the smooth part: features, plus the penalties' curvature terms.
    hess: BlockTridiagonal,
    /// The share of the gradient of the pieces that are on (N × n).
    pen_grad: Vec<f64>,
    /// Kinked terms kept out of `hess` and modelled piecewise: every clearance (on or off) and the
    /// features' inactive hinge samples near their kink.
    pieces: Pieces,
    /// `hess` includes the kinematics' second derivatives ([`KinematicCurvature`]).
    exact: bool,
}

impl Model {
    fn new(n: usize, waypoints: usize) -> Self {
        Model {
            hess: BlockTridiagonal::new(n, waypoints),
            pen_grad: vec![0.0; waypoints * n],
            pieces: Pieces::new(n),
            exact: false,
        }
    }
}

/// How a solve starts (see multiresolution in the module docs).
#[derive(Clone, Copy)]
enum Start<'a> {
    /// From the straight line, coarse to fine.
    Line,
    /// From a given plan, on its waypoints only.
    Plan,
    /// From a given plan (in `traj`) and the coarse plans that go with it, coarsest last, with the
    /// coarse solvers' states to resume from.
    Levels { plans: &'a [Vec<f64>], states: Option<&'a [SolverState]> },
}

/// Where the coarse levels' plans and solver states go (see [`PlanLevels`]).
struct LevelsOut<'a> {
    plans: &'a mut [Vec<f64>],
    states: &'a mut [SolverState],
}

/// Where a Newton solve left off: its damping relative to the curvature scale (0: not started)
/// and whether its model had the kinematic curvature.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct SolverState {
    lambda: f64,
    exact: bool,
}

#[derive(Clone, Copy)]
enum Buffer {
    Current,
    Trial,
}

/// a·Δq(s) for a piece at (segment − 1, segment), Δq(s) = (1 − s)·d_{i−1} + s·d_i.
#[inline]
fn piece_dot(a: &[f64], d: &[f64], segment: usize, s: f64, n: usize) -> f64 {
    let (d0, d1) = (&d[(segment - 1) * n..segment * n], &d[segment * n..(segment + 1) * n]);
    let mut f = 0.0;
    for j in 0..n {
        f += a[j] * ((1.0 - s) * d0[j] + s * d1[j]);
    }
    f
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// block += scale·a·aᵀ (block n × n row-major, n = a.len()).
#[inline]
fn add_outer(block: &mut [f64], a: &[f64], scale: f64) {
    for (row, ar) in block.chunks_exact_mut(a.len()).zip(a) {
        let sr = scale * ar;
        row.iter_mut().zip(a).for_each(|(b, ac)| *b += sr * ac);
    }
}

#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(taps: &[[(usize, f64); 2]], x: &[f64]) -> Vec<f64> {
        taps.iter().map(|row| row.iter().map(|&(k, w)| w * x[k]).sum()).collect()
    }

    #[test]
    fn interpolation_keeps_end_points_and_lines_and_is_linear_in_time() {
        for (from, to) in [(10, 30), (33, 99), (4, 11), (30, 10), (1, 5)] {
            let taps = interpolation_taps(from, to);
            assert_eq!(taps.len(), to + 1);
            // Weights in [0, 1] summing to one (constants are kept), only inputs 0..=from read.
            for row in &taps {
                assert!((row.iter().map(|t| t.1).sum::<f64>() - 1.0).abs() < 1e-14);
                assert!(row.iter().all(|t| t.0 <= from && (0.0..=1.0).contains(&t.1)));
            }
            let line: Vec<f64> = (0..=from).map(|i| 0.3 - 1.7 * i as f64 / from as f64).collect();
            let out = apply(&taps, &line);
            for (i, v) in out.iter().enumerate() {
                assert!((v - (0.3 - 1.7 * i as f64 / to as f64)).abs() < 1e-14, "{from} → {to}, row {i}");
            }
            let wavy: Vec<f64> = (0..=from).map(|i| (i as f64).sin()).collect();
            let out = apply(&taps, &wavy);
            assert_eq!(out[0], wavy[0]);
            assert!((out[to] - wavy[from]).abs() < 1e-15);
            // Between two inputs, on the segment joining them.
            for (i, v) in out.iter().enumerate() {
                let u = i as f64 * from as f64 / to as f64;
                let a = (u.floor() as usize).min(from - 1);
                let (lo, hi) = (wavy[a].min(wavy[a + 1]), wavy[a].max(wavy[a + 1]));
                assert!(*v >= lo - 1e-15 && *v <= hi + 1e-15, "{from} → {to}, row {i}");
            }
        }
    }
}
