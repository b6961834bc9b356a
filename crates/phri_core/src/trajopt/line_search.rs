//! The backtracking line search on the true cost that makes every Newton step a descent step: along
//! the projected path x(α) = clip(x + α·d) from α = 1, an Armijo test on the decrease the gradient
//! predicts for the move actually made, and a quadratic interpolation of the cost for the next α.

use super::cost::{Buffer, Derivatives};
use super::TrajectoryOptimizer;
use crate::features::FeatureSet;

/// Line-search trials per Newton step at most (α shrinks at least tenfold every two).
const MAX_BACKTRACKS: usize = 12;

/// Sufficient decrease: the cost must fall by this fraction of what the gradient predicts.
const ARMIJO: f64 = 1e-4;

/// What a line search found.
pub(super) struct LineSearch {
    /// Cost evaluations it made.
    pub(super) evaluations: usize,
    /// The accepted step, its cost and penalty (in the trial buffer), if any.
    pub(super) accepted: Option<(f64, f64, f64)>,
}

impl TrajectoryOptimizer {
    /// Searches along the Newton direction from the current plan of cost `cost`, with `slope` the
    /// cost's derivative along the projected path at α = 0 (negative).
    pub(super) fn line_search(&mut self, features: &mut FeatureSet, weights: &[f64], cost: f64, slope: f64) -> LineSearch {
        let (n, m) = (self.dof, self.waypoints);
        let (lo, hi) = (n, (m - 1) * n); // interior range
        let mut alpha = 1.0;
        for evaluations in 1..=MAX_BACKTRACKS {
            for i in 1..m - 1 {
                for j in 0..n {
                    let k = i * n + j;
                    self.trial[k] = (self.traj[k] + alpha * self.newton.direction[k]).clamp(self.lower[j], self.upper[j]);
                }
            }
            self.trial[..lo].copy_from_slice(&self.traj[..lo]);
            self.trial[hi..].copy_from_slice(&self.traj[hi..]);
            let (new_cost, new_penalty) = self.evaluate(features, weights, Buffer::Trial, Derivatives::Hessian);
            // Armijo along the projected path: a fraction of the decrease the gradient predicts
            // for the move actually made (shorter than α·d where the box cuts it).
            let moved: f64 = (lo..hi).map(|k| self.grad[k] * (self.trial[k] - self.traj[k])).sum();
            if new_cost.is_finite() && new_cost <= cost + ARMIJO * moved.min(0.0) {
                return LineSearch { evaluations, accepted: Some((alpha, new_cost, new_penalty)) };
            }
            alpha = next_alpha(alpha, cost, new_cost, slope);
        }
        LineSearch { evaluations: MAX_BACKTRACKS, accepted: None }
    }
}

/// The next trial step after `alpha` failed with `new_cost`: the minimiser of the quadratic through
/// the cost and slope at 0 and the cost at `alpha`, kept within [0.1, 0.5]·α.
fn next_alpha(alpha: f64, cost: f64, new_cost: f64, slope: f64) -> f64 {
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
    next.clamp(0.1 * alpha, 0.5 * alpha)
}
