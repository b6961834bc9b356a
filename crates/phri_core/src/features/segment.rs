//! The kinematics every feature reads, computed once per evaluation and shared: the feature frame's
//! pose and Jacobian at the waypoints (each shared by the two segments that meet there) and at the
//! points a feature samples along a segment, and where a feature adds its derivatives
//! ([`SegmentGrad`]).

use std::sync::Arc;

use nalgebra::{Matrix3, Matrix6xX, Vector3};

use super::second_order::{Pieces, SegmentHessian};
use crate::data::RobotData;
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

#[derive(Clone)]
struct Sample {
    s: f64,
    point: Point,
    jacobian: Matrix6xX<f64>,
    has_jacobian: bool,
}

/// Kinematics of one waypoint, valid for the evaluation whose epoch it carries.
#[derive(Clone)]
pub(super) struct WaypointKin {
    pub(super) data: RobotData,
    /// (sin, cos) of every joint position, for the samples of the segments that meet here.
    sin_cos: Vec<(f64, f64)>,
    point: Point,
    jacobian: Matrix6xX<f64>,
    epoch: u64,
    jacobian_epoch: u64,
    /// The waypoint whose kinematics these are (a slot holds many waypoints when streaming).
    index: usize,
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

/// The kinematics cache of a [`super::FeatureSet`]: per waypoint and per sample of the current
/// segment.
#[derive(Clone)]
pub(super) struct Workspace {
    model: Arc<RobotModel>,
    frame: FrameId,
    /// Per joint j, a bound on the distance from joint j's axis to the feature frame's origin [m]
    /// (None when a prismatic joint makes it unbounded); see [`Segment::travel_bound`].
    reach: Option<Vec<f64>>,
    /// Evaluation counter: waypoint kinematics carrying an older epoch are stale.
    epoch: u64,
    /// Per waypoint its kinematics; when `streaming`, two slots that waypoint i shares with i ± 2
    /// (a segment reads only its two ends), so that memory does not grow with the trajectory.
    waypoints: Vec<WaypointKin>,
    streaming: bool,
    /// Intermediate samples of the current segment.
    data: RobotData,
    /// Configuration whose forward kinematics is in `data` (as a sample parameter s).
    data_s: Option<f64>,
    q_s: Vec<f64>,
    samples: Vec<Sample>,
    used: usize,
    /// Jacobian of a frame other than the feature frame (see [`Segment::jacobian_of`]).
    other_jacobian: Matrix6xX<f64>,
}

impl Workspace {
    /// An empty cache for the feature frame `frame` of `model`.
    pub(super) fn new(model: Arc<RobotModel>, frame: FrameId) -> Self {
        let nq = model.nq();
        Workspace {
            data: model.data(),
            reach: reach_bounds(&model, frame),
            model,
            frame,
            epoch: 0,
            waypoints: Vec::new(),
            streaming: false,
            data_s: None,
            q_s: vec![0.0; nq],
            samples: Vec::with_capacity(8),
            used: 0,
            other_jacobian: Matrix6xX::zeros(nq),
        }
    }

    pub(super) fn model(&self) -> &Arc<RobotModel> {
        &self.model
    }

    /// The segment of `trajectory` that ends at waypoint `i`, with no samples computed yet.
    pub(super) fn segment<'a>(&'a mut self, trajectory: &'a [f64], i: usize, smoothing: f64) -> Segment<'a> {
        let n = self.model.nq();
        self.used = 0;
        self.data_s = None;
        Segment { q_prev: &trajectory[(i - 1) * n..i * n], q: &trajectory[i * n..(i + 1) * n], smoothing, index: i, ws: self }
    }

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
            let (base, q_s) = (&self.waypoints[self.slot(i - 1)].sin_cos, &self.q_s);
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

    /// Starts an evaluation of a trajectory of `waypoints` rows that keeps every waypoint's
    /// kinematics until the next (see `FeatureSet::waypoint_data`): all cached kinematics go stale.
    pub(super) fn begin(&mut self, waypoints: usize) {
        self.streaming = false;
        self.reserve(waypoints);
    }

    /// Starts an evaluation that visits the segments in order and keeps only the kinematics of
    /// the current segment's two ends: constant memory whatever the trajectory's length.
    pub(super) fn begin_streaming(&mut self) {
        self.streaming = true;
        self.reserve(2);
    }

    /// The slot of waypoint `i`'s kinematics.
    #[inline]
    fn slot(&self, i: usize) -> usize {
        if self.streaming {
            i % 2
        } else {
            i
        }
    }

    fn reserve(&mut self, waypoints: usize) {
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
                index: 0,
            };
            self.waypoints.resize(waypoints, blank);
        }
    }

    /// Forward kinematics of waypoint `i` at `q`, computed once per evaluation.
    pub(super) fn waypoint(&mut self, i: usize, q: &[f64]) -> &mut WaypointKin {
        let slot = self.slot(i);
        let w = &mut self.waypoints[slot];
        if w.epoch != self.epoch || w.index != i {
            w.index = i;
            w.jacobian_epoch = 0;
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
        let slot = self.slot(i);
        let w = &mut self.waypoints[slot];
        if w.jacobian_epoch != epoch {
            self.model.frame_jacobian_unchecked(self.frame, &w.data, &mut w.jacobian);
            w.jacobian_epoch = epoch;
        }
        &self.waypoints[slot].jacobian
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
    /// Index i of the segment's end waypoint (1 ≤ i < N): the segment runs from q_{i-1} to q_i.
    pub fn end_index(&self) -> usize {
        self.index
    }

    /// The robot model the kinematics are of.
    pub fn model(&self) -> &Arc<RobotModel> {
        &self.ws.model
    }

    /// `frame` unless it is the feature frame (whose kinematics are cached).
    fn other(&self, frame: Option<FrameId>) -> Option<FrameId> {
        frame.filter(|f| *f != self.ws.frame)
    }

    /// Forward kinematics at q(s) (the waypoints' own for s = 0 and 1).
    fn data_at(&mut self, s: f64) -> &RobotData {
        let (q_prev, q) = (self.q_prev, self.q);
        if s == 1.0 {
            return &self.ws.waypoint(self.index, q).data;
        }
        if s == 0.0 {
            return &self.ws.waypoint(self.index - 1, q_prev).data;
        }
        self.ws.fk_at(self.index, q_prev, q, s);
        &self.ws.data
    }

    /// Kinematics of `frame` (None: the feature frame) at q_{i-1} + s·(q_i − q_{i-1}), s ∈ [0, 1].
    /// Other frames are read off the same forward kinematics (computed once per waypoint and
    /// sample) without a cache of their own.
    pub fn point_of(&mut self, frame: Option<FrameId>, s: f64) -> Point {
        let Some(f) = self.other(frame) else { return self.point(s) };
        let model = self.ws.model.clone();
        let pose = model.frame_pose(f, self.data_at(s));
        Point { position: pose.translation.vector, rotation: *pose.rotation.matrix() }
    }

    /// World-aligned 6×n Jacobian of `frame` (None: the feature frame) at the same point as
    /// [`Segment::point_of`]; valid until the next call for another frame.
    pub fn jacobian_of(&mut self, frame: Option<FrameId>, s: f64) -> &Matrix6xX<f64> {
        let Some(f) = self.other(frame) else { return self.jacobian(s) };
        let model = self.ws.model.clone();
        let mut jac = std::mem::replace(&mut self.ws.other_jacobian, Matrix6xX::zeros(0));
        model.frame_jacobian_unchecked(f, self.data_at(s), &mut jac);
        self.ws.other_jacobian = jac;
        &self.ws.other_jacobian
    }

    /// [`Segment::travel_bound`] for `frame`'s origin (None: the feature frame).
    pub fn travel_bound_of(&self, frame: Option<FrameId>) -> Option<f64> {
        let Some(f) = self.other(frame) else { return self.travel_bound() };
        let reach = reach_bounds(&self.ws.model, f)?;
        Some(reach.iter().zip(self.q).zip(self.q_prev).map(|((r, a), b)| r * (a - b).abs()).sum())
    }

    /// [`Segment::add_position_curvature`] for `frame`'s origin (None: the feature frame).
    pub fn add_position_curvature_of(
        &mut self,
        frame: Option<FrameId>,
        s: f64,
        g: &Vector3<f64>,
        weight: f64,
        hessian: &mut SegmentHessian,
    ) {
        let jac = self.jacobian_of(frame, s);
        position_hessian(jac, g, hessian.scratch());
        hessian.add_scratch_at(s, weight);
    }

    /// [`Segment::add_axis_curvature`] for `frame`'s axis `col` (None: the feature frame).
    pub fn add_axis_curvature_of(
        &mut self,
        frame: Option<FrameId>,
        s: f64,
        col: usize,
        w: &Vector3<f64>,
        weight: f64,
        hessian: &mut SegmentHessian,
    ) {
        let x: Vector3<f64> = self.point_of(frame, s).rotation.column(col).into();
        let jac = self.jacobian_of(frame, s);
        direction_hessian(jac, &x, w, hessian.scratch());
        hessian.add_scratch_at(s, weight);
    }

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
        position_hessian(jac, g, hessian.scratch());
        hessian.add_scratch_at(s, weight);
    }

    /// Adds `weight`·Σ_c w_c·∂²R_{c,col}/∂ξ² to `hessian`, R the feature frame's rotation at q(s):
    /// the curvature of a cost whose gradient in the frame's axis `col` is w.
    pub fn add_axis_curvature(&mut self, s: f64, col: usize, w: &Vector3<f64>, weight: f64, hessian: &mut SegmentHessian) {
        let x: Vector3<f64> = self.point(s).rotation.column(col).into();
        let jac = self.jacobian(s);
        direction_hessian(jac, &x, w, hessian.scratch());
        hessian.add_scratch_at(s, weight);
    }
}
