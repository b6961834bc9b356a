//! The immutable robot model: a serial chain of revolute or prismatic joints read from a URDF.
//!
//! Links rigidly attached to a chain body (through fixed joints, or through movable joints that are
//! off the base→tip path, which are locked at zero) are merged into that body: their inertia is
//! lumped and each keeps a named [`Frame`]. Body 0 is the fixed base; body `i` (1-based) moves with
//! joint `i`. All mutable scratch lives in [`crate::RobotData`], so the model can be shared freely.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Matrix3, Unit, Vector3};

use crate::collision::bodies::CollisionModel;
use crate::error::{PhriError, Result};
use crate::pose::urdf_pose;
pub use crate::pose::{FrameId, Transform};

/// Standard gravity along −z of the base frame [m/s²].
pub const STANDARD_GRAVITY: f64 = 9.81;

/// How a chain joint moves its child body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about `axis` by q [rad] (URDF `revolute` and `continuous`).
    Revolute,
    /// Translation along `axis` by q [m].
    Prismatic,
}

/// One movable joint of the chain.
#[derive(Debug, Clone)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    /// Pose of the joint frame in the parent body's frame at q = 0 (fixed joints folded in).
    pub parent_t_joint: Transform,
    /// Unit motion axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// `parent_t_joint`'s rotation when it is a signed axis permutation (forward kinematics then
    /// permutes columns instead of multiplying).
    pub permutation: Option<AxisPermutation>,
    /// Position limits [rad or m]; ±∞ for continuous joints.
    pub lower: f64,
    pub upper: f64,
    /// Velocity limit [rad/s or m/s].
    pub velocity_limit: f64,
    /// Effort limit [N·m or N].
    pub effort_limit: f64,
}

/// Mass properties of one (lumped) body, in that body's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyInertia {
    /// Mass [kg].
    pub mass: f64,
    /// Centre of mass in the body frame [m].
    pub com: Vector3<f64>,
    /// Rotational inertia about the centre of mass, body-frame axes [kg·m²].
    pub inertia: Matrix3<f64>,
}

impl BodyInertia {
    pub const ZERO: BodyInertia = BodyInertia {
        mass: 0.0,
        com: Vector3::new(0.0, 0.0, 0.0),
        inertia: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    /// Combines two bodies expressed in the same frame (parallel-axis theorem).
    pub fn combine(&self, other: &BodyInertia) -> BodyInertia {
        let mass = self.mass + other.mass;
        if mass <= 0.0 {
            return BodyInertia::ZERO;
        }
        let com = (self.com * self.mass + other.com * other.mass) / mass;
        let shift = |b: &BodyInertia| {
            let d = b.com - com;
            b.inertia + (Matrix3::identity() * d.dot(&d) - d * d.transpose()) * b.mass
        };
        BodyInertia { mass, com, inertia: shift(self) + shift(other) }
    }

    /// The same body seen from a frame in which this body's frame has pose `t`.
    pub fn transformed(&self, t: &Transform) -> BodyInertia {
        let r = t.rotation.matrix();
        let com = t.transform_point(&nalgebra::Point3::from(self.com)).coords;
        BodyInertia { mass: self.mass, com, inertia: r * self.inertia * r.transpose() }
    }
}

/// A named frame rigidly attached to one body (every URDF link kept by the model is one).
#[derive(Debug, Clone)]
pub struct Frame {
    pub name: String,
    /// Index of the body it moves with (0 = base, i = child of joint i).
    pub body: usize,
    /// Pose of the frame in its body's frame.
    pub body_t_frame: Transform,
}

/// An immutable serial-chain robot.
#[derive(Debug, Clone)]
pub struct RobotModel {
    pub name: String,
    pub joints: Vec<Joint>,
    /// Lumped inertia of body 0 (the base) and of body i, the child of joint i.
    pub bodies: Vec<BodyInertia>,
    pub frames: Vec<Frame>,
    /// Gravity in the base frame [m/s²].
    pub gravity: Vector3<f64>,
    frame_index: HashMap<String, usize>,
    /// Spheres per link, fitted to the URDF's collision geometry (see [`crate::collision`]).
    pub(crate) collision: CollisionModel,
}

/// A rotation whose columns are signed base axes: column k is `sign[k]`·e_`axis[k]`, so R·P has
/// column k = `sign[k]`·(column `axis[k]` of R) and costs no multiplications.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisPermutation {
    pub axis: [usize; 3],
    pub sign: [f64; 3],
}

impl AxisPermutation {
    /// The permutation `r` is exactly, if it is one.
    pub fn of(r: &Matrix3<f64>) -> Option<Self> {
        let mut p = AxisPermutation { axis: [0; 3], sign: [0.0; 3] };
        for k in 0..3 {
            let col = r.column(k);
            let nonzero: Vec<usize> = (0..3).filter(|&i| col[i] != 0.0).collect();
            match nonzero.as_slice() {
                [i] if col[*i].abs() == 1.0 => {
                    p.axis[k] = *i;
                    p.sign[k] = col[*i];
                }
                _ => return None,
            }
        }
        Some(p)
    }
}

fn link_inertia(link: &urdf_rs::Link) -> BodyInertia {
    let i = &link.inertial;
    let local = Matrix3::new(
        i.inertia.ixx,
        i.inertia.ixy,
        i.inertia.ixz, //
        i.inertia.ixy,
        i.inertia.iyy,
        i.inertia.iyz, //
        i.inertia.ixz,
        i.inertia.iyz,
        i.inertia.izz,
    );
    let origin = urdf_pose(&i.origin);
    let r = origin.rotation.matrix();
    BodyInertia { mass: i.mass.value, com: origin.translation.vector, inertia: r * local * r.transpose() }
}

/// Why `inertia` is not a physical inertia tensor [kg·m²], if it is not: it must be finite,
/// symmetric, positive semidefinite, and its principal moments must obey the triangle inequality
/// (each at most the sum of the other two).
fn check_inertia(inertia: &Matrix3<f64>) -> std::result::Result<(), String> {
    if inertia.iter().any(|v| !v.is_finite()) {
        return Err("must be finite".into());
    }
    let scale = inertia.amax().max(1e-300);
    if (inertia - inertia.transpose()).amax() > 1e-9 * scale {
        return Err("must be symmetric".into());
    }
    let moments = inertia.symmetric_eigenvalues();
    let tol = 1e-12 * scale;
    let physical =
        moments.iter().all(|m| *m >= -tol) && (0..3).all(|i| moments[i] <= moments[(i + 1) % 3] + moments[(i + 2) % 3] + tol);
    if !physical {
        return Err(format!("is not a physical inertia tensor (principal moments {:?} kg·m²)", moments.as_slice()));
    }
    Ok(())
}

/// Checks the numbers a URDF gives a link (mass, inertia, their origin) and a joint (origin, limits),
/// so that a bad file fails when it is read rather than as NaN in a later result.
fn check_link(link: &urdf_rs::Link) -> Result<()> {
    let bad = |what: &str, reason: String| PhriError::Urdf {
        arg: "urdf".into(),
        reason: format!("link '{}' has {what} that {reason}", link.name),
    };
    let i = &link.inertial;
    if !(i.mass.value.is_finite() && i.mass.value >= 0.0) {
        return Err(bad("a mass", format!("is not a finite mass >= 0 kg ({})", i.mass.value)));
    }
    if i.origin.xyz.iter().chain(i.origin.rpy.iter()).any(|v| !v.is_finite()) {
        return Err(bad("an inertial origin", "is not finite".into()));
    }
    let inertia = link_inertia(link).inertia;
    check_inertia(&inertia).map_err(|reason| bad("an inertia", reason))
}

fn check_joint(j: &urdf_rs::Joint) -> Result<()> {
    let bad = |reason: String| PhriError::Urdf { arg: "urdf".into(), reason: format!("joint '{}' {reason}", j.name) };
    if j.origin.xyz.iter().chain(j.origin.rpy.iter()).any(|v| !v.is_finite()) {
        return Err(bad("has an origin that is not finite".into()));
    }
    if !matches!(j.joint_type, urdf_rs::JointType::Fixed) {
        let l = &j.limit;
        for (what, v) in [("velocity", l.velocity), ("effort", l.effort)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(format!("has a {what} limit that is not finite and >= 0 ({v})")));
            }
        }
        if !matches!(j.joint_type, urdf_rs::JointType::Continuous) && (l.lower.is_nan() || l.upper.is_nan()) {
            return Err(bad("has a NaN position limit".into()));
        }
    }
    Ok(())
}

/// Heaviest payload [kg] ([`RobotModel::with_payload`]; arms carry tens of kilograms at most).
pub const MAX_PAYLOAD_MASS: f64 = 1000.0;

/// Farthest a payload's centre of mass lies from its frame [m] in each axis.
pub const MAX_PAYLOAD_OFFSET: f64 = 10.0;

/// Largest robot description read [bytes] (32 MiB; the shipped JACO2's is 20 kB, and meshes are
/// separate files).
pub const MAX_URDF_BYTES: usize = 32 << 20;

/// Deepest nesting of XML elements in a robot description [levels]. A URDF nests about 5 deep
/// (robot, link, collision, geometry, box) and extensions a few more; urdf-rs's parser takes time
/// quadratic in the depth and overflows its stack at about 16,000 levels.
pub const MAX_URDF_DEPTH: usize = 64;

/// Checks what makes URDF text costly before it is parsed: its size and its nesting depth (one
/// linear pass). `arg` names the text in errors.
pub(crate) fn check_urdf_text(arg: &str, urdf: &str) -> Result<()> {
    let fail = |reason: String| Err(PhriError::Urdf { arg: arg.into(), reason });
    if urdf.len() > MAX_URDF_BYTES {
        return fail(format!("is {} bytes, more than a robot description may have ({MAX_URDF_BYTES} bytes)", urdf.len()));
    }
    let mut reader = quick_xml::Reader::from_str(urdf);
    let mut depth = 0usize;
    loop {
        match reader.read_event() {
            Ok(quick_xml::events::Event::Start(_)) => {
                depth += 1;
                if depth > MAX_URDF_DEPTH {
                    return fail(format!(
                        "not a valid URDF document (elements nested more than {MAX_URDF_DEPTH} deep, at byte {})",
                        reader.buffer_position()
                    ));
                }
            }
            Ok(quick_xml::events::Event::End(_)) => depth = depth.saturating_sub(1),
            Ok(quick_xml::events::Event::Eof) => return Ok(()),
            Ok(_) => {}
            Err(e) => return fail(format!("not a valid URDF document (XML error at byte {}: {e})", reader.error_position())),
        }
    }
}

/// The text of the URDF file at `path`: a regular file (a FIFO or device would block the reader
/// or never end) of at most [`MAX_URDF_BYTES`]; errors name `arg` and the path.
pub fn read_urdf_file(arg: &str, path: &Path) -> Result<String> {
    use std::io::Read;
    let fail =
        |reason: String| PhriError::Urdf { arg: arg.into(), reason: format!("cannot read '{}': {reason}", path.display()) };
    let meta = std::fs::metadata(path).map_err(|e| fail(e.to_string()))?;
    if !meta.is_file() {
        let what = if meta.is_dir() { "a folder" } else { "not a regular file (a FIFO, socket or device)" };
        return Err(fail(format!("it is {what}")));
    }
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut text = String::new();
    file.take(MAX_URDF_BYTES as u64 + 1).read_to_string(&mut text).map_err(|e| fail(e.to_string()))?;
    if text.len() > MAX_URDF_BYTES {
        return Err(fail(format!("it is larger than a robot description may be ({MAX_URDF_BYTES} bytes)")));
    }
    Ok(text)
}

impl RobotModel {
    /// Reads a URDF file. `base` defaults to the root link; `tip` to the end of the only
    /// leaf-most chain of movable joints (required when the tree branches).
    pub fn from_urdf_file(path: impl AsRef<Path>, base: Option<&str>, tip: Option<&str>) -> Result<Self> {
        let path = path.as_ref();
        let text = read_urdf_file("path", path)?;
        Self::from_urdf_str(&text, base, tip).map_err(|e| match e {
            PhriError::Urdf { arg, reason } if arg == "urdf" => {
                PhriError::Urdf { arg: "path".into(), reason: format!("'{}': {reason}", path.display()) }
            }
            other => other,
        })
    }

    /// Parses URDF text; see [`RobotModel::from_urdf_file`].
    pub fn from_urdf_str(urdf: &str, base: Option<&str>, tip: Option<&str>) -> Result<Self> {
        check_urdf_text("urdf", urdf)?;
        let robot = urdf_rs::read_from_string(urdf)
            .map_err(|e| PhriError::Urdf { arg: "urdf".into(), reason: format!("not a valid URDF document ({e})") })?;
        build(&robot, base, tip)
    }

    /// Number of movable joints in the chain.
    pub fn nq(&self) -> usize {
        self.joints.len()
    }

    /// The id of a frame (any kept URDF link) by name.
    pub fn frame_id(&self, name: &str) -> Result<FrameId> {
        self.frame_index.get(name).map(|&i| FrameId(i)).ok_or_else(|| {
            let mut known: Vec<&str> = self.frames.iter().map(|f| f.name.as_str()).collect();
            known.sort_unstable();
            PhriError::UnknownName { arg: "frame".into(), kind: "frame".into(), name: name.into(), known: known.join(", ") }
        })
    }

    /// Lower position limits [rad or m] (−∞ for continuous joints).
    pub fn lower_limits(&self) -> Vec<f64> {
        self.joints.iter().map(|j| j.lower).collect()
    }

    /// Upper position limits [rad or m] (+∞ for continuous joints).
    pub fn upper_limits(&self) -> Vec<f64> {
        self.joints.iter().map(|j| j.upper).collect()
    }

    /// Effort limits [N·m or N].
    pub fn effort_limits(&self) -> Vec<f64> {
        self.joints.iter().map(|j| j.effort_limit).collect()
    }

    /// Velocity limits [rad/s or m/s].
    pub fn velocity_limits(&self) -> Vec<f64> {
        self.joints.iter().map(|j| j.velocity_limit).collect()
    }

    /// Adds a rigid payload (e.g. a held cup) to the body that carries `frame`.
    /// `com` is the payload's centre of mass in that frame [m], `inertia` about it [kg·m²].
    pub fn with_payload(mut self, frame: FrameId, mass: f64, com: Vector3<f64>, inertia: Matrix3<f64>) -> Result<Self> {
        if !(0.0..=MAX_PAYLOAD_MASS).contains(&mass) {
            return Err(PhriError::invalid("mass", format!("must be in [0, {MAX_PAYLOAD_MASS}] kg, got {mass}")));
        }
        if !com.iter().all(|v| v.abs() <= MAX_PAYLOAD_OFFSET) {
            return Err(PhriError::invalid(
                "com",
                format!("must be within ±{MAX_PAYLOAD_OFFSET} m of the frame in each axis, got {:?}", com.as_slice()),
            ));
        }
        check_inertia(&inertia).map_err(|reason| PhriError::invalid("inertia", reason))?;
        let f = &self.frames[frame.0];
        let payload = BodyInertia { mass, com, inertia }.transformed(&f.body_t_frame);
        self.bodies[f.body] = self.bodies[f.body].combine(&payload);
        Ok(self)
    }
}

/// A URDF's links by name, each link's parent joint and each link's child joints, and its root
/// link; an error unless the links and joints form one tree.
fn tree(robot: &urdf_rs::Robot) -> Result<(Links<'_>, ParentJoints<'_>, ChildJoints<'_>, &str)> {
    let links: HashMap<&str, &urdf_rs::Link> = robot.links.iter().map(|l| (l.name.as_str(), l)).collect();
    if links.len() != robot.links.len() {
        let mut seen = std::collections::HashSet::new();
        let twice = robot.links.iter().find(|l| !seen.insert(l.name.as_str())).map_or("", |l| l.name.as_str());
        return Err(PhriError::Urdf { arg: "urdf".into(), reason: format!("link '{twice}' is defined twice") });
    }
    let mut joint_names = std::collections::HashSet::new();
    if let Some(j) = robot.joints.iter().find(|j| !joint_names.insert(j.name.as_str())) {
        return Err(PhriError::Urdf { arg: "urdf".into(), reason: format!("joint '{}' is defined twice", j.name) });
    }
    let mut parent_joint: HashMap<&str, &urdf_rs::Joint> = HashMap::new();
    let mut children: HashMap<&str, Vec<&urdf_rs::Joint>> = HashMap::new();
    for j in &robot.joints {
        for (which, name) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains_key(name.as_str()) {
                return Err(PhriError::Urdf {
                    arg: "urdf".into(),
                    reason: format!("joint '{}' names {which} link '{name}', which is not defined", j.name),
                });
            }
        }
        if parent_joint.insert(j.child.link.as_str(), j).is_some() {
            return Err(PhriError::Urdf { arg: "urdf".into(), reason: format!("link '{}' has two parent joints", j.child.link) });
        }
        children.entry(j.parent.link.as_str()).or_default().push(j);
    }
    let roots: Vec<&str> = robot.links.iter().map(|l| l.name.as_str()).filter(|n| !parent_joint.contains_key(n)).collect();
    if roots.len() != 1 {
        return Err(PhriError::Urdf { arg: "urdf".into(), reason: format!("expected one root link, found {roots:?}") });
    }
    // One root and one parent per link make a tree only if every link reaches the root: a link
    // whose parents never end within as many steps as there are links is on a cycle.
    for start in links.keys() {
        let mut link = *start;
        for _ in 0..=links.len() {
            match parent_joint.get(link) {
                Some(j) => link = j.parent.link.as_str(),
                None => break,
            }
        }
        if parent_joint.contains_key(link) {
            return Err(PhriError::Urdf {
                arg: "urdf".into(),
                reason: format!("the joints form a cycle through link '{link}' (a URDF must be a tree)"),
            });
        }
    }
    Ok((links, parent_joint, children, roots[0]))
}

/// A URDF's links by name.
type Links<'a> = HashMap<&'a str, &'a urdf_rs::Link>;
/// Each link's parent joint, by the link's name.
type ParentJoints<'a> = HashMap<&'a str, &'a urdf_rs::Joint>;
/// Each link's child joints, by the link's name.
type ChildJoints<'a> = HashMap<&'a str, Vec<&'a urdf_rs::Joint>>;

fn build(robot: &urdf_rs::Robot, base: Option<&str>, tip: Option<&str>) -> Result<RobotModel> {
    let (links, parent_joint, children, root) = tree(robot)?;
    robot.links.iter().try_for_each(check_link)?;
    robot.joints.iter().try_for_each(check_joint)?;
    let known = || {
        let mut names: Vec<&str> = links.keys().copied().collect();
        names.sort_unstable();
        names.join(", ")
    };
    let unknown = |arg: &str, name: &str| PhriError::UnknownName {
        arg: arg.into(),
        kind: "link".into(),
        name: name.into(),
        known: known(),
    };
    let base = base.unwrap_or(root);
    if !links.contains_key(base) {
        return Err(unknown("base", base));
    }
    let is_movable = |j: &urdf_rs::Joint| !matches!(j.joint_type, urdf_rs::JointType::Fixed);
    let tip = match tip {
        Some(t) if !links.contains_key(t) => return Err(unknown("tip", t)),
        Some(t) => t,
        None => default_tip(base, &children, &is_movable)?,
    };

    // The base→tip path, walking up from the tip.
    let mut path: Vec<&urdf_rs::Joint> = Vec::new();
    let mut link = tip;
    while link != base {
        match parent_joint.get(link) {
            Some(j) => {
                path.push(j);
                link = j.parent.link.as_str();
            }
            None => return Err(PhriError::invalid("tip", format!("link '{tip}' is not below the base link '{base}'"))),
        }
    }
    path.reverse();
    let on_path: std::collections::HashSet<&str> = path.iter().map(|j| j.name.as_str()).collect();

    let mut joints: Vec<Joint> = Vec::new();
    let mut bodies: Vec<BodyInertia> = vec![BodyInertia::ZERO];
    let mut frames: Vec<Frame> = Vec::new();
    let mut collision = CollisionModel::default();
    // Depth-first over the subtree below base: (link, body, body_T_link).
    let mut stack: Vec<(&str, usize, Transform)> = vec![(base, 0, Transform::identity())];
    // Chain joints must get body indices in path order; DFS visits a path joint only after its
    // parent body exists, so pushing in visit order keeps them in order along the path.
    while let Some((name, body, body_t_link)) = stack.pop() {
        let link = links[name];
        bodies[body] = bodies[body].combine(&link_inertia(link).transformed(&body_t_link));
        collision.add_urdf_link(link, FrameId(frames.len()), &Transform::identity())?;
        frames.push(Frame { name: name.to_string(), body, body_t_frame: body_t_link });
        for j in children.get(name).map(Vec::as_slice).unwrap_or(&[]) {
            let origin = body_t_link * urdf_pose(&j.origin);
            if on_path.contains(j.name.as_str()) && is_movable(j) {
                joints.push(chain_joint(j, origin)?);
                bodies.push(BodyInertia::ZERO);
                stack.push((j.child.link.as_str(), joints.len(), Transform::identity()));
            } else {
                // Fixed joints, and movable joints off the path locked at q = 0, stay on this body.
                stack.push((j.child.link.as_str(), body, origin));
            }
        }
    }
    if joints.is_empty() {
        return Err(PhriError::invalid("tip", format!("must lie below a movable joint of base '{base}', but '{tip}' does not")));
    }
    let frame_index = frames.iter().enumerate().map(|(i, f)| (f.name.clone(), i)).collect();
    Ok(RobotModel {
        name: robot.name.clone(),
        joints,
        bodies,
        frames,
        gravity: Vector3::new(0.0, 0.0, -STANDARD_GRAVITY),
        frame_index,
        collision,
    })
}

/// The chain joint `j` of the URDF, placed at `origin` in its parent body's frame.
fn chain_joint(j: &urdf_rs::Joint, origin: Transform) -> Result<Joint> {
    let kind = match j.joint_type {
        urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => JointKind::Revolute,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        ref other => {
            return Err(PhriError::Urdf {
                arg: "urdf".into(),
                reason: format!(
                "joint '{}' has type {other:?}; only revolute, continuous, prismatic and fixed joints are supported on the chain",
                j.name
            ),
            })
        }
    };
    let axis = Vector3::new(j.axis.xyz[0], j.axis.xyz[1], j.axis.xyz[2]);
    if !(axis.norm() > 1e-12) || axis.iter().any(|v| !v.is_finite()) {
        return Err(PhriError::Urdf { arg: "urdf".into(), reason: format!("joint '{}' has a zero or invalid axis", j.name) });
    }
    let continuous = matches!(j.joint_type, urdf_rs::JointType::Continuous);
    let (lower, upper) = if continuous { (f64::NEG_INFINITY, f64::INFINITY) } else { (j.limit.lower, j.limit.upper) };
    if !continuous && !(lower <= upper) {
        return Err(PhriError::Urdf {
            arg: "urdf".into(),
            reason: format!("joint '{}' has lower limit {lower} above upper limit {upper}", j.name),
        });
    }
    Ok(Joint {
        name: j.name.clone(),
        kind,
        parent_t_joint: origin,
        permutation: AxisPermutation::of(origin.rotation.matrix()),
        axis: Unit::new_normalize(axis),
        lower,
        upper,
        velocity_limit: j.limit.velocity,
        effort_limit: j.limit.effort,
    })
}

/// The deepest link reached through movable joints, if it is unique.
fn default_tip<'a>(
    base: &'a str,
    children: &HashMap<&'a str, Vec<&'a urdf_rs::Joint>>,
    is_movable: &dyn Fn(&urdf_rs::Joint) -> bool,
) -> Result<&'a str> {
    // (link, movable joints from base): keep the links with the most, then require one.
    let mut best: Vec<&str> = vec![base];
    let mut best_depth = 0;
    let mut stack = vec![(base, 0usize)];
    while let Some((link, depth)) = stack.pop() {
        for j in children.get(link).map(Vec::as_slice).unwrap_or(&[]) {
            let d = depth + usize::from(is_movable(j));
            let child = j.child.link.as_str();
            if d > best_depth {
                best_depth = d;
                best = vec![child];
            } else if d == best_depth && is_movable(j) {
                best.push(child);
            }
            stack.push((child, d));
        }
    }
    match best.as_slice() {
        [one] => Ok(one),
        many => {
            Err(PhriError::invalid("tip", format!("is required: the tree below the base has several deepest links {many:?}")))
        }
    }
}
