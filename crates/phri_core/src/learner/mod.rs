//! Algorithm 1 of the paper, the online learner: it owns the current plan and the weights, and at
//! every sampled interaction deforms the plan (eq. 7), updates the weights (eq. 13) and replans
//! (eq. 4) warm-started, while `reference(t)` feeds the control law. With `learning = false` it is
//! the impedance baseline: interactions are recorded but the plan never changes.
//!
//! # Where the learning and the replan run ([`LearnerParams::replan_latency`])
//! Inline (latency 0, the default), `observe` learns and replans before it returns, as Algorithm 1
//! is written. Otherwise `observe` only detects the push and deforms the plan on the control
//! thread (a few microseconds, no feature evaluated) and hands the correction to a worker thread
//! (module `worker`): the worker learns from every correction in the order they came (ΔΦ with its
//! gradient, β̂, the belief, the update; module `learning`), then replans for the newest weights.
//! The control tick never waits for it except in simulated mode, and what it learned and planned
//! is taken in later, the plan blended in as an inline replan's is, from the reference of the
//! previous `observe` (the last one the controller used):
//! - [`ReplanLatency::Fixed`]`(L)`, L > 0: a deterministic, simulated latency. The plan is adopted,
//!   and the weights and the belief of the corrections so far taken in, at the first `observe`
//!   with t ≥ t_request + L; that call waits for the worker if it has not finished, so results do
//!   not depend on the machine's load. With L one tick of a loop that calls `observe` every tick,
//!   the results are those of inline replanning, bit for bit (the weights a tick later).
//! - [`ReplanLatency::WallClock`]: hardware. What the worker learned is taken in at the first
//!   `observe` after it posted it, the plan at the first `observe` after the worker finished;
//!   `observe` never waits.
//!
//! A newer correction supersedes a replan still running (its solve stops at the next Newton
//! iteration); only the newest result is adopted, and an infeasible one is rejected as inline. A
//! correction whose learning fails on the worker changes nothing: a feature's failure is
//! recorded as a rejected plan, any other error is returned by the `observe` that takes it in.

mod history;
mod learning;
mod planner;
mod seeds;
mod worker;

use std::time::Duration;

pub use history::{History, Interaction, RejectedPlan};
use learning::{Correction, Learned, Learning};
pub use planner::infeasibility;
use planner::Planner;
use seeds::Seeds;
use worker::{Outcome, ReplanWorker};

use crate::belief::{Belief, DEFAULT_EFFORT};
use crate::deform::Deformation;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::features::FeatureSet;
use crate::interaction::InteractionDetector;
use crate::reference::{Interpolation, TimedTrajectory, MIN_SPEED_LIMIT};
use crate::trajopt::{TrajectoryOptimizer, TrajoptInfo};
use crate::update::WeightUpdate;

/// When a replan's plan takes effect (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReplanLatency {
    /// A fixed latency L [s]: 0 replans inline (Algorithm 1 as written, the default); L > 0
    /// replans on the worker thread and adopts the plan at the first `observe` with
    /// t ≥ t_request + L, waiting for the worker there if need be (simulation: deterministic).
    Fixed(f64),
    /// Replans on the worker thread and adopts the plan at the first `observe` after it finished
    /// (hardware: the wall clock decides); `observe` never waits.
    WallClock,
}

impl Default for ReplanLatency {
    fn default() -> Self {
        ReplanLatency::Fixed(0.0)
    }
}

impl ReplanLatency {
    /// Whether replans run on the worker thread.
    pub fn uses_worker(self) -> bool {
        self != ReplanLatency::Fixed(0.0)
    }
}

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
    /// original did (the arm then snaps onto the new plan, faster than its limits). Either 0 or in
    /// [[`MIN_TRANSITION_SPEED`], 1].
    pub transition_speed: f64,
    /// Newton iterations a replan may take per call of `observe` on each of the optimiser's levels
    /// (0: replan to convergence at once, Algorithm 1 as written). With a budget, a replan that
    /// has not converged goes on at the next calls from where it stopped, every tick, the robot
    /// blending into each better plan as it comes; one call then stays within the budget's time
    /// (at N = 31 here about 70 µs an iteration on the plan's 31 waypoints and 25 µs on the coarse
    /// level's 11) whatever the push. Inline replanning only (`replan_latency` 0): a worker
    /// replans to convergence (or the optimiser's own caps) off the control thread.
    pub replan_iterations: usize,
    /// Seed plans per learned weight (0: none). With s seeds, the learner plans at construction for
    /// s evenly spaced values of every learned weight between its bounds (s^L plans for L learned
    /// weights, at most [`MAX_SEEDS`]), and each replan starts from whichever of the current plan
    /// and the seeds costs least at the new weights (the plans' costs are linear in the weights:
    /// each plan's terms are worked out once, the seeds' at construction and a worker's results
    /// right after they are posted, so a worker's replan compares them without an evaluation).
    /// The authors' later code cached such seeds on a weight grid against trajopt's local minima;
    /// here they also make the replan after a large update short.
    pub seeds: usize,
    /// Where replans run and when their plans take effect: inline (`Fixed(0.0)`, the default), on
    /// a worker thread after a simulated latency `Fixed(L)` [s] (0 < L ≤ `duration`), or on a
    /// worker thread as soon as it is done (`WallClock`, hardware). See the module docs.
    pub replan_latency: ReplanLatency,
    /// How long the replan worker busy-waits for the next request, after it starts and after each
    /// replan, before it sleeps [s] (0: it sleeps at once, the default; `f64::INFINITY`: it never
    /// sleeps while the learner lives). A sleeping worker must be woken by the next correction,
    /// which takes tens of microseconds on an idle real-time kernel but up to milliseconds on a
    /// loaded or virtual machine (benches/learning.rs measures both). Spinning keeps one CPU core
    /// busy: use it on a machine with a core to spare for the worker, never where the spinning
    /// would take the control loop's or the simulator's core. Worker modes only.
    pub worker_spin: f64,
    /// Effort weight λ of the observation model (paper eq. 8) [1/(N·m)²], for the belief's
    /// covariance ([`crate::belief`]); finite and > 0.
    pub effort: f64,
    /// Risk-aware planning: plan with w + k ⊙ σ (clipped to the bounds), k per feature, σ the
    /// belief's standard deviations; empty (the default): plan with the estimate w, as the paper.
    /// A k > 0 plans as if the feature mattered more than the estimate says, by k standard
    /// deviations; features with no variance (not learned) are planned at w.
    pub risk: Vec<f64>,
}

/// Most seed plans a learner keeps (`LearnerParams::seeds`).
pub const MAX_SEEDS: usize = 64;

/// Smallest non-zero [`LearnerParams::transition_speed`] [fraction of the velocity limits]: slower
/// blends would outlast any task (and a subnormal one overflows the blend time).
pub const MIN_TRANSITION_SPEED: f64 = 1e-3;

/// `observe` accepts times up to this long after the task's duration [s]: a loop's last ticks may
/// run a little past T. Later times (a timestamp in ms, another clock) are refused.
pub const TIME_SLACK: f64 = 0.01;

/// Longest stall [`Learner::debug_stall_worker`] injects [s].
pub const MAX_DEBUG_STALL: f64 = 60.0;

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
            replan_latency: ReplanLatency::default(),
            worker_spin: 0.0,
            effort: DEFAULT_EFFORT,
            risk: Vec::new(),
        }
    }
}

/// Default [`LearnerParams::transition_speed`]: plans use up to half the limits (the study's
/// planner), so a blend on top of one stays within them with a margin for tracking.
pub const DEFAULT_TRANSITION_SPEED: f64 = 0.8;

/// What one `observe` call did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Observation {
    /// The call fell on a sample instant (otherwise it only checked for a finished replan).
    pub sampled: bool,
    /// The sample exceeded the interaction thresholds.
    pub interacted: bool,
    /// A replan's outcome arrived in this call: inline, the robot replanned (the plan adopted or,
    /// if infeasible, rejected); with a worker, a requested replan was adopted or rejected.
    pub replanned: bool,
    /// A new plan took effect in this call.
    pub adopted: bool,
}

/// The replan a worker is solving for the control side.
#[derive(Debug, Clone, Copy)]
struct Pending {
    generation: u64,
    /// Time of the interaction that asked for it [s].
    t: f64,
    /// Its record in `History::interactions`.
    record: usize,
}

/// Where corrections are learned from and replans run.
enum Replanner {
    Inline { planner: Box<Planner>, learning: Box<Learning> },
    Worker(ReplanWorker),
}

/// The weights and the belief as the control side knows them.
#[derive(Debug, Clone)]
struct Estimate {
    /// The estimate w (the belief's mean).
    weights: Vec<f64>,
    /// The belief's covariance Σ, K × K row-major [weight²].
    covariance: Vec<f64>,
    /// The weights the planner plans with: w, or with `LearnerParams::risk`, w + k ⊙ σ.
    plan_weights: Vec<f64>,
}

impl Estimate {
    /// Takes in what a correction taught, into the estimate and the correction's `record`.
    fn take(&mut self, record: &mut Interaction, learned: Learned) {
        self.weights.copy_from_slice(&learned.weights);
        self.plan_weights.copy_from_slice(&learned.plan_weights);
        self.covariance.copy_from_slice(&learned.covariance);
        record.delta_phi = learned.delta_phi;
        record.weights = learned.weights;
        record.update = Some(learned.update);
        record.rationality = Some(learned.rationality);
        record.covariance = learned.covariance;
    }
}

/// Algorithm 1.
pub struct Learner {
    params: LearnerParams,
    deformation: Deformation,
    detector: InteractionDetector,
    replanner: Replanner,
    /// The weights and the belief: inline, as learned; with a worker, as of the last correction
    /// whose learning the control side collected.
    estimate: Estimate,
    plan: TimedTrajectory,
    /// What `reset` returns to.
    initial_estimate: Estimate,
    initial_plan: TimedTrajectory,
    /// Index k of the next sample instant k·sample_period.
    next_sample: f64,
    /// Time of the previous `observe` [s] (None before the first).
    last_t: Option<f64>,
    /// transition_speed × velocity limits [rad/s] (empty: switch at once).
    speed_limits: Vec<f64>,
    /// Inline: a replan cut short by `replan_iterations` is still converging, since this time [s].
    replan_pending: bool,
    pending_since: f64,
    /// Worker: the replan requested and not yet adopted or rejected.
    pending: Option<Pending>,
    /// Generation of the plan the robot tracks (0: the initial plan).
    tracked: u64,
    /// Requested replans superseded by a newer correction before they were adopted.
    superseded: u64,
    /// Whether the last plan adopted from a replan converged (None: none adopted yet).
    last_converged: Option<bool>,
    /// The last observe's outcome.
    last_observation: Observation,
    /// What happened, for logs and plots.
    history: History,
    // Scratch of one tick, sized once so that a tick allocates nothing (tests/alloc.rs).
    /// The push being taken: the tracked plan, its deformation, the push.
    correction: Correction,
    rates: Vec<f64>,
    ones: Vec<f64>,
}

impl Learner {
    /// Plans the initial trajectory for `weights` from `start` to `goal` (cold start), and with a
    /// replan worker (`params.replan_latency`) starts its thread.
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
        check_params(&params)?;
        let speed_limits = speed_limits(&features, params.transition_speed)?;
        check_vector("weights", weights, k)?;
        let mut weights = weights.to_vec();
        update.clip(&mut weights);
        let belief = Belief::new(update.params(), params.effort)?;
        if !params.risk.is_empty() {
            check_vector("risk", &params.risk, k)?;
            check_finite("risk", &params.risk)?;
        }
        let m = optimizer.waypoints();
        let learning = Learning::new(features.clone(), update, belief, params.risk.clone(), weights, m);
        let estimate = Estimate {
            weights: learning.weights().to_vec(),
            covariance: learning.covariance().to_vec(),
            plan_weights: learning.plan_weights().to_vec(),
        };
        let plan_weights = &estimate.plan_weights;
        let full_cap = optimizer.params().max_iterations;
        let mut levels = optimizer.plan_levels();
        let info = optimizer.solve_levels(&mut features, plan_weights, start, goal, None, &mut levels)?;
        if !info.feasible {
            return Err(PhriError::Planning {
                reason: format!("the initial plan is not safe to track: {}", infeasibility(&info, &optimizer)),
            });
        }
        let plan0 = levels.plan().to_vec();
        let seeds = Seeds::plan(params.seeds, learning.update(), plan_weights, &mut features, &mut optimizer, start, goal)?;
        if params.replan_iterations > 0 {
            // The initial plan converged above; replans keep to the per-tick budget.
            optimizer.set_max_iterations(params.replan_iterations.min(full_cap))?;
        }
        let plan = TimedTrajectory::new(plan0.clone(), n, params.duration, params.interpolation)?;
        let planner = Planner::new(features, optimizer, start, goal, seeds, levels)?;
        let replanner = if params.replan_latency.uses_worker() {
            Replanner::Worker(ReplanWorker::spawn(
                planner,
                learning,
                (m, n),
                Duration::try_from_secs_f64(params.worker_spin).unwrap_or(Duration::MAX),
            )?)
        } else {
            Replanner::Inline { planner: Box::new(planner), learning: Box::new(learning) }
        };
        let history = History { interactions: Vec::new(), plans: vec![(0.0, plan0)], rejected: Vec::new() };
        Ok(Learner {
            deformation,
            detector,
            replanner,
            initial_estimate: estimate.clone(),
            estimate,
            initial_plan: plan.clone(),
            plan,
            next_sample: 0.0,
            last_t: None,
            speed_limits,
            replan_pending: false,
            pending_since: 0.0,
            pending: None,
            tracked: 0,
            superseded: 0,
            last_converged: None,
            last_observation: Observation::default(),
            correction: Correction::new(m, n),
            rates: vec![0.0; 2 * n],
            ones: vec![1.0; n],
            history,
            params,
        })
    }

    pub fn params(&self) -> &LearnerParams {
        &self.params
    }

    /// Current weights w (cost form). With a replan worker, which learns from each correction
    /// before it replans, they are those of the corrections taken in so far: with a simulated
    /// latency L, every correction up to the one whose replan is due, at t_push + L (a correction
    /// due after the last `observe` is never taken in); with the wall clock, every correction the
    /// worker has learned from by the tick. An interaction the worker did not learn from (no
    /// deformation, or a failed learning) records these.
    pub fn weights(&self) -> &[f64] {
        &self.estimate.weights
    }

    /// The belief over the weights: its mean (the estimate, [`Learner::weights`]) and covariance
    /// Σ (K × K row-major [weight²]; see [`crate::belief`]).
    pub fn belief(&self) -> (&[f64], &[f64]) {
        (&self.estimate.weights, &self.estimate.covariance)
    }

    /// The weights the planner plans with: the estimate, or with `LearnerParams::risk` the
    /// risk-aware w + k ⊙ σ.
    pub fn plan_weights(&self) -> &[f64] {
        &self.estimate.plan_weights
    }

    /// Current plan ξ_R, N × n row-major.
    pub fn plan(&self) -> &TimedTrajectory {
        &self.plan
    }

    pub fn history(&self) -> &History {
        &self.history
    }

    /// Whether a replan is under way: inline, one cut short by the per-tick budget is still
    /// converging; with a worker, one was requested and is not yet adopted or rejected.
    pub fn replan_pending(&self) -> bool {
        self.replan_running_since().is_some()
    }

    /// Time [s] of the correction whose replan is under way (requested and not yet adopted or
    /// rejected; inline, a budgeted replan still converging), or None. A watchdog compares it
    /// with the clock to see a stalled worker.
    pub fn replan_running_since(&self) -> Option<f64> {
        match (&self.pending, self.replan_pending) {
            (Some(p), _) => Some(p.t),
            (None, true) => Some(self.pending_since),
            (None, false) => None,
        }
    }

    /// Requested replans that a newer correction superseded before they were adopted (since
    /// construction or `reset`).
    pub fn superseded_replans(&self) -> u64 {
        self.superseded
    }

    /// Whether the optimiser converged for the last plan adopted from a replan (None: none yet).
    pub fn last_replan_converged(&self) -> Option<bool> {
        self.last_converged
    }

    /// What the last `observe` did.
    pub fn last_observation(&self) -> Observation {
        self.last_observation
    }

    /// The reference (q_R [rad], q̇_R [rad/s], q̈_R [rad/s²]) at time `t` [s]; allocates nothing.
    #[inline]
    pub fn reference(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        self.plan.sample(t, q, qd, qdd);
    }

    /// Back to t = 0 with the initial plan and weights and an empty record (the initial plan
    /// only), as constructed: a replan under way is cancelled, the next `observe` may start again
    /// from t = 0. Seeds are kept.
    pub fn reset(&mut self) {
        match &mut self.replanner {
            Replanner::Inline { planner, learning } => {
                planner.restart();
                learning.reset();
            }
            // The worker resets its learning before it takes the next correction.
            Replanner::Worker(worker) => worker.cancel(),
        }
        self.estimate.clone_from(&self.initial_estimate);
        self.plan.clone_from(&self.initial_plan);
        self.next_sample = 0.0;
        self.last_t = None;
        self.replan_pending = false;
        self.pending = None;
        self.tracked = 0;
        self.superseded = 0;
        self.last_converged = None;
        self.last_observation = Observation::default();
        self.history.interactions.clear();
        self.history.rejected.clear();
        self.history.plans.truncate(1);
    }

    /// Testing only (fault injection): the worker's next replan first stalls for `seconds` [s]
    /// (at most [`MAX_DEBUG_STALL`]), as a worker held up by the machine would. Needs a worker.
    pub fn debug_stall_worker(&self, seconds: f64) -> Result<()> {
        if !(seconds.is_finite() && (0.0..=MAX_DEBUG_STALL).contains(&seconds)) {
            return Err(PhriError::invalid("seconds", format!("must be in [0, {MAX_DEBUG_STALL}] s, got {seconds}")));
        }
        self.worker("debug_stall_worker")?.stall(Duration::from_secs_f64(seconds));
        Ok(())
    }

    /// Testing only (fault injection): the worker's next replan panics; the next `observe` after
    /// it reports a [`PhriError::ReplanWorker`]. Needs a worker.
    pub fn debug_panic_worker(&self) -> Result<()> {
        self.worker("debug_panic_worker")?.panic_next();
        Ok(())
    }

    fn worker(&self, what: &str) -> Result<&ReplanWorker> {
        match &self.replanner {
            Replanner::Worker(w) => Ok(w),
            Replanner::Inline { .. } => Err(PhriError::invalid(
                what,
                "needs a replan worker (replan_latency > 0, or the wall clock); this learner replans inline",
            )),
        }
    }

    /// One tick: adopt a replan the worker has finished (if due), then at each sample instant
    /// read the measured joint torque of the person `tau_measured` [N·m] and, on an interaction,
    /// deform → update → replan (inline) or deform and hand the correction to the worker, which
    /// updates the weights and the belief and replans. Between samples it returns at once. `t` [s] lies in [0, duration + [`TIME_SLACK`]] and never goes back (see
    /// `reset`); a refused `t` or torque leaves the learner as it was. With a worker, an error
    /// may also be an earlier correction's that failed there (see the module docs). No
    /// allocation unless an interaction is recorded.
    pub fn observe(&mut self, t: f64, tau_measured: &[f64]) -> Result<Observation> {
        self.check_time(t)?;
        check_vector("tau_measured", tau_measured, self.ones.len())?;
        let mut obs = Observation::default();
        // The reference the controller used last: a plan adopted now blends in from it.
        let anchor = self.last_t.unwrap_or(t);
        self.last_t = Some(t);
        self.last_observation = obs;
        if self.pending.is_some() {
            if let Err(e) = self.collect(t, anchor, &mut obs) {
                // What was taken in stays (a plan adopted with an earlier correction's error).
                self.last_observation = obs;
                return Err(e);
            }
        }
        // Sample instants lie on the grid k·period; a tick within 10⁻⁶ periods of one counts as on it
        // (tick times carry rounding). Missed instants are not replayed.
        let position = t / self.params.sample_period + crate::reference::GRID_TOLERANCE;
        if position < self.next_sample {
            self.continue_budgeted(t, &mut obs)?;
            self.last_observation = obs;
            return Ok(obs);
        }
        self.next_sample = position.floor() + 1.0;
        obs.sampled = true;
        obs.interacted = self.detector.detect(tau_measured, &mut self.correction.u_h)?;
        for ((p, tau), b) in self.correction.push.iter_mut().zip(tau_measured).zip(self.detector.bias()) {
            *p = tau - b;
        }
        if !obs.interacted {
            self.continue_budgeted(t, &mut obs)?;
            self.last_observation = obs;
            return Ok(obs);
        }
        let mut record = Interaction {
            t,
            u_h: self.correction.u_h.clone(),
            delta_phi: Vec::new(),
            weights: self.estimate.weights.clone(),
            moved: 0,
            update: None,
            replan: None,
            rationality: None,
            covariance: Vec::new(),
        };
        if self.params.learning {
            record.moved = self.deform(t)?;
            if record.moved > 0 {
                match &mut self.replanner {
                    Replanner::Inline { learning, .. } => {
                        let learned = learning.learn(&self.correction)?;
                        self.estimate.take(&mut record, learned);
                        let (info, adopted) = self.replan_inline(t)?;
                        record.replan = Some(info);
                        obs.replanned = true;
                        obs.adopted = adopted;
                    }
                    Replanner::Worker(_) => self.request(t),
                }
            }
        } else {
            self.continue_budgeted(t, &mut obs)?;
        }
        self.history.interactions.push(record);
        self.last_observation = obs;
        Ok(obs)
    }

    /// `t` is finite, within the task and not before the previous `observe`.
    fn check_time(&self, t: f64) -> Result<()> {
        check_finite("t", &[t])?;
        let end = self.params.duration + TIME_SLACK;
        if !(0.0..=end).contains(&t) {
            return Err(PhriError::invalid(
                "t",
                format!("must be a time within the task, in [0, {end}] s (duration + {TIME_SLACK} s), got {t} (in seconds?)"),
            ));
        }
        if let Some(last) = self.last_t {
            if t < last {
                return Err(PhriError::invalid(
                    "t",
                    format!("must not go back in time: got {t} s after an observe at {last} s (reset() starts the task again)"),
                ));
            }
        }
        Ok(())
    }

    /// Inline with a budget: the unfinished replan goes on.
    fn continue_budgeted(&mut self, t: f64, obs: &mut Observation) -> Result<()> {
        if self.replan_pending {
            let (_, adopted) = self.replan_inline(t)?;
            obs.replanned = true;
            obs.adopted = adopted;
        }
        Ok(())
    }

    /// ξ_R as the robot tracks it now, at the plan's waypoint times, into `correction`: the
    /// plan's waypoints, or while a switch to it is still blending, the blended reference.
    fn track(&mut self) {
        let n = self.plan.dof();
        if self.plan.blend_end() == 0.0 {
            self.correction.tracked.copy_from_slice(self.plan.waypoints());
            return;
        }
        let dt = self.plan.dt();
        let (qd, qdd) = self.rates.split_at_mut(n);
        for (i, q) in self.correction.tracked.chunks_exact_mut(n).enumerate() {
            self.plan.sample(i as f64 * dt, q, qd, qdd);
        }
    }

    /// Deforms the tracked plan by the push (into `correction`, with the deformation of a unit
    /// push for its sensitivity); returns the waypoints it moved (0: the push was too close to the
    /// goal to deform anything).
    fn deform(&mut self, t: f64) -> Result<usize> {
        let n = self.plan.dof();
        let index = self.plan.index_at(t);
        // The push deforms the trajectory the arm is following (Algorithm 1's ξ_R^t).
        self.track();
        let c = &mut self.correction;
        c.deformed.copy_from_slice(&c.tracked);
        let moved = self.deformation.deform_in_place(&mut c.deformed, n, index, &c.u_h)?;
        if moved > 0 {
            // Unit torque on every joint moves joint j of waypoint i by shape[i][j] = μ·H_i.
            c.shape.fill(0.0);
            self.deformation.deform_in_place(&mut c.shape, n, index, &self.ones)?;
        }
        Ok(moved)
    }

    /// Inline: replans over [0, T] from the original start, warm-started from the current plan
    /// and its coarse plans (or the seed's that costs least at the new weights, if it costs less),
    /// within the per-tick budget, and switches to the result at `t` if it is feasible; otherwise
    /// the robot keeps tracking its plan (the last feasible one) and the history records why.
    /// Returns the solve's info and whether the plan was adopted.
    fn replan_inline(&mut self, t: f64) -> Result<(TrajoptInfo, bool)> {
        let Replanner::Inline { planner, .. } = &mut self.replanner else {
            return Err(PhriError::invalid("replan_latency", "replans on its worker, not inline"));
        };
        let info = match planner.solve(&self.estimate.plan_weights) {
            Ok(info) => info,
            Err(e) => {
                // The arm keeps its plan; later replans start again from it.
                planner.reject();
                self.replan_pending = false;
                self.history.rejected.push(RejectedPlan { t, reason: format!("replan failed: {e}") });
                return Err(e);
            }
        };
        let pending = self.params.replan_iterations > 0 && !info.converged;
        if pending && !self.replan_pending {
            self.pending_since = t;
        }
        if !info.feasible {
            if pending {
                // A budgeted replan goes on from where it stopped; the arm does not follow it.
                planner.keep_going();
            } else {
                // Rejected: later replans start again from the plan the robot tracks.
                planner.reject();
                self.history.rejected.push(RejectedPlan { t, reason: planner.infeasibility(&info) });
            }
            self.replan_pending = pending;
            return Ok((info, false));
        }
        // Switch first: if that fails, the learner keeps the plan it is following.
        self.plan.switch_to(planner.replanned.plan(), t, &self.speed_limits)?;
        planner.adopt();
        self.replan_pending = pending;
        self.last_converged = Some(info.converged);
        self.history.plans.push((t, planner.levels.plan().to_vec()));
        Ok((info, true))
    }

    /// Worker: hands the correction to the worker, which learns from it and replans (superseding
    /// a replan still under way). The history makes room for its outcome now, so that adopting
    /// it allocates nothing.
    fn request(&mut self, t: f64) {
        let Replanner::Worker(worker) = &mut self.replanner else { return };
        let block = self.params.replan_latency != ReplanLatency::WallClock;
        let record = self.history.interactions.len();
        let generation = worker.request(&self.correction, record, self.tracked, block);
        if self.pending.is_some() {
            self.superseded += 1;
        }
        self.pending = Some(Pending { generation, t, record });
        self.history.plans.reserve(1);
        self.history.rejected.reserve(1);
    }

    /// Worker: takes in what the worker learned from the corrections so far, and adopts (or
    /// rejects) the pending replan if it is due (simulated latency: waiting for the worker if need
    /// be) or ready (wall clock), blending in from the reference at `anchor`.
    fn collect(&mut self, t: f64, anchor: f64, obs: &mut Observation) -> Result<()> {
        let (Some(pending), Replanner::Worker(worker)) = (self.pending, &mut self.replanner) else { return Ok(()) };
        let outcome = match self.params.replan_latency {
            ReplanLatency::Fixed(latency) => {
                // Due at t_request + L, with the sample grid's rounding slack.
                if t + crate::reference::GRID_TOLERANCE * self.params.sample_period < pending.t + latency {
                    return Ok(());
                }
                worker.collect(pending.generation, true)
            }
            ReplanLatency::WallClock => worker.collect(pending.generation, false),
        };
        // What was learned comes first: the replan was for the weights it gave.
        let learning_failed = self.take_taught();
        let Some(outcome) = outcome else { return learning_failed };
        self.pending = None;
        match outcome {
            Outcome::Feasible { plan, info } => {
                obs.replanned = true;
                // If the switch fails, the learner keeps the plan it is following.
                if let Err(e) = self.plan.switch_to(&plan, anchor, &self.speed_limits) {
                    self.history.rejected.push(RejectedPlan { t: anchor, reason: e.to_string() });
                    return Err(e);
                }
                self.tracked = pending.generation;
                self.last_converged = Some(info.converged);
                self.history.interactions[pending.record].replan = Some(info);
                self.history.plans.push((anchor, plan));
                obs.adopted = true;
            }
            Outcome::Infeasible { info, reason } => {
                obs.replanned = true;
                self.history.interactions[pending.record].replan = Some(info);
                self.history.rejected.push(RejectedPlan { t: anchor, reason });
            }
            // A feature that failed on the worker (e.g. a Python feature that raised) rejects that
            // replan only: the arm keeps its plan and the history says why.
            Outcome::Failed(e @ PhriError::Feature { .. }) => {
                obs.replanned = true;
                self.history.rejected.push(RejectedPlan { t: anchor, reason: format!("replan failed: {e}") });
            }
            Outcome::Failed(e) => {
                obs.replanned = true;
                self.history.rejected.push(RejectedPlan { t: anchor, reason: e.to_string() });
                return Err(e);
            }
            // The newest correction taught nothing (its learning failed, reported by
            // `take_taught`): there was no replan.
            Outcome::Unlearned => {}
        }
        learning_failed
    }

    /// Worker: takes in the corrections the worker has learned from (handed over by
    /// `ReplanWorker::collect`) into their records and the estimate. A correction whose learning
    /// failed changed nothing: a feature's failure (e.g. a Python feature that raised) is recorded
    /// as a rejected replan, any other error is returned (the first), as an inline learner's
    /// `observe` would have.
    fn take_taught(&mut self) -> Result<()> {
        let Replanner::Worker(worker) = &mut self.replanner else { return Ok(()) };
        let mut first_error = None;
        for taught in worker.taught() {
            match taught.learned {
                Ok(learned) => self.estimate.take(&mut self.history.interactions[taught.record], learned),
                Err(e @ PhriError::Feature { .. }) => {
                    let t = self.history.interactions[taught.record].t;
                    self.history.rejected.push(RejectedPlan { t, reason: format!("learning failed: {e}") });
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        first_error.map_or(Ok(()), Err)
    }
}

/// Checks the timing and mode settings.
fn check_params(params: &LearnerParams) -> Result<()> {
    if !(params.sample_period.is_finite() && params.sample_period > 0.0) {
        return Err(PhriError::invalid("sample_period", format!("must be a finite time > 0 s, got {}", params.sample_period)));
    }
    let ts = params.transition_speed;
    if !(ts == 0.0 || (MIN_TRANSITION_SPEED..=1.0).contains(&ts)) {
        return Err(PhriError::invalid(
            "transition_speed",
            format!(
                "must be a finite fraction of the velocity limits: 0 (switch at once) or in [{MIN_TRANSITION_SPEED}, 1], got {ts}"
            ),
        ));
    }
    match params.replan_latency {
        ReplanLatency::Fixed(latency) => {
            if !(latency.is_finite() && latency >= 0.0 && latency <= params.duration) {
                return Err(PhriError::invalid(
                    "replan_latency",
                    format!(
                        "must be a time in [0, duration = {}] s (0: inline), or None for the wall clock, got {latency}",
                        params.duration
                    ),
                ));
            }
        }
        ReplanLatency::WallClock => {}
    }
    if !(params.worker_spin >= 0.0) {
        return Err(PhriError::invalid(
            "worker_spin",
            format!("must be a time >= 0 s (0: the worker sleeps at once; inf: it never sleeps), got {}", params.worker_spin),
        ));
    }
    if params.worker_spin > 0.0 && !params.learning {
        return Err(PhriError::invalid(
            "worker_spin",
            format!(
                "must be 0 for a learner that does not learn (it never replans: the spin would keep a core busy for \
                 nothing), got {}",
                params.worker_spin
            ),
        ));
    }
    if params.worker_spin > 0.0 && !params.replan_latency.uses_worker() {
        return Err(PhriError::invalid(
            "worker_spin",
            format!(
                "needs a replan worker (replan_latency > 0, or the wall clock); this learner replans inline, got {}",
                params.worker_spin
            ),
        ));
    }
    if params.replan_latency.uses_worker() && params.replan_iterations > 0 {
        return Err(PhriError::invalid(
            "replan_iterations",
            format!(
                "budgets inline replans only (replan_latency = 0); a replan worker replans to convergence, got {}",
                params.replan_iterations
            ),
        ));
    }
    Ok(())
}

/// transition_speed × the model's velocity limits [rad/s] (empty for an instant switch).
fn speed_limits(features: &FeatureSet, transition_speed: f64) -> Result<Vec<f64>> {
    if transition_speed == 0.0 {
        return Ok(Vec::new());
    }
    let limits: Vec<f64> = features.model().velocity_limits().iter().map(|v| v * transition_speed).collect();
    if let Some((j, v)) = limits.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= MIN_SPEED_LIMIT)) {
        return Err(PhriError::invalid(
            "transition_speed",
            format!(
                "gives joint {j} a blend speed limit of {v} rad/s, outside [{MIN_SPEED_LIMIT}, ∞) (its velocity limit times \
                 transition_speed); use 0 to switch plans at once"
            ),
        ));
    }
    Ok(limits)
}
