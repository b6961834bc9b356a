//! The collision penalty: every collision body of the arm (and what it carries) kept at least
//! each pair's margin from the scene's objects and from the bodies it can meet, between waypoints
//! as well as at them.
//!
//! The penalty ρ·max(0, margin + buffer − d)² acts per sphere pair ([`crate::collision`]) at
//! `samples` points of each segment's chord q(u) = (1 − u)·q_{i−1} + u·q_i, which the Newton model
//! represents exactly (a point on the cubic would reach four waypoints and leave the model only
//! approximate: far slower convergence, measured). What the arm executes is the C¹ cubic Hermite
//! through the waypoints (`reference::Interpolation::Cubic`): a solved plan is checked along that
//! curve at [`CHECK_SAMPLES`] points per segment ([`executed_worst`]), and `buffer` covers both the
//! penalty's give at an optimum and the cubic's bulge beyond the chords.

use super::newton_model::Model;
use super::params::CollisionParams;
use crate::collision::{ProximityScratch, Violation};
use crate::data::RobotData;
use crate::model::RobotModel;
use crate::reference::{hermite, hermite_rate};

/// Points per segment at which a solved plan is checked against the margins (more than the
/// penalty's `samples`, so the reported clearance holds between them).
pub(super) const CHECK_SAMPLES: usize = 16;

/// The cubic's weights on (q_{a−1}, q_a, q_b, q_{b+1}) at u, for segment end `b` of `m` waypoints
/// (the end tangents are zero).
#[inline]
pub(super) fn cubic_weights(u: f64, b: usize, m: usize) -> [f64; 4] {
    waypoint_weights(hermite(u), b, m)
}

/// A Hermite `basis` (the basis or its rate) as weights on (q_{a−1}, q_a, q_b, q_{b+1}) through the
/// central-difference tangents m_a = ½(q_b − q_{a−1}) and m_b = ½(q_{b+1} − q_a).
#[inline]
fn waypoint_weights([h00, h10, h01, h11]: [f64; 4], b: usize, m: usize) -> [f64; 4] {
    // m_a exists only at an interior a = b − 1, m_b only at an interior b.
    let (ta, tb) = (if b > 1 { 0.5 * h10 } else { 0.0 }, if b < m - 1 { 0.5 * h11 } else { 0.0 });
    [-ta, h00 - tb, h01 + ta, tb]
}

/// The rows the weights of [`cubic_weights`] apply to (None where the waypoint does not exist).
#[inline]
fn rows(b: usize, m: usize) -> [Option<usize>; 4] {
    let a = b - 1;
    [a.checked_sub(1), Some(a), Some(b), (b + 1 < m).then_some(b + 1)]
}

/// q(u) on segment b of `traj` (m × n) into `out`.
#[inline]
pub(super) fn cubic_point(traj: &[f64], n: usize, b: usize, u: f64, out: &mut [f64]) {
    let m = traj.len() / n;
    let w = cubic_weights(u, b, m);
    out.fill(0.0);
    for (row, w) in rows(b, m).into_iter().zip(w) {
        if let Some(r) = row {
            for j in 0..n {
                out[j] += w * traj[r * n + j];
            }
        }
    }
}

/// Scratch of the collision penalty.
#[derive(Debug, Clone)]
pub(super) struct CollisionScratch {
    pub(super) data: RobotData,
    pub(super) q: Vec<f64>,
    pub(super) proximity: ProximityScratch,
}

impl CollisionScratch {
    pub(super) fn new(model: &RobotModel) -> Self {
        CollisionScratch { data: model.data(), q: vec![0.0; model.nq()], proximity: ProximityScratch::default() }
    }
}

/// The collision penalty of `traj` (m × n), its gradient added to `grad`; with `model`, a piece
/// per sphere pair within the band, and the active ones' modelled gradient in `pen_grad`.
pub(super) fn collision_penalty(
    params: &CollisionParams,
    robot: &RobotModel,
    scratch: &mut CollisionScratch,
    traj: &[f64],
    grad: &mut [f64],
    mut model: Option<&mut Model>,
) -> f64 {
    let n = robot.nq();
    let m = traj.len() / n;
    let rho = params.weight;
    let mut penalty = 0.0;
    let CollisionScratch { data, q, proximity } = scratch;
    for b in 1..m {
        for k in 1..=params.samples {
            let u = k as f64 / params.samples as f64;
            if b == m - 1 && k == params.samples {
                continue; // the goal: fixed
            }
            for j in 0..n {
                q[j] = (1.0 - u) * traj[(b - 1) * n + j] + u * traj[b * n + j];
            }
            robot.forward_kinematics_unchecked(q, data);
            params.checker.for_each_near(robot, data, proximity, params.band, |near, g| {
                let gap = near.margin + params.buffer - near.distance;
                if gap > 0.0 {
                    penalty += rho * gap * gap;
                    for (r, wr) in [(b - 1, 1.0 - u), (b, u)] {
                        for j in 0..n {
                            let d = -2.0 * rho * gap * wr * g[j];
                            grad[r * n + j] += d;
                            if let Some(model) = model.as_deref_mut() {
                                model.pen_grad[r * n + j] += d;
                            }
                        }
                    }
                }
                if let Some(model) = model.as_deref_mut() {
                    model.pieces.set_segment(b);
                    model.pieces.push(u, gap, 2.0 * rho, |j| -g[j]);
                }
            });
        }
    }
    penalty
}

/// The pair furthest into its margin along the executed curve of `traj` (checked at
/// [`CHECK_SAMPLES`] points per segment and at every waypoint), with the smallest distance.
pub(super) fn executed_worst(
    params: &CollisionParams,
    robot: &RobotModel,
    scratch: &mut CollisionScratch,
    traj: &[f64],
) -> Option<Violation> {
    let n = robot.nq();
    let m = traj.len() / n;
    let mut worst: Option<(usize, f64)> = None;
    let CollisionScratch { data, q, proximity } = scratch;
    for b in 1..m {
        for k in 0..=CHECK_SAMPLES {
            if k == 0 && b > 1 {
                continue; // the previous segment's end
            }
            cubic_point(traj, n, b, k as f64 / CHECK_SAMPLES as f64, q);
            robot.forward_kinematics_unchecked(q, data);
            // Only pairs nearer than the worst so far matter: their bounds skip the rest.
            let below = worst.map_or(f64::INFINITY, |(_, slack)| slack);
            if let Some(found) = params.checker.worst_below(robot, data, proximity, below) {
                worst = Some(found);
            }
        }
    }
    worst.map(|(k, slack)| params.checker.violation(k, slack))
}

/// Largest per-segment joint move of the executed curve beyond `max_step` [rad per segment], and
/// the largest as a fraction of that joint's `max_step` [1]: the cubic's |dq/du| at
/// [`CHECK_SAMPLES`] points per segment (its speed in units of the waypoint spacing); both at
/// least 0.
pub(super) fn executed_step_excess(max_step: &[f64], traj: &[f64]) -> (f64, f64) {
    let n = max_step.len();
    if n == 0 {
        return (0.0, 0.0);
    }
    let mut relative: f64 = 0.0;
    let m = traj.len() / n;
    let mut worst: f64 = 0.0;
    for b in 1..m {
        for k in 0..=CHECK_SAMPLES {
            let u = k as f64 / CHECK_SAMPLES as f64;
            let w = waypoint_weights(hermite_rate(u), b, m);
            for (j, limit) in max_step.iter().enumerate() {
                let mut v = 0.0;
                for (row, w) in rows(b, m).into_iter().zip(w) {
                    if let Some(r) = row {
                        v += w * traj[r * n + j];
                    }
                }
                worst = worst.max(v.abs() - limit);
                relative = relative.max((v.abs() - limit) / limit);
            }
        }
    }
    (worst, relative)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::{Interpolation, TimedTrajectory};

    #[test]
    fn cubic_points_are_the_references() {
        let (n, m) = (2, 6);
        let traj: Vec<f64> = (0..m * n).map(|k| ((k * 7) as f64 * 0.37).sin()).collect();
        let reference = TimedTrajectory::new(traj.clone(), n, (m - 1) as f64, Interpolation::Cubic).unwrap();
        let (mut q, mut qd, mut qdd, mut p) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut fastest: f64 = 0.0;
        for b in 1..m {
            for k in 0..=CHECK_SAMPLES {
                let u = k as f64 / CHECK_SAMPLES as f64;
                reference.sample_plan((b - 1) as f64 + u, &mut q, &mut qd, &mut qdd);
                cubic_point(&traj, n, b, u, &mut p);
                for j in 0..n {
                    assert!((p[j] - q[j]).abs() < 1e-12, "b {b} u {u}: {p:?} vs {q:?}");
                }
                // One second per segment: the speed is dq/du.
                fastest = fastest.max(qd[0].abs()).max(qd[1].abs());
            }
        }
        assert!((executed_step_excess(&[1e-300; 2], &traj).0 - fastest).abs() < 1e-12);
    }
}
