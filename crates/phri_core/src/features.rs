//! Task features φ and trajectory feature counts Φ(ξ) with analytic gradients and second derivatives.
//!
//! A trajectory ξ is N waypoints of the robot's joints (N × n, one waypoint per row). As in the
//! authors' code, Φ(ξ) = Σ_{i=1}^{N-1} φ(q_{i-1}, q_i): every feature is evaluated on the segment that
//! ends at waypoint i, and waypoint 0 (where the robot already is) contributes nothing.
//!
//! # Adding a feature
//! Implement [`Feature`]: `segment` returns φ for one segment and, when asked, adds the scaled
//! gradient with respect to both end waypoints (and, when the optimiser asks, the scaled second
//! derivatives into [`SegmentGrad::hessian`]; a feature that ignores it still works, the optimiser
//! then learns its curvature more slowly). Ask the [`Segment`] for the kinematics of any point along
//! it (`seg.point(s)`, `seg.jacobian(s)` for s ∈ [0, 1]); they are computed once per evaluation
//! (the end points once per waypoint, shared by the two segments that meet there) and shared by all
//! features. Then pass `Box::new(YourFeature)` to [`FeatureSet::new`].

use std::sync::Arc;

use nalgebra::{Matrix3, Matrix6xX, Vector2, Vector3};

use crate::block_tridiagonal::BlockTridiagonal;
use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::kinematics::{direction_hessian, position_hessian};
use crate::model::{FrameId, JointKind, RobotModel};

/// Kinematics of the feature frame (link_7 by default) at one configuration.
#[derive(Debug, Clone, Copy)]
pub struct Point {
    /// Origin of the feature frame in the base frame [m].
    pub position: Vector3<f64>,
    /// Orientation of the feature frame in the base frame.
    pub rotation: Matrix3<f64>,
}

/// Where a feature adds its derivatives: `prev += scale·∂φ/∂q_{i-1}`, `this += scale·∂φ/∂q_i`, and,
/// when `hessian` is given, `hessian += scale·∂²φ/∂(q_{i-1}, q_i)²`.
pub struct SegmentGrad<'a> {
    pub scale: f64,
    pub prev: &'a mut [f64],
    pub this: &'a mut [f64],
    /// Second derivatives, asked for by the Newton optimiser (None otherwise).
    pub hessian: Option<&'a mut SegmentHessian>,
    /// Where a kinked feature reports its pieces that are off now but may turn on within a step
    /// (asked for by the Newton optimiser along with `hessian`; None otherwise).
    pub pieces: Option<&'a mut Pieces>,
}

/// Inactive hinge pieces for the optimiser's model. A piece is a term ½·c·max(0, f)² of the cost
/// whose argument f, at the point q(s) = q_{i-1} + s·(q_i − q_{i-1}) of a segment, is f0 ≤ 0 now
/// and varies as f0 + a·Δq(s) with a step Δ. The model adds it once a step would turn it on, so a
/// Newton step does not run blindly across a kink (e.g. back into a keep-out circle).
#[derive(Debug, Clone)]
pub struct Pieces {
    n: usize,
    segment: usize,
    pub(crate) list: Vec<Piece>,
    pub(crate) a: Vec<f64>,
}

/// One entry of [`Pieces`]: at waypoints (segment − 1, segment), parameter s; f0; curvature c.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Piece {
    pub(crate) segment: usize,
    pub(crate) s: f64,
    pub(crate) f0: f64,
    pub(crate) c: f64,
}

impl Pieces {
    /// Empty, for `n` joints.
    pub fn new(n: usize) -> Self {
        Pieces { n, segment: 0, list: Vec::new(), a: Vec::new() }
    }

    /// Number of pieces.
    pub fn len(&self) -> usize {
        self.list.len()
    }

    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    pub fn clear(&mut self) {
        self.list.clear();
        self.a.clear();
    }

    /// The segment (its end waypoint i) that following pushes belong to.
    pub(crate) fn set_segment(&mut self, i: usize) {
        self.segment = i;
    }

    /// Adds the piece ½·`c`·max(0, f)² with f = `f0` + Σ_j a(j)·Δq_j(s) at the point q(s).
    pub fn push(&mut self, s: f64, f0: f64, c: f64, a: impl Fn(usize) -> f64) {
        self.list.push(Piece { segment: self.segment, s, f0, c });
        self.a.extend((0..self.n).map(a));
    }
}

/// Second derivatives of one segment's cost with respect to (q_{i-1}, q_i): a symmetric 2n × 2n
/// matrix, row-major, q_{i-1} first. Features add to it with the helpers below; a quantity of the
/// point q(s) = q_{i-1} + s·(q_i − q_{i-1}) with derivative v and Hessian H in q maps to the segment
/// as [(1−s)v, s·v] and [[(1−s)²H, s(1−s)H], [s(1−s)H, s²H]]. Terms at the same s are summed in
/// an n × n buffer and mapped once.
#[derive(Debug, Clone)]
pub struct SegmentHessian {
    n: usize,
    /// Whether to include second derivatives of the kinematics (see [`SegmentHessian::kinematic`]).
    kinematic: bool,
    m: Vec<f64>,
    v: Vec<f64>,
    /// Pending n × n Hessian at the point `pending`.
    h: Vec<f64>,
    pending: Option<f64>,
    tmp: Vec<f64>,
}

impl SegmentHessian {
    /// A zero matrix for `n` joints.
    pub fn new(n: usize) -> Self {
        SegmentHessian {
            n,
            kinematic: true,
            m: vec![0.0; 4 * n * n],
            v: vec![0.0; n],
            h: vec![0.0; n * n],
            pending: None,
            tmp: vec![0.0; n * n],
        }
    }

    /// Number of joints n (the matrix is 2n × 2n).
    pub fn dof(&self) -> usize {
        self.n
    }

    /// Whether the caller wants the terms with second derivatives of the kinematics (∂²p/∂q²,
    /// ∂²R/∂q²) of features that act at every waypoint (table, coffee, origin). True for the exact
    /// Hessian ([`FeatureSet::weighted_cost_curvature`]); the optimiser asks without them until
    /// its active set settles (`TrajoptParams::kinematic_curvature`): far from the optimum they
    /// make its model indefinite along the whole path and force heavy damping, while their
    /// Gauss–Newton part models these features well. Keep-out features keep them near their kink,
    /// where they decide the final convergence.
    pub fn kinematic(&self) -> bool {
        self.kinematic
    }

    /// Entry (r, c), r and c in 0..2n (terms still pending are not included; see `flush`).
    pub fn get(&self, r: usize, c: usize) -> f64 {
        self.m[r * 2 * self.n + c]
    }

    /// The 2n × 2n matrix, row-major, after [`SegmentHessian::flush`].
    pub fn matrix(&self) -> &[f64] {
        &self.m
    }

    /// Sets every entry to 0.
    pub fn clear(&mut self) {
        self.m.fill(0.0);
        self.h.fill(0.0);
        self.pending = None;
    }

    /// Adds `weight`·[[I, −I], [−I, I]] (the Hessian of weight·‖q_i − q_{i-1}‖²/2).
    pub fn add_difference(&mut self, weight: f64) {
        let (n, w) = (self.n, 2 * self.n);
        for j in 0..n {
            self.m[j * w + j] += weight;
            self.m[(n + j) * w + n + j] += weight;
            self.m[j * w + n + j] -= weight;
            self.m[(n + j) * w + j] -= weight;
        }
    }

    fn pending_at(&mut self, s: f64) {
        if self.pending != Some(s) {
            self.flush();
            self.pending = Some(s);
        }
    }

    /// Maps the pending n × n terms into the segment's matrix.
    pub fn flush(&mut self) {
        let Some(s) = self.pending.take() else { return };
        let (n, w) = (self.n, 2 * self.n);
        let (aa, ab, bb) = ((1.0 - s) * (1.0 - s), s * (1.0 - s), s * s);
        for r in 0..n {
            for c in 0..n {
                let x = self.h[r * n + c];
                self.m[(n + r) * w + n + c] += bb * x;
                if ab != 0.0 {
                    self.m[r * w + c] += aa * x;
                    self.m[r * w + n + c] += ab * x;
                    self.m[(n + r) * w + c] += ab * x;
                }
            }
        }
        self.h.fill(0.0);
    }

    /// Adds `weight`·u·uᵀ with u = [(1−s)v, s·v] and v_j = `v(j)`, the derivative in q of a quantity
    /// at the point q(s) (a Gauss–Newton term).
    pub fn add_outer(&mut self, s: f64, weight: f64, v: impl Fn(usize) -> f64) {
        self.pending_at(s);
        let n = self.n;
        for j in 0..n {
            self.v[j] = v(j);
        }
        for r in 0..n {
            let vr = weight * self.v[r];
            if vr == 0.0 {
                continue;
            }
            for c in 0..n {
                self.h[r * n + c] += vr * self.v[c];
            }
        }
    }

    /// The n × n matrix the curvature helpers fill (exposed for custom features): fill it with a
    /// Hessian in q at a point, then call [`SegmentHessian::add_scratch_at`].
    pub fn scratch(&mut self) -> &mut [f64] {
        &mut self.tmp
    }

    /// Adds `weight`·(the scratch matrix) as the Hessian at the point q(s).
    pub fn add_scratch_at(&mut self, s: f64, weight: f64) {
        self.pending_at(s);
        for (h, t) in self.h.iter_mut().zip(&self.tmp) {
            *h += weight * t;
        }
    }
}

#[derive(Clone)]
struct Sample {
    s: f64,
    point: Point,
    jacobian: Matrix6xX<f64>,
    has_jacobian: bool,
}

/// Kinematics of one waypoint, valid for the evaluation whose epoch it carries.
#[derive(Clone)]
struct WaypointKin {
    data: RobotData,
    /// (sin, cos) of every joint position, for the samples of the segments that meet here.
    sin_cos: Vec<(f64, f64)>,
    point: Point,
    jacobian: Matrix6xX<f64>,
    epoch: u64,
    jacobian_epoch: u64,
}

/// Per-segment kinematics cache, shared by all features of a [`FeatureSet`].
pub struct Segment<'a> {
    /// Start waypoint q_{i-1} [rad].
    pub q_prev: &'a [f64],
    /// End waypoint q_i [rad].
    pub q: &'a [f64],
    /// Smoothing width δ for kinked features (0 = exact); set by the optimiser, see [`huber`].
    pub smoothing: f64,
    /// Index i of the segment's end waypoint.
    index: usize,
    ws: &'a mut Workspace,
}

#[derive(Clone)]
struct Workspace {
    model: Arc<RobotModel>,
    frame: FrameId,
    /// Per joint j, a bound on the distance from joint j's axis to the feature frame's origin [m]
    /// (None when a prismatic joint makes it unbounded); see [`Segment::travel_bound`].
    reach: Option<Vec<f64>>,
    /// Evaluation counter: waypoint kinematics carrying an older epoch are stale.
    epoch: u64,
    waypoints: Vec<WaypointKin>,
    /// Intermediate samples of the current segment.
    data: RobotData,
    /// Configuration whose forward kinematics is in `data` (as a sample parameter s).
    data_s: Option<f64>,
    q_s: Vec<f64>,
    samples: Vec<Sample>,
    used: usize,
}

impl Workspace {
    /// Forward kinematics at q_{i-1} + s·(q_i − q_{i-1}) into `data`, for the segment ending at
    /// waypoint `i` (s ∈ (0, 1)). The sines and cosines come from waypoint i−1's by the angle
    /// addition formulas with short Taylor series for the small angle s·Δq (measured: libm's sincos
    /// was a quarter of a keep-out feature's evaluation).
    fn fk_at(&mut self, i: usize, q_prev: &[f64], q: &[f64], s: f64) {
        if self.data_s != Some(s) {
            self.waypoint(i - 1, q_prev);
            for ((out, a), b) in self.q_s.iter_mut().zip(q_prev).zip(q) {
                *out = a + s * (b - a);
            }
            let (base, q_s) = (&self.waypoints[i - 1].sin_cos, &self.q_s);
            let sin_cos = |j: usize| {
                let d = q_s[j] - q_prev[j];
                if d.abs() > SMALL_ANGLE {
                    return q_s[j].sin_cos();
                }
                let (sd, cd) = small_sin_cos(d);
                let (sa, ca) = base[j];
                (sa * cd + ca * sd, ca * cd - sa * sd)
            };
            self.model.forward_kinematics_with(&self.q_s, sin_cos, &mut self.data);
            self.data_s = Some(s);
        }
    }

    /// Starts an evaluation of a trajectory of `waypoints` rows: all cached kinematics go stale.
    fn begin(&mut self, waypoints: usize) {
        self.epoch += 1;
        if self.waypoints.len() < waypoints {
            let nq = self.model.nq();
            let blank = WaypointKin {
                data: self.model.data(),
                sin_cos: vec![(0.0, 1.0); nq],
                point: Point { position: Vector3::zeros(), rotation: Matrix3::identity() },
                jacobian: Matrix6xX::zeros(nq),
                epoch: 0,
                jacobian_epoch: 0,
            };
            self.waypoints.resize(waypoints, blank);
        }
    }

    /// Forward kinematics of waypoint `i` at `q`, computed once per evaluation.
    fn waypoint(&mut self, i: usize, q: &[f64]) -> &mut WaypointKin {
        let w = &mut self.waypoints[i];
        if w.epoch != self.epoch {
            for (sc, v) in w.sin_cos.iter_mut().zip(q) {
                *sc = v.sin_cos();
            }
            let sin_cos = &w.sin_cos;
            self.model.forward_kinematics_with(q, |j| sin_cos[j], &mut w.data);
            let pose = self.model.frame_pose(self.frame, &w.data);
            w.point = Point { position: pose.translation.vector, rotation: *pose.rotation.matrix() };
            w.epoch = self.epoch;
        }
        w
    }

    fn waypoint_jacobian(&mut self, i: usize, q: &[f64]) -> &Matrix6xX<f64> {
        let epoch = self.epoch;
        self.waypoint(i, q);
        let w = &mut self.waypoints[i];
        if w.jacobian_epoch != epoch {
            self.model.frame_jacobian_unchecked(self.frame, &w.data, &mut w.jacobian);
            w.jacobian_epoch = epoch;
        }
        &self.waypoints[i].jacobian
    }
}

/// Angles up to this size [rad] take [`small_sin_cos`] in [`Workspace::fk_at`].
const SMALL_ANGLE: f64 = 0.25;

/// (sin d, cos d) for |d| ≤ [`SMALL_ANGLE`] by Taylor series to d¹¹ and d¹²: the remainders are
/// below 3·10⁻¹⁸ there, under half an ulp of the results.
#[inline(always)]
fn small_sin_cos(d: f64) -> (f64, f64) {
    let x = d * d;
    let t = |k: f64| x * (1.0 / k); // x/k as a multiplication (the reciprocals fold at compile time)
    let s = d * (1.0 - t(6.0) * (1.0 - t(20.0) * (1.0 - t(42.0) * (1.0 - t(72.0) * (1.0 - t(110.0))))));
    let c = 1.0 - t(2.0) * (1.0 - t(12.0) * (1.0 - t(30.0) * (1.0 - t(56.0) * (1.0 - t(90.0) * (1.0 - t(132.0))))));
    (s, c)
}

/// Bounds on the distance from each joint's axis to `frame`'s origin, from the chain's link offsets
/// (triangle inequality); None when a prismatic joint lies between them.
fn reach_bounds(model: &RobotModel, frame: FrameId) -> Option<Vec<f64>> {
    let f = &model.frames[frame.0];
    let joints = &model.joints;
    if joints[..f.body.min(joints.len())].iter().any(|j| j.kind == JointKind::Prismatic) {
        return None;
    }
    let mut reach = vec![0.0; joints.len()];
    let mut acc = f.body_t_frame.translation.vector.norm();
    for j in (0..f.body.min(joints.len())).rev() {
        // Joint j's origin is body j+1's origin; joint j+1's origin sits at its offset from it.
        reach[j] = acc;
        acc += joints[j].parent_t_joint.translation.vector.norm();
    }
    Some(reach)
}

impl Segment<'_> {
    fn index(&mut self, s: f64) -> usize {
        if let Some(i) = self.ws.samples[..self.ws.used].iter().position(|x| x.s == s) {
            return i;
        }
        let (q_prev, q) = (self.q_prev, self.q);
        self.ws.fk_at(self.index, q_prev, q, s);
        let pose = self.ws.model.frame_pose(self.ws.frame, &self.ws.data);
        let point = Point { position: pose.translation.vector, rotation: *pose.rotation.matrix() };
        let nq = self.ws.model.nq();
        if self.ws.used == self.ws.samples.len() {
            self.ws.samples.push(Sample { s, point, jacobian: Matrix6xX::zeros(nq), has_jacobian: false });
        } else {
            let slot = &mut self.ws.samples[self.ws.used];
            slot.s = s;
            slot.point = point;
            slot.has_jacobian = false;
        }
        self.ws.used += 1;
        self.ws.used - 1
    }

    /// Feature-frame kinematics at q_{i-1} + s·(q_i − q_{i-1}), s ∈ [0, 1]. The end points (s = 0
    /// and s = 1) are the waypoints themselves, computed once per evaluation.
    pub fn point(&mut self, s: f64) -> Point {
        if s == 1.0 {
            return self.ws.waypoint(self.index, self.q).point;
        }
        if s == 0.0 {
            return self.ws.waypoint(self.index - 1, self.q_prev).point;
        }
        let i = self.index(s);
        self.ws.samples[i].point
    }

    /// World-aligned 6×n Jacobian of the feature frame at the same point as [`Segment::point`].
    pub fn jacobian(&mut self, s: f64) -> &Matrix6xX<f64> {
        if s == 1.0 {
            return self.ws.waypoint_jacobian(self.index, self.q);
        }
        if s == 0.0 {
            return self.ws.waypoint_jacobian(self.index - 1, self.q_prev);
        }
        let i = self.index(s);
        if !self.ws.samples[i].has_jacobian {
            let (q_prev, q) = (self.q_prev, self.q);
            self.ws.fk_at(self.index, q_prev, q, s);
            let ws = &mut *self.ws;
            ws.model.frame_jacobian_unchecked(ws.frame, &ws.data, &mut ws.samples[i].jacobian);
            ws.samples[i].has_jacobian = true;
        }
        &self.ws.samples[i].jacobian
    }

    /// An upper bound on how far the feature frame's origin travels along the segment [m]:
    /// Σ_j reach_j·|q_i,j − q_{i-1},j|, reach_j bounding the distance from joint j's axis to the
    /// origin (from the model's link offsets). Every point of the segment lies within s·L of the
    /// start and (1 − s)·L of the end. None when the model has prismatic joints.
    pub fn travel_bound(&self) -> Option<f64> {
        let reach = self.ws.reach.as_ref()?;
        Some(reach.iter().zip(self.q).zip(self.q_prev).map(|((r, a), b)| r * (a - b).abs()).sum())
    }

    /// Adds `weight`·Σ_c g_c·∂²p_c/∂ξ² to `hessian`, p the feature frame's origin at q(s): the
    /// curvature of a cost whose gradient in p is g.
    pub fn add_position_curvature(&mut self, s: f64, g: &Vector3<f64>, weight: f64, hessian: &mut SegmentHessian) {
        let jac = self.jacobian(s);
        position_hessian(jac, g, &mut hessian.tmp);
        hessian.add_scratch_at(s, weight);
    }

    /// Adds `weight`·Σ_c w_c·∂²R_{c,col}/∂ξ² to `hessian`, R the feature frame's rotation at q(s):
    /// the curvature of a cost whose gradient in the frame's axis `col` is w.
    pub fn add_axis_curvature(&mut self, s: f64, col: usize, w: &Vector3<f64>, weight: f64, hessian: &mut SegmentHessian) {
        let x: Vector3<f64> = self.point(s).rotation.column(col).into();
        let jac = self.jacobian(s);
        direction_hessian(jac, &x, w, &mut hessian.tmp);
        hessian.add_scratch_at(s, weight);
    }
}

/// Lets a `Box<dyn Feature>` be cloned; implemented for every `Feature + Clone` automatically.
pub trait FeatureClone {
    fn clone_box(&self) -> Box<dyn Feature>;
}

impl<T: Feature + Clone + 'static> FeatureClone for T {
    fn clone_box(&self) -> Box<dyn Feature> {
        Box::new(self.clone())
    }
}

impl Clone for Box<dyn Feature> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

/// One per-segment feature φ(q_{i-1}, q_i). Derive `Clone` on your type (see [`FeatureClone`]).
pub trait Feature: FeatureClone + Send + Sync {
    /// The feature's name (unique within a set).
    fn name(&self) -> &str;
    /// φ on this segment; if `grad` is given, adds the scaled gradient to it.
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64;
    /// How the feature's total over a fixed path grows with the number of segments S the path is
    /// cut into: Φ ∝ S^e. The default, 1, fits sums of a quantity at every waypoint or at points
    /// along every segment; a sum of squared differences between consecutive waypoints (like
    /// [`Efficiency`]) has −1. The optimiser's coarse levels weigh the feature by it (see
    /// `trajopt`, multiresolution; a wrong value makes their initial guess worse), and so does
    /// [`FeatureSet::rescale_weights`] (a wrong value there poses another trade-off).
    fn resolution_exponent(&self) -> i32 {
        1
    }
}

/// Path length in joint space: φ = ‖q_i − q_{i-1}‖² [rad²].
#[derive(Debug, Clone, Copy, Default)]
pub struct Efficiency;

impl Feature for Efficiency {
    fn name(&self) -> &str {
        "efficiency"
    }
    fn resolution_exponent(&self) -> i32 {
        -1
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let mut value = 0.0;
        match grad {
            Some(g) => {
                for j in 0..seg.q.len() {
                    let d = seg.q[j] - seg.q_prev[j];
                    value += d * d;
                    g.this[j] += 2.0 * g.scale * d;
                    g.prev[j] -= 2.0 * g.scale * d;
                }
                if let Some(h) = g.hessian {
                    h.add_difference(2.0 * g.scale);
                }
            }
            None => value = seg.q.iter().zip(seg.q_prev).map(|(a, b)| (a - b) * (a - b)).sum(),
        }
        value
    }
}

/// Height of the feature frame's origin above `height` [m] at q_i (the original uses raw z: height 0).
#[derive(Debug, Clone, Default)]
pub struct Table {
    pub height: f64,
}

impl Feature for Table {
    fn name(&self) -> &str {
        "table"
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let value = seg.point(1.0).position.z - self.height;
        if let Some(g) = grad {
            let jac = seg.jacobian(1.0);
            for j in 0..g.this.len() {
                g.this[j] += g.scale * jac[(2, j)];
            }
            if let Some(h) = g.hessian {
                if h.kinematic() {
                    seg.add_position_curvature(1.0, &Vector3::z(), g.scale, h);
                }
            }
        }
        value
    }
}

/// How the cup's tilt is measured. The cup's axis is the feature frame's x axis, x = R[:, 0].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CoffeeForm {
    /// |R₀₀| + |R₁₀|: the horizontal part of x, 0 when upright (the original); subgradient 0 at 0.
    Horizontal,
    /// 1 − x·ẑ: 0 upright, 2 upside down (the later variant); smooth.
    Dot,
}

/// Cup tilt at q_i.
#[derive(Debug, Clone)]
pub struct Coffee {
    pub form: CoffeeForm,
}

impl Feature for Coffee {
    fn name(&self) -> &str {
        match self.form {
            CoffeeForm::Horizontal => "coffee",
            CoffeeForm::Dot => "coffee_dot",
        }
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let x: Vector3<f64> = seg.point(1.0).rotation.column(0).into();
        let delta = seg.smoothing;
        let (value, weights) = match self.form {
            CoffeeForm::Horizontal => {
                let ((a, da), (b, db)) = (huber(x.x, delta), huber(x.y, delta));
                (a + b, Vector3::new(da, db, 0.0))
            }
            CoffeeForm::Dot => (1.0 - x.z, Vector3::new(0.0, 0.0, -1.0)),
        };
        if let Some(g) = grad {
            // ∂x/∂q_j = ω_j × x, with ω_j the angular rows of the Jacobian.
            let jac = seg.jacobian(1.0);
            let dx = |j: usize| Vector3::new(jac[(3, j)], jac[(4, j)], jac[(5, j)]).cross(&x);
            for j in 0..g.this.len() {
                g.this[j] += g.scale * weights.dot(&dx(j));
            }
            if let Some(h) = g.hessian {
                if self.form == CoffeeForm::Horizontal {
                    // Huber's curvature 1/δ inside its quadratic zone (Gauss–Newton term).
                    for c in 0..2 {
                        let k = huber_curvature(x[c], delta);
                        if k > 0.0 {
                            h.add_outer(1.0, g.scale * k, |j| dx(j)[c]);
                        }
                    }
                }
                if h.kinematic() {
                    seg.add_axis_curvature(1.0, 0, &weights, g.scale, h);
                }
            }
        }
        value
    }
}

/// Huber smoothing of |x| with width δ: x²/(2δ) for |x| < δ, |x| − δ/2 beyond; returns (value,
/// derivative). δ = 0 gives |x| with subgradient 0 at 0. The optimiser uses δ > 0 so L-BFGS sees a
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
fn huber_curvature(x: f64, delta: f64) -> f64 {
    let a = x.abs();
    if a > 0.0 || delta > 0.0 {
        1.0 / a.max(delta)
    } else {
        0.0
    }
}

/// Curvature of [`smooth_hinge`] for the optimiser's model, as [`huber_curvature`]: 1/max(x, δ)
/// where the hinge is active, 0 on its flat side.
fn smooth_hinge_curvature(x: f64, delta: f64) -> f64 {
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

/// Penetration into a vertical cylinder: φ = Σ_k max(0, r − ‖p_xy(s_k) − c‖) over `samples` points
/// s_k = k/samples along the segment (q_{i-1}, q_i] [m]. The original's laptop and human features.
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
}

impl Keepout {
    pub fn laptop() -> Self {
        Keepout { name: "laptop".into(), center: Vector2::new(-0.7929, -0.1), radius: 0.4, samples: 4 }
    }
    pub fn human() -> Self {
        Keepout { name: "human".into(), center: Vector2::new(0.0, 0.2), radius: 0.4, samples: 4 }
    }
}

impl Feature for Keepout {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, mut grad: Option<SegmentGrad<'_>>) -> f64 {
        let distance = |p: Vector3<f64>| Vector2::new(p.x - self.center.x, p.y - self.center.y).norm();
        // Conservative skip (see the type's docs): the bound is exact, so results do not change.
        let skip =
            seg.travel_bound().map(|travel| (distance(seg.point(0.0).position), distance(seg.point(1.0).position), travel));
        // The optimiser's model also wants the samples just outside (see [`Pieces`]).
        let delta = seg.smoothing;
        let margin = match grad.as_ref() {
            Some(g) if g.pieces.is_some() && delta > 0.0 => PIECE_MARGIN * self.radius,
            _ => 0.0,
        };
        let mut value = 0.0;
        for k in 1..=self.samples {
            let s = k as f64 / self.samples as f64;
            if let Some((d0, d1, travel)) = skip {
                if (d0 - s * travel).max(d1 - (1.0 - s) * travel) >= self.radius + margin + 1e-9 {
                    continue;
                }
            }
            let p = seg.point(s).position;
            let d = Vector2::new(p.x - self.center.x, p.y - self.center.y);
            let dist = d.norm();
            if dist >= self.radius {
                if dist < self.radius + margin {
                    if let Some(pieces) = grad.as_mut().and_then(|g| g.pieces.as_deref_mut().map(|p| (p, g.scale))) {
                        let (pieces, scale) = pieces;
                        let u = d / dist;
                        let jac = seg.jacobian(s);
                        pieces.push(s, self.radius - dist, scale / delta, |j| -(u.x * jac[(0, j)] + u.y * jac[(1, j)]));
                    }
                }
                continue;
            }
            let (v, slope) = smooth_hinge(self.radius - dist, delta);
            value += v;
            if let Some(g) = grad.as_mut() {
                if dist > 0.0 && slope > 0.0 {
                    let u = d / dist;
                    let jac = seg.jacobian(s);
                    // a = ∂(r − dist)/∂q, b = ∂(dist along the tangent)/∂q.
                    let a = |j: usize| -(u.x * jac[(0, j)] + u.y * jac[(1, j)]);
                    let b = |j: usize| -u.y * jac[(0, j)] + u.x * jac[(1, j)];
                    for j in 0..g.this.len() {
                        let dphi = a(j) * slope * g.scale;
                        g.this[j] += s * dphi;
                        g.prev[j] += (1.0 - s) * dphi;
                    }
                    if let Some(h) = g.hessian.as_deref_mut() {
                        // ∂²φ = h''·a·aᵀ − h'·(b·bᵀ/dist + Σ_c u_c ∂²p_c) (c = x, y), with the
                        // hinge's curvature h'' for the model (see `smooth_hinge_curvature`).
                        let curvature = smooth_hinge_curvature(self.radius - dist, delta);
                        if curvature > 0.0 {
                            h.add_outer(s, g.scale * curvature, a);
                        }
                        // The geometric (indefinite) terms only near the kink, where they matter for
                        // the final convergence; deep inside the circle they would force heavy
                        // damping (−1/dist near the centre) for no benefit.
                        if self.radius - dist < delta {
                            h.add_outer(s, -g.scale * slope / dist, b);
                            seg.add_position_curvature(s, &Vector3::new(u.x, u.y, 0.0), -g.scale * slope, h);
                        }
                    }
                }
            }
        }
        value
    }
}

/// How far outside a keep-out circle (as a fraction of its radius) samples are reported to the
/// optimiser's model as [`Pieces`].
const PIECE_MARGIN: f64 = 0.1;

/// Distance of the feature frame's origin from the base origin ‖p‖ [m] at q_i.
#[derive(Debug, Clone, Default)]
pub struct Origin;

impl Feature for Origin {
    fn name(&self) -> &str {
        "origin"
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let p = seg.point(1.0).position;
        let value = p.norm();
        if let Some(g) = grad {
            if value > 0.0 {
                let u = p / value;
                let jac = seg.jacobian(1.0);
                let a = |j: usize| u.x * jac[(0, j)] + u.y * jac[(1, j)] + u.z * jac[(2, j)];
                for j in 0..g.this.len() {
                    g.this[j] += g.scale * a(j);
                }
                if let Some(h) = g.hessian {
                    // ∂²‖p‖ = Jᵀ(I − u·uᵀ)J/‖p‖ + Σ_c u_c ∂²p_c.
                    for c in 0..3 {
                        h.add_outer(1.0, g.scale / value, |j| jac[(c, j)]);
                    }
                    h.add_outer(1.0, -g.scale / value, a);
                    if h.kinematic() {
                        seg.add_position_curvature(1.0, &u, g.scale, h);
                    }
                }
            }
        }
        value
    }
}

/// Scene numbers the built-in features use (defaults: original_system.md).
#[derive(Debug, Clone)]
pub struct SceneParams {
    /// Subtracted from the table feature's height [m]; 0 gives the original raw z.
    pub table_height: f64,
    /// Laptop feature centre (x, y) [m].
    pub laptop_center: [f64; 2],
    /// Human feature centre (x, y) [m].
    pub human_center: [f64; 2],
    /// Keep-out radius of the laptop feature [m].
    pub laptop_radius: f64,
    /// Keep-out radius of the human feature [m].
    pub human_radius: f64,
    /// Points per segment of the keep-out features.
    pub samples: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        SceneParams {
            table_height: 0.0,
            laptop_center: [-0.7929, -0.1],
            human_center: [0.0, 0.2],
            laptop_radius: 0.4,
            human_radius: 0.4,
            samples: 4,
        }
    }
}

/// Most keep-out samples per segment (the original used 4; more than this is a mistake, and would
/// make every evaluation slow).
pub const MAX_SAMPLES: usize = 1000;

/// Names accepted by [`builtin`].
pub const BUILTIN_FEATURES: [&str; 7] = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"];

/// A built-in feature by name.
pub fn builtin(name: &str, scene: &SceneParams) -> Result<Box<dyn Feature>> {
    for (arg, radius) in [("laptop_radius", scene.laptop_radius), ("human_radius", scene.human_radius)] {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(PhriError::invalid(arg, format!("must be a finite distance > 0 m, got {radius}")));
        }
    }
    if scene.samples == 0 || scene.samples > MAX_SAMPLES {
        return Err(PhriError::invalid(
            "samples",
            format!("must be 1 to {MAX_SAMPLES} points per segment, got {}", scene.samples),
        ));
    }
    check_finite("table_height", &[scene.table_height])?;
    check_finite("laptop_center", &scene.laptop_center)?;
    check_finite("human_center", &scene.human_center)?;
    let keepout = |name: &str, c: [f64; 2], radius: f64| Keepout {
        name: name.into(),
        center: Vector2::from(c),
        radius,
        samples: scene.samples,
    };
    Ok(match name {
        "efficiency" => Box::new(Efficiency),
        "table" => Box::new(Table { height: scene.table_height }),
        "coffee" => Box::new(Coffee { form: CoffeeForm::Horizontal }),
        "coffee_dot" => Box::new(Coffee { form: CoffeeForm::Dot }),
        "laptop" => Box::new(keepout("laptop", scene.laptop_center, scene.laptop_radius)),
        "human" => Box::new(keepout("human", scene.human_center, scene.human_radius)),
        "origin" => Box::new(Origin),
        other => {
            return Err(PhriError::UnknownName {
                arg: "features".into(),
                kind: "feature".into(),
                name: other.into(),
                known: BUILTIN_FEATURES.join(", "),
            })
        }
    })
}

/// An ordered set of features over one robot, with its own workspace (reuse it: calls allocate
/// nothing once the per-segment cache has grown to the largest sample count).
#[derive(Clone)]
pub struct FeatureSet {
    features: Vec<Box<dyn Feature>>,
    /// 1 / normalisation range per feature (1 when not normalised).
    inv_range: Vec<f64>,
    ws: Workspace,
    hessian: SegmentHessian,
}

impl FeatureSet {
    /// Features evaluated at `frame` (the original: the link_7 origin).
    pub fn new(model: Arc<RobotModel>, frame: FrameId, features: Vec<Box<dyn Feature>>) -> Result<Self> {
        if features.is_empty() {
            return Err(PhriError::invalid("features", "must name at least one feature"));
        }
        for (i, f) in features.iter().enumerate() {
            if features[..i].iter().any(|g| g.name() == f.name()) {
                return Err(PhriError::invalid("features", format!("lists '{}' twice", f.name())));
            }
        }
        if frame.0 >= model.frames.len() {
            return Err(PhriError::invalid("frame", "is not a frame of this robot"));
        }
        let nq = model.nq();
        let ws = Workspace {
            data: model.data(),
            reach: reach_bounds(&model, frame),
            model,
            frame,
            epoch: 0,
            waypoints: Vec::new(),
            data_s: None,
            q_s: vec![0.0; nq],
            samples: Vec::with_capacity(8),
            used: 0,
        };
        Ok(FeatureSet { inv_range: vec![1.0; features.len()], features, ws, hessian: SegmentHessian::new(nq) })
    }

    /// Built-in features by name (see [`BUILTIN_FEATURES`]).
    pub fn from_names(model: Arc<RobotModel>, frame: FrameId, names: &[&str], scene: &SceneParams) -> Result<Self> {
        let features = names.iter().map(|n| builtin(n, scene)).collect::<Result<Vec<_>>>()?;
        Self::new(model, frame, features)
    }

    /// Divide each feature by its range (e.g. the change between the plans for weight 100 and 0);
    /// `None` removes the normalisation.
    pub fn set_ranges(&mut self, ranges: Option<&[f64]>) -> Result<()> {
        match ranges {
            None => self.inv_range.iter_mut().for_each(|r| *r = 1.0),
            Some(r) => {
                if r.len() != self.len() {
                    return Err(PhriError::shape("ranges", format!("({},)", self.len()), format!("({},)", r.len())));
                }
                if let Some((i, v)) = r.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0 && (1.0 / **v).is_finite()))
                {
                    return Err(PhriError::invalid(
                        "ranges",
                        format!("[{i}] must be finite and > 0 (with a finite inverse), got {v}"),
                    ));
                }
                self.inv_range.iter_mut().zip(r).for_each(|(o, v)| *o = 1.0 / v);
            }
        }
        Ok(())
    }

    /// Normalisation ranges (1 where not normalised).
    pub fn ranges(&self) -> Vec<f64> {
        self.inv_range.iter().map(|v| 1.0 / v).collect()
    }

    pub fn len(&self) -> usize {
        self.features.len()
    }

    /// Each feature's [`Feature::resolution_exponent`].
    pub fn resolution_exponents(&self) -> Vec<i32> {
        self.features.iter().map(|f| f.resolution_exponent()).collect()
    }

    pub fn is_empty(&self) -> bool {
        self.features.is_empty()
    }

    /// The weights that pose on a path of `to_waypoints` waypoints the trade-off `weights` pose on
    /// the same path cut into `from_waypoints` (with the same ranges): w_k·r^(1+e_k),
    /// r = (from − 1)/(to − 1), e_k the feature's [`Feature::resolution_exponent`]. For a fixed
    /// path w'·Φ(to) ≈ r·w·Φ(from), so the objective is the same up to a factor and has the same
    /// optimum. Φ is a sum over waypoints or segments, so unscaled weights on a finer grid weigh
    /// per-waypoint features more against efficiency (a sum of squared steps): on 100 waypoints the
    /// study's weights for 31 weigh the task (99/30)² ≈ 11 times more, and the table plan is
    /// another plan (0.39 rad away from the 31-waypoint one in some joint; rescaled, within
    /// 0.02 rad on the four tasks: tests/test_trajopt.py). The optimiser's clearance penalty is a
    /// sum over waypoints too but not a feature: for the same trade-off scale its weight by r²
    /// (what the per-waypoint features get); left as it is, it holds the clearance tighter.
    pub fn rescale_weights(&self, weights: &[f64], from_waypoints: usize, to_waypoints: usize) -> Result<Vec<f64>> {
        check_vector("weights", weights, self.len())?;
        for (arg, n) in [("from_waypoints", from_waypoints), ("to_waypoints", to_waypoints)] {
            if n < 2 {
                return Err(PhriError::invalid(arg, format!("must be >= 2, got {n}")));
            }
        }
        let ratio = (from_waypoints - 1) as f64 / (to_waypoints - 1) as f64;
        let out: Vec<f64> = weights.iter().zip(self.resolution_scales(ratio)).map(|(w, scale)| w * scale).collect();
        if let Some(k) = out.iter().position(|v| !v.is_finite()) {
            return Err(PhriError::invalid(
                "weights",
                format!("rescaled from {from_waypoints} to {to_waypoints} waypoints overflow: weight {k} becomes {}", out[k]),
            ));
        }
        Ok(out)
    }

    /// Per feature, the factor r^(1+e) that keeps its weight's trade-off against the others when
    /// each segment becomes r times as long (see [`FeatureSet::rescale_weights`]).
    pub(crate) fn resolution_scales(&self, ratio: f64) -> impl Iterator<Item = f64> + '_ {
        self.features.iter().map(move |f| ratio.powi(f.resolution_exponent().saturating_add(1)))
    }

    pub fn names(&self) -> Vec<&str> {
        self.features.iter().map(|f| f.name()).collect()
    }

    /// Index of a feature by name.
    pub fn index_of(&self, name: &str) -> Result<usize> {
        self.features.iter().position(|f| f.name() == name).ok_or_else(|| PhriError::UnknownName {
            arg: "feature".into(),
            kind: "feature".into(),
            name: name.into(),
            known: self.names().join(", "),
        })
    }

    pub fn model(&self) -> &Arc<RobotModel> {
        &self.ws.model
    }

    /// Number of waypoints in a row-major trajectory, checking its shape and values.
    pub fn check_trajectory(&self, arg: &str, trajectory: &[f64]) -> Result<usize> {
        let n = self.ws.model.nq();
        if trajectory.len() % n != 0 || trajectory.len() < 2 * n {
            return Err(PhriError::shape(arg, format!("(N, {n}) with N >= 2"), format!("{} values", trajectory.len())));
        }
        check_finite(arg, trajectory)?;
        Ok(trajectory.len() / n)
    }

    fn begin_segment<'a>(ws: &'a mut Workspace, trajectory: &'a [f64], i: usize, smoothing: f64) -> Segment<'a> {
        let n = ws.model.nq();
        ws.used = 0;
        ws.data_s = None;
        Segment { q_prev: &trajectory[(i - 1) * n..i * n], q: &trajectory[i * n..(i + 1) * n], smoothing, index: i, ws }
    }

    /// Φ(ξ) into `phi` (one entry per feature, normalised if ranges are set).
    pub fn phi(&mut self, trajectory: &[f64], phi: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("phi", phi.len(), self.len())?;
        phi.fill(0.0);
        self.ws.begin(waypoints);
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, 0.0);
            for (k, f) in self.features.iter().enumerate() {
                phi[k] += f.segment(&mut seg, None) * self.inv_range[k];
            }
        }
        Ok(())
    }

    /// φ per segment: row i−1 holds φ(q_{i-1}, q_i), shape (N−1) × K row-major.
    pub fn per_segment(&mut self, trajectory: &[f64], out: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        let k_len = self.len();
        self.check_out("out", out.len(), (waypoints - 1) * k_len)?;
        self.ws.begin(waypoints);
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, 0.0);
            for (k, f) in self.features.iter().enumerate() {
                out[(i - 1) * k_len + k] = f.segment(&mut seg, None) * self.inv_range[k];
            }
        }
        Ok(())
    }

    /// Φ(ξ) and its full gradient ∂Φ_k/∂ξ into `jac`, K × N × n row-major.
    pub fn phi_gradient(&mut self, trajectory: &[f64], phi: &mut [f64], jac: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        let n = self.ws.model.nq();
        let k_len = self.len();
        self.check_out("phi", phi.len(), k_len)?;
        self.check_out("jac", jac.len(), k_len * waypoints * n)?;
        phi.fill(0.0);
        jac.fill(0.0);
        self.ws.begin(waypoints);
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, 0.0);
            for (k, f) in self.features.iter().enumerate() {
                let block = &mut jac[k * waypoints * n..(k + 1) * waypoints * n];
                let (before, after) = block.split_at_mut(i * n);
                let grad = SegmentGrad {
                    scale: self.inv_range[k],
                    prev: &mut before[(i - 1) * n..],
                    this: &mut after[..n],
                    hessian: None,
                    pieces: None,
                };
                phi[k] += f.segment(&mut seg, Some(grad)) * self.inv_range[k];
            }
        }
        Ok(())
    }

    /// The weighted cost c = Σ_k w_k Φ_k(ξ) and its gradient ∂c/∂ξ into `grad` (N × n), for the
    /// optimiser. Features with weight 0 are skipped entirely.
    pub fn weighted_cost_gradient(&mut self, trajectory: &[f64], weights: &[f64], grad: &mut [f64]) -> Result<f64> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("weights", weights.len(), self.len())?;
        check_finite("weights", weights)?;
        self.check_out("grad", grad.len(), trajectory.len())?;
        Ok(self.weighted_cost_unchecked(trajectory, waypoints, weights, Some(grad), None, None, 0.0))
    }

    /// The weighted cost c = Σ_k w_k Φ_k(ξ) with the kinked features smoothed by `smoothing` (see
    /// [`huber`]), its gradient ∂c/∂ξ into `grad` (N × n), and the curvature the Newton optimiser
    /// uses into `hessian` (N blocks): the exact second derivatives for smooth features (efficiency,
    /// table, coffee_dot, origin, and the hinges inside their quadratic zone), a convex model
    /// curvature on the linear sides of the kinks.
    pub fn weighted_cost_curvature(
        &mut self,
        trajectory: &[f64],
        weights: &[f64],
        smoothing: f64,
        grad: &mut [f64],
        hessian: &mut BlockTridiagonal,
    ) -> Result<f64> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("weights", weights.len(), self.len())?;
        check_finite("weights", weights)?;
        self.check_out("grad", grad.len(), trajectory.len())?;
        if !(smoothing >= 0.0 && smoothing.is_finite()) {
            return Err(PhriError::invalid("smoothing", format!("must be finite and >= 0, got {smoothing}")));
        }
        let n = self.ws.model.nq();
        if hessian.dof() != n || hessian.blocks() != waypoints {
            return Err(PhriError::shape(
                "hessian",
                format!("{waypoints} blocks of {n} × {n}"),
                format!("{} blocks of {} × {}", hessian.blocks(), hessian.dof(), hessian.dof()),
            ));
        }
        self.set_kinematic_curvature(true);
        Ok(self.weighted_cost_unchecked(trajectory, waypoints, weights, Some(grad), Some(hessian), None, smoothing))
    }

    /// The weighted cost c, its gradient (N × n) and its second derivatives (block tridiagonal,
    /// one n × n block per waypoint pair) with smoothing width `smoothing` (see [`huber`]), for the
    /// optimiser. Starts a new evaluation: afterwards [`FeatureSet::waypoint_data`] serves the
    /// waypoints' kinematics of `trajectory` without recomputing them.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn weighted_cost_unchecked(
        &mut self,
        trajectory: &[f64],
        waypoints: usize,
        weights: &[f64],
        mut grad: Option<&mut [f64]>,
        mut hessian: Option<&mut BlockTridiagonal>,
        mut pieces: Option<&mut Pieces>,
        smoothing: f64,
    ) -> f64 {
        let n = self.ws.model.nq();
        self.ws.begin(waypoints);
        if let Some(g) = grad.as_deref_mut() {
            g.fill(0.0);
        }
        if let Some(h) = hessian.as_deref_mut() {
            h.clear();
        }
        if let Some(p) = pieces.as_deref_mut() {
            p.clear();
        }
        let mut cost = 0.0;
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, smoothing);
            match grad.as_deref_mut() {
                None => {
                    for (k, f) in self.features.iter().enumerate() {
                        let scale = weights[k] * self.inv_range[k];
                        if scale != 0.0 {
                            cost += scale * f.segment(&mut seg, None);
                        }
                    }
                }
                Some(grad) => {
                    let (before, after) = grad.split_at_mut(i * n);
                    let prev = &mut before[(i - 1) * n..];
                    let this = &mut after[..n];
                    let with_hessian = hessian.is_some();
                    if with_hessian {
                        self.hessian.clear();
                    }
                    if let Some(p) = pieces.as_deref_mut() {
                        p.set_segment(i);
                    }
                    for (k, f) in self.features.iter().enumerate() {
                        let scale = weights[k] * self.inv_range[k];
                        if scale != 0.0 {
                            let h = if with_hessian { Some(&mut self.hessian) } else { None };
                            let g = SegmentGrad {
                                scale,
                                prev: &mut *prev,
                                this: &mut *this,
                                hessian: h,
                                pieces: pieces.as_deref_mut(),
                            };
                            cost += scale * f.segment(&mut seg, Some(g));
                        }
                    }
                    if let Some(h) = hessian.as_deref_mut() {
                        self.hessian.flush();
                        h.add_segment(i, &self.hessian);
                    }
                }
            }
        }
        cost
    }

    /// Whether the next evaluations with a Hessian include the kinematic curvature of the features
    /// that act at every waypoint (see [`SegmentHessian::kinematic`]).
    pub(crate) fn set_kinematic_curvature(&mut self, on: bool) {
        self.hessian.kinematic = on;
    }

    /// Kinematics of waypoint `i` of the trajectory of the current evaluation (see
    /// [`FeatureSet::weighted_cost_unchecked`]), computed now if no feature needed it.
    pub(crate) fn waypoint_data(&mut self, trajectory: &[f64], i: usize) -> &RobotData {
        let n = self.ws.model.nq();
        &self.ws.waypoint(i, &trajectory[i * n..(i + 1) * n]).data
    }

    fn check_out(&self, arg: &str, got: usize, want: usize) -> Result<()> {
        if got != want {
            return Err(PhriError::shape(arg, format!("({want},)"), format!("({got},)")));
        }
        Ok(())
    }
}
