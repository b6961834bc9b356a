//! A planned trajectory in time: N waypoints evenly spaced over [0, T], interpolated to give the
//! reference (q_R, q̇_R, q̈_R) the control law tracks at any time t.
//!
//! # Switching to a new plan
//! After a replan the original system tracked the new plan at once, at the same clock time: the
//! reference jumps by however far the new plan lies from the old one (tens of centimetres at the
//! hand after a large weight change), and an impedance-controlled arm snaps after it at several
//! times its joint velocity limits. [`TimedTrajectory::switch_to`] keeps the reference C¹ instead:
//! it adds to the new plan an offset e(τ) that starts at the old reference's position and velocity
//! and decays to zero by the cubic Hermite blend e(τ) = h₀₀(σ)·Δq + h₁₀(σ)·D·Δq̇, σ = τ/D, with
//! the shortest blend time D that keeps every joint's reference speed within a given limit, or the
//! plan's own speed where that is higher, or the speed the joint already had at the switch (checked
//! wherever the velocity can peak; see `blend_excess`). [`TimedTrajectory::set_waypoints`] keeps
//! the original's instant switch.

use crate::error::{check_finite, PhriError, Result};

/// The cubic Hermite basis (h00, h10, h01, h11) at s ∈ [0, 1]: the weights of the segment's start,
/// start tangent, end and end tangent.
#[inline]
pub(crate) fn hermite(s: f64) -> [f64; 4] {
    let (s2, s3) = (s * s, s * s * s);
    [2.0 * s3 - 3.0 * s2 + 1.0, s3 - 2.0 * s2 + s, -2.0 * s3 + 3.0 * s2, s3 - s2]
}

/// d/ds of [`hermite`].
#[inline]
pub(crate) fn hermite_rate(s: f64) -> [f64; 4] {
    let s2 = s * s;
    [6.0 * s2 - 6.0 * s, 3.0 * s2 - 4.0 * s + 1.0, -6.0 * s2 + 6.0 * s, 3.0 * s2 - 2.0 * s]
}

/// Shortest time between consecutive waypoints [s] (10 kHz): below it velocities and accelerations
/// of a plan's reference overflow (a duration of 1e-300 s gave ±inf).
pub const MIN_WAYPOINT_SPACING: f64 = 1e-4;

/// Longest duration of a trajectory [s] (about 11.6 days).
pub const MAX_DURATION: f64 = 1e6;

/// A tick within this fraction of a period of a time grid (the learner's samples, a loop's log)
/// counts as on it: tick times carry rounding [-]. Python's control loop uses it too
/// (`phri._phri.GRID_TOLERANCE`).
pub const GRID_TOLERANCE: f64 = 1e-6;

/// Checks `duration` [s] for `waypoints` evenly spaced waypoints (≥ 2) against
/// [`MIN_WAYPOINT_SPACING`] and [`MAX_DURATION`].
pub fn check_duration(duration: f64, waypoints: usize) -> Result<()> {
    let segments = waypoints.max(2) as f64 - 1.0;
    let shortest = MIN_WAYPOINT_SPACING * segments;
    if !(duration >= shortest && duration <= MAX_DURATION) {
        return Err(PhriError::invalid(
            "duration",
            format!(
                "must be in [{shortest:e}, {MAX_DURATION:e}] s for {waypoints} waypoints (at least \
                 {MIN_WAYPOINT_SPACING} s between waypoints), got {duration:e}"
            ),
        ));
    }
    Ok(())
}

/// How waypoints are joined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    /// Piecewise linear in time (the original's reference); velocity jumps at waypoints.
    Linear,
    /// Cubic Hermite with central-difference tangents and zero velocity at both ends: C¹.
    Cubic,
}

/// A trajectory of `n` joints over `duration` seconds. Before 0 it holds the start, after the end
/// it holds the goal, both with zero velocity.
#[derive(Debug, Clone)]
pub struct TimedTrajectory {
    waypoints: Vec<f64>,
    tangents: Vec<f64>,
    n: usize,
    duration: f64,
    interpolation: Interpolation,
    blend: Blend,
    scratch: Scratch,
}

/// Per-joint buffers for [`TimedTrajectory::switch_to`], so that it allocates nothing.
#[derive(Debug, Clone, Default)]
struct Scratch {
    q_old: Vec<f64>,
    v_old: Vec<f64>,
    q: Vec<f64>,
    v: Vec<f64>,
    a: Vec<f64>,
    /// Each joint's reference speed when the blend starts [rad/s].
    start_speed: Vec<f64>,
}

/// The decaying offset from the previous plan after [`TimedTrajectory::switch_to`] (see the
/// module docs), and scratch for computing it.
#[derive(Debug, Clone)]
struct Blend {
    /// Time the blend began [s] and its length D [s]; D = 0: no blend.
    start: f64,
    length: f64,
    /// Δq [rad] and Δq̇ [rad/s]: old reference minus new plan at `start`.
    offset: Vec<f64>,
    rate: Vec<f64>,
    /// The old reference's q [rad] and q̇ [rad/s] at `start`, returned there exactly: plan + offset
    /// may differ from it in the last bit, and a plan adopted one tick later (a replan worker) must
    /// give the same ticks as one adopted at once.
    start_q: Vec<f64>,
    start_qd: Vec<f64>,
}

/// Smallest speed limit of a blend ([`TimedTrajectory::switch_to`]) [rad/s]: slower than a degree
/// in five hours; a blend at it already lasts years.
pub const MIN_SPEED_LIMIT: f64 = 1e-6;

/// Points of a blend at which the speed limit is checked.
const BLEND_CHECKS: usize = 64;

impl Blend {
    fn new(n: usize) -> Self {
        Blend { start: 0.0, length: 0.0, offset: vec![0.0; n], rate: vec![0.0; n], start_q: vec![0.0; n], start_qd: vec![0.0; n] }
    }

    /// Adds the offset at time `t` [s] (no-op outside the blend).
    #[inline]
    fn add(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let d = self.length;
        if !(d > 0.0 && t >= self.start && t < self.start + d) {
            return;
        }
        let s = (t - self.start) / d;
        if s == 0.0 {
            q.copy_from_slice(&self.start_q);
            qd.copy_from_slice(&self.start_qd);
            for j in 0..qdd.len() {
                qdd[j] += (-6.0 * self.offset[j] - 4.0 * self.rate[j] * d) / (d * d);
            }
            return;
        }
        let (s2, s3) = (s * s, s * s * s);
        let (h00, h10) = (2.0 * s3 - 3.0 * s2 + 1.0, s3 - 2.0 * s2 + s);
        let (d00, d10) = (6.0 * s2 - 6.0 * s, 3.0 * s2 - 4.0 * s + 1.0);
        let (e00, e10) = (12.0 * s - 6.0, 6.0 * s - 4.0);
        for j in 0..q.len() {
            let (dp, dv) = (self.offset[j], self.rate[j] * d);
            q[j] += h00 * dp + h10 * dv;
            qd[j] += (d00 * dp + d10 * dv) / d;
            qdd[j] += (e00 * dp + e10 * dv) / (d * d);
        }
    }
}

impl TimedTrajectory {
    /// `waypoints` row-major N × n (N ≥ 2), `duration` [s] > 0.
    pub fn new(waypoints: Vec<f64>, n: usize, duration: f64, interpolation: Interpolation) -> Result<Self> {
        if n == 0 || waypoints.len() % n != 0 || waypoints.len() < 2 * n {
            return Err(PhriError::shape("waypoints", format!("(N, {n}) with N >= 2"), format!("{} values", waypoints.len())));
        }
        check_finite("waypoints", &waypoints)?;
        check_duration(duration, waypoints.len() / n)?;
        let scratch = Scratch {
            q_old: vec![0.0; n],
            v_old: vec![0.0; n],
            q: vec![0.0; n],
            v: vec![0.0; n],
            a: vec![0.0; n],
            start_speed: vec![0.0; n],
        };
        let mut t = TimedTrajectory {
            tangents: vec![0.0; waypoints.len()],
            waypoints,
            n,
            duration,
            interpolation,
            blend: Blend::new(n),
            scratch,
        };
        t.update_tangents();
        Ok(t)
    }

    /// Replaces the waypoints (same shape), e.g. after a replan, taking effect at once (the
    /// original's switch; any blend in progress ends); allocates nothing.
    pub fn set_waypoints(&mut self, waypoints: &[f64]) -> Result<()> {
        if waypoints.len() != self.waypoints.len() {
            return Err(PhriError::shape(
                "waypoints",
                format!("({}, {})", self.len(), self.n),
                format!("{} values", waypoints.len()),
            ));
        }
        check_finite("waypoints", waypoints)?;
        self.waypoints.copy_from_slice(waypoints);
        self.update_tangents();
        self.blend.length = 0.0;
        Ok(())
    }

    /// Switches to new `waypoints` at time `t` [s] without a jump: the reference keeps its position
    /// and velocity at `t` and blends into the new plan (module docs) within `speed_limits`
    /// [rad/s] per joint, or at once when `speed_limits` is empty. Where the new plan alone is
    /// faster than a limit, the blend adds nothing beyond the plan's own speed there, and a joint
    /// already faster than its limit at `t` is not sped up further. Returns the blend time D [s].
    /// Allocates nothing.
    pub fn switch_to(&mut self, waypoints: &[f64], t: f64, speed_limits: &[f64]) -> Result<f64> {
        check_finite("t", &[t])?;
        if !speed_limits.is_empty() {
            crate::error::check_vector("speed_limits", speed_limits, self.n)?;
            // A smaller limit (a subnormal one) would make the blend time overflow and the
            // reference NaN.
            if let Some((j, v)) = speed_limits.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= MIN_SPEED_LIMIT)) {
                return Err(PhriError::invalid(
                    "speed_limits",
                    format!("[{j}] must be a finite speed >= {MIN_SPEED_LIMIT:e} rad/s, got {v:e}"),
                ));
            }
        }
        let mut sc = std::mem::take(&mut self.scratch);
        self.sample(t, &mut sc.q_old, &mut sc.v_old, &mut sc.a); // the reference so far
        let result = self.set_waypoints(waypoints);
        if result.is_ok() && !speed_limits.is_empty() {
            self.start_blend(t, speed_limits, &mut sc);
        }
        self.scratch = sc;
        result.map(|_| self.blend.length)
    }

    /// Sets the blend from the old reference in `sc` into the current plan at `t` (see `switch_to`).
    fn start_blend(&mut self, t: f64, limits: &[f64], sc: &mut Scratch) {
        self.sample_plan(t, &mut sc.q, &mut sc.v, &mut sc.a);
        self.blend.start_q.copy_from_slice(&sc.q_old);
        self.blend.start_qd.copy_from_slice(&sc.v_old);
        let mut needed: f64 = 0.0;
        let mut largest: f64 = 0.0;
        for j in 0..self.n {
            self.blend.offset[j] = sc.q_old[j] - sc.q[j];
            self.blend.rate[j] = sc.v_old[j] - sc.v[j];
            sc.start_speed[j] = sc.v_old[j].abs();
            // The position offset alone moves at most 1.5·|Δq|/D (max |h₀₀'| = 3/2).
            needed = needed.max(1.5 * self.blend.offset[j].abs() / limits[j]);
            largest = largest.max(self.blend.offset[j].abs()).max(self.blend.rate[j].abs() * self.dt());
        }
        self.blend.start = t;
        if !(largest > 1e-12) {
            self.blend.length = 0.0;
            return;
        }
        // Lengthen the blend until the reference keeps to the limits (or to the plan's own speed).
        // q_old and v_old are free now: they hold the blended reference at each check. Where no
        // length does (the velocity offset alone, which any blend carries through −1/3 of itself,
        // can exceed a limit tighter than the plans' speeds), take the one of least excess among
        // those up to the plan's duration, so that the blend stays finite.
        let mut length = needed.max(1e-3);
        let (mut best, mut best_excess) = (length, f64::INFINITY);
        for _ in 0..60 {
            self.blend.length = length;
            let excess = self.blend_excess(limits, sc);
            if excess <= 0.0 {
                return;
            }
            if excess < best_excess {
                (best, best_excess) = (length, excess);
            }
            if length > self.duration.max(needed) {
                break;
            }
            length *= 1.25;
        }
        self.blend.length = best;
    }

    /// How far the blended reference exceeds `limits` over the blend, relative to them (≤ 0: it
    /// keeps to them), allowing where the plan alone is faster the plan's speed, and where the
    /// reference already was faster when the blend started that speed (a blend never speeds a
    /// joint up beyond the faster of the three).
    /// Between the plan's waypoints, and before 0 and after T, the reference's velocity is a
    /// quadratic in t (the plan's, linear or cubic, plus the blend's cubic offset), so beside
    /// evenly spaced points it is checked where it can peak: at both ends of every such interval
    /// (one-sided: a piecewise-linear plan's velocity jumps at its waypoints) and at each joint's
    /// vertex of the quadratic.
    fn blend_excess(&self, limits: &[f64], sc: &mut Scratch) -> f64 {
        let (start, end) = (self.blend.start, self.blend.start + self.blend.length);
        let mut excess = f64::NEG_INFINITY;
        for k in 1..=BLEND_CHECKS {
            let tk = start + self.blend.length * k as f64 / (BLEND_CHECKS + 1) as f64;
            excess = excess.max(self.excess_at(None, tk, None, limits, sc));
        }
        let dt = self.dt();
        let mut a = start;
        while a < end {
            // The interval from `a` to the next waypoint time, 0, T or the blend's end, and the
            // plan's segment there (None where the plan holds its start or goal).
            let (b, segment) = if a < 0.0 {
                (end.min(0.0), None)
            } else if a >= self.duration {
                (end, None)
            } else {
                let i = self.segment_at(a);
                (end.min((i + 1) as f64 * dt).min(self.duration), Some(i))
            };
            if !(b > a) {
                break;
            }
            let mid = 0.5 * (a + b);
            for tk in [a, b] {
                excess = excess.max(self.excess_at(segment, tk, None, limits, sc));
            }
            // The vertex of each joint's velocity v(τ) = c0 + c1·τ + c2·τ², τ = (t − mid)/(b − a),
            // from its values at τ = −½, 0, ½.
            for j in 0..self.n {
                let v = |tk: f64, sc: &mut Scratch| {
                    self.sample_plan_on(segment, tk, sc);
                    self.blend.add(tk, &mut sc.q, &mut sc.v, &mut sc.a);
                    sc.v[j]
                };
                let (va, vm, vb) = (v(a, sc), v(mid, sc), v(b, sc));
                let c2 = 2.0 * (va + vb - 2.0 * vm);
                let c1 = vb - va;
                if c2 != 0.0 {
                    let tau = -c1 / (2.0 * c2);
                    if tau.abs() < 0.5 {
                        excess = excess.max(self.excess_at(segment, mid + tau * (b - a), Some(j), limits, sc));
                    }
                }
            }
            a = b;
        }
        excess
    }

    /// The plan at `t` on `segment`, or wherever t falls (into `sc.q`, `sc.v`, `sc.a`).
    fn sample_plan_on(&self, segment: Option<usize>, t: f64, sc: &mut Scratch) {
        match segment {
            Some(i) => self.sample_plan_in(i, t, &mut sc.q, &mut sc.v, &mut sc.a),
            None => self.sample_plan(t, &mut sc.q, &mut sc.v, &mut sc.a),
        }
    }

    /// The check of [`TimedTrajectory::blend_excess`] at time `t`, on the plan's segment `segment`
    /// (or wherever t falls), for joint `only` (or every joint): the largest speed beyond what is
    /// allowed there, relative to it (≤ 0 when within).
    fn excess_at(&self, segment: Option<usize>, t: f64, only: Option<usize>, limits: &[f64], sc: &mut Scratch) -> f64 {
        self.sample_plan_on(segment, t, sc);
        sc.q_old.copy_from_slice(&sc.q);
        sc.v_old.copy_from_slice(&sc.v);
        self.blend.add(t, &mut sc.q_old, &mut sc.v_old, &mut sc.a);
        let excess = |j: usize| {
            let allowed = limits[j].max(sc.v[j].abs()).max(sc.start_speed[j]);
            sc.v_old[j].abs() / allowed - 1.0 - 1e-9
        };
        match only {
            Some(j) => excess(j),
            None => (0..self.n).map(excess).fold(f64::NEG_INFINITY, f64::max),
        }
    }

    /// The plan's segment (between waypoints i and i + 1) that holds time `t` [s].
    fn segment_at(&self, t: f64) -> usize {
        (((t / self.dt()).max(0.0)) as usize).min(self.len() - 2)
    }

    fn update_tangents(&mut self) {
        // Tangents in units per segment (dq/ds, s the segment parameter); zero at the ends.
        let (n, m) = (self.n, self.len());
        self.tangents[..n].fill(0.0);
        self.tangents[(m - 1) * n..].fill(0.0);
        for i in 1..m - 1 {
            for j in 0..n {
                self.tangents[i * n + j] = 0.5 * (self.waypoints[(i + 1) * n + j] - self.waypoints[(i - 1) * n + j]);
            }
        }
    }

    /// Number of waypoints N.
    pub fn len(&self) -> usize {
        self.waypoints.len() / self.n
    }

    pub fn is_empty(&self) -> bool {
        self.waypoints.is_empty()
    }

    pub fn dof(&self) -> usize {
        self.n
    }

    /// Duration T [s].
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// Time between waypoints [s].
    pub fn dt(&self) -> f64 {
        self.duration / (self.len() - 1) as f64
    }

    pub fn waypoints(&self) -> &[f64] {
        &self.waypoints
    }

    pub fn interpolation(&self) -> Interpolation {
        self.interpolation
    }

    /// Index of the last waypoint at or before time t [s], clamped to [0, N−1].
    pub fn index_at(&self, t: f64) -> usize {
        let s = (t / self.dt()).floor();
        if s.is_nan() || s <= 0.0 {
            0
        } else {
            (s as usize).min(self.len() - 1)
        }
    }

    /// Position [rad], velocity [rad/s] and acceleration [rad/s²] at time `t` [s] into the slices,
    /// including the blend from the previous plan after [`TimedTrajectory::switch_to`].
    #[inline]
    pub fn sample(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        self.sample_plan(t, q, qd, qdd);
        self.blend.add(t, q, qd, qdd);
    }

    /// Time [s] at which the blend into the current plan ends (0 when there is none).
    pub fn blend_end(&self) -> f64 {
        if self.blend.length > 0.0 {
            self.blend.start + self.blend.length
        } else {
            0.0
        }
    }

    /// The current plan alone at time `t`, without the blend.
    pub fn sample_plan(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let (n, m) = (self.n, self.len());
        let dt = self.dt();
        if !(t > 0.0) || t >= self.duration {
            let i = if t >= self.duration { m - 1 } else { 0 };
            q.copy_from_slice(&self.waypoints[i * n..(i + 1) * n]);
            qd.fill(0.0);
            qdd.fill(0.0);
            return;
        }
        self.sample_plan_in(((t / dt) as usize).min(m - 2), t, q, qd, qdd);
    }

    /// The plan's interpolation on segment `i` (waypoints i and i + 1) at time `t` [s], clamped to
    /// the segment.
    fn sample_plan_in(&self, i: usize, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let n = self.n;
        let dt = self.dt();
        let s = (t / dt - i as f64).clamp(0.0, 1.0);
        let (a, b) = (&self.waypoints[i * n..(i + 1) * n], &self.waypoints[(i + 1) * n..(i + 2) * n]);
        match self.interpolation {
            Interpolation::Linear => {
                for j in 0..n {
                    q[j] = a[j] + s * (b[j] - a[j]);
                    qd[j] = (b[j] - a[j]) / dt;
                    qdd[j] = 0.0;
                }
            }
            Interpolation::Cubic => {
                let (ta, tb) = (&self.tangents[i * n..(i + 1) * n], &self.tangents[(i + 1) * n..(i + 2) * n]);
                let [h00, h10, h01, h11] = hermite(s);
                let [d00, d10, d01, d11] = hermite_rate(s);
                let (e00, e10, e01, e11) = (12.0 * s - 6.0, 6.0 * s - 4.0, -12.0 * s + 6.0, 6.0 * s - 2.0);
                for j in 0..n {
                    q[j] = h00 * a[j] + h10 * ta[j] + h01 * b[j] + h11 * tb[j];
                    qd[j] = (d00 * a[j] + d10 * ta[j] + d01 * b[j] + d11 * tb[j]) / dt;
                    qdd[j] = (e00 * a[j] + e10 * ta[j] + e01 * b[j] + e11 * tb[j]) / (dt * dt);
                }
            }
        }
    }
}
