//! The per-tick paths allocate nothing: a counting global allocator proves it.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use phri_core::impedance::{Gain, ImpedanceController, ImpedanceParams};
use phri_core::interaction::{InteractionDetector, JACO2_THRESHOLDS};
use phri_core::reference::{Interpolation, TimedTrajectory};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn a_control_tick_allocates_nothing() {
    let model = Arc::new(common::jaco2());
    let params = ImpedanceParams { inertia: Some(Gain::Diagonal(vec![0.5; 7])), ..ImpedanceParams::jaco2_default() };
    let mut controller = ImpedanceController::new(model, params).unwrap();
    let waypoints: Vec<f64> = (0..31 * 7).map(|i| 3.0 + 0.01 * (i as f64).sin()).collect();
    let plan = TimedTrajectory::new(waypoints.clone(), 7, 15.0, Interpolation::Cubic).unwrap();
    let mut plan2 = plan.clone();
    let detector = InteractionDetector::new(JACO2_THRESHOLDS.to_vec(), None).unwrap();
    let (mut q_ref, mut qd_ref, mut qdd_ref, mut tau, mut u_h) = ([0.0; 7], [0.0; 7], [0.0; 7], [0.0; 7], [0.0; 7]);
    let q = [3.0; 7];
    let qd = [0.01; 7];
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    for k in 0..10_000 {
        let t = k as f64 * 1e-3;
        plan.sample(t, &mut q_ref, &mut qd_ref, &mut qdd_ref);
        detector.detect(&[0.5, 9.0, 0.0, 0.0, 0.0, 0.0, 0.0], &mut u_h).unwrap();
        controller.torque(&q, &qd, &q_ref, &qd_ref, &mut tau).unwrap();
        controller.torque_full(&q, &qd, &q_ref, &qd_ref, &qdd_ref, &u_h, &mut tau).unwrap();
        controller.torque_implicit(&q, &qd, &q_ref, &qd_ref, 1e-3, &mut tau).unwrap();
        if k % 100 == 0 {
            plan2.set_waypoints(&waypoints).unwrap();
        }
    }
    let after = ALLOCATIONS.load(Ordering::SeqCst);
    assert_eq!(after - before, 0, "the control tick allocated {} times", after - before);
    assert!(tau.iter().all(|v| v.is_finite()));
}
