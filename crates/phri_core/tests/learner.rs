//! Algorithm 1 driven by scripted pushes: the weights move the right way on every task.

mod common;

use std::sync::Arc;

use common::study::{away_from_keepout, study_features};
use common::{deg, jaco2};
use nalgebra::{Matrix6xX, Vector3};
use phri_core::deform::{DeformParams, Deformation};
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use phri_core::learner::{Learner, LearnerParams};
use phri_core::trajopt::{Clearance, TrajectoryOptimizer, TrajoptParams};
use phri_core::update::UpdateRule;

const PICK_BASIC: [f64; 7] = [104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8];
const PICK_SHELF: [f64; 7] = [210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8];
const PLACE_LOWER: [f64; 7] = [210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0];
const PLACE_HIGHER: [f64; 7] = [210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4];

fn learner(feature: &str, start: [f64; 7], goal: [f64; 7], gain: f64, upper: f64, rule: UpdateRule, learning: bool) -> Learner {
    learner_with(feature, start, goal, gain, upper, rule, LearnerParams { learning, ..Default::default() })
}

fn learner_with(
    feature: &str,
    start: [f64; 7],
    goal: [f64; 7],
    gain: f64,
    upper: f64,
    rule: UpdateRule,
    params: LearnerParams,
) -> Learner {
    let model = Arc::new(jaco2());
    let l7 = model.frame_id("j2s7s300_link_7").unwrap();
    let ee = model.frame_id("j2s7s300_end_effector").unwrap();
    let fs = study_features(model, l7, &["efficiency", feature]);
    let clearance = vec![Clearance { frame: ee, min_z: 0.0, weight: 1e3 }, Clearance { frame: l7, min_z: -0.04, weight: 1e3 }];
    let opt = TrajectoryOptimizer::new(&fs, 31, TrajoptParams { clearance, ..Default::default() }).unwrap();
    let update = common::one_feature_update(gain, upper, rule);
    let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
    let deformation = Deformation::new(DeformParams::default()).unwrap();
    Learner::new(params, fs, deformation, update, detector, opt, &[1.0, 0.0], &deg(start), &deg(goal)).unwrap()
}

/// The joint torque of a wrench (force [N], torque [N·m]) at the hand, at the plan's pose at t.
fn push(l: &Learner, t: f64, force: Vector3<f64>, torque: Vector3<f64>) -> Vec<f64> {
    let model = jaco2();
    let (mut q, mut qd, mut qdd) = (vec![0.0; 7], vec![0.0; 7], vec![0.0; 7]);
    l.reference(t, &mut q, &mut qd, &mut qdd);
    let mut d = model.data();
    model.forward_kinematics(&q, &mut d).unwrap();
    let mut j = Matrix6xX::zeros(7);
    model.frame_jacobian(model.frame_id("j2s7s300_end_effector").unwrap(), &d, &mut j).unwrap();
    let w = nalgebra::Vector6::new(force.x, force.y, force.z, torque.x, torque.y, torque.z);
    (j.transpose() * w).iter().copied().collect()
}

/// The hand position on the plan at time t.
fn hand(l: &Learner, t: f64) -> Vector3<f64> {
    let model = jaco2();
    let (mut q, mut qd, mut qdd) = (vec![0.0; 7], vec![0.0; 7], vec![0.0; 7]);
    l.reference(t, &mut q, &mut qd, &mut qdd);
    let mut d = model.data();
    model.forward_kinematics(&q, &mut d).unwrap();
    model.frame_pose(model.frame_id("j2s7s300_link_7").unwrap(), &d).translation.vector
}

#[test]
fn scripted_pushes_move_each_task_weight_the_right_way() {
    // (task feature, start, goal, step, upper bound)
    type Case = (&'static str, [f64; 7], [f64; 7], f64, f64);
    let cases: Vec<Case> = vec![
        ("table", PICK_BASIC, PLACE_LOWER, 2.0, 1.0),
        ("coffee", PICK_SHELF, PLACE_LOWER, 2.0, 1.0),
        ("laptop", PICK_BASIC, PLACE_HIGHER, 100.0, 10.0),
        ("human", PICK_SHELF, PLACE_HIGHER, 100.0, 10.0),
    ];
    for (feature, start, goal, gain, upper) in cases {
        for rule in [UpdateRule::All, UpdateRule::Max, UpdateRule::Confidence] {
            let mut l = learner(feature, start, goal, gain, upper, rule, true);
            let mut replans = 0;
            for k in 0..10 {
                let t = 4.0 + 0.1 * k as f64;
                let p = hand(&l, t);
                let (force, torque) = match feature {
                    "table" => (Vector3::new(0.0, 0.0, -25.0), Vector3::zeros()),
                    // Right the cup: rotate link_7's x axis towards +z.
                    "coffee" => {
                        let model = jaco2();
                        let (mut q, mut qd, mut qdd) = (vec![0.0; 7], vec![0.0; 7], vec![0.0; 7]);
                        l.reference(t, &mut q, &mut qd, &mut qdd);
                        let mut d = model.data();
                        model.forward_kinematics(&q, &mut d).unwrap();
                        let x: Vector3<f64> =
                            model.frame_pose(model.frame_id("j2s7s300_link_7").unwrap(), &d).rotation.matrix().column(0).into();
                        // Like a person: only while the cup is visibly tilted.
                        if x.z.acos() < 0.3 {
                            continue;
                        }
                        (Vector3::zeros(), x.cross(&Vector3::z()).normalize() * 4.0)
                    }
                    // Away from the keep-out centre, horizontally.
                    _ => (away_from_keepout(feature, &p) * 25.0, Vector3::zeros()),
                };
                let tau = push(&l, t, force, torque);
                let obs = l.observe(t, &tau).unwrap();
                replans += usize::from(obs.replanned);
            }
            let w = l.weights()[1];
            eprintln!("{feature} {rule:?}: w = {w}, replans {replans}");
            assert!(w > 0.0, "{feature} {rule:?}: the task weight did not grow ({w})");
            assert!(replans > 0);
            assert_eq!(l.history().plans.len(), replans + 1);
        }
    }
}

#[test]
fn without_learning_the_plan_never_changes() {
    let mut l = learner("table", PICK_BASIC, PLACE_LOWER, 2.0, 1.0, UpdateRule::All, false);
    let before = l.plan().waypoints().to_vec();
    for k in 0..20 {
        let t = 3.0 + 0.1 * k as f64;
        let tau = push(&l, t, Vector3::new(0.0, 0.0, -25.0), Vector3::zeros());
        let obs = l.observe(t, &tau).unwrap();
        assert!(obs.interacted && !obs.replanned);
    }
    assert_eq!(l.plan().waypoints(), &before[..]);
    assert_eq!(l.weights(), &[1.0, 0.0]);
    assert_eq!(l.history().interactions.len(), 20);
}

#[test]
fn samples_follow_the_sample_period_and_quiet_ticks_change_nothing() {
    let mut l = learner("table", PICK_BASIC, PLACE_LOWER, 2.0, 1.0, UpdateRule::All, true);
    let mut sampled = 0;
    for k in 0..1000 {
        let obs = l.observe(k as f64 * 1e-3, &[0.0; 7]).unwrap();
        sampled += usize::from(obs.sampled);
        assert!(!obs.interacted);
    }
    assert_eq!(sampled, 10, "10 Hz over one second, got {sampled}");
    assert!(l.history().interactions.is_empty());
    assert!(l.observe(f64::NAN, &[0.0; 7]).is_err());
    assert!(l.observe(2.0, &[0.0; 6]).is_err());
}

#[test]
fn a_replan_budget_spreads_the_replan_over_ticks_and_ends_on_the_same_plan() {
    let budget = 3;
    let params = LearnerParams { replan_iterations: budget, ..Default::default() };
    let mut capped = learner_with("laptop", PICK_BASIC, PLACE_HIGHER, 100.0, 10.0, UpdateRule::All, params);
    let mut full = learner("laptop", PICK_BASIC, PLACE_HIGHER, 100.0, 10.0, UpdateRule::All, true);
    assert_eq!(capped.plan().waypoints(), full.plan().waypoints(), "the initial plan converges either way");
    let t = 4.0;
    let p = hand(&full, t);
    let tau = push(&full, t, away_from_keepout("laptop", &p) * 25.0, Vector3::zeros());
    assert!(full.observe(t, &tau).unwrap().replanned);
    let obs = capped.observe(t, &tau).unwrap();
    assert!(obs.replanned && capped.replan_pending(), "one push at weight 0 takes more than {budget} iterations");
    assert_eq!(capped.weights(), full.weights());
    let first = capped.history().interactions[0].replan.unwrap();
    assert!(first.iterations <= budget && !first.converged, "{first:?}");
    // Quiet ticks at 1 kHz go on with the replan until it converges.
    let mut ticks = 0;
    while capped.replan_pending() {
        ticks += 1;
        assert!(ticks < 200, "the budgeted replan never converged");
        let obs = capped.observe(t + 1e-3 * ticks as f64, &[0.0; 7]).unwrap();
        assert!(obs.replanned && !obs.interacted);
    }
    assert!(ticks >= 2, "{ticks}");
    assert_eq!(capped.history().plans.len(), ticks + 2, "the initial plan, the first chunk, one per tick");
    // The same optimum as the uncapped replan (the chunks restart the damping, so not bit for bit).
    let worst = capped.plan().waypoints().iter().zip(full.plan().waypoints()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(worst < 1e-5, "the budgeted plan ends {worst} rad from the uncapped one");
    // Nothing pending: quiet ticks do nothing.
    assert!(!capped.observe(t + 0.5, &[0.0; 7]).unwrap().replanned);
}

#[test]
fn seed_plans_shorten_the_replan_after_a_large_update() {
    // (Starting from the better of the current plan and the seed does not promise a better optimum in
    // general; on these tasks it ends no worse.)
    for (feature, start, goal, gain, upper) in
        [("laptop", PICK_BASIC, PLACE_HIGHER, 100.0, 10.0), ("table", PICK_BASIC, PLACE_LOWER, 2.0, 1.0)]
    {
        let seeded = LearnerParams { seeds: 5, ..Default::default() };
        let mut with = learner_with(feature, start, goal, gain, upper, UpdateRule::All, seeded);
        let mut without = learner(feature, start, goal, gain, upper, UpdateRule::All, true);
        assert_eq!(with.plan().waypoints(), without.plan().waypoints(), "{feature}: the initial plan is the same");
        let t = 4.0;
        let force = match feature {
            "table" => Vector3::new(0.0, 0.0, -25.0),
            _ => {
                let p = hand(&without, t);
                away_from_keepout(feature, &p) * 25.0
            }
        };
        let tau = push(&without, t, force, Vector3::zeros());
        with.observe(t, &tau).unwrap();
        without.observe(t, &tau).unwrap();
        assert_eq!(with.weights(), without.weights());
        let (a, b) = (with.history().interactions[0].replan.unwrap(), without.history().interactions[0].replan.unwrap());
        assert!(a.converged && b.converged);
        assert!(a.iterations * 2 <= b.iterations, "{feature}: seeded {} iterations vs {}", a.iterations, b.iterations);
        assert!(a.cost <= b.cost + 1e-9, "{feature}: the seeded plan costs {} against {}", a.cost, b.cost);
    }
}

#[test]
fn seed_settings_are_checked() {
    let make = |seeds, upper| {
        let params = LearnerParams { seeds, ..Default::default() };
        let model = Arc::new(jaco2());
        let l7 = model.frame_id("j2s7s300_link_7").unwrap();
        let fs = study_features(model, l7, &["efficiency", "table"]);
        let opt = TrajectoryOptimizer::new(&fs, 31, TrajoptParams::default()).unwrap();
        let update = common::one_feature_update(2.0, upper, UpdateRule::All);
        let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
        let deformation = Deformation::new(DeformParams::default()).unwrap();
        Learner::new(params, fs, deformation, update, detector, opt, &[1.0, 0.0], &deg(PICK_BASIC), &deg(PLACE_LOWER))
    };
    let message = |r: Result<Learner, phri_core::PhriError>| r.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(message(make(1, 1.0)).starts_with("seeds must be 0 (none) or at least 2"));
    assert!(message(make(3, f64::INFINITY)).starts_with("seeds need finite bounds for every learned weight; weight 1"));
    assert!(message(make(65, 1.0)).contains("more than 64"));
    assert!(make(3, 1.0).is_ok());
}
