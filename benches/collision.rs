//! Distance queries of the arm against the study's scene, per configuration: the JACO2 carrying
//! the cup, every collision body against the scene's objects (table, laptop, the person's torso)
//! and against the bodies it can meet (`phri_core::collision::CollisionChecker` with
//! `SELF_MARGIN`), as the study's planner checks them.
//!
//! Target (issue 13): forward kinematics + the query ≤ 2 µs per configuration. Queries:
//! - `near`: forward kinematics + `for_each_near` with the planner's band (`CollisionParams`'s
//!   default, 5 cm) over all pairs, each near sphere pair's gradient in q consumed — what the
//!   collision penalty does at each of its points;
//! - `worst`: forward kinematics + `worst` (the pair nearest its margin, with its names) — what the
//!   post-solve check of the executed curve does at each of its points;
//! - `scene_distances`: forward kinematics + `CollisionModel::scene_distances` (every body to every
//!   object, no self pairs) — what the episode log records per sample;
//! - `fk`: forward kinematics alone, the part of each row above that is not the query.
//!
//! Each at a fixed pose (the study's place_lower, the cup low over the table) and at a new pose
//! every call: along the executed curves of the four tasks' cold plans (the planner's poses) and at
//! pseudo-random configurations within the joint limits (many inside the table or folded onto
//! themselves: more pairs within the band). Criterion gives medians of batch averages; a second
//! pass times individual calls with `Instant` over the varying poses and prints median, p99 and
//! max (timer included), and the mean number of sphere pairs within the band.
//!
//! `cargo bench -p phri_benches --bench collision`; under `cargo test --benches` each criterion
//! benchmark runs once and the timing pass makes 10³ calls.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use criterion::{criterion_group, BenchmarkId, Criterion, Throughput};
use phri_benches::study::study_scene;
use phri_benches::{configurations, jaco2_with_cup, place_lower, study_planner, study_tasks, DURATION, STUDY_WAYPOINTS};
use phri_core::collision::{CollisionChecker, ProximityScratch, SELF_MARGIN};
use phri_core::reference::{Interpolation, TimedTrajectory};
use phri_core::scene::Scene;
use phri_core::trajopt::CollisionParams;
use phri_core::{RobotData, RobotModel};

const NQ: usize = 7;
/// Poses sampled along each task's executed curve.
const PLAN_POSES: usize = 256;
/// Pseudo-random poses within the limits.
const RANDOM_POSES: usize = 1024;

/// One query workspace, allocation free per call except `worst`'s names.
struct Query {
    model: Arc<RobotModel>,
    scene: Scene,
    checker: Arc<CollisionChecker>,
    band: f64,
    data: RobotData,
    scratch: ProximityScratch,
    distances: Vec<f64>,
}

impl Query {
    fn new() -> Self {
        let model = Arc::new(jaco2_with_cup());
        let scene = study_scene();
        let checker = Arc::new(CollisionChecker::new(&model, &scene, Some(SELF_MARGIN)).expect("complete collision model"));
        // The planner's band.
        let band = CollisionParams::new(checker.clone()).band;
        let distances = vec![0.0; model.collision().bodies().len() * scene.objects().len()];
        Query { data: model.data(), scratch: ProximityScratch::default(), model, scene, checker, band, distances }
    }

    #[inline]
    fn fk(&mut self, q: &[f64; NQ]) -> f64 {
        self.model.forward_kinematics(q, &mut self.data).expect("valid q");
        self.data.axis[6].x
    }

    /// Forward kinematics + every sphere pair within margin + band, with its gradient.
    #[inline]
    fn near(&mut self, q: &[f64; NQ]) -> f64 {
        self.model.forward_kinematics(q, &mut self.data).expect("valid q");
        let mut acc = 0.0;
        self.checker.for_each_near(&self.model, &self.data, &mut self.scratch, self.band, |n, g| acc += n.distance + g[0]);
        acc
    }

    #[inline]
    fn worst(&mut self, q: &[f64; NQ]) -> f64 {
        self.model.forward_kinematics(q, &mut self.data).expect("valid q");
        self.checker.worst(&self.model, &self.data, &mut self.scratch).map_or(0.0, |v| v.distance)
    }

    #[inline]
    fn scene_distances(&mut self, q: &[f64; NQ]) -> f64 {
        self.model.forward_kinematics(q, &mut self.data).expect("valid q");
        let collision = self.model.collision();
        collision.scene_distances(&self.model, &self.data, &self.scene, &mut self.distances).expect("sized");
        self.distances[0]
    }

    /// Sphere pairs within margin + band at `q`.
    fn near_count(&mut self, q: &[f64; NQ]) -> usize {
        self.model.forward_kinematics(q, &mut self.data).expect("valid q");
        let mut count = 0;
        self.checker.for_each_near(&self.model, &self.data, &mut self.scratch, self.band, |_, _| count += 1);
        count
    }
}

type Op = fn(&mut Query, &[f64; NQ]) -> f64;

const OPS: [(&str, Op); 4] =
    [("near", Query::near), ("worst", Query::worst), ("scene_distances", Query::scene_distances), ("fk", Query::fk)];

/// Poses along the executed curves (cubic through the waypoints) of the four tasks' cold plans
/// for the true weights, by the study's planner.
fn plan_poses(model: &Arc<RobotModel>) -> Vec<[f64; NQ]> {
    let mut poses = Vec::new();
    for task in study_tasks() {
        let (mut fs, mut opt) = study_planner(model, &task, STUDY_WAYPOINTS);
        let mut plan = vec![0.0; STUDY_WAYPOINTS * NQ];
        let info = opt.solve(&mut fs, &[1.0, task.true_weight], &task.start, &task.goal, None, &mut plan).expect("valid");
        assert!(info.feasible, "{}: {info:?}", task.name);
        let reference = TimedTrajectory::new(plan, NQ, DURATION, Interpolation::Cubic).expect("valid plan");
        let (mut qd, mut qdd) = ([0.0; NQ], [0.0; NQ]);
        for k in 0..PLAN_POSES {
            let mut q = [0.0; NQ];
            reference.sample(DURATION * k as f64 / (PLAN_POSES - 1) as f64, &mut q, &mut qd, &mut qdd);
            poses.push(q);
        }
    }
    poses
}

fn pose_sets(w: &Query) -> [(&'static str, Vec<[f64; NQ]>); 2] {
    [("plan_poses", plan_poses(&w.model)), ("random_poses", configurations(&w.model, RANDOM_POSES, 0x9E37_79B9_7F4A_7C15))]
}

fn per_configuration(c: &mut Criterion) {
    let mut w = Query::new();
    let sets = pose_sets(&w);
    let fixed = place_lower();
    eprintln!(
        "{} checked pairs ({} excluded); {} sphere pairs within the band at place_lower",
        w.checker.len(),
        w.checker.excluded().len(),
        w.near_count(&fixed)
    );
    let mut group = c.benchmark_group("collision_query");
    group.throughput(Throughput::Elements(1));
    for (name, op) in OPS {
        group.bench_function(BenchmarkId::new(name, "place_lower"), |b| b.iter(|| op(&mut w, black_box(&fixed))));
        for (label, poses) in &sets {
            let mut k = 0;
            group.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| {
                    k = (k + 1) % poses.len();
                    op(&mut w, black_box(&poses[k]))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, per_configuration);

/// Nanoseconds at quantile `p` of sorted samples.
fn quantile(sorted: &[u64], p: f64) -> u64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Times `calls` individual calls of each query per pose set and prints median, p99 and max.
fn tails(calls: usize) {
    let mut w = Query::new();
    let sets = pose_sets(&w);
    let mut samples = vec![0u64; calls];
    for s in samples.iter_mut() {
        let t0 = Instant::now();
        *s = black_box(t0.elapsed()).as_nanos() as u64;
    }
    samples.sort_unstable();
    println!();
    println!("individual calls with Instant, a new pose every call [µs] (timer included: median {} ns)", quantile(&samples, 0.5));
    println!("  {:<30} {:>9} {:>9} {:>9}  sphere pairs in the band", "query", "median", "p99", "max");
    let us = |ns: u64| format!("{:.3}", ns as f64 / 1000.0);
    for (label, poses) in &sets {
        let near: usize = poses.iter().map(|q| w.near_count(q)).sum();
        let most = poses.iter().map(|q| w.near_count(q)).max().unwrap_or(0);
        for (name, op) in OPS {
            for k in 0..10_000 {
                black_box(op(&mut w, &poses[k % poses.len()]));
            }
            for (k, s) in samples.iter_mut().enumerate() {
                let q = black_box(&poses[k % poses.len()]);
                let t0 = Instant::now();
                black_box(op(&mut w, q));
                *s = t0.elapsed().as_nanos() as u64;
            }
            samples.sort_unstable();
            let extra =
                if name == "near" { format!("mean {:.1}, most {most}", near as f64 / poses.len() as f64) } else { String::new() };
            println!(
                "  {:<30} {:>9} {:>9} {:>9}  {extra}",
                format!("{name} {label}"),
                us(quantile(&samples, 0.5)),
                us(quantile(&samples, 0.99)),
                us(*samples.last().expect("non-empty")),
            );
        }
    }
}

fn main() {
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
    let benchmarking = std::env::args().any(|a| a == "--bench");
    tails(if benchmarking { 200_000 } else { 1_000 });
}
