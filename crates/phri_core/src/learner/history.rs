//! What the learner records, for logs and plots: every sampled interaction, every plan that took
//! effect and every replan it refused.

use crate::belief::Rationality;
use crate::trajopt::TrajoptInfo;
use crate::update::UpdateInfo;

/// One sampled interaction and what the learner did with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Interaction {
    /// Time [s].
    pub t: f64,
    /// Thresholded interaction torque u_H [N·m].
    pub u_h: Vec<f64>,
    /// Φ(ξ_H) − Φ(ξ_R) (empty when not learning or when the deformation was skipped).
    pub delta_phi: Vec<f64>,
    /// Weights after the update. Where none was made (no deformation, a failed learning), the
    /// learner's weights at the push: with a replan worker, those it had taken in by then.
    pub weights: Vec<f64>,
    /// Waypoints the deformation moved (0: skipped near the end, or not learning).
    pub moved: usize,
    pub update: Option<UpdateInfo>,
    /// What the replan this interaction asked for did. With a replan worker
    /// (`LearnerParams::replan_latency` not 0) it is filled in when its plan is adopted or
    /// rejected, and stays `None` if a newer interaction superseded it first.
    pub replan: Option<TrajoptInfo>,
    /// How well the learned features explain the push (None where no deformation was made).
    pub rationality: Option<Rationality>,
    /// The belief's covariance after the update, K × K row-major (empty where none was made).
    pub covariance: Vec<f64>,
}

/// A replan the learner did not adopt because it was not feasible (see
/// [`crate::trajopt::TrajoptInfo::feasible`]) or its worker failed: the robot kept tracking its
/// last feasible plan.
#[derive(Debug, Clone, PartialEq)]
pub struct RejectedPlan {
    /// Time the plan would have taken effect [s] (inline: the time of the replan).
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
    /// Replans not adopted because they were infeasible (or their worker failed).
    pub rejected: Vec<RejectedPlan>,
}
