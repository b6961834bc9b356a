//! Algorithm 1 of the paper, the online learner: it owns the current plan and the weights, and at
//! every sampled interaction deforms the plan (eq. 7), updates the weights (eq. 13) and replans
//! (eq. 4) warm-started, while `reference(t)` feeds the control law. With `learning = false` it is
//! the impedance baseline: interactions are recorded but the plan never changes.

use crate::deform::Deformation;
use crate::error::{check_finite, PhriError, Result};
use crate::features::FeatureSet;
use crate::interaction::InteractionDetector;
use crate::reference::{Interpolation, TimedTrajectory};
use crate::trajopt::{PlanLevels, TrajectoryOptimizer, TrajoptInfo};
use crate::update::{relevance, UpdateInfo, UpdateRule, WeightUpdate};

/// Timing and mode of the learner.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnerParams {
    /// Learn from interactions (Algorithm 1) or only record them (impedance baseline).
    pub learning: bool,
    /// Time between torque samples that may trigger an update [s]: 0.1 is the original's 10 Hz,
    /// 0.001 updates at every tick of a 1 kHz loop.
    pub sample_period: f64,
    /// Task duration T [s].
    pub duration: f64,
    /// Interpolation of the plan for the reference.
    pub interpolation: Interpolation,
    /// After a replan the reference blends into the new plan with each joint's speed at most this
    /// fraction of its velocity limit (`TimedTrajectory::switch_to`); 0 switches at once, as the
    /// original did (the arm then snaps onto the new plan, faster than its limits).
    pub transition_speed: f64,
    /// Newton iterations a replan may take per call of `observe` on each of the optimiser's levels
    /// (0: replan to convergence at once, Algorithm 1 as written). With a budget, a replan that
    /// has not converged goes on at the next calls from where it stopped, every tick, the robot
    /// blending into each better plan as it comes; one call then stays within the budget's time
    /// (at N = 31 here about 70 µs an iteration on the plan's 31 waypoints and 25 µs on the coarse
    /// level's 11) whatever the push.
    pub replan_iterations: usize,
    /// Seed plans per learned weight (0: none). With s seeds, the learner plans at construction for
    /// s evenly spaced values of every learned weight between its bounds (s^L plans for L learned
    /// weights, at most [`MAX_SEEDS`]), and each replan starts from whichever of the current plan
    /// and the seed nearest the new weights costs less at them. The authors' later code cached such
    /// seeds on a weight grid against trajopt's local minima; here they also make the replan after a
    /// large update short.
    pub seeds: usize,
}

/// Most seed plans a learner keeps (`LearnerParams::seeds`).
pub const MAX_SEEDS: usize = 64;

impl Default for LearnerParams {
    fn default() -> Self {
        LearnerParams {
            learning: true,
            sample_period: 0.1,
            duration: 15.0,
            interpolation: Interpolation::Cubic,
            transition_speed: DEFAULT_TRANSITION_SPEED,
            replan_iterations: 0,
            seeds: 0,
        }
    }
}

/// Default [`LearnerParams::transition_speed`]: plans use up to half the limits (the study's
/// planner), so a blend on top of one stays within them with a margin for tracking.
pub const DEFAULT_TRANSITION_SPEED: f64 = 0.8;

/// One sampled interaction and what the learner did with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Interaction {
    /// Time [s].
    pub t: f64,
    /// Thresholded interaction torque u_H [N·m].
    pub u_h: Vec<f64>,
    /// Φ(ξ_H) − Φ(ξ_R) (empty when not learning or when the deformation was skipped).
    pub delta_phi: Vec<f64>,
    /// Weights after the update.
    pub weights: Vec<f64>,
    /// Waypoints the deformation moved (0: skipped near the end, or not learning).
    pub moved: usize,
    pub update: Option<UpdateInfo>,
    pub replan: Option<TrajoptInfo>,
}

/// What one `observe` call did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Observation {
    /// The call fell on a sample instant (otherwise it returned at once).
    pub sampled: bool,
    /// The sample exceeded the interaction thresholds.
    pub interacted: bool,
    /// The weights changed and the robot replanned.
    pub replanned: bool,
}

/// A replan the learner did not adopt because it was not feasible (see
/// [`crate::trajopt::TrajoptInfo::feasible`]): the robot kept tracking its last feasible plan.
#[derive(Debug, Clone, PartialEq)]
pub struct RejectedPlan {
    /// Time of the replan [s].
    pub t: f64,
    /// Why: the violated margin or speed, with the pair that violated it.
    pub reason: String,
}

/// The learner's record, for logs and plots. Appended to only when something happens.
#[derive(Debug, Clone, Default)]
pub struct History {
    pub interactions: Vec<Interaction>,
    /// (time the plan took effect [s], waypoints N × n row-major); the first is the initial plan.
    pub plans: Vec<(f64, Vec<f64>)>,
    /// Replans not adopted because they were infeasible.
    pub rejected: Vec<RejectedPlan>,
}

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

/// Algorithm 1.
pub struct Learner {
    params: LearnerParams,
    features: FeatureSet,
    deformation: Deformation,
    update: WeightUpdate,
    detector: InteractionDetector,
    optimizer: TrajectoryOptimizer,
    weights: Vec<f64>,
    start: Vec<f64>,
    goal: Vec<f64>,
    plan: TimedTrajectory,
    /// The plan with the optimiser's coarse plans it came from (the warm start of a replan), and
    /// the replan's output.
    levels: PlanLevels,
    replanned: PlanLevels,
    /// The levels of the plan the robot tracks (the last adopted): a rejected replan goes back to
    /// them.
    adopted: PlanLevels,
    /// Index k of the next sample instant k·sample_period.
    next_sample: f64,
    /// transition_speed × velocity limits [rad/s] (empty: switch at once).
    speed_limits: Vec<f64>,
    /// A replan cut short by `replan_iterations` is still converging.
    replan_pending: bool,
    /// Converged plans on a weight grid (`LearnerParams::seeds`).
    seeds: Seeds,
    /// What happened, for logs and plots.
    history: History,
    // Scratch of one tick, sized once so that a tick allocates nothing (tests/alloc.rs).
    seed_grad: Vec<f64>,
    tracked: Vec<f64>,
    rates: Vec<f64>,
    deformed: Vec<f64>,
    shape: Vec<f64>,
    phi_r: Vec<f64>,
    phi_h: Vec<f64>,
    delta_phi: Vec<f64>,
    jacobian: Vec<f64>,
    sensitivity: Vec<f64>,
    relevance: Vec<f64>,
    u_h: Vec<f64>,
}

impl Learner {
    /// Plans the initial trajectory for `weights` from `start` to `goal` (cold start).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        params: LearnerParams,
        mut features: FeatureSet,
        deformation: Deformation,
        update: WeightUpdate,
        detector: InteractionDetector,
        mut optimizer: TrajectoryOptimizer,
        weights: &[f64],
        start: &[f64],
        goal: &[f64],
    ) -> Result<Self> {
        let k = features.len();
        let n = features.model().nq();
        if update.len() != k {
            return Err(PhriError::invalid(
                "update",
                format!("must have one step per feature ({k} features), got {} steps", update.len()),
            ));
        }
        if detector.thresholds().len() != n {
            return Err(PhriError::invalid(
                "detector",
                format!("must have one threshold per joint ({n} joints), got {}", detector.thresholds().len()),
            ));
        }
        if !(params.sample_period.is_finite() && params.sample_period > 0.0) {
            return Err(PhriError::invalid(
                "sample_period",
                format!("must be a finite time > 0 s, got {}", params.sample_period),
            ));
        }
        if !(params.transition_speed.is_finite() && params.transition_speed >= 0.0) {
            return Err(PhriError::invalid(
                "transition_speed",
                format!("must be a finite fraction of the velocity limits >= 0, got {}", params.transition_speed),
            ));
        }
        let speed_limits: Vec<f64> = if params.transition_speed > 0.0 {
            features.model().velocity_limits().iter().map(|v| v * params.transition_speed).collect()
        } else {
            Vec::new()
        };
        if let Some((j, v)) = speed_limits.iter().enumerate().find(|(_, v)| !(**v > 0.0)) {
            return Err(PhriError::invalid(
                "transition_speed",
                format!("needs velocity limits > 0, but joint {j} has {v} rad/s; use 0 to switch plans at once"),
            ));
        }
        crate::error::check_vector("weights", weights, k)?;
        let mut weights = weights.to_vec();
        update.clip(&mut weights);
        let m = optimizer.waypoints();
        let full_cap = optimizer.params().max_iterations;
        let mut levels = optimizer.plan_levels();
        let info = optimizer.solve_levels(&mut features, &weights, start, goal, None, &mut levels)?;
        if !info.feasible {
            return Err(PhriError::Planning {
                reason: format!("the initial plan is not safe to track: {}", infeasibility(&info, &optimizer)),
            });
        }
        let plan0 = levels.plan().to_vec();
        let seeds = Seeds::plan(params.seeds, &update, &weights, &mut features, &mut optimizer, start, goal)?;
        if params.replan_iterations > 0 {
            // The initial plan converged above; replans keep to the per-tick budget.
            optimizer.set_max_iterations(params.replan_iterations.min(full_cap))?;
        }
        let plan = TimedTrajectory::new(plan0.clone(), n, params.duration, params.interpolation)?;
        // The deformation of unit torques, μ·H per waypoint of a full window (for relevance).
        let history = History { interactions: Vec::new(), plans: vec![(0.0, plan0)], rejected: Vec::new() };
        Ok(Learner {
            features,
            deformation,
            update,
            detector,
            optimizer,
            weights,
            start: start.to_vec(),
            goal: goal.to_vec(),
            plan,
            replanned: levels.clone(),
            adopted: levels.clone(),
            levels,
            next_sample: 0.0,
            speed_limits,
            replan_pending: false,
            seeds,
            seed_grad: vec![0.0; m * n],
            tracked: vec![0.0; m * n],
            rates: vec![0.0; 2 * n],
            deformed: vec![0.0; m * n],
            shape: vec![0.0; m * n],
            phi_r: vec![0.0; k],
            phi_h: vec![0.0; k],
            delta_phi: vec![0.0; k],
            jacobian: vec![0.0; k * m * n],
            sensitivity: vec![0.0; k * n],
            relevance: vec![0.0; k],
            u_h: vec![0.0; n],
            history,
            params,
        })
    }

    pub fn params(&self) -> &LearnerParams {
        &self.params
    }

    /// Current weights w (cost form).
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Current plan ξ_R, N × n row-major.
    pub fn plan(&self) -> &TimedTrajectory {
        &self.plan
    }

    pub fn features(&mut self) -> &mut FeatureSet {
        &mut self.features
    }

    pub fn history(&self) -> &History {
        &self.history
    }

    /// Whether a replan cut short by the per-tick budget is still converging.
    pub fn replan_pending(&self) -> bool {
        self.replan_pending
    }

    /// The reference (q_R [rad], q̇_R [rad/s], q̈_R [rad/s²]) at time `t` [s]; allocates nothing.
    #[inline]
    pub fn reference(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        self.plan.sample(t, q, qd, qdd);
    }

    /// One tick: at each sample instant, read the measured joint torque of the person
    /// `tau_measured` [N·m] and, on an interaction, deform → update → replan. Between samples it
    /// returns at once. No allocation unless an interaction is recorded.
    pub fn observe(&mut self, t: f64, tau_measured: &[f64]) -> Result<Observation> {
        check_finite("t", &[t])?;
        let mut obs = Observation::default();
        // Sample instants lie on the grid k·period; a tick within 10⁻⁶ periods of one counts as on it
        // (tick times carry rounding). Missed instants are not replayed.
        let position = t / self.params.sample_period + 1e-6;
        if position < self.next_sample {
            if self.replan_pending {
                self.replan(t)?;
                obs.replanned = true;
            }
            return Ok(obs);
        }
        self.next_sample = position.floor() + 1.0;
        obs.sampled = true;
        obs.interacted = self.detector.detect(tau_measured, &mut self.u_h)?;
        if !obs.interacted {
            if self.replan_pending {
                self.replan(t)?;
                obs.replanned = true;
            }
            return Ok(obs);
        }
        let mut record = Interaction {
            t,
            u_h: self.u_h.clone(),
            delta_phi: Vec::new(),
            weights: self.weights.clone(),
            moved: 0,
            update: None,
            replan: None,
        };
        if self.params.learning {
            self.learn(t, &mut record)?;
            obs.replanned = record.replan.is_some();
        } else if self.replan_pending {
            self.replan(t)?;
            obs.replanned = true;
        }
        self.history.interactions.push(record);
        Ok(obs)
    }

    /// ξ_R as the robot tracks it now, at the plan's waypoint times, into `tracked`: the plan's
    /// waypoints, or while a switch to it is still blending, the blended reference.
    fn track(&mut self) {
        let n = self.plan.dof();
        if self.plan.blend_end() == 0.0 {
            self.tracked.copy_from_slice(self.plan.waypoints());
            return;
        }
        let dt = self.plan.dt();
        let (qd, qdd) = self.rates.split_at_mut(n);
        for (i, q) in self.tracked.chunks_exact_mut(n).enumerate() {
            self.plan.sample(i as f64 * dt, q, qd, qdd);
        }
    }

    fn learn(&mut self, t: f64, record: &mut Interaction) -> Result<()> {
        let n = self.plan.dof();
        let index = self.plan.index_at(t);
        // The push deforms the trajectory the arm is following (Algorithm 1's ξ_R^t).
        self.track();
        self.deformed.copy_from_slice(&self.tracked);
        record.moved = self.deformation.deform_in_place(&mut self.deformed, n, index, &self.u_h)?;
        if record.moved == 0 {
            return Ok(());
        }
        self.features.phi(&self.tracked, &mut self.phi_r)?;
        self.features.phi(&self.deformed, &mut self.phi_h)?;
        for k in 0..self.delta_phi.len() {
            self.delta_phi[k] = self.phi_h[k] - self.phi_r[k];
        }
        if self.delta_phi.iter().any(|v| !v.is_finite()) {
            return Err(PhriError::invalid(
                "tau_measured",
                "is so large that the deformed trajectory's features overflow (non-finite)",
            ));
        }
        let relevance = if self.update.params().rule == UpdateRule::Confidence {
            self.compute_relevance(index)?;
            Some(&self.relevance[..])
        } else {
            None
        };
        let info = self.update.apply(&mut self.weights, &self.delta_phi, relevance)?;
        record.delta_phi = self.delta_phi.clone();
        record.weights = self.weights.clone();
        record.update = Some(info);
        record.replan = Some(self.replan(t)?);
        Ok(())
    }

    /// Replans over [0, T] from the original start, warm-started from the current plan and its
    /// coarse plans (or the nearest seed's, if its plan costs less at the new weights), within the
    /// per-tick budget, and switches to the result at `t` if it is feasible; otherwise the robot
    /// keeps tracking its plan (the last feasible one) and the history records why.
    fn replan(&mut self, t: f64) -> Result<TrajoptInfo> {
        let mut init = &self.levels;
        if let Some(seed) = self.seeds.nearest(&self.weights) {
            let seed = &self.seeds.plans[seed];
            let (here, _) = self.optimizer.objective(&mut self.features, &self.weights, init.plan(), &mut self.seed_grad)?;
            let (there, _) = self.optimizer.objective(&mut self.features, &self.weights, seed.plan(), &mut self.seed_grad)?;
            if there < here {
                init = seed;
            }
        }
        let info = self.optimizer.solve_levels(
            &mut self.features,
            &self.weights,
            &self.start,
            &self.goal,
            Some(init),
            &mut self.replanned,
        )?;
        let pending = self.params.replan_iterations > 0 && !info.converged;
        if !info.feasible {
            if pending {
                // A budgeted replan goes on from where it stopped; the arm does not follow it.
                std::mem::swap(&mut self.levels, &mut self.replanned);
            } else {
                // Rejected: later replans start again from the plan the robot tracks.
                self.levels.clone_from(&self.adopted);
                self.history.rejected.push(RejectedPlan { t, reason: infeasibility(&info, &self.optimizer) });
            }
            self.replan_pending = pending;
            return Ok(info);
        }
        // Switch first: if that fails, the learner keeps the plan it is following.
        self.plan.switch_to(self.replanned.plan(), t, &self.speed_limits)?;
        std::mem::swap(&mut self.levels, &mut self.replanned);
        self.adopted.clone_from(&self.levels);
        self.replan_pending = pending;
        self.history.plans.push((t, self.levels.plan().to_vec()));
        Ok(info)
    }

    /// Linearised sensitivity S = ∂ΔΦ/∂u_H (K × n) at the current plan, then relevance.
    fn compute_relevance(&mut self, index: usize) -> Result<()> {
        let (n, m, k_len) = (self.plan.dof(), self.plan.len(), self.features.len());
        // Unit torque on every joint moves joint j of waypoint i by shape[i][j] = μ·H_i.
        self.shape.fill(0.0);
        let ones = vec![1.0; n];
        self.deformation.deform_in_place(&mut self.shape, n, index, &ones)?;
        self.features.phi_gradient(&self.tracked, &mut self.phi_r, &mut self.jacobian)?;
        self.sensitivity.fill(0.0);
        for k in 0..k_len {
            for i in 0..m {
                for j in 0..n {
                    self.sensitivity[k * n + j] += self.jacobian[(k * m + i) * n + j] * self.shape[i * n + j];
                }
            }
        }
        relevance(&self.delta_phi, &self.sensitivity, &self.u_h, &mut self.relevance)
    }
}

/// Plans converged on a grid of the learned weights (see [`LearnerParams::seeds`]).
#[derive(Default)]
struct Seeds {
    weights: Vec<Vec<f64>>,
    plans: Vec<PlanLevels>,
    /// 1 / (upper − lower) of each learned weight, 0 for the others: distances in bound units.
    scale: Vec<f64>,
}

impl Seeds {
    /// `per_weight` values of every learned weight between its bounds, the other weights as in
    /// `weights`, each planned cold to convergence.
    #[allow(clippy::too_many_arguments)]
    fn plan(
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
        let mut seeds = Seeds { scale: vec![0.0; weights.len()], ..Default::default() };
        for &k in &learned {
            let span = p.upper[k] - p.lower[k];
            seeds.scale[k] = if span > 0.0 { 1.0 / span } else { 0.0 };
        }
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
            seeds.weights.push(w);
            seeds.plans.push(plan);
        }
        Ok(seeds)
    }

    /// The seed whose weights are nearest `weights` (in units of each learned weight's bounds).
    fn nearest(&self, weights: &[f64]) -> Option<usize> {
        let distance =
            |s: &[f64]| -> f64 { s.iter().zip(weights).zip(&self.scale).map(|((a, b), c)| ((a - b) * c).powi(2)).sum() };
        (0..self.weights.len()).min_by(|&a, &b| distance(&self.weights[a]).total_cmp(&distance(&self.weights[b])))
    }
}
