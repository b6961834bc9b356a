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
//! features. Then pass `Box::new(YourFeature)` to [`FeatureSet::new`]; the built-in features come
//! from their specifications through [`FeatureSet::from_specs`].

mod batch;
mod builtin;
mod declared;
mod efficiency;
mod keepout;
mod orientation;
mod position;
mod second_order;
mod segment;
mod smoothing;

use std::sync::Arc;

pub use batch::{BatchFeature, BatchFunction};
pub use builtin::{feature_parameters, FeatureParams, FeatureSpec, KeepoutSpec, BUILTIN_FEATURES, DEFAULT_SAMPLES, MAX_SAMPLES};
pub use declared::{declared_parameters, Alignment, DeclaredSpec, Height, JointDistance, Speed, DECLARED_KINDS};
pub use efficiency::Efficiency;
pub use keepout::Keepout;
pub use orientation::{Coffee, CoffeeForm};
pub use position::{Origin, Table};
pub use second_order::{Pieces, SegmentHessian};
use segment::Workspace;
pub use segment::{Point, Segment, SegmentGrad};
pub use smoothing::{huber, smooth_hinge};

use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::model::{FrameId, RobotModel};
use crate::scene::Scene;

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
    /// Called once per evaluation, before its segments, with the whole trajectory (N × n
    /// row-major, `n` joints) and what the evaluation asks for: a feature that computes its values
    /// for all waypoints at once (e.g. one written in Python, see [`BatchFeature`]) does it here
    /// and serves them from `segment`. The built-ins need nothing. An error stops the evaluation
    /// (and the solve) and reaches the caller.
    fn prepare(&mut self, _trajectory: &[f64], _n: usize, _need: Need) -> Result<()> {
        Ok(())
    }
}

/// What an evaluation asks of its features (see [`Feature::prepare`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Need {
    /// Values only.
    Value,
    /// Values and gradients.
    Gradient,
    /// Values, gradients and second derivatives: `exact` when the caller wants the true Hessian
    /// (see [`SegmentHessian::kinematic`]), else a convex model of it will do.
    Hessian { exact: bool },
}

/// Where [`FeatureSet::weighted_cost_unchecked`] reports the second-order model of the cost: each
/// segment's [`SegmentHessian`] to `segment_hessian(i, h)` (i the segment's end waypoint), and the
/// hinge pieces near their kink to `pieces`.
pub(crate) struct SecondOrder<'a> {
    pub(crate) segment_hessian: &'a mut dyn FnMut(usize, &SegmentHessian),
    pub(crate) pieces: Option<&'a mut Pieces>,
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
    /// The first error of a feature's [`Feature::prepare`] in an infallible (optimiser)
    /// evaluation, until the solve takes it (see [`FeatureSet::take_failure`]).
    failure: Option<PhriError>,
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
        let ws = Workspace::new(model, frame);
        Ok(FeatureSet { inv_range: vec![1.0; features.len()], features, ws, hessian: SegmentHessian::new(nq), failure: None })
    }

    /// The built-in features of `specs` (see [`FeatureSpec`]), in order, evaluated at `frame`;
    /// keep-out features are placed by `scene` (errors name "features[i]").
    pub fn from_specs(model: Arc<RobotModel>, frame: FrameId, specs: &[FeatureSpec], scene: Option<&Scene>) -> Result<Self> {
        let features = specs
            .iter()
            .enumerate()
            .map(|(i, s)| s.build(&format!("features[{i}]"), scene, &model))
            .collect::<Result<Vec<_>>>()?;
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
        self.ws.model()
    }

    /// Number of waypoints in a row-major trajectory, checking its shape and values.
    pub fn check_trajectory(&self, arg: &str, trajectory: &[f64]) -> Result<usize> {
        let n = self.ws.model().nq();
        if trajectory.len() % n != 0 || trajectory.len() < 2 * n {
            return Err(PhriError::shape(arg, format!("(N, {n}) with N >= 2"), format!("{} values", trajectory.len())));
        }
        check_finite(arg, trajectory)?;
        Ok(trajectory.len() / n)
    }

    /// Φ(ξ) into `phi` (one entry per feature, normalised if ranges are set).
    pub fn phi(&mut self, trajectory: &[f64], phi: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("phi", phi.len(), self.len())?;
        self.prepare(trajectory, None, Need::Value)?;
        phi.fill(0.0);
        self.ws.begin_streaming();
        for i in 1..waypoints {
            let mut seg = self.ws.segment(trajectory, i, 0.0);
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
        self.prepare(trajectory, None, Need::Value)?;
        self.ws.begin_streaming();
        for i in 1..waypoints {
            let mut seg = self.ws.segment(trajectory, i, 0.0);
            for (k, f) in self.features.iter().enumerate() {
                out[(i - 1) * k_len + k] = f.segment(&mut seg, None) * self.inv_range[k];
            }
        }
        Ok(())
    }

    /// Φ(ξ) and its full gradient ∂Φ_k/∂ξ into `jac`, K × N × n row-major.
    pub fn phi_gradient(&mut self, trajectory: &[f64], phi: &mut [f64], jac: &mut [f64]) -> Result<()> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        let n = self.ws.model().nq();
        let k_len = self.len();
        self.check_out("phi", phi.len(), k_len)?;
        self.check_out("jac", jac.len(), k_len * waypoints * n)?;
        self.prepare(trajectory, None, Need::Gradient)?;
        phi.fill(0.0);
        jac.fill(0.0);
        self.ws.begin_streaming();
        for i in 1..waypoints {
            let mut seg = self.ws.segment(trajectory, i, 0.0);
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
        self.prepare(trajectory, Some(weights), Need::Gradient)?;
        self.ws.begin_streaming();
        Ok(self.weighted_cost_evaluation(trajectory, waypoints, weights, Some(grad), None, 0.0))
    }

    /// The weighted cost c = Σ_k w_k Φ_k(ξ) with the kinked features smoothed by `smoothing` (see
    /// [`huber`]), its gradient ∂c/∂ξ into `grad` (N × n), and the curvature the Newton optimiser
    /// uses, one segment at a time: `segment_hessian(i, h)` receives the 2n × 2n second derivatives
    /// `h` of the segment that ends at waypoint i (1 ≤ i < N), e.g. to add them to a
    /// block-tridiagonal matrix. They are the exact second derivatives for smooth features
    /// (efficiency, table, coffee_dot, origin, and the hinges inside their quadratic zone), a convex
    /// model curvature on the linear sides of the kinks.
    pub fn weighted_cost_curvature(
        &mut self,
        trajectory: &[f64],
        weights: &[f64],
        smoothing: f64,
        grad: &mut [f64],
        mut segment_hessian: impl FnMut(usize, &SegmentHessian),
    ) -> Result<f64> {
        let waypoints = self.check_trajectory("trajectory", trajectory)?;
        self.check_out("weights", weights.len(), self.len())?;
        check_finite("weights", weights)?;
        self.check_out("grad", grad.len(), trajectory.len())?;
        if !(smoothing >= 0.0 && smoothing.is_finite()) {
            return Err(PhriError::invalid("smoothing", format!("must be finite and >= 0, got {smoothing}")));
        }
        self.set_kinematic_curvature(true);
        self.prepare(trajectory, Some(weights), Need::Hessian { exact: true })?;
        let second_order = SecondOrder { segment_hessian: &mut segment_hessian, pieces: None };
        Ok(self.weighted_cost_unchecked(trajectory, waypoints, weights, Some(grad), Some(second_order), smoothing))
    }

    /// The weighted cost c, its gradient (N × n) and, with `second_order`, each segment's second
    /// derivatives and pieces, with smoothing width `smoothing` (see [`huber`]), for the optimiser.
    /// Starts a new evaluation: afterwards [`FeatureSet::waypoint_data`] serves the waypoints'
    /// kinematics of `trajectory` without recomputing them.
    pub(crate) fn weighted_cost_unchecked(
        &mut self,
        trajectory: &[f64],
        waypoints: usize,
        weights: &[f64],
        grad: Option<&mut [f64]>,
        second_order: Option<SecondOrder<'_>>,
        smoothing: f64,
    ) -> f64 {
        let need = match (&grad, &second_order) {
            (_, Some(_)) => Need::Hessian { exact: self.hessian.kinematic() },
            (Some(_), None) => Need::Gradient,
            (None, None) => Need::Value,
        };
        self.prepare_unchecked(&trajectory[..waypoints * self.ws.model().nq()], Some(weights), need);
        self.ws.begin(waypoints);
        self.weighted_cost_evaluation(trajectory, waypoints, weights, grad, second_order, smoothing)
    }

    /// Each feature's term of [`FeatureSet::weighted_cost_unchecked`]'s cost (no gradient) at unit
    /// weight, into `terms` (one per feature): that cost at weights w is Σ w_k·terms[k] over the k
    /// with w_k ≠ 0 (the cost skips the features of weight 0).
    pub(crate) fn cost_terms_unchecked(&mut self, trajectory: &[f64], waypoints: usize, smoothing: f64, terms: &mut [f64]) {
        self.prepare_unchecked(&trajectory[..waypoints * self.ws.model().nq()], None, Need::Value);
        self.ws.begin(waypoints);
        terms.fill(0.0);
        for i in 1..waypoints {
            let mut seg = self.ws.segment(trajectory, i, smoothing);
            for (k, f) in self.features.iter().enumerate() {
                terms[k] += self.inv_range[k] * f.segment(&mut seg, None);
            }
        }
    }

    /// [`FeatureSet::weighted_cost_unchecked`] after the workspace's `begin` (kept or streaming).
    fn weighted_cost_evaluation(
        &mut self,
        trajectory: &[f64],
        waypoints: usize,
        weights: &[f64],
        grad: Option<&mut [f64]>,
        second_order: Option<SecondOrder<'_>>,
        smoothing: f64,
    ) -> f64 {
        let Some(grad) = grad else {
            let mut cost = 0.0;
            for i in 1..waypoints {
                let mut seg = self.ws.segment(trajectory, i, smoothing);
                for (k, f) in self.features.iter().enumerate() {
                    let scale = weights[k] * self.inv_range[k];
                    if scale != 0.0 {
                        cost += scale * f.segment(&mut seg, None);
                    }
                }
            }
            return cost;
        };
        grad.fill(0.0);
        let (mut segment_hessian, mut pieces) = match second_order {
            Some(SecondOrder { segment_hessian, pieces }) => (Some(segment_hessian), pieces),
            None => (None, None),
        };
        if let Some(p) = pieces.as_deref_mut() {
            p.clear();
        }
        let n = self.ws.model().nq();
        let mut cost = 0.0;
        for i in 1..waypoints {
            let mut seg = self.ws.segment(trajectory, i, smoothing);
            let (before, after) = grad.split_at_mut(i * n);
            let prev = &mut before[(i - 1) * n..];
            let this = &mut after[..n];
            let with_hessian = segment_hessian.is_some();
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
                    let g = SegmentGrad { scale, prev: &mut *prev, this: &mut *this, hessian: h, pieces: pieces.as_deref_mut() };
                    cost += scale * f.segment(&mut seg, Some(g));
                }
            }
            if let Some(sink) = segment_hessian.as_deref_mut() {
                self.hessian.flush();
                sink(i, &self.hessian);
            }
        }
        cost
    }

    /// Runs every feature's [`Feature::prepare`] (with `weights`, only those of weight ≠ 0).
    fn prepare(&mut self, trajectory: &[f64], weights: Option<&[f64]>, need: Need) -> Result<()> {
        let n = self.ws.model().nq();
        for (k, f) in self.features.iter_mut().enumerate() {
            if weights.is_none_or(|w| w[k] * self.inv_range[k] != 0.0) {
                f.prepare(trajectory, n, need)?;
            }
        }
        Ok(())
    }

    /// [`FeatureSet::prepare`] for the infallible evaluations: the first error is kept for the
    /// solve to report ([`FeatureSet::take_failure`]); the failed feature contributes nothing.
    fn prepare_unchecked(&mut self, trajectory: &[f64], weights: Option<&[f64]>, need: Need) {
        if let Err(e) = self.prepare(trajectory, weights, need) {
            self.failure.get_or_insert(e);
        }
    }

    /// Whether a feature failed in an evaluation since the last [`FeatureSet::take_failure`].
    pub(crate) fn failed(&self) -> bool {
        self.failure.is_some()
    }

    /// The first feature error of the evaluations since the last call, if any.
    pub(crate) fn take_failure(&mut self) -> Option<PhriError> {
        self.failure.take()
    }

    /// Whether the next evaluations with a Hessian include the kinematic curvature of the features
    /// that act at every waypoint (see [`SegmentHessian::kinematic`]).
    pub(crate) fn set_kinematic_curvature(&mut self, on: bool) {
        self.hessian.set_kinematic(on);
    }

    /// Kinematics of waypoint `i` of the trajectory of the current evaluation (see
    /// [`FeatureSet::weighted_cost_unchecked`]), computed now if no feature needed it.
    pub(crate) fn waypoint_data(&mut self, trajectory: &[f64], i: usize) -> &RobotData {
        let n = self.ws.model().nq();
        &self.ws.waypoint(i, &trajectory[i * n..(i + 1) * n]).data
    }

    fn check_out(&self, arg: &str, got: usize, want: usize) -> Result<()> {
        if got != want {
            return Err(PhriError::shape(arg, format!("({want},)"), format!("({got},)")));
        }
        Ok(())
    }
}
