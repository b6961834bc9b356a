//! Feature counts: gradients against finite differences, sums, and known values.

mod common;

use std::sync::Arc;

use common::study::{feature_spec, keepout_circle, study_features};
use common::{deg, jaco2, within_limits};
use phri_core::features::{FeatureParams, FeatureSet, FeatureSpec, SegmentHessian, BUILTIN_FEATURES};
use phri_core::scene::Scene;
use phri_core::trajopt::block_tridiagonal::BlockTridiagonal;
use proptest::prelude::*;

fn feature_set(names: &[&str]) -> FeatureSet {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    study_features(model, frame, names)
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
    let scene = common::study::study_scene();
    let build = |specs: &[FeatureSpec]| FeatureSet::from_specs(model.clone(), frame, specs, Some(&scene));
    assert!(build(&[FeatureSpec { name: "tabel".into(), params: FeatureParams::None }]).is_err());
    assert!(build(&[feature_spec("table"), feature_spec("table")]).is_err());
    for (name, radius) in [("laptop", -1.0), ("human", f64::NAN)] {
        let mut bad = feature_spec(name);
        match &mut bad.params {
            FeatureParams::Keepout(k) => k.radius = radius,
            other => panic!("{name} is a keep-out feature, got {other:?}"),
        }
        assert!(build(&[bad]).is_err());
    }
    assert!(FeatureSet::from_specs(model.clone(), frame, &[feature_spec("laptop")], Some(&Scene::empty())).is_err());
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
        // The learner takes Φ(ξ_R) from phi_gradient: it must be phi's, to the bit.
        prop_assert_eq!(&phi, &p0);
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

/// Central finite differences of the gradient, column `v`, of the weighted cost.
fn gradient_difference(fs: &mut FeatureSet, xi: &[f64], w: &[f64], smoothing: f64, v: usize, h: f64) -> Vec<f64> {
    let n = 7;
    let waypoints = xi.len() / n;
    let mut hess = BlockTridiagonal::new(n, waypoints);
    let (mut gp, mut gm) = (vec![0.0; xi.len()], vec![0.0; xi.len()]);
    let mut x = xi.to_vec();
    x[v] += h;
    fs.weighted_cost_curvature(&x, w, smoothing, &mut gp, filling(&mut hess)).unwrap();
    x[v] -= 2.0 * h;
    fs.weighted_cost_curvature(&x, w, smoothing, &mut gm, filling(&mut hess)).unwrap();
    gp.iter().zip(&gm).map(|(a, b)| (a - b) / (2.0 * h)).collect()
}

/// Entry (r, c) of a block-tridiagonal matrix over N × n variables (0 outside the band).
/// A sink for `weighted_cost_curvature` that fills `hess` (cleared first) with the segments' blocks.
fn filling(hess: &mut BlockTridiagonal) -> impl FnMut(usize, &SegmentHessian) + '_ {
    hess.clear();
    move |i, h| hess.add_segment(i, h.matrix())
}

fn entry(h: &BlockTridiagonal, r: usize, c: usize) -> f64 {
    let n = h.dof();
    let (br, bc) = (r / n, c / n);
    match br as isize - bc as isize {
        0 => h.diag(br)[(r % n) * n + c % n],
        -1 => h.off(br)[(r % n) * n + c % n],
        1 => h.off(bc)[(c % n) * n + r % n],
        _ => 0.0,
    }
}

#[test]
fn second_derivatives_of_smooth_features_match_finite_differences() {
    // Smooth features: the optimiser's curvature is their exact Hessian.
    let names = ["efficiency", "table", "coffee_dot", "origin"];
    let mut fs = feature_set(&names);
    let model = jaco2();
    let w = [1.0, 0.7, 1.3, 0.4];
    for seed in 0..6 {
        let u: Vec<f64> = (0..14).map(|k| 0.1 + 0.8 * (((seed * 14 + k) as f64) * 0.618).fract()).collect();
        let xi = trajectory(&within_limits(&model, &u[..7]), &within_limits(&model, &u[7..]), 5, 0.4);
        let mut hess = BlockTridiagonal::new(7, 5);
        let mut grad = vec![0.0; xi.len()];
        fs.weighted_cost_curvature(&xi, &w, 0.0, &mut grad, filling(&mut hess)).unwrap();
        for v in 0..xi.len() {
            let fd = gradient_difference(&mut fs, &xi, &w, 0.0, v, 1e-6);
            for (r, fd) in fd.iter().enumerate() {
                let an = entry(&hess, r, v);
                assert!((fd - an).abs() < 2e-6 * (1.0 + an.abs()), "seed {seed}: H[{r}, {v}] fd {fd} vs {an}");
            }
        }
    }
}

#[test]
fn hinge_curvature_is_exact_inside_the_quadratic_zone() {
    // A trajectory that grazes the human keep-out circle: every active sample inside the smoothing
    // zone, where the smoothed hinge is C² and its curvature is exact.
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let delta = 0.2;
    let mut fs = study_features(model.clone(), frame, &["human"]);
    let (center, radius) = keepout_circle("human");
    let a = deg([210.8, 241.0, 209.2, 97.8, 316.8, 91.9, 322.8]);
    let b = deg([210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4]);
    // Find a blend of the two poses whose link_7 origin lies 5 cm inside the circle.
    let mut xi = trajectory(&a, &b, 4, 0.0);
    let mut per = vec![0.0; 3];
    fs.per_segment(&xi, &mut per).unwrap();
    assert!(per.iter().any(|v| *v > 0.0), "the straight line must enter the circle: {per:?}");
    // Shrink towards the start until the deepest sample is within the zone.
    for _ in 0..40 {
        let model2 = jaco2();
        let mut d = model2.data();
        let mut deepest: f64 = 0.0;
        for i in 0..3 {
            for k in 1..=4 {
                let s = k as f64 / 4.0;
                let q: Vec<f64> = (0..7).map(|j| xi[i * 7 + j] + s * (xi[(i + 1) * 7 + j] - xi[i * 7 + j])).collect();
                model2.forward_kinematics(&q, &mut d).unwrap();
                let p = model2.frame_pose(frame, &d).translation.vector;
                deepest = deepest.max(radius - (p.xy() - center).norm());
            }
        }
        if deepest < 0.5 * delta {
            break;
        }
        for v in xi.iter_mut().zip(a.iter().cycle()) {
            *v.0 = *v.1 + 0.9 * (*v.0 - *v.1);
        }
    }
    let mut hess = BlockTridiagonal::new(7, 4);
    let mut grad = vec![0.0; xi.len()];
    fs.weighted_cost_curvature(&xi, &[1.0], delta, &mut grad, filling(&mut hess)).unwrap();
    assert!((0..xi.len()).any(|r| entry(&hess, r, r).abs() > 1e-3), "no sample inside the circle");
    for v in 7..21 {
        let fd = gradient_difference(&mut fs, &xi, &[1.0], delta, v, 1e-6);
        for (r, fd) in fd.iter().enumerate() {
            let an = entry(&hess, r, v);
            assert!((fd - an).abs() < 1e-5 * (1.0 + an.abs()), "H[{r}, {v}] fd {fd} vs {an}");
        }
    }
}

#[test]
fn the_keepout_skip_changes_nothing() {
    // The conservative skip must give exactly what evaluating every sample gives: compare the
    // per-segment keep-out counts with a direct evaluation of all samples.
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let mut fs = study_features(model.clone(), frame, &["laptop", "human"]);
    let circles = [keepout_circle("laptop"), keepout_circle("human")];
    let mut data = model.data();
    let mut checked = 0;
    for seed in 0..40u64 {
        let u: Vec<f64> = (0..14).map(|k| (((seed * 14 + k) as f64 + 0.5) * 0.754_877_666).fract()).collect();
        let xi = trajectory(&within_limits(&model, &u[..7]), &within_limits(&model, &u[7..]), 9, 0.5);
        let mut per = vec![0.0; 8 * 2];
        fs.per_segment(&xi, &mut per).unwrap();
        for i in 1..9 {
            for (f, (c, radius)) in circles.iter().enumerate() {
                let mut expect = 0.0;
                for k in 1..=4 {
                    let s = k as f64 / 4.0;
                    let q: Vec<f64> = (0..7).map(|j| xi[(i - 1) * 7 + j] + s * (xi[i * 7 + j] - xi[(i - 1) * 7 + j])).collect();
                    model.forward_kinematics(&q, &mut data).unwrap();
                    let p = model.frame_pose(frame, &data).translation.vector;
                    expect += (radius - (p.xy() - c).norm()).max(0.0);
                }
                let got = per[(i - 1) * 2 + f];
                assert!((got - expect).abs() < 1e-12, "seed {seed} segment {i} feature {f}: {got} vs {expect}");
                checked += usize::from(expect > 0.0);
            }
        }
    }
    assert!(checked > 20, "too few segments entered a circle ({checked})");
}

/// A feature written outside the crate, as the module docs describe: the squared height of link_7
/// above 0.3 m, φ = (z − 0.3)² at q_i, with its gradient 2(z − 0.3)·∂z/∂q_i and, when asked, the
/// Gauss–Newton curvature 2·∇z∇zᵀ.
#[derive(Clone)]
struct HeightAbove;

impl phri_core::features::Feature for HeightAbove {
    fn name(&self) -> &str {
        "height_above"
    }
    fn segment(&self, seg: &mut phri_core::features::Segment<'_>, grad: Option<phri_core::features::SegmentGrad<'_>>) -> f64 {
        let dz = seg.point(1.0).position.z - 0.3;
        if let Some(g) = grad {
            let jac = seg.jacobian(1.0).clone();
            for j in 0..g.this.len() {
                g.this[j] += g.scale * 2.0 * dz * jac[(2, j)];
            }
            if let Some(h) = g.hessian {
                h.add_outer(1.0, 2.0 * g.scale, |j| jac[(2, j)]);
            }
        }
        dz * dz
    }
}

#[test]
fn a_feature_written_outside_the_crate_is_counted_differentiated_and_optimised() {
    use phri_core::features::{Efficiency, Feature};
    use phri_core::trajopt::{TrajectoryOptimizer, TrajoptParams};
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let features: Vec<Box<dyn Feature>> = vec![Box::new(Efficiency), Box::new(HeightAbove)];
    let mut fs = FeatureSet::new(model.clone(), frame, features).unwrap();
    let a = deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let b = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let xi = trajectory(&a, &b, 9, 0.3);
    // Φ sums φ over waypoints 1..N-1.
    let mut phi = [0.0; 2];
    fs.phi(&xi, &mut phi).unwrap();
    let mut d = model.data();
    let mut expected = 0.0;
    for i in 1..9 {
        model.forward_kinematics(&xi[i * 7..(i + 1) * 7], &mut d).unwrap();
        expected += (model.frame_pose(frame, &d).translation.z - 0.3).powi(2);
    }
    assert!((phi[1] - expected).abs() < 1e-12, "{} vs {expected}", phi[1]);
    // Its gradient matches finite differences.
    let w = [0.0, 1.0];
    let mut grad = vec![0.0; xi.len()];
    fs.weighted_cost_gradient(&xi, &w, &mut grad).unwrap();
    for v in 7..xi.len() - 7 {
        let (mut up, mut down) = (xi.clone(), xi.clone());
        up[v] += 1e-6;
        down[v] -= 1e-6;
        let (mut g0, mut p0, mut p1) = (vec![0.0; xi.len()], 0.0, 0.0);
        p1 += fs.weighted_cost_gradient(&up, &w, &mut g0).unwrap();
        p0 += fs.weighted_cost_gradient(&down, &w, &mut g0).unwrap();
        let fd = (p1 - p0) / 2e-6;
        assert!((fd - grad[v]).abs() < 1e-6 * (1.0 + fd.abs()), "entry {v}: fd {fd} vs {}", grad[v]);
    }
    // And the optimiser lowers it against the plan that ignores it.
    let mut opt = TrajectoryOptimizer::new(&fs, 9, TrajoptParams::default()).unwrap();
    let (mut with, mut without) = (vec![0.0; xi.len()], vec![0.0; xi.len()]);
    let info = opt.solve(&mut fs, &[1.0, 5.0], &a, &b, None, &mut with).unwrap();
    opt.solve(&mut fs, &[1.0, 0.0], &a, &b, None, &mut without).unwrap();
    let (mut pw, mut po) = ([0.0; 2], [0.0; 2]);
    fs.phi(&with, &mut pw).unwrap();
    fs.phi(&without, &mut po).unwrap();
    assert!(info.converged, "{info:?}");
    assert!(pw[1] < po[1] - 1e-3, "the custom feature did not drop: {} vs {}", pw[1], po[1]);
}

#[test]
fn rescaled_weights_cost_a_path_the_same_on_any_grid() {
    // For a fixed smooth path Φ_k(S) ≈ S^(e_k)·c_k (S segments), so with the rescaled weights
    // w'·Φ(S₂) = (S₁/S₂)·w·Φ(S₁): the same objective up to a factor, hence the same optimum.
    let names = ["efficiency", "table", "coffee", "laptop", "origin"];
    let mut fs = feature_set(&names);
    let a = deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]);
    let b = deg([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0]);
    let phi = |fs: &mut FeatureSet, n: usize| {
        let mut phi = vec![0.0; names.len()];
        fs.phi(&trajectory(&a, &b, n, 0.3), &mut phi).unwrap();
        phi
    };
    let (coarse, fine) = (phi(&mut fs, 31), phi(&mut fs, 301));
    let ratio: f64 = 30.0 / 300.0;
    for (k, e) in fs.resolution_exponents().into_iter().enumerate() {
        // Each feature's own growth, so each exponent is checked (the sums' ends differ by O(1/S)).
        assert!(coarse[k].abs() > 1e-3, "{}: the path must give it a value, got {}", names[k], coarse[k]);
        let expected = coarse[k] * ratio.powi(-e);
        assert!((fine[k] - expected).abs() < 0.05 * expected.abs(), "{}: {} vs {expected}", names[k], fine[k]);
    }
    let w = [1.0, 0.7, 0.4, 2.0, 3.0];
    let rescaled = fs.rescale_weights(&w, 31, 301).unwrap();
    assert_eq!(rescaled[0], w[0], "efficiency keeps its weight");
    for k in 1..names.len() {
        assert!((rescaled[k] - w[k] * ratio * ratio).abs() < 1e-15, "{rescaled:?}");
    }
    let cost = |weights: &[f64], phi: &[f64]| weights.iter().zip(phi).map(|(w, p)| w * p).sum::<f64>();
    let (before, after) = (cost(&w, &coarse), cost(&rescaled, &fine));
    assert!((after / ratio - before).abs() < 0.03 * before, "{} vs {before}", after / ratio);
    // Unscaled, the same weights price the path differently relative to efficiency.
    assert!((cost(&w, &fine) / ratio - before).abs() > 10.0 * before);
    assert_eq!(fs.rescale_weights(&w, 31, 31).unwrap(), w.to_vec());
    let err = fs.rescale_weights(&w[..3], 31, 100).unwrap_err().to_string();
    assert!(err.starts_with("weights must have shape (5,)"), "{err}");
    for (from, to, arg) in [(1, 100, "from_waypoints"), (31, 0, "to_waypoints")] {
        let err = fs.rescale_weights(&w, from, to).unwrap_err().to_string();
        assert!(err.starts_with(arg), "{err}");
    }
    let err = fs.rescale_weights(&[1.0, f64::NAN, 0.0, 0.0, 0.0], 31, 100).unwrap_err().to_string();
    assert!(err.starts_with("weights must be finite"), "{err}");
    let err = fs.rescale_weights(&[1.0, 1e300, 0.0, 0.0, 0.0], 1_000_000, 2).unwrap_err().to_string();
    assert!(err.starts_with("weights rescaled from 1000000 to 2 waypoints overflow"), "{err}");
}
