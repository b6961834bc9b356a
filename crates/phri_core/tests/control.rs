//! Impedance law, reference interpolation, interaction detection and the weight update.

mod common;

use std::sync::Arc;

use common::{deg, jaco2, within_limits};
use nalgebra::{DMatrix, DVector};
use phri_core::impedance::{Gain, ImpedanceController, ImpedanceParams};
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use phri_core::reference::{Interpolation, TimedTrajectory};
use phri_core::update::{relevance, UpdateParams, UpdateRule, WeightUpdate};
use phri_core::PhriError;
use proptest::prelude::*;

fn place_lower() -> Vec<f64> {
    deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
}

#[test]
fn on_the_reference_the_law_is_gravity_compensation() {
    let model = Arc::new(jaco2());
    let mut c = ImpedanceController::new(model.clone(), ImpedanceParams::jaco2_default()).unwrap();
    let q = place_lower();
    let mut tau = vec![0.0; 7];
    let status = c.torque(&q, &[0.0; 7], &q, &[0.0; 7], &mut tau).unwrap();
    let mut g = vec![0.0; 7];
    model.gravity_torques(&q, &mut model.data(), &mut g).unwrap();
    assert_eq!(tau, g);
    assert!(!status.is_saturated());
    // A position error adds K·e, a velocity error B·ė.
    let mut q_ref = q.clone();
    q_ref[3] += 0.01;
    let mut qd = [0.0; 7];
    qd[5] = 0.2;
    c.torque(&q, &qd, &q_ref, &[0.0; 7], &mut tau).unwrap();
    assert!((tau[3] - g[3] - 15.0 * 0.01).abs() < 1e-12);
    assert!((tau[5] - g[5] + 15.0 * 0.2).abs() < 1e-12);
}

#[test]
fn saturation_clips_to_the_effort_limits_and_says_so() {
    let model = Arc::new(jaco2());
    let mut c = ImpedanceController::new(model, ImpedanceParams::jaco2_default()).unwrap();
    let q = place_lower();
    let mut q_ref = q.clone();
    q_ref[4] += 3.0; // 10 N·m/rad · 3 rad = 30 N·m > 20 N·m
    let mut tau = vec![0.0; 7];
    let status = c.torque(&q, &[0.0; 7], &q_ref, &[0.0; 7], &mut tau).unwrap();
    assert_eq!(status.saturated, 1 << 4);
    assert!((tau[4] - 20.0).abs() < 1e-12);
}

#[test]
fn full_gains_equal_diagonal_gains_when_diagonal() {
    let model = Arc::new(jaco2());
    let k = vec![200.0, 300.0, 150.0, 150.0, 50.0, 50.0, 30.0];
    let b = vec![20.0, 30.0, 15.0, 15.0, 5.0, 5.0, 3.0];
    let diag = ImpedanceParams {
        stiffness: Gain::Diagonal(k.clone()),
        damping: Gain::Diagonal(b.clone()),
        inertia: None,
        gravity_compensation: true,
    };
    let full = ImpedanceParams {
        stiffness: Gain::Full(DMatrix::from_diagonal(&DVector::from_vec(k))),
        damping: Gain::Full(DMatrix::from_diagonal(&DVector::from_vec(b))),
        inertia: None,
        gravity_compensation: true,
    };
    let (mut c1, mut c2) =
        (ImpedanceController::new(model.clone(), diag).unwrap(), ImpedanceController::new(model, full).unwrap());
    let q = place_lower();
    let q_ref: Vec<f64> = q.iter().map(|v| v + 0.02).collect();
    let (mut t1, mut t2) = (vec![0.0; 7], vec![0.0; 7]);
    c1.torque(&q, &[0.1; 7], &q_ref, &[0.0; 7], &mut t1).unwrap();
    c2.torque(&q, &[0.1; 7], &q_ref, &[0.0; 7], &mut t2).unwrap();
    for j in 0..7 {
        assert!((t1[j] - t2[j]).abs() < 1e-12);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// Feeding the full law's torque to the arm's own dynamics yields the closed loop of eq. 5.
    #[test]
    fn the_full_law_renders_the_desired_impedance(
        u in prop::collection::vec(0.05..0.95f64, 7),
        qd in prop::collection::vec(-0.3..0.3f64, 7),
        dq in prop::collection::vec(-0.05..0.05f64, 7),
        uh in prop::collection::vec(-1.0..1.0f64, 7),
    ) {
        let model = Arc::new(jaco2());
        let mr = vec![0.5, 0.5, 0.3, 0.3, 0.1, 0.1, 0.1];
        let params = ImpedanceParams { inertia: Some(Gain::Diagonal(mr.clone())), ..ImpedanceParams::jaco2_default() };
        let mut c = ImpedanceController::new(model.clone(), params.clone()).unwrap();
        let q = within_limits(&model, &u);
        let q_ref: Vec<f64> = q.iter().zip(&dq).map(|(a, b)| a + b).collect();
        let qdd_ref = [0.05; 7];
        let mut tau = vec![0.0; 7];
        let status = c.torque_full(&q, &qd, &q_ref, &[0.0; 7], &qdd_ref, &uh, &mut tau).unwrap();
        prop_assume!(!status.is_saturated());
        // Forward dynamics: q̈ = M⁻¹(τ + u_H − h).
        let mut d = model.data();
        let mut m = DMatrix::zeros(7, 7);
        model.mass_matrix(&q, &mut d, &mut m).unwrap();
        let mut h = vec![0.0; 7];
        model.nonlinear_effects(&q, &qd, &mut d, &mut h).unwrap();
        let rhs = DVector::from_iterator(7, (0..7).map(|j| tau[j] + uh[j] - h[j]));
        let qdd = m.cholesky().unwrap().solve(&rhs);
        let (Gain::Diagonal(k), Gain::Diagonal(b)) = (&params.stiffness, &params.damping) else { unreachable!() };
        for j in 0..7 {
            let lhs = mr[j] * (qdd[j] - qdd_ref[j]) + b[j] * qd[j] + k[j] * (q[j] - q_ref[j]);
            prop_assert!((lhs - uh[j]).abs() < 1e-8, "joint {j}: {lhs} vs {}", uh[j]);
        }
    }
}

#[test]
fn bad_gains_and_inputs_are_typed_errors() {
    let model = Arc::new(jaco2());
    let bad = ImpedanceParams { stiffness: Gain::Diagonal(vec![1.0; 6]), ..ImpedanceParams::jaco2_default() };
    assert!(ImpedanceController::new(model.clone(), bad).is_err());
    let nan = ImpedanceParams { damping: Gain::Diagonal(vec![f64::NAN; 7]), ..ImpedanceParams::jaco2_default() };
    assert!(ImpedanceController::new(model.clone(), nan).is_err());
    let neg = ImpedanceParams { inertia: Some(Gain::Diagonal(vec![-1.0; 7])), ..ImpedanceParams::jaco2_default() };
    assert!(ImpedanceController::new(model.clone(), neg).is_err());
    let mut c = ImpedanceController::new(model, ImpedanceParams::jaco2_default()).unwrap();
    let mut tau = vec![0.0; 7];
    let q = place_lower();
    assert!(c.torque(&q, &[f64::INFINITY; 7], &q, &[0.0; 7], &mut tau).is_err());
    assert!(c.torque_full(&q, &[0.0; 7], &q, &[0.0; 7], &[0.0; 7], &[0.0; 7], &mut tau).is_err(), "no inertia set");
}

#[test]
fn the_reference_is_continuous_and_holds_its_ends() {
    let n = 7;
    let w: Vec<f64> = (0..31 * n).map(|i| ((i / n) as f64 * 0.3 + (i % n) as f64).sin()).collect();
    for interp in [Interpolation::Linear, Interpolation::Cubic] {
        let t = TimedTrajectory::new(w.clone(), n, 15.0, interp).unwrap();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        // Waypoints are hit at their times.
        for i in 0..31 {
            t.sample(i as f64 * 0.5, &mut q, &mut qd, &mut qdd);
            for j in 0..n {
                assert!((q[j] - w[i * n + j]).abs() < 1e-12, "{interp:?} waypoint {i}");
            }
        }
        t.sample(-1.0, &mut q, &mut qd, &mut qdd);
        assert_eq!(&q[..], &w[..n]);
        t.sample(20.0, &mut q, &mut qd, &mut qdd);
        assert_eq!(&q[..], &w[30 * n..]);
        assert!(qd.iter().all(|v| *v == 0.0));
        // Velocity is the derivative of position (finite differences inside segments).
        let h = 1e-6;
        let (mut qa, mut qb) = (vec![0.0; n], vec![0.0; n]);
        for k in 0..200 {
            let time = 0.013 + k as f64 * 0.0731;
            t.sample(time - h, &mut qa, &mut qd, &mut qdd);
            t.sample(time + h, &mut qb, &mut qd, &mut qdd);
            t.sample(time, &mut q, &mut qd, &mut qdd);
            for j in 0..n {
                let fd = (qb[j] - qa[j]) / (2.0 * h);
                assert!((fd - qd[j]).abs() < 1e-5 || ((time / 0.5).fract() < 1e-5), "{interp:?} t={time}");
            }
        }
    }
    // The cubic reference is C¹: velocity is continuous across a waypoint.
    let t = TimedTrajectory::new(w.clone(), n, 15.0, Interpolation::Cubic).unwrap();
    let (mut q, mut qa, mut qb, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    t.sample(5.0 - 1e-9, &mut q, &mut qa, &mut qdd);
    t.sample(5.0 + 1e-9, &mut q, &mut qb, &mut qdd);
    for j in 0..n {
        assert!((qa[j] - qb[j]).abs() < 1e-6);
    }
    assert!(TimedTrajectory::new(vec![0.0; 7], 7, 15.0, Interpolation::Cubic).is_err());
    assert!(TimedTrajectory::new(vec![0.0; 14], 7, 0.0, Interpolation::Cubic).is_err());
}

/// A slow 31-waypoint plan over 15 s of `n` joints, offset by `shift` [rad] in the middle.
fn slow_plan(n: usize, shift: f64) -> Vec<f64> {
    (0..31 * n)
        .map(|k| {
            let (i, j) = ((k / n) as f64, (k % n) as f64);
            3.0 + 0.2 * (0.1 * i + j).sin() + shift * (std::f64::consts::PI * i / 30.0).sin()
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// After `switch_to` at t0 the reference starts where the old one was (position and velocity),
    /// stays within the speed limits, ends on the new plan, and its velocity is its derivative.
    #[test]
    fn switching_plans_is_continuous_and_within_the_speed_limits(
        t0 in 0.2..13.0f64, shift in -0.8..0.8f64, limit in 0.2..1.0f64, cubic in any::<bool>(), first in -0.3..0.3f64,
    ) {
        let n = 7;
        let interp = if cubic { Interpolation::Cubic } else { Interpolation::Linear };
        let mut traj = TimedTrajectory::new(slow_plan(n, first), n, 15.0, interp).unwrap();
        let limits = vec![limit; n];
        // A switch before (so the old reference may itself be blending), then the one under test.
        traj.switch_to(&slow_plan(n, 0.5 * first), 0.5 * t0, &limits).unwrap();
        let old = traj.clone();
        let new = slow_plan(n, shift);
        let length = traj.switch_to(&new, t0, &limits).unwrap();
        let end = if length > 0.0 { t0 + length } else { 0.0 };
        prop_assert!(length >= 0.0 && traj.blend_end() == end);
        let (mut qa, mut va, mut qb, mut vb, mut acc) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        old.sample(t0, &mut qa, &mut va, &mut acc);
        traj.sample(t0, &mut qb, &mut vb, &mut acc);
        if length > 0.0 {
            // Exactly the old reference at t0, to the last bit: a plan adopted a tick later (on a
            // replan worker) must give the same ticks as one adopted at once.
            prop_assert!(qa == qb && va == vb, "jump at t0: {:?} {:?} against {:?} {:?}", qb, vb, qa, va);
        }
        for j in 0..n {
            prop_assert!((qa[j] - qb[j]).abs() < 1e-12 && (va[j] - vb[j]).abs() < 1e-9, "jump at t0, joint {}", j);
        }
        // The speed of the old reference at t0 bounds nothing; from then on the limit holds
        // wherever the new plan alone keeps to it (its own speed stays far below `limit` here, or
        // the blend adds nothing beyond it).
        let (mut qp, mut vp) = (vec![0.0; n], vec![0.0; n]);
        let h = 1e-6;
        for k in 1..400 {
            let t = t0 + k as f64 * (length.max(0.01) * 1.2) / 400.0;
            traj.sample(t, &mut qb, &mut vb, &mut acc);
            traj.sample_plan(t, &mut qp, &mut vp, &mut acc);
            let start_speed = va.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for j in 0..n {
                let allowed = limit.max(vp[j].abs()).max(if t < t0 + 0.02 * length { start_speed } else { 0.0 });
                prop_assert!(vb[j].abs() <= allowed * (1.0 + 1e-6) + 1e-9, "t={} joint {}: {} > {}", t, j, vb[j], allowed);
            }
            let (mut q1, mut q2, mut v) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            traj.sample(t - h, &mut q1, &mut v, &mut acc);
            traj.sample(t + h, &mut q2, &mut v, &mut acc);
            let on_knot = !cubic && ((t / 0.5).fract() < 1e-4 || (t / 0.5).fract() > 1.0 - 1e-4);
            // The reference is C¹: its acceleration jumps where the blend ends, which the central
            // difference sees within h of it (a short blend's jump is large).
            let at_blend_end = (t - (t0 + length)).abs() < 2.0 * h;
            for j in 0..n {
                prop_assert!(on_knot || at_blend_end || ((q2[j] - q1[j]) / (2.0 * h) - vb[j]).abs() < 1e-4, "velocity at t={}", t);
            }
        }
        // After the blend the reference is the new plan.
        let after = t0 + length + 1e-9;
        let fresh = TimedTrajectory::new(new, n, 15.0, interp).unwrap();
        traj.sample(after, &mut qa, &mut va, &mut acc);
        fresh.sample(after, &mut qb, &mut vb, &mut acc);
        prop_assert_eq!(qa, qb);
    }
}

#[test]
fn switching_needs_valid_limits_and_keeps_the_instant_switch_available() {
    let n = 7;
    let mut traj = TimedTrajectory::new(slow_plan(n, 0.0), n, 15.0, Interpolation::Cubic).unwrap();
    assert!(matches!(traj.switch_to(&slow_plan(n, 0.5), 3.0, &[1.0; 6]), Err(PhriError::Shape { .. })));
    assert!(matches!(traj.switch_to(&slow_plan(n, 0.5), 3.0, &[0.0; 7]), Err(PhriError::InvalidParameter { .. })));
    assert!(matches!(traj.switch_to(&slow_plan(n, 0.5), f64::NAN, &[1.0; 7]), Err(PhriError::NonFinite { .. })));
    // Without limits the switch is instant: the reference is the new plan at once.
    assert_eq!(traj.switch_to(&slow_plan(n, 0.5), 3.0, &[]).unwrap(), 0.0);
    let fresh = TimedTrajectory::new(slow_plan(n, 0.5), n, 15.0, Interpolation::Cubic).unwrap();
    let (mut qa, mut qb, mut v, mut a) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    traj.sample(3.0, &mut qa, &mut v, &mut a);
    fresh.sample(3.0, &mut qb, &mut v, &mut a);
    assert_eq!(qa, qb);
    // A blend that is long: a 0.8 rad shift at 0.1 rad/s needs at least 1.5·0.8/0.1 = 12 s.
    let length = traj.switch_to(&slow_plan(n, -0.3), 2.0, &[0.1; 7]).unwrap();
    assert!(length >= 12.0, "{length}");
}

#[test]
fn interaction_thresholds_zero_small_components() {
    let d = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
    let mut u = [0.0; 7];
    assert!(!d.detect(&[7.9, -7.9, 7.0, 1.9, 0.9, -0.9, 0.5], &mut u).unwrap());
    assert_eq!(u, [0.0; 7]);
    assert!(d.detect(&[9.0, 1.0, 0.0, -2.5, 0.0, 0.0, 0.0], &mut u).unwrap());
    assert_eq!(u, [9.0, 0.0, 0.0, -2.5, 0.0, 0.0, 0.0]);
    let biased = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), Some(vec![0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0])).unwrap();
    assert!(!biased.detect(&[0.0, 0.0, 0.0, 4.5, 0.0, 0.0, 0.0], &mut u).unwrap());
    assert!(InteractionDetector::new(vec![-1.0; 7], None).is_err());
    assert!(d.detect(&[0.0; 6], &mut u).is_err());
}

fn params(rule: UpdateRule) -> UpdateParams {
    UpdateParams {
        step: vec![1.0, 2.0, 100.0],
        lower: vec![1.0, 0.0, 0.0],
        upper: vec![1.0, 1.0, 10.0],
        learned: vec![false, true, true],
        ranges: vec![1.0, 1.8761, 1.0048],
        rule,
    }
}

#[test]
fn update_rules_move_the_right_weights_within_bounds() {
    // ALL: the cost form of eq. 13, clipped.
    let u = WeightUpdate::new(params(UpdateRule::All)).unwrap();
    let mut w = vec![1.0, 0.5, 5.0];
    let info = u.apply(&mut w, &[3.0, -0.1, 0.01], None).unwrap();
    assert_eq!(w, vec![1.0, 0.7, 4.0]);
    assert!(!info.clipped);
    let info = u.apply(&mut w, &[0.0, -1.0, 1.0], None).unwrap();
    assert_eq!(w, vec![1.0, 1.0, 0.0]);
    assert!(info.clipped);
    // MAX: only the largest range-normalised change moves.
    let u = WeightUpdate::new(params(UpdateRule::Max)).unwrap();
    let mut w = vec![1.0, 0.5, 5.0];
    let info = u.apply(&mut w, &[100.0, -0.1, 0.05], None).unwrap();
    assert_eq!(info.chosen, Some(1), "efficiency is not learned, 0.1/1.876 > 0.05/1.005");
    assert_eq!(w, vec![1.0, 0.7, 5.0]);
    // Confidence: scaled by relevance, which it requires.
    let u = WeightUpdate::new(params(UpdateRule::Confidence)).unwrap();
    let mut w = vec![1.0, 0.5, 5.0];
    assert!(u.apply(&mut w, &[0.0, -0.1, 0.01], None).is_err());
    u.apply(&mut w, &[0.0, -0.1, 0.01], Some(&[1.0, 0.5, 0.0])).unwrap();
    assert!((w[1] - 0.6).abs() < 1e-12 && w[2] == 5.0);
    // Bad parameters.
    let mut p = params(UpdateRule::All);
    p.lower[2] = 20.0;
    assert!(WeightUpdate::new(p).is_err());
    let mut p = params(UpdateRule::All);
    p.step.pop();
    assert!(WeightUpdate::new(p).is_err());
}

#[test]
fn relevance_is_one_when_the_push_is_the_cheapest_way_to_change_the_feature() {
    // Sensitivity row parallel to u_H: the push is exactly the minimum-norm torque.
    let s = [1.0, 2.0, 0.0, 0.0, 0.0, 1.0];
    let u_h = [0.5, 1.0, 0.0];
    let dphi = [1.0 * 0.5 + 2.0 * 1.0, 0.0];
    let mut r = [0.0; 2];
    relevance(&dphi, &s, &u_h, &mut r).unwrap();
    assert!((r[0] - 1.0).abs() < 1e-12);
    assert_eq!(r[1], 0.0);
}

proptest! {
    #[test]
    fn updates_always_respect_bounds(dphi in prop::collection::vec(-100.0..100.0f64, 3), w0 in prop::collection::vec(-5.0..15.0f64, 3)) {
        for rule in [UpdateRule::All, UpdateRule::Max] {
            let u = WeightUpdate::new(params(rule)).unwrap();
            let mut w = w0.clone();
            u.clip(&mut w);
            u.apply(&mut w, &dphi, None).unwrap();
            let p = u.params();
            for (i, wi) in w.iter().enumerate() {
                prop_assert!(*wi >= p.lower[i] && *wi <= p.upper[i]);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// The implicit law satisfies its definition with the arm's own dynamics, and tends to eq. 6.
    #[test]
    fn the_implicit_law_is_eq_6_at_the_predicted_state(
        u in prop::collection::vec(0.05..0.95f64, 7),
        qd in prop::collection::vec(-0.3..0.3f64, 7),
        dq in prop::collection::vec(-0.05..0.05f64, 7),
    ) {
        let model = Arc::new(jaco2());
        let params = ImpedanceParams::jaco2_default();
        let mut c = ImpedanceController::new(model.clone(), params.clone()).unwrap();
        let q = within_limits(&model, &u);
        let q_ref: Vec<f64> = q.iter().zip(&dq).map(|(a, b)| a + b).collect();
        let qd_ref = [0.1; 7];
        let dt = 1e-3;
        let mut tau = vec![0.0; 7];
        let status = c.torque_implicit(&q, &qd, &q_ref, &qd_ref, dt, &mut tau).unwrap();
        prop_assume!(!status.is_saturated());
        let mut d = model.data();
        let mut m = DMatrix::zeros(7, 7);
        model.mass_matrix(&q, &mut d, &mut m).unwrap();
        let (mut h, mut g) = (vec![0.0; 7], vec![0.0; 7]);
        model.nonlinear_effects(&q, &qd, &mut d, &mut h).unwrap();
        model.gravity_torques(&q, &mut d, &mut g).unwrap();
        let qdd = m.cholesky().unwrap().solve(&DVector::from_iterator(7, (0..7).map(|j| tau[j] - h[j])));
        let (Gain::Diagonal(k), Gain::Diagonal(b)) = (&params.stiffness, &params.damping) else { unreachable!() };
        for j in 0..7 {
            let law = g[j] + k[j] * (q_ref[j] - q[j] - qd[j] * dt) + b[j] * (qd_ref[j] - qd[j] - qdd[j] * dt);
            prop_assert!((law - tau[j]).abs() < 1e-9, "joint {j}: {law} vs {}", tau[j]);
        }
        let mut explicit = vec![0.0; 7];
        c.torque(&q, &qd, &q_ref, &qd_ref, &mut explicit).unwrap();
        c.torque_implicit(&q, &qd, &q_ref, &qd_ref, 1e-12, &mut tau).unwrap();
        for j in 0..7 {
            prop_assert!((explicit[j] - tau[j]).abs() < 1e-6, "joint {j}: explicit {} implicit {}", explicit[j], tau[j]);
        }
    }
}

#[test]
fn a_blend_past_the_plans_end_keeps_to_the_speed_limits_and_any_blend_is_finite() {
    const N: usize = 7;
    // A plan B off A by an offset that grows to the goal, so that a switch late in the task blends
    // on past T, where the plan holds still. Every switch is checked densely: the reference keeps
    // to the limit, or the plan's speed, or the speed the joint had at the switch.
    let a = slow_plan(N, 0.0);
    let b: Vec<f64> = a.iter().enumerate().map(|(k, v)| v + 0.02 * (k / N) as f64 / 30.0 * ((k % N) + 1) as f64 / 7.0).collect();
    let limit = 0.05;
    let mut past_t = 0;
    for t0 in [13.0, 14.0, 14.5, 14.7, 14.9] {
        let mut traj = TimedTrajectory::new(a.clone(), N, 15.0, Interpolation::Linear).unwrap();
        let (mut q, mut v0, mut acc) = ([0.0; N], [0.0; N], [0.0; N]);
        traj.sample(t0, &mut q, &mut v0, &mut acc);
        let length = traj.switch_to(&b, t0, &[limit; N]).unwrap();
        assert!(length > 0.0 && length < 20.0, "t0 = {t0}: blend of {length} s");
        past_t += usize::from(traj.blend_end() > 15.0);
        let (mut v, mut vp) = ([0.0; N], [0.0; N]);
        for i in 0..=20_000 {
            let t = t0 + (length * 1.01) * i as f64 / 20_000.0;
            traj.sample(t, &mut q, &mut v, &mut acc);
            traj.sample_plan(t, &mut q, &mut vp, &mut acc);
            for j in 0..N {
                let allowed = limit.max(vp[j].abs()).max(v0[j].abs());
                assert!(v[j].abs() <= allowed * (1.0 + 1e-6) + 1e-12, "t0 = {t0}, t = {t}, joint {j}: {} > {allowed}", v[j]);
            }
        }
    }
    assert!(past_t >= 2, "only {past_t} blends ran past T: the test needs them");
    // A limit tighter than the plans' own speeds with the plans' velocities apart at the switch:
    // no blend keeps to it after T (the velocity offset alone overshoots by a third of itself), so
    // the least excessive blend within the task's duration is taken, never an endless one.
    let c = slow_plan(N, 0.3);
    let mut traj = TimedTrajectory::new(a.clone(), N, 15.0, Interpolation::Cubic).unwrap();
    let (mut qa, mut qc, mut v, mut acc) = ([0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    traj.sample(13.0, &mut qa, &mut v, &mut acc);
    TimedTrajectory::new(c.clone(), N, 15.0, Interpolation::Cubic).unwrap().sample(13.0, &mut qc, &mut v, &mut acc);
    // The position offset alone needs 1.5·|Δq|/limit.
    let needed = qa.iter().zip(&qc).map(|(x, y)| 1.5 * (x - y).abs() / 0.001).fold(0.0, f64::max);
    let length = traj.switch_to(&c, 13.0, &[0.001; N]).unwrap();
    assert!(
        length >= needed * (1.0 - 1e-9) && length <= 1.25 * needed.max(15.0) * (1.0 + 1e-9),
        "blend of {length} s, {needed} s needed"
    );
    let mut q = [0.0; N];
    for i in 0..=2_000 {
        traj.sample(13.0 + 2.0 * length * i as f64 / 2_000.0, &mut q, &mut v, &mut acc);
        assert!(v.iter().all(|x| x.is_finite() && x.abs() < 1.0));
    }
}

#[test]
fn update_rules_are_named_once_and_round_trip() {
    assert_eq!(UpdateRule::NAMES, ["all", "max", "confidence", "beta"]);
    for (rule, name) in UpdateRule::ALL.iter().zip(UpdateRule::NAMES) {
        assert_eq!(rule.name(), name);
        assert_eq!(UpdateRule::from_name("rule", name).unwrap(), *rule);
    }
    let err = UpdateRule::from_name("rule", "MAX").unwrap_err();
    assert_eq!(err.to_string(), "rule must be one of 'all', 'max', 'confidence', 'beta', got 'MAX'");
}
