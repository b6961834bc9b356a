//! Multiresolution: most of a solve's iterations find where the path goes (around a keep-out
//! circle, down to the table); the number of waypoints only sets how finely. So each optimiser
//! keeps a coarser copy of its problem ([`Coarse`]) with about 1/`coarsening` of the segments
//! (31 → 11 waypoints; 100 → 34 → 12), the same features with each weight scaled so that the
//! coarse cost of a path approximates the fine one (a feature whose total grows like S^e with the
//! number of segments S weighs r^(1+e) as much, r the ratio of segments; see
//! [`crate::features::Feature::resolution_exponent`], the rule of
//! [`crate::features::FeatureSet::rescale_weights`]), the clearance weight r² and the step
//! limits r.
//!
//! - A cold solve plans the coarse level first (recursively), interpolates its plan linearly in
//!   time ([`interpolation_taps`]) and finishes on the given waypoints, each level's iteration
//!   costing about in proportion to its waypoints.
//! - A warm start from a plan alone stays on the given waypoints. A warm start from a plan *and*
//!   the coarse plans that led to it ([`PlanLevels`]) replans the coarse level from its own plan
//!   and adds the interpolated *change* of the coarse plan to the fine one, which the fine level
//!   then finishes: a weight change that moves the path far is worked out on the coarse level,
//!   while what the fine level had already resolved stays (a plan optimal for the weights stays
//!   put). The learner replans this way.

use std::time::Instant;

use super::newton::SolverState;
use super::{pin_ends_within_limits, TrajectoryOptimizer, TrajoptParams, MAX_COLLISION_SAMPLES};
use crate::error::{PhriError, Result};
use crate::features::FeatureSet;

/// A plan with the plans of the optimiser's coarse levels it came from (multiresolution; see the
/// module docs), finest first: the warm start of [`TrajectoryOptimizer::solve_levels`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlanLevels {
    pub(super) levels: Vec<Vec<f64>>,
    /// Where each level's solver left off, and the problem it solved (weights, start, goal): a
    /// solve of the same problem goes on from there (a replan cut short by an iteration cap).
    pub(super) states: Vec<SolverState>,
    pub(super) problem: Vec<f64>,
    pub(super) dof: usize,
}

impl PlanLevels {
    /// The plan itself (N × n row-major).
    pub fn plan(&self) -> &[f64] {
        &self.levels[0]
    }

    /// Number of levels (1 + the optimiser's coarse levels).
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Always false: a plan has at least its own level.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k` (0 = the plan, then ever coarser), waypoints × n row-major.
    pub fn level(&self, k: usize) -> &[f64] {
        &self.levels[k]
    }

    /// Level `k`, to write (e.g. plans stored earlier); the solvers' states are forgotten.
    pub fn level_mut(&mut self, k: usize) -> &mut [f64] {
        self.problem.clear();
        &mut self.levels[k]
    }
}

impl TrajectoryOptimizer {
    /// Empty [`PlanLevels`] shaped for this optimiser (its waypoints, then each coarse level's).
    pub fn plan_levels(&self) -> PlanLevels {
        let mut levels = vec![vec![0.0; self.waypoints * self.dof]];
        let mut next = self.coarse.as_deref();
        while let Some(c) = next {
            levels.push(vec![0.0; c.optimizer.waypoints * self.dof]);
            next = c.optimizer.coarse.as_deref();
        }
        PlanLevels { states: vec![SolverState::default(); levels.len()], levels, problem: Vec::new(), dof: self.dof }
    }

    pub(super) fn check_levels(&self, arg: &str, levels: &PlanLevels) -> Result<()> {
        // Walk the coarse chain alongside the given levels (no allocation: this runs every tick of
        // a budgeted replan).
        let mut fits = levels.dof == self.dof && !levels.levels.is_empty();
        let (mut optimizer, mut k) = (Some(self), 0);
        while let Some(o) = optimizer {
            fits &= levels.levels.get(k).is_some_and(|l| l.len() == o.waypoints * o.dof);
            optimizer = o.coarse.as_deref().map(|c| &c.optimizer);
            k += 1;
        }
        if fits && levels.levels.len() == k && levels.states.len() == k {
            return Ok(());
        }
        let want = self.plan_levels();
        let shapes = |l: &PlanLevels| l.levels.iter().map(|v| v.len() / l.dof.max(1)).collect::<Vec<_>>();
        Err(PhriError::shape(
            arg,
            format!("plan levels of {:?} waypoints × {}", shapes(&want), self.dof),
            format!("{:?} × {}", shapes(levels), levels.dof),
        ))
    }

    /// The multiresolution start (module docs): solves the coarse level — from its straight line
    /// (`Start::Line`), or from the coarse plan that goes with `traj` (`Start::Levels`) — and sets
    /// `traj` to the interpolated coarse plan, or adds the interpolated change of the coarse plan
    /// to it. Writes the coarse plans to `levels[1..]`. Returns the coarse levels' iterations and
    /// whether they all converged.
    pub(super) fn coarse_correction(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, bool) {
        let Some(mut coarse) = self.coarse.take() else { return (0, true) };
        let (n, m) = (self.dof, self.waypoints);
        let c = &mut *coarse;
        for (k, w) in weights.iter().enumerate() {
            c.weights[k] = w * c.weight_scale[k];
        }
        let below = c.prepare(&self.traj[..n], &self.traj[(m - 1) * n..], start);
        let (iterations, coarse_iterations, _, _, _, level_converged) = c.solve(features, deadline, below, levels);
        c.hand_down(&mut self.traj, matches!(start, Start::Levels { .. }));
        let converged = level_converged && c.optimizer.coarse_converged;
        self.coarse = Some(coarse);
        (iterations + coarse_iterations, converged)
    }

    /// Plan by knots ([`TrajoptParams::knots`]): the knot level solved as `start` says, `traj` set
    /// to its interpolation. Returns the knot level's (iterations, its coarse levels' iterations,
    /// evaluations, cost, penalty, whether it and its coarse levels converged).
    pub(super) fn solve_by_knots(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, usize, usize, f64, f64, bool) {
        let mut coarse = self.coarse.take().expect("a plan by knots has its knot level");
        let mut traj = std::mem::take(&mut self.traj);
        let result = coarse.solve_knots(features, weights, &mut traj, deadline, start, levels);
        self.traj = traj;
        self.coarse = Some(coarse);
        result
    }

    /// Whether plans are piecewise linear through knots ([`TrajoptParams::knots`]).
    pub(super) fn by_knots(&self) -> bool {
        self.coarse.as_ref().is_some_and(|c| c.knots)
    }
}

/// Relative tolerance of the coarse levels at least: they only give the next level its start.
const COARSE_TOLERANCE: f64 = 1e-6;

/// A coarser copy of the problem (multiresolution; see the module docs).
#[derive(Clone)]
pub(super) struct Coarse {
    pub(super) optimizer: TrajectoryOptimizer,
    /// Coarse weight per unit fine weight, ratio^(1 + e) for a feature of resolution exponent e:
    /// then the coarse cost of a path approximates `ratio` times the fine cost of it.
    weight_scale: Vec<f64>,
    weights: Vec<f64>,
    /// Interpolation taps (see [`interpolation_taps`]): every fine waypoint from the coarse ones.
    up: Vec<[(usize, f64); 2]>,
    /// The coarse plan a warm start began from (coarse N × n).
    start: Vec<f64>,
    /// This level holds the knots of a plan by knots ([`TrajoptParams::knots`]): the fine plan is
    /// its interpolation, and `down` samples a fine plan at the knots' times.
    pub(super) knots: bool,
    down: Vec<[(usize, f64); 2]>,
}

impl Coarse {
    /// The coarse level below a problem of `waypoints`, if `params` asks for one that has at least
    /// `params.coarsest` waypoints and fewer than `waypoints`.
    pub(super) fn build(features: &FeatureSet, waypoints: usize, params: &TrajoptParams) -> Result<Option<Box<Coarse>>> {
        if params.knots != 0 {
            return Self::knot_level(features, waypoints, params).map(Some);
        }
        if params.coarsening < 2 {
            return Ok(None);
        }
        let segments = waypoints - 1;
        let coarse_segments = segments.div_ceil(params.coarsening);
        let m = coarse_segments + 1;
        if m < params.coarsest || m >= waypoints {
            return Ok(None);
        }
        let ratio = segments as f64 / coarse_segments as f64;
        // The same problem on longer segments: per-waypoint penalties weigh ratio² as much (like
        // per-waypoint features), the step limit grows with the segment, and the step penalty,
        // a sum of squares of differences, keeps its weight (as efficiency does).
        let mut coarse_params = params.clone();
        for c in &mut coarse_params.clearance {
            c.weight *= ratio * ratio;
        }
        if let Some(c) = coarse_params.collision.as_mut() {
            c.weight *= ratio * ratio;
        }
        for v in &mut coarse_params.max_step {
            *v *= ratio;
        }
        coarse_params.relative_tolerance = coarse_params.relative_tolerance.max(COARSE_TOLERANCE);
        coarse_params.gradient_tolerance *= ratio;
        let optimizer = TrajectoryOptimizer::new(features, m, coarse_params)?;
        let weight_scale = features.resolution_scales(ratio).collect();
        let n = features.model().nq();
        Ok(Some(Box::new(Coarse {
            optimizer,
            weight_scale,
            weights: vec![0.0; features.len()],
            up: interpolation_taps(coarse_segments, segments),
            start: vec![0.0; m * n],
            knots: false,
            down: Vec::new(),
        })))
    }

    /// The knot problem of a plan by knots ([`TrajoptParams::knots`]) on `waypoints`: the same
    /// features and weights at the knots (as the original planner weighed its 4 waypoints), the
    /// penalties' weights as given, the step limit per knot interval, and the collision penalty at
    /// as many points of each chord as the waypoints' samples would put there (at most
    /// `MAX_COLLISION_SAMPLES`).
    fn knot_level(features: &FeatureSet, waypoints: usize, params: &TrajoptParams) -> Result<Box<Coarse>> {
        let knots = params.knots;
        let segments = waypoints - 1;
        // Every knot on a waypoint: the plan then passes through its knots, and a plan's knots are
        // read off its waypoints exactly (warm starts, the objective of a plan).
        if knots >= waypoints || segments % (knots - 1) != 0 {
            let fitting: Vec<String> = (3..waypoints).filter(|k| segments % (k - 1) == 0).map(|k| k.to_string()).collect();
            return Err(PhriError::invalid(
                "knots",
                format!(
                    "must put every knot on one of the {waypoints} waypoints (knots − 1 dividing {segments}: {}), got {knots}",
                    if fitting.is_empty() { "none".to_string() } else { fitting.join(", ") }
                ),
            ));
        }
        let intervals = knots - 1;
        let ratio = segments as f64 / intervals as f64;
        let mut knot_params = params.clone();
        knot_params.knots = 0;
        for v in &mut knot_params.max_step {
            *v *= ratio;
        }
        if let Some(c) = knot_params.collision.as_mut() {
            c.samples = ((c.samples as f64 * ratio).ceil() as usize).min(MAX_COLLISION_SAMPLES);
        }
        let optimizer = TrajectoryOptimizer::new(features, knots, knot_params)?;
        let n = features.model().nq();
        Ok(Box::new(Coarse {
            optimizer,
            weight_scale: vec![1.0; features.len()],
            weights: vec![0.0; features.len()],
            up: interpolation_taps(intervals, segments),
            start: vec![0.0; knots * n],
            knots: true,
            down: interpolation_taps(segments, intervals),
        }))
    }

    /// The knots of the fine plan `traj` (its linear interpolation at the knots' times) into `out`.
    pub(super) fn sample(&self, traj: &[f64], out: &mut [f64]) {
        let n = self.optimizer.dof;
        for (k, taps) in self.down.iter().enumerate() {
            for j in 0..n {
                out[k * n + j] = taps.iter().map(|&(i, w)| w * traj[i * n + j]).sum::<f64>();
            }
        }
    }

    /// The gradient `grad` (fine N × n) of a cost of the knots whose gradient is `knot_grad`,
    /// the knots being [`Coarse::sample`] of the fine plan.
    pub(super) fn spread(&self, knot_grad: &[f64], grad: &mut [f64]) {
        let n = self.optimizer.dof;
        grad.fill(0.0);
        for (k, taps) in self.down.iter().enumerate() {
            for &(i, w) in taps {
                for j in 0..n {
                    grad[i * n + j] += w * knot_grad[k * n + j];
                }
            }
        }
    }

    /// Sets the coarse plan to start from, with the fine plan's ends `first` and `last`: the
    /// coarse plan that goes with the fine one (`Start::Levels`, resuming its solver's state), or
    /// the straight line. Returns how the coarse level's own coarse levels start.
    fn prepare<'a>(&mut self, first: &[f64], last: &[f64], start: Start<'a>) -> Start<'a> {
        let co = &mut self.optimizer;
        co.resume = None;
        match start {
            Start::Levels { plans, states } => {
                co.resume = states.map(|s| s[0]);
                co.traj.copy_from_slice(&plans[0]);
                pin_ends_within_limits(&mut co.traj, first, last, &co.lower, &co.upper);
                self.start.copy_from_slice(&co.traj);
                Start::Levels { plans: &plans[1..], states: states.map(|s| &s[1..]) }
            }
            _ => {
                let mut line = std::mem::take(&mut co.traj);
                co.straight_line(first, last, &mut line);
                co.traj = line;
                Start::Line
            }
        }
    }

    /// Solves the coarse level (and its own coarse levels, as `start` says), writing its plan and
    /// state, and those below, to `levels`.
    fn solve(
        &mut self,
        features: &mut FeatureSet,
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, usize, usize, f64, f64, bool) {
        let co = &mut self.optimizer;
        match levels {
            Some(out) => {
                let (plan, plans) = out.plans.split_first_mut().expect("one plan per level");
                let (state, states) = out.states.split_first_mut().expect("one state per level");
                let result = co.solve_prepared(features, &self.weights, deadline, start, Some(LevelsOut { plans, states }));
                plan.copy_from_slice(&co.traj);
                *state = co.state;
                result
            }
            None => co.solve_prepared(features, &self.weights, deadline, start, None),
        }
    }

    /// Plan by knots: solves the knot problem — from the knots of `traj` (`Start::Plan`), from the
    /// knot plan that goes with it (`Start::Levels`), or from the straight line — and sets `traj`
    /// (N × n) to the knots' interpolation. Returns what [`TrajectoryOptimizer::solve_by_knots`]
    /// returns.
    fn solve_knots(
        &mut self,
        features: &mut FeatureSet,
        weights: &[f64],
        traj: &mut [f64],
        deadline: Option<Instant>,
        start: Start<'_>,
        levels: Option<LevelsOut<'_>>,
    ) -> (usize, usize, usize, f64, f64, bool) {
        let n = self.optimizer.dof;
        let m = traj.len() / n;
        self.weights.copy_from_slice(weights);
        let below = match start {
            Start::Plan => {
                let mut knots = std::mem::take(&mut self.optimizer.traj);
                self.sample(traj, &mut knots);
                let co = &mut self.optimizer;
                co.traj = knots;
                co.resume = None;
                pin_ends_within_limits(&mut co.traj, &traj[..n], &traj[(m - 1) * n..], &co.lower, &co.upper);
                Start::Plan
            }
            other => self.prepare(&traj[..n], &traj[(m - 1) * n..], other),
        };
        let (iterations, coarse_iterations, evaluations, cost, penalty, converged) =
            self.solve(features, deadline, below, levels);
        self.hand_down(traj, false);
        (iterations, coarse_iterations, evaluations, cost, penalty, converged && self.optimizer.coarse_converged)
    }

    /// Hands the coarse plan down to the fine plan `traj` (N × n, ends kept): its interpolation,
    /// or with `correct` the interpolated change from the coarse start added to `traj`; clamped
    /// into the joint limits.
    fn hand_down(&self, traj: &mut [f64], correct: bool) {
        let co = &self.optimizer;
        let n = co.dof;
        let m = traj.len() / n;
        for (i, taps) in self.up.iter().enumerate().take(m - 1).skip(1) {
            for j in 0..n {
                let k = i * n + j;
                let q = if correct {
                    traj[k] + taps.iter().map(|&(ci, w)| w * (co.traj[ci * n + j] - self.start[ci * n + j])).sum::<f64>()
                } else {
                    taps.iter().map(|&(ci, w)| w * co.traj[ci * n + j]).sum::<f64>()
                };
                traj[k] = q.clamp(co.lower[j], co.upper[j]);
            }
        }
    }
}

/// Taps of the linear interpolation in time of a trajectory of `from` segments at the waypoints of
/// one of `to` segments over the same time: each output waypoint from the two inputs around it
/// (end points and straight lines exactly). Linear rather than a spline through the waypoints: a
/// spline overshoots where the path bends hardest, which is where it presses against a clearance
/// or a keep-out.
fn interpolation_taps(from: usize, to: usize) -> Vec<[(usize, f64); 2]> {
    (0..=to)
        .map(|i| {
            let u = i as f64 * from as f64 / to as f64;
            let a = (u.floor() as usize).min(from - 1);
            let s = u - a as f64;
            [(a, 1.0 - s), (a + 1, s)]
        })
        .collect()
}

/// How a solve starts (see multiresolution in the module docs).
#[derive(Clone, Copy)]
pub(super) enum Start<'a> {
    /// From the straight line, coarse to fine.
    Line,
    /// From a given plan, on its waypoints only.
    Plan,
    /// From a given plan (in `traj`) and the coarse plans that go with it, coarsest last, with the
    /// coarse solvers' states to resume from.
    Levels { plans: &'a [Vec<f64>], states: Option<&'a [SolverState]> },
}

/// Where the coarse levels' plans and solver states go (see [`PlanLevels`]).
pub(super) struct LevelsOut<'a> {
    pub(super) plans: &'a mut [Vec<f64>],
    pub(super) states: &'a mut [SolverState],
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(taps: &[[(usize, f64); 2]], x: &[f64]) -> Vec<f64> {
        taps.iter().map(|row| row.iter().map(|&(k, w)| w * x[k]).sum()).collect()
    }

    #[test]
    fn interpolation_keeps_end_points_and_lines_and_is_linear_in_time() {
        for (from, to) in [(10, 30), (33, 99), (4, 11), (30, 10), (1, 5)] {
            let taps = interpolation_taps(from, to);
            assert_eq!(taps.len(), to + 1);
            // Weights in [0, 1] summing to one (constants are kept), only inputs 0..=from read.
            for row in &taps {
                assert!((row.iter().map(|t| t.1).sum::<f64>() - 1.0).abs() < 1e-14);
                assert!(row.iter().all(|t| t.0 <= from && (0.0..=1.0).contains(&t.1)));
            }
            let line: Vec<f64> = (0..=from).map(|i| 0.3 - 1.7 * i as f64 / from as f64).collect();
            let out = apply(&taps, &line);
            for (i, v) in out.iter().enumerate() {
                assert!((v - (0.3 - 1.7 * i as f64 / to as f64)).abs() < 1e-14, "{from} → {to}, row {i}");
            }
            let wavy: Vec<f64> = (0..=from).map(|i| (i as f64).sin()).collect();
            let out = apply(&taps, &wavy);
            assert_eq!(out[0], wavy[0]);
            assert!((out[to] - wavy[from]).abs() < 1e-15);
            // Between two inputs, on the segment joining them.
            for (i, v) in out.iter().enumerate() {
                let u = i as f64 * from as f64 / to as f64;
                let a = (u.floor() as usize).min(from - 1);
                let (lo, hi) = (wavy[a].min(wavy[a + 1]), wavy[a].max(wavy[a + 1]));
                assert!(*v >= lo - 1e-15 && *v <= hi + 1e-15, "{from} → {to}, row {i}");
            }
        }
    }
}
