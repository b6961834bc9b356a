//! The intended trajectory of a push (paper eq. 7): ξ_H = ξ_R + μ·A⁻¹·U_H.
//!
//! A correction at waypoint `index` moves the window of the next m waypoints, index+1 ..= index+m
//! (m = n, the configured window, unless the end rule shrinks it), joint j of the k-th moved waypoint
//! by
//!
//! Δξ[index+1+k, j] = μ·H[k]·u_H[j],   H = R⁻¹e₁ scaled to ‖H‖ = √m,   R = AᵀA,
//!
//! where A is the zero-padded finite-difference matrix of the norm: (m+2)×m with columns [1, −2, 1]
//! for [`Norm::Acceleration`] (the paper and the original code; R is pentadiagonal 6, −4, 1) or
//! (m+3)×m with columns [−1, 3, −3, 1] for [`Norm::Jerk`] (R heptadiagonal 20, −15, 6, −1). For
//! n = 5 the acceleration shape is H ≈ [1.0031, 1.3375, 1.2038, 0.8025, 0.3344], the original's.
//!
//! **Sign.** `u_h` is the torque the person applies to the arm [N·m], so μ > 0 moves the trajectory
//! the way they push. The original code used μ = −0.01 with its arm's measured-torque sign.
//!
//! **Ends of the window.** Waypoints outside the window are not touched (bit for bit): the current
//! waypoint and everything before it, and the waypoint after the window and everything after it,
//! keep their positions, so finite-difference velocities outside the window are unchanged. That is
//! the zero padding of A: its rows are the second (third) differences of the window padded with two
//! (three) unmoved waypoints on each side. Inside, the shape is a clamped beam's response to the
//! push at the first moved waypoint: H[k] ∝ (k+1)(m−k)(m+1−k) for acceleration, the discrete form
//! of s(1−s)² (s = k/m), and H[k] ∝ (k+1)(k+2)(m−k)(m+1−k)(m+2−k) for jerk, of s²(1−s)³. The
//! continuum shapes start and end with zero displacement, the jerk one also with zero slope; a
//! discrete window steps into and out of them. Relative to the peak, the first moved waypoint steps
//! by H[0]/max H = 0.75 (acceleration) and 0.58 (jerk) for n = 5, 0.13 and 0.019 for n = 50,
//! shrinking like 1/m and 1/m²; the last by 0.25 (both) for n = 5, 0.005 and 0.001 for n = 50,
//! like 1/m² and 1/m³ (tests check these orders). So the original's 5-waypoint window is a visible
//! kink at the push, and continuity at both ends is a property of long windows (at 1 kHz, a window
//! of a second or more), best with [`Norm::Jerk`].
//!
//! **Normalisation.** ‖H‖ = √m for whatever window m is moved, so the root-mean-square displacement
//! of the moved waypoints is μ·|u_H[j]| per joint whatever the window length (the peak is 1.34× that
//! for n = 5, about 1.52× for long acceleration windows and 1.66× for long jerk windows). Feature
//! differences summed over waypoints therefore grow with m; retune the learning rate when changing
//! the window.
//!
//! **End of the trajectory.** The last waypoint (the goal) never moves, so a full window at `index`
//! needs index + n ≤ N − 2. Closer to the end [`EndRule::Skip`] (the original) moves nothing and
//! reports 0 waypoints moved; [`EndRule::Shrink`] moves the m = N − 2 − index waypoints left before
//! the goal, with the shape of the m-window (m = 0 at the last two waypoints: nothing moves). The
//! original code skipped only when the window ran past the goal, so it did move the goal when the
//! window ended on it; phri is one waypoint stricter.
//!
//! **Numerics.** R is factored once, R = L·D·Lᵀ with unit lower-banded L, by a hand-written banded
//! LDLᵀ (the factorisation is about 40 lines). faer, the maintained alternative, factors R in f64
//! only: measured on a 10,000-waypoint window its H is off by 1.1·10⁻⁴ relative (phri 2.3·10⁻¹⁵)
//! and its per-correction solve takes 110 µs against phri's 15.5 µs for the whole correction
//! (`cargo bench -p phri_benches --bench linalg`). R is Toeplitz, so the
//! m×m system of a shrunk window is R's leading block and its factor is the leading block of L and
//! D: one factor serves every m ≤ n, and a shrunk window costs an O(m) back substitution, done
//! twice (once for ‖x‖, once to apply) so that `deform_in_place` needs neither `&mut self` nor
//! scratch. No dense matrix is formed.
//!
//! R is very ill-conditioned (κ ~ m⁴, jerk m⁶) and the pivots converge to 1 only like 1/i², so an
//! f64 factorisation loses everything: measured against the closed forms above, H from an f64 LDLᵀ
//! was off by 2·10⁻⁴ (acceleration) and 8 (jerk, i.e. garbage) relative at m = 10⁴. The factor is
//! therefore computed in double-double arithmetic and rounded; the full-window H is solved in
//! double-double too (relative error 2·10⁻¹⁵ for acceleration, 5·10⁻¹³ for jerk at m = 10⁴),
//! shrunk windows in f64 from the rounded factor (4·10⁻¹² and 6·10⁻⁹ at m ≈ 10⁴). Windows are
//! capped at [`MAX_WINDOW`] = 10⁵, where the jerk shape is still good to ~10⁻⁶ (acceleration 10⁻¹⁴).

use crate::error::{check_vector, PhriError, Result};

/// The largest window accepted: 100 s at 1 kHz. Beyond it the jerk factor loses accuracy even in
/// double-double arithmetic (relative error ~0.5 at 10⁶).
pub const MAX_WINDOW: usize = 100_000;

/// The norm A on trajectory deformations, which dictates the deformation's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Norm {
    /// Sum of squared second differences (the paper): the shape is a cubic in the waypoint index.
    Acceleration,
    /// Sum of squared third differences (minimum jerk): a quintic, also acceleration-continuous.
    Jerk,
}

impl Norm {
    /// The finite-difference stencil: each column of A.
    pub fn stencil(self) -> &'static [f64] {
        match self {
            Norm::Acceleration => &[1.0, -2.0, 1.0],
            Norm::Jerk => &[-1.0, 3.0, -3.0, 1.0],
        }
    }

    /// Half-bandwidth p of R = AᵀA (2: pentadiagonal, 3: heptadiagonal).
    pub fn bandwidth(self) -> usize {
        self.stencil().len() - 1
    }

    /// The band of the Toeplitz R: `band[k]` = R[i, i+k] = Σ_l s_l·s_{l+k}, k = 0..=p.
    pub fn band(self) -> Vec<f64> {
        let s = self.stencil();
        (0..s.len()).map(|k| s.iter().zip(&s[k..]).map(|(a, b)| a * b).sum()).collect()
    }
}

/// What happens when fewer than a full window of waypoints is left before the goal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EndRule {
    /// Move nothing and report 0 waypoints moved (the original).
    Skip,
    /// Move the waypoints left before the goal, with the shape of the shorter window.
    Shrink,
}

/// Parameters of the deformation, with the original's defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeformParams {
    /// Waypoints n moved by a correction, after the current one (default 5: 2.5 s of the study's
    /// plan). At most [`MAX_WINDOW`].
    pub window: usize,
    /// Deformation gain μ [rad per N·m] (default +0.01; > 0 moves the trajectory the way the person
    /// pushes, with `u_h` the torque they apply).
    pub mu: f64,
    /// The norm A (default [`Norm::Acceleration`], the paper's).
    pub norm: Norm,
    /// What to do near the goal (default [`EndRule::Skip`], the original's).
    pub end_rule: EndRule,
}

impl Default for DeformParams {
    fn default() -> Self {
        DeformParams { window: 5, mu: 0.01, norm: Norm::Acceleration, end_rule: EndRule::Skip }
    }
}

/// A validated deformation with R factored and the full-window shape H precomputed. Immutable:
/// `deform_in_place` takes `&self` and allocates nothing.
#[derive(Debug, Clone)]
pub struct Deformation {
    params: DeformParams,
    /// The p sub-diagonals of L, one after the other: `factor[(k − 1)·n + i]` = L[i+k, i] for
    /// k = 1..=p (0 past the window). Separate bands, not rows, so that the back substitution stays
    /// scalar: with rows the compiler pairs the multiplies into one vector op, which lengthens the
    /// latency-bound recurrence 2.5× (measured).
    factor: Vec<f64>,
    /// D⁻¹·L⁻¹·e₁, what is left for Lᵀ after the forward solve; its first m entries serve the
    /// m-window (forward substitution on a leading block gives the leading entries).
    rhs: Vec<f64>,
    /// H of the full window, ‖H‖ = √n.
    shape: Vec<f64>,
}

impl Deformation {
    /// Validates `params`, factors R and computes the full-window shape: O(n) time and memory.
    pub fn new(params: DeformParams) -> Result<Self> {
        let n = params.window;
        if n == 0 {
            return Err(PhriError::invalid("window", "must be ≥ 1, got 0"));
        }
        if n > MAX_WINDOW {
            return Err(PhriError::invalid("window", format!("must be ≤ {MAX_WINDOW}, got {n}")));
        }
        if !params.mu.is_finite() || params.mu == 0.0 {
            return Err(PhriError::invalid("mu", format!("must be finite and non-zero [rad/(N·m)], got {}", params.mu)));
        }
        let (factor, rhs, shape) = factor_and_shape(&params.norm.band(), n);
        Ok(Deformation { params, factor, rhs, shape })
    }

    pub fn params(&self) -> &DeformParams {
        &self.params
    }

    /// The full-window shape H (n entries, ‖H‖ = √n; unitless).
    pub fn shape(&self) -> &[f64] {
        &self.shape
    }

    /// How many waypoints a correction at waypoint `index` of an `n_waypoints` trajectory moves:
    /// n, or under the end rule fewer (Shrink) or 0 (Skip; and at the last two waypoints).
    /// An `index` outside the trajectory is an error.
    pub fn window_at(&self, index: usize, n_waypoints: usize) -> Result<usize> {
        if index >= n_waypoints {
            return Err(PhriError::invalid("index", format!("must be < {n_waypoints}, the number of waypoints, got {index}")));
        }
        // Waypoints strictly between the current one and the goal.
        let room = (n_waypoints - 1 - index).saturating_sub(1);
        let n = self.params.window;
        Ok(match self.params.end_rule {
            EndRule::Skip if room >= n => n,
            EndRule::Skip => 0,
            EndRule::Shrink => room.min(n),
        })
    }

    /// Deforms `trajectory` (N×dof row-major, one waypoint per row [rad]) in place by the push
    /// `u_h` (dof,) [N·m] at waypoint `index`, and returns how many waypoints moved (see
    /// [`window_at`](Self::window_at)). Waypoint `index` itself and the goal never move. O(n·dof)
    /// for a full window, O(m·(p + dof)) for a shrunk one; no allocation.
    pub fn deform_in_place(&self, trajectory: &mut [f64], dof: usize, index: usize, u_h: &[f64]) -> Result<usize> {
        if dof == 0 {
            return Err(PhriError::invalid("dof", "must be ≥ 1, got 0"));
        }
        if trajectory.len() % dof != 0 {
            return Err(PhriError::shape(
                "trajectory",
                format!("(N, {dof}) (a multiple of {dof} values)"),
                format!("{} values", trajectory.len()),
            ));
        }
        check_vector("u_h", u_h, dof)?;
        // The shape's peak is below 2 for every window (1.34 at n = 5, ≤ 1.66 for long ones).
        let largest = u_h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if !(2.0 * self.params.mu.abs() * largest).is_finite() {
            return Err(PhriError::invalid("u_h", format!("is so large that μ·u_h overflows (|u_h| up to {largest:e})")));
        }
        let m = self.window_at(index, trajectory.len() / dof)?;
        if m == 0 {
            return Ok(0);
        }
        let rows = &mut trajectory[(index + 1) * dof..(index + 1 + m) * dof];
        // The moved waypoints stay finite: each moves by less than 2·|μ|·|u_H|.
        let reach = 2.0 * self.params.mu.abs() * largest;
        if let Some(v) = rows.iter().find(|v| !(v.abs() + reach).is_finite()) {
            return Err(PhriError::invalid(
                "trajectory",
                format!("has a waypoint so large ({v:e}) that the deformed one overflows (non-finite)"),
            ));
        }
        // Rows of a known length unroll and vectorise: 1.5–2× faster for the arm's 7 joints (measured).
        match dof {
            6 => self.apply(rows, m, fixed::<6>(u_h)),
            7 => self.apply(rows, m, fixed::<7>(u_h)),
            _ => self.apply(rows, m, |row: &mut [f64], c: f64| add_scaled(row, c, u_h)),
        }
        Ok(m)
    }

    /// Adds μ·H[k]·u_H to row k of the m `rows`, `add(row, c)` doing row += c·u_H.
    #[inline]
    fn apply(&self, rows: &mut [f64], m: usize, add: impl Fn(&mut [f64], f64)) {
        let dof = rows.len() / m;
        let mu = self.params.mu;
        if m == self.params.window {
            for (row, &h) in rows.chunks_exact_mut(dof).zip(&self.shape) {
                add(row, mu * h);
            }
        } else {
            // Shrunk window: x = R_m⁻¹e₁ from the leading block of the factor, twice (‖x‖ first).
            let mut sum_sq = 0.0;
            self.solve_leading(m, |_, x| sum_sq += x * x);
            let scale = mu * (m as f64).sqrt() / sum_sq.sqrt();
            self.solve_leading(m, |k, x| add(&mut rows[k * dof..(k + 1) * dof], scale * x));
        }
    }

    /// Solves R_m·x = e₁ (R_m the leading m×m block of R) by back substitution with Lᵀ, calling
    /// `visit(k, x[k])` for k = m−1 down to 0.
    #[inline]
    fn solve_leading(&self, m: usize, visit: impl FnMut(usize, f64)) {
        let n = self.params.window;
        let band = |k: usize| &self.factor[(k - 1) * n..(k - 1) * n + m];
        match self.params.norm {
            Norm::Acceleration => back_substitute_2(band(1), band(2), &self.rhs[..m], visit),
            Norm::Jerk => back_substitute_3(band(1), band(2), band(3), &self.rhs[..m], visit),
        }
    }
}

/// row += c·u.
#[inline]
fn add_scaled(row: &mut [f64], c: f64, u: &[f64]) {
    for (q, &uj) in row.iter_mut().zip(u) {
        *q += c * uj;
    }
}

/// `add_scaled` for rows of D values (`u` has D values: checked by the caller).
#[inline]
fn fixed<const D: usize>(u: &[f64]) -> impl Fn(&mut [f64], f64) + '_ {
    let u: [f64; D] = std::array::from_fn(|j| u[j]);
    move |row: &mut [f64], c: f64| {
        if let Ok(row) = <&mut [f64; D]>::try_from(row) {
            for (q, uj) in row.iter_mut().zip(u) {
                *q += c * uj;
            }
        }
    }
}

/// Solves Lᵀ·x = rhs for a pentadiagonal R (sub-diagonals `l1`, `l2` of L), from the last row up,
/// calling `visit(i, x[i])`; x's past the block are taken as 0, so any leading block can be solved.
/// Latency-bound: x[i] waits for x[i+1] through one multiply and one subtraction, so the term in
/// x[i+2] is formed first.
#[inline]
fn back_substitute_2(l1: &[f64], l2: &[f64], rhs: &[f64], mut visit: impl FnMut(usize, f64)) {
    let (mut x1, mut x2) = (0.0, 0.0);
    for (i, ((&a, &b), &w)) in l1.iter().zip(l2).zip(rhs).enumerate().rev() {
        let x = (w - b * x2) - a * x1;
        (x2, x1) = (x1, x);
        visit(i, x);
    }
}

/// [`back_substitute_2`] for a heptadiagonal R (sub-diagonals `l1`, `l2`, `l3` of L).
#[inline]
fn back_substitute_3(l1: &[f64], l2: &[f64], l3: &[f64], rhs: &[f64], mut visit: impl FnMut(usize, f64)) {
    let (mut x1, mut x2, mut x3) = (0.0, 0.0, 0.0);
    for (i, (((&a, &b), &c), &w)) in l1.iter().zip(l2).zip(l3).zip(rhs).enumerate().rev() {
        let x = ((w - c * x3) - b * x2) - a * x1;
        (x3, x2, x1) = (x2, x1, x);
        visit(i, x);
    }
}

/// The banded LDLᵀ of the n×n Toeplitz R with `band` = [R[i,i], R[i,i+1], …, R[i,i+p]], in
/// double-double, and what the deformation keeps of it, rounded to f64: the rows of Lᵀ, the
/// right-hand side D⁻¹L⁻¹e₁ of the back substitution, and the full-window H (‖H‖ = √n).
fn factor_and_shape(band: &[f64], n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let p = band.len() - 1;
    // lower[i·p + k − 1] = L[i, i−k].
    let mut lower = vec![Dd::ZERO; n * p];
    let mut diag = vec![Dd::ZERO; n];
    for i in 0..n {
        let reach = p.min(i);
        // L[i, j] for j = i−reach .. i−1 in increasing j (each needs the L[i, l], l < j, before it):
        // L[i, j] = (R[i, j] − Σ_{l<j} L[i, l]·D[l]·L[j, l]) / D[j].
        for k in (1..=reach).rev() {
            let j = i - k;
            let mut s = Dd::from(band[k]);
            for kl in (k + 1)..=reach {
                // l = i − kl, and L[j, l] = lower[j·p + (kl − k) − 1].
                s = s - lower[i * p + kl - 1] * diag[i - kl] * lower[j * p + kl - k - 1];
            }
            lower[i * p + k - 1] = s / diag[j];
        }
        let mut d = Dd::from(band[0]);
        for k in 1..=reach {
            let l = lower[i * p + k - 1];
            d = d - l * l * diag[i - k];
        }
        diag[i] = d;
    }
    // Forward: z = L⁻¹e₁, then rhs = D⁻¹z.
    let mut rhs = vec![Dd::ZERO; n];
    let mut z = vec![Dd::ZERO; n];
    z[0] = Dd::from(1.0);
    for i in 0..n {
        for k in 1..=p.min(i) {
            z[i] = z[i] - lower[i * p + k - 1] * z[i - k];
        }
        rhs[i] = z[i] / diag[i];
    }
    // Back: Lᵀx = rhs, in double-double for the full window.
    let mut x = vec![Dd::ZERO; n];
    for i in (0..n).rev() {
        let mut s = rhs[i];
        for k in 1..=p.min(n - 1 - i) {
            s = s - lower[(i + k) * p + k - 1] * x[i + k];
        }
        x[i] = s;
    }
    let norm = x.iter().map(|v| v.hi * v.hi).sum::<f64>().sqrt();
    let scale = (n as f64).sqrt() / norm;
    let shape = x.iter().map(|v| v.hi * scale).collect();
    let mut factor = vec![0.0; n * p];
    for i in 0..n {
        for k in 1..=p.min(n - 1 - i) {
            factor[(k - 1) * n + i] = lower[(i + k) * p + k - 1].hi;
        }
    }
    (factor, rhs.iter().map(|v| v.hi).collect(), shape)
}

/// A double-double number hi + lo (|lo| ≤ ½ ulp(hi)), ~106 bits: just the operations the
/// factorisation needs (Dekker; Hida, Li and Bailey's QD library).
#[derive(Debug, Clone, Copy)]
struct Dd {
    hi: f64,
    lo: f64,
}

impl Dd {
    const ZERO: Dd = Dd { hi: 0.0, lo: 0.0 };

    /// a + b exactly, as a normalised pair.
    #[inline]
    fn two_sum(a: f64, b: f64) -> Dd {
        let s = a + b;
        let bb = s - a;
        Dd { hi: s, lo: (a - (s - bb)) + (b - bb) }
    }

    /// a + b exactly, given |a| ≥ |b|.
    #[inline]
    fn quick_two_sum(a: f64, b: f64) -> Dd {
        let s = a + b;
        Dd { hi: s, lo: b - (s - a) }
    }
}

impl From<f64> for Dd {
    fn from(hi: f64) -> Self {
        Dd { hi, lo: 0.0 }
    }
}

impl std::ops::Add for Dd {
    type Output = Dd;
    #[inline]
    fn add(self, o: Dd) -> Dd {
        let s = Dd::two_sum(self.hi, o.hi);
        let t = Dd::two_sum(self.lo, o.lo);
        let u = Dd::quick_two_sum(s.hi, s.lo + t.hi);
        Dd::quick_two_sum(u.hi, u.lo + t.lo)
    }
}

impl std::ops::Sub for Dd {
    type Output = Dd;
    #[inline]
    fn sub(self, o: Dd) -> Dd {
        self + Dd { hi: -o.hi, lo: -o.lo }
    }
}

impl std::ops::Mul for Dd {
    type Output = Dd;
    #[inline]
    fn mul(self, o: Dd) -> Dd {
        let p = self.hi * o.hi;
        // The rounding error of hi·hi, exactly (a fused multiply-add rounds once).
        let e = self.hi.mul_add(o.hi, -p);
        Dd::quick_two_sum(p, e + (self.hi * o.lo + self.lo * o.hi))
    }
}

impl std::ops::Div for Dd {
    type Output = Dd;
    #[inline]
    fn div(self, o: Dd) -> Dd {
        // Long division: three f64 quotient digits.
        let q1 = self.hi / o.hi;
        let r = self - o * Dd::from(q1);
        let q2 = r.hi / o.hi;
        let r = r - o * Dd::from(q2);
        let q3 = r.hi / o.hi;
        Dd::quick_two_sum(q1, q2) + Dd::from(q3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use proptest::prelude::*;

    const NORMS: [Norm; 2] = [Norm::Acceleration, Norm::Jerk];

    fn deformation(window: usize, norm: Norm, end_rule: EndRule) -> Deformation {
        Deformation::new(DeformParams { window, mu: 0.01, norm, end_rule }).expect("valid parameters")
    }

    /// The closed-form shape for an m-window, normalised to ‖H‖ = √m (exact products in u128).
    fn closed_form(norm: Norm, m: usize) -> Vec<f64> {
        let mm = m as u128;
        let raw: Vec<f64> = (0..mm)
            .map(|k| match norm {
                Norm::Acceleration => ((k + 1) * (mm - k) * (mm + 1 - k)) as f64,
                Norm::Jerk => ((k + 1) * (k + 2) * (mm - k) * (mm + 1 - k) * (mm + 2 - k)) as f64,
            })
            .collect();
        normalised(&raw)
    }

    fn normalised(x: &[f64]) -> Vec<f64> {
        let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
        x.iter().map(|v| v * (x.len() as f64).sqrt() / norm).collect()
    }

    /// H of an m-window read back from a deformation of a zero trajectory by a unit push.
    fn shape_of(d: &Deformation, m: usize) -> Vec<f64> {
        let mut traj = vec![0.0; m + 2];
        assert_eq!(d.deform_in_place(&mut traj, 1, 0, &[1.0]).unwrap(), m);
        traj[1..=m].iter().map(|v| v / d.params().mu).collect()
    }

    fn max_rel_err(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| ((x - y) / y).abs()).fold(0.0, f64::max)
    }

    /// The steps into and out of the window, relative to the peak, at n = 5 (the numbers the module
    /// docs quote) and their decay with the window: entry like 1/m (acceleration) and 1/m² (jerk),
    /// exit like 1/m² and 1/m³.
    #[test]
    fn the_window_ends_become_continuous_as_it_lengthens() {
        let steps = |norm: Norm, m: usize| {
            let d = Deformation::new(DeformParams { window: m, norm, ..Default::default() }).unwrap();
            let h = shape_of(&d, m);
            let peak = h.iter().cloned().fold(0.0, f64::max);
            (h[0] / peak, h[m - 1] / peak)
        };
        for (norm, entry5, exit5, entry_order, exit_order) in
            [(Norm::Acceleration, 0.75, 0.25, 1, 2), (Norm::Jerk, 0.5833, 0.25, 2, 3)]
        {
            let (a, b) = steps(norm, 5);
            assert!((a - entry5).abs() < 1e-4 && (b - exit5).abs() < 1e-4, "{norm:?} n = 5: {a} {b}");
            let (a1, b1) = steps(norm, 100);
            let (a2, b2) = steps(norm, 1000);
            // Ten times the window: the entry step shrinks ~10^order times (within a factor 1.5).
            let (re, rx) = (a1 / a2, b1 / b2);
            let (ee, ex) = (10f64.powi(entry_order), 10f64.powi(exit_order));
            assert!(re > ee / 1.5 && re < ee * 1.5, "{norm:?} entry ratio {re}");
            assert!(rx > ex / 1.5 && rx < ex * 1.5, "{norm:?} exit ratio {rx}");
        }
    }

    #[test]
    fn bands_of_the_two_norms() {
        assert_eq!(Norm::Acceleration.band(), vec![6.0, -4.0, 1.0]);
        assert_eq!(Norm::Jerk.band(), vec![20.0, -15.0, 6.0, -1.0]);
    }

    #[test]
    fn original_shape_for_n_5() {
        let d = Deformation::new(DeformParams::default()).unwrap();
        let expected = [1.0031, 1.3375, 1.2038, 0.8025, 0.3344];
        for (h, e) in d.shape().iter().zip(expected) {
            assert!((h - e).abs() < 5e-5, "H = {:?}", d.shape());
        }
        let norm: f64 = d.shape().iter().map(|h| h * h).sum();
        assert!((norm - 5.0).abs() < 1e-13);
    }

    #[test]
    fn factor_matches_its_closed_form() {
        // Acceleration: D[i] = (i+3)(i+4)/((i+1)(i+2)), L[i,i−1] = −2i/(i+2), L[i,i−2] = (i−1)i/((i+1)(i+2)).
        let n = 2000;
        let d = deformation(n, Norm::Acceleration, EndRule::Skip);
        for i in 0..n - 2 {
            let f = i as f64;
            let l1 = -2.0 * (f + 1.0) / (f + 3.0);
            let l2 = (f + 1.0) * (f + 2.0) / ((f + 3.0) * (f + 4.0));
            assert!((d.factor[i] - l1).abs() < 4e-15 && (d.factor[n + i] - l2).abs() < 4e-15, "row {i}");
        }
    }

    #[test]
    fn banded_solve_equals_a_dense_solve() {
        for norm in NORMS {
            let s = norm.stencil();
            // Small n: the dense LU of R itself loses ~κ(R)·ε, 10⁻¹² for the jerk R at n ≈ 20.
            for n in 1..=16 {
                let mut a = DMatrix::<f64>::zeros(n + s.len() - 1, n);
                for k in 0..n {
                    for (r, v) in s.iter().enumerate() {
                        a[(k + r, k)] = *v;
                    }
                }
                let r = a.transpose() * &a;
                let x = r.lu().solve(&DVector::from_element(1, 1.0).resize_vertically(n, 0.0)).unwrap();
                let dense = normalised(x.as_slice());
                let d = deformation(n, norm, EndRule::Shrink);
                let err = d.shape().iter().zip(&dense).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
                assert!(err < 1e-12, "{norm:?} n = {n}: {err:e}");
                assert!(max_rel_err(d.shape(), &closed_form(norm, n)) < 1e-13, "{norm:?} n = {n}");
                // And every shrunk window solved from the same factor.
                for m in 1..n {
                    let h = shape_of(&d, m);
                    assert!(max_rel_err(&h, &closed_form(norm, m)) < 1e-12, "{norm:?} n = {n}, m = {m}");
                }
            }
        }
    }

    #[test]
    fn long_windows_are_accurate() {
        for (norm, full_tol, shrunk_tol) in [(Norm::Acceleration, 1e-13, 1e-10), (Norm::Jerk, 1e-10, 1e-7)] {
            let n = 10_000;
            let d = deformation(n, norm, EndRule::Shrink);
            assert!(d.shape().iter().all(|h| h.is_finite() && *h > 0.0));
            let err = max_rel_err(d.shape(), &closed_form(norm, n));
            assert!(err < full_tol, "{norm:?} full window: {err:e}");
            for m in [n - 1, 3_333] {
                let err = max_rel_err(&shape_of(&d, m), &closed_form(norm, m));
                assert!(err < shrunk_tol, "{norm:?} m = {m}: {err:e}");
            }
        }
    }

    #[test]
    fn the_largest_window_is_still_accurate() {
        let n = MAX_WINDOW;
        for (norm, tol) in [(Norm::Acceleration, 1e-12), (Norm::Jerk, 1e-5)] {
            let d = deformation(n, norm, EndRule::Skip);
            let err = max_rel_err(d.shape(), &closed_form(norm, n));
            assert!(err < tol, "{norm:?}: {err:e}");
        }
    }

    #[test]
    fn slopes_at_the_ends_of_the_window() {
        // Per-step slope H[k]·n/peak in the continuum limit: acceleration s(1−s)² enters with slope
        // 27/4 and leaves with O(1/n); jerk s²(1−s)³ enters with O(1/n) and leaves with O(1/n²).
        for n in [100, 1000, 10_000] {
            let nf = n as f64;
            for norm in NORMS {
                let d = deformation(n, norm, EndRule::Skip);
                let h = d.shape();
                let peak = h.iter().copied().fold(0.0, f64::max);
                let (start, end) = (h[0] * nf / peak, h[n - 1] * nf / peak);
                match norm {
                    Norm::Acceleration => assert!((start - 6.75).abs() < 25.0 / nf && end < 14.0 / nf),
                    Norm::Jerk => assert!(start < 60.0 / nf && end < 180.0 / (nf * nf)),
                }
            }
        }
    }

    #[test]
    fn end_rules_near_the_goal() {
        let skip = deformation(5, Norm::Acceleration, EndRule::Skip);
        let shrink = deformation(5, Norm::Acceleration, EndRule::Shrink);
        let n_waypoints = 10;
        // A full window at index i needs i + 5 ≤ 8.
        let expected_skip = [5, 5, 5, 5, 0, 0, 0, 0, 0, 0];
        let expected_shrink = [5, 5, 5, 5, 4, 3, 2, 1, 0, 0];
        for i in 0..n_waypoints {
            assert_eq!(skip.window_at(i, n_waypoints).unwrap(), expected_skip[i]);
            assert_eq!(shrink.window_at(i, n_waypoints).unwrap(), expected_shrink[i]);
            for d in [&skip, &shrink] {
                let mut traj: Vec<f64> = (0..2 * n_waypoints).map(|v| v as f64).collect();
                let before = traj.clone();
                let moved = d.deform_in_place(&mut traj, 2, i, &[3.0, -4.0]).unwrap();
                assert_eq!(moved, d.window_at(i, n_waypoints).unwrap());
                let changed: Vec<usize> =
                    (0..n_waypoints).filter(|&w| traj[2 * w..2 * w + 2] != before[2 * w..2 * w + 2]).collect();
                assert_eq!(changed, (i + 1..i + 1 + moved).collect::<Vec<_>>(), "index {i}");
            }
        }
        assert!(matches!(skip.window_at(10, 10), Err(PhriError::InvalidParameter { .. })));
        assert!(matches!(shrink.window_at(0, 0), Err(PhriError::InvalidParameter { .. })));
    }

    #[test]
    fn shrunk_windows_are_normalised_to_their_length() {
        let d = deformation(50, Norm::Jerk, EndRule::Shrink);
        for m in [1, 2, 7, 49] {
            let h = shape_of(&d, m);
            let norm: f64 = h.iter().map(|v| v * v).sum();
            assert!((norm - m as f64).abs() < 1e-10 * m as f64, "m = {m}");
        }
        assert_eq!(shape_of(&d, 1), vec![1.0]);
    }

    #[test]
    fn invalid_parameters_and_arguments_name_themselves() {
        let err = |p: DeformParams| Deformation::new(p).unwrap_err().to_string();
        let base = DeformParams::default();
        assert_eq!(err(DeformParams { window: 0, ..base }), "window must be ≥ 1, got 0");
        assert!(err(DeformParams { window: MAX_WINDOW + 1, ..base }).starts_with("window must be ≤ 100000"));
        for mu in [0.0, f64::NAN, f64::INFINITY] {
            assert!(err(DeformParams { mu, ..base }).starts_with("mu must be finite and non-zero"));
        }
        let d = Deformation::new(base).unwrap();
        let mut traj = vec![0.0; 31 * 7];
        let u = [1.0; 7];
        let msg = |r: Result<usize>| r.unwrap_err().to_string();
        assert_eq!(msg(d.deform_in_place(&mut traj, 7, 0, &[1.0; 6])), "u_h must have shape (7,), got (6,)");
        assert!(msg(d.deform_in_place(&mut traj, 7, 0, &[f64::NAN; 7])).starts_with("u_h must be finite"));
        assert_eq!(msg(d.deform_in_place(&mut traj, 7, 31, &u)), "index must be < 31, the number of waypoints, got 31");
        assert!(msg(d.deform_in_place(&mut traj[..30], 7, 0, &u)).starts_with("trajectory must have shape (N, 7)"));
        assert_eq!(msg(d.deform_in_place(&mut traj, 0, 0, &[])), "dof must be ≥ 1, got 0");
        assert_eq!(msg(d.deform_in_place(&mut [], 7, 0, &u)), "index must be < 0, the number of waypoints, got 0");
    }

    #[test]
    fn mu_sign_follows_the_push() {
        let d = Deformation::new(DeformParams::default()).unwrap();
        let mut traj = vec![0.0; 10];
        d.deform_in_place(&mut traj, 1, 0, &[2.0]).unwrap();
        assert!(traj[1..=5].iter().all(|&q| q > 0.0) && traj[6..].iter().all(|&q| q == 0.0));
        assert!((traj[1] - 0.01 * 1.0031 * 2.0).abs() < 1e-6);
    }

    /// A trajectory, a push and an index; the window and norm vary too.
    fn case() -> impl Strategy<Value = (Deformation, usize, Vec<f64>, usize, Vec<f64>, Vec<f64>)> {
        (1usize..40, 0usize..2, 0usize..2, 1usize..8, 1usize..60).prop_flat_map(|(window, norm, rule, dof, n_waypoints)| {
            let norm = NORMS[norm];
            let rule = [EndRule::Skip, EndRule::Shrink][rule];
            (
                Just(deformation(window, norm, rule)),
                Just(dof),
                prop::collection::vec(-3.0..3.0f64, n_waypoints * dof),
                0..n_waypoints,
                prop::collection::vec(-20.0..20.0f64, dof),
                prop::collection::vec(-20.0..20.0f64, dof),
            )
        })
    }

    proptest! {
        #[test]
        fn zero_torque_is_the_identity((d, dof, traj, index, _u, _v) in case()) {
            let mut deformed = traj.clone();
            d.deform_in_place(&mut deformed, dof, index, &vec![0.0; dof]).unwrap();
            prop_assert_eq!(deformed, traj);
        }

        #[test]
        fn linear_in_the_push((d, dof, traj, index, u, v) in case(), a in -2.0..2.0f64, b in -2.0..2.0f64) {
            let delta = |push: &[f64]| {
                let mut t = traj.clone();
                d.deform_in_place(&mut t, dof, index, push).unwrap();
                t.iter().zip(&traj).map(|(x, y)| x - y).collect::<Vec<_>>()
            };
            let combined: Vec<f64> = u.iter().zip(&v).map(|(x, y)| a * x + b * y).collect();
            let (du, dv, dc) = (delta(&u), delta(&v), delta(&combined));
            for k in 0..traj.len() {
                prop_assert!((dc[k] - (a * du[k] + b * dv[k])).abs() < 1e-12, "entry {}", k);
            }
        }

        #[test]
        fn outside_the_window_nothing_moves_and_inside_it_is_the_shape_times_the_push((d, dof, traj, index, u, _v) in case()) {
            let n_waypoints = traj.len() / dof;
            let mut deformed = traj.clone();
            let moved = d.deform_in_place(&mut deformed, dof, index, &u).unwrap();
            prop_assert_eq!(moved, d.window_at(index, n_waypoints).unwrap());
            prop_assert!(index + moved < n_waypoints.saturating_sub(1) || moved == 0, "the goal moved");
            // Everything up to the current waypoint, and from the one after the window on, is
            // untouched: positions there and the differences across both ends are unchanged.
            let untouched = |w: usize| w <= index || w > index + moved;
            for w in 0..n_waypoints {
                if untouched(w) {
                    prop_assert_eq!(&deformed[w * dof..(w + 1) * dof], &traj[w * dof..(w + 1) * dof], "waypoint {}", w);
                }
            }
            prop_assert!(deformed.iter().all(|q| q.is_finite()));
            // The deformation itself is the shape times the push, joint by joint.
            if moved > 0 {
                let h = shape_of(&d, moved);
                for (k, hk) in h.iter().enumerate() {
                    let w = index + 1 + k;
                    for (j, uj) in u.iter().enumerate() {
                        let expected = d.params().mu * hk * uj;
                        prop_assert!((deformed[w * dof + j] - traj[w * dof + j] - expected).abs() < 1e-12);
                    }
                }
            }
        }
    }
}
