//! Declared features and batched (e.g. Python) features: second derivatives against finite
//! differences, equality with the built-ins they generalise, and a failing feature's error.

mod common;

use std::sync::Arc;

use common::study::study_scene;
use common::{deg, jaco2, within_limits};
use phri_core::features::{
    BatchFeature, BatchFunction, DeclaredSpec, Feature, FeatureParams, FeatureSet, FeatureSpec, SegmentHessian,
};
use phri_core::model::RobotModel;
use phri_core::trajopt::block_tridiagonal::BlockTridiagonal;
use phri_core::trajopt::{TrajectoryOptimizer, TrajoptParams};
use phri_core::{PhriError, Result};

const FEATURE_FRAME: &str = "j2s7s300_link_7";

fn trajectory(a: &[f64], b: &[f64], waypoints: usize, wiggle: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(waypoints * 7);
    for i in 0..waypoints {
        let s = i as f64 / (waypoints - 1) as f64;
        for j in 0..7 {
            out.push(a[j] + s * (b[j] - a[j]) + wiggle * (3.0 * s + j as f64).sin() * s * (1.0 - s));
        }
    }
    out
}

fn declared(name: &str, spec: DeclaredSpec) -> FeatureSpec {
    FeatureSpec { name: name.into(), params: FeatureParams::Declared(spec) }
}

fn set(model: &Arc<RobotModel>, specs: &[FeatureSpec]) -> FeatureSet {
    let frame = model.frame_id(FEATURE_FRAME).unwrap();
    FeatureSet::from_specs(model.clone(), frame, specs, Some(&study_scene())).unwrap()
}

fn filling(hess: &mut BlockTridiagonal) -> impl FnMut(usize, &SegmentHessian) + '_ {
    hess.clear();
    move |i, h| hess.add_segment(i, h.matrix())
}

fn entry(h: &BlockTridiagonal, r: usize, c: usize) -> f64 {
    let n = h.dof();
    let (br, bc) = (r / n, c / n);
    match br as isize - bc as isize {
        0 => h.diag(br)[(r % n) * n + c % n],
        -1 => h.off(br)[(r % n) * n + c % n],
        1 => h.off(bc)[(c % n) * n + r % n],
        _ => 0.0,
    }
}

/// The exact Hessian of `w`·Φ at `xi` against central differences of its gradient.
fn check_hessian(fs: &mut FeatureSet, xi: &[f64], w: &[f64], tolerance: f64, what: &str) {
    let waypoints = xi.len() / 7;
    let mut hess = BlockTridiagonal::new(7, waypoints);
    let mut grad = vec![0.0; xi.len()];
    fs.weighted_cost_curvature(xi, w, 0.0, &mut grad, filling(&mut hess)).unwrap();
    let mut scratch = BlockTridiagonal::new(7, waypoints);
    let h = 1e-6;
    for v in 0..xi.len() {
        let (mut gp, mut gm) = (vec![0.0; xi.len()], vec![0.0; xi.len()]);
        let mut x = xi.to_vec();
        x[v] += h;
        fs.weighted_cost_curvature(&x, w, 0.0, &mut gp, filling(&mut scratch)).unwrap();
        x[v] -= 2.0 * h;
        fs.weighted_cost_curvature(&x, w, 0.0, &mut gm, filling(&mut scratch)).unwrap();
        for r in 0..xi.len() {
            let fd = (gp[r] - gm[r]) / (2.0 * h);
            let an = entry(&hess, r, v);
            assert!((fd - an).abs() < tolerance * (1.0 + an.abs()), "{what}: H[{r}, {v}] fd {fd} vs {an}");
        }
    }
}

#[test]
fn declared_smooth_kinds_have_exact_second_derivatives_on_several_frames() {
    let model = Arc::new(jaco2());
    let frames = ["j2s7s300_link_3", "j2s7s300_link_5", FEATURE_FRAME];
    for (seed, frame) in frames.iter().enumerate() {
        let f = Some(frame.to_string());
        let specs = [
            declared("height", DeclaredSpec::Height { frame: f.clone(), object: Some("table".into()), offset: 0.1 }),
            declared("level", DeclaredSpec::Alignment { frame: f.clone(), axis: 1, direction: [0.3, -0.2, 1.0] }),
            declared("pose", DeclaredSpec::JointDistance { pose: vec![3.0, 2.5, 3.1, 1.8, 3.9, 3.8, 5.4] }),
            declared("speed", DeclaredSpec::Speed { frame: f.clone() }),
        ];
        let mut fs = set(&model, &specs);
        let u: Vec<f64> = (0..14).map(|k| 0.1 + 0.8 * (((seed * 14 + k) as f64) * 0.618).fract()).collect();
        let xi = trajectory(&within_limits(&model, &u[..7]), &within_limits(&model, &u[7..]), 5, 0.4);
        check_hessian(&mut fs, &xi, &[0.7, 1.3, 0.4, 2.0], 2e-6, frame);
    }
}

#[test]
fn declared_kinds_equal_the_builtins_they_generalise() {
    let model = Arc::new(jaco2());
    let builtin = |name: &str| FeatureSpec {
        name: name.into(),
        params: if name == "table" { FeatureParams::Table { height: -0.1016 } } else { FeatureParams::None },
    };
    let mut a = set(&model, &[builtin("table"), builtin("coffee_dot")]);
    let top = study_scene().get("table").unwrap().top().unwrap();
    let mut b = set(
        &model,
        &[
            declared("t", DeclaredSpec::Height { frame: None, object: Some("table".into()), offset: -0.1016 - top }),
            declared("c", DeclaredSpec::Alignment { frame: None, axis: 0, direction: [0.0, 0.0, 1.0] }),
        ],
    );
    let xi = trajectory(
        &deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]),
        &deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]),
        31,
        0.3,
    );
    let (mut pa, mut pb) = ([0.0; 2], [0.0; 2]);
    let (mut ja, mut jb) = (vec![0.0; 2 * xi.len()], vec![0.0; 2 * xi.len()]);
    a.phi_gradient(&xi, &mut pa, &mut ja).unwrap();
    b.phi_gradient(&xi, &mut pb, &mut jb).unwrap();
    for k in 0..2 {
        assert!((pa[k] - pb[k]).abs() < 1e-12, "feature {k}: {} vs {}", pa[k], pb[k]);
    }
    assert!(ja.iter().zip(&jb).all(|(x, y)| (x - y).abs() < 1e-12));
}

/// The table feature (height of the feature frame above 0) computed for a batch, with its
/// gradient, or failing on purpose.
#[derive(Clone)]
struct BatchTable {
    model: Arc<RobotModel>,
    gradient: bool,
    fail: bool,
}

impl BatchFunction for BatchTable {
    fn name(&self) -> &str {
        "batch_table"
    }
    fn has_gradient(&self) -> bool {
        self.gradient
    }
    fn has_hessian(&self) -> bool {
        false
    }
    fn values(&self, q: &[f64], n: usize, values: &mut [f64]) -> Result<()> {
        if self.fail {
            return Err(PhriError::Feature { feature: "batch_table".into(), reason: "failed on purpose".into() });
        }
        let frame = self.model.frame_id(FEATURE_FRAME)?;
        let mut d = self.model.data();
        for (r, v) in values.iter_mut().enumerate() {
            self.model.forward_kinematics(&q[r * n..(r + 1) * n], &mut d)?;
            *v = self.model.frame_pose(frame, &d).translation.z;
        }
        Ok(())
    }
    fn gradients(&self, q: &[f64], n: usize, gradients: &mut [f64]) -> Result<()> {
        let frame = self.model.frame_id(FEATURE_FRAME)?;
        let mut d = self.model.data();
        let mut jac = nalgebra::Matrix6xX::zeros(n);
        for r in 0..q.len() / n {
            self.model.forward_kinematics(&q[r * n..(r + 1) * n], &mut d)?;
            self.model.frame_jacobian(frame, &d, &mut jac)?;
            for j in 0..n {
                gradients[r * n + j] = jac[(2, j)];
            }
        }
        Ok(())
    }
    fn hessians(&self, _q: &[f64], _n: usize, _hessians: &mut [f64]) -> Result<()> {
        unimplemented!("has_hessian is false")
    }
}

fn batch_set(model: &Arc<RobotModel>, gradient: bool, fail: bool) -> FeatureSet {
    let frame = model.frame_id(FEATURE_FRAME).unwrap();
    let f = BatchFeature::new(Arc::new(BatchTable { model: model.clone(), gradient, fail }), 1).unwrap();
    let features: Vec<Box<dyn Feature>> = vec![Box::new(phri_core::features::Efficiency), Box::new(f)];
    FeatureSet::new(model.clone(), frame, features).unwrap()
}

#[test]
fn a_batched_feature_plans_as_the_builtin_with_finite_difference_curvature() {
    let model = Arc::new(jaco2());
    let frame = model.frame_id(FEATURE_FRAME).unwrap();
    let specs = [
        FeatureSpec { name: "efficiency".into(), params: FeatureParams::None },
        FeatureSpec { name: "table".into(), params: FeatureParams::None },
    ];
    let mut builtin = FeatureSet::from_specs(model.clone(), frame, &specs, None).unwrap();
    let a = deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let b = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let xi = trajectory(&a, &b, 6, 0.3);
    for gradient in [true, false] {
        let mut batch = batch_set(&model, gradient, false);
        // The exact Hessian by finite differences agrees with the built-in's analytic one.
        let (mut h1, mut h2) = (BlockTridiagonal::new(7, 6), BlockTridiagonal::new(7, 6));
        let (mut g1, mut g2) = (vec![0.0; xi.len()], vec![0.0; xi.len()]);
        let c1 = builtin.weighted_cost_curvature(&xi, &[1.0, 1.0], 0.0, &mut g1, filling(&mut h1)).unwrap();
        let c2 = batch.weighted_cost_curvature(&xi, &[1.0, 1.0], 0.0, &mut g2, filling(&mut h2)).unwrap();
        assert!((c1 - c2).abs() < 1e-12);
        let (gtol, htol) = if gradient { (1e-12, 1e-5) } else { (1e-8, 2e-3) };
        assert!(g1.iter().zip(&g2).all(|(x, y)| (x - y).abs() < gtol), "gradient (analytic: {gradient})");
        for r in 0..xi.len() {
            for c in 0..xi.len() {
                let (x, y) = (entry(&h1, r, c), entry(&h2, r, c));
                assert!((x - y).abs() < htol * (1.0 + x.abs()), "H[{r}, {c}]: {x} vs {y} (analytic gradient: {gradient})");
            }
        }
        // And a plan of the same cost.
        let mut opt = TrajectoryOptimizer::new(&builtin, 31, TrajoptParams::default()).unwrap();
        let (mut p1, mut p2) = (vec![0.0; 31 * 7], vec![0.0; 31 * 7]);
        let i1 = opt.solve(&mut builtin, &[1.0, 1.0], &a, &b, None, &mut p1).unwrap();
        let i2 = opt.solve(&mut batch, &[1.0, 1.0], &a, &b, None, &mut p2).unwrap();
        assert!(i1.converged && i2.converged, "{i1:?} {i2:?}");
        assert!((i1.cost - i2.cost).abs() < 1e-6 * i1.cost.abs(), "{} vs {} (analytic gradient: {gradient})", i1.cost, i2.cost);
    }
}

#[test]
fn a_failing_batched_feature_ends_the_solve_with_its_error() {
    let model = Arc::new(jaco2());
    let mut fs = batch_set(&model, true, true);
    let a = deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let b = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let mut opt = TrajectoryOptimizer::new(&fs, 31, TrajoptParams::default()).unwrap();
    let mut plan = vec![0.0; 31 * 7];
    let e = opt.solve(&mut fs, &[1.0, 1.0], &a, &b, None, &mut plan).unwrap_err();
    assert!(matches!(&e, PhriError::Feature { feature, .. } if feature == "batch_table"), "{e}");
    let mut phi = [0.0; 2];
    let xi = trajectory(&a, &b, 5, 0.0);
    assert!(matches!(fs.phi(&xi, &mut phi), Err(PhriError::Feature { .. })));
    // Weight 0: the feature is not evaluated, so the plan goes ahead.
    assert!(opt.solve(&mut fs, &[1.0, 0.0], &a, &b, None, &mut plan).is_ok());
}
