//! Property fuzzing of the kernels that take user data (issue 16), on stable Rust with proptest:
//! the URDF loader, the deformation and the weight update. Whatever they are given, they return
//! `Ok` or a typed `PhriError`: never a panic, a hang or a non-finite result. (The task parser is
//! Python, `phri.config`: tests/fuzz_targets.py fuzzes it with Hypothesis.)

mod common;

use phri_core::belief::{rationality, Belief, BETA_MAX};
use phri_core::deform::{DeformParams, Deformation, EndRule, Norm};
use phri_core::update::{relevance, UpdateParams, UpdateRule, WeightUpdate};
use phri_core::{FrameId, RobotModel};
use proptest::prelude::*;

const JACO2_URDF: &str = include_str!("../../../python/phri/robots/jaco2/j2s7s300.urdf");
const CUP_URDF: &str = include_str!("../../../python/phri/robots/jaco2/cup.urdf");

/// Any f64, with the awkward ones (±0, subnormal, huge, ±inf, NaN) often.
fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => -10.0..10.0f64,
        1 => prop::sample::select(vec![0.0, -0.0, 5e-324, 1e-300, 1e300, -1e300, f64::MAX, f64::MIN, f64::INFINITY, f64::NEG_INFINITY, f64::NAN]),
        1 => any::<f64>(),
    ]
}

/// A URDF text near the JACO2's: cut short, with text put in, or with one number replaced.
fn urdf_text(base: &'static str) -> impl Strategy<Value = String> {
    let len = base.len();
    prop_oneof![
        (0..=len).prop_map(move |k| base[..floor_char(base, k)].to_string()),
        (0..=len, ".{0,12}").prop_map(move |(k, s)| {
            let k = floor_char(base, k);
            format!("{}{s}{}", &base[..k], &base[k..])
        }),
        (0..200usize, prop::sample::select(vec!["nan", "inf", "-1", "1e400", "1e308", "", "0", "x", "1 2", "-0"]))
            .prop_map(move |(nth, value)| replace_nth_number(base, nth, value)),
        ".{0,64}",
    ]
}

fn floor_char(s: &str, mut k: usize) -> usize {
    while !s.is_char_boundary(k) {
        k -= 1;
    }
    k
}

/// `text` with its `nth` attribute value that starts with a digit or '-' replaced by `value`.
fn replace_nth_number(text: &str, nth: usize, value: &str) -> String {
    let starts: Vec<usize> = text
        .match_indices("=\"")
        .map(|(i, _)| i + 2)
        .filter(|&i| text[i..].starts_with(|c: char| c.is_ascii_digit() || c == '-'))
        .collect();
    let Some(&start) = starts.get(nth % starts.len().max(1)) else { return text.to_string() };
    let end = start + text[start..].find('"').unwrap_or(0);
    format!("{}{value}{}", &text[..start], &text[end..])
}

/// A small random kinematic tree (or not a tree: cycles, two parents, missing links).
fn random_tree() -> impl Strategy<Value = String> {
    let joint =
        (0..6usize, 0..6usize, prop::sample::select(vec!["revolute", "continuous", "prismatic", "fixed", "planar"]), any_f64());
    (1..6usize, prop::collection::vec(joint, 0..8)).prop_map(|(links, joints)| {
        let mut s = String::from("<robot name=\"r\">");
        for l in 0..links {
            s += &format!("<link name=\"l{l}\"><inertial><mass value=\"1\"/><inertia ixx=\"1\" iyy=\"1\" izz=\"1\" ixy=\"0\" ixz=\"0\" iyz=\"0\"/></inertial></link>");
        }
        for (j, (parent, child, kind, limit)) in joints.into_iter().enumerate() {
            s += &format!(
                "<joint name=\"j{j}\" type=\"{kind}\"><parent link=\"l{parent}\"/><child link=\"l{child}\"/><axis xyz=\"0 0 1\"/>\
                 <limit lower=\"-{limit}\" upper=\"{limit}\" effort=\"10\" velocity=\"1\"/></joint>"
            );
        }
        s + "</robot>"
    })
}

fn cases() -> u32 {
    std::env::var("PHRI_PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
}

fn check_model(model: &RobotModel) {
    // A model that loads gives finite kinematics and gravity within its limits.
    let q = common::within_limits(model, &vec![0.5; model.nq()]);
    let mut data = model.data();
    let mut tau = vec![0.0; model.nq()];
    if model.gravity_torques(&q, &mut data, &mut tau).is_ok() {
        assert!(tau.iter().all(|v| v.is_finite()), "gravity {tau:?} at {q:?}");
    }
}

proptest! {
    // PHRI_PROPTEST_CASES sets the cases for a longer run (default 256 each, a few seconds).
    #![proptest_config(ProptestConfig { cases: cases(), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn the_urdf_loader_never_panics(text in urdf_text(JACO2_URDF)) {
        if let Ok(model) = RobotModel::from_urdf_str(&text, None, None) {
            check_model(&model);
        }
    }

    #[test]
    fn the_urdf_loader_never_hangs_on_any_tree(text in random_tree(), base in prop::option::of(0..6usize), tip in prop::option::of(0..6usize)) {
        let (base, tip) = (base.map(|b| format!("l{b}")), tip.map(|t| format!("l{t}")));
        if let Ok(model) = RobotModel::from_urdf_str(&text, base.as_deref(), tip.as_deref()) {
            check_model(&model);
        }
        let jaco2 = common::jaco2();
        let last = FrameId(jaco2.frames.len() - 1);
        let _ = jaco2.with_attached_urdf("thing", last, &text);
    }

    #[test]
    fn attaching_any_urdf_never_panics(text in urdf_text(CUP_URDF)) {
        let jaco2 = common::jaco2();
        let last = FrameId(jaco2.frames.len() - 1);
        let _ = jaco2.with_attached_urdf("cup", last, &text);
    }

    #[test]
    fn the_deformation_is_finite_or_an_error(
        window in 0..300usize,
        mu in any_f64(),
        jerk in any::<bool>(),
        shrink in any::<bool>(),
        dof in 1..8usize,
        waypoints in 0..80usize,
        index in 0..90usize,
        values in prop::collection::vec(any_f64(), 0..640),
        push in prop::collection::vec(any_f64(), 1..8),
    ) {
        let params = DeformParams {
            window,
            mu,
            norm: if jerk { Norm::Jerk } else { Norm::Acceleration },
            end_rule: if shrink { EndRule::Shrink } else { EndRule::Skip },
        };
        let Ok(deformation) = Deformation::new(params) else { return Ok(()) };
        let mut trajectory: Vec<f64> = (0..waypoints * dof).map(|i| values.get(i).copied().unwrap_or(0.1)).collect();
        let before = trajectory.clone();
        let u_h: Vec<f64> = (0..dof).map(|j| push[j % push.len()]).collect();
        let finite = trajectory.iter().all(|v| v.is_finite());
        match deformation.deform_in_place(&mut trajectory, dof, index, &u_h) {
            // The kernel checks what it moves; a NaN elsewhere is the caller's (the binding checks).
            Ok(_) if finite => prop_assert!(trajectory.iter().all(|v| v.is_finite()), "deformed into {trajectory:?}"),
            Ok(_) => {}
            Err(_) => prop_assert!(
                trajectory.iter().zip(&before).all(|(a, b)| a.to_bits() == b.to_bits()),
                "an error left the trajectory changed"
            ),
        }
        let _ = deformation.window_at(index, waypoints);
    }

    #[test]
    fn the_weight_update_is_finite_or_an_error(
        k in 0..6usize,
        step in prop::collection::vec(any_f64(), 0..7),
        lower in prop::collection::vec(any_f64(), 0..7),
        upper in prop::collection::vec(any_f64(), 0..7),
        learned in prop::collection::vec(any::<bool>(), 0..7),
        ranges in prop::collection::vec(any_f64(), 0..7),
        rule in prop::sample::select(UpdateRule::ALL.to_vec()),
        weights in prop::collection::vec(any_f64(), 0..7),
        delta_phi in prop::collection::vec(any_f64(), 0..7),
        confidence in prop::option::of(prop::collection::vec(any_f64(), 0..7)),
    ) {
        let fit = |v: &[f64], fill: f64| -> Vec<f64> { (0..k).map(|i| v.get(i).copied().unwrap_or(fill)).collect() };
        let params = UpdateParams {
            step: fit(&step, 0.5),
            lower: fit(&lower, -1.0),
            upper: fit(&upper, 1.0),
            learned: (0..k).map(|i| learned.get(i).copied().unwrap_or(true)).collect(),
            ranges: fit(&ranges, 1.0),
            rule,
        };
        let Ok(update) = WeightUpdate::new(params) else { return Ok(()) };
        let mut w = fit(&weights, 0.0);
        let before = w.clone();
        match update.apply(&mut w, &fit(&delta_phi, 0.0), confidence.as_deref()) {
            Ok(_) => prop_assert!(w.iter().all(|v| !v.is_nan()), "updated into {w:?}"),
            Err(_) => prop_assert!(w.iter().zip(&before).all(|(a, b)| a.to_bits() == b.to_bits()), "an error changed the weights"),
        }
    }

    #[test]
    fn rationality_and_the_belief_are_finite_or_an_error(
        learned in prop::collection::vec(any::<bool>(), 0..5),
        sensitivity in prop::collection::vec(any_f64(), 0..40),
        u_h in prop::collection::vec(any_f64(), 0..8),
        step in prop::collection::vec(any_f64(), 0..5),
        effort in any_f64(),
    ) {
        if let Ok(r) = rationality(&sensitivity, &learned, &u_h) {
            prop_assert!((0.0..=BETA_MAX).contains(&r.beta) && (0.0..=1.0).contains(&r.explained), "{r:?}");
        }
        let k = learned.len();
        let params = UpdateParams {
            step: (0..k).map(|i| step.get(i).copied().unwrap_or(1.0)).collect(),
            lower: vec![-1.0; k],
            upper: vec![1.0; k],
            learned: learned.clone(),
            ranges: vec![1.0; k],
            rule: UpdateRule::All,
        };
        let Ok(update) = WeightUpdate::new(params) else { return Ok(()) };
        let Ok(mut belief) = Belief::new(update.params(), effort) else { return Ok(()) };
        let before = belief.covariance().to_vec();
        match belief.observe(&sensitivity, u_h.len()) {
            Ok(()) => prop_assert!(belief.covariance().iter().all(|v| v.is_finite()), "{:?}", belief.covariance()),
            Err(_) => prop_assert_eq!(belief.covariance(), &before[..]),
        }
    }

    #[test]
    fn relevance_is_finite_or_an_error(
        delta_phi in prop::collection::vec(any_f64(), 0..5),
        sensitivity in prop::collection::vec(any_f64(), 0..40),
        u_h in prop::collection::vec(any_f64(), 0..8),
    ) {
        let mut out = vec![0.0; delta_phi.len()];
        if relevance(&delta_phi, &sensitivity, &u_h, &mut out).is_ok() {
            prop_assert!(out.iter().all(|v| v.is_finite()), "relevance {out:?}");
        }
    }
}
