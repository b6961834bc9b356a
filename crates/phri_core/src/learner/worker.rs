//! The replan worker: a thread that owns the [`Planner`] (the optimiser, the seed plans and the
//! warm start) and solves the newest correction's replan while the control thread keeps ticking.
//!
//! Handover is by two single-slot mailboxes, each a mutex held only to copy a few hundred numbers:
//! the control side posts a request (generation, the generation of the plan it tracks, the new
//! weights) and collects the result for the newest generation. In hardware mode it only
//! `try_lock`s them (a busy slot is tried again at the next tick), so a tick never waits on the
//! worker; in simulated mode it may wait, which is the point there. Posting bumps the shared
//! generation counter first, which cancels a solve still running for an older request at its
//! next Newton iteration ([`Cancellation`]); the worker posts only results that are still the
//! newest. The worker allocates each result's plan, so that adopting it allocates nothing on the
//! control thread.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, TryLockError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::planner::Planner;
use crate::error::{PhriError, Result};
use crate::trajopt::{Cancellation, PlanLevels, TrajoptInfo};

/// How long dropping a learner waits for its worker to stop before leaving the thread to end on
/// its own [s]: a running solve stops at its next Newton iteration (well under a millisecond),
/// so only a worker stuck in a bug is left behind.
const SHUTDOWN_WAIT: Duration = Duration::from_secs(2);

/// While a simulated-mode `observe` waits for a result, how often it checks that the worker
/// still runs.
const LIVENESS_CHECK: Duration = Duration::from_millis(20);

/// A stalled worker (test hook) checks this often whether it is being shut down.
const STALL_STEP: Duration = Duration::from_millis(5);

/// A spinning worker looks at the clock (and yields its core once) every this many checks for a
/// request.
const SPINS_PER_CLOCK: u32 = 256;

/// What a replan came to.
#[derive(Debug)]
pub(super) enum Outcome {
    /// A feasible plan, N × n row-major (allocated by the worker).
    Feasible { plan: Vec<f64>, info: TrajoptInfo },
    /// An infeasible plan, and why.
    Infeasible { info: TrajoptInfo, reason: String },
    /// The solve failed with an error, or the worker panicked ([`PhriError::ReplanWorker`]).
    Failed(PhriError),
}

/// A replan request.
#[derive(Debug, Clone)]
struct Request {
    /// Its generation (1, 2, ...; 0 is the initial plan).
    generation: u64,
    /// Generation of the plan the robot tracks when it was made: the warm start.
    base: u64,
    weights: Vec<f64>,
}

/// The result slot: the outcome of request `generation`, until collected.
struct Posted {
    generation: u64,
    outcome: Option<Outcome>,
}

/// What the control side and the worker share.
struct Shared {
    /// Generation of the newest request: a solve of any other stops ([`Cancellation`]).
    latest: Arc<AtomicU64>,
    /// Generation of the request in the request slot, stored once the slot holds it: what a
    /// spinning worker watches.
    delivered: AtomicU64,
    request: Mutex<Request>,
    result: Mutex<Posted>,
    /// Signalled when a result is posted.
    posted: Condvar,
    shutdown: AtomicBool,
    /// Test hooks: stall the next solve this long [ns]; panic in the next solve.
    stall_nanos: AtomicU64,
    panic_next: AtomicBool,
}

/// Locks `m`, taking over a mutex poisoned by a panic elsewhere (the slots hold plain data that
/// every writer leaves whole).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Locks `m` if it is free now.
fn try_lock<T>(m: &Mutex<T>) -> Option<MutexGuard<'_, T>> {
    match m.try_lock() {
        Ok(g) => Some(g),
        Err(TryLockError::Poisoned(e)) => Some(e.into_inner()),
        Err(TryLockError::WouldBlock) => None,
    }
}

/// The control side's handle on the worker thread.
pub(super) struct ReplanWorker {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    /// Generation of the last request posted (or cancelled).
    posted: u64,
    /// The newest request, until the request slot has taken it (hardware mode: the slot may be
    /// busy at one tick).
    outbox: Request,
    undelivered: bool,
}

impl ReplanWorker {
    /// Starts the worker with `planner` (whose warm start is the initial plan, generation 0), for
    /// `k` weights; it busy-waits `spin` for each next request before it sleeps
    /// (`LearnerParams::worker_spin`).
    pub(super) fn spawn(planner: Planner, k: usize, spin: Duration) -> Result<Self> {
        let request = Request { generation: 0, base: 0, weights: vec![0.0; k] };
        let shared = Arc::new(Shared {
            latest: Arc::new(AtomicU64::new(0)),
            delivered: AtomicU64::new(0),
            request: Mutex::new(request.clone()),
            result: Mutex::new(Posted { generation: 0, outcome: None }),
            posted: Condvar::new(),
            shutdown: AtomicBool::new(false),
            stall_nanos: AtomicU64::new(0),
            panic_next: AtomicBool::new(false),
        });
        let worker = Worker::new(shared.clone(), planner, k, spin);
        let thread = std::thread::Builder::new()
            .name("phri-replan".into())
            .spawn(move || worker.run())
            .map_err(|e| PhriError::ReplanWorker { reason: format!("the replan worker thread could not start: {e}") })?;
        Ok(ReplanWorker { shared, thread: Some(thread), posted: 0, outbox: request, undelivered: false })
    }

    /// Posts a replan for `weights` warm-started from the plan of generation `base` (the one the
    /// robot tracks) and returns its generation. A solve still running for an older request stops.
    /// With `block` false it never waits: if the slot is busy, the request goes out at a later
    /// call. Allocates nothing.
    pub(super) fn request(&mut self, weights: &[f64], base: u64, block: bool) -> u64 {
        self.posted += 1;
        self.shared.latest.store(self.posted, Ordering::Release);
        self.outbox.generation = self.posted;
        self.outbox.base = base;
        self.outbox.weights.copy_from_slice(weights);
        self.undelivered = true;
        self.deliver(block);
        self.posted
    }

    /// Cancels whatever the worker is solving: no result of a request made so far will be
    /// collected.
    pub(super) fn cancel(&mut self) {
        self.posted += 1;
        self.shared.latest.store(self.posted, Ordering::Release);
        self.undelivered = false;
    }

    /// Hands the outbox to the worker if it has not taken it yet.
    fn deliver(&mut self, block: bool) {
        if !self.undelivered {
            return;
        }
        let slot = if block { Some(lock(&self.shared.request)) } else { try_lock(&self.shared.request) };
        let Some(mut slot) = slot else { return };
        slot.generation = self.outbox.generation;
        slot.base = self.outbox.base;
        slot.weights.copy_from_slice(&self.outbox.weights);
        drop(slot);
        self.shared.delivered.store(self.outbox.generation, Ordering::Release);
        self.undelivered = false;
        if let Some(thread) = &self.thread {
            thread.thread().unpark();
        }
    }

    /// The outcome of request `generation` if the worker has posted it (taken out of the slot),
    /// or with `block` once it has; a worker that stopped gives [`Outcome::Failed`]. Without
    /// `block` it never waits. Allocates nothing.
    pub(super) fn collect(&mut self, generation: u64, block: bool) -> Option<Outcome> {
        self.deliver(block);
        let slot = if block { Some(lock(&self.shared.result)) } else { try_lock(&self.shared.result) };
        let mut slot = slot?;
        loop {
            if slot.generation == generation {
                if let Some(outcome) = slot.outcome.take() {
                    return Some(outcome);
                }
            }
            if self.thread.as_ref().is_none_or(JoinHandle::is_finished) {
                let reason = "the replan worker thread stopped; the arm keeps its plan".to_string();
                return Some(Outcome::Failed(PhriError::ReplanWorker { reason }));
            }
            if !block {
                return None;
            }
            slot = match self.shared.posted.wait_timeout(slot, LIVENESS_CHECK) {
                Ok((slot, _)) => slot,
                Err(e) => e.into_inner().0,
            };
        }
    }

    /// Test hook: the worker's next solve first stalls for `duration`.
    pub(super) fn stall(&self, duration: Duration) {
        self.shared.stall_nanos.store(duration.as_nanos().min(u64::MAX as u128) as u64, Ordering::Release);
    }

    /// Test hook: the worker's next solve panics.
    pub(super) fn panic_next(&self) {
        self.shared.panic_next.store(true, Ordering::Release);
    }
}

impl Drop for ReplanWorker {
    /// Stops the worker (a running solve stops at its next iteration) and joins it; a worker that
    /// does not stop within [`SHUTDOWN_WAIT`] is left to end on its own (it holds nothing the
    /// learner needs), so dropping never hangs.
    fn drop(&mut self) {
        self.shared.shutdown.store(true, Ordering::Release);
        self.shared.latest.store(u64::MAX, Ordering::Release);
        let Some(thread) = self.thread.take() else { return };
        thread.thread().unpark();
        let began = Instant::now();
        while !thread.is_finished() && began.elapsed() < SHUTDOWN_WAIT {
            std::thread::sleep(Duration::from_micros(200));
        }
        if thread.is_finished() {
            // The worker catches panics in solves; anything else it could return is ().
            let _ = thread.join();
        }
    }
}

/// The worker thread's state.
struct Worker {
    shared: Arc<Shared>,
    planner: Planner,
    /// The last feasible result, until the control side adopts it (`Request::base` says so) or a
    /// newer one replaces it, and its generation.
    candidate: PlanLevels,
    candidate_generation: Option<u64>,
    /// Generation of the plan in `planner.levels` (the warm start).
    levels_generation: u64,
    weights: Vec<f64>,
    /// How long to busy-wait for a request before sleeping.
    spin: Duration,
}

impl Worker {
    fn new(shared: Arc<Shared>, planner: Planner, k: usize, spin: Duration) -> Self {
        let candidate = planner.levels.clone();
        Worker { shared, planner, candidate, candidate_generation: None, levels_generation: 0, weights: vec![0.0; k], spin }
    }

    /// Waits for a request newer than `taken`: busy until `spin` after `idle_since` (the end of
    /// the last job, yielding the core now and then to whatever else is runnable), then asleep
    /// until the control side unparks it. May return early (a wake-up token left by a request the
    /// spin already saw, shutdown); the caller looks again, and spins no longer than the deadline.
    fn wait(&self, taken: u64, idle_since: Instant) {
        let mut spins = 0u32;
        while !self.spin.is_zero() {
            if self.shared.delivered.load(Ordering::Acquire) > taken || self.shared.shutdown.load(Ordering::Acquire) {
                return;
            }
            std::hint::spin_loop();
            spins += 1;
            if spins == SPINS_PER_CLOCK {
                spins = 0;
                if idle_since.elapsed() >= self.spin {
                    break;
                }
                std::thread::yield_now();
            }
        }
        std::thread::park();
    }

    fn run(mut self) {
        let mut taken = 0;
        let mut idle_since = Instant::now();
        while !self.shared.shutdown.load(Ordering::Acquire) {
            let job = {
                let slot = lock(&self.shared.request);
                (slot.generation > taken).then(|| {
                    self.weights.copy_from_slice(&slot.weights);
                    (slot.generation, slot.base)
                })
            };
            let Some((generation, base)) = job else {
                self.wait(taken, idle_since);
                continue;
            };
            taken = generation;
            idle_since = Instant::now();
            if self.shared.latest.load(Ordering::Acquire) != generation {
                continue; // superseded before it started
            }
            let outcome = match catch_unwind(AssertUnwindSafe(|| self.solve(generation, base))) {
                Ok(outcome) => outcome,
                Err(payload) => {
                    let message = payload
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| payload.downcast_ref::<String>().cloned())
                        .unwrap_or_else(|| "no message".into());
                    // A panic inside the solve leaves `levels` and `candidate` as they were (it
                    // writes only `replanned`); the next request starts from them as usual.
                    let reason = format!("the replan worker panicked (a bug in phri; please report it): {message}");
                    Some(Outcome::Failed(PhriError::ReplanWorker { reason }))
                }
            };
            let Some(outcome) = outcome else { continue };
            if self.shared.latest.load(Ordering::Acquire) != generation {
                continue; // superseded meanwhile: only the newest result can be adopted
            }
            let mut slot = lock(&self.shared.result);
            slot.generation = generation;
            slot.outcome = Some(outcome);
            drop(slot);
            self.shared.posted.notify_all();
            if self.candidate_generation == Some(generation) {
                // The next replan likely starts from this plan: its cost, ahead of the request.
                // (A failure here fails that replan's own evaluation too, and is reported there.)
                let _ = self.planner.prime(self.candidate.plan());
            }
            idle_since = Instant::now();
        }
    }

    /// Solves request `generation` warm-started from the plan of generation `base`; `None` if it
    /// was superseded before the end.
    fn solve(&mut self, generation: u64, base: u64) -> Option<Outcome> {
        self.rebase(base);
        self.inject_faults();
        self.planner.set_cancellation(Some(Cancellation::new(self.shared.latest.clone(), generation)));
        let result = self.planner.solve(&self.weights);
        if self.shared.latest.load(Ordering::Acquire) != generation {
            return None;
        }
        Some(match result {
            Err(e) => Outcome::Failed(e),
            Ok(info) if info.feasible => {
                self.planner.hold(&mut self.candidate);
                self.candidate_generation = Some(generation);
                Outcome::Feasible { plan: self.candidate.plan().to_vec(), info }
            }
            Ok(info) => Outcome::Infeasible { reason: self.planner.infeasibility(&info), info },
        })
    }

    /// Makes the plan of generation `base` the warm start: the candidate if the control side
    /// adopted it since, the initial plan after a reset, else the plan already there.
    fn rebase(&mut self, base: u64) {
        if base == self.levels_generation {
            return;
        }
        if self.candidate_generation == Some(base) {
            self.planner.promote(&mut self.candidate);
            self.candidate_generation = None;
        } else {
            // Generation 0: the initial plan (after `Learner::reset`). The control side adopts only
            // results of the worker, so no other generation can be asked for.
            self.planner.restart();
        }
        self.levels_generation = base;
    }

    /// The test hooks: a stall (cut short by shutdown), then a panic.
    fn inject_faults(&self) {
        let stall = Duration::from_nanos(self.shared.stall_nanos.swap(0, Ordering::AcqRel));
        let began = Instant::now();
        while began.elapsed() < stall && !self.shared.shutdown.load(Ordering::Acquire) {
            std::thread::sleep(STALL_STEP.min(stall - began.elapsed().min(stall)));
        }
        if self.shared.panic_next.swap(false, Ordering::AcqRel) {
            panic!("injected by Learner::debug_panic_worker");
        }
    }
}
