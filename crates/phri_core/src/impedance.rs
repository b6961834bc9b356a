//! The impedance control law for a 1 kHz loop (paper eqs. 5 and 6), with gravity compensation and
//! saturation to the effort limits. Construct once; every step writes into caller storage and
//! allocates nothing.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector};

use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::model::RobotModel;
use crate::wall::{VirtualWall, WallStatus};

/// A gain matrix: diagonal (one value per joint) or full n × n.
#[derive(Debug, Clone, PartialEq)]
pub enum Gain {
    Diagonal(Vec<f64>),
    Full(DMatrix<f64>),
}

impl Gain {
    fn check(&self, arg: &str, n: usize) -> Result<()> {
        match self {
            Gain::Diagonal(d) => {
                check_vector(arg, d, n)?;
                if let Some((i, v)) = d.iter().enumerate().find(|(_, v)| **v < 0.0) {
                    return Err(PhriError::invalid(arg, format!("[{i}] must be >= 0, got {v}")));
                }
            }
            Gain::Full(m) => {
                if m.shape() != (n, n) {
                    return Err(PhriError::shape(arg, format!("({n}, {n})"), format!("{:?}", m.shape())));
                }
                check_finite(arg, m.as_slice())?;
                // A gain matrix is symmetric positive semidefinite: the law then only stores or
                // dissipates energy (passivity); the asymmetric part would be silently a curl.
                let scale = m.amax().max(1e-300);
                if (m - m.transpose()).amax() > 1e-9 * scale {
                    return Err(PhriError::invalid(arg, "must be a symmetric matrix"));
                }
                let lowest = m.clone().symmetric_eigenvalues().min();
                if lowest < -1e-12 * scale {
                    return Err(PhriError::invalid(
                        arg,
                        format!("must be positive semidefinite, got an eigenvalue of {lowest:e}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// out = G·x
    #[inline]
    fn apply(&self, x: &DVector<f64>, out: &mut DVector<f64>) {
        match self {
            Gain::Diagonal(d) => out.iter_mut().zip(d).zip(x.iter()).for_each(|((o, g), v)| *o = g * v),
            Gain::Full(m) => out.gemv(1.0, m, x, 0.0),
        }
    }
}

/// Gains of the law. Defaults are `ImpedanceParams::jaco2_default()`.
#[derive(Debug, Clone)]
pub struct ImpedanceParams {
    /// Stiffness K_R [N·m/rad].
    pub stiffness: Gain,
    /// Damping B_R [N·m·s/rad].
    pub damping: Gain,
    /// Desired inertia M_R [kg·m²] for the full law (eq. 5); unused by eq. 6.
    pub inertia: Option<Gain>,
    /// Add g(q) from the model to eq. 6 (`torque`, `torque_implicit`), as a real arm needs to hold
    /// its own weight. The full law (eq. 5, `torque_full`) always includes g: feedback
    /// linearisation cancels the arm's whole dynamics.
    pub gravity_compensation: bool,
}

impl ImpedanceParams {
    /// Gains for the JACO2 holding the 0.3 kg cup, as compliant as the study's arm was: it ran in
    /// Kinova's admittance mode, and in the authors' published trajectories a person's push
    /// untilted the cup or lowered it by 20–30 cm within about a second, after which it drifted
    /// back over seconds. Soft springs with a time constant B/K of 2 s (1.5 s at joints 5 and 6,
    /// 1.7 s at the roll, stiffer than the rest so that a person's twist does not rock it) do that.
    /// Measured in the PyBullet scene (implicit law at 1 kHz): the arm tracks the study's plans
    /// within 0.46–0.50 cm at the hand with nobody touching it (the damping acts on the velocity
    /// error, so the arm does not lag), and a 20 N push down at the hand held for 1.5 s from the
    /// table task's start moves it by 42 cm (tests/test_sim.py bounds both).
    /// Stiffer arms: `robot.toml`'s `[impedance]` (the FR3's).
    pub fn jaco2_default() -> Self {
        ImpedanceParams {
            stiffness: Gain::Diagonal(vec![20.0, 30.0, 15.0, 15.0, 10.0, 10.0, 6.0]),
            damping: Gain::Diagonal(vec![40.0, 60.0, 30.0, 30.0, 15.0, 15.0, 10.0]),
            inertia: None,
            gravity_compensation: true,
        }
    }
}

/// What a step did beyond computing the torque.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControlStatus {
    /// Bit j is set when joint j was clipped to its effort limit.
    pub saturated: u64,
    /// What the virtual wall did (force 0 without a wall or when it did not act).
    pub wall: WallStatus,
}

impl ControlStatus {
    pub fn is_saturated(&self) -> bool {
        self.saturated != 0
    }
}

/// An impedance controller for one robot.
pub struct ImpedanceController {
    model: Arc<RobotModel>,
    data: RobotData,
    params: ImpedanceParams,
    effort_limits: Vec<f64>,
    /// M_R⁻¹, precomputed once (eq. 5).
    inertia_inv: Option<Gain>,
    error: DVector<f64>,
    error_dot: DVector<f64>,
    scratch: DVector<f64>,
    scratch2: DVector<f64>,
    qdd: Vec<f64>,
    /// M(q) + B·Δt for the implicit step (moved into the Cholesky and back, never reallocated).
    implicit_lhs: DMatrix<f64>,
    rhs: DVector<f64>,
    bias: Vec<f64>,
    /// The run-time wall around the furniture, if set.
    wall: Option<VirtualWall>,
}

impl ImpedanceController {
    pub fn new(model: Arc<RobotModel>, params: ImpedanceParams) -> Result<Self> {
        let n = model.nq();
        params.stiffness.check("stiffness", n)?;
        params.damping.check("damping", n)?;
        let inertia_inv = match &params.inertia {
            None => None,
            Some(g) => {
                g.check("inertia", n)?;
                Some(match g {
                    Gain::Diagonal(d) => {
                        if let Some((i, v)) = d.iter().enumerate().find(|(_, v)| !(1.0 / **v).is_finite() || **v <= 0.0) {
                            return Err(PhriError::invalid(
                                "inertia",
                                format!("[{i}] must be > 0 kg·m² (and not so small that its inverse overflows), got {v}"),
                            ));
                        }
                        Gain::Diagonal(d.iter().map(|v| 1.0 / v).collect())
                    }
                    Gain::Full(m) => Gain::Full(
                        m.clone()
                            .cholesky()
                            .ok_or_else(|| PhriError::invalid("inertia", "must be symmetric positive definite"))?
                            .inverse(),
                    ),
                })
            }
        };
        let effort_limits = model.effort_limits();
        Ok(ImpedanceController {
            data: model.data(),
            model,
            params,
            effort_limits,
            inertia_inv,
            error: DVector::zeros(n),
            error_dot: DVector::zeros(n),
            scratch: DVector::zeros(n),
            scratch2: DVector::zeros(n),
            qdd: vec![0.0; n],
            implicit_lhs: DMatrix::zeros(n, n),
            rhs: DVector::zeros(n),
            bias: vec![0.0; n],
            wall: None,
        })
    }

    /// Adds (or with None removes) a virtual wall: its torque is added to every law's output
    /// before saturation. A wall made for another robot (or collision model) is an error.
    pub fn set_wall(&mut self, wall: Option<VirtualWall>) -> Result<()> {
        if let Some(w) = &wall {
            w.check_robot(&self.model)?;
        }
        self.wall = wall;
        Ok(())
    }

    pub fn wall(&self) -> Option<&VirtualWall> {
        self.wall.as_ref()
    }

    pub fn params(&self) -> &ImpedanceParams {
        &self.params
    }

    pub fn model(&self) -> &Arc<RobotModel> {
        &self.model
    }

    /// Effort limits applied by saturation [N·m].
    pub fn effort_limits(&self) -> &[f64] {
        &self.effort_limits
    }

    fn errors(&mut self, q: &[f64], qd: &[f64], q_ref: &[f64], qd_ref: &[f64]) -> Result<()> {
        let n = self.model.nq();
        check_vector("q", q, n)?;
        check_vector("qd", qd, n)?;
        check_vector("q_ref", q_ref, n)?;
        check_vector("qd_ref", qd_ref, n)?;
        for j in 0..n {
            self.error[j] = q_ref[j] - q[j];
            self.error_dot[j] = qd_ref[j] - qd[j];
        }
        Ok(())
    }

    /// Clips `tau` to the effort limits. Finite inputs so large that the torque overflows are an
    /// error naming `args` (the inputs that scale it), never a NaN passed on to the motors.
    fn saturate(&mut self, args: &str, q: &[f64], qd: &[f64], tau: &mut [f64]) -> Result<ControlStatus> {
        let wall = match self.wall.as_mut() {
            Some(w) => w.add_torque(&self.model, q, qd, tau),
            None => WallStatus::default(),
        };
        if let Some(j) = tau.iter().position(|t| !t.is_finite()) {
            return Err(PhriError::invalid(args, format!("so large that the torque of joint {j} overflows (non-finite)")));
        }
        let mut status = ControlStatus { saturated: 0, wall };
        for (j, (t, lim)) in tau.iter_mut().zip(&self.effort_limits).enumerate() {
            if t.abs() > *lim {
                *t = t.clamp(-lim, *lim);
                status.saturated |= 1 << j.min(63);
            }
        }
        Ok(status)
    }

    /// Eq. 6 with gravity compensation: τ = g(q) + K_R(q_R − q) + B_R(q̇_R − q̇) [N·m], saturated.
    pub fn torque(&mut self, q: &[f64], qd: &[f64], q_ref: &[f64], qd_ref: &[f64], tau: &mut [f64]) -> Result<ControlStatus> {
        self.errors(q, qd, q_ref, qd_ref)?;
        check_vector_len("tau", tau, self.model.nq())?;
        if self.params.gravity_compensation {
            self.model.forward_kinematics_unchecked(q, &mut self.data);
            self.model.gravity_after_fk(&mut self.data, tau);
        } else {
            tau.fill(0.0);
        }
        self.params.stiffness.apply(&self.error, &mut self.scratch);
        self.params.damping.apply(&self.error_dot, &mut self.scratch2);
        for j in 0..tau.len() {
            tau[j] += self.scratch[j] + self.scratch2[j];
        }
        self.saturate("q, qd, q_ref, qd_ref and the gains are", q, qd, tau)
    }

    /// Eq. 6 discretised implicitly for a simulator that integrates explicitly with step `dt` [s]
    /// (the "stable PD" of Tan, Liu and Turk, 2011): the spring acts on the position predicted at
    /// the end of the step and the damper on the predicted velocity,
    /// τ = g + K(q_R − q − q̇Δt) + B(q̇_R − q̇ − q̈Δt), with q̈ from the model,
    /// (M + BΔt) q̈ = K(q_R − q − q̇Δt) + B(q̇_R − q̇) − C(q, q̇)q̇.
    /// In continuous time it is the same law; at 1 kHz it stays stable where the explicit law goes
    /// unstable: near singular poses, modes of tiny inertia (a real arm's rotor inertia prevents
    /// them; a simulated arm without it does not).
    pub fn torque_implicit(
        &mut self,
        q: &[f64],
        qd: &[f64],
        q_ref: &[f64],
        qd_ref: &[f64],
        dt: f64,
        tau: &mut [f64],
    ) -> Result<ControlStatus> {
        let n = self.model.nq();
        if !(dt.is_finite() && dt > 0.0) {
            return Err(PhriError::invalid("dt", format!("must be a finite time step > 0 s, got {dt}")));
        }
        self.errors(q, qd, q_ref, qd_ref)?;
        check_vector_len("tau", tau, n)?;
        for j in 0..n {
            self.error[j] -= qd[j] * dt; // predicted position error
        }
        self.params.stiffness.apply(&self.error, &mut self.scratch); // K·e_pred
        self.params.damping.apply(&self.error_dot, &mut self.scratch2); // B·ė
                                                                        // C(q, q̇)q̇ + g(q) and g(q), then M(q) (all after one forward kinematics).
        self.model.nonlinear_effects(q, qd, &mut self.data, &mut self.bias)?;
        if self.params.gravity_compensation {
            self.model.gravity_after_fk(&mut self.data, tau);
        } else {
            tau.fill(0.0); // gravity then acts on the arm, in the predicted q̈ as in the physics
        }
        let mut lhs = std::mem::take(&mut self.implicit_lhs);
        self.model.mass_matrix_after_fk(&mut self.data, &mut lhs);
        match &self.params.damping {
            Gain::Diagonal(d) => (0..n).for_each(|j| lhs[(j, j)] += d[j] * dt),
            Gain::Full(b) => lhs += b * dt,
        }
        // Spring and damper torques, kept for τ: K·e_pred + B·ė.
        for j in 0..n {
            self.scratch[j] += self.scratch2[j];
            // (M + BΔt) q̈ = K e_pred + B ė − (h − g)
            self.rhs[j] = self.scratch[j] - (self.bias[j] - tau[j]);
        }
        let Some(chol) = lhs.cholesky() else {
            self.implicit_lhs = DMatrix::zeros(n, n);
            return Err(PhriError::invalid("q", "gives a mass matrix that is not positive definite"));
        };
        chol.solve_mut(&mut self.rhs);
        self.implicit_lhs = chol.unpack();
        // τ = g + K e_pred + B ė − B q̈ Δt
        self.rhs.iter_mut().for_each(|a| *a *= -dt);
        self.params.damping.apply(&self.rhs, &mut self.scratch2);
        for j in 0..n {
            tau[j] += self.scratch[j] + self.scratch2[j];
        }
        self.saturate("q, qd, q_ref, qd_ref, dt and the gains are", q, qd, tau)
    }

    /// Eq. 5 by feedback linearisation: commands the closed loop
    /// M_R(q̈ − q̈_R) + B_R(q̇ − q̇_R) + K_R(q − q_R) = u_H, i.e. q̈* = q̈_R + M_R⁻¹(u_H + K_R e + B_R ė)
    /// and τ = M(q)q̈* + C(q, q̇)q̇ + g(q) − u_H, with u_H the measured human torque [N·m].
    #[allow(clippy::too_many_arguments)]
    pub fn torque_full(
        &mut self,
        q: &[f64],
        qd: &[f64],
        q_ref: &[f64],
        qd_ref: &[f64],
        qdd_ref: &[f64],
        u_h: &[f64],
        tau: &mut [f64],
    ) -> Result<ControlStatus> {
        let n = self.model.nq();
        self.errors(q, qd, q_ref, qd_ref)?;
        check_vector("qdd_ref", qdd_ref, n)?;
        check_vector("u_h", u_h, n)?;
        check_vector_len("tau", tau, n)?;
        let Some(inertia_inv) = &self.inertia_inv else {
            return Err(PhriError::invalid("inertia", "must be set to use the full impedance law (eq. 5)"));
        };
        self.params.stiffness.apply(&self.error, &mut self.scratch);
        self.params.damping.apply(&self.error_dot, &mut self.scratch2);
        for j in 0..n {
            self.scratch2[j] += self.scratch[j] + u_h[j];
        }
        inertia_inv.apply(&self.scratch2, &mut self.scratch);
        for j in 0..n {
            self.qdd[j] = qdd_ref[j] + self.scratch[j];
        }
        self.model.forward_kinematics_unchecked(q, &mut self.data);
        self.model.rnea_after_fk(qd, Some(&self.qdd), true, &mut self.data, tau);
        for j in 0..n {
            tau[j] -= u_h[j];
        }
        self.saturate("q, qd, q_ref, qd_ref, qdd_ref, u_h and the gains are", q, qd, tau)
    }
}

fn check_vector_len(arg: &str, out: &[f64], n: usize) -> Result<()> {
    if out.len() != n {
        return Err(PhriError::shape(arg, format!("({n},)"), format!("({},)", out.len())));
    }
    Ok(())
}
