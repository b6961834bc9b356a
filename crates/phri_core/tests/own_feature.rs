//! A feature of your own in Rust (docs/features.md): the elbow's height above the table, written
//! against the `Feature` trait, plans as the same feature declared in a task file does.

mod common;

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};
use phri_core::features::{DeclaredSpec, Efficiency, Feature, FeatureParams, FeatureSet, FeatureSpec, Segment, SegmentGrad};
use phri_core::scene::{ObjectKind, Scene, SceneObject, Shape, DEFAULT_MARGIN};
use phri_core::trajopt::{TrajectoryOptimizer, TrajoptParams};
use phri_core::FrameId;

/// φ = z − `top` of the elbow's origin at each waypoint q_i [m].
#[derive(Debug, Clone)]
struct ElbowHeight {
    elbow: FrameId,
    /// The table's top [m].
    top: f64,
}

impl Feature for ElbowHeight {
    fn name(&self) -> &str {
        "elbow"
    }

    /// φ at the segment's end, q_i (s = 1); with `grad`, adds its gradient (and, when the
    /// optimiser asks for it, the kinematic curvature) scaled by `g.scale`.
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let frame = Some(self.elbow);
        let value = seg.point_of(frame, 1.0).position.z - self.top;
        if let Some(g) = grad {
            let jac = seg.jacobian_of(frame, 1.0); // 6 × n: linear rows first
            for j in 0..g.this.len() {
                g.this[j] += g.scale * jac[(2, j)];
            }
            if let Some(h) = g.hessian {
                if h.kinematic() {
                    seg.add_position_curvature_of(frame, 1.0, &Vector3::z(), g.scale, h);
                }
            }
        }
        value
    }
}

#[test]
fn a_rust_feature_plans_as_the_same_feature_declared() {
    let model = Arc::new(common::jaco2());
    let cup = model.frame_id("j2s7s300_link_7").unwrap();
    let elbow = model.frame_id("j2s7s300_link_4").unwrap();
    // The study's table: a box whose top is at z = -0.1016 m.
    let table = Shape::Box { size: Vector3::new(0.81, 1.62, 0.7) };
    let pose = Isometry3::translation(-0.405, 0.0, -0.4516);
    let scene = Scene::new(vec![SceneObject::new("table", table, pose, DEFAULT_MARGIN, ObjectKind::Furniture).unwrap()]).unwrap();
    let top = scene.get("table").and_then(|t| t.top()).unwrap();

    let mut mine = FeatureSet::new(model.clone(), cup, vec![Box::new(Efficiency), Box::new(ElbowHeight { elbow, top })]).unwrap();
    let declared = FeatureSpec {
        name: "elbow".into(),
        params: FeatureParams::Declared(DeclaredSpec::Height {
            frame: Some("j2s7s300_link_4".into()),
            object: Some("table".into()),
            offset: 0.0,
        }),
    };
    let specs = [FeatureSpec { name: "efficiency".into(), params: FeatureParams::None }, declared];
    let mut theirs = FeatureSet::from_specs(model.clone(), cup, &specs, Some(&scene)).unwrap();

    let start = common::deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let goal = common::deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let mut opt = TrajectoryOptimizer::new(&mine, 31, TrajoptParams::default()).unwrap();
    let (mut a, mut b) = (vec![0.0; 31 * 7], vec![0.0; 31 * 7]);
    let weights = [1.0, 1.0];
    let ia = opt.solve(&mut mine, &weights, &start, &goal, None, &mut a).unwrap();
    let ib = opt.solve(&mut theirs, &weights, &start, &goal, None, &mut b).unwrap();
    assert!(ia.converged && ib.converged, "{ia:?} {ib:?}");
    assert!((ia.cost - ib.cost).abs() <= 1e-9 * ib.cost.abs(), "{} against {}", ia.cost, ib.cost);

    // The weight on the elbow's height lowers it, on average over the plan's waypoints.
    let mut unweighted = vec![0.0; 31 * 7];
    opt.solve(&mut mine, &[1.0, 0.0], &start, &goal, None, &mut unweighted).unwrap();
    let (mut phi_low, mut phi_free) = ([0.0; 2], [0.0; 2]);
    mine.phi(&a, &mut phi_low).unwrap();
    mine.phi(&unweighted, &mut phi_free).unwrap();
    assert!(phi_low[1] < phi_free[1] - 0.3, "elbow Φ {} with the weight, {} without", phi_low[1], phi_free[1]);
}
