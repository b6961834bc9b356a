//! The simulated arm: rigid-body dynamics integrated by semi-implicit Euler.

use std::sync::Arc;

use nalgebra::{DMatrix, Vector3};

use crate::error::{check_vector, PhriError, Result};
use crate::{RobotData, RobotModel};

/// An arm without contacts or joint limits, integrated with time step `dt` [s] by the step PyBullet
/// takes (semi-implicit Euler): q̈ = M(q)⁻¹(τ + τ_ext − d·q̇ − C(q, q̇)q̇ − g(q)), then q̇ += Δt·q̈
/// and q += Δt·q̇. The viscous damping d is phri's own: PyBullet's joint damping agrees with it
/// for about 0.5 s only. Allocates nothing per step.
#[derive(Debug, Clone)]
pub struct SimulatedArm {
    model: Arc<RobotModel>,
    dt: f64,
    /// Viscous friction per joint [N·m·s/rad].
    damping: Vec<f64>,
    q: Vec<f64>,
    qd: Vec<f64>,
    data: RobotData,
    mass: DMatrix<f64>,
    qdd: Vec<f64>,
    net: Vec<f64>,
}

/// Largest gravity a simulated arm accepts [m/s²] (as the PyBullet world does).
pub const MAX_GRAVITY: f64 = 100.0;

impl SimulatedArm {
    /// The arm of `model` at rest at its zero position, with time step `dt` [s] (finite, > 0),
    /// `gravity` [m/s², along −z of the base frame, in [0, 100]] and viscous `damping` per joint
    /// [N·m·s/rad, finite, >= 0].
    pub fn new(model: Arc<RobotModel>, dt: f64, gravity: f64, damping: &[f64]) -> Result<Self> {
        let n = model.nq();
        if !(dt.is_finite() && dt > 0.0) {
            return Err(PhriError::invalid("dt", format!("must be a finite time step > 0 s, got {dt}")));
        }
        if !(0.0..=MAX_GRAVITY).contains(&gravity) {
            return Err(PhriError::invalid("gravity", format!("must be in [0, {MAX_GRAVITY}] m/s², got {gravity}")));
        }
        check_vector("damping", damping, n)?;
        if let Some(j) = damping.iter().position(|d| *d < 0.0) {
            return Err(PhriError::invalid("damping", format!("must be >= 0 N·m·s/rad, got {} at joint {j}", damping[j])));
        }
        let g = Vector3::new(0.0, 0.0, -gravity);
        let model = if model.gravity == g {
            model
        } else {
            let mut own = (*model).clone();
            own.gravity = g;
            Arc::new(own)
        };
        let data = model.data();
        Ok(SimulatedArm {
            dt,
            damping: damping.to_vec(),
            q: vec![0.0; n],
            qd: vec![0.0; n],
            data,
            mass: DMatrix::zeros(n, n),
            qdd: vec![0.0; n],
            net: vec![0.0; n],
            model,
        })
    }

    /// The arm's model (with the arm's gravity).
    pub fn model(&self) -> &Arc<RobotModel> {
        &self.model
    }

    /// The time step [s].
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Joint positions [rad].
    pub fn q(&self) -> &[f64] {
        &self.q
    }

    /// Joint velocities [rad/s].
    pub fn qd(&self) -> &[f64] {
        &self.qd
    }

    /// Places the arm at rest at `q` [rad].
    pub fn reset(&mut self, q: &[f64]) -> Result<()> {
        check_vector("q", q, self.model.nq())?;
        self.q.copy_from_slice(q);
        self.qd.fill(0.0);
        Ok(())
    }

    /// One time step under joint torques `tau` [N·m] and, if given, external joint torques
    /// `tau_ext` [N·m] (e.g. Jᵀ·w of a push). A step that would leave a non-finite state is an
    /// error and leaves the state as it was.
    pub fn step(&mut self, tau: &[f64], tau_ext: Option<&[f64]>) -> Result<()> {
        let n = self.model.nq();
        check_vector("tau", tau, n)?;
        if let Some(ext) = tau_ext {
            check_vector("tau_ext", ext, n)?;
        }
        for j in 0..n {
            self.net[j] = tau[j] - self.damping[j] * self.qd[j] + tau_ext.map_or(0.0, |e| e[j]);
        }
        self.model.forward_dynamics(&self.q, &self.qd, &self.net, &mut self.data, &mut self.mass, &mut self.qdd)?;
        let dt = self.dt;
        let finite = (0..n).all(|j| {
            let v = self.qd[j] + dt * self.qdd[j];
            v.is_finite() && (self.q[j] + dt * v).is_finite()
        });
        if !finite {
            return Err(PhriError::Simulation {
                reason: format!("the arm's state became non-finite (q = {:?}, qd = {:?}, tau = {tau:?})", self.q, self.qd),
            });
        }
        for j in 0..n {
            self.qd[j] += dt * self.qdd[j];
            self.q[j] += dt * self.qd[j];
        }
        Ok(())
    }
}
