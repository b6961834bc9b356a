//! The safety layer's per-tick checks: each limit is named with its joint and value when crossed,
//! torques are clipped and counted, and random states never give a NaN command.

mod common;

use std::sync::Arc;

use phri_core::safety::{Limit, Quantity, SafetyLayer, SafetyLimits, SafetyParams, SafetyStatus, ToolBox, Violation};
use phri_core::{Result, RobotModel};
use proptest::prelude::*;

fn jaco2() -> Arc<RobotModel> {
    Arc::new(common::jaco2())
}

/// The study's start pose of the table task [rad].
fn start() -> Vec<f64> {
    [104.2_f64, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8].iter().map(|d| d.to_radians()).collect()
}

fn limits(model: &RobotModel) -> SafetyLimits {
    let margin = 0.05;
    SafetyLimits {
        position_lower: model.lower_limits().iter().map(|l| l + margin).collect(),
        position_upper: model.upper_limits().iter().map(|u| u - margin).collect(),
        velocity: model.velocity_limits(),
        torque: model.effort_limits(),
        torque_rate: vec![1000.0; 7],
        tool_box: Some(ToolBox { lower: [-1.0, -1.0, -0.1], upper: [1.0, 1.0, 1.2] }),
    }
}

fn layer(params: SafetyParams) -> SafetyLayer {
    let model = jaco2();
    let tool = model.frame_id("j2s7s300_end_effector").unwrap();
    let limits = limits(&model);
    SafetyLayer::new(model, tool, limits, params).unwrap()
}

/// A motion's first check (no clock yet) at time 0.
fn checked(s: &mut SafetyLayer, q: &[f64], qd: &[f64], tau_ext: &[f64]) -> Result<SafetyStatus> {
    checked_at(s, 0.0, q, qd, tau_ext)
}

fn checked_at(s: &mut SafetyLayer, t: f64, q: &[f64], qd: &[f64], tau_ext: &[f64]) -> Result<SafetyStatus> {
    s.reset(None)?;
    s.check_state(t, q, qd, tau_ext)
}

fn violation(status: Result<SafetyStatus>) -> Violation {
    status.unwrap().violation.expect("a violation")
}

#[test]
fn a_state_within_every_limit_passes() {
    let mut s = layer(SafetyParams::default());
    let status = checked(&mut s, &start(), &[0.1; 7], &[0.0; 7]).unwrap();
    assert_eq!(status, SafetyStatus::default());
}

#[test]
fn each_non_finite_input_is_named() {
    let mut s = layer(SafetyParams::default());
    let v = violation(checked_at(&mut s, f64::NAN, &start(), &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.quantity), (Limit::NonFinite, Quantity::Time));
    let mut q = start();
    q[3] = f64::INFINITY;
    let v = violation(checked(&mut s, &q, &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.quantity, v.index, v.value), (Limit::NonFinite, Quantity::Position, 3, f64::INFINITY));
    let v = violation(checked(&mut s, &start(), &[0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0], &[0.0; 7]));
    assert_eq!((v.quantity, v.index), (Quantity::Velocity, 1));
    let v = violation(checked(&mut s, &start(), &[0.0; 7], &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, f64::NEG_INFINITY]));
    assert_eq!((v.quantity, v.index), (Quantity::ExternalTorque, 6));
    let mut tau = [0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0];
    let mut command = [9.0; 7];
    let v = violation(s.limit_torque(&start(), &mut tau, &mut command));
    assert_eq!((v.quantity, v.index), (Quantity::Torque, 2));
    assert_eq!(command, [0.0; 7], "no previous command: the command is zero, never the NaN");
}

#[test]
fn a_joint_beyond_its_position_limit_less_the_margin_is_named_with_its_bound() {
    let mut s = layer(SafetyParams::default());
    let model = jaco2();
    let mut q = start();
    q[1] = model.lower_limits()[1] + 0.04; // inside the joint's range, within the 0.05 rad margin
    let v = violation(checked(&mut s, &q, &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.index, v.value), (Limit::JointPosition, 1, q[1]));
    assert!((v.bound - (model.lower_limits()[1] + 0.05)).abs() < 1e-12);
    let mut q = start();
    q[5] = model.upper_limits()[5] - 0.01;
    let v = violation(checked(&mut s, &q, &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.index), (Limit::JointPosition, 5));
    assert!((v.bound - (model.upper_limits()[5] - 0.05)).abs() < 1e-12);
    // A continuous joint has no position limit.
    let mut q = start();
    q[0] = 1e3;
    assert!(checked(&mut s, &q, &[0.0; 7], &[0.0; 7]).unwrap().is_ok());
}

#[test]
fn a_joint_faster_than_its_velocity_limit_is_named_with_its_signed_bound() {
    let mut s = layer(SafetyParams::default());
    let mut qd = [0.0; 7];
    qd[4] = -0.9; // the wrist's limit is 0.838 rad/s
    let v = violation(checked(&mut s, &start(), &qd, &[0.0; 7]));
    assert_eq!((v.limit, v.quantity, v.index, v.value), (Limit::JointVelocity, Quantity::Velocity, 4, -0.9));
    assert!((v.bound + 0.837758).abs() < 1e-9);
    qd[4] = -0.8;
    assert!(checked(&mut s, &start(), &qd, &[0.0; 7]).unwrap().is_ok());
}

#[test]
fn the_tool_outside_its_box_is_named_by_axis() {
    let model = jaco2();
    let tool = model.frame_id("j2s7s300_end_effector").unwrap();
    let mut data = model.data();
    model.forward_kinematics(&start(), &mut data).unwrap();
    let p = model.frame_pose(tool, &data).translation.vector;
    let mut l = limits(&model);
    l.tool_box = Some(ToolBox { lower: [-2.0, -2.0, p.z + 0.01], upper: [2.0, 2.0, 2.0] });
    let mut s = SafetyLayer::new(model, tool, l, SafetyParams::default()).unwrap();
    let v = violation(checked(&mut s, &start(), &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.quantity, v.index), (Limit::ToolBox, Quantity::ToolPosition, 2));
    assert!((v.value - p.z).abs() < 1e-12 && (v.bound - (p.z + 0.01)).abs() < 1e-12);
}

#[test]
fn late_ticks_in_a_row_are_a_violation_on_the_robots_clock() {
    let mut s = layer(SafetyParams { late_ticks: 3, ..SafetyParams::default() });
    let q = start();
    let mut check = |t: f64| s.check_state(t, &q, &[0.0; 7], &[0.0; 7]).unwrap();
    assert!(check(0.0).is_ok() && check(0.001).is_ok());
    // Two late ticks, then an on-time one: the count starts again.
    assert!(check(0.003).is_ok() && check(0.005).is_ok() && check(0.006).is_ok());
    assert!(check(0.008).is_ok() && check(0.010).is_ok());
    let v = check(0.012).violation.expect("the third late tick in a row");
    assert_eq!((v.limit, v.quantity, v.index), (Limit::LateTicks, Quantity::TickGap, 3));
    assert!((v.value - 0.002).abs() < 1e-12 && (v.bound - 0.0015).abs() < 1e-12);
}

#[test]
fn torques_are_clipped_to_their_limits_and_counted() {
    let mut s = layer(SafetyParams::default());
    let mut tau = [50.0, -100.0, 0.0, 0.0, 0.0, 0.0, 25.0];
    let mut command = [0.0; 7];
    let status = s.limit_torque(&start(), &mut tau, &mut command).unwrap();
    assert!(status.is_ok());
    assert_eq!(status.torque_saturated, 0b100_0011);
    assert_eq!(tau, [40.0, -80.0, 0.0, 0.0, 0.0, 0.0, 20.0]);
    assert_eq!(command, tau, "an arm without gravity compensation is commanded the torque");
    assert_eq!(s.torque_clips(), &[1, 1, 0, 0, 0, 0, 1]);
}

#[test]
fn the_commands_rate_is_limited_from_the_previous_command() {
    let mut s = layer(SafetyParams::default());
    s.reset(Some(&[0.0; 7])).unwrap();
    let mut command = [0.0; 7];
    // 1000 N·m/s at 1 kHz: at most 1 N·m per tick.
    let mut tau = [5.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0];
    let status = s.limit_torque(&start(), &mut tau, &mut command).unwrap();
    assert_eq!(status.rate_saturated, 0b1);
    assert_eq!(&command[..2], &[1.0, -0.5]);
    let mut tau = [5.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0];
    s.limit_torque(&start(), &mut tau, &mut command).unwrap();
    assert_eq!(command[0], 2.0);
    assert_eq!(s.rate_clips()[0], 2);
    // Without a previous command (a simulator's first step) the first command is free.
    s.reset(None).unwrap();
    let mut tau = [5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(s.limit_torque(&start(), &mut tau, &mut command).unwrap().rate_saturated, 0);
    assert_eq!(command[0], 5.0);
}

#[test]
fn an_arm_that_compensates_gravity_is_commanded_the_torque_less_g() {
    let model = jaco2();
    let tool = model.frame_id("j2s7s300_end_effector").unwrap();
    let mut l = limits(&model);
    l.torque_rate = vec![1e9; 7];
    let params = SafetyParams { gravity_compensated: true, ..SafetyParams::default() };
    let mut s = SafetyLayer::new(model.clone(), tool, l, params).unwrap();
    let (mut data, mut g) = (model.data(), vec![0.0; 7]);
    model.gravity_torques(&start(), &mut data, &mut g).unwrap();
    let mut tau = g.clone();
    tau[0] += 1.0;
    let mut command = [0.0; 7];
    assert!(s.limit_torque(&start(), &mut tau, &mut command).unwrap().is_ok());
    for j in 0..7 {
        let expected = if j == 0 { 1.0 } else { 0.0 };
        assert!((command[j] - expected).abs() < 1e-9, "joint {j}: {command:?}");
    }
}

#[test]
fn bad_limits_are_errors_naming_them() {
    let model = jaco2();
    let tool = model.frame_id("j2s7s300_end_effector").unwrap();
    let bad = |f: &dyn Fn(&mut SafetyLimits), p: SafetyParams| {
        let mut l = limits(&model);
        f(&mut l);
        SafetyLayer::new(model.clone(), tool, l, p).err().map(|e| e.to_string()).unwrap_or_default()
    };
    let ok = SafetyParams::default();
    assert!(bad(&|l| l.velocity[2] = 0.0, ok).contains("velocity"));
    assert!(bad(&|l| l.torque.pop().map(|_| ()).unwrap_or(()), ok).contains("torque must have shape (7,)"));
    assert!(bad(&|l| l.torque_rate[0] = f64::NAN, ok).contains("torque_rate"));
    assert!(bad(&|l| l.position_lower[1] = 10.0, ok).contains("position_lower"));
    assert!(bad(&|l| l.tool_box = Some(ToolBox { lower: [0.0; 3], upper: [1.0, 0.0, 1.0] }), ok).contains("tool_box"));
    assert!(bad(&|_| (), SafetyParams { late_ticks: 0, ..ok }).contains("late_ticks"));
    assert!(bad(&|_| (), SafetyParams { period: 0.0, ..ok }).contains("period"));
}

proptest! {
    /// Random states and torques (some far beyond the limits): the check never panics, a state is
    /// passed exactly when every value is within its limit, and the applied torque and the command
    /// always stay finite, within the torque limits and (for the command) within the rate limit.
    #[test]
    fn random_states_and_torques_give_an_allowed_status_and_a_bounded_command(
        q in prop::collection::vec(-1.0f64..7.0, 7),
        qd in prop::collection::vec(-1.5f64..1.5, 7),
        taus in prop::collection::vec(prop::collection::vec(-200.0f64..200.0, 7), 1..20),
        gravity_compensated in any::<bool>(),
    ) {
        let model = jaco2();
        let l = limits(&model);
        let tool = model.frame_id("j2s7s300_end_effector").unwrap();
        let params = SafetyParams { gravity_compensated, ..SafetyParams::default() };
        let mut s = SafetyLayer::new(model.clone(), tool, l.clone(), params).unwrap();
        s.reset(Some(&[0.0; 7])).unwrap();
        let status = s.check_state(0.0, &q, &qd, &[0.0; 7]).unwrap();
        let position_ok = (0..7).all(|j| q[j] >= l.position_lower[j] && q[j] <= l.position_upper[j]);
        let velocity_ok = (0..7).all(|j| qd[j].abs() <= l.velocity[j]);
        if !(position_ok && velocity_ok) {
            let v = status.violation.expect("a limit crossed is a violation");
            prop_assert!(matches!(v.limit, Limit::JointPosition | Limit::JointVelocity), "{v:?} for q={q:?} qd={qd:?}");
        } else if let Some(v) = status.violation {
            prop_assert_eq!(v.limit, Limit::ToolBox);
        }
        let (mut previous, mut command) = ([0.0; 7], [0.0; 7]);
        for tau_in in &taus {
            let mut tau = tau_in.clone();
            let status = s.limit_torque(&q, &mut tau, &mut command).unwrap();
            prop_assert!(status.is_ok());
            for j in 0..7 {
                prop_assert!(tau[j].is_finite() && command[j].is_finite());
                prop_assert!(tau[j].abs() <= l.torque[j] + 1e-9, "joint {}: {} beyond {}", j, tau[j], l.torque[j]);
                let step = (command[j] - previous[j]).abs();
                // The rate limit holds unless the torque limit (the harder one) forces a larger step.
                let forced = tau[j].abs() >= l.torque[j] - 1e-9;
                prop_assert!(step <= l.torque_rate[j] * 1e-3 + 1e-9 || forced, "joint {}: step {} N·m", j, step);
            }
            previous = command;
        }
    }
}

#[test]
fn a_clock_that_does_not_advance_is_a_violation() {
    let mut s = layer(SafetyParams::default());
    assert!(s.check_state(1.0, &start(), &[0.0; 7], &[0.0; 7]).unwrap().is_ok());
    let v = violation(s.check_state(1.0, &start(), &[0.0; 7], &[0.0; 7]));
    assert_eq!((v.limit, v.quantity, v.value), (Limit::Clock, Quantity::TickGap, 0.0));
    s.reset(None).unwrap();
    assert!(s.check_state(1.0, &start(), &[0.0; 7], &[0.0; 7]).unwrap().is_ok(), "a reset forgets the clock");
}
