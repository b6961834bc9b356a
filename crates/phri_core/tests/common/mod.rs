// Shared by the integration tests (each test file includes it with `mod common;`).
#![allow(dead_code)]

use phri_core::RobotModel;

pub mod study;

pub const JACO2_URDF: &str = include_str!("../../../../python/phri/robots/jaco2/j2s7s300.urdf");

pub fn jaco2() -> RobotModel {
    RobotModel::from_urdf_str(JACO2_URDF, Some("root"), Some("j2s7s300_end_effector")).unwrap()
}

pub const CUP_URDF: &str = include_str!("../../../../python/phri/robots/jaco2/cup.urdf");

/// The JACO2 carrying the study's cup at its cup frame (as `Robot.jaco2()` does).
pub fn jaco2_with_cup() -> RobotModel {
    let model = jaco2();
    let frame = model.frame_id("j2s7s300_cup_frame").unwrap();
    model.with_attached_urdf("cup", frame, CUP_URDF).unwrap()
}

/// The update of a task learning one feature beside efficiency (weight 1, fixed): its `gain` and
/// clip [0, `upper`], with `rule`.
pub fn one_feature_update(gain: f64, upper: f64, rule: phri_core::update::UpdateRule) -> phri_core::update::WeightUpdate {
    phri_core::update::WeightUpdate::new(phri_core::update::UpdateParams {
        step: vec![0.0, gain],
        lower: vec![1.0, 0.0],
        upper: vec![1.0, upper],
        learned: vec![false, true],
        ranges: vec![1.0, 1.0],
        rule,
    })
    .unwrap()
}

pub fn deg(q: [f64; 7]) -> Vec<f64> {
    q.iter().map(|d| d.to_radians()).collect()
}

/// A configuration inside the limits from seven numbers in [0, 1).
pub fn within_limits(model: &RobotModel, u: &[f64]) -> Vec<f64> {
    model
        .joints
        .iter()
        .zip(u)
        .map(|(j, &u)| if j.lower.is_finite() { j.lower + u * (j.upper - j.lower) } else { u * std::f64::consts::TAU })
        .collect()
}

/// The study table task's learner on `model` (features ["efficiency", "table"] at link_7, N = 31,
/// initial weights [1, 0], the original thresholds and deformation) with `params`.
pub fn table_learner(
    model: std::sync::Arc<RobotModel>,
    params: phri_core::learner::LearnerParams,
) -> phri_core::learner::Learner {
    use phri_core::deform::{DeformParams, Deformation};
    use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
    use phri_core::trajopt::{TrajectoryOptimizer, TrajoptParams};
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let fs = study::study_features(model, frame, &["efficiency", "table"]);
    let opt = TrajectoryOptimizer::new(&fs, 31, TrajoptParams::default()).unwrap();
    let update = one_feature_update(2.0, 1.0, phri_core::update::UpdateRule::All);
    let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
    let deformation = Deformation::new(DeformParams::default()).unwrap();
    let start = deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let goal = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    phri_core::learner::Learner::new(params, fs, deformation, update, detector, opt, &[1.0, 0.0], &start, &goal).unwrap()
}
