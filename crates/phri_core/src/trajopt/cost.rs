//! The cost the optimiser minimises: the planning objective w·Φ(ξ) of eq. 4 with the kinked
//! features Huber-smoothed, plus the clearance penalty ρ·Σ max(0, z_min − z)² and the max_step
//! penalty; its gradient; and, for the Newton model, its second-order data ([`Model`], in `newton_model`).
//!
//! The penalties are quadratic so that the cost stays C¹: with ρ = 10³ per m² the optimum violates
//! a clearance by about w_table/(2ρ) = 5·10⁻⁴ m per unit weight, and the reported `max_violation`
//! is the check.

use nalgebra::{Matrix6xX, Vector3};

use super::newton_model::Model;
use super::params::Clearance;
use super::TrajectoryOptimizer;
use crate::data::RobotData;
use crate::features::{FeatureSet, SecondOrder};
use crate::kinematics::position_hessian;

/// How much of the cost an evaluation computes.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Derivatives {
    Gradient,
    Hessian,
}

/// Which trajectory an evaluation reads (and whose gradient and model it writes).
#[derive(Clone, Copy)]
pub(super) enum Buffer {
    Current,
    Trial,
}

/// Kinematics scratch of the penalties.
#[derive(Clone)]
pub(super) struct Scratch {
    pub(super) data: RobotData,
    pub(super) jacobian: Matrix6xX<f64>,
    /// An n × n Hessian of a frame's height.
    pub(super) hz: Vec<f64>,
}

impl TrajectoryOptimizer {
    /// Cost (and derivatives, per `level`) of a buffer; the gradient covers all N × n entries.
    /// With `Derivatives::Hessian` the buffer's [`Model`] receives the smooth part's Hessian, the
    /// penalties' gradient, and every clearance's linearisation (active or not). Returns (cost,
    /// penalty).
    pub(super) fn evaluate(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        which: Buffer,
        level: Derivatives,
    ) -> (f64, f64) {
        let (traj, grad, model) = match which {
            Buffer::Current => (&self.traj, &mut self.grad, &mut self.model),
            Buffer::Trial => (&self.trial, &mut self.trial_grad, &mut self.trial_model),
        };
        features.set_kinematic_curvature(self.exact_curvature);
        let (smoothing, m) = (self.params.smoothing, self.waypoints);
        let mut model = match level {
            Derivatives::Hessian => Some(model),
            Derivatives::Gradient => None,
        };
        let mut cost = match model.as_deref_mut() {
            Some(model) => {
                model.exact = self.exact_curvature;
                model.hess.clear();
                let hess = &mut model.hess;
                let second_order =
                    SecondOrder { segment_hessian: &mut |i, h| hess.add_segment(i, h.matrix()), pieces: Some(&mut model.pieces) };
                features.weighted_cost_unchecked(traj, m, weights, Some(grad), Some(second_order), smoothing)
            }
            None => features.weighted_cost_unchecked(traj, m, weights, Some(grad), None, smoothing),
        };
        if let Some(model) = model.as_deref_mut() {
            model.pen_grad.fill(0.0);
        }
        let mut penalty = 0.0;
        if !self.params.clearance.is_empty() {
            let exact = self.exact_curvature;
            penalty =
                clearance_penalty(&self.params.clearance, &mut self.scratch, features, traj, grad, model.as_deref_mut(), exact);
            cost += penalty;
        }
        if let Some(params) = &self.params.collision {
            let robot = features.model();
            let collision_penalty =
                super::collision::collision_penalty(params, robot, &mut self.collision_scratch, traj, grad, model.as_deref_mut());
            penalty += collision_penalty;
            cost += collision_penalty;
        }
        if !self.params.max_step.is_empty() {
            let pen_grad = model.map(|model| &mut model.pen_grad[..]);
            let step_penalty = step_penalty(&self.params.max_step, self.params.step_weight, traj, grad, pen_grad);
            penalty += step_penalty;
            cost += step_penalty;
        }
        (cost, penalty)
    }

    /// Largest violation of a clearance (at the waypoints) or of a collision margin (along the
    /// executed curve) of a trajectory [m]; notes the pair closest to its margin.
    pub(super) fn violation(&mut self, features: &FeatureSet, traj: &[f64]) -> f64 {
        let model = features.model();
        let n = self.dof;
        let mut worst: f64 = 0.0;
        self.worst_pair = None;
        if let Some(params) = &self.params.collision {
            self.worst_pair = super::collision::executed_worst(params, model, &mut self.collision_scratch, traj);
            if let Some(v) = &self.worst_pair {
                worst = worst.max(v.margin - v.distance);
            }
        }
        if self.params.clearance.is_empty() {
            return worst;
        }
        for i in 0..self.waypoints {
            model.forward_kinematics_unchecked(&traj[i * n..(i + 1) * n], &mut self.scratch.data);
            for c in &self.params.clearance {
                worst = worst.max(c.min_z - model.frame_pose(c.frame, &self.scratch.data).translation.z);
            }
        }
        worst
    }
}

/// The clearance penalty Σ ρ·max(0, z_min − z)² over the interior waypoints of `traj` (the
/// waypoints' kinematics of the evaluation that `features` just made), its gradient added to
/// `grad`; with `model`, each clearance's linearisation as a piece, the active ones' gradient in
/// `pen_grad`, and with `exact` their kinematic curvature in `hess`.
fn clearance_penalty(
    clearance: &[Clearance],
    scratch: &mut Scratch,
    features: &mut FeatureSet,
    traj: &[f64],
    grad: &mut [f64],
    mut model: Option<&mut Model>,
    exact: bool,
) -> f64 {
    let robot = features.model().clone();
    let n = robot.nq();
    let mut penalty = 0.0;
    for i in 1..traj.len() / n - 1 {
        let data = features.waypoint_data(traj, i);
        for c in clearance {
            let gap = c.min_z - robot.frame_pose(c.frame, data).translation.z;
            if !(gap > 0.0 || model.is_some()) {
                continue;
            }
            robot.frame_jacobian_unchecked(c.frame, data, &mut scratch.jacobian);
            if let Some(model) = model.as_deref_mut() {
                // ρ·gap² = ½·2ρ·gap², gap varying as gap − ∂z/∂q·Δq.
                let jac = &scratch.jacobian;
                model.pieces.set_segment(i);
                model.pieces.push(1.0, gap, 2.0 * c.weight, |j| -jac[(2, j)]);
            }
            if gap > 0.0 {
                penalty += c.weight * gap * gap;
                for j in 0..n {
                    let g = -2.0 * c.weight * gap * scratch.jacobian[(2, j)];
                    grad[i * n + j] += g;
                    if let Some(model) = model.as_deref_mut() {
                        model.pen_grad[i * n + j] += g;
                    }
                }
                if let Some(model) = model.as_deref_mut().filter(|_| exact) {
                    // The curvature part of ∂²(ρ·gap²) = 2ρ·∇z·∇zᵀ − 2ρ·gap·∂²z; the
                    // Gauss–Newton part enters the Newton model with the active set.
                    position_hessian(&scratch.jacobian, &Vector3::z(), &mut scratch.hz);
                    let block = model.hess.diag_mut(i);
                    for (b, h) in block.iter_mut().zip(&scratch.hz) {
                        *b -= 2.0 * c.weight * gap * h;
                    }
                }
            }
        }
    }
    penalty
}

/// The step limit of segment `i` (of `m` waypoints) for a joint's `max_step` [rad]: two thirds of
/// it on the first and last segments, where the executed cubic starts or ends at rest and so runs
/// up to 1.5 times its chord's speed (see `collision::executed_step_excess`).
#[inline]
pub(super) fn segment_step(max_step: f64, i: usize, m: usize) -> f64 {
    if i == 1 || i == m - 1 {
        max_step * (2.0 / 3.0)
    } else {
        max_step
    }
}

/// The max_step penalty Σ ρ·max(0, |q_i,j − q_{i−1},j| − limit_j)² of `traj`, its gradient added to
/// `grad` (and to `pen_grad`, the Newton model's share of the pieces that are on).
fn step_penalty(max_step: &[f64], weight: f64, traj: &[f64], grad: &mut [f64], mut pen_grad: Option<&mut [f64]>) -> f64 {
    let n = max_step.len();
    let m = traj.len() / n;
    let mut penalty = 0.0;
    for i in 1..m {
        for (j, limit) in max_step.iter().enumerate() {
            let d = traj[i * n + j] - traj[(i - 1) * n + j];
            let excess = d.abs() - segment_step(*limit, i, m);
            if excess > 0.0 {
                penalty += weight * excess * excess;
                let g = 2.0 * weight * excess * d.signum();
                grad[i * n + j] += g;
                grad[(i - 1) * n + j] -= g;
                if let Some(pen_grad) = pen_grad.as_deref_mut() {
                    pen_grad[i * n + j] += g;
                    pen_grad[(i - 1) * n + j] -= g;
                }
            }
        }
    }
    penalty
}
