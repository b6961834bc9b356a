//! The Newton iteration: a projected, damped Newton method on a model of the cost that keeps its
//! kinks piecewise.
//!
//! Each step minimises the model m(d) = g_sᵀd + ½dᵀ(H_s + D_λ)d + Σ_k ½c_k·max(0, f_k + a_k·d)²
//! (the smooth part by its second derivatives, the kinked terms as pieces: see `pieces`) by a
//! damped semismooth Newton iteration: solve with the pieces that are on, minimise the model
//! exactly along the way to that solution, re-mark the pieces, until they agree (refactoring only
//! from the first changed block). The damping D_λ = λ·(I + κT), T = tridiag(−1, 2, −1) ⊗ I the
//! smoothness metric, keeps the model positive definite where the Hessian is not, and makes a
//! heavily damped step a smooth, covariant deformation of the path (as in CHOMP) rather than a
//! jagged gradient step. Variables at a joint limit that the gradient or the step pushes outward
//! are held (projected Newton), and the line search on the true cost makes every step a descent
//! step.

use std::time::Instant;

use super::block_tridiagonal::{BlockCholesky, BlockTridiagonal, Damping};
use super::cost::{Buffer, Derivatives};
use super::pieces::{PieceModel, Steps};
use super::{KinematicCurvature, TrajectoryOptimizer};
use crate::features::FeatureSet;

/// Semismooth re-solves per Newton step at most, up to 45 waypoints. Each costs a factorisation
/// from the first changed block; more make the steps more exact but not the solve cheaper (the
/// outer line search keeps a step that stops short a descent step).
const MAX_INNER: usize = 3;

/// Semismooth re-solves per Newton step at most for `m` waypoints: [`MAX_INNER`], or one per 15
/// waypoints if more (more waypoints, more pieces that switch together).
fn max_inner(m: usize) -> usize {
    MAX_INNER.max(m / 15)
}

/// Weight κ of the smoothness metric in the Newton damping λ·(I + κT), T = tridiag(−1, 2, −1) ⊗ I
/// over the interior waypoints: a heavily damped step is then a smooth (covariant, CHOMP-like)
/// deformation of the whole path rather than a jagged gradient step at a few waypoints.
const DAMPING_METRIC: f64 = 100.0;

/// Least damping, relative to the curvature scale, once a factorisation has failed (then ×4 until
/// one succeeds).
const INDEFINITE_DAMPING: f64 = 1e-5;

/// Damping, relative to the curvature scale, at or below which a step counts as a Newton step: a
/// small predicted or actual decrease means convergence only then (a heavily damped step is short
/// whatever is left to gain), and damping harder starts from at least this.
const LOW_DAMPING: f64 = 1e-4;

/// [`KinematicCurvature::Settled`] switches to the exact curvature once a step's pieces agree with
/// it and it predicts a decrease below this fraction of the cost.
const SETTLED_DECREASE: f64 = 1e-3;

/// Consecutive steps in which the settled kinematic curvature needs its damping raised beyond
/// [`LOW_DAMPING`] before [`KinematicCurvature::Settled`] drops it for the rest of the solve.
const INDEFINITE_STEPS: usize = 2;

/// The Newton damping for λ (see [`DAMPING_METRIC`]).
fn damping(lambda: f64) -> Damping {
    Damping { diagonal: lambda, difference: DAMPING_METRIC * lambda }
}

/// Where a Newton solve left off: its damping relative to the curvature scale (0: not started),
/// whether its model had the kinematic curvature, and whether [`KinematicCurvature::Settled`] had
/// dropped it (a solve that goes on from here does not take it on again: the exact Hessian was
/// found indefinite at this problem's iterate).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) struct SolverState {
    pub(super) lambda: f64,
    pub(super) exact: bool,
    pub(super) fell_back: bool,
}

/// The Newton iteration's workspace, sized once for N waypoints of n joints.
#[derive(Debug, Clone)]
pub(super) struct NewtonWorkspace {
    /// The step d of the current model minimisation, and the next candidate (N × n).
    pub(super) direction: Vec<f64>,
    candidate: Vec<f64>,
    /// (H_s + D_λ)·direction, (H_s + D_λ)·v, and the smooth part of the gradient.
    hd: Vec<f64>,
    hv: Vec<f64>,
    smooth_grad: Vec<f64>,
    /// The Newton system of the current inner iteration, its right-hand side and factorisation.
    system: BlockTridiagonal,
    rhs: Vec<f64>,
    cholesky: BlockCholesky,
    /// Variables held at a joint limit (N × n; the start and goal always).
    fixed: Vec<bool>,
    pieces: PieceModel,
}

impl NewtonWorkspace {
    pub(super) fn new(n: usize, waypoints: usize) -> Self {
        let len = waypoints * n;
        NewtonWorkspace {
            direction: vec![0.0; len],
            candidate: vec![0.0; len],
            hd: vec![0.0; len],
            hv: vec![0.0; len],
            smooth_grad: vec![0.0; len],
            system: BlockTridiagonal::new(n, waypoints),
            rhs: vec![0.0; len],
            cholesky: BlockCholesky::new(n, waypoints - 2),
            fixed: vec![false; len],
            pieces: PieceModel::default(),
        }
    }
}

/// The state of one run of the Newton iteration.
struct Run {
    cost: f64,
    penalty: f64,
    evaluations: usize,
    iterations: usize,
    converged: bool,
    /// Mean curvature on the Hessian's diagonal: the damping's unit.
    scale: f64,
    lambda: f64,
    lambda_min: f64,
    lambda_max: f64,
    /// Largest free gradient entry.
    largest: f64,
    /// The settled kinematic curvature was dropped for the rest of the run.
    fell_back: bool,
    /// Consecutive steps whose exact model needed more damping than asked, beyond a Newton step's.
    indefinite: usize,
    /// The damping asked for at the first of those steps: where Gauss–Newton goes on from.
    lambda_before_indefinite: f64,
}

impl TrajectoryOptimizer {
    /// Projected Newton from `traj` (see the module docs). Returns (iterations, evaluations, cost,
    /// penalty, converged).
    pub(super) fn run_newton(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
    ) -> (usize, usize, f64, f64, bool) {
        let mut run = self.begin_newton(features, weights);
        while run.iterations < self.params.max_iterations {
            if run.largest <= self.params.gradient_tolerance {
                run.converged = true;
                break;
            }
            // A feature that failed (e.g. a Python feature that raised) ends the solve: it reports
            // the error.
            if deadline.is_some_and(|d| Instant::now() >= d)
                || self.cancel.as_ref().is_some_and(|c| c.requested())
                || features.failed()
            {
                break;
            }
            run.iterations += 1;
            if !self.newton_iteration(features, weights, &mut run) {
                break;
            }
        }
        self.state = SolverState { lambda: run.lambda / run.scale, exact: self.exact_curvature, fell_back: run.fell_back };
        (run.iterations, run.evaluations, run.cost, run.penalty, run.converged)
    }

    /// Evaluates the start with its model and sets the damping: from where the solve to resume
    /// left off, else the least.
    fn begin_newton(&mut self, features: &mut FeatureSet, weights: &[f64]) -> Run {
        let (n, m) = (self.dof, self.waypoints);
        let resume = self.resume.take();
        self.exact_curvature = self.params.kinematic_curvature == KinematicCurvature::Exact || resume.is_some_and(|r| r.exact);
        let (cost, penalty) = self.evaluate(features, weights, Buffer::Current, Derivatives::Hessian);
        // Damping relative to the mean curvature on the diagonal.
        let scale = (1..m - 1).map(|i| (0..n).map(|j| self.model.hess.diag(i)[j * n + j].abs()).sum::<f64>()).sum::<f64>()
            / ((m - 2) * n) as f64;
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { 1.0 };
        let (lambda_min, lambda_max) = (1e-8 * scale, 1e12 * scale);
        let lambda = resume.map_or(lambda_min, |r| (r.lambda * scale).clamp(lambda_min, lambda_max));
        let largest = self.mark_fixed();
        Run {
            cost,
            penalty,
            evaluations: 1,
            iterations: 0,
            converged: false,
            scale,
            lambda,
            lambda_min,
            lambda_max,
            largest,
            fell_back: resume.is_some_and(|r| r.fell_back),
            indefinite: 0,
            lambda_before_indefinite: lambda,
        }
    }

    /// One outer iteration: a model step, then the line search on the true cost. Returns whether
    /// the run goes on.
    fn newton_iteration(&mut self, features: &mut FeatureSet, weights: &[f64], run: &mut Run) -> bool {
        let (lo, hi) = (self.dof, (self.waypoints - 1) * self.dof); // interior range
        let cost = run.cost;
        run.lambda = (run.lambda * 0.25).max(run.lambda_min);
        let asked = run.lambda;
        let Some((predicted, consistent)) = self.projected_step(&mut run.lambda, run.scale, run.lambda_max) else {
            return false;
        };
        // The exact Hessian can be indefinite for a step or two on the way to the optimum; where
        // it stays so, no quadratic end comes of the damping it needs, only a linear crawl (the
        // table task with the collision model: 48 iterations for 1e-6 of the cost). Gauss–Newton
        // then, at the damping asked for before the exact model raised it.
        let raised = self.model.exact && run.lambda > asked.max(LOW_DAMPING * run.scale);
        if raised && run.indefinite == 0 {
            run.lambda_before_indefinite = asked;
        }
        run.indefinite = if raised { run.indefinite + 1 } else { 0 };
        if run.indefinite >= INDEFINITE_STEPS && self.drop_settled_curvature(features, weights, &mut run.fell_back) {
            run.lambda = run.lambda_before_indefinite;
            return true;
        }
        let settled = consistent && predicted <= SETTLED_DECREASE * cost.abs() && !run.fell_back;
        if settled && self.params.kinematic_curvature == KinematicCurvature::Settled {
            // The next models (from the trial points on) include the kinematic curvature.
            self.exact_curvature = true;
        }
        // The slope of the projected path clip(x + α·d) at α = 0: the variables strictly inside
        // the box move along d, and those at a bound that d pushes out are held.
        let slope = dot(&self.grad[lo..hi], &self.newton.direction[lo..hi]);
        let tolerance = self.params.relative_tolerance * cost.abs().max(1e-300);
        if consistent && predicted <= tolerance && run.lambda <= LOW_DAMPING * run.scale {
            // The model predicts no further decrease worth a step: converged.
            run.converged = true;
            return false;
        }
        if !(slope < 0.0) {
            // Not a descent direction (the pieces' model is only linearised): damp harder, or
            // first drop a kinematic curvature taken on too early.
            if !self.drop_settled_curvature(features, weights, &mut run.fell_back) {
                run.lambda = (run.lambda * 16.0).max(LOW_DAMPING * run.scale);
            }
            return true;
        }
        let search = self.line_search(features, weights, cost, slope);
        run.evaluations += search.evaluations;
        let Some((alpha, new_cost, new_penalty)) = search.accepted else {
            return self.after_failed_search(features, weights, run);
        };
        std::mem::swap(&mut self.traj, &mut self.trial);
        std::mem::swap(&mut self.grad, &mut self.trial_grad);
        std::mem::swap(&mut self.model, &mut self.trial_model);
        let decrease = cost - new_cost;
        run.cost = new_cost;
        run.penalty = new_penalty;
        run.largest = self.mark_fixed();
        // (A heavily damped step is short whatever is left to gain: not a sign of the end.)
        let done = alpha == 1.0
            && decrease <= self.params.relative_tolerance * new_cost.abs().max(1e-300)
            && run.lambda <= LOW_DAMPING * run.scale;
        run.converged = done;
        !done
    }

    /// No step along the model's direction lowered the cost: the model misleads at this damping.
    /// If it took on the kinematic curvature when the active set seemed settled, that was too
    /// early (the exact Hessian can be indefinite away from the optimum and mislead at any
    /// damping): go back to Gauss–Newton for the rest of the solve. Otherwise damp harder and try
    /// again. Returns whether the run goes on.
    fn after_failed_search(&mut self, features: &mut FeatureSet, weights: &[f64], run: &mut Run) -> bool {
        if self.drop_settled_curvature(features, weights, &mut run.fell_back) {
            return true;
        }
        run.lambda = (run.lambda * 16.0).max(LOW_DAMPING * run.scale);
        if run.lambda > run.lambda_max {
            run.converged = run.cost.is_finite(); // no step of any length helps: stationary
            return false;
        }
        true
    }

    /// The Newton step into `direction`, again without the variables at a bound that the first
    /// step pushes out (the gradient alone let it leave the box there, and clipped it would not be
    /// a descent direction). See [`TrajectoryOptimizer::newton_step`].
    fn projected_step(&mut self, lambda: &mut f64, scale: f64, lambda_max: f64) -> Option<(f64, bool)> {
        let step = self.newton_step(lambda, scale, lambda_max)?;
        if self.hold_variables_the_step_pushes_out() {
            return self.newton_step(lambda, scale, lambda_max);
        }
        Some(step)
    }

    /// The Newton step of one outer iteration into `direction`: the minimiser of the model, found by
    /// the damped semismooth Newton iteration of the module docs. Returns the model decrease
    /// m(0) − m(d) and whether the pieces agree with d, or None if no damping makes the system
    /// positive definite.
    fn newton_step(&mut self, lambda: &mut f64, scale: f64, lambda_max: f64) -> Option<(f64, bool)> {
        let len = self.dof * self.waypoints;
        for k in 0..len {
            self.newton.smooth_grad[k] = self.grad[k] - self.model.pen_grad[k];
        }
        'restart: loop {
            let steps = Steps { max_step: &self.params.max_step, weight: self.params.step_weight, traj: &self.traj };
            self.newton.pieces.prepare(&self.model.pieces, &steps);
            self.newton.direction.fill(0.0);
            self.newton.hd.fill(0.0);
            let mut decrease = 0.0;
            let mut changed_from: Option<usize> = Some(0);
            let mut factored_lambda = f64::NAN;
            let mut consistent = false;
            for _ in 0..max_inner(self.waypoints) {
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
                let Some((t, drop)) = self.model_line_step(*lambda) else {
                    // d already minimises the model.
                    consistent = true;
                    break;
                };
                decrease += drop;
                changed_from = self.newton.pieces.advance(t);
                if changed_from.is_none() && t < 1.0 - 1e-9 {
                    // Stopped short without a piece changing: rounding; d is as good as it gets.
                    consistent = t > 0.999;
                    break;
                }
            }
            return Some((decrease, consistent));
        }
    }

    /// Solves the factored system and moves `direction` to the model's minimum along the way to
    /// the solution, t·v with v = d* − d. Returns (t, the model's decrease), or None when t = 0.
    fn model_line_step(&mut self, lambda: f64) -> Option<(f64, f64)> {
        let n = self.dof;
        let len = n * self.waypoints;
        self.solve_system();
        // v = d* − d, A = ∇m_s(d)·v, B = vᵀ(H_s + D_λ)v.
        let ws = &mut self.newton;
        for k in 0..len {
            ws.candidate[k] -= ws.direction[k];
        }
        let mut hv = std::mem::take(&mut self.newton.hv);
        self.smooth_times(&self.newton.candidate, &mut hv, lambda);
        let ws = &mut self.newton;
        let (mut a, mut b) = (0.0, 0.0);
        for k in n..len - n {
            let v = ws.candidate[k];
            a += (ws.smooth_grad[k] + ws.hd[k]) * v;
            b += hv[k] * v;
        }
        ws.pieces.slopes(&self.model.pieces, !self.params.max_step.is_empty(), &ws.candidate);
        let (t, drop) = ws.pieces.line_minimum(a, b);
        if t == 0.0 {
            ws.hv = hv;
            return None;
        }
        for k in n..len - n {
            ws.direction[k] += t * ws.candidate[k];
            ws.hd[k] += t * hv[k];
        }
        ws.hv = hv;
        Some((t, drop))
    }

    /// The Newton system for the pieces that are on: `system` = smooth Hessian + their Gauss–Newton
    /// terms, `rhs` = −(smooth gradient + their linearised gradients).
    fn assemble(&mut self) {
        let ws = &mut self.newton;
        ws.system.diag.copy_from_slice(&self.model.hess.diag);
        ws.system.off.copy_from_slice(&self.model.hess.off);
        for k in 0..self.waypoints * self.dof {
            ws.rhs[k] = self.model.pen_grad[k] - self.grad[k];
        }
        let steps = Steps { max_step: &self.params.max_step, weight: self.params.step_weight, traj: &self.traj };
        ws.pieces.add_active(&self.model.pieces, &steps, &mut ws.system, &mut ws.rhs);
    }

    /// Factors `system` + λ·(I + κT) ([`damping`]), from block `from` on (earlier blocks kept from
    /// the last factorisation with the same λ), raising λ until it is positive definite. False if
    /// no λ ≤ `lambda_max` is.
    fn factor_system(&mut self, lambda: &mut f64, from: usize, scale: f64, lambda_max: f64) -> bool {
        let ws = &mut self.newton;
        let mut from = from;
        while *lambda <= lambda_max {
            if ws.cholesky.factor_from(&ws.system, 1, damping(*lambda), &ws.fixed, from) {
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
        let ws = &mut self.newton;
        for k in 0..m * n {
            let interior = k >= n && k < (m - 1) * n;
            ws.candidate[k] = if interior && !ws.fixed[k] { ws.rhs[k] } else { 0.0 };
        }
        ws.cholesky.solve(&mut ws.candidate, 1);
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

    /// Marks the interior variables held at a bound (gradient pushing outward) and returns the
    /// largest remaining gradient entry.
    fn mark_fixed(&mut self) -> f64 {
        let n = self.dof;
        let fixed = &mut self.newton.fixed;
        let mut largest: f64 = 0.0;
        fixed.fill(true);
        for i in 1..self.waypoints - 1 {
            for j in 0..n {
                let k = i * n + j;
                let g = self.grad[k];
                let held = (self.traj[k] <= self.lower[j] && g > 0.0) || (self.traj[k] >= self.upper[j] && g < 0.0);
                fixed[k] = held;
                if !held {
                    largest = largest.max(g.abs());
                }
            }
        }
        largest
    }

    /// Marks as fixed the free interior variables at a bound that `direction` pushes further out;
    /// returns whether there were any.
    fn hold_variables_the_step_pushes_out(&mut self) -> bool {
        let n = self.dof;
        let ws = &mut self.newton;
        let mut any = false;
        for i in 1..self.waypoints - 1 {
            for j in 0..n {
                let k = i * n + j;
                let (x, d) = (self.traj[k], ws.direction[k]);
                if !ws.fixed[k] && ((x <= self.lower[j] && d < 0.0) || (x >= self.upper[j] && d > 0.0)) {
                    ws.fixed[k] = true;
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
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
