//! Forward kinematics, frame poses and world-aligned frame Jacobians.

use nalgebra::{Matrix6xX, Rotation3, Translation3, Vector3};

use crate::data::RobotData;
use crate::error::{check_vector, PhriError, Result};
use crate::model::{FrameId, JointKind, RobotModel, Transform};

/// Motion of one joint at position q: rotation by q [rad] or translation by q [m] along `axis`.
#[inline]
fn joint_motion(kind: JointKind, axis: &Vector3<f64>, q: f64) -> Transform {
    match kind {
        JointKind::Revolute => {
            // Rodrigues' formula; cheaper than going through a quaternion.
            let (s, c) = q.sin_cos();
            let (x, y, z) = (axis.x, axis.y, axis.z);
            let t = 1.0 - c;
            let m = nalgebra::Matrix3::new(
                t * x * x + c,
                t * x * y - s * z,
                t * x * z + s * y,
                t * x * y + s * z,
                t * y * y + c,
                t * y * z - s * x,
                t * x * z - s * y,
                t * y * z + s * x,
                t * z * z + c,
            );
            Transform::from_parts(Translation3::identity(), Rotation3::from_matrix_unchecked(m))
        }
        JointKind::Prismatic => Transform::from_parts(Translation3::from(axis * q), Rotation3::identity()),
    }
}

impl RobotModel {
    /// Computes the pose of every body for joint positions `q` [rad or m], into `data`.
    pub fn forward_kinematics(&self, q: &[f64], data: &mut RobotData) -> Result<()> {
        check_vector("q", q, self.nq())?;
        self.forward_kinematics_unchecked(q, data);
        Ok(())
    }

    /// [`forward_kinematics`](Self::forward_kinematics) for a `q` already known to have length
    /// `nq()` (for inner loops that validated once).
    #[inline]
    pub fn forward_kinematics_unchecked(&self, q: &[f64], data: &mut RobotData) {
        self.forward_kinematics_with(q, |i| q[i].sin_cos(), data);
    }

    /// Forward kinematics with (sin q_i, cos q_i) of the revolute joints about their z axis given by
    /// `sin_cos(i)` (for callers that have them cheaper than libm, e.g. along a segment).
    #[inline(always)]
    pub(crate) fn forward_kinematics_with(&self, q: &[f64], sin_cos: impl Fn(usize) -> (f64, f64), data: &mut RobotData) {
        debug_assert_eq!(q.len(), self.nq());
        for (i, joint) in self.joints.iter().enumerate() {
            let axis = joint.axis.into_inner();
            if joint.kind == JointKind::Revolute && axis.x == 0.0 && axis.y == 0.0 {
                // Rotation about ±z of the joint frame (every JACO2 joint): rotate two columns of the
                // joint frame's rotation instead of multiplying by a general Rodrigues matrix
                // (measured: forward kinematics of the JACO2 about 1.5× faster).
                let body = &data.base_t_body[i];
                let r = match &joint.permutation {
                    Some(p) => {
                        let b = body.rotation.matrix();
                        nalgebra::Matrix3::from_columns(&[
                            b.column(p.axis[0]) * p.sign[0],
                            b.column(p.axis[1]) * p.sign[1],
                            b.column(p.axis[2]) * p.sign[2],
                        ])
                    }
                    None => body.rotation.matrix() * joint.parent_t_joint.rotation.matrix(),
                };
                let t = body.translation.vector + body.rotation * joint.parent_t_joint.translation.vector;
                let (s, c) = sin_cos(i);
                let s = s * axis.z;
                let (c0, c1, c2) = (r.column(0), r.column(1), r.column(2));
                let m = nalgebra::Matrix3::from_columns(&[c0 * c + c1 * s, c1 * c - c0 * s, c2.into_owned()]);
                data.axis[i] = c2 * axis.z;
                data.base_t_body[i + 1] = Transform::from_parts(Translation3::from(t), Rotation3::from_matrix_unchecked(m));
            } else {
                let parent = data.base_t_body[i] * joint.parent_t_joint;
                data.axis[i] = parent.rotation * axis;
                data.base_t_body[i + 1] = parent * joint_motion(joint.kind, &joint.axis, q[i]);
            }
        }
    }

    /// Pose of `frame` in the base frame, after [`forward_kinematics`](Self::forward_kinematics).
    #[inline]
    pub fn frame_pose(&self, frame: FrameId, data: &RobotData) -> Transform {
        let f = &self.frames[frame.0];
        data.base_t_body[f.body] * f.body_t_frame
    }

    /// The 6×nq Jacobian of `frame`'s origin, rows (linear [m/s], angular [rad/s]) per unit joint
    /// velocity, expressed in base-frame axes ("local world aligned"), after forward kinematics.
    pub fn frame_jacobian(&self, frame: FrameId, data: &RobotData, jacobian: &mut Matrix6xX<f64>) -> Result<()> {
        if jacobian.ncols() != self.nq() {
            return Err(PhriError::shape("jacobian", format!("(6, {})", self.nq()), format!("(6, {})", jacobian.ncols())));
        }
        self.frame_jacobian_unchecked(frame, data, jacobian);
        Ok(())
    }

    #[inline]
    pub(crate) fn frame_jacobian_unchecked(&self, frame: FrameId, data: &RobotData, jacobian: &mut Matrix6xX<f64>) {
        let body = self.frames[frame.0].body;
        let p = self.frame_pose(frame, data).translation.vector;
        for (i, joint) in self.joints.iter().enumerate() {
            let mut col = jacobian.column_mut(i);
            if i >= body {
                col.fill(0.0);
                continue;
            }
            let z = data.axis[i];
            match joint.kind {
                JointKind::Revolute => {
                    let v = z.cross(&(p - data.base_t_body[i + 1].translation.vector));
                    col.fixed_rows_mut::<3>(0).copy_from(&v);
                    col.fixed_rows_mut::<3>(3).copy_from(&z);
                }
                JointKind::Prismatic => {
                    col.fixed_rows_mut::<3>(0).copy_from(&z);
                    col.fixed_rows_mut::<3>(3).fill(0.0);
                }
            }
        }
    }

    /// Checks that `q` lies within the position limits, naming the first joint outside them.
    pub fn check_within_limits(&self, arg: &str, q: &[f64]) -> Result<()> {
        check_vector(arg, q, self.nq())?;
        for (j, (joint, &v)) in self.joints.iter().zip(q).enumerate() {
            if v < joint.lower || v > joint.upper {
                return Err(PhriError::invalid(
                    arg,
                    format!("has [{j}] = {v}, outside the limits [{}, {}] of joint '{}'", joint.lower, joint.upper, joint.name),
                ));
            }
        }
        Ok(())
    }
}

/// Σ_c g_c·∂²p_c/∂q_a∂q_b for a frame origin p, written into `out` (n × n row-major) from the frame's
/// world-aligned Jacobian (see [`RobotModel::frame_jacobian`]): the curvature of a cost whose
/// gradient in p is g [per m]. For a ≤ b, ∂²p/∂q_a∂q_b = ω_a × v_b (ω the angular rows — the joint
/// axes, 0 for prismatic joints — and v the linear rows), so the entry is (g × ω_a)·v_b.
pub fn position_hessian(jacobian: &Matrix6xX<f64>, g: &Vector3<f64>, out: &mut [f64]) {
    let n = jacobian.ncols();
    for a in 0..n {
        let c = g.cross(&Vector3::new(jacobian[(3, a)], jacobian[(4, a)], jacobian[(5, a)]));
        for b in a..n {
            let v = c.x * jacobian[(0, b)] + c.y * jacobian[(1, b)] + c.z * jacobian[(2, b)];
            out[a * n + b] = v;
            out[b * n + a] = v;
        }
    }
}

/// Σ_c w_c·∂²x_c/∂q_a∂q_b for a unit vector x fixed in a frame (e.g. a column of its rotation), into
/// `out` (n × n row-major), from the frame's world-aligned Jacobian: for a ≤ b,
/// ∂²x/∂q_a∂q_b = ω_a × (ω_b × x), so the entry is (w × ω_a)·(ω_b × x).
pub fn direction_hessian(jacobian: &Matrix6xX<f64>, x: &Vector3<f64>, w: &Vector3<f64>, out: &mut [f64]) {
    let n = jacobian.ncols();
    let omega = |j: usize| Vector3::new(jacobian[(3, j)], jacobian[(4, j)], jacobian[(5, j)]);
    for a in 0..n {
        let c = w.cross(&omega(a));
        for b in a..n {
            let v = c.dot(&omega(b).cross(x));
            out[a * n + b] = v;
            out[b * n + a] = v;
        }
    }
}
