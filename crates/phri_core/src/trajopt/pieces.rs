//! The kinked part of the Newton model: every term that a step can switch on — each clearance
//! penalty, both sides of each max_step penalty, the keep-out samples just outside their circle —
//! is a piece ½c·max(0, f0 + a·d)², linearised at the current plan (max_step exactly). Along a
//! line of steps the model is then convex and piecewise quadratic, and is minimised exactly
//! ([`PieceModel::line_minimum`]), so a step never runs blindly into a penalty or back into a
//! keep-out circle it could not see.

use super::block_tridiagonal::BlockTridiagonal;
use crate::features::Pieces;

/// The pieces of one Newton step: the model's [`Pieces`], then both sides of every max_step pair
/// (segment, joint, side), each with its curvature, lowest waypoint, value at the current step and
/// slope along the next one, and whether it is on.
#[derive(Debug, Clone, Default)]
pub(super) struct PieceModel {
    /// Curvature c of each piece.
    c: Vec<f64>,
    /// Lowest waypoint whose system blocks the piece touches.
    lowest: Vec<usize>,
    /// Value f at the current step d.
    f: Vec<f64>,
    /// Slope a·v along the next step v.
    g: Vec<f64>,
    /// Pieces on somewhere along the current line (scratch of `line_minimum`).
    relevant: Vec<usize>,
    /// Whether each piece is on at d.
    active: Vec<bool>,
}

/// The max_step penalties of a problem and the plan they are linearised at.
pub(super) struct Steps<'a> {
    /// Largest move per joint [rad] (empty for none).
    pub(super) max_step: &'a [f64],
    /// Penalty weight ρ [cost per rad²].
    pub(super) weight: f64,
    /// The current plan (N × n).
    pub(super) traj: &'a [f64],
}

impl PieceModel {
    /// Sets up the pieces at d = 0: `pieces`, then both sides of every max_step pair
    /// (½·2ρ·max(0, ±diff − limit)², exact since linear), marking those on.
    pub(super) fn prepare(&mut self, pieces: &Pieces, steps: &Steps<'_>) {
        let n = pieces.dof();
        let m = steps.traj.len() / n;
        let step_count = if steps.max_step.is_empty() { 0 } else { 2 * m * n };
        let count = pieces.len() + step_count;
        for v in [&mut self.c, &mut self.f, &mut self.g] {
            v.clear();
            v.resize(count, 0.0);
        }
        self.lowest.clear();
        self.lowest.resize(count, 0);
        self.active.clear();
        self.active.resize(count, false);
        for (k, p) in pieces.list.iter().enumerate() {
            self.c[k] = p.c;
            self.f[k] = p.f0;
            self.lowest[k] = if p.s < 1.0 { p.segment - 1 } else { p.segment };
        }
        if step_count > 0 {
            let base = pieces.len();
            for i in 1..m {
                for (j, limit) in steps.max_step.iter().enumerate() {
                    let diff = steps.traj[i * n + j] - steps.traj[(i - 1) * n + j];
                    for (side, sign) in [(0, 1.0), (1, -1.0)] {
                        let k = base + (i * n + j) * 2 + side;
                        self.c[k] = 2.0 * steps.weight;
                        self.f[k] = sign * diff - super::cost::segment_step(*limit, i, m);
                        self.lowest[k] = i - 1;
                    }
                }
            }
        }
        for k in 0..count {
            self.active[k] = self.f[k] > 0.0;
        }
    }

    /// The slopes a_k·v of every piece along a model step v (N × n).
    pub(super) fn slopes(&mut self, pieces: &Pieces, has_steps: bool, v: &[f64]) {
        let n = pieces.dof();
        for (k, p) in pieces.list.iter().enumerate() {
            self.g[k] = piece_dot(&pieces.a[k * n..(k + 1) * n], v, p.segment, p.s, n);
        }
        if has_steps {
            let base = pieces.len();
            for i in 1..v.len() / n {
                for j in 0..n {
                    let dv = v[i * n + j] - v[(i - 1) * n + j];
                    let k = base + (i * n + j) * 2;
                    self.g[k] = dv;
                    self.g[k + 1] = -dv;
                }
            }
        }
    }

    /// Minimises the model along d + t·v, t ∈ [0, 1]: φ(t) = A·t + ½B·t² + Σ_k ½c_k·max(0, f_k +
    /// t·g_k)², convex and piecewise quadratic (safeguarded Newton on φ', exact on each piece).
    /// Returns (t, φ(0) − φ(t)); t = 0 when v is not a descent direction.
    pub(super) fn line_minimum(&mut self, a: f64, b: f64) -> (f64, f64) {
        // Only pieces that are on somewhere in [0, 1] matter.
        self.relevant.clear();
        for k in 0..self.f.len() {
            let (f, g) = (self.f[k], self.g[k]);
            if f > 0.0 || f + g > 0.0 {
                self.relevant.push(k);
            }
        }
        let derivative = |t: f64| {
            let (mut d1, mut d2) = (a + b * t, b);
            for &k in &self.relevant {
                let (f, g, c) = (self.f[k], self.g[k], self.c[k]);
                let x = f + t * g;
                if x > 0.0 {
                    d1 += c * x * g;
                    d2 += c * g * g;
                }
            }
            (d1, d2)
        };
        let (slope, _) = derivative(0.0);
        if !(slope < 0.0) {
            return (0.0, 0.0);
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        let (mut t, (mut d1, mut d2)) = (1.0, derivative(1.0));
        if d1 > 0.0 {
            for _ in 0..40 {
                let newton = t - d1 / d2;
                let next = if newton > lo && newton < hi && d2 > 0.0 { newton } else { 0.5 * (lo + hi) };
                let (n1, n2) = derivative(next);
                if n1 > 0.0 {
                    hi = next;
                } else {
                    lo = next;
                }
                let done = (next - t).abs() <= 1e-14 * t.max(1e-300) || n1 == 0.0;
                (t, d1, d2) = (next, n1, n2);
                if done || hi - lo <= 1e-15 {
                    break;
                }
            }
        }
        let mut drop = -(a * t + 0.5 * b * t * t);
        for &k in &self.relevant {
            let (f, g, c) = (self.f[k], self.g[k], self.c[k]);
            let (x0, x1) = (f.max(0.0), (f + t * g).max(0.0));
            drop -= 0.5 * c * (x1 * x1 - x0 * x0);
        }
        (t, drop)
    }

    /// After a step t along the line: updates the values, marks the pieces on, and returns the
    /// lowest waypoint whose system blocks changed, if any did.
    pub(super) fn advance(&mut self, t: f64) -> Option<usize> {
        let mut lowest: Option<usize> = None;
        for k in 0..self.f.len() {
            self.f[k] += t * self.g[k];
            let on = self.f[k] > 0.0;
            if on != self.active[k] {
                self.active[k] = on;
                let w = self.lowest[k];
                lowest = Some(lowest.map_or(w, |l| l.min(w)));
            }
        }
        lowest
    }

    /// Adds the Gauss–Newton terms of the pieces that are on to the Newton system: their
    /// curvature to `system`, minus their linearised gradient to `rhs` (N × n; the fixed start and
    /// goal rows are left out).
    pub(super) fn add_active(&self, pieces: &Pieces, steps: &Steps<'_>, system: &mut BlockTridiagonal, rhs: &mut [f64]) {
        let n = pieces.dof();
        let (m, nn) = (rhs.len() / n, n * n);
        for (k, p) in pieces.list.iter().enumerate() {
            if !self.active[k] {
                continue;
            }
            // ½c·(f0 + a·Δq(s))², Δq(s) = (1−s)·Δ_{i−1} + s·Δ_i: gradient c·f0·a, Hessian c·a·aᵀ.
            let a = &pieces.a[k * n..(k + 1) * n];
            let (i, s, c, f0) = (p.segment, p.s, p.c, p.f0);
            let weights = [(i - 1, 1.0 - s), (i, s)];
            for (w, ws) in weights {
                if ws == 0.0 || w == 0 || w == m - 1 {
                    continue;
                }
                axpy(-c * f0 * ws, a, &mut rhs[w * n..(w + 1) * n]);
                add_outer(&mut system.diag[w * nn..(w + 1) * nn], a, c * ws * ws);
            }
            if s > 0.0 && s < 1.0 && i >= 2 && i < m - 1 {
                add_outer(&mut system.off[(i - 1) * nn..i * nn], a, c * s * (1.0 - s));
            }
        }
        if !steps.max_step.is_empty() {
            let (base, rho) = (pieces.len(), steps.weight);
            for i in 1..m {
                for (j, limit) in steps.max_step.iter().enumerate() {
                    let diff = steps.traj[i * n + j] - steps.traj[(i - 1) * n + j];
                    for (side, sign) in [(0, 1.0), (1, -1.0)] {
                        if !self.active[base + (i * n + j) * 2 + side] {
                            continue;
                        }
                        // ρ·(sign·(diff + Δ_i − Δ_{i−1}) − limit)².
                        let c0 = sign * diff - super::cost::segment_step(*limit, i, m);
                        rhs[i * n + j] -= 2.0 * rho * c0 * sign;
                        rhs[(i - 1) * n + j] += 2.0 * rho * c0 * sign;
                        system.diag[(i * n + j) * n + j] += 2.0 * rho;
                        system.diag[((i - 1) * n + j) * n + j] += 2.0 * rho;
                        system.off[((i - 1) * n + j) * n + j] -= 2.0 * rho;
                    }
                }
            }
        }
    }
}

/// a·Δq(s) for a piece at (segment − 1, segment), Δq(s) = (1 − s)·d_{i−1} + s·d_i.
#[inline]
fn piece_dot(a: &[f64], d: &[f64], segment: usize, s: f64, n: usize) -> f64 {
    let (d0, d1) = (&d[(segment - 1) * n..segment * n], &d[segment * n..(segment + 1) * n]);
    let mut f = 0.0;
    for j in 0..n {
        f += a[j] * ((1.0 - s) * d0[j] + s * d1[j]);
    }
    f
}

/// block += scale·a·aᵀ (block n × n row-major, n = a.len()).
#[inline]
fn add_outer(block: &mut [f64], a: &[f64], scale: f64) {
    for (row, ar) in block.chunks_exact_mut(a.len()).zip(a) {
        let sr = scale * ar;
        row.iter_mut().zip(a).for_each(|(b, ac)| *b += sr * ac);
    }
}

#[inline]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}
