//! The per-tick paths allocate nothing: a counting global allocator proves it. It counts only on
//! the measuring thread: the test harness's own threads, and the learner's replan worker, allocate
//! whenever they like.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::Arc;

use phri_core::impedance::{Gain, ImpedanceController, ImpedanceParams};
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use phri_core::learner::{Learner, LearnerParams, ReplanLatency};
use phri_core::reference::{Interpolation, TimedTrajectory};
use phri_core::safety::{SafetyLayer, SafetyLimits, SafetyParams, ToolBox};
use phri_core::wall::{VirtualWall, WallParams};

struct Counting;

thread_local! {
    /// Whether allocations on this thread are counted, and how many were (const-initialised:
    /// reading them allocates nothing; per thread, so tests running side by side do not mix).
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Builds everything a tick needs up front, so the measured loop holds nothing but tick work.
fn learner() -> Learner {
    learner_with(ReplanLatency::default())
}

/// The table task's learner sampling every tick, replanning as `latency` says.
fn learner_with(latency: ReplanLatency) -> Learner {
    let params = LearnerParams { sample_period: 1e-3, replan_latency: latency, ..Default::default() };
    common::table_learner(Arc::new(common::jaco2()), params)
}

#[test]
fn a_control_tick_allocates_nothing() {
    let mut learner = learner();
    let model = Arc::new(common::jaco2());
    let params = ImpedanceParams { inertia: Some(Gain::Diagonal(vec![0.5; 7])), ..ImpedanceParams::jaco2_default() };
    let mut controller = ImpedanceController::new(model, params).unwrap();
    // The same law with the virtual wall, at a pose where it acts (a table raised under the arm).
    let carrying = Arc::new(common::jaco2_with_cup());
    let mut walled = ImpedanceController::new(carrying.clone(), ImpedanceParams::jaco2_default()).unwrap();
    let table = phri_core::scene::SceneObject::new(
        "table",
        phri_core::scene::Shape::Plane,
        nalgebra::Isometry3::translation(0.0, 0.0, 0.2),
        0.02,
        phri_core::scene::ObjectKind::Furniture,
    )
    .unwrap();
    let scene = phri_core::scene::Scene::new(vec![table]).unwrap();
    walled
        .set_wall(Some(VirtualWall::new(&carrying, &scene, WallParams { band: 1.0, ..WallParams::default() }).unwrap()))
        .unwrap();
    let waypoints: Vec<f64> = (0..31 * 7).map(|i| 3.0 + 0.01 * (i as f64).sin()).collect();
    let plan = TimedTrajectory::new(waypoints.clone(), 7, 15.0, Interpolation::Cubic).unwrap();
    let mut plan2 = plan.clone();
    let shifted: Vec<f64> = waypoints.iter().map(|v| v + 0.1).collect();
    let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
    // The safety layer with every check on: a tool box, the rate limit, and (for an arm that
    // compensates gravity) g(q) subtracted from the command.
    let tool = carrying.frame_id("j2s7s300_end_effector").unwrap();
    let limits = SafetyLimits {
        position_lower: carrying.lower_limits(),
        position_upper: carrying.upper_limits(),
        velocity: carrying.velocity_limits(),
        torque: carrying.effort_limits(),
        torque_rate: vec![1000.0; 7],
        tool_box: Some(ToolBox { lower: [-2.0; 3], upper: [2.0; 3] }),
    };
    let mut safety =
        SafetyLayer::new(carrying.clone(), tool, limits, SafetyParams { gravity_compensated: true, ..SafetyParams::default() })
            .unwrap();
    safety.reset(Some(&[0.0; 7])).unwrap();
    let mut command = [0.0; 7];
    let (mut q_ref, mut qd_ref, mut qdd_ref, mut tau, mut u_h) = ([0.0; 7], [0.0; 7], [0.0; 7], [0.0; 7], [0.0; 7]);
    let q = [3.0; 7];
    let qd = [0.01; 7];
    COUNTING.with(|c| c.set(true));
    let before = ALLOCATIONS.with(Cell::get);
    for k in 0..10_000 {
        let t = k as f64 * 1e-3;
        plan.sample(t, &mut q_ref, &mut qd_ref, &mut qdd_ref);
        // Algorithm 1's per-tick path with nobody touching the arm, sampling every tick.
        let obs = learner.observe(t, &[0.5, 1.0, 0.0, 0.3, 0.2, 0.1, 0.0]).unwrap();
        assert!(obs.sampled && !obs.interacted);
        learner.reference(t, &mut q_ref, &mut qd_ref, &mut qdd_ref);
        detector.detect(&[0.5, 9.0, 0.0, 0.0, 0.0, 0.0, 0.0], &mut u_h).unwrap();
        controller.torque(&q, &qd, &q_ref, &qd_ref, &mut tau).unwrap();
        controller.torque_full(&q, &qd, &q_ref, &qd_ref, &qdd_ref, &u_h, &mut tau).unwrap();
        controller.torque_implicit(&q, &qd, &q_ref, &qd_ref, 1e-3, &mut tau).unwrap();
        let status = walled.torque_implicit(&q, &qd, &q_ref, &qd_ref, 1e-3, &mut tau).unwrap();
        assert!(status.wall.force > 0.0);
        // The safety layer's two checks, as the loop calls them.
        assert!(safety.check_state(t, &q, &qd, &u_h).unwrap().is_ok());
        assert!(safety.limit_torque(&q, &mut tau, &mut command).unwrap().is_ok());
        if k % 100 == 0 {
            plan2.set_waypoints(&waypoints).unwrap();
        }
        if k % 100 == 50 {
            // A replan's switch: blended into a plan 0.1 rad away, within 0.5 rad/s.
            plan2.switch_to(&shifted, t, &[0.5; 7]).unwrap();
        }
    }
    let after = ALLOCATIONS.with(Cell::get);
    COUNTING.with(|c| c.set(false));
    assert_eq!(after - before, 0, "the control tick allocated {} times", after - before);
    assert!(tau.iter().all(|v| v.is_finite()));
}

/// Allocations on this thread during `f`.
fn allocations<T>(f: impl FnOnce() -> T) -> (T, usize) {
    COUNTING.with(|c| c.set(true));
    let before = ALLOCATIONS.with(Cell::get);
    let value = f();
    let after = ALLOCATIONS.with(Cell::get);
    COUNTING.with(|c| c.set(false));
    (value, after - before)
}

#[test]
fn forward_dynamics_allocates_nothing() {
    // A simulated arm's step: q̈ from the torque, with the work matrix made once.
    let model = common::jaco2();
    let mut data = model.data();
    let mut mass = nalgebra::DMatrix::zeros(7, 7);
    let (q, qd, tau) = ([0.1, 2.9, 0.2, 1.3, -2.0, 1.5, 0.4], [0.3; 7], [1.0; 7]);
    let mut qdd = [0.0; 7];
    let (_, count) = allocations(|| {
        for _ in 0..1000 {
            model.forward_dynamics(&q, &qd, &tau, &mut data, &mut mass, &mut qdd).unwrap();
        }
    });
    assert_eq!(count, 0, "forward_dynamics allocated {count} times in 1000 calls");
}

#[test]
fn the_simulated_loops_ticks_allocate_nothing() {
    // The native episode's ticks with a push (below the detector's thresholds): the read, the
    // safety checks, observe, reference, the implicit law, the limits, the step and the log rows
    // (made for the whole motion at the start).
    use phri_core::sim::{LoopSettings, SimulatedArm, SimulatedLoop};
    let mut learner = learner();
    let carrying = Arc::new(common::jaco2_with_cup());
    let mut controller = ImpedanceController::new(carrying.clone(), ImpedanceParams::jaco2_default()).unwrap();
    let tool = carrying.frame_id("j2s7s300_end_effector").unwrap();
    let limits = SafetyLimits {
        position_lower: vec![f64::NEG_INFINITY; 7],
        position_upper: vec![f64::INFINITY; 7],
        velocity: vec![10.0; 7],
        torque: carrying.effort_limits(),
        torque_rate: vec![1e4; 7],
        tool_box: None,
    };
    let mut safety = SafetyLayer::new(carrying.clone(), tool, limits, SafetyParams::default()).unwrap();
    let arm = SimulatedArm::new(carrying.clone(), 1e-3, 9.81, &[0.0; 7]).unwrap();
    let settings = LoopSettings { duration: 2.0, hold_time: 0.5, log_period: 0.01, sample_every: 1, hand: tool };
    let start = learner.plan().waypoints()[..7].to_vec();
    let mut sim = SimulatedLoop::new(arm, settings, &start, &mut safety).unwrap();
    let offsets = vec![0.01; 20 * 7];
    let push = [0.5, 0.0, 0.2, 0.0, 0.0, 0.0];
    let (_, count) = allocations(|| {
        while !sim.done() {
            let until = sim.tick() + 20;
            let rows = sim.samples_before(until) as usize * 7;
            sim.advance(until, Some(&push), &offsets[..rows], &mut learner, &mut controller, &mut safety).unwrap();
        }
    });
    assert_eq!(sim.ticks(), 2001);
    assert!(sim.stop().is_none() && sim.log().rows() == 201);
    assert_eq!(count, 0, "the simulated loop allocated {count} times in 2001 ticks");
}

#[test]
fn with_a_replan_worker_only_ticks_that_record_a_push_allocate() {
    // A push on joint 2 (threshold 8 N·m): deform, update, and a replan handed to the worker.
    let push = [0.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for latency in [ReplanLatency::Fixed(0.005), ReplanLatency::WallClock] {
        let mut learner = learner_with(latency);
        let (mut q_ref, mut qd_ref, mut qdd_ref) = ([0.0; 7], [0.0; 7], [0.0; 7]);
        let (mut adoptions, mut quiet_ticks, mut k) = (0, 0, 1000);
        // Two single pushes, then two on consecutive ticks (the second supersedes the first's replan).
        for pushes in [[1000, 1000], [3000, 3000], [5000, 5001]] {
            if pushes[0] == 5000 {
                // Held up, the worker cannot finish the first replan before the second push (with
                // the simulated latency, the tick the plan is due waits for it).
                learner.debug_stall_worker(0.2).unwrap();
            }
            while k <= pushes[1] || learner.replan_pending() {
                // The robot's clock; it stays at 14 s if a loaded machine makes the worker slow.
                let t = (k as f64 * 1e-3).min(14.0);
                let tau = if pushes.contains(&k) { push } else { [0.0; 7] };
                let (obs, count) = allocations(|| {
                    let obs = learner.observe(t, &tau).unwrap();
                    learner.reference(t, &mut q_ref, &mut qd_ref, &mut qdd_ref);
                    obs
                });
                if obs.interacted {
                    assert!(learner.replan_pending(), "{latency:?}: the push at tick {k} asked for a replan");
                } else {
                    assert_eq!(count, 0, "{latency:?}: tick {k} (adopted: {}) allocated {count} times", obs.adopted);
                    quiet_ticks += 1;
                }
                adoptions += usize::from(obs.adopted);
                k += 1;
                if latency == ReplanLatency::WallClock {
                    std::thread::sleep(std::time::Duration::from_micros(100));
                }
            }
        }
        assert_eq!(adoptions, 3, "{latency:?}: one plan per push, the superseded one excepted");
        assert_eq!(learner.superseded_replans(), 1);
        assert!(quiet_ticks > 4000, "{quiet_ticks}");
        assert!(q_ref.iter().all(|v| v.is_finite()));
    }
}
