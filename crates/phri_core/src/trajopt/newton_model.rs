//! What one evaluation of the cost hands the Newton step: the Hessian of the cost's smooth part,
//! the active penalties' gradient, and the kinked terms it models piecewise.

use super::block_tridiagonal::BlockTridiagonal;
use crate::features::Pieces;

/// Second-order data of one trajectory for the Newton model.
#[derive(Debug, Clone)]
pub(super) struct Model {
    /// Hessian of the smooth part: features, plus the penalties' curvature terms.
    pub(super) hess: BlockTridiagonal,
    /// The share of the gradient of the pieces that are on (N × n).
    pub(super) pen_grad: Vec<f64>,
    /// Kinked terms kept out of `hess` and modelled piecewise: every clearance (on or off) and the
    /// features' inactive hinge samples near their kink.
    pub(super) pieces: Pieces,
    /// `hess` includes the kinematics' second derivatives (`KinematicCurvature`).
    pub(super) exact: bool,
}

impl Model {
    pub(super) fn new(n: usize, waypoints: usize) -> Self {
        Model {
            hess: BlockTridiagonal::new(n, waypoints),
            pen_grad: vec![0.0; waypoints * n],
            pieces: Pieces::new(n),
            exact: false,
        }
    }
}
