//! Rigid transforms and the ids of a robot's frames: the vocabulary the robot model and its
//! collision bodies share (the model re-exports both).

use nalgebra::{IsometryMatrix3, Rotation3, Translation3};

/// Rigid transform with a rotation matrix (cheap to apply and to read rotation entries from).
pub type Transform = IsometryMatrix3<f64>;

/// Index of a frame in [`crate::RobotModel::frames`], obtained once by name with [`crate::RobotModel::frame_id`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FrameId(pub usize);

/// A URDF origin (xyz, rpy) as a transform.
pub(crate) fn urdf_pose(p: &urdf_rs::Pose) -> Transform {
    let rot = snap_axis_permutation(Rotation3::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]));
    IsometryMatrix3::from_parts(Translation3::new(p.xyz[0], p.xyz[1], p.xyz[2]), rot)
}

/// A rotation within 10⁻¹⁵ per entry of a signed permutation (rpy angles that are multiples of
/// π/2, as in most robot descriptions) becomes exactly that permutation: cos(π/2) is 6·10⁻¹⁷ in
/// floating point, and exact zeros let forward kinematics skip the product (see `AxisPermutation`).
fn snap_axis_permutation(r: Rotation3<f64>) -> Rotation3<f64> {
    let near = |v: f64| {
        if v.abs() < 1e-15 {
            Some(0.0)
        } else if (v.abs() - 1.0).abs() < 1e-15 {
            Some(v.signum())
        } else {
            None
        }
    };
    let mut m = *r.matrix();
    for v in m.iter_mut() {
        match near(*v) {
            Some(s) => *v = s,
            None => return r,
        }
    }
    Rotation3::from_matrix_unchecked(m)
}
