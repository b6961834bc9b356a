//! The smoothed kinks of the features: Huber smoothing of |x| (the coffee feature) and of the hinge
//! max(0, x) (the keep-out features), with the curvatures the optimiser's Newton model uses for them.
//! The optimiser plans on the smoothed (C¹) cost; learning counts features exactly (δ = 0).

/// Huber smoothing of |x| with width δ: x²/(2δ) for |x| < δ, |x| − δ/2 beyond; returns (value,
/// derivative). δ = 0 gives |x| with subgradient 0 at 0. The optimiser uses δ > 0 so that it minimises a
/// C¹ cost; learning always counts features exactly (δ = 0).
pub fn huber(x: f64, delta: f64) -> (f64, f64) {
    if x.abs() >= delta {
        (x.abs() - 0.5 * delta, sign(x))
    } else {
        (0.5 * x * x / delta, x / delta)
    }
}

/// Huber-smoothed hinge max(0, x): 0 for x ≤ 0, x²/(2δ) up to δ, x − δ/2 beyond; (value, slope).
pub fn smooth_hinge(x: f64, delta: f64) -> (f64, f64) {
    if x <= 0.0 {
        (0.0, 0.0)
    } else if x >= delta {
        (x - 0.5 * delta, 1.0)
    } else {
        (0.5 * x * x / delta, x / delta)
    }
}

/// Curvature of [`huber`] for the optimiser's model: its second derivative 1/δ inside the quadratic
/// zone, and on the linear sides the secant curvature 1/|x| of the quadratic through the kink with
/// the same slope (the reweighting of IRLS, a convex majoriser of |x|), continuous at |x| = δ. It
/// makes Newton steps aim at the kink instead of running off along a linear piece.
pub(super) fn huber_curvature(x: f64, delta: f64) -> f64 {
    let a = x.abs();
    if a > 0.0 || delta > 0.0 {
        1.0 / a.max(delta)
    } else {
        0.0
    }
}

/// Curvature of [`smooth_hinge`] for the optimiser's model, as [`huber_curvature`]: 1/max(x, δ)
/// where the hinge is active, 0 on its flat side.
pub(super) fn smooth_hinge_curvature(x: f64, delta: f64) -> f64 {
    if x > 0.0 {
        1.0 / x.max(delta)
    } else {
        0.0
    }
}

fn sign(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}
