//! Keep-out features (the laptop and human tasks): penetration of sample points along each segment
//! into a vertical cylinder (or a ball).

use nalgebra::{Vector2, Vector3};

use super::smoothing::{smooth_hinge, smooth_hinge_curvature};
use super::{Feature, Segment, SegmentGrad};
use crate::model::FrameId;

/// Penetration into a vertical cylinder: φ = Σ_k max(0, r − ‖p_xy(s_k) − c‖) over `samples` points
/// s_k = k/samples along the segment (q_{i-1}, q_i] [m]. The original's laptop and human features.
/// With `height`, a ball about (c, height) instead: φ = Σ_k max(0, r − ‖p(s_k) − (c, height)‖).
/// p is the origin of `frame` (None: the feature set's frame).
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
    /// The frame whose origin is kept out (None: the feature set's frame).
    pub frame: Option<FrameId>,
    /// The ball's centre height [m]; None for the vertical cylinder.
    pub height: Option<f64>,
}

impl Keepout {
    /// The vertical cylinder about `center` of the feature set's frame (the built-ins).
    pub fn cylinder(name: impl Into<String>, center: Vector2<f64>, radius: f64, samples: usize) -> Self {
        Keepout { name: name.into(), center, radius, samples, frame: None, height: None }
    }

    /// p − centre, z zeroed for the cylinder.
    fn offset(&self, p: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(p.x - self.center.x, p.y - self.center.y, self.height.map_or(0.0, |h| p.z - h))
    }
}

impl Feature for Keepout {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, mut grad: Option<SegmentGrad<'_>>) -> f64 {
        let frame = self.frame;
        let distance = |p: Vector3<f64>| self.offset(&p).norm();
        // Conservative skip (see the type's docs): the bound is exact, so results do not change.
        let skip = seg
            .travel_bound_of(frame)
            .map(|travel| (distance(seg.point_of(frame, 0.0).position), distance(seg.point_of(frame, 1.0).position), travel));
        // The optimiser's model also wants the samples just outside (see `Pieces`).
        let delta = seg.smoothing;
        let margin = match grad.as_ref() {
            Some(g) if g.pieces.is_some() && delta > 0.0 => PIECE_MARGIN * self.radius,
            _ => 0.0,
        };
        let ball = self.height.is_some();
        let mut value = 0.0;
        for k in 1..=self.samples {
            let s = k as f64 / self.samples as f64;
            if let Some((d0, d1, travel)) = skip {
                if (d0 - s * travel).max(d1 - (1.0 - s) * travel) >= self.radius + margin + 1e-9 {
                    continue;
                }
            }
            let p = seg.point_of(frame, s).position;
            let d = self.offset(&p);
            let dist = d.norm();
            if dist >= self.radius {
                if dist < self.radius + margin {
                    if let Some(pieces) = grad.as_mut().and_then(|g| g.pieces.as_deref_mut().map(|p| (p, g.scale))) {
                        let (pieces, scale) = pieces;
                        let u = d / dist;
                        let jac = seg.jacobian_of(frame, s);
                        pieces.push(s, self.radius - dist, scale / delta, |j| {
                            -(u.x * jac[(0, j)] + u.y * jac[(1, j)] + u.z * jac[(2, j)])
                        });
                    }
                }
                continue;
            }
            let (v, slope) = smooth_hinge(self.radius - dist, delta);
            value += v;
            if let Some(g) = grad.as_mut() {
                if dist > 0.0 && slope > 0.0 {
                    let u = d / dist;
                    let jac = seg.jacobian_of(frame, s);
                    // a = ∂(r − dist)/∂q, b = ∂(dist along the tangent)/∂q (the cylinder's).
                    let a = |j: usize| -(u.x * jac[(0, j)] + u.y * jac[(1, j)] + u.z * jac[(2, j)]);
                    let b = |j: usize| -u.y * jac[(0, j)] + u.x * jac[(1, j)];
                    for j in 0..g.this.len() {
                        let dphi = a(j) * slope * g.scale;
                        g.this[j] += s * dphi;
                        g.prev[j] += (1.0 - s) * dphi;
                    }
                    if let Some(h) = g.hessian.as_deref_mut() {
                        // ∂²φ = h''·a·aᵀ − h'·(Jᵀ(P − u·uᵀ)J/dist + Σ_c u_c ∂²p_c), P the
                        // projection onto the plane (cylinder: b·bᵀ) or the identity (ball), with
                        // the hinge's curvature h'' for the model (see `smooth_hinge_curvature`).
                        let curvature = smooth_hinge_curvature(self.radius - dist, delta);
                        if curvature > 0.0 {
                            h.add_outer(s, g.scale * curvature, a);
                        }
                        // The geometric (indefinite) terms only near the kink, where they matter for
                        // the final convergence; deep inside the circle they would force heavy
                        // damping (−1/dist near the centre) for no benefit.
                        if self.radius - dist < delta {
                            let w = -g.scale * slope / dist;
                            if ball {
                                for c in 0..3 {
                                    h.add_outer(s, w, |j| jac[(c, j)]);
                                }
                                h.add_outer(s, -w, a);
                            } else {
                                h.add_outer(s, w, b);
                            }
                            seg.add_position_curvature_of(frame, s, &u, -g.scale * slope, h);
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
