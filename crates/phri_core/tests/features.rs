//! Feature counts: gradients against finite differences, sums, and known values.

mod common;

use std::sync::Arc;

use common::{deg, jaco2, within_limits};
use phri_core::features::{FeatureSet, SceneParams, BUILTIN_FEATURES};
use proptest::prelude::*;

fn feature_set(names: &[&str]) -> FeatureSet {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    FeatureSet::from_names(model, frame, names, &SceneParams::default()).unwrap()
}

/// A trajectory of `waypoints` rows from `a` to `b` with a wiggle, row-major.
fn trajectory(a: &[f64], b: &[f64], waypoints: usize, wiggle: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(waypoints * 7);
    for i in 0..waypoints {
        let s = i as f64 / (waypoints - 1) as f64;
        for j in 0..7 {
            out.push(a[j] + s * (b[j] - a[j]) + wiggle * (3.0 * s + j as f64).sin() * s * (1.0 - s));
        }
    }
    out
}

#[test]
fn phi_sums_segments_and_skips_the_first_waypoint() {
    let mut fs = feature_set(&BUILTIN_FEATURES);
    let a = deg([210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8]);
    let b = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let xi = trajectory(&a, &b, 31, 0.3);
    let mut phi = vec![0.0; fs.len()];
    fs.phi(&xi, &mut phi).unwrap();
    let mut per = vec![0.0; 30 * fs.len()];
    fs.per_segment(&xi, &mut per).unwrap();
    for k in 0..fs.len() {
        let sum: f64 = (0..30).map(|i| per[i * fs.len() + k]).sum();
        assert!((sum - phi[k]).abs() < 1e-12);
    }
    // Efficiency is the squared joint path length.
    let eff: f64 = (1..31).map(|i| (0..7).map(|j| (xi[i * 7 + j] - xi[(i - 1) * 7 + j]).powi(2)).sum::<f64>()).sum();
    assert!((phi[0] - eff).abs() < 1e-12);
    // Changing waypoint 0's task-space position alone changes nothing but the first segment's
    // efficiency and keep-out samples: the table feature ignores waypoint 0.
    let mut moved = xi.clone();
    moved[1] += 0.2;
    let mut phi2 = vec![0.0; fs.len()];
    fs.phi(&moved, &mut phi2).unwrap();
    let table = fs.index_of("table").unwrap();
    assert_eq!(phi[table], phi2[table]);
}

#[test]
fn coffee_measures_the_tilt_of_link_7s_x_axis() {
    // Candle pose: link_7's x axis is horizontal (cup on its side), tilt |R00|+|R10| = 1.
    let mut fs = feature_set(&["coffee", "coffee_dot", "table"]);
    let xi = [std::f64::consts::PI; 14];
    let mut phi = [0.0; 3];
    fs.phi(&xi, &mut phi).unwrap();
    assert!((phi[0] - 1.0).abs() < 1e-9, "{phi:?}");
    assert!((phi[1] - 1.0).abs() < 1e-9, "{phi:?}");
    assert!((phi[2] - 1.1003).abs() < 1e-4, "{phi:?}");
}

#[test]
fn bad_feature_input_is_a_typed_error() {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    assert!(FeatureSet::from_names(model.clone(), frame, &["tabel"], &SceneParams::default()).is_err());
    assert!(FeatureSet::from_names(model.clone(), frame, &["table", "table"], &SceneParams::default()).is_err());
    let bad = SceneParams { radius: -1.0, ..Default::default() };
    assert!(FeatureSet::from_names(model, frame, &["laptop"], &bad).is_err());
    let mut fs = feature_set(&["table"]);
    let mut phi = [0.0];
    assert!(fs.phi(&[0.0; 7], &mut phi).is_err(), "one waypoint is not a trajectory");
    assert!(fs.phi(&[0.0; 15], &mut phi).is_err());
    assert!(fs.phi(&[f64::NAN; 14], &mut phi).is_err());
    assert!(fs.set_ranges(Some(&[0.0])).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn gradients_match_finite_differences(u in prop::collection::vec(0.05..0.95f64, 14), wiggle in 0.0..0.5f64) {
        let names = BUILTIN_FEATURES;
        let mut fs = feature_set(&names);
        let model = jaco2();
        let xi = trajectory(&within_limits(&model, &u[..7]), &within_limits(&model, &u[7..]), 6, wiggle);
        let k_len = fs.len();
        let mut phi = vec![0.0; k_len];
        let mut jac = vec![0.0; k_len * xi.len()];
        fs.phi_gradient(&xi, &mut phi, &mut jac).unwrap();
        let h = 1e-6;
        let (mut p0, mut pp, mut pm) = (vec![0.0; k_len], vec![0.0; k_len], vec![0.0; k_len]);
        fs.phi(&xi, &mut p0).unwrap();
        let (mut checked, mut kinks) = (0, 0);
        for v in 0..xi.len() {
            let mut x = xi.clone();
            x[v] += h;
            fs.phi(&x, &mut pp).unwrap();
            x[v] -= 2.0 * h;
            fs.phi(&x, &mut pm).unwrap();
            for k in 0..k_len {
                let (right, left) = ((pp[k] - p0[k]) / h, (p0[k] - pm[k]) / h);
                // A hinge or |.| kink within ±h makes the one-sided quotients disagree: skip it.
                if (right - left).abs() > 1e-3 {
                    kinks += 1;
                    continue;
                }
                checked += 1;
                let fd = (pp[k] - pm[k]) / (2.0 * h);
                let an = jac[k * xi.len() + v];
                prop_assert!((fd - an).abs() < 1e-5, "{} d/dxi[{v}]: fd {fd} vs analytic {an}", names[k]);
            }
        }
        prop_assert!(kinks * 20 < checked, "{kinks} kinks of {checked}");
        // The weighted gradient is the weighted sum of the per-feature gradients.
        let w: Vec<f64> = (0..k_len).map(|k| 0.5 + k as f64).collect();
        let mut g = vec![0.0; xi.len()];
        let cost = fs.weighted_cost_gradient(&xi, &w, &mut g).unwrap();
        let expect_cost: f64 = (0..k_len).map(|k| w[k] * phi[k]).sum();
        prop_assert!((cost - expect_cost).abs() < 1e-9);
        for v in 0..xi.len() {
            let e: f64 = (0..k_len).map(|k| w[k] * jac[k * xi.len() + v]).sum();
            prop_assert!((g[v] - e).abs() < 1e-9);
        }
    }
}
