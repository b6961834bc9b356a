//! Rigid-body dynamics of the chain, all in base-frame coordinates: recursive Newton–Euler inverse
//! dynamics, gravity torques through composite bodies, and the joint-space mass matrix by the
//! composite-rigid-body algorithm. The base is fixed; gravity is `model.gravity`.

use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::data::RobotData;
use crate::error::{check_vector, PhriError, Result};
use crate::model::{JointKind, RobotModel};

impl RobotModel {
    /// Joint efforts [N·m or N] that produce accelerations `qdd` at state (`q`, `qd`) under gravity:
    /// τ = M(q)q̈ + C(q, q̇)q̇ + g(q). Writes into `tau`.
    pub fn inverse_dynamics(&self, q: &[f64], qd: &[f64], qdd: &[f64], data: &mut RobotData, tau: &mut [f64]) -> Result<()> {
        let n = self.nq();
        check_vector("q", q, n)?;
        check_vector("qd", qd, n)?;
        check_vector("qdd", qdd, n)?;
        check_len("tau", tau, n)?;
        self.forward_kinematics_unchecked(q, data);
        self.rnea_after_fk(qd, Some(qdd), true, data, tau);
        check_result("qd, qdd", tau)
    }

    /// C(q, q̇)q̇ + g(q) [N·m]: the efforts that hold the arm at zero acceleration.
    pub fn nonlinear_effects(&self, q: &[f64], qd: &[f64], data: &mut RobotData, tau: &mut [f64]) -> Result<()> {
        let n = self.nq();
        check_vector("q", q, n)?;
        check_vector("qd", qd, n)?;
        check_len("tau", tau, n)?;
        self.forward_kinematics_unchecked(q, data);
        self.rnea_after_fk(qd, None, true, data, tau);
        check_result("qd", tau)
    }

    /// Forward dynamics q̈ = M(q)⁻¹(τ − C(q, q̇)q̇ − g(q)) [rad/s²] for joint efforts `tau` [N·m],
    /// into `qdd`: the composite-rigid-body mass matrix (into the work matrix `mass`, n × n) and its
    /// Cholesky factor, with the Newton–Euler bias. The step of a simulator integrating the arm
    /// (PyBullet's is semi-implicit Euler on the same equation). Allocates nothing.
    pub fn forward_dynamics(
        &self,
        q: &[f64],
        qd: &[f64],
        tau: &[f64],
        data: &mut RobotData,
        mass: &mut DMatrix<f64>,
        qdd: &mut [f64],
    ) -> Result<()> {
        let n = self.nq();
        check_vector("q", q, n)?;
        check_vector("qd", qd, n)?;
        check_vector("tau", tau, n)?;
        check_len("qdd", qdd, n)?;
        check_square("mass", mass, n)?;
        self.forward_kinematics_unchecked(q, data);
        self.rnea_after_fk(qd, None, true, data, qdd); // the bias C(q, q̇)q̇ + g(q)
        check_result("qd", qdd)?;
        for (a, t) in qdd.iter_mut().zip(tau) {
            *a = t - *a;
        }
        self.mass_matrix_after_fk(data, mass);
        // Cholesky in place: nalgebra's factor owns its matrix, so the work matrix is moved in and back.
        let work = std::mem::replace(mass, DMatrix::zeros(0, 0));
        let Some(factor) = work.cholesky() else {
            *mass = DMatrix::zeros(n, n); // the factor took the work matrix: give the caller one back
            return Err(PhriError::invalid(
                "q",
                "gives a mass matrix that is not positive definite (check the model's inertias)",
            ));
        };
        let mut rhs = nalgebra::DVectorViewMut::from_slice(qdd, n);
        factor.solve_mut(&mut rhs);
        *mass = factor.unpack();
        check_result("tau", qdd)
    }

    /// Coriolis and centrifugal efforts C(q, q̇)q̇ [N·m], without gravity.
    pub fn coriolis(&self, q: &[f64], qd: &[f64], data: &mut RobotData, tau: &mut [f64]) -> Result<()> {
        let n = self.nq();
        check_vector("q", q, n)?;
        check_vector("qd", qd, n)?;
        check_len("tau", tau, n)?;
        self.forward_kinematics_unchecked(q, data);
        self.rnea_after_fk(qd, None, false, data, tau);
        check_result("qd", tau)
    }

    /// Gravity efforts g(q) [N·m]: what the motors must apply to hold the arm still.
    pub fn gravity_torques(&self, q: &[f64], data: &mut RobotData, tau: &mut [f64]) -> Result<()> {
        check_vector("q", q, self.nq())?;
        check_len("tau", tau, self.nq())?;
        self.forward_kinematics_unchecked(q, data);
        self.gravity_after_fk(data, tau);
        check_result("the model's masses", tau)
    }

    /// Gravity efforts for the configuration of the last forward kinematics. O(n) through the
    /// composite centre of mass of each subchain; the per-tick path of gravity compensation.
    #[inline]
    pub fn gravity_after_fk(&self, data: &mut RobotData, tau: &mut [f64]) {
        let n = self.nq();
        let mut mass = 0.0;
        let mut first_moment = Vector3::zeros(); // Σ m_k c_k over the subchain [kg·m]
        for i in (0..n).rev() {
            let b = &self.bodies[i + 1];
            let t = &data.base_t_body[i + 1];
            mass += b.mass;
            first_moment += (t.rotation * b.com + t.translation.vector) * b.mass;
            let weight = -self.gravity * mass; // force the joint must support [N]
            tau[i] = match self.joints[i].kind {
                JointKind::Revolute => {
                    let arm = first_moment - t.translation.vector * mass; // mass·(com − p_i)
                    data.axis[i].dot(&arm.cross(&(-self.gravity)))
                }
                JointKind::Prismatic => data.axis[i].dot(&weight),
            };
        }
    }

    /// Recursive Newton–Euler after forward kinematics. `qdd = None` means zero acceleration.
    pub(crate) fn rnea_after_fk(
        &self,
        qd: &[f64],
        qdd: Option<&[f64]>,
        with_gravity: bool,
        data: &mut RobotData,
        tau: &mut [f64],
    ) {
        let n = self.nq();
        data.omega[0] = Vector3::zeros();
        data.omega_dot[0] = Vector3::zeros();
        // Accelerating the base upwards by −g is the same as gravity acting on every body.
        data.acc[0] = if with_gravity { -self.gravity } else { Vector3::zeros() };
        for i in 0..n {
            let z = data.axis[i];
            let qdd_i = qdd.map_or(0.0, |a| a[i]);
            let (w0, dw0, a0) = (data.omega[i], data.omega_dot[i], data.acc[i]);
            let r = data.base_t_body[i + 1].translation.vector - data.base_t_body[i].translation.vector;
            let mut a = a0 + dw0.cross(&r) + w0.cross(&w0.cross(&r));
            let (w, dw) = match self.joints[i].kind {
                JointKind::Revolute => (w0 + z * qd[i], dw0 + z * qdd_i + w0.cross(&z) * qd[i]),
                JointKind::Prismatic => {
                    a += z * qdd_i + w0.cross(&z) * (2.0 * qd[i]);
                    (w0, dw0)
                }
            };
            data.omega[i + 1] = w;
            data.omega_dot[i + 1] = dw;
            data.acc[i + 1] = a;
        }
        let mut f_next = Vector3::zeros();
        let mut n_next = Vector3::zeros();
        for i in (0..n).rev() {
            let b = &self.bodies[i + 1];
            let t = &data.base_t_body[i + 1];
            let rot = t.rotation.matrix();
            let c = rot * b.com; // com relative to the body origin, base axes
            let inertia = rot * b.inertia * rot.transpose();
            let (w, dw) = (data.omega[i + 1], data.omega_dot[i + 1]);
            let a_com = data.acc[i + 1] + dw.cross(&c) + w.cross(&w.cross(&c));
            let force = a_com * b.mass;
            let torque = inertia * dw + w.cross(&(inertia * w));
            // Moments about this body's origin; the child's origin is `d` away.
            let d = if i + 1 < n { data.base_t_body[i + 2].translation.vector - t.translation.vector } else { Vector3::zeros() };
            let f = force + f_next;
            let m = torque + c.cross(&force) + n_next + d.cross(&f_next);
            tau[i] = match self.joints[i].kind {
                JointKind::Revolute => data.axis[i].dot(&m),
                JointKind::Prismatic => data.axis[i].dot(&f),
            };
            data.force[i + 1] = f;
            data.moment[i + 1] = m;
            f_next = f;
            n_next = m;
        }
    }

    /// Joint-space mass matrix M(q) [kg·m² or kg], symmetric positive definite, into `mass`.
    pub fn mass_matrix(&self, q: &[f64], data: &mut RobotData, mass: &mut DMatrix<f64>) -> Result<()> {
        let n = self.nq();
        check_vector("q", q, n)?;
        check_square("mass", mass, n)?;
        self.forward_kinematics_unchecked(q, data);
        self.mass_matrix_after_fk(data, mass);
        Ok(())
    }

    /// Composite-rigid-body algorithm in base coordinates, after forward kinematics.
    pub fn mass_matrix_after_fk(&self, data: &mut RobotData, mass: &mut DMatrix<f64>) {
        let n = self.nq();
        // Composite j = bodies j..n, accumulated from the tip (index n+1 is the empty body).
        data.comp_mass[n + 1] = 0.0;
        data.comp_com[n + 1] = Vector3::zeros();
        data.comp_inertia[n + 1] = Matrix3::zeros();
        for j in (1..=n).rev() {
            let b = &self.bodies[j];
            let t = &data.base_t_body[j];
            let rot = t.rotation.matrix();
            let com = t.rotation * b.com + t.translation.vector;
            let inertia = rot * b.inertia * rot.transpose();
            let body = crate::model::BodyInertia { mass: b.mass, com, inertia };
            let rest = crate::model::BodyInertia {
                mass: data.comp_mass[j + 1],
                com: data.comp_com[j + 1],
                inertia: data.comp_inertia[j + 1],
            };
            let c = body.combine(&rest);
            data.comp_mass[j] = c.mass;
            data.comp_com[j] = c.com;
            data.comp_inertia[j] = c.inertia;
        }
        for j in 0..n {
            // Momentum of composite j+1 moving with unit velocity of joint j.
            let (m, c, inertia) = (data.comp_mass[j + 1], data.comp_com[j + 1], data.comp_inertia[j + 1]);
            let zj = data.axis[j];
            let pj = data.base_t_body[j + 1].translation.vector;
            let (h, l_com) = match self.joints[j].kind {
                JointKind::Revolute => (zj.cross(&(c - pj)) * m, inertia * zj),
                JointKind::Prismatic => (zj * m, Vector3::zeros()),
            };
            for i in 0..=j {
                let zi = data.axis[i];
                let v = match self.joints[i].kind {
                    JointKind::Revolute => zi.dot(&(l_com + (c - data.base_t_body[i + 1].translation.vector).cross(&h))),
                    JointKind::Prismatic => zi.dot(&h),
                };
                mass[(i, j)] = v;
                mass[(j, i)] = v;
            }
        }
    }
}

/// Finite inputs so large that the products overflow (e.g. q̇ = 1e200) must not pass as a result;
/// `args` names the inputs that scale the efforts.
fn check_result(args: &str, tau: &[f64]) -> Result<()> {
    if tau.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(PhriError::invalid(args, "so large that the efforts overflow (non-finite result)"))
    }
}

fn check_len(arg: &str, out: &[f64], n: usize) -> Result<()> {
    if out.len() != n {
        return Err(PhriError::shape(arg, format!("({n},)"), format!("({},)", out.len())));
    }
    Ok(())
}

fn check_square(arg: &str, out: &DMatrix<f64>, n: usize) -> Result<()> {
    if out.shape() != (n, n) {
        return Err(PhriError::shape(arg, format!("({n}, {n})"), format!("{:?}", out.shape())));
    }
    Ok(())
}
