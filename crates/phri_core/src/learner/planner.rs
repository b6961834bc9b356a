//! The replanning half of Algorithm 1 (eq. 4, warm-started): the optimiser with its own copy of
//! the features, the seed plans, and the warm start (the plan the robot tracks with the coarse
//! plans it came from). The learner runs it inline or hands it to its replan worker.

use super::seeds::Seeds;
use crate::error::Result;
use crate::features::FeatureSet;
use crate::trajopt::{Cancellation, PlanLevels, TrajectoryOptimizer, TrajoptInfo};

/// Why a plan with `info` is infeasible, naming the pair closest to its margin (`optimizer`'s last
/// solve).
pub fn infeasibility(info: &TrajoptInfo, optimizer: &TrajectoryOptimizer) -> String {
    let mut reasons = Vec::new();
    if info.max_violation > crate::trajopt::CLEARANCE_TOLERANCE {
        match optimizer.closest_pair() {
            Some(v) => {
                reasons.push(format!("'{}' comes within {:.4} m of '{}' (margin {:.3} m)", v.body, v.distance, v.other, v.margin))
            }
            None => reasons.push(format!("a clearance is violated by {:.4} m", info.max_violation)),
        }
    }
    if info.step_excess_ratio > crate::trajopt::STEP_TOLERANCE {
        reasons.push(format!("a joint moves {:.4} rad per segment faster than max_step allows", info.max_step_excess));
    }
    if reasons.is_empty() {
        reasons.push("it violates a limit".into());
    }
    reasons.join("; ")
}

/// Replans over [0, T] from the original start to the goal.
pub(super) struct Planner {
    features: FeatureSet,
    optimizer: TrajectoryOptimizer,
    start: Vec<f64>,
    goal: Vec<f64>,
    /// Converged plans on a weight grid (`LearnerParams::seeds`).
    seeds: Seeds,
    /// The warm start of the next replan: the plan the robot tracks with its coarse plans (inline
    /// with a budget: the unfinished replan).
    pub(super) levels: PlanLevels,
    /// The last replan's output.
    pub(super) replanned: PlanLevels,
    /// The levels of the plan the robot tracks (the last adopted): a rejected replan goes back to
    /// them (inline; a worker never moves `levels` off the adopted plan).
    adopted: PlanLevels,
    /// The initial plan's levels, for `Learner::reset`.
    initial: PlanLevels,
    // Scratch of the seed comparison.
    seed_grad: Vec<f64>,
}

impl Planner {
    /// `levels`: the initial plan as `optimizer.solve_levels` wrote it.
    pub(super) fn new(
        features: FeatureSet,
        optimizer: TrajectoryOptimizer,
        start: &[f64],
        goal: &[f64],
        seeds: Seeds,
        levels: PlanLevels,
    ) -> Self {
        let len = levels.plan().len();
        Planner {
            features,
            optimizer,
            start: start.to_vec(),
            goal: goal.to_vec(),
            seeds,
            replanned: levels.clone(),
            adopted: levels.clone(),
            initial: levels.clone(),
            levels,
            seed_grad: vec![0.0; len],
        }
    }

    /// Replans for `weights` into `replanned`, warm-started from `levels` or, if its plan costs
    /// less at `weights`, the seed nearest them.
    pub(super) fn solve(&mut self, weights: &[f64]) -> Result<TrajoptInfo> {
        let mut init = &self.levels;
        if let Some(seed) = self.seeds.nearest(weights) {
            let seed = &self.seeds.plans[seed];
            let (here, _) = self.optimizer.objective(&mut self.features, weights, init.plan(), &mut self.seed_grad)?;
            let (there, _) = self.optimizer.objective(&mut self.features, weights, seed.plan(), &mut self.seed_grad)?;
            if there < here {
                init = seed;
            }
        }
        self.optimizer.solve_levels(&mut self.features, weights, &self.start, &self.goal, Some(init), &mut self.replanned)
    }

    /// Why the last replan is infeasible.
    pub(super) fn infeasibility(&self, info: &TrajoptInfo) -> String {
        infeasibility(info, &self.optimizer)
    }

    /// Inline: the robot tracks the replan now; the next replan starts from it.
    pub(super) fn adopt(&mut self) {
        std::mem::swap(&mut self.levels, &mut self.replanned);
        self.adopted.clone_from(&self.levels);
    }

    /// Inline with a budget: the next call goes on from the unfinished replan (not tracked).
    pub(super) fn keep_going(&mut self) {
        std::mem::swap(&mut self.levels, &mut self.replanned);
    }

    /// Inline: the replan was rejected; later replans start again from the plan the robot tracks.
    pub(super) fn reject(&mut self) {
        self.levels.clone_from(&self.adopted);
    }

    /// Back to the initial plan (`Learner::reset`).
    pub(super) fn restart(&mut self) {
        self.levels.clone_from(&self.initial);
        self.adopted.clone_from(&self.initial);
    }

    /// Worker: keeps the replan (a feasible result the control side may adopt) in `candidate`.
    pub(super) fn hold(&mut self, candidate: &mut PlanLevels) {
        std::mem::swap(&mut self.replanned, candidate);
    }

    /// Worker: the control side adopted `candidate`; later replans start from it.
    pub(super) fn promote(&mut self, candidate: &mut PlanLevels) {
        std::mem::swap(&mut self.levels, candidate);
    }

    /// See [`TrajectoryOptimizer::set_cancellation`].
    pub(super) fn set_cancellation(&mut self, cancel: Option<Cancellation>) {
        self.optimizer.set_cancellation(cancel);
    }
}
