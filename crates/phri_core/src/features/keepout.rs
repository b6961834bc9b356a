//! Keep-out features (the laptop and human tasks): penetration of sample points along each segment
//! into a vertical cylinder.

use nalgebra::{Vector2, Vector3};

use super::smoothing::{smooth_hinge, smooth_hinge_curvature};
use super::{Feature, Segment, SegmentGrad};

/// Penetration into a vertical cylinder: φ = Σ_k max(0, r − ‖p_xy(s_k) − c‖) over `samples` points
/// s_k = k/samples along the segment (q_{i-1}, q_i] [m]. The original's laptop and human features.
///
/// A sample is skipped without its kinematics when a bound proves it outside the circle: with d₀, d₁
/// the end points' distances from the centre and L the [`Segment::travel_bound`], the point at s is
/// at least max(d₀ − s·L, d₁ − (1 − s)·L) from it; when that is ≥ r (plus 10⁻⁹ m for rounding)
/// the sample contributes exactly 0, as it would if computed.
#[derive(Debug, Clone)]
pub struct Keepout {
    pub name: String,
    /// Centre in the base frame's xy plane [m].
    pub center: Vector2<f64>,
    /// Radius [m].
    pub radius: f64,
    /// Points per segment (the original uses 4).
    pub samples: usize,
}

impl Feature for Keepout {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, mut grad: Option<SegmentGrad<'_>>) -> f64 {
        let distance = |p: Vector3<f64>| Vector2::new(p.x - self.center.x, p.y - self.center.y).norm();
        // Conservative skip (see the type's docs): the bound is exact, so results do not change.
        let skip =
            seg.travel_bound().map(|travel| (distance(seg.point(0.0).position), distance(seg.point(1.0).position), travel));
        // The optimiser's model also wants the samples just outside (see `Pieces`).
        let delta = seg.smoothing;
        let margin = match grad.as_ref() {
            Some(g) if g.pieces.is_some() && delta > 0.0 => PIECE_MARGIN * self.radius,
            _ => 0.0,
        };
        let mut value = 0.0;
        for k in 1..=self.samples {
            let s = k as f64 / self.samples as f64;
            if let Some((d0, d1, travel)) = skip {
                if (d0 - s * travel).max(d1 - (1.0 - s) * travel) >= self.radius + margin + 1e-9 {
                    continue;
                }
            }
            let p = seg.point(s).position;
            let d = Vector2::new(p.x - self.center.x, p.y - self.center.y);
            let dist = d.norm();
            if dist >= self.radius {
                if dist < self.radius + margin {
                    if let Some(pieces) = grad.as_mut().and_then(|g| g.pieces.as_deref_mut().map(|p| (p, g.scale))) {
                        let (pieces, scale) = pieces;
                        let u = d / dist;
                        let jac = seg.jacobian(s);
                        pieces.push(s, self.radius - dist, scale / delta, |j| -(u.x * jac[(0, j)] + u.y * jac[(1, j)]));
                    }
                }
                continue;
            }
            let (v, slope) = smooth_hinge(self.radius - dist, delta);
            value += v;
            if let Some(g) = grad.as_mut() {
                if dist > 0.0 && slope > 0.0 {
                    let u = d / dist;
                    let jac = seg.jacobian(s);
                    // a = ∂(r − dist)/∂q, b = ∂(dist along the tangent)/∂q.
                    let a = |j: usize| -(u.x * jac[(0, j)] + u.y * jac[(1, j)]);
                    let b = |j: usize| -u.y * jac[(0, j)] + u.x * jac[(1, j)];
                    for j in 0..g.this.len() {
                        let dphi = a(j) * slope * g.scale;
                        g.this[j] += s * dphi;
                        g.prev[j] += (1.0 - s) * dphi;
                    }
                    if let Some(h) = g.hessian.as_deref_mut() {
                        // ∂²φ = h''·a·aᵀ − h'·(b·bᵀ/dist + Σ_c u_c ∂²p_c) (c = x, y), with the
                        // hinge's curvature h'' for the model (see `smooth_hinge_curvature`).
                        let curvature = smooth_hinge_curvature(self.radius - dist, delta);
                        if curvature > 0.0 {
                            h.add_outer(s, g.scale * curvature, a);
                        }
                        // The geometric (indefinite) terms only near the kink, where they matter for
                        // the final convergence; deep inside the circle they would force heavy
                        // damping (−1/dist near the centre) for no benefit.
                        if self.radius - dist < delta {
                            h.add_outer(s, -g.scale * slope / dist, b);
                            seg.add_position_curvature(s, &Vector3::new(u.x, u.y, 0.0), -g.scale * slope, h);
                        }
                    }
                }
            }
        }
        value
    }
}

/// How far outside a keep-out circle (as a fraction of its radius) samples are reported to the
/// optimiser's model as [`Pieces`](super::Pieces).
const PIECE_MARGIN: f64 = 0.1;
