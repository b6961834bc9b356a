//! The collision bodies of a robot: unions of spheres fixed to its frames, fitted to the URDF's
//! collision geometry ([`super::fit`]) or given by the user. The robot model owns them; the
//! checker ([`super::CollisionChecker`]) measures them.

use nalgebra::Vector3;

use super::fit::{self, Sphere};
use crate::error::{PhriError, Result};
use crate::pose::{urdf_pose, FrameId, Transform};

/// One rigid collision body: a link's spheres (or a carried object's), fixed to `frame`.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionBody {
    /// The link's name (or the carried object's).
    pub name: String,
    /// The frame the spheres' centres are given in.
    pub frame: FrameId,
    pub spheres: Vec<Sphere>,
    /// A sphere enclosing all of them (a quick test before the spheres).
    pub(super) bound: Sphere,
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
    pub(super) bodies: Vec<CollisionBody>,
    /// (link, why) for each link with collision geometry phri cannot fit (meshes).
    pub(super) unfitted: Vec<(String, String)>,
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
                    let pose = frame_t_link * urdf_pose(&c.origin);
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
}
