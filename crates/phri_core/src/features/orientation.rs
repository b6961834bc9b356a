//! Features of the feature frame's orientation at each waypoint: the cup's tilt (the coffee task).

use nalgebra::Vector3;

use super::smoothing::{huber, huber_curvature};
use super::{Feature, Segment, SegmentGrad};

/// How the cup's tilt is measured. The cup's axis is the feature frame's x axis, x = R[:, 0].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CoffeeForm {
    /// |R₀₀| + |R₁₀|: the horizontal part of x, 0 when upright (the original); subgradient 0 at 0.
    Horizontal,
    /// 1 − x·ẑ: 0 upright, 2 upside down (the later variant); smooth.
    Dot,
}

/// Cup tilt at q_i.
#[derive(Debug, Clone)]
pub struct Coffee {
    pub form: CoffeeForm,
}

impl Feature for Coffee {
    fn name(&self) -> &str {
        match self.form {
            CoffeeForm::Horizontal => "coffee",
            CoffeeForm::Dot => "coffee_dot",
        }
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let x: Vector3<f64> = seg.point(1.0).rotation.column(0).into();
        let delta = seg.smoothing;
        let (value, weights) = match self.form {
            CoffeeForm::Horizontal => {
                let ((a, da), (b, db)) = (huber(x.x, delta), huber(x.y, delta));
                (a + b, Vector3::new(da, db, 0.0))
            }
            CoffeeForm::Dot => (1.0 - x.z, Vector3::new(0.0, 0.0, -1.0)),
        };
        if let Some(g) = grad {
            // ∂x/∂q_j = ω_j × x, with ω_j the angular rows of the Jacobian.
            let jac = seg.jacobian(1.0);
            let dx = |j: usize| Vector3::new(jac[(3, j)], jac[(4, j)], jac[(5, j)]).cross(&x);
            for j in 0..g.this.len() {
                g.this[j] += g.scale * weights.dot(&dx(j));
            }
            if let Some(h) = g.hessian {
                if self.form == CoffeeForm::Horizontal {
                    // Huber's curvature 1/δ inside its quadratic zone (Gauss–Newton term).
                    for c in 0..2 {
                        let k = huber_curvature(x[c], delta);
                        if k > 0.0 {
                            h.add_outer(1.0, g.scale * k, |j| dx(j)[c]);
                        }
                    }
                }
                if h.kinematic() {
                    seg.add_axis_curvature(1.0, 0, &weights, g.scale, h);
                }
            }
        }
        value
    }
}
