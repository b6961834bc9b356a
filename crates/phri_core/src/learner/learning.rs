//! The learning half of Algorithm 1: from a push's deformation to new weights (eq. 13, under the
//! update rule) with the belief's covariance and β̂ ([`crate::belief`]). The learner runs it
//! inline, or hands each correction to its replan worker, which learns from the corrections in
//! the order they came and then replans for the newest weights: the control tick then only
//! detects and deforms.

use crate::belief::{rationality, Belief, Rationality};
use crate::error::{PhriError, Result};
use crate::features::FeatureSet;
use crate::update::{relevance, UpdateInfo, UpdateRule, WeightUpdate};

/// What the control side hands over for one push: the plan as the robot tracked it, its
/// deformation by the push, and the push. Its buffers are sized once (a queued correction is
/// copied into one, never allocated).
#[derive(Debug, Clone)]
pub(super) struct Correction {
    /// ξ_R as tracked at the push, N × n row-major [rad].
    pub(super) tracked: Vec<f64>,
    /// ξ_H = ξ_R + μ A⁻¹ U_H (eq. 7), N × n [rad].
    pub(super) deformed: Vec<f64>,
    /// The deformation of a unit torque on every joint at the push's waypoint, N × n [rad/(N·m)]:
    /// ∂ξ_H/∂u_H, for the push's sensitivity.
    pub(super) shape: Vec<f64>,
    /// The thresholded push u_H (n,) [N·m].
    pub(super) u_h: Vec<f64>,
    /// The sampled torque less the detector's bias (n,) [N·m]: β̂'s push.
    pub(super) push: Vec<f64>,
}

impl Correction {
    pub(super) fn new(m: usize, n: usize) -> Self {
        Correction {
            tracked: vec![0.0; m * n],
            deformed: vec![0.0; m * n],
            shape: vec![0.0; m * n],
            u_h: vec![0.0; n],
            push: vec![0.0; n],
        }
    }

    /// Copies `other` into this one's buffers (same sizes).
    pub(super) fn copy_from(&mut self, other: &Correction) {
        self.tracked.copy_from_slice(&other.tracked);
        self.deformed.copy_from_slice(&other.deformed);
        self.shape.copy_from_slice(&other.shape);
        self.u_h.copy_from_slice(&other.u_h);
        self.push.copy_from_slice(&other.push);
    }
}

/// What one correction taught: the learner's record of it.
#[derive(Debug, Clone)]
pub(super) struct Learned {
    /// Φ(ξ_H) − Φ(ξ_R).
    pub(super) delta_phi: Vec<f64>,
    /// The weights after the update, and those the planner plans with.
    pub(super) weights: Vec<f64>,
    pub(super) plan_weights: Vec<f64>,
    pub(super) update: UpdateInfo,
    pub(super) rationality: Rationality,
    /// The belief's covariance after the update, K × K row-major.
    pub(super) covariance: Vec<f64>,
}

/// The weights, the belief and the update rule, with the features that score a correction.
pub(super) struct Learning {
    features: FeatureSet,
    update: WeightUpdate,
    belief: Belief,
    /// `LearnerParams::risk` (empty: plan with the estimate).
    risk: Vec<f64>,
    weights: Vec<f64>,
    plan_weights: Vec<f64>,
    initial_weights: Vec<f64>,
    /// Which features β̂ asks about (learned, with a step).
    explaining: Vec<bool>,
    // Scratch, sized once.
    phi_r: Vec<f64>,
    phi_h: Vec<f64>,
    delta_phi: Vec<f64>,
    jacobian: Vec<f64>,
    sensitivity: Vec<f64>,
    relevance: Vec<f64>,
}

impl Learning {
    /// `weights` clipped to the update's bounds are the estimate's start; `risk` is checked by the
    /// learner. `m` waypoints of the model's n joints.
    pub(super) fn new(
        features: FeatureSet,
        update: WeightUpdate,
        belief: Belief,
        risk: Vec<f64>,
        weights: Vec<f64>,
        m: usize,
    ) -> Self {
        let (k, n) = (features.len(), features.model().nq());
        let p = update.params();
        // The features β̂ asks about: those the belief has a variance for (learned, step > 0).
        let explaining: Vec<bool> = (0..k).map(|i| p.learned[i] && p.step[i] > 0.0).collect();
        let mut learning = Learning {
            features,
            update,
            belief,
            risk,
            plan_weights: vec![0.0; k],
            initial_weights: weights.clone(),
            weights,
            explaining,
            phi_r: vec![0.0; k],
            phi_h: vec![0.0; k],
            delta_phi: vec![0.0; k],
            jacobian: vec![0.0; k * m * n],
            sensitivity: vec![0.0; k * n],
            relevance: vec![0.0; k],
        };
        learning.refresh_plan_weights();
        learning
    }

    pub(super) fn update(&self) -> &WeightUpdate {
        &self.update
    }

    /// Current weights w (cost form).
    pub(super) fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The weights the planner plans with: `weights`, or with a risk vector w + k ⊙ σ.
    pub(super) fn plan_weights(&self) -> &[f64] {
        &self.plan_weights
    }

    /// The belief's covariance, K × K row-major.
    pub(super) fn covariance(&self) -> &[f64] {
        self.belief.covariance()
    }

    /// Back to the initial weights and the prior.
    pub(super) fn reset(&mut self) {
        self.weights.clone_from(&self.initial_weights);
        self.belief.reset();
        self.refresh_plan_weights();
    }

    /// Learns from one correction: ΔΦ, the push's sensitivity, β̂, the update and the belief.
    /// Anything that refuses the push does so before anything changes.
    pub(super) fn learn(&mut self, c: &Correction) -> Result<Learned> {
        let n = c.u_h.len();
        // Φ(ξ_R) with its gradient, for the push's sensitivity (the belief, β̂, the relevance).
        self.features.phi_gradient(&c.tracked, &mut self.phi_r, &mut self.jacobian)?;
        self.features.phi(&c.deformed, &mut self.phi_h)?;
        for k in 0..self.delta_phi.len() {
            self.delta_phi[k] = self.phi_h[k] - self.phi_r[k];
        }
        if self.delta_phi.iter().any(|v| !v.is_finite()) {
            return Err(PhriError::invalid(
                "tau_measured",
                "is so large that the deformed trajectory's features overflow (non-finite)",
            ));
        }
        self.compute_sensitivity(&c.shape, n);
        // β̂ looks at the whole push: the detector's thresholds zero the joints it barely loads,
        // which would hide how well the features explain it.
        let rationality = rationality(&self.sensitivity, &self.explaining, &c.push)?;
        let relevance = match self.update.params().rule {
            UpdateRule::Confidence => {
                relevance(&self.delta_phi, &self.sensitivity, &c.u_h, &mut self.relevance)?;
                Some(&self.relevance[..])
            }
            UpdateRule::Beta => {
                self.relevance.fill(rationality.step_scale());
                Some(&self.relevance[..])
            }
            _ => None,
        };
        let evidence = self.belief.evidence(&self.sensitivity, n)?;
        let mut weights = self.weights.clone();
        let update = self.update.apply(&mut weights, &self.delta_phi, relevance)?;
        self.weights = weights;
        self.belief.accept(evidence);
        self.refresh_plan_weights();
        Ok(Learned {
            delta_phi: self.delta_phi.clone(),
            weights: self.weights.clone(),
            plan_weights: self.plan_weights.clone(),
            update,
            rationality,
            covariance: self.belief.covariance().to_vec(),
        })
    }

    /// Linearised sensitivity S = ∂ΔΦ/∂u_H (K × n) of the push whose unit deformation is `shape`
    /// (N × n), from the gradient of Φ at the tracked plan (in `jacobian`).
    fn compute_sensitivity(&mut self, shape: &[f64], n: usize) {
        let (k_len, m) = (self.delta_phi.len(), shape.len() / n.max(1));
        self.sensitivity.fill(0.0);
        for k in 0..k_len {
            for i in 0..m {
                for j in 0..n {
                    self.sensitivity[k * n + j] += self.jacobian[(k * m + i) * n + j] * shape[i * n + j];
                }
            }
        }
    }

    /// `plan_weights` from the estimate and the belief: w, or with a risk vector w + k ⊙ σ clipped
    /// to the bounds.
    fn refresh_plan_weights(&mut self) {
        self.plan_weights.copy_from_slice(&self.weights);
        if !self.risk.is_empty() {
            for (i, w) in self.plan_weights.iter_mut().enumerate() {
                *w += self.risk[i] * self.belief.std_of(i);
            }
            self.update.clip(&mut self.plan_weights);
        }
    }
}
