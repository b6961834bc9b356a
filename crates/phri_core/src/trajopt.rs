//! Gradient trajectory optimisation of eq. 4: ξ_R = argmin_ξ w·Φ(ξ) over N waypoints with the start
//! and goal fixed and the joint position limits as bounds.
//!
//! Solver: projected L-BFGS whose initial inverse Hessian is the banded smoothness metric (the
//! efficiency term's Hessian, a tridiagonal second-difference matrix per joint), so the first step
//! is a covariant, CHOMP-style step and later steps add curvature from the history. The metric is
//! factored once per problem size and applied in O(N) per iteration.
//!
//! The hinge features (laptop, human, |·| of coffee) are used with their subgradients (zero on the
//! flat side and at the kink; see `features.rs`), Huber-smoothed with width `smoothing` during the
//! optimisation so that L-BFGS sees a C¹ cost. The table clearance is a quadratic penalty
//! ρ·Σ max(0, z_min − z)² on each clearance frame's height at every waypoint; with ρ = 10³ per m²
//! the optimum violates it by about w_table/(2ρ) = 5·10⁻⁴ m per unit weight (the documented
//! tolerance is 10⁻³ m), and the reported `max_violation` is the check.

use std::time::{Duration, Instant};

use nalgebra::Matrix6xX;

use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::features::FeatureSet;
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

/// Tuning of the optimiser; `Default` gives the documented defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajoptParams {
    /// Iteration cap.
    pub max_iterations: usize,
    /// Wall-time cap; `None` (the default) keeps results deterministic.
    pub max_time: Option<Duration>,
    /// Stop when the largest projected-gradient entry is below this [cost per rad].
    pub gradient_tolerance: f64,
    /// Stop when an iteration lowers the cost by less than this fraction of it.
    pub relative_tolerance: f64,
    /// L-BFGS history length.
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
}

impl Default for TrajoptParams {
    fn default() -> Self {
        TrajoptParams {
            max_iterations: 500,
            max_time: None,
            gradient_tolerance: 1e-6,
            relative_tolerance: 1e-10,
            memory: 20,
            smoothing: 0.05,
            clearance: Vec::new(),
            max_step: Vec::new(),
            step_weight: 1e3,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajoptInfo {
    pub iterations: usize,
    /// Cost evaluations (each one Φ and ∇Φ).
    pub evaluations: usize,
    /// Final cost w·Φ + penalty.
    pub cost: f64,
    /// Final penalty part of the cost.
    pub penalty: f64,
    /// Largest clearance violation at the solution [m] (0 when satisfied or unused).
    pub max_violation: f64,
    /// Met a tolerance (rather than an iteration or time cap).
    pub converged: bool,
    /// Wall time [s].
    pub seconds: f64,
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
    s_hist: Vec<Vec<f64>>,
    y_hist: Vec<Vec<f64>>,
    rho_hist: Vec<f64>,
    alpha: Vec<f64>,
    data: RobotData,
    jacobian: Matrix6xX<f64>,
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
        Ok(TrajectoryOptimizer {
            lower: model.lower_limits(),
            upper: model.upper_limits(),
            data: model.data(),
            jacobian: Matrix6xX::zeros(dof),
            s_hist: vec![vec![0.0; dim]; params.memory],
            y_hist: vec![vec![0.0; dim]; params.memory],
            rho_hist: vec![0.0; params.memory],
            alpha: vec![0.0; params.memory],
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
        })
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

    /// Cost and gradient of `traj` into `grad` (full N × n; callers use the interior).
    fn evaluate(&mut self, features: &mut FeatureSet, weights: &[f64], which: Buffer) -> (f64, f64) {
        let (traj, grad) = match which {
            Buffer::Current => (&self.traj, &mut self.grad),
            Buffer::Trial => (&self.trial, &mut self.trial_grad),
        };
        let mut cost = features.weighted_cost_gradient_unchecked(traj, self.waypoints, weights, grad, self.params.smoothing);
        let mut penalty = 0.0;
        if !self.params.clearance.is_empty() {
            let model = features.model();
            let n = self.dof;
            for i in 1..self.waypoints - 1 {
                model.forward_kinematics_unchecked(&traj[i * n..(i + 1) * n], &mut self.data);
                for c in &self.params.clearance {
                    let gap = c.min_z - model.frame_pose(c.frame, &self.data).translation.z;
                    if gap > 0.0 {
                        penalty += c.weight * gap * gap;
                        model.frame_jacobian_unchecked(c.frame, &self.data, &mut self.jacobian);
                        for j in 0..n {
                            grad[i * n + j] -= 2.0 * c.weight * gap * self.jacobian[(2, j)];
                        }
                    }
                }
            }
            cost += penalty;
        }
        if !self.params.max_step.is_empty() {
            let (n, w) = (self.dof, self.params.step_weight);
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
        for i in 0..self.waypoints {
            model.forward_kinematics_unchecked(&traj[i * n..(i + 1) * n], &mut self.data);
            for c in &self.params.clearance {
                worst = worst.max(c.min_z - model.frame_pose(c.frame, &self.data).translation.z);
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

    /// Minimises w·Φ(ξ) (+ clearance penalty) from `init` (warm start; `None` = straight line),
    /// with `start` and `goal` fixed, writing the plan into `out` (N × n row-major).
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
        if features.model().nq() != n {
            return Err(PhriError::invalid("features", "belong to a robot with a different number of joints"));
        }
        check_vector("weights", weights, features.len())?;
        check_vector("start", start, n)?;
        check_vector("goal", goal, n)?;
        if out.len() != m * n {
            return Err(PhriError::shape("out", format!("({m}, {n})"), format!("{} values", out.len())));
        }
        for (arg, q) in [("start", start), ("goal", goal)] {
            features.model().check_within_limits(arg, q)?;
        }
        match init {
            Some(x) => {
                if x.len() != m * n {
                    return Err(PhriError::shape("init", format!("({m}, {n})"), format!("{} values", x.len())));
                }
                check_finite("init", x)?;
                self.traj.copy_from_slice(x);
            }
            None => {
                let mut line = std::mem::take(&mut self.traj);
                self.straight_line(start, goal, &mut line);
                self.traj = line;
            }
        }
        self.traj[..n].copy_from_slice(start);
        self.traj[(m - 1) * n..].copy_from_slice(goal);
        for i in 1..m - 1 {
            for j in 0..n {
                let k = i * n + j;
                self.traj[k] = self.traj[k].clamp(self.lower[j], self.upper[j]);
            }
        }
        Ok(self.run(features, weights, out))
    }

    fn run(&mut self, features: &mut FeatureSet, weights: &[f64], out: &mut [f64]) -> TrajoptInfo {
        let began = Instant::now();
        let (n, m) = (self.dof, self.waypoints);
        let (lo, hi) = (n, (m - 1) * n); // interior range
        let (mut cost, mut penalty) = self.evaluate(features, weights, Buffer::Current);
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
            if self.params.max_time.is_some_and(|t| began.elapsed() >= t) {
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
                (new_cost, new_penalty) = self.evaluate(features, weights, Buffer::Trial);
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
        out.copy_from_slice(&self.traj);
        let traj = std::mem::take(&mut self.traj);
        let max_violation = self.violation(features, &traj);
        self.traj = traj;
        TrajoptInfo { iterations, evaluations, cost, penalty, max_violation, converged, seconds: began.elapsed().as_secs_f64() }
    }
}

#[derive(Clone, Copy)]
enum Buffer {
    Current,
    Trial,
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}
