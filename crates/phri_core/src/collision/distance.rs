//! Signed distance from a point to a scene object's surface, with its gradient: the closed forms
//! for a plane, a box, a cylinder and a ball. A sphere of radius R at c is then d(c) − R away.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::scene::Shape;

/// Signed distance [m] from `point` (base frame) to the surface of `shape` placed at `pose`
/// (negative inside), and its gradient in `point` (the unit outward normal at the closest point).
#[inline]
pub fn signed_distance(shape: &Shape, pose: &Isometry3<f64>, point: &Vector3<f64>) -> (f64, Vector3<f64>) {
    let p = pose.inverse_transform_point(&Point3::from(*point)).coords;
    let (d, n) = local(shape, &p);
    (d, pose.rotation * n)
}

/// The signed distance of [`signed_distance`] alone, from the point `p` in the object's frame: a
/// cheap test before the gradient is needed.
#[inline]
pub(super) fn local_distance(shape: &Shape, p: &Vector3<f64>) -> f64 {
    match *shape {
        Shape::Plane => p.z,
        Shape::Sphere { radius } => p.norm() - radius,
        Shape::Box { size } => {
            let q = p.abs() - size / 2.0;
            if q.iter().any(|v| *v > 0.0) {
                q.map(|v| v.max(0.0)).norm()
            } else {
                q.max()
            }
        }
        Shape::Cylinder { radius, length } => {
            let (qr, qz) = (p.xy().norm() - radius, p.z.abs() - length / 2.0);
            if qr > 0.0 && qz > 0.0 {
                qr.hypot(qz)
            } else {
                qr.max(qz)
            }
        }
    }
}

/// [`signed_distance`] in the object's frame.
pub(super) fn local(shape: &Shape, p: &Vector3<f64>) -> (f64, Vector3<f64>) {
    match *shape {
        Shape::Plane => (p.z, Vector3::z()),
        Shape::Sphere { radius } => {
            let r = p.norm();
            let n = if r > 0.0 { p / r } else { Vector3::z() };
            (r - radius, n)
        }
        Shape::Box { size } => {
            let h = size / 2.0;
            let q = p.abs() - h;
            if q.iter().any(|v| *v > 0.0) {
                let outside = q.map(|v| v.max(0.0));
                let d = outside.norm();
                let n = outside.component_mul(&p.map(|v| if v < 0.0 { -1.0 } else { 1.0 })) / d;
                (d, n)
            } else {
                let k = q.imax();
                let mut n = Vector3::zeros();
                n[k] = if p[k] < 0.0 { -1.0 } else { 1.0 };
                (q[k], n)
            }
        }
        Shape::Cylinder { radius, length } => {
            let rho = p.xy().norm();
            let radial = if rho > 0.0 { Vector3::new(p.x / rho, p.y / rho, 0.0) } else { Vector3::x() };
            let axial = Vector3::new(0.0, 0.0, if p.z < 0.0 { -1.0 } else { 1.0 });
            let (qr, qz) = (rho - radius, p.z.abs() - length / 2.0);
            match (qr > 0.0, qz > 0.0) {
                (true, true) => {
                    let d = qr.hypot(qz);
                    (d, (radial * qr + axial * qz) / d)
                }
                (true, false) => (qr, radial),
                (false, true) => (qz, axial),
                (false, false) if qr > qz => (qr, radial),
                (false, false) => (qz, axial),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};

    use super::*;

    fn shapes() -> Vec<(Shape, Isometry3<f64>)> {
        let turned = Isometry3::from_parts(Translation3::new(0.1, -0.2, 0.3), UnitQuaternion::from_euler_angles(0.3, -0.5, 1.1));
        vec![
            (Shape::Plane, turned),
            (Shape::Sphere { radius: 0.2 }, turned),
            (Shape::Box { size: Vector3::new(0.4, 0.6, 0.2) }, turned),
            (Shape::Cylinder { radius: 0.15, length: 0.5 }, turned),
        ]
    }

    #[test]
    fn gradients_match_finite_differences() {
        let h = 1e-6;
        for (shape, pose) in shapes() {
            for k in 0..400 {
                let t = k as f64;
                let p = Vector3::new((t * 0.37).sin(), (t * 0.61).cos(), (t * 0.23).sin()) * 0.6 + Vector3::new(0.1, -0.2, 0.3);
                let (d, g) = signed_distance(&shape, &pose, &p);
                assert!((g.norm() - 1.0).abs() < 1e-12);
                for a in 0..3 {
                    let mut e = Vector3::zeros();
                    e[a] = h;
                    let fd =
                        (signed_distance(&shape, &pose, &(p + e)).0 - signed_distance(&shape, &pose, &(p - e)).0) / (2.0 * h);
                    // Skip points within h of a ridge of the distance field (its kinks inside).
                    let (dp, _) = signed_distance(&shape, &pose, &(p + e));
                    if (dp - d - g[a] * h).abs() < 1e-9 {
                        assert!((fd - g[a]).abs() < 1e-6, "{shape:?} at {p:?}: {fd} vs {}", g[a]);
                    }
                }
            }
        }
    }

    #[test]
    fn the_distance_alone_is_the_signed_distance() {
        for (shape, pose) in shapes() {
            for k in 0..400 {
                let t = k as f64;
                let p = Vector3::new((t * 0.41).cos(), (t * 0.29).sin(), (t * 0.53).cos()) * 0.6 + Vector3::new(0.1, -0.2, 0.3);
                let local_p = pose.inverse_transform_point(&Point3::from(p)).coords;
                assert_eq!(local_distance(&shape, &local_p), local(&shape, &local_p).0, "{shape:?} at {p:?}");
            }
        }
    }

    #[test]
    fn known_distances() {
        let at = Isometry3::identity();
        let b = Shape::Box { size: Vector3::new(2.0, 2.0, 2.0) };
        assert!((signed_distance(&b, &at, &Vector3::new(2.0, 2.0, 0.0)).0 - 2f64.sqrt()).abs() < 1e-15);
        assert!((signed_distance(&b, &at, &Vector3::new(0.0, 0.0, 0.5)).0 + 0.5).abs() < 1e-15);
        let c = Shape::Cylinder { radius: 1.0, length: 2.0 };
        assert!((signed_distance(&c, &at, &Vector3::new(0.0, 3.0, 0.5)).0 - 2.0).abs() < 1e-15);
        assert!((signed_distance(&c, &at, &Vector3::new(0.0, 0.0, 3.0)).0 - 2.0).abs() < 1e-15);
        assert!((signed_distance(&Shape::Plane, &at, &Vector3::new(5.0, 1.0, -0.25)).0 + 0.25).abs() < 1e-15);
    }
}
