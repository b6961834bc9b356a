//! Spheres that cover a primitive shape: the collision model's bodies are unions of spheres
//! fitted here to the URDF's collision geometry (boxes, cylinders, capsules, spheres).
//!
//! Every fit covers its shape (each point of the solid lies in some sphere), so distances
//! measured to the spheres are never larger than to the shape itself: a clearance kept by the
//! spheres is kept by the link.

use nalgebra::{Point3, Vector3};

use crate::error::{check_finite, PhriError, Result};
use crate::pose::Transform;

/// A ball of `radius` [m] centred at `center`, in its body's frame [m].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub center: Vector3<f64>,
    pub radius: f64,
}

/// Largest radius of a sphere covering a cylinder or capsule, as a multiple of its radius [1].
/// 1.1 puts the spheres at most 0.92 radii apart along the axis and overestimates the side by at
/// most a tenth of the radius (4.5 mm on the JACO2's links); the end spheres reach 0.64 radii beyond
/// the end faces (2.6 cm past the cup's bottom). Distances to the spheres are lower bounds of the
/// distances to the links: conservative, by up to that much.
pub const COVER: f64 = 1.1;

/// Largest size of a collision primitive [m] (beyond it squares of sizes overflow, and no robot or
/// object near one is that large).
pub const MAX_SIZE: f64 = 1000.0;

/// Most spheres one box is covered with (its cells grow beyond this).
const MAX_BOX_CELLS: usize = 64;

/// Most spheres along one cylinder or capsule (they grow beyond this: a thin rod 10⁶ times longer
/// than thick would otherwise need 10⁶ spheres, and one 10³⁰⁰ times longer an allocation that aborts).
const MAX_CYLINDER_SPHERES: usize = 64;

/// A solid primitive in its own frame (as URDF `<geometry>` describes it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// A ball of `radius` [m] about the origin.
    Sphere { radius: f64 },
    /// A box of full extents `size` [m] centred on the origin.
    Box { size: Vector3<f64> },
    /// A cylinder of `radius` [m] and `length` [m] along z, centred on the origin.
    Cylinder { radius: f64, length: f64 },
    /// A cylinder of `radius` and `length` along z capped by two half balls [m].
    Capsule { radius: f64, length: f64 },
}

impl Primitive {
    fn check(&self) -> Result<()> {
        let values: Vec<f64> = match self {
            Primitive::Sphere { radius } => vec![*radius],
            Primitive::Box { size } => size.iter().copied().collect(),
            Primitive::Cylinder { radius, length } | Primitive::Capsule { radius, length } => vec![*radius, *length],
        };
        check_finite("geometry", &values)?;
        if let Some(v) = values.iter().find(|v| !(**v > 0.0 && **v <= MAX_SIZE)) {
            return Err(PhriError::invalid("geometry", format!("has a size that is not a distance in (0, {MAX_SIZE}] m ({v})")));
        }
        Ok(())
    }
}

/// Spheres covering `shape` placed at `pose` in a body's frame, their centres in that frame.
pub fn fit(shape: &Primitive, pose: &Transform) -> Result<Vec<Sphere>> {
    shape.check()?;
    let local = match *shape {
        Primitive::Sphere { radius } => vec![(Vector3::zeros(), radius)],
        Primitive::Cylinder { radius, length } => cylinder(radius, length),
        Primitive::Capsule { radius, length } => {
            let mut spheres = cylinder(radius, length);
            spheres.extend([-0.5, 0.5].map(|s| (Vector3::new(0.0, 0.0, s * length), radius)));
            spheres
        }
        Primitive::Box { size } => cuboid(size),
    };
    Ok(local.into_iter().map(|(c, radius)| Sphere { center: pose.transform_point(&Point3::from(c)).coords, radius }).collect())
}

/// Spheres of radius at most [`COVER`]·r along the axis, the outer ones reaching the end faces.
fn cylinder(r: f64, length: f64) -> Vec<(Vector3<f64>, f64)> {
    let big = COVER * r;
    // A sphere of radius R on the axis covers the solid cylinder over ±e of its centre.
    let e = (big * big - r * r).sqrt();
    if length <= 2.0 * e {
        return vec![(Vector3::zeros(), (r * r + length * length / 4.0).sqrt())];
    }
    let span = length - 2.0 * e;
    let needed = (span / (2.0 * e)).ceil() + 1.0;
    if needed > MAX_CYLINDER_SPHERES as f64 {
        // A cylinder much longer than thick: MAX_CYLINDER_SPHERES larger spheres, each covering
        // its 1/count of the length (radius √(r² + half²)), rather than a count without bound.
        let count = MAX_CYLINDER_SPHERES;
        let half = length / (2.0 * count as f64);
        let radius = (r * r + half * half).sqrt();
        return (0..count).map(|k| (Vector3::new(0.0, 0.0, -length / 2.0 + (2 * k + 1) as f64 * half), radius)).collect();
    }
    let count = needed as usize;
    let spacing = span / (count - 1) as f64;
    (0..count).map(|k| (Vector3::new(0.0, 0.0, -span / 2.0 + k as f64 * spacing), big)).collect()
}

/// A grid of near-cubic cells, each covered by the sphere through its corners.
fn cuboid(size: Vector3<f64>) -> Vec<(Vector3<f64>, f64)> {
    let mut cell = size.min();
    let counts = loop {
        let counts = size.map(|s| (s / cell - 1e-9).ceil().max(1.0) as usize);
        if counts.iter().product::<usize>() <= MAX_BOX_CELLS {
            break counts;
        }
        cell *= 1.25;
    };
    let step = size.component_div(&counts.map(|c| c as f64));
    let radius = step.norm() / 2.0;
    let mut spheres = Vec::with_capacity(counts.iter().product());
    for i in 0..counts.x {
        for j in 0..counts.y {
            for k in 0..counts.z {
                let index = Vector3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
                spheres.push((index.component_mul(&step) - size / 2.0, radius));
            }
        }
    }
    spheres
}

/// The primitive a URDF geometry is, or why it has none (a mesh).
pub fn from_urdf(geometry: &urdf_rs::Geometry) -> std::result::Result<Primitive, String> {
    match geometry {
        urdf_rs::Geometry::Sphere { radius } => Ok(Primitive::Sphere { radius: *radius }),
        urdf_rs::Geometry::Box { size } => Ok(Primitive::Box { size: Vector3::new(size[0], size[1], size[2]) }),
        urdf_rs::Geometry::Cylinder { radius, length } => Ok(Primitive::Cylinder { radius: *radius, length: *length }),
        urdf_rs::Geometry::Capsule { radius, length } => Ok(Primitive::Capsule { radius: *radius, length: *length }),
        urdf_rs::Geometry::Mesh { filename, .. } => Err(format!("a mesh ('{filename}'), which phri does not fit spheres to")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point of a dense grid inside the solid lies in some sphere.
    fn covers(shape: Primitive, inside: impl Fn(&Vector3<f64>) -> bool, extent: Vector3<f64>) {
        let spheres = fit(&shape, &Transform::identity()).unwrap();
        let steps = 24;
        for i in 0..=steps {
            for j in 0..=steps {
                for k in 0..=steps {
                    let f = |n: usize| n as f64 / steps as f64 - 0.5;
                    let p = Vector3::new(f(i) * extent.x, f(j) * extent.y, f(k) * extent.z);
                    if inside(&p) {
                        assert!(
                            spheres.iter().any(|s| (p - s.center).norm() <= s.radius + 1e-12),
                            "{shape:?}: {p:?} is not covered"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn fits_cover_their_shapes() {
        for (r, l) in [(0.045, 0.205), (0.04, 0.1), (0.05, 0.01), (0.01, 1.0)] {
            let inside = |p: &Vector3<f64>| p.xy().norm() <= r && p.z.abs() <= l / 2.0;
            covers(Primitive::Cylinder { radius: r, length: l }, inside, Vector3::new(2.0 * r, 2.0 * r, l));
            let capsule = |p: &Vector3<f64>| {
                let z = p.z.clamp(-l / 2.0, l / 2.0);
                (p - Vector3::new(0.0, 0.0, z)).norm() <= r
            };
            covers(Primitive::Capsule { radius: r, length: l }, capsule, Vector3::new(2.0 * r, 2.0 * r, l + 2.0 * r));
        }
        for size in [Vector3::new(0.06, 0.07, 0.085), Vector3::new(0.81, 1.62, 0.04), Vector3::new(0.1, 0.1, 0.1)] {
            let inside = |p: &Vector3<f64>| (0..3).all(|k| p[k].abs() <= size[k] / 2.0);
            covers(Primitive::Box { size }, inside, size);
        }
    }

    #[test]
    fn fits_stay_tight() {
        // The cylinder's spheres reach at most COVER radii from the axis and the end faces by
        // less than the radius.
        let s = fit(&Primitive::Cylinder { radius: 0.045, length: 0.205 }, &Transform::identity()).unwrap();
        assert!(s.iter().all(|s| s.radius <= COVER * 0.045 + 1e-15));
        let reach = s.iter().map(|s| s.center.z.abs() + s.radius).fold(0.0, f64::max);
        assert!(reach < 0.205 / 2.0 + 0.045, "{reach}");
        assert!(fit(&Primitive::Sphere { radius: 0.0 }, &Transform::identity()).is_err());
        assert!(fit(&Primitive::Box { size: Vector3::new(1.0, f64::NAN, 1.0) }, &Transform::identity()).is_err());
    }
}
