//! The arm's collision model: each link (and anything it carries, like the cup) is a union of
//! spheres fixed to one of its frames, fitted to the URDF's collision geometry ([`fit`]) or given
//! by the user. Spheres keep every distance a closed form with a cheap gradient ([`distance`]);
//! the fits cover their shapes, so a clearance kept by the spheres is kept by the links.
//!
//! [`CollisionChecker`] pairs the bodies with a scene's objects and with each other, leaving out
//! the pairs that are in contact in every pose (a link and its neighbour at their joint, a base
//! standing on its table), and measures the pairs' distances and their gradients in q.

pub(crate) mod bodies;
mod checker;
pub mod distance;
pub mod fit;

use nalgebra::Point3;

pub use bodies::{CollisionBody, CollisionModel};
pub use checker::{CollisionChecker, Near, Other, ProximityScratch, Violation, SELF_BAND, SELF_MARGIN};
pub use fit::{Primitive, Sphere};

use crate::data::RobotData;
use crate::error::{check_finite, PhriError, Result};
use crate::model::{FrameId, RobotModel, Transform};
use crate::scene::Scene;

/// Most spheres of one collision body given with `with_collision_spheres` [count]: each distance
/// query of a pair of bodies costs the product of their sphere counts (the fitted JACO2 has 48
/// spheres in 9 bodies, a fitted box at most 64).
pub const MAX_BODY_SPHERES: usize = 1024;

impl CollisionModel {
    /// The smallest signed distance [m] of every body to every object of `scene` (bodies × objects,
    /// row-major; negative: overlapping) after forward kinematics into `data`.
    pub fn scene_distances(&self, robot: &RobotModel, data: &RobotData, scene: &Scene, out: &mut [f64]) -> Result<()> {
        let objects = scene.objects();
        if out.len() != self.bodies.len() * objects.len() {
            return Err(PhriError::shape(
                "out",
                format!("({}, {})", self.bodies.len(), objects.len()),
                format!("{} values", out.len()),
            ));
        }
        for (b, body) in self.bodies.iter().enumerate() {
            let pose = robot.frame_pose(body.frame, data);
            for (o, object) in objects.iter().enumerate() {
                out[b * objects.len() + o] = body
                    .spheres
                    .iter()
                    .map(|s| {
                        let c = pose.transform_point(&Point3::from(s.center)).coords;
                        distance::signed_distance(object.shape(), object.pose(), &c).0 - s.radius
                    })
                    .fold(f64::INFINITY, f64::min);
            }
        }
        Ok(())
    }
}

impl RobotModel {
    /// The robot's collision model (fitted to its URDF's collision geometry, plus what was added).
    pub fn collision(&self) -> &CollisionModel {
        &self.collision
    }

    /// The robot with body `name`'s spheres set to `spheres` (centres in `frame` [m], radii [m]):
    /// a link's own spheres replaced, or a new body (a carried object, a tool) added.
    pub fn with_collision_spheres(mut self, name: &str, frame: FrameId, spheres: Vec<Sphere>) -> Result<Self> {
        if name.is_empty() {
            return Err(PhriError::invalid("name", "must not be empty"));
        }
        if frame.0 >= self.frames.len() {
            return Err(PhriError::invalid("frame", "is not a frame of this robot"));
        }
        if spheres.is_empty() || spheres.len() > MAX_BODY_SPHERES {
            return Err(PhriError::invalid(
                "spheres",
                format!("must hold 1 to {MAX_BODY_SPHERES} spheres, got {}", spheres.len()),
            ));
        }
        let size = fit::MAX_SIZE;
        for s in &spheres {
            check_finite("spheres", s.center.as_slice())?;
            if !s.center.iter().all(|c| c.abs() <= size) {
                return Err(PhriError::invalid("spheres", format!("centres must be within ±{size} m of the frame")));
            }
            if !(s.radius > 0.0 && s.radius <= size) {
                return Err(PhriError::invalid(
                    "spheres",
                    format!("radius must be a distance in (0, {size}] m, got {}", s.radius),
                ));
            }
        }
        self.collision.set(name.to_string(), frame, spheres);
        Ok(self)
    }

    /// The robot carrying the objects a URDF describes (e.g. a cup): the collision geometry of its
    /// links, joined by fixed joints from its root, attached at `frame` as body `name`.
    pub fn with_attached_urdf(self, name: &str, frame: FrameId, urdf: &str) -> Result<Self> {
        crate::model::check_urdf_text("urdf", urdf)?;
        let robot = urdf_rs::read_from_string(urdf)
            .map_err(|e| PhriError::Urdf { arg: "urdf".into(), reason: format!("not a valid URDF document ({e})") })?;
        let mut attached = CollisionModel::default();
        for link in &robot.links {
            // The link's pose in the attached root's frame, through fixed joints.
            let mut pose = Transform::identity();
            let mut current = link.name.as_str();
            // A chain is at most as long as there are joints: a longer walk is a cycle.
            let mut steps = 0;
            while let Some(j) = robot.joints.iter().find(|j| j.child.link == current) {
                steps += 1;
                if steps > robot.joints.len() {
                    return Err(PhriError::Urdf {
                        arg: "urdf".into(),
                        reason: format!("the joints above link '{}' form a cycle", link.name),
                    });
                }
                if !matches!(j.joint_type, urdf_rs::JointType::Fixed) {
                    return Err(PhriError::Urdf {
                        arg: "urdf".into(),
                        reason: format!("joint '{}' of an attached object must be fixed", j.name),
                    });
                }
                pose = crate::pose::urdf_pose(&j.origin) * pose;
                current = j.parent.link.as_str();
            }
            attached.add_urdf_link(link, frame, &pose)?;
        }
        if let Some((link, why)) = attached.unfitted.first() {
            return Err(PhriError::Urdf {
                arg: "urdf".into(),
                reason: format!("link '{link}' has collision geometry that is {why}"),
            });
        }
        let spheres: Vec<Sphere> = attached.bodies.into_iter().flat_map(|b| b.spheres).collect();
        if spheres.is_empty() {
            return Err(PhriError::Urdf { arg: "urdf".into(), reason: "has no <collision> geometry to attach".into() });
        }
        self.with_collision_spheres(name, frame, spheres)
    }
}
