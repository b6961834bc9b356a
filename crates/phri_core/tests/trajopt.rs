//! Trajectory optimisation on the study's four tasks.

mod common;

use std::sync::Arc;

use common::{deg, jaco2};
use phri_core::features::{FeatureSet, SceneParams};
use phri_core::trajopt::{Clearance, TrajectoryOptimizer, TrajoptParams};

const PICK_BASIC: [f64; 7] = [104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8];
const PICK_SHELF: [f64; 7] = [210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8];
const PLACE_LOWER: [f64; 7] = [210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0];
const PLACE_HIGHER: [f64; 7] = [210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4];

/// (task feature, start, goal, true weight)
fn tasks() -> Vec<(&'static str, [f64; 7], [f64; 7], f64)> {
    vec![
        ("human", PICK_SHELF, PLACE_HIGHER, 10.0),
        ("coffee", PICK_SHELF, PLACE_LOWER, 1.0),
        ("table", PICK_BASIC, PLACE_LOWER, 1.0),
        ("laptop", PICK_BASIC, PLACE_HIGHER, 10.0),
    ]
}

fn model_frame(fs: &FeatureSet, name: &str) -> phri_core::FrameId {
    fs.model().frame_id(name).unwrap()
}

fn setup(feature: &str) -> (FeatureSet, TrajectoryOptimizer) {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let ee = model.frame_id("j2s7s300_end_effector").unwrap();
    let fs = FeatureSet::from_names(model, frame, &["efficiency", feature], &SceneParams::default()).unwrap();
    let l7 = model_frame(&fs, "j2s7s300_link_7");
    let params = TrajoptParams {
        clearance: vec![
            Clearance { frame: ee, min_z: 0.0, weight: 1e3 },
            Clearance { frame: l7, min_z: -0.1016 + 0.06, weight: 1e3 },
        ],
        ..Default::default()
    };
    let opt = TrajectoryOptimizer::new(&fs, 31, params).unwrap();
    (fs, opt)
}

#[test]
fn plans_lower_the_task_feature_and_keep_the_constraints() {
    for (feature, start, goal, weight) in tasks() {
        let (mut fs, mut opt) = setup(feature);
        let (start, goal) = (deg(start), deg(goal));
        let mut plan0 = vec![0.0; 31 * 7];
        let info0 = opt.solve(&mut fs, &[1.0, 0.0], &start, &goal, None, &mut plan0).unwrap();
        let mut plan = vec![0.0; 31 * 7];
        let info = opt.solve(&mut fs, &[1.0, weight], &start, &goal, None, &mut plan).unwrap();
        let (mut phi0, mut phi) = ([0.0; 2], [0.0; 2]);
        fs.phi(&plan0, &mut phi0).unwrap();
        fs.phi(&plan, &mut phi).unwrap();
        eprintln!("{feature}: w=0 {phi0:?} {info0:?}\n        w={weight} {phi:?} {info:?}");
        assert!(phi[1] < phi0[1] - 1e-3, "{feature}: {} !< {}", phi[1], phi0[1]);
        assert!(info.converged && info0.converged, "{feature}: {info:?}");
        assert!(info.max_violation < 1e-3, "{feature}: clearance violated by {}", info.max_violation);
        assert_eq!(&plan[..7], &start[..]);
        assert_eq!(&plan[30 * 7..], &goal[..]);
        let model = fs.model().clone();
        for i in 0..31 {
            model.check_within_limits("plan", &plan[i * 7..(i + 1) * 7]).unwrap();
        }
    }
}

#[test]
fn warm_start_from_the_solution_is_cheap_and_solves_are_deterministic() {
    let (mut fs, mut opt) = setup("table");
    let (start, goal) = (deg(PICK_BASIC), deg(PLACE_LOWER));
    let mut plan = vec![0.0; 31 * 7];
    let cold = opt.solve(&mut fs, &[1.0, 0.5], &start, &goal, None, &mut plan).unwrap();
    let mut again = vec![0.0; 31 * 7];
    opt.solve(&mut fs, &[1.0, 0.5], &start, &goal, None, &mut again).unwrap();
    assert_eq!(plan, again, "same inputs, same plan");
    let mut warm = vec![0.0; 31 * 7];
    let info = opt.solve(&mut fs, &[1.0, 0.5], &start, &goal, Some(&plan), &mut warm).unwrap();
    assert!(info.iterations * 4 <= cold.iterations, "warm {info:?}\ncold {cold:?}");
    assert!(info.cost <= cold.cost + 1e-12);
}

#[test]
fn bad_problems_are_typed_errors() {
    let (mut fs, mut opt) = setup("table");
    let (start, goal) = (deg(PICK_BASIC), deg(PLACE_LOWER));
    let mut plan = vec![0.0; 31 * 7];
    assert!(opt.solve(&mut fs, &[1.0], &start, &goal, None, &mut plan).is_err());
    assert!(opt.solve(&mut fs, &[1.0, f64::NAN], &start, &goal, None, &mut plan).is_err());
    assert!(opt.solve(&mut fs, &[1.0, 1.0], &[0.0; 7], &goal, None, &mut plan).is_err(), "q = 0 violates joint 2's limits");
    assert!(opt.solve(&mut fs, &[1.0, 1.0], &start, &goal, Some(&[0.0; 7]), &mut plan).is_err());
    assert!(TrajectoryOptimizer::new(&fs, 2, TrajoptParams::default()).is_err());
}
