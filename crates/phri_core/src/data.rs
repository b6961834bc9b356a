//! Mutable scratch for a [`RobotModel`]: everything a kinematics or dynamics call writes, allocated
//! once so that repeated calls allocate nothing (the model/data split of Pinocchio and MuJoCo).

use nalgebra::{Matrix3, Vector3};

use crate::model::{RobotModel, Transform};

/// Per-call workspace for one [`RobotModel`]; create it with [`RobotModel::data`].
#[derive(Debug, Clone)]
pub struct RobotData {
    /// Pose of each body in the base frame after the last forward kinematics (0 = base).
    pub base_t_body: Vec<Transform>,
    /// Motion axis of each joint in the base frame (unit).
    pub axis: Vec<Vector3<f64>>,
    // Recursive Newton–Euler scratch, in the base frame, per body.
    pub(crate) omega: Vec<Vector3<f64>>,
    pub(crate) omega_dot: Vec<Vector3<f64>>,
    pub(crate) acc: Vec<Vector3<f64>>,
    pub(crate) force: Vec<Vector3<f64>>,
    pub(crate) moment: Vec<Vector3<f64>>,
    // Composite bodies (body i and everything after it), base frame.
    pub(crate) comp_mass: Vec<f64>,
    pub(crate) comp_com: Vec<Vector3<f64>>,
    pub(crate) comp_inertia: Vec<Matrix3<f64>>,
}

impl RobotModel {
    /// A fresh workspace sized for this model.
    pub fn data(&self) -> RobotData {
        let nb = self.nq() + 1;
        let z = Vector3::zeros();
        RobotData {
            base_t_body: vec![Transform::identity(); nb],
            axis: vec![z; self.nq()],
            omega: vec![z; nb],
            omega_dot: vec![z; nb],
            acc: vec![z; nb],
            force: vec![z; nb],
            moment: vec![z; nb],
            comp_mass: vec![0.0; nb + 1],
            comp_com: vec![z; nb + 1],
            comp_inertia: vec![Matrix3::zeros(); nb + 1],
        }
    }
}
