//! What a caller tunes ([`TrajoptParams`], with the penalties [`Clearance`] and `max_step`, and the
//! Newton model's [`KinematicCurvature`]) and what a solve reports ([`TrajoptInfo`]).

use std::sync::Arc;
use std::time::Duration;

use crate::collision::CollisionChecker;
use crate::error::{check_vector, PhriError, Result};
use crate::model::{FrameId, RobotModel};

/// Keep a frame's origin above a height (the hand above the table top plus a clearance), as the
/// quadratic penalty ρ·max(0, z_min − z)² at every interior waypoint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clearance {
    /// The frame whose origin is kept up.
    pub frame: FrameId,
    /// Lowest allowed z of the frame origin [m] (table top + clearance).
    pub min_z: f64,
    /// Penalty weight ρ [cost per m²].
    pub weight: f64,
}

/// Keep the arm's collision bodies clear of a scene and of each other along the executed curve
/// (see `trajopt::collision`): the penalty ρ·max(0, margin + buffer − d)² per sphere pair at
/// `samples` points per segment.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionParams {
    /// The pairs and their margins.
    pub checker: Arc<CollisionChecker>,
    /// Penalty weight ρ [cost per m²] (default 10⁴).
    pub weight: f64,
    /// Extra clearance the penalty aims at beyond each margin [m] (default 6 mm): the quadratic
    /// penalty's give at an optimum, and the executed cubic's bulge beyond the chords at which the
    /// penalty acts, stay inside it.
    pub buffer: f64,
    /// Pairs within margin + band are modelled by the Newton step [m] (default 5 cm).
    pub band: f64,
    /// Points per segment of the executed cubic at which the penalty acts (default 4, the last
    /// the waypoint).
    pub samples: usize,
}

/// Default [`CollisionParams::weight`] [cost per m²].
pub const DEFAULT_COLLISION_WEIGHT: f64 = 1e4;
/// Default [`CollisionParams::buffer`] [m].
pub const DEFAULT_COLLISION_BUFFER: f64 = 6e-3;
/// Default [`CollisionParams::band`] [m].
pub const DEFAULT_COLLISION_BAND: f64 = 0.05;
/// Default [`CollisionParams::samples`] [points per segment].
pub const DEFAULT_COLLISION_SAMPLES: usize = 4;
/// Most [`CollisionParams::samples`] [points per segment]: each costs a distance query per sphere
/// pair per segment and Newton iteration.
pub const MAX_COLLISION_SAMPLES: usize = 64;

impl CollisionParams {
    /// The defaults for `checker`.
    pub fn new(checker: Arc<CollisionChecker>) -> Self {
        CollisionParams {
            checker,
            weight: DEFAULT_COLLISION_WEIGHT,
            buffer: DEFAULT_COLLISION_BUFFER,
            band: DEFAULT_COLLISION_BAND,
            samples: DEFAULT_COLLISION_SAMPLES,
        }
    }

    fn check(&self) -> Result<()> {
        for (arg, v) in [("collision_weight", self.weight), ("collision_buffer", self.buffer), ("collision_band", self.band)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(PhriError::invalid(arg, format!("must be finite and >= 0, got {v}")));
            }
        }
        if !(self.weight > 0.0) {
            return Err(PhriError::invalid("collision_weight", "must be > 0"));
        }
        // The penalty is on from margin + buffer, and pairs are visited within margin + band (self
        // pairs within SELF_BAND at most): the band must reach past the buffer, or the cost jumps.
        if self.buffer > self.band.min(crate::collision::SELF_BAND) {
            return Err(PhriError::invalid(
                "collision_buffer",
                format!("must be at most the band ({} m) and {} m, got {}", self.band, crate::collision::SELF_BAND, self.buffer),
            ));
        }
        if !(1..=MAX_COLLISION_SAMPLES).contains(&self.samples) {
            return Err(PhriError::invalid(
                "collision_samples",
                format!("must be in 1..={MAX_COLLISION_SAMPLES} points per segment, got {}", self.samples),
            ));
        }
        Ok(())
    }
}

/// Most waypoints of a plan [count]. What a plan costs grows with N: about 10 kB of workspace per
/// waypoint for 7 joints (100 MB at the limit), and a Newton iteration more than linearly (measured
/// on the shared 2-core machine, efficiency and table, speed limits on: 0.08 s per iteration at
/// N = 1000, 1.7 s at 4000, 20 s at 10⁴, where a cold solve takes minutes; `max_time` caps it).
/// 10⁴ waypoints are 10 s at 1 kHz; the paper plans 31.
pub const MAX_WAYPOINTS: usize = 10_000;

/// Most Newton iterations of a solve per level [count] (`max_iterations`; the default is 500, and
/// the study's plans converge within about 150).
pub const MAX_ITERATIONS: usize = 100_000;

/// Longest wall-time cap `max_time` of a solve [s] (a day).
pub const MAX_TIME: f64 = 86_400.0;

/// A plan is feasible when no margin is violated by more than this along its executed curve [m].
pub const CLEARANCE_TOLERANCE: f64 = 1e-3;

/// ... and no joint moves faster along the executed cubic than its `max_step` allows by more than
/// this fraction of it [1]: the penalty holds the chords between waypoints (the end segments at 2/3),
/// and the cubic through them runs faster where a joint speeds up and slows down within a segment
/// (measured up to about 1.3 times on the study's tasks and variations). With `max_step` at most
/// 1/(1 + STEP_TOLERANCE) = 2/3 of velocity limit × spacing, the executed speed of a feasible plan
/// stays within the limits (the study plans at 0.5).
pub const STEP_TOLERANCE: f64 = 0.5;

/// The Newton model's share of the kinematics' second derivatives (see
/// `TrajoptParams::kinematic_curvature`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KinematicCurvature {
    /// Leave them out: the Gauss–Newton part only. Far from the optimum it models these features
    /// better than the exact Hessian, which is indefinite along much of the path and forces heavy
    /// damping; near it, convergence is only linear where they matter (table: the clearance holds
    /// the hand down and the table feature's curvature decides the rest).
    GaussNewton,
    /// Gauss–Newton until the model's pieces agree with its step (the active set has settled) and
    /// it predicts little more decrease, exact from then on, for a quadratic end; back to
    /// Gauss–Newton for the rest of the solve if a step with it fails, or if its Hessian stays
    /// indefinite (two steps in a row need more damping than a Newton step's), where no quadratic
    /// end comes of it.
    #[default]
    Settled,
    /// Include them from the start.
    Exact,
}

/// Tuning of the optimiser; `Default` gives the documented defaults.
///
/// With `max_time` unset every solve is deterministic: the same inputs give bit-identical plans.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajoptParams {
    /// Iteration cap: Newton steps tried on the given waypoints (each coarse level has its own).
    pub max_iterations: usize,
    /// Wall-time cap; `None` (the default) keeps results deterministic.
    pub max_time: Option<Duration>,
    /// Stop when the largest projected-gradient entry is below this [cost per rad].
    pub gradient_tolerance: f64,
    /// Stop when a step lowers (or the model predicts it lowers) the cost by less than this
    /// fraction of it [1].
    pub relative_tolerance: f64,
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
    /// The collision bodies kept clear of the scene and of each other; None for no checks.
    pub collision: Option<CollisionParams>,
    /// How the Newton model treats the second derivatives of the kinematics in the features that
    /// act at every waypoint (table, coffee, origin) and in the clearance penalty (default
    /// [`KinematicCurvature::Settled`]). See `features::SegmentHessian::kinematic`.
    pub kinematic_curvature: KinematicCurvature,
    /// Multiresolution (see the module docs): a coarser copy of the problem with about
    /// 1/`coarsening` of the segments, recursively, on which cold solves and `solve_levels` warm
    /// starts begin; 0 or 1 solves on the given waypoints only. Default 3.
    pub coarsening: usize,
    /// Fewest waypoints of a coarse level (default 8): a level that would have fewer is not built.
    pub coarsest: usize,
    /// Plan by knots: 0 (the default) optimises every waypoint; K ≥ 3, with K − 1 dividing the
    /// waypoints' segments (every knot on a waypoint), makes every plan piecewise linear in joint
    /// space through K knots evenly spaced in time (the start and the goal among them), found by optimising the problem on the knots (the features and penalties at the
    /// knots, the collision penalty along the chords between them, the step limit per knot
    /// interval) and sampled at the waypoints. This is the original system's planner, which ran
    /// trajopt on 4 waypoints and upsampled its plan linearly to 31 (`coarsening` then applies
    /// to the knot problem). Feasibility is checked on the sampled plan, as the arm executes it.
    pub knots: usize,
}

impl Default for TrajoptParams {
    fn default() -> Self {
        TrajoptParams {
            max_iterations: 500,
            max_time: None,
            gradient_tolerance: 1e-6,
            relative_tolerance: 1e-9,
            smoothing: 0.05,
            clearance: Vec::new(),
            max_step: Vec::new(),
            step_weight: 1e3,
            collision: None,
            kinematic_curvature: KinematicCurvature::Settled,
            coarsening: 3,
            coarsest: 8,
            knots: 0,
        }
    }
}

impl TrajoptParams {
    /// Checks the parameters for `model`, naming the offending one.
    pub(super) fn check(&self, model: &RobotModel) -> Result<()> {
        if !(1..=MAX_ITERATIONS).contains(&self.max_iterations) {
            return Err(PhriError::invalid(
                "max_iterations",
                format!("must be in 1..={MAX_ITERATIONS} Newton iterations, got {}", self.max_iterations),
            ));
        }
        if let Some(t) = self.max_time {
            if t.is_zero() || t.as_secs_f64() > MAX_TIME {
                return Err(PhriError::invalid("max_time", format!("must be in (0, {MAX_TIME}] s, got {} s", t.as_secs_f64())));
            }
        }
        if !(self.smoothing >= 0.0 && self.smoothing.is_finite()) {
            return Err(PhriError::invalid("smoothing", format!("must be finite and >= 0, got {}", self.smoothing)));
        }
        if !(self.gradient_tolerance >= 0.0 && self.relative_tolerance >= 0.0) {
            return Err(PhriError::invalid("gradient_tolerance", "and relative_tolerance must be >= 0"));
        }
        for c in &self.clearance {
            if c.frame.0 >= model.frames.len() {
                return Err(PhriError::invalid("clearance", "frame is not a frame of this robot"));
            }
            if !(c.min_z.is_finite() && c.weight.is_finite() && c.weight > 0.0) {
                return Err(PhriError::invalid("clearance", "min_z must be finite and weight finite and > 0"));
            }
        }
        if let Some(c) = &self.collision {
            c.check()?;
        }
        if !(3..=MAX_WAYPOINTS).contains(&self.coarsest) {
            return Err(PhriError::invalid(
                "coarsest",
                format!("must be in 3..={MAX_WAYPOINTS} waypoints, got {}", self.coarsest),
            ));
        }
        if self.coarsening > MAX_WAYPOINTS {
            return Err(PhriError::invalid(
                "coarsening",
                format!("must be in 0..={MAX_WAYPOINTS} (segments per coarse segment; 0 or 1 for none), got {}", self.coarsening),
            ));
        }
        if self.knots != 0 && !(3..=MAX_WAYPOINTS).contains(&self.knots) {
            return Err(PhriError::invalid(
                "knots",
                format!(
                    "must be 0 (plan every waypoint) or in 3..={MAX_WAYPOINTS} (start, a free knot, goal), got {}",
                    self.knots
                ),
            ));
        }
        if !self.max_step.is_empty() {
            check_vector("max_step", &self.max_step, model.nq())?;
            if self.max_step.iter().any(|v| *v <= 0.0) || !(self.step_weight.is_finite() && self.step_weight > 0.0) {
                return Err(PhriError::invalid("max_step", "entries and step_weight must be > 0"));
            }
        }
        Ok(())
    }
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajoptInfo {
    /// Newton iterations on the given waypoints (for a plan by knots: on the knots) [count].
    pub iterations: usize,
    /// Newton iterations on the coarse levels, all together (0 without multiresolution; for a plan
    /// by knots, the knot problem's own coarse levels) [count].
    pub coarse_iterations: usize,
    /// Cost evaluations on the given waypoints (for a plan by knots: on the knots), each one Φ,
    /// ∇Φ and ∇²Φ [count].
    pub evaluations: usize,
    /// Final cost w·Φ + penalty [cost].
    pub cost: f64,
    /// Final penalty part of the cost (clearance and max_step) [cost].
    pub penalty: f64,
    /// Largest violation of a clearance or a collision margin along the executed curve [m] (0
    /// when all are kept or none is set).
    pub max_violation: f64,
    /// Largest joint move per segment of the executed curve (the cubic's speed times the waypoint
    /// spacing) beyond `max_step` [rad] (0 without max_step); much more than the penalty's give,
    /// gradient/(2·step_weight), means the goal is too far for the duration.
    pub max_step_excess: f64,
    /// The largest such excess as a fraction of its joint's `max_step` [1] (0 without max_step):
    /// above [`STEP_TOLERANCE`] the plan is infeasible.
    pub step_excess_ratio: f64,
    /// The plan keeps every margin within [`CLEARANCE_TOLERANCE`] and every joint within
    /// `max_step` by [`STEP_TOLERANCE`] along its executed curve (whether or not it converged).
    pub feasible: bool,
    /// Met a tolerance (rather than an iteration or time cap).
    pub converged: bool,
    /// Wall time [s].
    pub seconds: f64,
}
