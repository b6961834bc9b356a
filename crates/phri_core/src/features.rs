//! Task features φ and trajectory feature counts Φ(ξ) with analytic gradients.
//!
//! A trajectory ξ is N waypoints of the robot's joints (N × n, one waypoint per row). As in the
//! authors' code, Φ(ξ) = Σ_{i=1}^{N-1} φ(q_{i-1}, q_i): every feature is evaluated on the segment that
//! ends at waypoint i, and waypoint 0 (where the robot already is) contributes nothing.
//!
//! # Adding a feature
//! Implement [`Feature`]: `segment` returns φ for one segment and, when asked, adds the scaled
//! gradient with respect to both end waypoints. Ask the [`Segment`] for the kinematics of any point
//! along it (`seg.point(s)`, `seg.jacobian(s)` for s ∈ [0, 1]); they are computed once per segment
//! and shared by all features. Then pass `Box::new(YourFeature)` to [`FeatureSet::new`].

use std::sync::Arc;

use nalgebra::{Matrix3, Matrix6xX, Vector2, Vector3};

use crate::data::RobotData;
use crate::error::{check_finite, PhriError, Result};
use crate::model::{FrameId, RobotModel};

/// Kinematics of the feature frame (link_7 by default) at one configuration.
#[derive(Debug, Clone, Copy)]
pub struct Point {
    /// Origin of the feature frame in the base frame [m].
    pub position: Vector3<f64>,
    /// Orientation of the feature frame in the base frame.
    pub rotation: Matrix3<f64>,
}

/// Where a feature adds its gradient: `prev += scale·∂φ/∂q_{i-1}`, `this += scale·∂φ/∂q_i`.
pub struct SegmentGrad<'a> {
    pub scale: f64,
    pub prev: &'a mut [f64],
    pub this: &'a mut [f64],
}

#[derive(Clone)]
struct Sample {
    s: f64,
    point: Point,
    jacobian: Matrix6xX<f64>,
    has_jacobian: bool,
}

/// Per-segment kinematics cache, shared by all features of a [`FeatureSet`].
pub struct Segment<'a> {
    /// Start waypoint q_{i-1} [rad].
    pub q_prev: &'a [f64],
    /// End waypoint q_i [rad].
    pub q: &'a [f64],
    /// Smoothing width δ for kinked features (0 = exact); set by the optimiser, see [`huber`].
    pub smoothing: f64,
    ws: &'a mut Workspace,
}

#[derive(Clone)]
struct Workspace {
    model: Arc<RobotModel>,
    frame: FrameId,
    data: RobotData,
    /// Configuration whose forward kinematics is in `data` (as a sample parameter s).
    data_s: Option<f64>,
    q_s: Vec<f64>,
    samples: Vec<Sample>,
    used: usize,
}

impl Workspace {
    fn fk_at(&mut self, q_prev: &[f64], q: &[f64], s: f64) {
        if self.data_s != Some(s) {
            for ((out, a), b) in self.q_s.iter_mut().zip(q_prev).zip(q) {
                *out = a + s * (b - a);
            }
            self.model.forward_kinematics_unchecked(&self.q_s, &mut self.data);
            self.data_s = Some(s);
        }
    }
}

impl Segment<'_> {
    fn index(&mut self, s: f64) -> usize {
        if let Some(i) = self.ws.samples[..self.ws.used].iter().position(|x| x.s == s) {
            return i;
        }
        let (q_prev, q) = (self.q_prev, self.q);
        self.ws.fk_at(q_prev, q, s);
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

    /// Feature-frame kinematics at q_{i-1} + s·(q_i − q_{i-1}), s ∈ [0, 1].
    pub fn point(&mut self, s: f64) -> Point {
        let i = self.index(s);
        self.ws.samples[i].point
    }

    /// World-aligned 6×n Jacobian of the feature frame at the same point as [`Segment::point`].
    pub fn jacobian(&mut self, s: f64) -> &Matrix6xX<f64> {
        let i = self.index(s);
        if !self.ws.samples[i].has_jacobian {
            let (q_prev, q) = (self.q_prev, self.q);
            self.ws.fk_at(q_prev, q, s);
            let ws = &mut *self.ws;
            ws.model.frame_jacobian_unchecked(ws.frame, &ws.data, &mut ws.samples[i].jacobian);
            ws.samples[i].has_jacobian = true;
        }
        &self.ws.samples[i].jacobian
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
}

/// Path length in joint space: φ = ‖q_i − q_{i-1}‖² [rad²].
#[derive(Debug, Clone, Copy, Default)]
pub struct Efficiency;

impl Feature for Efficiency {
    fn name(&self) -> &str {
        "efficiency"
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
        let (value, weights) = match self.form {
            CoffeeForm::Horizontal => {
                let ((a, da), (b, db)) = (huber(x.x, seg.smoothing), huber(x.y, seg.smoothing));
                (a + b, Vector3::new(da, db, 0.0))
            }
            CoffeeForm::Dot => (1.0 - x.z, Vector3::new(0.0, 0.0, -1.0)),
        };
        if let Some(g) = grad {
            // ∂x/∂q_j = ω_j × x, with ω_j the angular rows of the Jacobian.
            let jac = seg.jacobian(1.0);
            for j in 0..g.this.len() {
                let w = Vector3::new(jac[(3, j)], jac[(4, j)], jac[(5, j)]);
                g.this[j] += g.scale * weights.dot(&w.cross(&x));
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
        let mut value = 0.0;
        for k in 1..=self.samples {
            let s = k as f64 / self.samples as f64;
            let p = seg.point(s).position;
            let d = Vector2::new(p.x - self.center.x, p.y - self.center.y);
            let dist = d.norm();
            if dist >= self.radius {
                continue;
            }
            let (v, slope) = smooth_hinge(self.radius - dist, seg.smoothing);
            value += v;
            if let Some(g) = grad.as_mut() {
                if dist > 0.0 && slope > 0.0 {
                    let u = d / dist;
                    let jac = seg.jacobian(s);
                    for j in 0..g.this.len() {
                        let dphi = -(u.x * jac[(0, j)] + u.y * jac[(1, j)]) * slope * g.scale;
                        g.this[j] += s * dphi;
                        g.prev[j] += (1.0 - s) * dphi;
                    }
                }
            }
        }
        value
    }
}

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
                for j in 0..g.this.len() {
                    g.this[j] += g.scale * (u.x * jac[(0, j)] + u.y * jac[(1, j)] + u.z * jac[(2, j)]);
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
    /// Keep-out radius of both [m].
    pub radius: f64,
    /// Points per segment of the keep-out features.
    pub samples: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        SceneParams { table_height: 0.0, laptop_center: [-0.7929, -0.1], human_center: [0.0, 0.2], radius: 0.4, samples: 4 }
    }
}

/// Names accepted by [`builtin`].
pub const BUILTIN_FEATURES: [&str; 7] = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"];

/// A built-in feature by name.
pub fn builtin(name: &str, scene: &SceneParams) -> Result<Box<dyn Feature>> {
    if !(scene.radius.is_finite() && scene.radius > 0.0) {
        return Err(PhriError::invalid("radius", format!("must be a finite distance > 0 m, got {}", scene.radius)));
    }
    if scene.samples == 0 {
        return Err(PhriError::invalid("samples", "must be at least 1 point per segment, got 0"));
    }
    check_finite("table_height", &[scene.table_height])?;
    check_finite("laptop_center", &scene.laptop_center)?;
    check_finite("human_center", &scene.human_center)?;
    let keepout = |name: &str, c: [f64; 2]| Keepout {
        name: name.into(),
        center: Vector2::from(c),
        radius: scene.radius,
        samples: scene.samples,
    };
    Ok(match name {
        "efficiency" => Box::new(Efficiency),
        "table" => Box::new(Table { height: scene.table_height }),
        "coffee" => Box::new(Coffee { form: CoffeeForm::Horizontal }),
        "coffee_dot" => Box::new(Coffee { form: CoffeeForm::Dot }),
        "laptop" => Box::new(keepout("laptop", scene.laptop_center)),
        "human" => Box::new(keepout("human", scene.human_center)),
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
            model,
            frame,
            data_s: None,
            q_s: vec![0.0; nq],
            samples: Vec::with_capacity(8),
            used: 0,
        };
        Ok(FeatureSet { inv_range: vec![1.0; features.len()], features, ws })
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
                if let Some((i, v)) = r.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
                    return Err(PhriError::invalid("ranges", format!("[{i}] must be finite and > 0, got {v}")));
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

    pub fn is_empty(&self) -> bool {
        self.features.is_empty()
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
        Segment { q_prev: &trajectory[(i - 1) * n..i * n], q: &trajectory[i * n..(i + 1) * n], smoothing, ws }
    }

    /// Φ(ξ) into `phi` (one entry per feature, normalised if ranges are set).
    pub fn phi(&mut self, trajectory: &[f64], phi: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("phi", phi.len(), self.len())?;
        phi.fill(0.0);
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
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, 0.0);
            for (k, f) in self.features.iter().enumerate() {
                let block = &mut jac[k * waypoints * n..(k + 1) * waypoints * n];
                let (before, after) = block.split_at_mut(i * n);
                let grad = SegmentGrad { scale: self.inv_range[k], prev: &mut before[(i - 1) * n..], this: &mut after[..n] };
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
        Ok(self.weighted_cost_gradient_unchecked(trajectory, waypoints, weights, grad, 0.0))
    }

    pub(crate) fn weighted_cost_gradient_unchecked(
        &mut self,
        trajectory: &[f64],
        waypoints: usize,
        weights: &[f64],
        grad: &mut [f64],
        smoothing: f64,
    ) -> f64 {
        let n = self.ws.model.nq();
        grad.fill(0.0);
        let mut cost = 0.0;
        for i in 1..waypoints {
            let mut seg = Self::begin_segment(&mut self.ws, trajectory, i, smoothing);
            let (before, after) = grad.split_at_mut(i * n);
            let prev = &mut before[(i - 1) * n..];
            let this = &mut after[..n];
            for (k, f) in self.features.iter().enumerate() {
                let scale = weights[k] * self.inv_range[k];
                if scale != 0.0 {
                    cost += scale * f.segment(&mut seg, Some(SegmentGrad { scale, prev: &mut *prev, this: &mut *this }));
                }
            }
        }
        cost
    }

    fn check_out(&self, arg: &str, got: usize, want: usize) -> Result<()> {
        if got != want {
            return Err(PhriError::shape(arg, format!("({want},)"), format!("({got},)")));
        }
        Ok(())
    }
}
