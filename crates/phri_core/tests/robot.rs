//! Robot model, kinematics and dynamics: test vectors, finite differences and invariants.

mod common;

use common::{deg, jaco2, within_limits};
use nalgebra::{DMatrix, DVector, Matrix6xX};
use phri_core::{PhriError, RobotModel};
use proptest::prelude::*;

#[test]
fn jaco2_has_seven_joints_and_its_frames() {
    let m = jaco2();
    assert_eq!(m.nq(), 7);
    for name in ["root", "j2s7s300_link_base", "j2s7s300_link_7", "j2s7s300_end_effector", "j2s7s300_cup_frame"] {
        m.frame_id(name).unwrap();
    }
    assert!(m.joints[0].lower.is_infinite() && m.joints[1].lower > 0.8);
    assert_eq!(m.effort_limits(), vec![40.0, 80.0, 40.0, 40.0, 20.0, 20.0, 20.0]);
    // Total moving mass: the table's links 1..7 (the tiny frame links add 2e-5 kg).
    let moving: f64 = m.bodies[1..].iter().map(|b| b.mass).sum();
    assert!((moving - 5.0894).abs() < 1e-4, "{moving}");
}

fn assert_close(a: &[f64], b: &[f64], tol: f64, what: &str) {
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((x - y).abs() <= tol, "{what}[{i}]: {x} vs {y} (tol {tol})");
    }
}

#[test]
fn fk_matches_the_published_test_vectors() {
    let m = jaco2();
    let mut d = m.data();
    let ee = m.frame_id("j2s7s300_end_effector").unwrap();
    let l7 = m.frame_id("j2s7s300_link_7").unwrap();

    m.forward_kinematics(&[std::f64::consts::PI; 7], &mut d).unwrap();
    let t = m.frame_pose(ee, &d);
    assert_close(t.translation.vector.as_slice(), &[0.0, -0.0130, 1.2603], 1e-4, "candle end_effector");
    let r = t.rotation.matrix();
    let expected = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
    for i in 0..3 {
        assert_close(&[r[(i, 0)], r[(i, 1)], r[(i, 2)]], &expected[i], 1e-9, "candle rotation row");
    }
    assert_close(m.frame_pose(l7, &d).translation.vector.as_slice(), &[0.0, -0.0130, 1.1003], 1e-4, "candle link_7");

    m.forward_kinematics(&deg([103.366, 197.13, 180.070, 43.4309, 265.11, 257.271, 287.9276]), &mut d).unwrap();
    assert_close(m.frame_pose(ee, &d).translation.vector.as_slice(), &[0.21275, -0.26827, 0.50506], 1e-4, "home");

    m.forward_kinematics(&deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]), &mut d).unwrap();
    assert_close(m.frame_pose(l7, &d).translation.vector.as_slice(), &[-0.5822, 0.3302, 0.1059], 1e-4, "place_lower");
}

#[test]
fn bad_inputs_are_typed_errors() {
    let m = jaco2();
    let mut d = m.data();
    assert!(matches!(m.forward_kinematics(&[0.0; 6], &mut d), Err(PhriError::Shape { .. })));
    let mut q = [3.0; 7];
    q[2] = f64::NAN;
    assert!(matches!(m.forward_kinematics(&q, &mut d), Err(PhriError::NonFinite { index: 2, .. })));
    assert!(matches!(m.frame_id("nope"), Err(PhriError::UnknownName { .. })));
    let e = RobotModel::from_urdf_str(common::JACO2_URDF, Some("j2s7s300_link_7"), Some("j2s7s300_link_2")).unwrap_err();
    assert!(e.to_string().contains("not below"), "{e}");
    assert!(matches!(RobotModel::from_urdf_str("<robot", None, None), Err(PhriError::Urdf { .. })));
    assert!(matches!(RobotModel::from_urdf_file("/does/not/exist.urdf", None, None), Err(PhriError::Urdf { .. })));
    assert!(matches!(RobotModel::from_urdf_str(common::JACO2_URDF, None, Some("hand")), Err(PhriError::UnknownName { .. })));
}

#[test]
fn default_tip_is_the_last_moving_link() {
    let m = RobotModel::from_urdf_str(common::JACO2_URDF, None, None).unwrap();
    assert_eq!(m.nq(), 7);
    assert!(m.frame_id("j2s7s300_end_effector").is_ok(), "fixed children of the tip stay as frames");
}

fn frame_position(m: &RobotModel, d: &mut phri_core::RobotData, frame: phri_core::FrameId, q: &[f64]) -> nalgebra::Vector3<f64> {
    m.forward_kinematics(q, d).unwrap();
    m.frame_pose(frame, d).translation.vector
}

fn jacobian_matches_finite_differences(u: &[f64], frame_name: &str) {
    let m = jaco2();
    let mut d = m.data();
    let f = m.frame_id(frame_name).unwrap();
    let q = within_limits(&m, u);
    m.forward_kinematics(&q, &mut d).unwrap();
    let mut jac = Matrix6xX::zeros(7);
    m.frame_jacobian(f, &d, &mut jac).unwrap();
    let r0 = m.frame_pose(f, &d).rotation;
    let h = 1e-6;
    for j in 0..7 {
        let (mut qp, mut qm) = (q.clone(), q.clone());
        qp[j] += h;
        qm[j] -= h;
        let dp = (frame_position(&m, &mut d, f, &qp) - frame_position(&m, &mut d, f, &qm)) / (2.0 * h);
        m.forward_kinematics(&qp, &mut d).unwrap();
        let rp = *m.frame_pose(f, &d).rotation.matrix();
        m.forward_kinematics(&qm, &mut d).unwrap();
        let rm = *m.frame_pose(f, &d).rotation.matrix();
        // Ṙ Rᵀ = [ω]×
        let s = (rp - rm) / (2.0 * h) * r0.matrix().transpose();
        let omega = nalgebra::Vector3::new(s[(2, 1)], s[(0, 2)], s[(1, 0)]);
        for k in 0..3 {
            assert!((jac[(k, j)] - dp[k]).abs() < 1e-7, "linear ({k},{j}): {} vs {}", jac[(k, j)], dp[k]);
            assert!((jac[(k + 3, j)] - omega[k]).abs() < 1e-5, "angular ({k},{j}): {} vs {}", jac[(k + 3, j)], omega[k]);
        }
    }
}

fn rnea(m: &RobotModel, q: &[f64], qd: &[f64], qdd: &[f64]) -> DVector<f64> {
    let mut d = m.data();
    let mut tau = vec![0.0; m.nq()];
    m.inverse_dynamics(q, qd, qdd, &mut d, &mut tau).unwrap();
    DVector::from_vec(tau)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn jacobians_match_finite_differences(u in prop::collection::vec(0.0..1.0f64, 7)) {
        jacobian_matches_finite_differences(&u, "j2s7s300_link_7");
        jacobian_matches_finite_differences(&u, "j2s7s300_end_effector");
        jacobian_matches_finite_differences(&u, "j2s7s300_link_3");
    }

    #[test]
    fn dynamics_are_consistent(
        u in prop::collection::vec(0.0..1.0f64, 7),
        qd in prop::collection::vec(-1.0..1.0f64, 7),
        qdd in prop::collection::vec(-2.0..2.0f64, 7),
    ) {
        let m = jaco2();
        let mut d = m.data();
        let q = within_limits(&m, &u);
        let zero = vec![0.0; 7];
        // Gravity by composite bodies equals RNEA at rest.
        let mut g = vec![0.0; 7];
        m.gravity_torques(&q, &mut d, &mut g).unwrap();
        let g_rnea = rnea(&m, &q, &zero, &zero);
        for i in 0..7 { prop_assert!((g[i] - g_rnea[i]).abs() < 1e-10); }
        // τ = M q̈ + h(q, q̇): the mass matrix from CRBA agrees with RNEA.
        let mut mm = DMatrix::zeros(7, 7);
        m.mass_matrix(&q, &mut d, &mut mm).unwrap();
        let mut h = vec![0.0; 7];
        m.nonlinear_effects(&q, &qd, &mut d, &mut h).unwrap();
        let lhs = rnea(&m, &q, &qd, &qdd);
        let rhs = &mm * DVector::from_column_slice(&qdd) + DVector::from_vec(h.clone());
        prop_assert!((lhs - rhs).amax() < 1e-10);
        // M is symmetric positive definite.
        prop_assert!((&mm - mm.transpose()).amax() < 1e-14);
        prop_assert!(mm.clone().cholesky().is_some());
        // Coriolis = nonlinear effects − gravity, and the kinetic-energy identity q̇ᵀC q̇ ... is
        // covered by: Coriolis is quadratic in q̇.
        let mut c = vec![0.0; 7];
        m.coriolis(&q, &qd, &mut d, &mut c).unwrap();
        let qd2: Vec<f64> = qd.iter().map(|v| 2.0 * v).collect();
        let mut c2 = vec![0.0; 7];
        m.coriolis(&q, &qd2, &mut d, &mut c2).unwrap();
        for i in 0..7 {
            prop_assert!((c[i] + g[i] - h[i]).abs() < 1e-10);
            prop_assert!((c2[i] - 4.0 * c[i]).abs() < 1e-9);
        }
    }

    #[test]
    fn forward_dynamics_inverts_inverse_dynamics(
        u in prop::collection::vec(0.0..1.0f64, 7),
        qd in prop::collection::vec(-1.0..1.0f64, 7),
        qdd in prop::collection::vec(-2.0..2.0f64, 7),
    ) {
        let m = jaco2();
        let mut d = m.data();
        let q = within_limits(&m, &u);
        let tau = rnea(&m, &q, &qd, &qdd);
        let mut work = DMatrix::zeros(7, 7);
        let mut out = vec![0.0; 7];
        // Twice with the same work matrix: the factor handed back must not change the second answer.
        for _ in 0..2 {
            m.forward_dynamics(&q, &qd, tau.as_slice(), &mut d, &mut work, &mut out).unwrap();
            for i in 0..7 { prop_assert!((out[i] - qdd[i]).abs() < 1e-8, "joint {i}: {} vs {}", out[i], qdd[i]); }
        }
    }

    #[test]
    fn fk_never_yields_nan_within_limits(u in prop::collection::vec(0.0..1.0f64, 7)) {
        let m = jaco2();
        let mut d = m.data();
        let q = within_limits(&m, &u);
        m.check_within_limits("q", &q).unwrap();
        m.forward_kinematics(&q, &mut d).unwrap();
        for t in &d.base_t_body {
            prop_assert!(t.translation.vector.iter().all(|v| v.is_finite()));
            let r = t.rotation.matrix();
            prop_assert!((r * r.transpose() - nalgebra::Matrix3::identity()).amax() < 1e-12);
        }
    }
}

#[test]
fn a_payload_adds_its_weight_to_the_gravity_torques() {
    let m = jaco2();
    let cup = m.frame_id("j2s7s300_cup_frame").unwrap();
    let with_cup = m.clone().with_payload(cup, 0.3, nalgebra::Vector3::zeros(), nalgebra::Matrix3::identity() * 1e-4).unwrap();
    let q = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let (mut g0, mut g1) = (vec![0.0; 7], vec![0.0; 7]);
    m.gravity_torques(&q, &mut m.data(), &mut g0).unwrap();
    with_cup.gravity_torques(&q, &mut with_cup.data(), &mut g1).unwrap();
    // Joint 2 carries the cup's 2.94 N at a horizontal lever of well over 0.3 m.
    assert!((g1[1] - g0[1]).abs() > 0.5, "{g0:?} {g1:?}");
    assert!(m.clone().with_payload(cup, -1.0, nalgebra::Vector3::zeros(), nalgebra::Matrix3::zeros()).is_err());
    let not_physical = [
        -nalgebra::Matrix3::identity(),                                           // negative moments
        nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, 3.0)), // 3 > 1 + 1
        nalgebra::Matrix3::new(1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),      // not symmetric
    ];
    for inertia in not_physical {
        assert!(m.clone().with_payload(cup, 0.3, nalgebra::Vector3::zeros(), inertia).is_err(), "{inertia}");
    }
    // Overflowing velocities are an error, not a NaN result.
    let mut tau = vec![0.0; 7];
    assert!(m.inverse_dynamics(&q, &[1e200; 7], &[0.0; 7], &mut m.data(), &mut tau).is_err());
}

#[test]
fn axis_permutation_joint_frames_take_the_fast_path_and_agree_with_the_product() {
    let m = common::jaco2();
    // The shipped URDF writes its rpy angles as multiples of π/2 to full precision.
    assert!(m.joints.iter().all(|j| j.permutation.is_some()), "every JACO2 joint frame is an axis permutation");
    let mut generic = m.clone();
    generic.joints.iter_mut().for_each(|j| j.permutation = None);
    let (mut a, mut b) = (m.data(), generic.data());
    let frame = m.frame_id("j2s7s300_end_effector").unwrap();
    for k in 0..50 {
        let u: Vec<f64> = (0..7).map(|j| (0.37 * (k * 7 + j) as f64).sin() * 0.5 + 0.5).collect();
        let q = common::within_limits(&m, &u);
        m.forward_kinematics(&q, &mut a).unwrap();
        generic.forward_kinematics(&q, &mut b).unwrap();
        let (pa, pb) = (m.frame_pose(frame, &a), generic.frame_pose(frame, &b));
        assert!((pa.to_homogeneous() - pb.to_homogeneous()).amax() < 1e-15, "q = {q:?}");
    }
}

#[test]
fn forward_dynamics_refuses_bad_inputs_by_name() {
    let m = jaco2();
    let mut d = m.data();
    let (q, qd) = (vec![0.0; 7], vec![0.0; 7]);
    let mut qdd = vec![0.0; 7];
    let mut work = DMatrix::zeros(7, 7);
    let mut tau = vec![0.0; 7];
    tau[2] = f64::NAN;
    let e = m.forward_dynamics(&q, &qd, &tau, &mut d, &mut work, &mut qdd).unwrap_err();
    assert!(e.to_string().starts_with("tau"), "{e}");
    let e = m.forward_dynamics(&q, &qd[..6], &[0.0; 7], &mut d, &mut work, &mut qdd).unwrap_err();
    assert!(e.to_string().starts_with("qd"), "{e}");
    let mut small = DMatrix::zeros(6, 6);
    let e = m.forward_dynamics(&q, &qd, &[0.0; 7], &mut d, &mut small, &mut qdd).unwrap_err();
    assert!(e.to_string().starts_with("mass"), "{e}");
    let huge = [1e300; 7];
    assert!(m.forward_dynamics(&q, &huge, &[0.0; 7], &mut d, &mut work, &mut qdd).is_err());
}
