//! The replan worker: a thread that owns the learning (the weights, the belief and the update
//! rule, [`Learning`]) and the [`Planner`] (the optimiser, the seed plans and the warm start). It
//! learns from every correction in the order they came and solves the newest one's replan while
//! the control thread keeps ticking: the control tick only detects and deforms.
//!
//! Handover is by two mailboxes, each a mutex held only to move a few buffers: the control side
//! queues corrections (each with its generation and its record, the generation of the plan it
//! tracks) and collects what the worker learned from them and the replan result for the newest
//! generation. In hardware mode it only `try_lock`s them (a busy slot is tried again at the next
//! tick), so a tick never waits on the worker; in simulated mode it may wait, which is the point
//! there. Posting bumps the shared generation counter first, which cancels a solve still running
//! for an older request at its next Newton iteration ([`Cancellation`]); the worker posts only
//! results that are still the newest, but what it learned from every correction. The worker
//! allocates each result's plan and records, so that taking them in allocates nothing on the
//! control thread.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, TryLockError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::learning::{Correction, Learned, Learning};
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

/// Corrections the request slot and each side's queue hold. A new correction stops a running
/// solve at its next Newton iteration, and the worker then takes the slot's: only a worker held up
/// (a stall, the machine) for QUEUE sample periods fills the slot. Then a simulated-mode tick waits
/// for it to take them, and a hardware-mode tick keeps them in its own queue, which grows beyond
/// QUEUE rather than waits.
pub(super) const QUEUE: usize = 16;

/// While the slot is full, how long a simulated-mode request waits before it looks again.
const QUEUE_WAIT: Duration = Duration::from_micros(20);

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
    /// The newest correction's learning failed (its [`Taught`] says why) and the weights are
    /// those the tracked plan was made for: no replan.
    Unlearned,
}

/// What the worker learned from one correction.
#[derive(Debug)]
pub(super) struct Taught {
    /// The correction's record in `History::interactions`.
    pub(super) record: usize,
    pub(super) learned: Result<Learned>,
}

/// A correction waiting for the worker.
#[derive(Debug, Clone)]
struct Queued {
    correction: Correction,
    generation: u64,
    record: usize,
}

/// Corrections for the worker, oldest first, in buffers sized once.
#[derive(Debug, Clone)]
struct Request {
    /// Generation of the newest correction in or through the slot (1, 2, ...; 0 is the initial
    /// plan); a reset moves it on too.
    generation: u64,
    /// Generation of the plan the robot tracks when the newest was made: the warm start.
    base: u64,
    /// Resets so far: the worker starts its learning again when it sees a new one.
    epoch: u64,
    /// `queue[..queued]` wait, oldest first; the rest are spare buffers.
    queue: Vec<Queued>,
    queued: usize,
}

impl Request {
    fn new(m: usize, n: usize) -> Self {
        let spare = Queued { correction: Correction::new(m, n), generation: 0, record: 0 };
        Request { generation: 0, base: 0, epoch: 0, queue: vec![spare; QUEUE], queued: 0 }
    }

    /// Moves as many of `from`'s queued corrections as fit to the end of this one's (buffers are
    /// swapped, not copied); returns how many.
    fn take_from(&mut self, from: &mut Request) -> usize {
        let moved = from.queued.min(self.queue.len() - self.queued);
        for i in 0..moved {
            std::mem::swap(&mut self.queue[self.queued + i], &mut from.queue[i]);
        }
        self.queued += moved;
        // The rest move to the front, oldest first.
        from.queue.rotate_left(moved);
        from.queued -= moved;
        moved
    }
}

/// The result slot: the outcome of request `generation`, until collected, and what the worker
/// learned from the corrections since the last collection.
struct Posted {
    generation: u64,
    outcome: Option<Outcome>,
    /// The epoch the control side is in: the worker posts nothing learned in another.
    epoch: u64,
    taught: Vec<Taught>,
}

/// What the control side and the worker share.
struct Shared {
    /// Generation of the newest request: a solve of any other stops ([`Cancellation`]).
    latest: Arc<AtomicU64>,
    /// Generation of the newest correction delivered to the request slot (or of a reset), stored
    /// once the slot holds it: what a spinning worker watches.
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
    /// Generation of the last correction posted (or of the last reset).
    posted: u64,
    /// Resets so far.
    epoch: u64,
    /// Corrections the request slot has not taken yet (hardware mode: the slot may be busy at a
    /// tick).
    outbox: Request,
    /// What the worker learned, collected and not yet taken in by the learner.
    taught: Vec<Taught>,
}

impl ReplanWorker {
    /// Starts the worker with `learning` and `planner` (whose warm start is the initial plan,
    /// generation 0), for corrections of plans of m waypoints × n joints (`(m, n)`). It busy-waits
    /// `spin` for each next request before it sleeps (`LearnerParams::worker_spin`).
    pub(super) fn spawn(planner: Planner, learning: Learning, (m, n): (usize, usize), spin: Duration) -> Result<Self> {
        let shared = Arc::new(Shared {
            latest: Arc::new(AtomicU64::new(0)),
            delivered: AtomicU64::new(0),
            request: Mutex::new(Request::new(m, n)),
            result: Mutex::new(Posted { generation: 0, outcome: None, epoch: 0, taught: Vec::with_capacity(QUEUE) }),
            posted: Condvar::new(),
            shutdown: AtomicBool::new(false),
            stall_nanos: AtomicU64::new(0),
            panic_next: AtomicBool::new(false),
        });
        let worker = Worker::new(shared.clone(), planner, learning, Request::new(m, n), spin);
        let thread = std::thread::Builder::new()
            .name("phri-replan".into())
            .spawn(move || worker.run())
            .map_err(|e| PhriError::ReplanWorker { reason: format!("the replan worker thread could not start: {e}") })?;
        Ok(ReplanWorker {
            shared,
            thread: Some(thread),
            posted: 0,
            epoch: 0,
            outbox: Request::new(m, n),
            taught: Vec::with_capacity(QUEUE),
        })
    }

    /// Queues `correction` (its record `record`) for the worker, which learns from it and replans
    /// for the weights it gives warm-started from the plan of generation `base` (the one the robot
    /// tracks), and returns its generation. A solve still running for an older correction stops.
    /// With `block` false it never waits: corrections the slot has no room for go out at a later
    /// call. Allocates nothing unless more than [`QUEUE`] corrections wait on this side.
    pub(super) fn request(&mut self, correction: &Correction, record: usize, base: u64, block: bool) -> u64 {
        self.posted += 1;
        self.shared.latest.store(self.posted, Ordering::Release);
        if self.thread.as_ref().is_none_or(JoinHandle::is_finished) {
            // Nobody to learn from it: `collect` reports the stopped worker.
            return self.posted;
        }
        if self.outbox.queued == self.outbox.queue.len() && block {
            self.deliver(true);
        }
        if self.outbox.queued == self.outbox.queue.len() {
            // A worker held up for [`QUEUE`] samples and more: the queue grows (one allocation)
            // rather than the tick waits (it may hold what the worker needs, e.g. the GIL).
            let spare = self.outbox.queue[0].clone();
            self.outbox.queue.push(spare);
        }
        let queued = &mut self.outbox.queue[self.outbox.queued];
        queued.correction.copy_from(correction);
        queued.generation = self.posted;
        queued.record = record;
        self.outbox.queued += 1;
        self.outbox.base = base;
        self.deliver(block);
        self.posted
    }

    /// Cancels whatever the worker is doing, and the corrections it has not learned from yet: no
    /// result of a request made so far will be collected, and the worker starts its learning
    /// again (`Learner::reset`). Waits for the slots.
    pub(super) fn cancel(&mut self) {
        self.posted += 1;
        self.epoch += 1;
        self.shared.latest.store(self.posted, Ordering::Release);
        self.outbox.queued = 0;
        self.taught.clear();
        let mut result = lock(&self.shared.result);
        result.epoch = self.epoch;
        result.outcome = None;
        result.taught.clear();
        drop(result);
        let mut slot = lock(&self.shared.request);
        slot.queued = 0;
        slot.generation = self.posted;
        slot.epoch = self.epoch;
        drop(slot);
        self.shared.delivered.store(self.posted, Ordering::Release);
        if let Some(thread) = &self.thread {
            thread.thread().unpark();
        }
    }

    /// Hands the outbox's corrections to the worker, as many as the slot has room for; with
    /// `block`, waits until it has taken them all (or has stopped).
    fn deliver(&mut self, block: bool) {
        while self.outbox.queued > 0 {
            let slot = if block { Some(lock(&self.shared.request)) } else { try_lock(&self.shared.request) };
            let Some(mut slot) = slot else { return };
            if slot.take_from(&mut self.outbox) > 0 {
                slot.generation = slot.queue[slot.queued - 1].generation;
                slot.base = self.outbox.base;
                let generation = slot.generation;
                drop(slot);
                self.shared.delivered.store(generation, Ordering::Release);
                if let Some(thread) = &self.thread {
                    thread.thread().unpark();
                }
            } else {
                drop(slot);
            }
            if self.outbox.queued == 0 || !block || self.thread.as_ref().is_none_or(JoinHandle::is_finished) {
                return;
            }
            // The slot is full: the worker takes its corrections at its next look.
            std::thread::sleep(QUEUE_WAIT);
        }
    }

    /// The outcome of request `generation` if the worker has posted it (taken out of the slot),
    /// or with `block` once it has; a worker that stopped gives [`Outcome::Failed`]. What the
    /// worker has learned by then is kept for [`ReplanWorker::taught`] (with the outcome, at
    /// least everything up to `generation`). Without `block` it never waits. Allocates nothing.
    pub(super) fn collect(&mut self, generation: u64, block: bool) -> Option<Outcome> {
        self.deliver(block);
        let slot = if block { Some(lock(&self.shared.result)) } else { try_lock(&self.shared.result) };
        let mut slot = slot?;
        loop {
            if slot.generation == generation && slot.outcome.is_some() {
                take_taught(&mut slot.taught, &mut self.taught);
                return slot.outcome.take();
            }
            if self.thread.as_ref().is_none_or(JoinHandle::is_finished) {
                take_taught(&mut slot.taught, &mut self.taught);
                let reason = "the replan worker thread stopped; the arm keeps its plan".to_string();
                return Some(Outcome::Failed(PhriError::ReplanWorker { reason }));
            }
            if !block {
                take_taught(&mut slot.taught, &mut self.taught);
                return None;
            }
            slot = match self.shared.posted.wait_timeout(slot, LIVENESS_CHECK) {
                Ok((slot, _)) => slot,
                Err(e) => e.into_inner().0,
            };
        }
    }

    /// What the worker learned, as far as collected, oldest first (drained).
    pub(super) fn taught(&mut self) -> std::vec::Drain<'_, Taught> {
        self.taught.drain(..)
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

/// Moves what the worker posted to the control side's list (the lists' buffers are swapped when
/// that is empty, so nothing is allocated there).
fn take_taught(posted: &mut Vec<Taught>, taken: &mut Vec<Taught>) {
    if taken.is_empty() {
        std::mem::swap(posted, taken);
    } else {
        taken.append(posted);
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
    learning: Learning,
    planner: Planner,
    /// The corrections taken from the slot, to learn from.
    inbox: Request,
    /// The epoch `learning` is in.
    epoch: u64,
    /// The last feasible result, until the control side adopts it (`Request::base` says so) or a
    /// newer one replaces it, its generation and the weights it was planned for.
    candidate: PlanLevels,
    candidate_generation: Option<u64>,
    candidate_weights: Vec<f64>,
    /// Generation of the plan in `planner.levels` (the warm start), and the weights it was
    /// planned for.
    levels_generation: u64,
    levels_weights: Vec<f64>,
    /// The initial plan's weights.
    initial_weights: Vec<f64>,
    /// How long to busy-wait for a request before sleeping.
    spin: Duration,
}

impl Worker {
    fn new(shared: Arc<Shared>, planner: Planner, learning: Learning, inbox: Request, spin: Duration) -> Self {
        let candidate = planner.levels.clone();
        let initial_weights = learning.plan_weights().to_vec();
        Worker {
            shared,
            learning,
            planner,
            inbox,
            epoch: 0,
            candidate,
            candidate_generation: None,
            candidate_weights: initial_weights.clone(),
            levels_generation: 0,
            levels_weights: initial_weights.clone(),
            initial_weights,
            spin,
        }
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
                let mut slot = lock(&self.shared.request);
                (slot.generation > taken).then(|| {
                    self.inbox.queued = 0;
                    self.inbox.take_from(&mut slot);
                    (slot.generation, slot.base, slot.epoch)
                })
            };
            let Some((generation, base, epoch)) = job else {
                self.wait(taken, idle_since);
                continue;
            };
            taken = generation;
            idle_since = Instant::now();
            if epoch != self.epoch {
                // The control side reset: the corrections from now on start from the prior.
                self.learning.reset();
                self.epoch = epoch;
            }
            let Some(newest_learned) = self.learn(epoch) else { continue };
            if self.shared.latest.load(Ordering::Acquire) != generation {
                continue; // superseded before it started
            }
            self.rebase(base);
            // A failed newest correction still replans for what the ones before it taught (their
            // own replans were superseded), unless the tracked plan was made for those weights.
            let outcome = if !newest_learned && self.learning.plan_weights() == &self.levels_weights[..] {
                Some(Outcome::Unlearned)
            } else {
                match catch_unwind(AssertUnwindSafe(|| self.solve(generation, base))) {
                    Ok(outcome) => outcome,
                    // A panic inside the solve leaves `levels` and `candidate` as they were (it
                    // writes only `replanned`); the next request starts from them as usual.
                    Err(payload) => Some(Outcome::Failed(panicked(payload.as_ref()))),
                }
            };
            let Some(outcome) = outcome else { continue };
            let mut slot = lock(&self.shared.result);
            if self.shared.latest.load(Ordering::Acquire) != generation || slot.epoch != epoch {
                continue; // superseded meanwhile: only the newest result can be adopted
            }
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

    /// Learns from the corrections taken (in order) and posts what it learned; returns whether
    /// the newest one taught anything, or None if none were taken (a reset).
    fn learn(&mut self, epoch: u64) -> Option<bool> {
        let count = self.inbox.queued;
        if count == 0 {
            return None;
        }
        let mut taught = Vec::with_capacity(count);
        for queued in &self.inbox.queue[..count] {
            if self.shared.shutdown.load(Ordering::Acquire) {
                break;
            }
            let learning = &mut self.learning;
            let learned = catch_unwind(AssertUnwindSafe(|| learning.learn(&queued.correction)))
                .unwrap_or_else(|payload| Err(panicked(payload.as_ref())));
            taught.push(Taught { record: queued.record, learned });
        }
        self.inbox.queued = 0;
        let newest = taught.last().is_some_and(|t| t.learned.is_ok());
        let mut slot = lock(&self.shared.result);
        if slot.epoch == epoch {
            slot.taught.append(&mut taught);
        }
        drop(slot);
        Some(newest)
    }

    /// Solves request `generation` warm-started from the plan of generation `base`; `None` if it
    /// was superseded before the end.
    fn solve(&mut self, generation: u64, base: u64) -> Option<Outcome> {
        self.rebase(base);
        self.inject_faults();
        self.planner.set_cancellation(Some(Cancellation::new(self.shared.latest.clone(), generation)));
        let result = self.planner.solve(self.learning.plan_weights());
        if self.shared.latest.load(Ordering::Acquire) != generation {
            return None;
        }
        Some(match result {
            Err(e) => Outcome::Failed(e),
            Ok(info) if info.feasible => {
                self.planner.hold(&mut self.candidate);
                self.candidate_generation = Some(generation);
                self.candidate_weights.copy_from_slice(self.learning.plan_weights());
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
            std::mem::swap(&mut self.levels_weights, &mut self.candidate_weights);
        } else {
            // Generation 0: the initial plan (after `Learner::reset`). The control side adopts only
            // results of the worker, so no other generation can be asked for.
            self.planner.restart();
            self.levels_weights.clone_from(&self.initial_weights);
        }
        self.levels_generation = base;
    }

    /// The test hooks: a stall (cut short by shutdown), then a panic. (The panic is in the solve:
    /// a learn that panics is caught the same way.)
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

/// The error for a panic on the worker, with its message.
fn panicked(payload: &(dyn std::any::Any + Send)) -> PhriError {
    let message = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".into());
    PhriError::ReplanWorker { reason: format!("the replan worker panicked (a bug in phri; please report it): {message}") }
}
