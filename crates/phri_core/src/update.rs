//! The online MAP update of the objective's weights (paper eq. 13) and its published variants.
//!
//! The paper writes rewards: θ ← θ + α(Φ(ξ_H) − Φ(ξ_R)). phri, like the authors' code, keeps *cost*
//! weights w = −θ (the planner minimises w·Φ), so the same step reads
//!
//! w ← clip(w − α ⊙ (Φ(ξ_H) − Φ(ξ_R)), lower, upper),
//!
//! with a per-feature step α, bounds, and a mask of the features that are learned at all (the paper
//! never learns efficiency).

use crate::error::{check_finite, check_vector, PhriError, Result};

/// Which learned weights one correction moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UpdateRule {
    /// Every learned weight (the paper).
    All,
    /// Only the learned feature with the largest range-normalised |ΔΦ_k| ("one feature at a time",
    /// Bajcsy et al., HRI 2018).
    Max,
    /// Every learned weight, each step scaled by the feature's relevance to the push: the fraction
    /// (‖u*_k‖/‖u_H‖)² of the applied torque that the smallest torque u*_k producing the same change
    /// of feature k would need (after Bobu et al., CoRL 2018, without their fitted β model).
    Confidence,
    /// Every learned weight, the step scaled by how well the learned features explain the push:
    /// min(1, β̂ / [`crate::belief::BETA_FULL`]) with β̂ the push's rationality
    /// ([`crate::belief::rationality`], after Bobu et al., T-RO 2020), the same for every feature.
    Beta,
}

impl UpdateRule {
    /// Every rule, in the order of [`UpdateRule::NAMES`].
    pub const ALL: [UpdateRule; 4] = [UpdateRule::All, UpdateRule::Max, UpdateRule::Confidence, UpdateRule::Beta];
    /// The rules' names, as task files, study files and the Python API spell them.
    pub const NAMES: [&'static str; 4] = ["all", "max", "confidence", "beta"];

    /// The rule's name.
    pub fn name(self) -> &'static str {
        match self {
            UpdateRule::All => UpdateRule::NAMES[0],
            UpdateRule::Max => UpdateRule::NAMES[1],
            UpdateRule::Confidence => UpdateRule::NAMES[2],
            UpdateRule::Beta => UpdateRule::NAMES[3],
        }
    }

    /// Whether the rule scales its steps by a per-feature factor (`WeightUpdate::apply`'s
    /// `relevance`): the relevance for [`UpdateRule::Confidence`], the step scale of the push's β̂
    /// for [`UpdateRule::Beta`].
    pub fn scales_steps(self) -> bool {
        matches!(self, UpdateRule::Confidence | UpdateRule::Beta)
    }

    /// The rule named `name`, or an InvalidParameter error naming `arg` and the known rules.
    pub fn from_name(arg: &str, name: &str) -> Result<Self> {
        match UpdateRule::NAMES.iter().position(|n| *n == name) {
            Some(i) => Ok(UpdateRule::ALL[i]),
            None => {
                let known = UpdateRule::NAMES.map(|n| format!("'{n}'")).join(", ");
                Err(PhriError::invalid(arg, format!("must be one of {known}, got '{name}'")))
            }
        }
    }
}

/// Step sizes, bounds and the rule; one entry per feature, in the feature set's order.
#[derive(Debug, Clone)]
pub struct UpdateParams {
    /// Step α_k per feature [weight per unit feature count].
    pub step: Vec<f64>,
    /// Lower bound of each weight.
    pub lower: Vec<f64>,
    /// Upper bound of each weight.
    pub upper: Vec<f64>,
    /// Whether each weight is learned.
    pub learned: Vec<bool>,
    /// Range of each feature, for the MAX rule's normalisation (1 = none).
    pub ranges: Vec<f64>,
    pub rule: UpdateRule,
}

/// What one update did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateInfo {
    /// The feature the MAX rule chose (None for the other rules, or if nothing was learned).
    pub chosen: Option<usize>,
    /// Whether any weight hit a bound.
    pub clipped: bool,
    /// The largest |change| of a weight.
    pub max_change: f64,
}

/// A validated update rule; `apply` allocates nothing.
#[derive(Debug, Clone)]
pub struct WeightUpdate {
    params: UpdateParams,
}

impl WeightUpdate {
    pub fn new(params: UpdateParams) -> Result<Self> {
        let k = params.step.len();
        if k == 0 {
            return Err(PhriError::invalid("step", "must have one entry per feature, got none"));
        }
        for (name, v) in [("lower", &params.lower), ("upper", &params.upper), ("ranges", &params.ranges)] {
            if v.len() != k {
                return Err(PhriError::shape(name, format!("({k},) like step"), format!("({},)", v.len())));
            }
        }
        if params.learned.len() != k {
            return Err(PhriError::shape("learned", format!("({k},) like step"), format!("({},)", params.learned.len())));
        }
        check_finite("step", &params.step)?;
        if let Some((i, v)) = params.step.iter().enumerate().find(|(_, v)| **v < 0.0) {
            return Err(PhriError::invalid("step", format!("[{i}] must be >= 0, got {v}")));
        }
        for (i, (lo, hi)) in params.lower.iter().zip(&params.upper).enumerate() {
            if lo.is_nan() || hi.is_nan() || lo > hi {
                return Err(PhriError::invalid("lower", format!("[{i}] = {lo} must not be above upper[{i}] = {hi}")));
            }
            // ±∞ bounds mean "unbounded on that side"; both on the same infinity leave no weight.
            if *lo == f64::INFINITY || *hi == f64::NEG_INFINITY {
                return Err(PhriError::invalid(
                    "lower",
                    format!("[{i}] = {lo} and upper[{i}] = {hi} leave no finite weight between them"),
                ));
            }
        }
        if let Some((i, v)) =
            params.ranges.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0 && (1.0 / **v).is_finite()))
        {
            return Err(PhriError::invalid("ranges", format!("[{i}] must be finite and > 0 (with a finite inverse), got {v}")));
        }
        Ok(WeightUpdate { params })
    }

    pub fn params(&self) -> &UpdateParams {
        &self.params
    }

    pub fn len(&self) -> usize {
        self.params.step.len()
    }

    pub fn is_empty(&self) -> bool {
        self.params.step.is_empty()
    }

    /// Clips `weights` into the bounds (e.g. initial weights from a task file).
    pub fn clip(&self, weights: &mut [f64]) -> bool {
        let mut clipped = false;
        for ((w, lo), hi) in weights.iter_mut().zip(&self.params.lower).zip(&self.params.upper) {
            let c = w.clamp(*lo, *hi);
            clipped |= c != *w;
            *w = c;
        }
        clipped
    }

    /// One step w ← clip(w − α ⊙ ΔΦ) with ΔΦ = Φ(ξ_H) − Φ(ξ_R). `relevance` (per feature, in [0, 1]:
    /// the factor on each step) is required by [`UpdateRule::Confidence`] and [`UpdateRule::Beta`]
    /// and ignored by the others.
    pub fn apply(&self, weights: &mut [f64], delta_phi: &[f64], relevance: Option<&[f64]>) -> Result<UpdateInfo> {
        let k = self.len();
        check_vector("weights", weights, k)?;
        check_vector("delta_phi", delta_phi, k)?;
        let p = &self.params;
        let chosen = match p.rule {
            UpdateRule::Max => (0..k)
                .filter(|&i| p.learned[i])
                .map(|i| (i, (delta_phi[i] / p.ranges[i]).abs()))
                .fold(None, |best: Option<(usize, f64)>, (i, v)| match best {
                    Some((_, b)) if b >= v => best,
                    _ => Some((i, v)),
                })
                .map(|(i, _)| i),
            _ => None,
        };
        let relevance = match (p.rule.scales_steps(), relevance) {
            (true, Some(r)) => {
                check_vector("relevance", r, k)?;
                Some(r)
            }
            (true, None) => {
                return Err(PhriError::invalid("relevance", format!("is required by the {} update rule", p.rule.name())))
            }
            (false, _) => None,
        };
        let moves = |i: usize| p.learned[i] && (p.rule != UpdateRule::Max || chosen == Some(i));
        let target = |i: usize, w: f64| w - p.step[i] * relevance.map_or(1.0, |r| r[i].clamp(0.0, 1.0)) * delta_phi[i];
        if let Some(i) = (0..k).find(|&i| moves(i) && !target(i, weights[i]).is_finite()) {
            // Checked before any weight moves, so an error leaves the weights as they were.
            return Err(PhriError::invalid(
                "delta_phi",
                format!("[{i}] = {:e} times step {:e} overflows the weight (non-finite)", delta_phi[i], p.step[i]),
            ));
        }
        let mut info = UpdateInfo { chosen, clipped: false, max_change: 0.0 };
        for i in 0..k {
            if !moves(i) {
                continue;
            }
            let target = target(i, weights[i]);
            let new = target.clamp(p.lower[i], p.upper[i]);
            info.clipped |= new != target;
            info.max_change = info.max_change.max((new - weights[i]).abs());
            weights[i] = new;
        }
        Ok(info)
    }
}

/// Relevance of each feature to a push u_H, from the linearised sensitivity of the feature change
/// to the torque, S = ∂ΔΦ/∂u_H (K × n, row-major): the smallest torque producing the observed change
/// of feature k is u*_k = S_k ΔΦ_k / ‖S_k‖², so relevance_k = min(1, (‖u*_k‖ / ‖u_H‖)²).
pub fn relevance(delta_phi: &[f64], sensitivity: &[f64], u_h: &[f64], out: &mut [f64]) -> Result<()> {
    let (k, n) = (delta_phi.len(), u_h.len());
    check_vector("sensitivity", sensitivity, k * n)?;
    check_vector("relevance", out, k)?;
    let push: f64 = u_h.iter().map(|v| v * v).sum();
    for i in 0..k {
        let s2: f64 = sensitivity[i * n..(i + 1) * n].iter().map(|v| v * v).sum();
        out[i] = if push > 0.0 && s2 > 0.0 { (delta_phi[i] * delta_phi[i] / s2 / push).min(1.0) } else { 0.0 };
    }
    Ok(())
}
