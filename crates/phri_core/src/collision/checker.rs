//! The pairs a plan keeps apart — every collision body against every scene object and against
//! the bodies it can meet — and their distances with gradients in q.

use nalgebra::{IsometryMatrix3, Point3, Rotation3, Vector3};

use super::distance::{local, local_distance};
use super::Sphere;
use crate::data::RobotData;
use crate::error::{PhriError, Result};
use crate::model::{JointKind, RobotModel};
use crate::scene::{ObjectKind, Scene};

/// Clearance kept between two bodies of the robot [m].
pub const SELF_MARGIN: f64 = 0.01;

/// Body–body pairs are visited within at most this much beyond their margin [m], whatever band a
/// query asks for: links two joints apart sit a few centimetres from each other along every plan
/// and would otherwise cost a gradient at every point without ever coming near their margin.
pub const SELF_BAND: f64 = 0.02;

/// Poses sampled (a Halton sequence over the joint limits) to find the pairs in contact in every
/// pose, which are left out.
const CONTACT_SAMPLES: usize = 512;

/// What a body is kept away from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Other {
    /// Object `k` of the scene.
    Object(usize),
    /// Collision body `k` of the robot.
    Body(usize),
}

/// A body–object or body–body pair that is checked.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pair {
    body: usize,
    other: Other,
    /// Least distance kept [m].
    margin: f64,
}

/// One sphere pair closer than its margin plus the caller's band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Near {
    /// Index of the checked pair (see [`CollisionChecker::pair_names`]).
    pub pair: usize,
    /// Signed distance between the spheres' surfaces [m].
    pub distance: f64,
    /// The pair's margin [m]: the gap margin − distance is what a plan must keep ≤ 0.
    pub margin: f64,
}

/// The pair closest to (or furthest into) its margin.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    /// The body's name and the object's (or other body's).
    pub body: String,
    pub other: String,
    /// Smallest distance [m] and the pair's margin [m].
    pub distance: f64,
    pub margin: f64,
}

/// Per-query scratch: the spheres' centres in the base frame.
#[derive(Debug, Clone, Default)]
pub struct ProximityScratch {
    centers: Vec<Vec<Vector3<f64>>>,
    bounds: Vec<Vector3<f64>>,
    grad: Vec<f64>,
}

impl ProximityScratch {
    /// Scratch sized for `robot` at once, so that no query allocates (a control tick).
    pub fn for_robot(robot: &RobotModel) -> Self {
        let bodies = robot.collision().bodies();
        ProximityScratch {
            centers: bodies.iter().map(|b| Vec::with_capacity(b.spheres.len())).collect(),
            bounds: vec![Vector3::zeros(); bodies.len()],
            grad: vec![0.0; robot.nq()],
        }
    }
}

/// The checked pairs of one robot in one scene (see the module docs). Immutable; queries write
/// into a [`ProximityScratch`].
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionChecker {
    scene: Scene,
    /// Per scene object: the base frame in its frame, and its rotation in the base frame (as
    /// matrices: cheaper per point than the scene's quaternions).
    object_frames: Vec<(IsometryMatrix3<f64>, Rotation3<f64>)>,
    pairs: Vec<Pair>,
    /// Names of the body pairs left out as in contact in every pose, and of the object pairs.
    excluded: Vec<(String, String)>,
    /// Chain body each collision body moves with.
    chain_body: Vec<usize>,
    names: Vec<String>,
    robot: String,
}

impl CollisionChecker {
    /// The pairs of `robot`'s collision bodies with `scene`'s objects (each with its margin) and
    /// with each other (`self_margin`, None to leave self-collision out). A robot whose collision
    /// model is incomplete is an error: planning cannot check collisions.
    pub fn new(robot: &RobotModel, scene: &Scene, self_margin: Option<f64>) -> Result<Self> {
        if let Some(reason) = robot.collision().incomplete_reason(&robot.name) {
            return Err(PhriError::Planning { reason });
        }
        if let Some(m) = self_margin {
            if !(m >= 0.0 && m.is_finite()) {
                return Err(PhriError::invalid("self_margin", format!("must be a finite distance >= 0 m, got {m}")));
            }
        }
        let bodies = robot.collision().bodies();
        let chain_body: Vec<usize> = bodies.iter().map(|b| robot.frames[b.frame.0].body).collect();
        let mut candidates = Vec::new();
        for b in 0..bodies.len() {
            for (k, object) in scene.objects().iter().enumerate() {
                candidates.push(Pair { body: b, other: Other::Object(k), margin: object.margin() });
            }
        }
        if let Some(margin) = self_margin {
            for a in 0..bodies.len() {
                for b in a + 1..bodies.len() {
                    // Bodies on one chain body never move against each other.
                    if chain_body[a] != chain_body[b] {
                        candidates.push(Pair { body: a, other: Other::Body(b), margin });
                    }
                }
            }
        }
        let names = bodies.iter().map(|b| b.name.clone()).collect();
        let object_frames = scene
            .objects()
            .iter()
            .map(|o| {
                let rotation = o.pose().rotation.to_rotation_matrix();
                (IsometryMatrix3::from_parts(o.pose().translation, rotation).inverse(), rotation)
            })
            .collect();
        let mut checker = CollisionChecker {
            scene: scene.clone(),
            object_frames,
            pairs: candidates,
            excluded: Vec::new(),
            chain_body,
            names,
            robot: robot.name.clone(),
        };
        checker.leave_out_permanent_contacts(robot);
        Ok(checker)
    }

    /// Leaves out the pairs within their margin in every sampled pose.
    fn leave_out_permanent_contacts(&mut self, robot: &RobotModel) {
        let n = robot.nq();
        let mut always = vec![true; self.pairs.len()];
        let (mut data, mut scratch) = (robot.data(), ProximityScratch::default());
        let mut q = vec![0.0; n];
        for k in 1..=CONTACT_SAMPLES {
            for (j, joint) in robot.joints.iter().enumerate() {
                let (lo, hi) = if joint.lower.is_finite() && joint.upper.is_finite() {
                    (joint.lower, joint.upper)
                } else {
                    (-std::f64::consts::PI, std::f64::consts::PI)
                };
                q[j] = lo + (hi - lo) * halton(k, PRIMES[j % PRIMES.len()]);
            }
            robot.forward_kinematics_unchecked(&q, &mut data);
            self.place(robot, &data, &mut scratch);
            for (p, pair) in self.pairs.iter().enumerate() {
                if always[p] && self.pair_distance(robot, &scratch, pair) >= pair.margin {
                    always[p] = false;
                }
            }
        }
        let mut kept = Vec::new();
        for (pair, always) in self.pairs.iter().zip(always) {
            if always {
                self.excluded.push((self.names[pair.body].clone(), self.other_name(pair.other)));
            } else {
                kept.push(*pair);
            }
        }
        self.pairs = kept;
    }

    /// The name of the robot the pairs were made for.
    pub fn robot_name(&self) -> &str {
        &self.robot
    }

    /// Number of collision bodies of that robot.
    pub fn body_count(&self) -> usize {
        self.names.len()
    }

    /// The scene the pairs refer to.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Number of checked pairs.
    pub fn len(&self) -> usize {
        self.pairs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }

    /// (body, object or body) names of checked pair `k`.
    pub fn pair_names(&self, k: usize) -> (String, String) {
        let p = &self.pairs[k];
        (self.names[p.body].clone(), self.other_name(p.other))
    }

    /// The pairs left out because they are within their margin in every pose.
    pub fn excluded(&self) -> &[(String, String)] {
        &self.excluded
    }

    fn other_name(&self, other: Other) -> String {
        match other {
            Other::Object(k) => self.scene.objects()[k].name().to_string(),
            Other::Body(k) => self.names[k].clone(),
        }
    }

    /// Places every sphere in the base frame for the kinematics in `data`.
    pub fn place(&self, robot: &RobotModel, data: &RobotData, scratch: &mut ProximityScratch) {
        let bodies = robot.collision().bodies();
        scratch.centers.resize(bodies.len(), Vec::new());
        scratch.bounds.resize(bodies.len(), Vector3::zeros());
        for (b, body) in bodies.iter().enumerate() {
            let pose = robot.frame_pose(body.frame, data);
            let centers = &mut scratch.centers[b];
            centers.clear();
            centers.extend(body.spheres.iter().map(|s| pose.transform_point(&Point3::from(s.center)).coords));
            scratch.bounds[b] = pose.transform_point(&Point3::from(body.bound.center)).coords;
        }
    }

    /// Smallest signed distance of a pair over its spheres (after [`Self::place`]).
    fn pair_distance(&self, robot: &RobotModel, scratch: &ProximityScratch, pair: &Pair) -> f64 {
        let mut best = f64::INFINITY;
        self.for_each_sphere_pair(robot, scratch, pair, f64::INFINITY, |d, _, _, _| best = best.min(d));
        best
    }

    /// Calls `visit(distance, centre, normal, other centre)` for each sphere pair of `pair` whose
    /// distance is below `within` [m] (the normal is the distance's gradient in the body sphere's
    /// centre; the other centre is None for an object).
    #[inline]
    fn for_each_sphere_pair(
        &self,
        robot: &RobotModel,
        scratch: &ProximityScratch,
        pair: &Pair,
        within: f64,
        mut visit: impl FnMut(f64, &Vector3<f64>, &Vector3<f64>, Option<&Vector3<f64>>),
    ) {
        let bodies = robot.collision().bodies();
        let body = &bodies[pair.body];
        match pair.other {
            Other::Object(k) => {
                let shape = self.scene.objects()[k].shape();
                let (object_t_base, rotation) = &self.object_frames[k];
                let to_local = |p: &Vector3<f64>| (object_t_base * Point3::from(*p)).coords;
                let bound = local_distance(shape, &to_local(&scratch.bounds[pair.body])) - body.bound.radius;
                if bound >= within {
                    return;
                }
                for (s, c) in body.spheres.iter().zip(&scratch.centers[pair.body]) {
                    // The distance first; its gradient only for the spheres within.
                    let p = to_local(c);
                    let d = local_distance(shape, &p) - s.radius;
                    if d < within {
                        let n = rotation * local(shape, &p).1;
                        visit(d, c, &n, None);
                    }
                }
            }
            Other::Body(k) => {
                let other = &bodies[k];
                let gap = (scratch.bounds[pair.body] - scratch.bounds[k]).norm() - body.bound.radius - other.bound.radius;
                if gap >= within {
                    return;
                }
                let other_bound = &scratch.bounds[k];
                for (s, c) in body.spheres.iter().zip(&scratch.centers[pair.body]) {
                    // This sphere against the other body's bound first.
                    if (c - other_bound).norm() - s.radius - other.bound.radius >= within {
                        continue;
                    }
                    for (t, e) in other.spheres.iter().zip(&scratch.centers[k]) {
                        let v = c - e;
                        // Below `within` only if |v| < reach: compared squared, without the root.
                        let reach = within + s.radius + t.radius;
                        if reach <= 0.0 || v.norm_squared() >= reach * reach {
                            continue;
                        }
                        let r = v.norm();
                        let d = r - s.radius - t.radius;
                        if d < within {
                            let n = if r > 0.0 { v / r } else { Vector3::z() };
                            visit(d, c, &n, Some(e));
                        }
                    }
                }
            }
        }
    }

    /// Calls `visit(near, gradient)` for every sphere pair closer than its margin + `band` [m] for
    /// the kinematics in `data`, with the distance's gradient in q (nq entries).
    pub fn for_each_near(
        &self,
        robot: &RobotModel,
        data: &RobotData,
        scratch: &mut ProximityScratch,
        band: f64,
        mut visit: impl FnMut(&Near, &[f64]),
    ) {
        self.place(robot, data, scratch);
        let n = robot.nq();
        let mut grad = std::mem::take(&mut scratch.grad);
        grad.resize(n, 0.0);
        for (k, pair) in self.pairs.iter().enumerate() {
            let body = self.chain_body[pair.body];
            let other_body = match pair.other {
                Other::Body(b) => Some(self.chain_body[b]),
                Other::Object(_) => None,
            };
            let within = pair.margin + if other_body.is_some() { band.min(SELF_BAND) } else { band };
            self.for_each_sphere_pair(robot, scratch, pair, within, |d, c, normal, e| {
                grad.fill(0.0);
                point_gradient(robot, data, body, c, normal, 1.0, &mut grad);
                if let (Some(other), Some(e)) = (other_body, e) {
                    point_gradient(robot, data, other, e, normal, -1.0, &mut grad);
                }
                visit(&Near { pair: k, distance: d, margin: pair.margin }, &grad);
            });
        }
        scratch.grad = grad;
    }

    /// The pair nearest to (or furthest into) its margin for the kinematics in `data`: the one
    /// with the least distance − margin; None without pairs.
    pub fn worst(&self, robot: &RobotModel, data: &RobotData, scratch: &mut ProximityScratch) -> Option<Violation> {
        self.worst_below(robot, data, scratch, f64::INFINITY).map(|(k, slack)| self.violation(k, slack))
    }

    /// The pair with the least distance − margin (its index and that slack [m]) for the kinematics
    /// in `data`, among the pairs whose slack is below `below` [m]: None if there are none. The
    /// first such pair in the checker's order on ties, as [`Self::worst`].
    pub(crate) fn worst_below(
        &self,
        robot: &RobotModel,
        data: &RobotData,
        scratch: &mut ProximityScratch,
        below: f64,
    ) -> Option<(usize, f64)> {
        self.place(robot, data, scratch);
        let mut worst: Option<(usize, f64)> = None;
        for (k, pair) in self.pairs.iter().enumerate() {
            // Only sphere pairs closer than the worst so far matter (the bounds skip the rest).
            let within = worst.map_or(below, |(_, w)| w) + pair.margin;
            let mut nearest = f64::INFINITY;
            self.for_each_sphere_pair(robot, scratch, pair, within, |d, _, _, _| nearest = nearest.min(d));
            if nearest < within {
                worst = Some((k, nearest - pair.margin));
            }
        }
        worst
    }

    /// Pair `k` at `slack` [m] beyond its margin, named.
    pub(crate) fn violation(&self, k: usize, slack: f64) -> Violation {
        let (body, other) = self.pair_names(k);
        Violation { body, other, distance: slack + self.pairs[k].margin, margin: self.pairs[k].margin }
    }

    /// Whether pair `k` is a body against furniture (the pairs a run-time wall acts on).
    pub fn is_furniture(&self, k: usize) -> bool {
        matches!(self.pairs[k].other, Other::Object(o) if self.scene.objects()[o].kind() == ObjectKind::Furniture)
    }
}

/// grad += sign·∂(n·p)/∂q for a point p moving with chain body `body`: for each joint i before it,
/// revolute: n·(z_i × (p − o_i)); prismatic: n·z_i.
#[inline]
pub(crate) fn point_gradient(
    robot: &RobotModel,
    data: &RobotData,
    body: usize,
    p: &Vector3<f64>,
    n: &Vector3<f64>,
    sign: f64,
    grad: &mut [f64],
) {
    for (i, joint) in robot.joints.iter().enumerate().take(body) {
        let z = &data.axis[i];
        let g = match joint.kind {
            JointKind::Revolute => z.dot(&(p - data.base_t_body[i + 1].translation.vector).cross(n)),
            JointKind::Prismatic => z.dot(n),
        };
        grad[i] += sign * g;
    }
}

const PRIMES: [usize; 12] = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37];

/// Element `k` of the van der Corput sequence in `base` (a Halton coordinate), in [0, 1).
fn halton(mut k: usize, base: usize) -> f64 {
    let (mut x, mut f) = (0.0, 1.0);
    while k > 0 {
        f /= base as f64;
        x += f * (k % base) as f64;
        k /= base;
    }
    x
}

impl Sphere {
    /// A sphere of `radius` [m] at `center` [m].
    pub fn new(center: Vector3<f64>, radius: f64) -> Self {
        Sphere { center, radius }
    }
}
