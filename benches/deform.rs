//! The trajectory deformation of eq. 7: criterion medians, then the worst case.
//!
//! Targets (per correction, 7 joints): the original windowed deformation, n = 5 on a 31-waypoint
//! plan, ≤ 0.2 µs; the banded deformation with n = 10,000 (10 s at 1 kHz) ≤ 100 µs. The long
//! window is timed twice per norm: `full` (the precomputed shape H, O(n·dof)) and `shrunk` (a
//! correction 10,000 waypoints before the goal under `EndRule::Shrink`: the 9,999-waypoint shape is
//! solved from the banded factor per call, two O(m) back substitutions, then applied). The one-off
//! construction (the double-double banded LDLᵀ and the full-window H) is reported alongside.
//!
//! The worst-case pass times individual calls with `Instant` (timer included; see
//! benches/kinematics.rs for how to read the maximum). Every call pushes with the opposite sign of
//! the previous one, so the trajectory stays where it started.
//!
//! `cargo bench -p phri_benches --bench deform`; under `cargo test --benches` each criterion
//! benchmark runs once and the worst-case pass uses few calls.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, BenchmarkId, Criterion, Throughput};
use phri_benches::place_lower;
use phri_core::deform::{DeformParams, Deformation, EndRule, Norm};

const DOF: usize = 7;
/// The push [N·m] (about the study's thresholds; its sign alternates call to call).
const PUSH: [f64; DOF] = [9.0, -8.5, 8.2, 2.4, -1.2, 1.1, 1.3];

/// A plan of `n_waypoints` rows moving from the place_lower pose by a slow sine per joint [rad].
fn plan(n_waypoints: usize) -> Vec<f64> {
    let q0 = place_lower();
    let mut traj = vec![0.0; n_waypoints * DOF];
    for (i, row) in traj.chunks_exact_mut(DOF).enumerate() {
        let s = i as f64 / n_waypoints as f64;
        for (j, q) in row.iter_mut().enumerate() {
            *q = q0[j] + 0.3 * (std::f64::consts::PI * s * (j + 1) as f64).sin();
        }
    }
    traj
}

/// One benchmarked correction: a deformation, its plan, and where the pushes land.
struct Case {
    name: &'static str,
    deformation: Deformation,
    traj: Vec<f64>,
    /// Indices cycled through, call after call.
    indices: Vec<usize>,
    moved: usize,
}

impl Case {
    fn new(name: &'static str, params: DeformParams, n_waypoints: usize, indices: Vec<usize>) -> Self {
        let deformation = Deformation::new(params).expect("valid parameters");
        let moved = deformation.window_at(indices[0], n_waypoints).expect("index inside the plan");
        for &i in &indices {
            assert_eq!(deformation.window_at(i, n_waypoints).expect("index inside"), moved, "{name}: same window");
        }
        Case { name, deformation, traj: plan(n_waypoints), indices, moved }
    }

    /// The `k`-th call: push at the next index with sign (−1)^k.
    #[inline]
    fn call(&mut self, k: usize, push: &[[f64; DOF]; 2]) -> usize {
        let index = self.indices[k % self.indices.len()];
        self.deformation.deform_in_place(&mut self.traj, DOF, black_box(index), black_box(&push[k & 1])).expect("valid")
    }
}

fn cases() -> Vec<Case> {
    let long = |norm, end_rule| DeformParams { window: 10_000, mu: 0.01, norm, end_rule };
    // The original: n = 5 on a 31-waypoint plan, every index where a full window fits.
    let original = Case::new("window_5/plan_31", DeformParams::default(), 31, (0..=24).collect());
    let mut cases = vec![original];
    for (norm, full, shrunk) in [
        (Norm::Acceleration, "window_10000/acceleration/full", "window_10000/acceleration/shrunk_9999"),
        (Norm::Jerk, "window_10000/jerk/full", "window_10000/jerk/shrunk_9999"),
    ] {
        // 20,000 waypoints (20 s at 1 kHz): a full window at index 0; a shrunk one of 9,999
        // waypoints at index 9,999 (the goal is waypoint 19,999).
        cases.push(Case::new(full, long(norm, EndRule::Shrink), 20_000, vec![0, 1, 2, 3]));
        cases.push(Case::new(shrunk, long(norm, EndRule::Shrink), 20_000, vec![9_999]));
    }
    cases
}

fn pushes() -> [[f64; DOF]; 2] {
    [PUSH, PUSH.map(|u| -u)]
}

fn per_correction(c: &mut Criterion) {
    let push = pushes();
    let mut group = c.benchmark_group("deform");
    for mut case in cases() {
        group.throughput(Throughput::Elements(case.moved as u64));
        let mut k = 0;
        group.bench_function(case.name, |b| {
            b.iter(|| {
                k += 1;
                case.call(k, &push)
            })
        });
    }
    group.finish();

    let mut group = c.benchmark_group("deform_construction");
    for window in [5, 10_000] {
        for (norm, tag) in [(Norm::Acceleration, "acceleration"), (Norm::Jerk, "jerk")] {
            let params = DeformParams { window, norm, ..DeformParams::default() };
            group.bench_function(BenchmarkId::new(tag, window), |b| {
                b.iter(|| Deformation::new(black_box(params)).expect("valid").shape()[0])
            });
        }
    }
    group.finish();
}

criterion_group!(benches, per_correction);

/// Nanoseconds at the given quantile of sorted samples.
fn quantile(sorted: &[u64], p: f64) -> u64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Times individual calls of each case and prints percentiles and the maximum.
fn worst_case(scale: usize) {
    let push = pushes();
    println!();
    println!("worst case: individual calls, alternating push, timer included");
    println!("  {:<38} {:>8} {:>10} {:>10} {:>10} {:>10}", "case", "calls", "median", "p99", "p99.9", "max");
    for mut case in cases() {
        let calls = if case.moved > 100 { 10 * scale } else { 1000 * scale };
        for k in 0..calls.min(10_000) {
            black_box(case.call(k, &push));
        }
        let mut samples: Vec<u64> = (0..calls)
            .map(|k| {
                let t0 = Instant::now();
                black_box(case.call(k, &push));
                t0.elapsed().as_nanos() as u64
            })
            .collect();
        samples.sort_unstable();
        let us = |ns: u64| format!("{:.3} µs", ns as f64 / 1000.0);
        println!(
            "  {:<38} {:>8} {:>10} {:>10} {:>10} {:>10}",
            case.name,
            calls,
            us(quantile(&samples, 0.5)),
            us(quantile(&samples, 0.99)),
            us(quantile(&samples, 0.999)),
            us(*samples.last().expect("non-empty")),
        );
        assert!(case.traj.iter().all(|q| q.is_finite()));
    }
}

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let benchmarking = std::env::args().any(|a| a == "--bench");
    worst_case(if benchmarking { 1000 } else { 1 });
}
