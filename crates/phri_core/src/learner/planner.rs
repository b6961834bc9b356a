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

/// A plan's objective as a function of the weights, which it is linear in
/// ([`TrajectoryOptimizer::objective_terms`]): comparing the warm start with a seed at new weights
/// then costs no evaluation.
struct PlanCost {
    plan: Vec<f64>,
    terms: Vec<f64>,
    penalty: f64,
}

impl PlanCost {
    fn of(optimizer: &mut TrajectoryOptimizer, features: &mut FeatureSet, plan: &[f64]) -> Result<Self> {
        let mut terms = vec![0.0; features.len()];
        let penalty = optimizer.objective_terms(features, plan, &mut terms)?;
        Ok(PlanCost { plan: plan.to_vec(), terms, penalty })
    }

    /// The plan's objective at `weights`.
    fn at(&self, weights: &[f64]) -> f64 {
        self.terms.iter().zip(weights).filter(|(_, w)| **w != 0.0).map(|(t, w)| w * t).sum::<f64>() + self.penalty
    }
}

/// Recent plans' costs kept for warm starts ([`Planner::prime`]): the plan the robot tracks and
/// the worker's candidate (the initial plan's, which a reset goes back to, is kept apart).
const PLAN_COSTS_KEPT: usize = 2;

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
    /// With seeds only: the seeds' plan costs, the initial plan's, and those of recent warm
    /// starts (newest last).
    seed_costs: Vec<PlanCost>,
    initial_cost: Option<PlanCost>,
    plan_costs: Vec<PlanCost>,
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
    ) -> Result<Self> {
        let mut planner = Planner {
            features,
            optimizer,
            start: start.to_vec(),
            goal: goal.to_vec(),
            seeds,
            replanned: levels.clone(),
            adopted: levels.clone(),
            initial: levels.clone(),
            levels,
            seed_costs: Vec::new(),
            initial_cost: None,
            plan_costs: Vec::new(),
        };
        for k in 0..planner.seeds.plans.len() {
            let cost = PlanCost::of(&mut planner.optimizer, &mut planner.features, planner.seeds.plans[k].plan())?;
            planner.seed_costs.push(cost);
        }
        if !planner.seed_costs.is_empty() {
            planner.initial_cost = Some(PlanCost::of(&mut planner.optimizer, &mut planner.features, planner.initial.plan())?);
        }
        Ok(planner)
    }

    /// Replans for `weights` into `replanned`, warm-started from `levels` or from the seed plan
    /// that costs least at `weights` if it costs less than `levels`' plan (the costs are the
    /// plans' terms at the new weights; `levels`' are worked out here unless primed).
    pub(super) fn solve(&mut self, weights: &[f64]) -> Result<TrajoptInfo> {
        let mut from_seed = None;
        if !self.seed_costs.is_empty() {
            let mut least = match self.known(self.levels.plan()).map(|cost| cost.at(weights)) {
                Some(here) => here,
                None => {
                    let cost = PlanCost::of(&mut self.optimizer, &mut self.features, self.levels.plan())?;
                    let here = cost.at(weights);
                    self.keep(cost);
                    here
                }
            };
            for (k, seed) in self.seed_costs.iter().enumerate() {
                let there = seed.at(weights);
                if there < least {
                    (least, from_seed) = (there, Some(k));
                }
            }
        }
        let init = from_seed.map_or(&self.levels, |seed| &self.seeds.plans[seed]);
        self.optimizer.solve_levels(&mut self.features, weights, &self.start, &self.goal, Some(init), &mut self.replanned)
    }

    /// With seeds, works out the cost of `plan` (a likely next warm start) ahead, so that the
    /// replan from it compares it with a seed at no cost: the worker primes each result after
    /// posting it, off the control side's wait.
    pub(super) fn prime(&mut self, plan: &[f64]) -> Result<()> {
        if self.seed_costs.is_empty() || self.known(plan).is_some() {
            return Ok(());
        }
        let cost = PlanCost::of(&mut self.optimizer, &mut self.features, plan)?;
        self.keep(cost);
        Ok(())
    }

    /// The cost of `plan` if it is the initial plan's or a recent one's.
    fn known(&self, plan: &[f64]) -> Option<&PlanCost> {
        self.initial_cost.iter().chain(&self.plan_costs).find(|c| c.plan == plan)
    }

    /// Keeps `cost`, forgetting the oldest beyond [`PLAN_COSTS_KEPT`].
    fn keep(&mut self, cost: PlanCost) {
        if self.plan_costs.len() == PLAN_COSTS_KEPT {
            self.plan_costs.remove(0);
        }
        self.plan_costs.push(cost);
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
