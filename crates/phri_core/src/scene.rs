//! The scene around the robot: named objects (the table, the laptop, the person, …) with a shape,
//! a pose in the robot's base frame and a clearance margin.
//!
//! One type for every consumer: keep-out features name the object they keep away from (the
//! authors' laptop and human features are circles about the laptop and the person), the planner
//! keeps the hand above the table's top, and the simulation builds its bodies from the same
//! objects. The margin and the kind (furniture or the person) are declared here so that distance
//! checks of the whole arm against every object can use them: the person's hand touching the arm
//! is the point of physical interaction, their body is kept clear of like furniture.

use nalgebra::{Isometry3, Vector2, Vector3};

use crate::error::{check_finite, PhriError, Result};

/// Clearance margin an object gets when its description gives none [m].
pub const DEFAULT_MARGIN: f64 = 0.02;

/// The geometry of a scene object, in the object's own frame (its pose places that frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// The half-space below the plane through the pose's origin whose normal is the pose's z axis
    /// (e.g. a floor or an unbounded table top).
    Plane,
    /// A box centred on the pose's origin with full extents `size` along the pose's x, y, z [m].
    Box { size: Vector3<f64> },
    /// A solid cylinder centred on the pose's origin, its axis along the pose's z: `radius` [m],
    /// `length` end to end [m].
    Cylinder { radius: f64, length: f64 },
    /// A ball centred on the pose's origin of `radius` [m].
    Sphere { radius: f64 },
}

/// Names of the shapes, as task files and the bindings spell them.
pub const SHAPE_NAMES: [&str; 4] = ["plane", "box", "cylinder", "sphere"];

impl Shape {
    /// The shape's name (one of [`SHAPE_NAMES`]).
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Plane => "plane",
            Shape::Box { .. } => "box",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Sphere { .. } => "sphere",
        }
    }

    fn check(&self) -> Result<()> {
        let positive = |arg: &str, values: &[f64]| -> Result<()> {
            check_finite(arg, values)?;
            match values.iter().find(|v| !(**v > 0.0)) {
                Some(v) => Err(PhriError::invalid(arg, format!("must be a distance > 0 m, got {v}"))),
                None => Ok(()),
            }
        };
        match self {
            Shape::Plane => Ok(()),
            Shape::Box { size } => positive("size", size.as_slice()),
            Shape::Cylinder { radius, length } => {
                positive("radius", &[*radius])?;
                positive("length", &[*length])
            }
            Shape::Sphere { radius } => positive("radius", &[*radius]),
        }
    }
}

/// What an object is, for clearance: furniture (table, laptop) or the person.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectKind {
    Furniture,
    /// The person teaching the robot: their body is kept clear of, their hand is meant to touch.
    Person,
}

/// Names of the kinds, as task files and the bindings spell them.
pub const KIND_NAMES: [&str; 2] = ["furniture", "person"];

impl ObjectKind {
    pub fn name(&self) -> &'static str {
        match self {
            ObjectKind::Furniture => "furniture",
            ObjectKind::Person => "person",
        }
    }

    /// The kind named `name` (one of [`KIND_NAMES`]).
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "furniture" => Ok(ObjectKind::Furniture),
            "person" => Ok(ObjectKind::Person),
            other => Err(PhriError::UnknownName {
                arg: "kind".into(),
                kind: "object kind".into(),
                name: other.into(),
                known: KIND_NAMES.join(", "),
            }),
        }
    }
}

/// One named object of a [`Scene`]; constructed through [`SceneObject::new`], which validates it.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneObject {
    name: String,
    shape: Shape,
    pose: Isometry3<f64>,
    margin: f64,
    kind: ObjectKind,
}

impl SceneObject {
    /// An object `name` of `shape` placed at `pose` (the object frame in the robot's base frame,
    /// translation in m) with clearance `margin` [m] ≥ 0.
    pub fn new(name: impl Into<String>, shape: Shape, pose: Isometry3<f64>, margin: f64, kind: ObjectKind) -> Result<Self> {
        let name = name.into();
        if name.is_empty() {
            return Err(PhriError::invalid("name", "must not be empty"));
        }
        shape.check()?;
        check_finite("position", pose.translation.vector.as_slice())?;
        check_finite("rotation", pose.rotation.coords.as_slice())?;
        if !(margin >= 0.0 && margin.is_finite()) {
            return Err(PhriError::invalid("margin", format!("must be a finite distance >= 0 m, got {margin}")));
        }
        Ok(SceneObject { name, shape, pose, margin, kind })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn shape(&self) -> &Shape {
        &self.shape
    }

    /// The object frame in the robot's base frame.
    pub fn pose(&self) -> &Isometry3<f64> {
        &self.pose
    }

    /// Clearance margin [m].
    pub fn margin(&self) -> f64 {
        self.margin
    }

    pub fn kind(&self) -> ObjectKind {
        self.kind
    }

    /// Origin of the object frame in the base frame [m] (the centre of a box, cylinder or ball).
    pub fn position(&self) -> Vector3<f64> {
        self.pose.translation.vector
    }

    /// The object's position in the base frame's xy plane [m] (e.g. a keep-out circle's centre).
    pub fn xy(&self) -> Vector2<f64> {
        self.position().xy()
    }

    /// Height of the object's highest point in the base frame [m]; None for a plane that is not
    /// horizontal with its normal up (the solid then reaches up without bound).
    pub fn top(&self) -> Option<f64> {
        let z = self.position().z;
        let r = self.pose.rotation.to_rotation_matrix();
        let m = r.matrix();
        // Row 2 of R: how much each object axis points up.
        let up = Vector3::new(m[(2, 0)], m[(2, 1)], m[(2, 2)]);
        match self.shape {
            Shape::Plane => (up.x == 0.0 && up.y == 0.0 && up.z > 0.0).then_some(z),
            Shape::Box { size } => Some(z + (up.x.abs() * size.x + up.y.abs() * size.y + up.z.abs() * size.z) / 2.0),
            Shape::Cylinder { radius, length } => {
                Some(z + up.z.abs() * length / 2.0 + radius * (1.0 - up.z * up.z).max(0.0).sqrt())
            }
            Shape::Sphere { radius } => Some(z + radius),
        }
    }
}

/// Named objects in the robot's base frame; names are unique.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    objects: Vec<SceneObject>,
}

impl Scene {
    /// A scene of `objects`, which must have distinct names.
    pub fn new(objects: Vec<SceneObject>) -> Result<Self> {
        for (i, o) in objects.iter().enumerate() {
            if objects[..i].iter().any(|p| p.name == o.name) {
                return Err(PhriError::invalid("objects", format!("name '{}' twice", o.name)));
            }
        }
        Ok(Scene { objects })
    }

    /// The scene with no objects.
    pub fn empty() -> Self {
        Scene::default()
    }

    pub fn objects(&self) -> &[SceneObject] {
        &self.objects
    }

    pub fn names(&self) -> Vec<&str> {
        self.objects.iter().map(|o| o.name.as_str()).collect()
    }

    /// The object named `name`, if any.
    pub fn get(&self, name: &str) -> Option<&SceneObject> {
        self.objects.iter().find(|o| o.name == name)
    }

    /// The object named `name`; an [`PhriError::UnknownName`] about argument `arg` listing the
    /// scene's objects otherwise.
    pub fn require(&self, arg: &str, name: &str) -> Result<&SceneObject> {
        self.get(name).ok_or_else(|| PhriError::UnknownName {
            arg: arg.into(),
            kind: "scene object".into(),
            name: name.into(),
            known: if self.objects.is_empty() { "(the scene is empty)".into() } else { self.names().join(", ") },
        })
    }
}
