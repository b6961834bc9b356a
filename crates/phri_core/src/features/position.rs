//! Features of the feature frame's position at each waypoint: its height (the table task) and its
//! distance from the robot's base.

use nalgebra::Vector3;

use super::{Feature, Segment, SegmentGrad};

/// Height of the feature frame's origin above `height` [m] at q_i (the original uses raw z: height 0).
#[derive(Debug, Clone, Default)]
pub struct Table {
    pub height: f64,
}

impl Feature for Table {
    fn name(&self) -> &str {
        "table"
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let value = seg.point(1.0).position.z - self.height;
        if let Some(g) = grad {
            let jac = seg.jacobian(1.0);
            for j in 0..g.this.len() {
                g.this[j] += g.scale * jac[(2, j)];
            }
            if let Some(h) = g.hessian {
                if h.kinematic() {
                    seg.add_position_curvature(1.0, &Vector3::z(), g.scale, h);
                }
            }
        }
        value
    }
}

/// Distance of the feature frame's origin from the base origin ‖p‖ [m] at q_i.
#[derive(Debug, Clone, Default)]
pub struct Origin;

impl Feature for Origin {
    fn name(&self) -> &str {
        "origin"
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let p = seg.point(1.0).position;
        let value = p.norm();
        if let Some(g) = grad {
            if value > 0.0 {
                let u = p / value;
                let jac = seg.jacobian(1.0);
                let a = |j: usize| u.x * jac[(0, j)] + u.y * jac[(1, j)] + u.z * jac[(2, j)];
                for j in 0..g.this.len() {
                    g.this[j] += g.scale * a(j);
                }
                if let Some(h) = g.hessian {
                    // ∂²‖p‖ = Jᵀ(I − u·uᵀ)J/‖p‖ + Σ_c u_c ∂²p_c.
                    for c in 0..3 {
                        h.add_outer(1.0, g.scale / value, |j| jac[(c, j)]);
                    }
                    h.add_outer(1.0, -g.scale / value, a);
                    if h.kinematic() {
                        seg.add_position_curvature(1.0, &u, g.scale, h);
                    }
                }
            }
        }
        value
    }
}
