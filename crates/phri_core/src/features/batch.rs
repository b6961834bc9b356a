//! Features given as a function of the configuration and evaluated for many configurations at
//! once: φ(q) at points along every segment, computed for the whole trajectory in one call per
//! evaluation (a Python feature crosses into Python once per evaluation, not once per waypoint).
//!
//! Φ(ξ) = Σ_{i=1}^{N-1} Σ_{k=1}^{K} φ(q_{i-1} + s_k·(q_i − q_{i-1})), s_k = k/K: with K = 1 (the
//! default) the sum over the waypoints q_1 … q_{N-1}, as the table and cup features; with K > 1 the
//! keep-outs' sampling along each segment. Derivatives the function does not give are taken by
//! finite differences, still in one batched call each: the gradient by central differences of the
//! values, the Hessian by forward differences of the gradient (or second differences of the
//! values). The Hessian is computed only when the optimiser asks for the exact one (see
//! [`SegmentHessian::kinematic`](super::SegmentHessian::kinematic)); its convex model before that
//! leaves the feature's curvature out, as it does for the built-in table and cup features (a
//! Gauss–Newton model with no residual to build it from), and the damping and the other
//! features' curvature carry the steps.

use std::sync::Arc;

use super::{Feature, Need, Segment, SegmentGrad};
use crate::error::{PhriError, Result};

/// A feature φ(q) evaluated for a batch of m configurations (m × n row-major, [rad]); implement it
/// to plan and learn with a feature computed outside the core (see [`BatchFeature`]).
pub trait BatchFunction: Send + Sync {
    /// The feature's name (unique within a set).
    fn name(&self) -> &str;
    /// Whether [`BatchFunction::gradients`] gives ∂φ/∂q (else finite differences of the values).
    fn has_gradient(&self) -> bool;
    /// Whether [`BatchFunction::hessians`] gives ∂²φ/∂q² (else finite differences).
    fn has_hessian(&self) -> bool;
    /// φ at each configuration of `q` (m × n) into `values` (m).
    fn values(&self, q: &[f64], n: usize, values: &mut [f64]) -> Result<()>;
    /// ∂φ/∂q at each configuration into `gradients` (m × n); called only if `has_gradient`.
    fn gradients(&self, q: &[f64], n: usize, gradients: &mut [f64]) -> Result<()>;
    /// ∂²φ/∂q² at each configuration into `hessians` (m × n × n); called only if `has_hessian`.
    fn hessians(&self, q: &[f64], n: usize, hessians: &mut [f64]) -> Result<()>;
}

/// Central-difference step for gradients from values [rad] (≈ ε^(1/3)).
const GRADIENT_STEP: f64 = 6e-6;
/// Forward-difference step for Hessians from gradients [rad] (≈ ε^(1/2), a little larger).
const HESSIAN_STEP: f64 = 1e-6;
/// Step for Hessians from values by second differences [rad] (≈ ε^(1/4)).
const SECOND_DIFFERENCE_STEP: f64 = 1e-4;

/// A [`Feature`] made of a [`BatchFunction`]: [`Feature::prepare`] evaluates the function at every
/// point of the trajectory at once and `segment` serves the results.
#[derive(Clone)]
pub struct BatchFeature {
    function: Arc<dyn BatchFunction>,
    samples: usize,
    /// Points of the last prepared evaluation (m × n) and the segments they cover.
    points: Vec<f64>,
    segments: usize,
    /// Whether the cache holds the results of the last evaluation (false after a failure).
    valid: bool,
    values: Vec<f64>,
    gradients: Vec<f64>,
    hessians: Vec<f64>,
    has_gradients: bool,
    has_hessians: bool,
    scratch: Vec<f64>,
    scratch_out: Vec<f64>,
}

impl BatchFeature {
    /// The feature of `function`, evaluated at `samples` points per segment (1: at the waypoints).
    pub fn new(function: Arc<dyn BatchFunction>, samples: usize) -> Result<Self> {
        if samples == 0 || samples > super::MAX_SAMPLES {
            return Err(PhriError::invalid(
                "samples",
                format!("must be in 1..={} points per segment, got {samples}", super::MAX_SAMPLES),
            ));
        }
        Ok(BatchFeature {
            function,
            samples,
            points: Vec::new(),
            segments: 0,
            valid: false,
            values: Vec::new(),
            gradients: Vec::new(),
            hessians: Vec::new(),
            has_gradients: false,
            has_hessians: false,
            scratch: Vec::new(),
            scratch_out: Vec::new(),
        })
    }

    /// Points per segment.
    pub fn samples(&self) -> usize {
        self.samples
    }

    fn fail(&self, reason: impl Into<String>) -> PhriError {
        PhriError::Feature { feature: self.function.name().into(), reason: reason.into() }
    }

    /// Checks that `what` (of a batch of `rows` configurations) is finite.
    fn check_finite(&self, what: &str, values: &[f64], per_row: usize) -> Result<()> {
        match values.iter().position(|v| !v.is_finite()) {
            None => Ok(()),
            Some(i) => Err(self.fail(format!(
                "{what} is not finite at configuration {} (entry {}): {}",
                i / per_row,
                i % per_row,
                values[i]
            ))),
        }
    }

    /// Gradients at the points: the function's, or central differences of its values.
    fn gradients_at(&mut self, n: usize) -> Result<()> {
        let m = self.values.len();
        self.gradients.resize(m * n, 0.0);
        if self.function.has_gradient() {
            self.function.gradients(&self.points, n, &mut self.gradients)?;
            return self.check_finite("the gradient", &self.gradients, n);
        }
        // Rows (r, j, ±): point r with joint j moved by ±h.
        self.scratch.clear();
        for r in 0..m {
            let q = &self.points[r * n..(r + 1) * n];
            for j in 0..n {
                for sign in [1.0, -1.0] {
                    self.scratch.extend_from_slice(q);
                    let last = self.scratch.len() - n;
                    self.scratch[last + j] += sign * GRADIENT_STEP;
                }
            }
        }
        self.scratch_out.resize(2 * m * n, 0.0);
        self.function.values(&self.scratch, n, &mut self.scratch_out)?;
        self.check_finite("the value (finite differences)", &self.scratch_out, 2 * n)?;
        for (g, pair) in self.gradients.iter_mut().zip(self.scratch_out.chunks_exact(2)) {
            *g = (pair[0] - pair[1]) / (2.0 * GRADIENT_STEP);
        }
        Ok(())
    }

    /// Hessians at the points: the function's, or finite differences (module docs).
    fn hessians_at(&mut self, n: usize) -> Result<()> {
        let m = self.values.len();
        self.hessians.resize(m * n * n, 0.0);
        if self.function.has_hessian() {
            self.function.hessians(&self.points, n, &mut self.hessians)?;
            self.check_finite("the Hessian", &self.hessians, n * n)?;
        } else if self.function.has_gradient() {
            self.scratch.clear();
            for r in 0..m {
                for j in 0..n {
                    self.scratch.extend_from_slice(&self.points[r * n..(r + 1) * n]);
                    let last = self.scratch.len() - n;
                    self.scratch[last + j] += HESSIAN_STEP;
                }
            }
            self.scratch_out.resize(m * n * n, 0.0);
            self.function.gradients(&self.scratch, n, &mut self.scratch_out)?;
            self.check_finite("the gradient (finite differences)", &self.scratch_out, n)?;
            for r in 0..m {
                let g0 = &self.gradients[r * n..(r + 1) * n];
                for j in 0..n {
                    let g1 = &self.scratch_out[(r * n + j) * n..(r * n + j + 1) * n];
                    for c in 0..n {
                        self.hessians[(r * n + j) * n + c] = (g1[c] - g0[c]) / HESSIAN_STEP;
                    }
                }
            }
        } else {
            self.second_differences(n)?;
        }
        // Symmetrised: finite differences leave the two triangles a rounding apart.
        for r in 0..m {
            let block = &mut self.hessians[r * n * n..(r + 1) * n * n];
            for a in 0..n {
                for b in a + 1..n {
                    let v = 0.5 * (block[a * n + b] + block[b * n + a]);
                    block[a * n + b] = v;
                    block[b * n + a] = v;
                }
            }
        }
        Ok(())
    }

    /// Hessians from values alone: H_jk = (φ(q + h·e_j + h·e_k) − φ(q + h·e_j) − φ(q + h·e_k) + φ(q))/h².
    fn second_differences(&mut self, n: usize) -> Result<()> {
        let m = self.values.len();
        let h = SECOND_DIFFERENCE_STEP;
        // Per point: n rows q + h·e_j, then the n(n+1)/2 rows q + h·e_j + h·e_k (j ≤ k).
        let per = n + n * (n + 1) / 2;
        self.scratch.clear();
        for r in 0..m {
            let q = &self.points[r * n..(r + 1) * n];
            for j in 0..n {
                self.scratch.extend_from_slice(q);
                let last = self.scratch.len() - n;
                self.scratch[last + j] += h;
            }
            for j in 0..n {
                for k in j..n {
                    self.scratch.extend_from_slice(q);
                    let last = self.scratch.len() - n;
                    self.scratch[last + j] += h;
                    self.scratch[last + k] += h;
                }
            }
        }
        self.scratch_out.resize(m * per, 0.0);
        self.function.values(&self.scratch, n, &mut self.scratch_out)?;
        self.check_finite("the value (finite differences)", &self.scratch_out, per)?;
        for r in 0..m {
            let f = &self.scratch_out[r * per..(r + 1) * per];
            let f0 = self.values[r];
            let mut pair = n;
            for j in 0..n {
                for k in j..n {
                    let v = (f[pair] - f[j] - f[k] + f0) / (h * h);
                    self.hessians[(r * n + j) * n + k] = v;
                    self.hessians[(r * n + k) * n + j] = v;
                    pair += 1;
                }
            }
        }
        Ok(())
    }

    fn evaluate(&mut self, trajectory: &[f64], n: usize, need: Need) -> Result<()> {
        let waypoints = trajectory.len() / n;
        let segments = waypoints.saturating_sub(1);
        let m = segments * self.samples;
        self.points.clear();
        for i in 1..waypoints {
            let (a, b) = (&trajectory[(i - 1) * n..i * n], &trajectory[i * n..(i + 1) * n]);
            for k in 1..=self.samples {
                if k == self.samples {
                    self.points.extend_from_slice(b);
                } else {
                    let s = k as f64 / self.samples as f64;
                    self.points.extend(a.iter().zip(b).map(|(x, y)| x + s * (y - x)));
                }
            }
        }
        self.values.resize(m, 0.0);
        self.function.values(&self.points, n, &mut self.values)?;
        self.check_finite("the value", &self.values, 1)?;
        self.has_gradients = false;
        self.has_hessians = false;
        if need != Need::Value {
            self.gradients_at(n)?;
            self.has_gradients = true;
        }
        if let Need::Hessian { exact } = need {
            // The convex model leaves the feature's curvature out, as it leaves out the built-in
            // table and cup features' (their Gauss–Newton part is zero): measured on the table
            // task, the PSD-projected Hessian made a learner's replan take 466 Newton iterations
            // against the built-in's 68, and settle at a 0.6 % higher cost.
            if exact {
                self.hessians_at(n)?;
                self.has_hessians = true;
            }
        }
        self.segments = segments;
        Ok(())
    }
}

impl Feature for BatchFeature {
    fn name(&self) -> &str {
        self.function.name()
    }

    fn prepare(&mut self, trajectory: &[f64], n: usize, need: Need) -> Result<()> {
        self.valid = false;
        self.evaluate(trajectory, n, need)?;
        self.valid = true;
        Ok(())
    }

    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let i = seg.end_index();
        if !self.valid || i > self.segments {
            return 0.0; // the evaluation failed (and reports it) or was not prepared
        }
        let n = seg.q.len();
        let k_len = self.samples;
        let mut value = 0.0;
        let mut grad = grad;
        for k in 0..k_len {
            let r = (i - 1) * k_len + k;
            value += self.values[r];
            let Some(g) = grad.as_mut() else { continue };
            if !self.has_gradients {
                continue;
            }
            let s = (k + 1) as f64 / k_len as f64;
            let d = &self.gradients[r * n..(r + 1) * n];
            for j in 0..n {
                g.this[j] += g.scale * s * d[j];
                if s < 1.0 {
                    g.prev[j] += g.scale * (1.0 - s) * d[j];
                }
            }
            if let (Some(h), true) = (g.hessian.as_deref_mut(), self.has_hessians) {
                h.scratch().copy_from_slice(&self.hessians[r * n * n..(r + 1) * n * n]);
                h.add_scratch_at(s, g.scale);
            }
        }
        value
    }
}
