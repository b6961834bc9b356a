//! Trajectory optimisation (eq. 4) and the online loop of Algorithm 1 on the study's four tasks, with
//! the study's planner (python/phri/sim/episode.py `Planner`: the JACO2 carrying the cup, features
//! ["efficiency", task], the full collision model against the task's scene with self-collision,
//! max_step from the velocity limits; see `phri_benches::study_planner`).
//!
//! Targets:
//! - cold plan from the straight line for the true weights, N = 31, with the full collision model:
//!   ≤ 2 ms median on each of the four tasks (issue 13);
//! - a replan after a correction — `Learner::observe` with a push (deform + update + warm replan),
//!   N = 31: ≤ 2 ms at p99 (issue 13; the `observe` rows of the timing pass);
//! - warm replan after one correction, N = 31: ≤ 1 ms median — from the converged plan for task
//!   weight 0 (with its coarse plans, `solve_levels`, as the learner replans), replan for the weight
//!   one update step later (0 → 0.3 × the true weight);
//! - the cold plan for N = 100: ≤ 4 × the N = 31 time. The true weights are the study's for 31
//!   waypoints (Φ sums over waypoints); on 100 the same task takes them rescaled by
//!   `FeatureSet::rescale_weights` (task weight × (30/99)²) and the collision weight by the same
//!   factor (`phri_benches::study_problem_at`). The tail rows also time the study's planner with
//!   the weights unscaled, which pose another trade-off on 100 waypoints (the task weighed 11 times
//!   more against efficiency).
//!
//! Criterion gives medians (of batch averages). A single repeated problem has no tail apart from
//! the machine, so after the criterion groups this binary times individual calls with `Instant` over
//! *varied* problems and prints median, p99 and max per case: cold solves repeated per task and N
//! (and at N = 100 with the study's weights unscaled);
//! warm replans from the converged plans for task weights {0, 0.2, 0.5} × true to that weight plus
//! {0.1, 0.3} × true and to the true weight (the learner's first push on the keep-out tasks jumps
//! straight to it), through the coarse levels and, for comparison, from the plan alone; and every
//! observe of 1 s pushes (10 samples at 10 Hz, each an update and a replan) starting at
//! t = 2, 4, 6, 8 s on fresh learners.
//!
//! The observe rows repeat the pushes with seed plans (`LearnerParams::seeds` = 5) and with a
//! per-call budget (`LearnerParams::replan_iterations` = 5): every call that does work (the pushes,
//! and the 1 kHz ticks that go on with an unfinished replan) is timed.
//!
//! `cargo bench -p phri_benches --bench trajopt`; under `cargo test --benches` each criterion
//! benchmark runs once and the timing pass runs one repetition.

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, BatchSize, BenchmarkId, Criterion, Throughput};
use phri_benches::{corrective_push, jaco2_with_cup, study_learner, study_planner, study_problem_at, study_tasks, StudyTask};
use phri_core::features::FeatureSet;
use phri_core::learner::LearnerParams;
use phri_core::trajopt::{PlanLevels, TrajectoryOptimizer, TrajoptInfo};
use phri_core::RobotModel;

const NQ: usize = 7;
/// Task weight after one update step from 0, as a fraction of the true weight (table: 0 → 0.3).
const ONE_STEP: f64 = 0.3;

fn solve(
    fs: &mut FeatureSet,
    opt: &mut TrajectoryOptimizer,
    task: &StudyTask,
    w: f64,
    init: Option<&[f64]>,
    out: &mut [f64],
) -> TrajoptInfo {
    opt.solve(fs, &[1.0, w], &task.start, &task.goal, init, out).expect("valid problem")
}

/// The same through the coarse levels (`solve_levels`), from `init` (None: cold).
fn solve_levels(
    fs: &mut FeatureSet,
    opt: &mut TrajectoryOptimizer,
    task: &StudyTask,
    w: f64,
    init: Option<&PlanLevels>,
    out: &mut PlanLevels,
) -> TrajoptInfo {
    opt.solve_levels(fs, &[1.0, w], &task.start, &task.goal, init, out).expect("valid problem")
}

fn cold(c: &mut Criterion) {
    let model = Arc::new(jaco2_with_cup());
    let mut group = c.benchmark_group("trajopt_cold");
    group.sample_size(20).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_millis(500));
    for n in [31, 100] {
        group.throughput(Throughput::Elements(n as u64));
        for task in study_tasks() {
            let (mut fs, mut opt, weights) = study_problem_at(&model, &task, n);
            let w = weights[1];
            let mut plan = vec![0.0; n * NQ];
            let info = solve(&mut fs, &mut opt, &task, w, None, &mut plan);
            eprintln!("cold {:>6} N={n:<3} {info:?}", task.name);
            group.bench_function(BenchmarkId::new(task.name, n), |b| {
                b.iter(|| solve(&mut fs, &mut opt, &task, black_box(w), None, &mut plan))
            });
        }
    }
    group.finish();
}

fn warm(c: &mut Criterion) {
    let model = Arc::new(jaco2_with_cup());
    let n = 31;
    let mut group = c.benchmark_group("trajopt_warm_one_step");
    group.throughput(Throughput::Elements(n as u64));
    for task in study_tasks() {
        let (mut fs, mut opt) = study_planner(&model, &task, n);
        let mut converged = opt.plan_levels();
        solve_levels(&mut fs, &mut opt, &task, 0.0, None, &mut converged);
        let mut plan = opt.plan_levels();
        let w = ONE_STEP * task.true_weight;
        let info = solve_levels(&mut fs, &mut opt, &task, w, Some(&converged), &mut plan);
        eprintln!("warm {:>6} 0 -> {w}: {info:?}", task.name);
        group.bench_function(task.name, |b| {
            b.iter(|| solve_levels(&mut fs, &mut opt, &task, black_box(w), Some(&converged), &mut plan))
        });
    }
    group.finish();
}

fn observe(c: &mut Criterion) {
    let model = Arc::new(jaco2_with_cup());
    let mut group = c.benchmark_group("learner_observe_push");
    group.sample_size(30).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_millis(500));
    for task in study_tasks() {
        let t = 4.0;
        // The first sample of a push on a fresh learner (task weight 0): deform, update, replan.
        let setup = || {
            let learner = study_learner(&model, &task, 31, LearnerParams::default());
            let tau = corrective_push(&model, &learner, &task, t);
            (learner, tau)
        };
        {
            let (mut l, tau) = setup();
            let obs = l.observe(t, &tau).expect("valid sample");
            assert!(obs.replanned, "{}: the push must trigger an update and a replan", task.name);
            let last = l.history().interactions.last().expect("recorded");
            eprintln!("observe {:>6}: weights {:?}, replan {:?}", task.name, last.weights, last.replan);
        }
        group.bench_function(task.name, |b| {
            b.iter_batched(setup, |(mut l, tau)| l.observe(black_box(t), &tau).expect("valid sample"), BatchSize::PerIteration)
        });
    }
    group.finish();
}

criterion_group!(benches, cold, warm, observe);

/// (median, p99, max) of durations, in milliseconds.
fn summary(samples: &mut [Duration]) -> (f64, f64, f64) {
    samples.sort_unstable();
    let q = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize].as_secs_f64() * 1e3;
    (q(0.5), q(0.99), q(1.0))
}

fn row(label: &str, samples: &mut [Duration], extra: &str) {
    let (median, p99, max) = summary(samples);
    println!("  {label:<26} {:>6} {median:>9.3} {p99:>9.3} {max:>9.3}  {extra}", samples.len());
}

/// Individual calls over varied problems: median, p99 and max per case.
fn tails(reps: usize) {
    let model: Arc<RobotModel> = Arc::new(jaco2_with_cup());
    println!();
    println!("individual calls with Instant over varied problems [ms] (the max also measures the machine)");
    println!("  {:<26} {:>6} {:>9} {:>9} {:>9}", "case", "calls", "median", "p99", "max");
    let mut cold31 = Vec::new();
    // N = 100 with the weights and the collision weight rescaled (the task's plan on 100
    // waypoints), then the study's planner with its weights for 31 unscaled: they weigh the task
    // (99/30)² ≈ 11 times more against efficiency, a harder problem.
    for (n, rescaled) in [(31, true), (100, true), (100, false)] {
        for task in study_tasks() {
            let (mut fs, mut opt, w) = if rescaled {
                let (fs, opt, weights) = study_problem_at(&model, &task, n);
                (fs, opt, weights[1])
            } else {
                let (fs, opt) = study_planner(&model, &task, n);
                (fs, opt, task.true_weight)
            };
            let mut plan = vec![0.0; n * NQ];
            let mut samples = Vec::new();
            let mut info = None;
            for _ in 0..reps.max(1) * 5 {
                let t0 = Instant::now();
                info = Some(solve(&mut fs, &mut opt, &task, w, None, &mut plan));
                samples.push(t0.elapsed());
            }
            if n == 31 {
                cold31.extend_from_slice(&samples);
            }
            let info = info.expect("solved");
            let feasible = if info.feasible { "feasible" } else { "INFEASIBLE" };
            let extra = format!(
                "{} + {} coarse iterations, {} evaluations, {feasible}",
                info.iterations, info.coarse_iterations, info.evaluations
            );
            let label = if rescaled { format!("cold {} N={n}", task.name) } else { format!("cold {} N={n} unscaled", task.name) };
            row(&label, &mut samples, &extra);
        }
        if n == 31 {
            row("cold all tasks N=31", &mut cold31, "");
        }
    }
    let n = 31;
    for through_levels in [true, false] {
        let label = if through_levels { "warm" } else { "warm, plan only" };
        let mut warm_all = Vec::new();
        for task in study_tasks() {
            let (mut fs, mut opt) = study_planner(&model, &task, n);
            let mut samples = Vec::new();
            let (mut iterations, mut coarse, mut worst) = (0, 0, 0);
            for from in [0.0, 0.2, 0.5] {
                let w0 = from * task.true_weight;
                let mut converged = opt.plan_levels();
                solve_levels(&mut fs, &mut opt, &task, w0, None, &mut converged);
                for w in [w0 + 0.1 * task.true_weight, w0 + ONE_STEP * task.true_weight, task.true_weight] {
                    let mut out = opt.plan_levels();
                    let mut plan = vec![0.0; n * NQ];
                    for _ in 0..reps.max(1) * 10 {
                        let t0 = Instant::now();
                        let info = if through_levels {
                            solve_levels(&mut fs, &mut opt, &task, w, Some(&converged), &mut out)
                        } else {
                            solve(&mut fs, &mut opt, &task, w, Some(converged.plan()), &mut plan)
                        };
                        samples.push(t0.elapsed());
                        iterations += info.iterations;
                        coarse += info.coarse_iterations;
                        worst = worst.max(info.iterations);
                    }
                }
            }
            let calls = samples.len() as f64;
            let extra =
                format!("mean {:.1} + {:.1} coarse iterations, worst {worst}", iterations as f64 / calls, coarse as f64 / calls);
            row(&format!("{label} {}", task.name), &mut samples, &extra);
            warm_all.extend_from_slice(&samples);
        }
        row(&format!("{label} all tasks"), &mut warm_all, "");
    }
    let variants = [
        ("", LearnerParams::default()),
        (" seeds 5", LearnerParams { seeds: SEEDS, ..Default::default() }),
        (" budget 5", LearnerParams { replan_iterations: REPLAN_BUDGET, ..Default::default() }),
    ];
    for (label, params) in variants {
        observe_rows(&model, label, &params, reps);
    }
}

/// Seed plans per learned weight in the seeded rows (`LearnerParams::seeds`).
const SEEDS: usize = 5;

/// One second of 1 kHz ticks from each of t0 = 2, 4, 6, 8 s on fresh learners with `params`, a
/// corrective push at every 10 Hz sample: times every `observe` call that replanned (the pushes, and
/// with a budget the ticks that go on with an unfinished replan, until it converges).
fn observe_rows(model: &Arc<RobotModel>, label: &str, params: &LearnerParams, reps: usize) {
    let mut all = Vec::new();
    for task in study_tasks() {
        let mut samples = Vec::new();
        let mut longest = 0;
        for _ in 0..reps.max(1) {
            for t0 in [2.0, 4.0, 6.0, 8.0] {
                let mut learner = study_learner(model, &task, 31, params.clone());
                let (mut k, mut pending_ticks) = (0usize, 0);
                while k < 1000 || learner.replan_pending() {
                    let t = t0 + 1e-3 * k as f64;
                    let pushing = k < 1000 && k.is_multiple_of(100);
                    let tau = if pushing { corrective_push(model, &learner, &task, t) } else { [0.0; NQ] };
                    let began = Instant::now();
                    let obs = learner.observe(t, &tau).expect("valid sample");
                    let elapsed = began.elapsed();
                    if obs.replanned {
                        samples.push(elapsed);
                    }
                    pending_ticks = if learner.replan_pending() { pending_ticks + 1 } else { 0 };
                    longest = longest.max(pending_ticks);
                    k += 1;
                }
            }
        }
        let extra = format!("{} replanning calls; a replan spans up to {} ticks", samples.len(), longest + 1);
        row(&format!("observe {}{label}", task.name), &mut samples, &extra);
        all.extend_from_slice(&samples);
    }
    row(&format!("observe all{label}"), &mut all, "");
}

/// Newton iterations per `observe` call in the budgeted rows (`LearnerParams::replan_iterations`).
const REPLAN_BUDGET: usize = 5;

fn main() {
    benches();
    criterion::Criterion::default().configure_from_args().final_summary();
    let benchmarking = std::env::args().any(|a| a == "--bench");
    tails(if benchmarking { 3 } else { 0 });
}
