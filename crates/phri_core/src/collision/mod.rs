//! The arm's collision model: each link (and anything it carries, like the cup) is a union of
//! spheres fixed to one of its frames, fitted to the URDF's collision geometry ([`fit`]) or given
//! by the user. Spheres keep every distance a closed form with a cheap gradient ([`distance`]);
//! the fits cover their shapes, so a clearance kept by the spheres is kept by the links.
//!
//! [`CollisionChecker`] pairs the bodies with a scene's objects and with each other, leaving out
//! the pairs that are in contact in every pose (a link and its neighbour at their joint, a base
//! standing on its table), and measures the pairs' distances and their gradients in q.

mod checker;
pub mod distance;
pub mod fit;

use nalgebra::{Point3, Vector3};

pub use checker::{CollisionChecker, Near, Other, ProximityScratch, Violation, SELF_BAND, SELF_MARGIN};
pub use fit::Primitive;

use crate::data::RobotData;
use crate::error::{check_finite, PhriError, Result};
use crate::model::{FrameId, RobotModel, Transform};
use crate::scene::Scene;

/// Most spheres of one collision body given with `with_collision_spheres` [count]: each distance
/// query of a pair of bodies costs the product of their sphere counts (the fitted JACO2 has 48
/// spheres in 9 bodies, a fitted box at most 64).
pub const MAX_BODY_SPHERES: usize = 1024;

/// A ball of `radius` [m] centred at `center`, in its body's frame [m].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub center: Vector3<f64>,
    pub radius: f64,
}

/// One rigid collision body: a link's spheres (or a carried object's), fixed to `frame`.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionBody {
    /// The link's name (or the carried object's).
    pub name: String,
    /// The frame the spheres' centres are given in.
    pub frame: FrameId,
    pub spheres: Vec<Sphere>,
    /// A sphere enclosing all of them (a quick test before the spheres).
    bound: Sphere,
}

impl CollisionBody {
    fn new(name: String, frame: FrameId, spheres: Vec<Sphere>) -> Self {
        let center = spheres.iter().map(|s| s.center).sum::<Vector3<f64>>() / spheres.len().max(1) as f64;
        let radius = spheres.iter().map(|s| (s.center - center).norm() + s.radius).fold(0.0, f64::max);
        CollisionBody { name, frame, spheres, bound: Sphere { center, radius } }
    }
}

/// The collision bodies of a robot, and the links whose geometry could not be fitted.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CollisionModel {
    bodies: Vec<CollisionBody>,
    /// (link, why) for each link with collision geometry phri cannot fit (meshes).
    unfitted: Vec<(String, String)>,
}

impl CollisionModel {
    pub fn bodies(&self) -> &[CollisionBody] {
        &self.bodies
    }

    /// The links whose collision geometry has no spheres, with the reason.
    pub fn unfitted(&self) -> &[(String, String)] {
        &self.unfitted
    }

    /// Whether collisions can be checked: some bodies, and none left unfitted.
    pub fn is_complete(&self) -> bool {
        !self.bodies.is_empty() && self.unfitted.is_empty()
    }

    /// Why collisions cannot be checked, if they cannot (for a typed error).
    pub fn incomplete_reason(&self, robot: &str) -> Option<String> {
        if let Some((link, why)) = self.unfitted.first() {
            return Some(format!(
                "robot '{robot}' has no collision spheres for link '{link}': its collision geometry is {why}; give its spheres (with_collision_spheres)"
            ));
        }
        self.bodies.is_empty().then(|| {
            format!("robot '{robot}' has no collision model (its URDF has no <collision> geometry); give spheres per link (with_collision_spheres)")
        })
    }

    /// Adds the spheres of `link`'s URDF collision elements, placed by `frame_t_link` (the
    /// link's pose in `frame`).
    pub(crate) fn add_urdf_link(&mut self, link: &urdf_rs::Link, frame: FrameId, frame_t_link: &Transform) -> Result<()> {
        let mut spheres = Vec::new();
        for c in &link.collision {
            match fit::from_urdf(&c.geometry) {
                Ok(shape) => {
                    let pose = frame_t_link * crate::model::urdf_pose(&c.origin);
                    spheres.extend(fit::fit(&shape, &pose).map_err(|e| PhriError::Urdf {
                        arg: "urdf".into(),
                        reason: format!("link '{}' has collision geometry that {e}", link.name),
                    })?);
                }
                Err(why) => self.unfitted.push((link.name.clone(), why)),
            }
        }
        if !spheres.is_empty() {
            self.set(link.name.clone(), frame, spheres);
        }
        Ok(())
    }

    /// Sets body `name`'s spheres (replacing a body of that name and its unfitted entry).
    pub(crate) fn set(&mut self, name: String, frame: FrameId, spheres: Vec<Sphere>) {
        self.unfitted.retain(|(link, _)| *link != name);
        let body = CollisionBody::new(name, frame, spheres);
        match self.bodies.iter_mut().find(|b| b.name == body.name) {
            Some(b) => *b = body,
            None => self.bodies.push(body),
        }
    }

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
                pose = crate::model::urdf_pose(&j.origin) * pose;
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
