//! Stopping a running solve from another thread: the learner's replan worker solves the newest
//! correction only, so a newer one cancels the solve in progress.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A solve tagged `generation` stops at its next Newton iteration (as at its `max_time` deadline)
/// once the shared counter `latest` holds another generation: whoever posts a newer request bumps
/// the counter, and every solve of an older one ends early. Checking costs one atomic load per
/// iteration.
#[derive(Debug, Clone)]
pub struct Cancellation {
    latest: Arc<AtomicU64>,
    generation: u64,
}

impl Cancellation {
    /// A solve of request `generation`, cancelled once `latest` moves on from it.
    pub fn new(latest: Arc<AtomicU64>, generation: u64) -> Self {
        Cancellation { latest, generation }
    }

    /// Whether a newer request has superseded this solve's.
    #[inline]
    pub fn requested(&self) -> bool {
        self.latest.load(Ordering::Acquire) != self.generation
    }
}
