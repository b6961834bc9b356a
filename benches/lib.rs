//! Shared fixtures for the criterion benchmarks.

use phri_core::RobotModel;

/// The shipped JACO2 description (the same file the Python package loads).
pub const JACO2_URDF: &str = include_str!("../python/phri/robots/jaco2/j2s7s300.urdf");

/// The JACO2 chain from `root` to the tool point.
pub fn jaco2() -> RobotModel {
    RobotModel::from_urdf_str(JACO2_URDF, Some("root"), Some("j2s7s300_end_effector")).expect("shipped URDF parses")
}

/// Kinova degrees to radians.
pub fn deg(q: [f64; 7]) -> [f64; 7] {
    q.map(f64::to_radians)
}

/// The study's place_lower pose [rad].
pub fn place_lower() -> [f64; 7] {
    deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
}
