//! What the learner knows about the weights besides its estimate: a Gaussian belief, and how well
//! the features explain each push.
//!
//! # The belief (Laplace's method on the paper's observation model)
//! Eq. 8 of the paper models a push u_H [N·m] given reward weights θ (= −w) as
//! P(u_H | θ) ∝ exp(θᵀΔΦ(u_H) − λ‖u_H‖²), and eq. 10 normalises it with Laplace's method. Linearised
//! about the tracked plan, ΔΦ(u) ≈ S u with S = ∂ΔΦ/∂u_H (K × n, the feature change per unit torque
//! through the deformation), the normaliser is a Gaussian integral:
//!
//! ∫ exp(θᵀS u − λ‖u‖²) du = (π/λ)^{n/2} exp(θᵀ S Sᵀ θ / (4λ)).
//!
//! The paper keeps only its value at the current estimate (so its λ term "drops out", eq. 12, and
//! the update is eq. 13). Kept as a function of θ, each push adds the curvature S Sᵀ/(2λ) to the
//! log posterior's, whatever the push was; with the prior of eq. 11 (covariance α, the update's
//! step), the posterior over the learned weights is Gaussian with
//!
//! Σ⁻¹ = diag(1/α) + Σ_τ S_τ Sᵀ_τ / (2λ),
//!
//! here about the learner's estimate (the paper's MAP, eq. 13: its mean). The covariance shrinks
//! along the features a push *could* change at the time (where the person's choice of push was
//! informative) and stays at the prior along features no push could reach. Features that are not
//! learned, or have step 0, are known: their rows and columns are 0. Bounds on the weights are
//! not in the Gaussian.
//!
//! # Rationality β (after Bobu et al., T-RO 2020)
//! The best push the learned features could explain for the same effect is u* = P u_H, the
//! projection of u_H onto the span of the learned features' rows of S (the smallest push that
//! makes the same change of every learned feature). Under eq. 8 with a rationality β,
//! P(u | θ, β) ∝ exp(β(θᵀS u − λ‖u‖²)), the residual u_H − u* is pure noise of variance 1/(2βλ)
//! per dimension, and the explained part carries the signal. Their ratio per dimension,
//!
//! β̂ = (‖u*‖² / r) / (‖u_H − u*‖² / (n − r)), r = rank of the learned rows of S,
//!
//! is about 1 for a push the features explain no better than a push in a random direction would
//! be, and grows with how well they explain it (an F statistic: it does not depend on the push's
//! size or on λ). The learner takes u_H here as the whole sampled torque less the detector's bias:
//! the detector's thresholds zero the joints a push barely loads, which would hide its direction.
//!
//! The linearisation ignores the features' curvature along the push: where a feature curves
//! strongly over the pushes' spread 1/√(2λ), Σ is too narrow along it. A correction with β̂ below [`BETA_THRESHOLD`] is "unexplained"; the `"beta"`
//! update rule scales its step by min(1, β̂ / [`BETA_FULL`]).

use nalgebra::{DMatrix, DVector};

use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::update::UpdateParams;

/// Below this β̂ a correction is unexplained: its push is explained by the learned features no
/// better than a push in a random direction would be.
pub const BETA_THRESHOLD: f64 = 1.0;

/// At and above this β̂ the `"beta"` rule takes the paper's full step; below, the step is
/// β̂ / BETA_FULL of it (a correction at [`BETA_THRESHOLD`] moves the weights a tenth as far).
pub const BETA_FULL: f64 = 10.0;

/// β̂ of a push the features explain entirely (no residual, or as many independent learned
/// features as joints): large, but finite so that logs and means stay numbers.
pub const BETA_MAX: f64 = 1e6;

/// Default effort weight λ of eq. 8 [1/(N·m)²]: under the model a person's pushes spread by
/// 1/√(2λ) = 5 N·m about the best one.
pub const DEFAULT_EFFORT: f64 = 0.02;

/// Singular values of S below this fraction of the largest count as zero (rank of the learned rows).
const RANK_TOLERANCE: f64 = 1e-9;

/// How well the learned features explain one push.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rationality {
    /// β̂, in [0, [`BETA_MAX`]] (dimensionless).
    pub beta: f64,
    /// ‖u*‖² / ‖u_H‖², the fraction of the push's squared torque the learned features explain, in [0, 1].
    pub explained: f64,
    /// r, the rank of the learned features' rows of S.
    pub rank: usize,
}

impl Rationality {
    /// Whether β̂ is below [`BETA_THRESHOLD`].
    pub fn unexplained(&self) -> bool {
        self.beta < BETA_THRESHOLD
    }

    /// The `"beta"` rule's step scale, min(1, β̂ / [`BETA_FULL`]).
    pub fn step_scale(&self) -> f64 {
        (self.beta / BETA_FULL).min(1.0)
    }
}

/// β̂ of the push `u_h` (n,) [N·m] from the sensitivity S (K × n row-major, `sensitivity`) and which
/// features are learned (K,). A zero push or features that cannot explain any push give β̂ = 0.
pub fn rationality(sensitivity: &[f64], learned: &[bool], u_h: &[f64]) -> Result<Rationality> {
    let (k, n) = (learned.len(), u_h.len());
    check_vector("sensitivity", sensitivity, k * n)?;
    check_finite("sensitivity", sensitivity)?;
    check_finite("u_h", u_h)?;
    let rows: Vec<usize> = (0..k).filter(|&i| learned[i]).collect();
    // β̂ does not depend on the push's or the rows' scale: both are scaled to a largest entry of 1,
    // so that no square overflows.
    let largest_entry = |v: &mut dyn Iterator<Item = f64>| v.fold(0.0_f64, |m, x| m.max(x.abs()));
    let push_scale = largest_entry(&mut u_h.iter().copied());
    let row_scale = largest_entry(&mut rows.iter().flat_map(|&i| sensitivity[i * n..(i + 1) * n].iter().copied()));
    let none = Rationality { beta: 0.0, explained: 0.0, rank: 0 };
    if rows.is_empty() || push_scale == 0.0 || row_scale == 0.0 || n == 0 {
        return Ok(none);
    }
    let u_h: Vec<f64> = u_h.iter().map(|v| v / push_scale).collect();
    let push: f64 = u_h.iter().map(|v| v * v).sum();
    // The learned rows as the columns of an n × L matrix; its left singular vectors span them.
    let s = DMatrix::from_fn(n, rows.len(), |j, c| sensitivity[rows[c] * n + j] / row_scale);
    let svd = s.svd(true, false);
    let largest = svd.singular_values.max();
    let Some(u) = svd.u else { return Err(PhriError::invalid("sensitivity", "its decomposition failed")) };
    if !(largest > 0.0) {
        return Ok(none);
    }
    let push_vec = DVector::from_column_slice(&u_h);
    let mut rank = 0;
    let mut projected = 0.0;
    for (c, sigma) in svd.singular_values.iter().enumerate() {
        if *sigma > RANK_TOLERANCE * largest {
            rank += 1;
            projected += u.column(c).dot(&push_vec).powi(2);
        }
    }
    let explained = (projected / push).clamp(0.0, 1.0);
    let residual = 1.0 - explained;
    let beta = if rank >= n || residual <= 0.0 {
        BETA_MAX
    } else {
        ((explained / rank as f64) / (residual / (n - rank) as f64)).min(BETA_MAX)
    };
    Ok(Rationality { beta, explained, rank })
}

/// The Gaussian belief over the cost weights (see the module docs): its covariance, with the
/// learner's weights as its mean.
#[derive(Debug, Clone)]
pub struct Belief {
    /// Number of weights K.
    k: usize,
    /// Effort weight λ of eq. 8 [1/(N·m)²].
    effort: f64,
    /// Learned features with a prior variance (step > 0), in order.
    rows: Vec<usize>,
    /// Prior variance α_k of each of `rows`.
    prior: Vec<f64>,
    /// Σ⁻¹ over `rows` (L × L).
    precision: DMatrix<f64>,
    /// Σ over all K features (K × K row-major; 0 on known features' rows and columns).
    covariance: Vec<f64>,
}

impl Belief {
    /// The prior of eq. 11: variance α_k (the update's step) on each learned weight, none on the
    /// others; `effort` is λ [1/(N·m)²], finite and > 0.
    pub fn new(update: &UpdateParams, effort: f64) -> Result<Self> {
        if !(effort.is_finite() && effort > 0.0 && (1.0 / effort).is_finite()) {
            return Err(PhriError::invalid("effort", format!("must be finite and > 0 [1/(N·m)²], got {effort}")));
        }
        let rows: Vec<usize> = (0..update.step.len()).filter(|&i| update.learned[i] && update.step[i] > 0.0).collect();
        let prior: Vec<f64> = rows.iter().map(|&i| update.step[i]).collect();
        let k = update.step.len();
        let mut belief =
            Belief { k, effort, precision: DMatrix::zeros(rows.len(), rows.len()), covariance: vec![0.0; k * k], rows, prior };
        belief.reset();
        Ok(belief)
    }

    /// Back to the prior.
    pub fn reset(&mut self) {
        self.precision.fill(0.0);
        self.covariance.fill(0.0);
        for (c, (a, &i)) in self.prior.iter().zip(&self.rows).enumerate() {
            self.precision[(c, c)] = 1.0 / a;
            // The prior's covariance exactly (its inverse's inverse would carry rounding).
            self.covariance[i * self.k + i] = *a;
        }
    }

    /// λ [1/(N·m)²].
    pub fn effort(&self) -> f64 {
        self.effort
    }

    /// Number of weights K.
    pub fn len(&self) -> usize {
        self.k
    }

    pub fn is_empty(&self) -> bool {
        self.k == 0
    }

    /// Σ, K × K row-major [weight²].
    pub fn covariance(&self) -> &[f64] {
        &self.covariance
    }

    /// The standard deviation √Σ_kk of each weight into `out` (K,).
    pub fn std(&self, out: &mut [f64]) -> Result<()> {
        check_vector("std", out, self.len())?;
        for (i, o) in out.iter_mut().enumerate() {
            *o = self.std_of(i);
        }
        Ok(())
    }

    /// The standard deviation √Σ_ii of weight `i` (< K).
    pub fn std_of(&self, i: usize) -> f64 {
        self.covariance[i * self.k + i].max(0.0).sqrt()
    }

    /// One push's evidence: Σ⁻¹ += S Sᵀ/(2λ) over the learned rows of `sensitivity` (K × n
    /// row-major, n = `dof`). A refused sensitivity leaves the belief as it was.
    pub fn observe(&mut self, sensitivity: &[f64], dof: usize) -> Result<()> {
        let evidence = self.evidence(sensitivity, dof)?;
        self.accept(evidence);
        Ok(())
    }

    /// The belief after one push's evidence, without taking it in yet ([`Belief::accept`]): the
    /// learner checks everything a push could refuse before it changes anything.
    pub fn evidence(&self, sensitivity: &[f64], dof: usize) -> Result<Evidence> {
        let k = self.len();
        check_vector("sensitivity", sensitivity, k * dof)?;
        check_finite("sensitivity", sensitivity)?;
        let scale = 1.0 / (2.0 * self.effort);
        let mut precision = self.precision.clone();
        for (a, &i) in self.rows.iter().enumerate() {
            for (b, &j) in self.rows.iter().enumerate() {
                let si = &sensitivity[i * dof..(i + 1) * dof];
                let sj = &sensitivity[j * dof..(j + 1) * dof];
                precision[(a, b)] += scale * si.iter().zip(sj).map(|(x, y)| x * y).sum::<f64>();
            }
        }
        let overflow = || PhriError::invalid("sensitivity", "is so large that the belief's precision overflows");
        if precision.iter().any(|v| !v.is_finite()) {
            return Err(overflow());
        }
        let mut covariance = vec![0.0; k * k];
        if !self.rows.is_empty() {
            // Symmetric positive definite (the prior's diagonal plus Gram matrices) unless rounding
            // at extreme scales says otherwise: then refused, never a silent zero.
            let inverse = precision.clone().cholesky().ok_or_else(overflow)?.inverse();
            for (a, &i) in self.rows.iter().enumerate() {
                for (b, &j) in self.rows.iter().enumerate() {
                    // Symmetrised: the two triangles of a Cholesky inverse differ by rounding.
                    covariance[i * k + j] = 0.5 * (inverse[(a, b)] + inverse[(b, a)]);
                }
            }
            if covariance.iter().any(|v| !v.is_finite()) {
                return Err(overflow());
            }
        }
        Ok(Evidence { precision, covariance })
    }

    /// Takes in the evidence of [`Belief::evidence`].
    pub fn accept(&mut self, evidence: Evidence) {
        self.precision = evidence.precision;
        self.covariance = evidence.covariance;
    }
}

/// The belief after one more push, from [`Belief::evidence`].
#[derive(Debug, Clone)]
pub struct Evidence {
    precision: DMatrix<f64>,
    covariance: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::update::UpdateRule;

    fn params(step: Vec<f64>, learned: Vec<bool>) -> UpdateParams {
        let k = step.len();
        UpdateParams { step, lower: vec![0.0; k], upper: vec![1.0; k], learned, ranges: vec![1.0; k], rule: UpdateRule::All }
    }

    #[test]
    fn rationality_of_an_explained_and_an_orthogonal_push() {
        // Two joints, one learned feature that sees only joint 0.
        let s = [2.0, 0.0];
        let along = rationality(&s, &[true], &[3.0, 0.0]).unwrap();
        assert_eq!((along.rank, along.explained, along.beta), (1, 1.0, BETA_MAX));
        let across = rationality(&s, &[true], &[0.0, 3.0]).unwrap();
        assert_eq!((across.explained, across.beta), (0.0, 0.0));
        assert!(across.unexplained() && across.step_scale() == 0.0);
        // 45°: half explained, one dimension each side: β̂ = 1.
        let half = rationality(&s, &[true], &[1.0, 1.0]).unwrap();
        assert!((half.explained - 0.5).abs() < 1e-12 && (half.beta - 1.0).abs() < 1e-12);
        // A feature that is not learned explains nothing.
        assert_eq!(rationality(&s, &[false], &[3.0, 0.0]).unwrap().beta, 0.0);
    }

    #[test]
    fn rationality_is_an_f_ratio_over_the_span() {
        // Three joints, two learned features spanning joints 0 and 1 (not orthogonal rows).
        let s = [1.0, 1.0, 0.0, 1.0, -2.0, 0.0];
        let r = rationality(&s, &[true, true], &[1.0, 2.0, 2.0]).unwrap();
        assert_eq!(r.rank, 2);
        let (explained, residual) = (5.0 / 9.0, 4.0 / 9.0);
        assert!((r.explained - explained).abs() < 1e-12);
        assert!((r.beta - (explained / 2.0) / (residual / 1.0)).abs() < 1e-12);
        // Scale-free.
        let big = rationality(&s, &[true, true], &[10.0, 20.0, 20.0]).unwrap();
        assert!((big.beta - r.beta).abs() < 1e-12);
        // Scale-free down to the last squares: pushes and rows near f64's range do not overflow.
        let huge = rationality(&[1e300, 0.0, 0.0, 0.0, 1e300, 0.0], &[true, true], &[1e300, 1e300, 1e300]).unwrap();
        assert!((huge.explained - 2.0 / 3.0).abs() < 1e-12 && (huge.beta - 1.0).abs() < 1e-9, "{huge:?}");
        // Parallel rows have rank 1.
        assert_eq!(rationality(&[1.0, 0.0, 0.0, 2.0, 0.0, 0.0], &[true, true], &[1.0, 1.0, 1.0]).unwrap().rank, 1);
    }

    #[test]
    fn rationality_refuses_bad_input() {
        assert!(rationality(&[1.0], &[true], &[1.0, 2.0]).is_err());
        assert!(rationality(&[f64::NAN, 0.0], &[true], &[1.0, 2.0]).is_err());
        assert!(rationality(&[1.0, 0.0], &[true], &[f64::INFINITY, 2.0]).is_err());
    }

    #[test]
    fn covariance_is_the_closed_form_posterior() {
        let p = params(vec![1.0, 2.0, 0.5], vec![false, true, true]);
        let mut belief = Belief::new(&p, 0.25).unwrap();
        let k = 3;
        assert_eq!(belief.covariance(), &[0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.5]);
        // Σ⁻¹ = diag(1/2, 2) + s sᵀ / (2 · 0.25) on features 1 and 2.
        let s = [5.0, 5.0, 1.0, 1.0, 0.0, 3.0]; // K × n with n = 2
        belief.observe(&s, 2).unwrap();
        let (a, b, d) = (0.5 + 2.0 * 2.0, 2.0 * 3.0, 2.0 + 2.0 * 9.0); // [[a, b], [b, d]]
        let det = a * d - b * b;
        let want = [d / det, -b / det, -b / det, a / det];
        let got = [belief.covariance()[4], belief.covariance()[5], belief.covariance()[7], belief.covariance()[8]];
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-12, "{got:?} against {want:?}");
        }
        assert!(belief.covariance()[..k].iter().all(|v| *v == 0.0), "a known weight has no variance");
        let mut std = [0.0; 3];
        belief.std(&mut std).unwrap();
        assert!((std[1] - (d / det).sqrt()).abs() < 1e-12 && std[0] == 0.0);
        belief.reset();
        assert_eq!(belief.covariance()[4], 2.0);
    }

    #[test]
    fn covariance_shrinks_only_where_pushes_reach() {
        let p = params(vec![1.0, 1.0], vec![true, true]);
        let mut belief = Belief::new(&p, DEFAULT_EFFORT).unwrap();
        // Pushes that change feature 0 only.
        for _ in 0..5 {
            belief.observe(&[0.3, 0.1, 0.0, 0.0], 2).unwrap();
        }
        let c = belief.covariance();
        assert!(c[0] < 0.1, "the corrected feature's variance shrinks: {}", c[0]);
        assert_eq!(c[3], 1.0, "the untouched feature keeps its prior");
    }

    #[test]
    fn belief_refuses_bad_input_and_keeps_its_state() {
        let p = params(vec![1.0], vec![true]);
        assert!(Belief::new(&p, 0.0).is_err() && Belief::new(&p, f64::NAN).is_err() && Belief::new(&p, 1e-320).is_err());
        let mut belief = Belief::new(&p, 1.0).unwrap();
        assert!(belief.observe(&[1.0, 2.0, 3.0], 2).is_err());
        assert!(belief.observe(&[f64::NAN, 0.0], 2).is_err());
        assert!(belief.observe(&[1e200, 0.0], 2).is_err());
        assert_eq!(belief.covariance(), &[1.0]);
    }
}
