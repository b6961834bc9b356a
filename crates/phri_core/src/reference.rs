//! A planned trajectory in time: N waypoints evenly spaced over [0, T], interpolated to give the
//! reference (q_R, q̇_R, q̈_R) the control law tracks at any time t.

use crate::error::{check_finite, PhriError, Result};

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
}

impl TimedTrajectory {
    /// `waypoints` row-major N × n (N ≥ 2), `duration` [s] > 0.
    pub fn new(waypoints: Vec<f64>, n: usize, duration: f64, interpolation: Interpolation) -> Result<Self> {
        if n == 0 || waypoints.len() % n != 0 || waypoints.len() < 2 * n {
            return Err(PhriError::shape("waypoints", format!("(N, {n}) with N >= 2"), format!("{} values", waypoints.len())));
        }
        check_finite("waypoints", &waypoints)?;
        if !(duration.is_finite() && duration > 0.0) {
            return Err(PhriError::invalid("duration", format!("must be a finite time > 0 s, got {duration}")));
        }
        let mut t = TimedTrajectory { tangents: vec![0.0; waypoints.len()], waypoints, n, duration, interpolation };
        t.update_tangents();
        Ok(t)
    }

    /// Replaces the waypoints (same shape), e.g. after a replan; allocates nothing.
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
        Ok(())
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

    /// Position [rad], velocity [rad/s] and acceleration [rad/s²] at time `t` [s] into the slices.
    pub fn sample(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let (n, m) = (self.n, self.len());
        let dt = self.dt();
        if !(t > 0.0) || t >= self.duration {
            let i = if t >= self.duration { m - 1 } else { 0 };
            q.copy_from_slice(&self.waypoints[i * n..(i + 1) * n]);
            qd.fill(0.0);
            qdd.fill(0.0);
            return;
        }
        let i = ((t / dt) as usize).min(m - 2);
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
                let (s2, s3) = (s * s, s * s * s);
                let (h00, h10, h01, h11) = (2.0 * s3 - 3.0 * s2 + 1.0, s3 - 2.0 * s2 + s, -2.0 * s3 + 3.0 * s2, s3 - s2);
                let (d00, d10, d01, d11) =
                    (6.0 * s2 - 6.0 * s, 3.0 * s2 - 4.0 * s + 1.0, -6.0 * s2 + 6.0 * s, 3.0 * s2 - 2.0 * s);
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
