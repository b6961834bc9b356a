//! The efficiency feature: path length in joint space, the term every task of the paper weighs
//! with 1 (Bajcsy et al. 2017, Sec. 4).

use super::{Feature, Segment, SegmentGrad};

/// Path length in joint space: φ = ‖q_i − q_{i-1}‖² [rad²].
#[derive(Debug, Clone, Copy, Default)]
pub struct Efficiency;

impl Feature for Efficiency {
    fn name(&self) -> &str {
        "efficiency"
    }
    fn resolution_exponent(&self) -> i32 {
        -1
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let mut value = 0.0;
        match grad {
            Some(g) => {
                for j in 0..seg.q.len() {
                    let d = seg.q[j] - seg.q_prev[j];
                    value += d * d;
                    g.this[j] += 2.0 * g.scale * d;
                    g.prev[j] -= 2.0 * g.scale * d;
                }
                if let Some(h) = g.hessian {
                    h.add_difference(2.0 * g.scale);
                }
            }
            None => value = seg.q.iter().zip(seg.q_prev).map(|(a, b)| (a - b) * (a - b)).sum(),
        }
        value
    }
}
