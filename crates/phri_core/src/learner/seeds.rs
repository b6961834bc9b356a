//! Seed plans on a grid of the learned weights (`LearnerParams::seeds`): each replan starts from
//! whichever of the current plan and the seeds costs least at the new weights.

use super::MAX_SEEDS;
use crate::error::{PhriError, Result};
use crate::features::FeatureSet;
use crate::trajopt::{PlanLevels, TrajectoryOptimizer};
use crate::update::WeightUpdate;

/// Plans converged on a grid of the learned weights (see [`LearnerParams::seeds`]).
#[derive(Default)]
pub(super) struct Seeds {
    pub(super) plans: Vec<PlanLevels>,
}

impl Seeds {
    /// `per_weight` values of every learned weight between its bounds, the other weights as in
    /// `weights`, each planned cold to convergence.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn plan(
        per_weight: usize,
        update: &WeightUpdate,
        weights: &[f64],
        features: &mut FeatureSet,
        optimizer: &mut TrajectoryOptimizer,
        start: &[f64],
        goal: &[f64],
    ) -> Result<Self> {
        if per_weight == 0 {
            return Ok(Seeds::default());
        }
        if per_weight == 1 {
            return Err(PhriError::invalid("seeds", "must be 0 (none) or at least 2 values per learned weight, got 1"));
        }
        let p = update.params();
        let learned: Vec<usize> = (0..weights.len()).filter(|&k| p.learned[k]).collect();
        if let Some(&k) = learned.iter().find(|&&k| !(p.lower[k].is_finite() && p.upper[k].is_finite())) {
            return Err(PhriError::invalid(
                "seeds",
                format!("need finite bounds for every learned weight; weight {k} has [{}, {}]", p.lower[k], p.upper[k]),
            ));
        }
        let count = (per_weight as f64).powi(learned.len() as i32);
        if count > MAX_SEEDS as f64 {
            return Err(PhriError::invalid(
                "seeds",
                format!(
                    "{per_weight} per learned weight make {count} plans for {} learned weights, more than {MAX_SEEDS}",
                    learned.len()
                ),
            ));
        }
        let mut seeds = Seeds::default();
        for index in 0..count as usize {
            let mut w = weights.to_vec();
            let mut rest = index;
            for &k in &learned {
                let i = rest % per_weight;
                rest /= per_weight;
                w[k] = p.lower[k] + (p.upper[k] - p.lower[k]) * i as f64 / (per_weight - 1) as f64;
            }
            let mut plan = optimizer.plan_levels();
            optimizer.solve_levels(features, &w, start, goal, None, &mut plan)?;
            seeds.plans.push(plan);
        }
        Ok(seeds)
    }
}
