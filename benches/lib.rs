//! Shared fixtures for the criterion benchmarks.

use std::sync::Arc;

use nalgebra::{Matrix6xX, Vector3, Vector6};
use phri_core::collision::{CollisionChecker, SELF_MARGIN};
use phri_core::deform::{DeformParams, Deformation};
use phri_core::features::FeatureSet;
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use phri_core::learner::{Learner, LearnerParams};
use phri_core::trajopt::{Clearance, CollisionParams, TrajectoryOptimizer, TrajoptParams};
use phri_core::update::{UpdateParams, UpdateRule, WeightUpdate};
use phri_core::RobotModel;

/// The study's scene and feature parameters, read from the shipped task files (the same helper
/// phri_core's integration tests use).
#[path = "../crates/phri_core/tests/common/study.rs"]
pub mod study;
use study::{away_from_keepout, study_features, table_top, task_scene};

/// The shipped JACO2 description (the same file the Python package loads).
pub const JACO2_URDF: &str = include_str!("../python/phri/robots/jaco2/j2s7s300.urdf");

/// The JACO2 chain from `root` to the tool point.
pub fn jaco2() -> RobotModel {
    RobotModel::from_urdf_str(JACO2_URDF, Some("root"), Some("j2s7s300_end_effector")).expect("shipped URDF parses")
}

/// The shipped cup the study's JACO2 carries.
pub const CUP_URDF: &str = include_str!("../python/phri/robots/jaco2/cup.urdf");

/// The JACO2 carrying the study's cup at its cup frame (as `Robot.jaco2()` does): the robot of
/// the study's planner and learner.
pub fn jaco2_with_cup() -> RobotModel {
    let model = jaco2();
    let frame = model.frame_id("j2s7s300_cup_frame").expect("cup frame exists");
    model.with_attached_urdf("cup", frame, CUP_URDF).expect("shipped cup URDF attaches")
}

/// `count` configurations within `model`'s joint limits (continuous joints in [0, 2π)), from a
/// seeded xorshift so the benchmarks need no RNG crate and are the same every run.
pub fn configurations(model: &RobotModel, count: usize, seed: u64) -> Vec<[f64; 7]> {
    let mut state = seed;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..count)
        .map(|_| {
            let mut q = [0.0; 7];
            for (v, j) in q.iter_mut().zip(&model.joints) {
                let (lo, hi) = if j.lower.is_finite() { (j.lower, j.upper) } else { (0.0, std::f64::consts::TAU) };
                *v = lo + (hi - lo) * uniform();
            }
            q
        })
        .collect()
}

/// Kinova degrees to radians.
pub fn deg(q: [f64; 7]) -> [f64; 7] {
    q.map(f64::to_radians)
}

/// The study's pick_basic pose [rad].
pub fn pick_basic() -> [f64; 7] {
    deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8])
}

/// The study's pick_shelf pose [rad].
pub fn pick_shelf() -> [f64; 7] {
    deg([210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8])
}

/// The study's place_lower pose [rad].
pub fn place_lower() -> [f64; 7] {
    deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
}

/// The study's place_higher pose [rad].
pub fn place_higher() -> [f64; 7] {
    deg([210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4])
}

/// One of the study's four tasks (python/phri/tasks/*.toml, after the authors' published code).
#[derive(Debug, Clone, Copy)]
pub struct StudyTask {
    /// Task name, which is also the name of its learned feature.
    pub name: &'static str,
    pub start: [f64; 7],
    pub goal: [f64; 7],
    /// The demonstrated (true) cost weight of the task feature; efficiency has weight 1.
    pub true_weight: f64,
    /// Update gain of the task feature [weight per unit feature count].
    pub gain: f64,
}

/// The four tasks, in the study's order.
pub fn study_tasks() -> [StudyTask; 4] {
    [
        StudyTask { name: "human", start: pick_shelf(), goal: place_higher(), true_weight: 10.0, gain: 100.0 },
        StudyTask { name: "coffee", start: pick_shelf(), goal: place_lower(), true_weight: 1.0, gain: 2.0 },
        StudyTask { name: "table", start: pick_basic(), goal: place_lower(), true_weight: 1.0, gain: 2.0 },
        StudyTask { name: "laptop", start: pick_basic(), goal: place_higher(), true_weight: 10.0, gain: 100.0 },
    ]
}

/// Task duration T [s].
pub const DURATION: f64 = 15.0;
/// Plans move each joint at most this fraction of its velocity limit.
pub const VELOCITY_MARGIN: f64 = 0.5;
/// Waypoints of the study's plans (T = 15 s in 0.5 s steps).
pub const STUDY_WAYPOINTS: usize = 31;

/// The collision checker of the study's planner for `task`: every collision body of `model` (the
/// JACO2 with the cup) against the objects of the task file's scene, each with its margin, and
/// against each other ([`SELF_MARGIN`]).
pub fn study_checker(model: &RobotModel, task: &StudyTask) -> CollisionChecker {
    assert!(
        model.collision().bodies().iter().any(|b| b.name == "cup"),
        "the study's planner is built for the JACO2 carrying the cup (jaco2_with_cup)"
    );
    CollisionChecker::new(model, &task_scene(task.name), Some(SELF_MARGIN)).expect("complete collision model")
}

/// The study's planner for `task` over `waypoints` waypoints, as `phri.sim.Planner` builds it:
/// features ["efficiency", task] on `model` (the JACO2 with the cup, [`jaco2_with_cup`]), the full
/// collision model against the task's scene with self-collision ([`study_checker`], the penalty's
/// defaults), and max_step = 0.5 × velocity limit × waypoint spacing; other parameters at their
/// defaults.
pub fn study_planner(model: &Arc<RobotModel>, task: &StudyTask, waypoints: usize) -> (FeatureSet, TrajectoryOptimizer) {
    planner(model, task, waypoints, 1.0)
}

/// The study's planning problem posed on `waypoints` waypoints with the trade-off it has on the
/// study's 31: the planner of [`study_planner`] with the collision weight scaled by r² (r = 30 /
/// (waypoints − 1), as the per-waypoint features) and the weights [1, true weight] rescaled by
/// `FeatureSet::rescale_weights`, which it returns.
pub fn study_problem_at(
    model: &Arc<RobotModel>,
    task: &StudyTask,
    waypoints: usize,
) -> (FeatureSet, TrajectoryOptimizer, Vec<f64>) {
    let r = resolution_ratio(waypoints);
    let (features, optimizer) = planner(model, task, waypoints, r * r);
    let weights = features.rescale_weights(&[1.0, task.true_weight], STUDY_WAYPOINTS, waypoints).expect("two weights");
    (features, optimizer, weights)
}

/// r = 30 / (waypoints − 1): the study's waypoint spacing over this one's.
fn resolution_ratio(waypoints: usize) -> f64 {
    (STUDY_WAYPOINTS - 1) as f64 / (waypoints - 1) as f64
}

fn study_max_step(model: &RobotModel, waypoints: usize) -> Vec<f64> {
    let spacing = DURATION / (waypoints - 1) as f64;
    model.velocity_limits().iter().map(|v| VELOCITY_MARGIN * v * spacing).collect()
}

fn planner(model: &Arc<RobotModel>, task: &StudyTask, waypoints: usize, weight_scale: f64) -> (FeatureSet, TrajectoryOptimizer) {
    let link_7 = model.frame_id("j2s7s300_link_7").expect("link_7 exists");
    let features = study_features(model.clone(), link_7, &["efficiency", task.name]);
    let mut collision = CollisionParams::new(Arc::new(study_checker(model, task)));
    collision.weight *= weight_scale;
    let params = TrajoptParams { collision: Some(collision), max_step: study_max_step(model, waypoints), ..Default::default() };
    let optimizer = TrajectoryOptimizer::new(&features, waypoints, params).expect("valid parameters");
    (features, optimizer)
}

/// The earlier study planner's tool-point clearance above the table top [m].
pub const HAND_CLEARANCE: f64 = 0.1016;
/// The earlier study planner's link_7 clearance above the table top [m].
pub const CUP_CLEARANCE: f64 = 0.06;
/// The earlier study planner's clearance penalty weight [1/m²].
const CLEARANCE_WEIGHT: f64 = 1e3;

/// The study's planner before the collision model, the problem benches/trajopt_peers.py poses to
/// the peers and benches/trajopt_work.py counts: features ["efficiency", task] on `model` (the bare
/// JACO2, [`jaco2`]), the tool point and link_7 kept [`HAND_CLEARANCE`] and [`CUP_CLEARANCE`] above
/// the table top (weight 10³), max_step as [`study_planner`]; posed on `waypoints` with the
/// trade-off of the study's 31 (the clearance weight and the returned weights rescaled as in
/// [`study_problem_at`]) when `rescaled`, else with the weights [1, true weight].
pub fn clearance_problem_at(
    model: &Arc<RobotModel>,
    task: &StudyTask,
    waypoints: usize,
    rescaled: bool,
) -> (FeatureSet, TrajectoryOptimizer, Vec<f64>) {
    let r = if rescaled { resolution_ratio(waypoints) } else { 1.0 };
    let link_7 = model.frame_id("j2s7s300_link_7").expect("link_7 exists");
    let hand = model.frame_id("j2s7s300_end_effector").expect("tool point exists");
    let features = study_features(model.clone(), link_7, &["efficiency", task.name]);
    let (top, weight) = (table_top(), CLEARANCE_WEIGHT * r * r);
    let params = TrajoptParams {
        clearance: vec![
            Clearance { frame: hand, min_z: top + HAND_CLEARANCE, weight },
            Clearance { frame: link_7, min_z: top + CUP_CLEARANCE, weight },
        ],
        max_step: study_max_step(model, waypoints),
        ..Default::default()
    };
    let optimizer = TrajectoryOptimizer::new(&features, waypoints, params).expect("valid parameters");
    let weights = if rescaled {
        features.rescale_weights(&[1.0, task.true_weight], STUDY_WAYPOINTS, waypoints).expect("two weights")
    } else {
        vec![1.0, task.true_weight]
    };
    (features, optimizer, weights)
}

/// Algorithm 1 on `task` as the simulated study runs it (initial task weight 0, the task's gain and
/// clip, the "all" rule, original thresholds and deformation) with `params` (its duration set to
/// the task's). Construction plans cold.
pub fn study_learner(model: &Arc<RobotModel>, task: &StudyTask, waypoints: usize, params: LearnerParams) -> Learner {
    let (features, optimizer) = study_planner(model, task, waypoints);
    let update = WeightUpdate::new(UpdateParams {
        step: vec![0.0, task.gain],
        lower: vec![1.0, 0.0],
        upper: vec![1.0, task.true_weight],
        learned: vec![false, true],
        ranges: vec![1.0, 1.0],
        rule: UpdateRule::All,
    })
    .expect("valid update");
    let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).expect("valid thresholds");
    let deformation = Deformation::new(DeformParams::default()).expect("default deformation");
    let params = LearnerParams { duration: DURATION, ..params };
    Learner::new(params, features, deformation, update, detector, optimizer, &[1.0, 0.0], &task.start, &task.goal)
        .expect("valid learner")
}

/// The joint torque [N·m] of a person's push at the tool point, at the learner's reference pose at
/// time `t` [s]: a 25 N force that moves the cup the way the task wants (down for table, away from
/// the keep-out centre for laptop and human), or a 4 N·m torque righting the cup for coffee.
pub fn corrective_push(model: &RobotModel, learner: &Learner, task: &StudyTask, t: f64) -> [f64; 7] {
    let (mut q, mut qd, mut qdd) = ([0.0; 7], [0.0; 7], [0.0; 7]);
    learner.reference(t, &mut q, &mut qd, &mut qdd);
    let mut data = model.data();
    model.forward_kinematics(&q, &mut data).expect("valid q");
    let link_7 = model.frame_id("j2s7s300_link_7").expect("link_7 exists");
    let hand = model.frame_id("j2s7s300_end_effector").expect("tool point exists");
    let pose = model.frame_pose(link_7, &data);
    let p = pose.translation.vector;
    let (force, torque) = match task.name {
        "table" => (Vector3::new(0.0, 0.0, -25.0), Vector3::zeros()),
        "coffee" => {
            let x: Vector3<f64> = pose.rotation.matrix().column(0).into();
            (Vector3::zeros(), x.cross(&Vector3::z()).normalize() * 4.0)
        }
        _ => (away_from_keepout(task.name, &p) * 25.0, Vector3::zeros()),
    };
    let mut jacobian = Matrix6xX::zeros(7);
    model.frame_jacobian(hand, &data, &mut jacobian).expect("7 columns");
    let tau = jacobian.transpose() * Vector6::new(force.x, force.y, force.z, torque.x, torque.y, torque.z);
    let mut out = [0.0; 7];
    out.iter_mut().zip(tau.iter()).for_each(|(o, v)| *o = *v);
    out
}
