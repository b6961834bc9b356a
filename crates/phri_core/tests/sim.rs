//! The simulated arm and the simulated control loop: the step is semi-implicit Euler on the
//! forward dynamics, bad input is refused by name, and the loop runs the ticks it should.

mod common;

use std::sync::Arc;

use phri_core::impedance::{ImpedanceController, ImpedanceParams};
use phri_core::learner::{Learner, LearnerParams};
use phri_core::safety::{Limit, SafetyLayer, SafetyLimits, SafetyParams};
use phri_core::sim::{LoopSettings, SimulatedArm, SimulatedLoop};
use phri_core::{PhriError, RobotModel};

const Q: [f64; 7] = [0.1, 2.9, 0.2, 1.3, -2.0, 1.5, 0.4];

fn arm(damping: f64) -> SimulatedArm {
    SimulatedArm::new(Arc::new(common::jaco2_with_cup()), 1e-3, 9.81, &[damping; 7]).unwrap()
}

fn arg_of(e: PhriError) -> String {
    match e {
        PhriError::Shape { arg, .. } | PhriError::NonFinite { arg, .. } | PhriError::InvalidParameter { arg, .. } => arg,
        e => panic!("unexpected error {e}"),
    }
}

#[test]
fn a_step_is_semi_implicit_euler_on_the_forward_dynamics() {
    let model = common::jaco2_with_cup();
    let (mut data, mut mass, mut qdd) = (model.data(), nalgebra::DMatrix::zeros(7, 7), [0.0; 7]);
    for damping in [0.0, 0.7] {
        let mut a = arm(damping);
        a.reset(&Q).unwrap();
        let (mut q, mut qd) = (Q.to_vec(), vec![0.0; 7]);
        for k in 0..200 {
            let tau: Vec<f64> = (0..7).map(|j| ((k + j) as f64 * 0.1).sin()).collect();
            let ext: Vec<f64> = (0..7).map(|j| 0.2 * (j as f64 - 3.0)).collect();
            a.step(&tau, Some(&ext)).unwrap();
            let net: Vec<f64> = (0..7).map(|j| tau[j] - damping * qd[j] + ext[j]).collect();
            model.forward_dynamics(&q, &qd, &net, &mut data, &mut mass, &mut qdd).unwrap();
            for j in 0..7 {
                qd[j] += 1e-3 * qdd[j];
                q[j] += 1e-3 * qd[j];
            }
        }
        assert_eq!(a.q(), &q[..], "damping {damping}");
        assert_eq!(a.qd(), &qd[..]);
        assert!((a.q()[1] - Q[1]).abs() > 1e-3, "the arm did not move: nothing was compared");
    }
}

#[test]
fn gravity_is_the_arms_own() {
    // Without gravity and without torque an arm at rest stays there; with it, it falls.
    let model = Arc::new(common::jaco2_with_cup());
    let mut floating = SimulatedArm::new(model.clone(), 1e-3, 0.0, &[0.0; 7]).unwrap();
    let mut falling = SimulatedArm::new(model, 1e-3, 9.81, &[0.0; 7]).unwrap();
    for a in [&mut floating, &mut falling] {
        a.reset(&Q).unwrap();
        for _ in 0..100 {
            a.step(&[0.0; 7], None).unwrap();
        }
    }
    assert_eq!(floating.q(), &Q[..]);
    assert!(falling.qd().iter().map(|v| v.abs()).sum::<f64>() > 0.1);
}

#[test]
fn bad_arm_input_is_refused_by_name() {
    let model = Arc::new(common::jaco2());
    let new = |dt: f64, g: f64, d: &[f64]| SimulatedArm::new(model.clone(), dt, g, d).unwrap_err();
    assert_eq!(arg_of(new(0.0, 9.81, &[0.0; 7])), "dt");
    assert_eq!(arg_of(new(f64::NAN, 9.81, &[0.0; 7])), "dt");
    assert_eq!(arg_of(new(1e-3, -1.0, &[0.0; 7])), "gravity");
    assert_eq!(arg_of(new(1e-3, f64::INFINITY, &[0.0; 7])), "gravity");
    assert_eq!(arg_of(new(1e-3, 9.81, &[0.0; 6])), "damping");
    assert_eq!(arg_of(new(1e-3, 9.81, &[-1.0; 7])), "damping");
    let mut a = arm(0.0);
    assert_eq!(arg_of(a.reset(&[0.0; 6]).unwrap_err()), "q");
    assert_eq!(arg_of(a.step(&[f64::NAN; 7], None).unwrap_err()), "tau");
    assert_eq!(arg_of(a.step(&[0.0; 7], Some(&[0.0; 3])).unwrap_err()), "tau_ext");
}

#[test]
fn a_step_that_would_leave_a_non_finite_state_is_an_error_and_changes_nothing() {
    let mut a = arm(0.0);
    a.reset(&Q).unwrap();
    let e = a.step(&[1e306; 7], None).unwrap_err();
    assert!(matches!(e, PhriError::Simulation { .. } | PhriError::InvalidParameter { .. }), "{e}");
    assert_eq!(a.q(), &Q[..]);
    assert_eq!(a.qd(), &[0.0; 7]);
}

/// The study table task's robot side: a learner that only tracks (impedance), the law and the
/// safety layer of the arm carrying its cup.
fn robot_side(model: &Arc<RobotModel>, velocity_limit: f64) -> (Learner, ImpedanceController, SafetyLayer) {
    let learner = common::table_learner(model.clone(), LearnerParams { learning: false, ..Default::default() });
    let controller = ImpedanceController::new(model.clone(), ImpedanceParams::jaco2_default()).unwrap();
    let tool = model.frame_id("j2s7s300_end_effector").unwrap();
    let limits = SafetyLimits {
        position_lower: vec![f64::NEG_INFINITY; 7],
        position_upper: vec![f64::INFINITY; 7],
        velocity: vec![velocity_limit; 7],
        torque: model.effort_limits(),
        torque_rate: vec![1e4; 7],
        tool_box: None,
    };
    let safety = SafetyLayer::new(model.clone(), tool, limits, SafetyParams::default()).unwrap();
    (learner, controller, safety)
}

fn settings(model: &RobotModel, duration: f64) -> LoopSettings {
    let hand = model.frame_id("j2s7s300_end_effector").unwrap();
    LoopSettings { duration, hold_time: 0.1, log_period: 0.01, sample_every: 100, hand }
}

#[test]
fn a_quiet_motion_runs_every_tick_logs_at_the_log_rate_and_tracks_its_plan() {
    let model = Arc::new(common::jaco2_with_cup());
    let (mut learner, mut controller, mut safety) = robot_side(&model, 10.0);
    let start = learner.plan().waypoints()[..7].to_vec();
    let a = SimulatedArm::new(model.clone(), 1e-3, 9.81, &[0.0; 7]).unwrap();
    let mut sim = SimulatedLoop::new(a, settings(&model, 0.5), &start, &mut safety).unwrap();
    // In chunks of 20 ticks (a person's looks at 50 Hz), each with its sensor samples' offsets.
    while !sim.done() {
        let until = sim.tick() + 20;
        let offsets = vec![0.01; sim.samples_before(until) as usize * 7];
        sim.advance(until, None, &offsets, &mut learner, &mut controller, &mut safety).unwrap();
    }
    assert_eq!(sim.ticks(), 501);
    let log = sim.log();
    assert_eq!(log.rows(), 51);
    assert!((log.t[50] - 0.5).abs() < 1e-12 && log.touched.iter().all(|t| !t));
    assert!(log.tau_ext.iter().all(|v| *v == 0.01), "the sensor measures its offsets only");
    let gap = (0..log.rows() * 7).map(|i| (log.q[i] - log.q_ref[i]).abs()).fold(0.0, f64::max);
    assert!(gap < 0.01, "the arm strays {gap} rad from its reference");
    assert!(sim.stop().is_none() && sim.held() == 0.0);
    // Done: further chunks run nothing.
    sim.advance(sim.tick() + 20, None, &[0.0; 0], &mut learner, &mut controller, &mut safety).unwrap();
    assert_eq!(sim.ticks(), 501);
}

#[test]
fn a_push_moves_the_arm_and_a_crossed_limit_stops_it_which_holds_then_ends() {
    let model = Arc::new(common::jaco2_with_cup());
    let (mut learner, mut controller, mut safety) = robot_side(&model, 0.2);
    let start = learner.plan().waypoints()[..7].to_vec();
    let a = SimulatedArm::new(model.clone(), 1e-3, 9.81, &[0.0; 7]).unwrap();
    let mut sim = SimulatedLoop::new(a, settings(&model, 2.0), &start, &mut safety).unwrap();
    let push = [0.0, 0.0, 60.0, 0.0, 0.0, 0.0];
    while !sim.done() {
        let until = sim.tick() + 20;
        let offsets = vec![0.0; sim.samples_before(until) as usize * 7];
        sim.advance(until, Some(&push), &offsets, &mut learner, &mut controller, &mut safety).unwrap();
    }
    let stop = sim.stop().expect("a 60 N push drove a joint past 0.2 rad/s");
    assert_eq!(stop.violation.limit, Limit::JointVelocity);
    assert!(stop.hold && stop.tick < 2000);
    // It held for the hold time, then ended: the ticks of the motion up to the stop and the hold's.
    assert!((sim.held() - 0.1).abs() < 1.5e-3, "held {}", sim.held());
    assert_eq!(sim.ticks(), stop.tick + 101);
    let log = sim.log();
    assert!(log.touched.iter().all(|t| *t) && log.push[2] == 60.0);
    let last = log.rows() - 1;
    assert_eq!(&log.q_ref[last * 7..], &stop.q[..], "the hold tracks the position at the stop");
}

#[test]
fn bad_loop_input_is_refused_by_name() {
    let model = Arc::new(common::jaco2_with_cup());
    let (mut learner, mut controller, mut safety) = robot_side(&model, 10.0);
    let start = learner.plan().waypoints()[..7].to_vec();
    let a = || SimulatedArm::new(model.clone(), 1e-3, 9.81, &[0.0; 7]).unwrap();
    let ok = settings(&model, 1.0);
    for (bad, arg) in [
        (LoopSettings { duration: 0.0, ..ok }, "duration"),
        (LoopSettings { hold_time: -1.0, ..ok }, "hold_time"),
        (LoopSettings { log_period: 1e-4, ..ok }, "log_period"),
        (LoopSettings { sample_every: 0, ..ok }, "sample_every"),
        // A log too long to make (about 56 TB): refused, not an aborted allocation.
        (LoopSettings { duration: 1e10, ..ok }, "duration"),
        (LoopSettings { duration: 1e300, ..ok }, "duration"),
    ] {
        assert_eq!(arg_of(SimulatedLoop::new(a(), bad, &start, &mut safety).unwrap_err()), arg);
    }
    assert_eq!(arg_of(SimulatedLoop::new(a(), ok, &[0.0; 6], &mut safety).unwrap_err()), "q_start");
    // The simulated arm does not compensate gravity: a layer that subtracts g(q) would let it fall.
    let mut compensating = SafetyLayer::new(
        model.clone(),
        model.frame_id("j2s7s300_end_effector").unwrap(),
        safety.limits().clone(),
        SafetyParams { gravity_compensated: true, ..SafetyParams::default() },
    )
    .unwrap();
    assert_eq!(arg_of(SimulatedLoop::new(a(), ok, &start, &mut compensating).unwrap_err()), "safety");
    let mut sim = SimulatedLoop::new(a(), ok, &start, &mut safety).unwrap();
    // Tick 0 is a sample instant: one row of offsets is needed, not none.
    assert_eq!(sim.samples_before(20), 1);
    assert_eq!(sim.samples_before(101), 2);
    let e = sim.advance(20, None, &[], &mut learner, &mut controller, &mut safety).unwrap_err();
    assert_eq!(arg_of(e), "offsets");
    let e = sim.advance(20, Some(&[f64::NAN; 6]), &[0.0; 7], &mut learner, &mut controller, &mut safety).unwrap_err();
    assert_eq!(arg_of(e), "push");
    let e = sim.advance(20, None, &[0.0; 7], &mut learner, &mut controller, &mut compensating).unwrap_err();
    assert_eq!(arg_of(e), "safety");
    let params = ImpedanceParams { gravity_compensation: false, ..ImpedanceParams::jaco2_default() };
    let mut without_gravity = ImpedanceController::new(model.clone(), params).unwrap();
    let e = sim.advance(20, None, &[0.0; 7], &mut learner, &mut without_gravity, &mut safety).unwrap_err();
    assert_eq!(arg_of(e), "controller");
}
