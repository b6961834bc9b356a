//! Trajectory optimisation, the planning step of Bajcsy et al. (CoRL 2017), eq. 4:
//! ξ_R = argmin_ξ w·Φ(ξ) over N waypoints
//! with the start and goal fixed and the joint position limits as bounds, plus quadratic penalties
//! that keep frames above the table and joint steps within a velocity limit ([`cost`]).
//!
//! Every feature and penalty couples at most two consecutive waypoints, so the Hessian is block
//! tridiagonal and every linear system of a Newton method costs O(N·n³) ([`block_tridiagonal`]).
//! The solver is a projected, damped Newton method ([`newton`]) on a model that keeps the kinks
//! piecewise ([`pieces`]): the smooth part by its second derivatives (the efficiency term's
//! 2·w·tridiag(−1, 2, −1) ⊗ I, the exact Hessians of the kinematic features, and on the linear
//! side of a hinge the secant curvature 1/|f|, the IRLS weight of |·|, so that steps aim at the
//! kink), the terms a step can switch on as pieces ½c·max(0, f0 + a·d)². A backtracking line search
//! on the true cost ([`line_search`]) makes every step a descent step.
//!
//! - Convergence: the projected gradient below `gradient_tolerance`, or the model predicting a
//!   decrease below `relative_tolerance`·|cost| with its pieces consistent (quadratic convergence
//!   near the optimum makes this cheap), or a full step lowering the cost by less than that.
//! - Kinematic curvature: Gauss–Newton for the table, coffee and origin features and the clearance
//!   until the active set settles, exact from then on ([`KinematicCurvature`]).
//! - Multiresolution ([`levels`]): a cold solve starts on a coarser copy of the problem and
//!   finishes on the given waypoints; [`TrajectoryOptimizer::solve_levels`] warm-starts through
//!   the coarse levels too.
//! - Plans by knots ([`TrajoptParams::knots`], the original system's planner): the knot problem is
//!   the only level solved, and the plan is its linear interpolation at the waypoints.
//!
//! The hinge features (laptop, human, |·| of coffee) are used with their subgradients (zero on the
//! flat side and at the kink), Huber-smoothed with width `smoothing` during the optimisation so
//! that the cost is C¹ (and piecewise C²).

pub mod block_tridiagonal;
mod cancel;
mod collision;
mod cost;
mod levels;
mod line_search;
mod newton;
mod newton_model;
mod params;
mod pieces;

use std::time::Instant;

use nalgebra::Matrix6xX;

use crate::collision::Violation;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::features::FeatureSet;
pub use cancel::Cancellation;
use collision::CollisionScratch;
use cost::{Buffer, Derivatives, Scratch};
pub use levels::PlanLevels;
use levels::{Coarse, LevelsOut, Start};
use newton::{NewtonWorkspace, SolverState};
use newton_model::Model;
pub use params::{
    Clearance, CollisionParams, KinematicCurvature, TrajoptInfo, TrajoptParams, CLEARANCE_TOLERANCE, DEFAULT_COLLISION_BUFFER,
    DEFAULT_COLLISION_SAMPLES, DEFAULT_COLLISION_WEIGHT, MAX_COLLISION_SAMPLES, MAX_ITERATIONS, MAX_TIME, MAX_WAYPOINTS,
    STEP_TOLERANCE,
};

/// A reusable optimiser for trajectories of `waypoints` × `dof` (workspaces sized once).
#[derive(Clone)]
pub struct TrajectoryOptimizer {
    params: TrajoptParams,
    waypoints: usize,
    dof: usize,
    /// Joint position limits [rad].
    lower: Vec<f64>,
    upper: Vec<f64>,
    /// The current plan and a trial point, with their gradients (N × n) and Newton models.
    traj: Vec<f64>,
    trial: Vec<f64>,
    grad: Vec<f64>,
    trial_grad: Vec<f64>,
    model: Model,
    trial_model: Model,
    scratch: Scratch,
    collision_scratch: CollisionScratch,
    /// The pair furthest into its margin along the last solve's plan.
    worst_pair: Option<Violation>,
    newton: NewtonWorkspace,
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
    /// Stops later solves early once another thread supersedes them (see [`Cancellation`]).
    cancel: Option<Cancellation>,
}

impl TrajectoryOptimizer {
    /// For trajectories of `waypoints` (≥ 3) rows of the model's joints, within `lower`/`upper`.
    pub fn new(features: &FeatureSet, waypoints: usize, params: TrajoptParams) -> Result<Self> {
        let model = features.model();
        let dof = model.nq();
        if !(3..=MAX_WAYPOINTS).contains(&waypoints) {
            return Err(PhriError::invalid(
                "waypoints",
                format!("must be in 3..={MAX_WAYPOINTS} (start, at least one free waypoint, goal; see MAX_WAYPOINTS), got {waypoints}"),
            ));
        }
        params.check(model)?;
        if let Some(c) = &params.collision {
            if c.checker.robot_name() != model.name || c.checker.body_count() != model.collision().bodies().len() {
                return Err(PhriError::invalid("collision", "was made for another robot (or its collision model changed)"));
            }
        }
        let len = waypoints * dof;
        let coarse = Coarse::build(features, waypoints, &params)?;
        Ok(TrajectoryOptimizer {
            coarse,
            exact_curvature: false,
            resume: None,
            state: SolverState::default(),
            coarse_converged: true,
            cancel: None,
            lower: model.lower_limits(),
            upper: model.upper_limits(),
            scratch: Scratch { data: model.data(), jacobian: Matrix6xX::zeros(dof), hz: vec![0.0; dof * dof] },
            collision_scratch: CollisionScratch::new(model),
            worst_pair: None,
            model: Model::new(dof, waypoints),
            trial_model: Model::new(dof, waypoints),
            newton: NewtonWorkspace::new(dof, waypoints),
            params,
            waypoints,
            dof,
            traj: vec![0.0; len],
            trial: vec![0.0; len],
            grad: vec![0.0; len],
            trial_grad: vec![0.0; len],
        })
    }

    /// Sets the iteration cap of later solves (e.g. a per-tick budget; see `LearnerParams`).
    pub fn set_max_iterations(&mut self, cap: usize) -> Result<()> {
        if !(1..=MAX_ITERATIONS).contains(&cap) {
            return Err(PhriError::invalid(
                "max_iterations",
                format!("must be in 1..={MAX_ITERATIONS} Newton iterations, got {cap}"),
            ));
        }
        self.params.max_iterations = cap;
        if let Some(c) = self.coarse.as_mut() {
            c.optimizer.set_max_iterations(cap)?;
        }
        Ok(())
    }

    /// Lets another thread stop later solves (on every level) at their next Newton iteration, as
    /// at a `max_time` deadline; `None` removes the hook. A stopped solve reports what it reached,
    /// not converged.
    pub fn set_cancellation(&mut self, cancel: Option<Cancellation>) {
        if let Some(c) = self.coarse.as_mut() {
            c.optimizer.set_cancellation(cancel.clone());
        }
        self.cancel = cancel;
    }

    pub fn params(&self) -> &TrajoptParams {
        &self.params
    }

    pub fn waypoints(&self) -> usize {
        self.waypoints
    }

    /// After a solve with collision checks: the pair closest to (or furthest into) its margin
    /// along the plan's executed curve, with that distance.
    pub fn closest_pair(&self) -> Option<&Violation> {
        self.worst_pair.as_ref()
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
    /// plus the clearance and max_step penalties; for a plan by knots, that of the knot problem at
    /// the trajectory's knots — at `trajectory` (N × n), and its gradient into
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
        if let Some(c) = self.coarse.as_mut().filter(|c| c.knots) {
            // A plan by knots minimises the knot problem's cost at the trajectory's knots.
            let mut knots = vec![0.0; c.optimizer.waypoints * n];
            let mut knot_grad = knots.clone();
            c.sample(trajectory, &mut knots);
            let result = c.optimizer.objective(features, weights, &knots, &mut knot_grad)?;
            c.spread(&knot_grad, grad);
            return Ok(result);
        }
        self.trial.copy_from_slice(trajectory);
        let result = self.evaluate(features, weights, Buffer::Trial, Derivatives::Gradient);
        grad.copy_from_slice(&self.trial_grad);
        Ok(result)
    }

    /// [`TrajectoryOptimizer::objective`] of `trajectory` taken apart, since it is linear in the
    /// weights: each feature's term at unit weight into `terms` (one per feature), and the
    /// returned penalty (clearance, collision and step penalties, which no weight scales). The
    /// objective at weights w is Σ w_k·terms[k] (over w_k ≠ 0) + the penalty: a plan's cost at
    /// any weights for the price of about one evaluation of its objective.
    pub fn objective_terms(&mut self, features: &mut FeatureSet, trajectory: &[f64], terms: &mut [f64]) -> Result<f64> {
        let (n, m) = (self.dof, self.waypoints);
        if features.model().nq() != n {
            return Err(PhriError::invalid("features", "belong to a robot with a different number of joints"));
        }
        if trajectory.len() != m * n {
            return Err(PhriError::shape("trajectory", format!("({m}, {n})"), format!("{} values", trajectory.len())));
        }
        if terms.len() != features.len() {
            return Err(PhriError::shape("terms", format!("({},)", features.len()), format!("{} values", terms.len())));
        }
        check_finite("trajectory", trajectory)?;
        if let Some(c) = self.coarse.as_mut().filter(|c| c.knots) {
            let mut knots = vec![0.0; c.optimizer.waypoints * n];
            c.sample(trajectory, &mut knots);
            return c.optimizer.objective_terms(features, &knots, terms);
        }
        self.trial.copy_from_slice(trajectory);
        features.cost_terms_unchecked(&self.trial, m, self.params.smoothing, terms);
        // With every weight 0 the evaluation is the penalties alone.
        let zeros = vec![0.0; features.len()];
        let (_, penalty) = self.evaluate(features, &zeros, Buffer::Trial, Derivatives::Gradient);
        match features.take_failure() {
            Some(e) => Err(e),
            None => Ok(penalty),
        }
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
        let n = self.dof;
        if features.model().nq() != n {
            return Err(PhriError::invalid("features", "belong to a robot with a different number of joints"));
        }
        check_vector("weights", weights, features.len())?;
        // A negative weight on a sum of squared steps (efficiency) has no minimum: the cost falls
        // without bound as the path lengthens, and the straight line, where the solver would stop
        // with a zero gradient, is its maximum.
        for (k, e) in features.resolution_exponents().into_iter().enumerate() {
            if e == -1 && weights[k] < 0.0 {
                return Err(PhriError::invalid(
                    "weights",
                    format!(
                        "[{k}] ('{}') must be >= 0, got {}: a negative weight on a sum of squared steps has no minimum",
                        features.names()[k],
                        weights[k]
                    ),
                ));
            }
        }
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
        pin_ends_within_limits(&mut self.traj, start, goal, &self.lower, &self.upper);
        let began = Instant::now();
        let deadline = self.params.max_time.map(|t| began + t);
        features.take_failure();
        let (iterations, coarse_iterations, evaluations, cost, penalty, converged) =
            self.solve_prepared(features, weights, deadline, start_mode, levels);
        if let Some(e) = features.take_failure() {
            // A feature failed: the plan is not a solve of the problem asked.
            return Err(e);
        }
        let traj = std::mem::take(&mut self.traj);
        let max_violation = self.violation(features, &traj);
        let (max_step_excess, relative_step_excess) = collision::executed_step_excess(&self.params.max_step, &traj);
        self.traj = traj;
        let step_ok = relative_step_excess <= STEP_TOLERANCE;
        let step_excess_ratio = relative_step_excess;
        let feasible = max_violation <= CLEARANCE_TOLERANCE && step_ok;
        Ok(TrajoptInfo {
            iterations,
            coarse_iterations,
            evaluations,
            cost,
            penalty,
            max_violation,
            max_step_excess,
            step_excess_ratio,
            feasible,
            converged,
            seconds: began.elapsed().as_secs_f64(),
        })
    }

    /// Minimises from `traj` (checked, within the limits, start and goal in place): first the
    /// coarse levels as `start` says, then the Newton iteration on these waypoints; with `levels`, writes
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
        if self.by_knots() {
            // The plan is the knots' interpolation: nothing is left to optimise on the waypoints.
            let (iterations, coarse_iterations, evaluations, cost, penalty, converged) =
                self.solve_by_knots(features, weights, deadline, start, levels);
            self.coarse_converged = converged;
            return (iterations, coarse_iterations, evaluations, cost, penalty, converged);
        }
        let (coarse_iterations, coarse_converged) = match start {
            Start::Plan => (0, true),
            _ => self.coarse_correction(features, weights, deadline, start, levels),
        };
        let (iterations, evaluations, cost, penalty, converged) = self.run_newton(features, weights, deadline);
        self.coarse_converged = coarse_converged;
        (iterations, coarse_iterations, evaluations, cost, penalty, converged)
    }
}

/// Puts `start` and `goal` at the ends of `traj` (waypoints × n) and clamps its interior into the
/// joint limits `lower`, `upper`.
fn pin_ends_within_limits(traj: &mut [f64], start: &[f64], goal: &[f64], lower: &[f64], upper: &[f64]) {
    let n = start.len();
    let m = traj.len() / n;
    traj[..n].copy_from_slice(start);
    traj[(m - 1) * n..].copy_from_slice(goal);
    for i in 1..m - 1 {
        for j in 0..n {
            let k = i * n + j;
            traj[k] = traj[k].clamp(lower[j], upper[j]);
        }
    }
}
