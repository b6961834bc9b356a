//! The one error type of the core. Every variant names the argument it is about, so the Python
//! layer can map it to a typed exception whose message says what was expected.

use thiserror::Error;

/// Result alias used across the core.
pub type Result<T> = std::result::Result<T, PhriError>;

#[derive(Debug, Clone, PartialEq, Error)]
pub enum PhriError {
    /// An array or slice has the wrong length or shape.
    #[error("{arg} must have shape {expected}, got {got}")]
    Shape { arg: String, expected: String, got: String },

    /// A value that must be finite holds NaN or ±inf.
    #[error("{arg} must be finite, got {value} at index {index}")]
    NonFinite { arg: String, index: usize, value: f64 },

    /// A scalar or setting outside its allowed range.
    #[error("{arg} {reason}")]
    InvalidParameter { arg: String, reason: String },

    /// A name (frame, joint, feature) that the model does not know.
    #[error("{arg}: unknown {kind} '{name}'; known: {known}")]
    UnknownName { arg: String, kind: String, name: String, known: String },

    /// A robot description that cannot be read or does not describe a usable chain.
    #[error("{arg}: {reason}")]
    Urdf { arg: String, reason: String },

    /// A plan cannot be made safe, or safety cannot be checked (no collision model).
    #[error("{reason}")]
    Planning { reason: String },

    /// The learner's replan worker failed: a panic inside phri (a bug to report) or a worker that
    /// stopped. The arm kept the plan it was tracking.
    #[error("{reason}")]
    ReplanWorker { reason: String },

    /// A feature defined outside the core (e.g. in Python) failed: it raised, returned the wrong
    /// shape or a non-finite value, or overran its time limit. Names the feature.
    #[error("feature '{feature}': {reason}")]
    Feature { feature: String, reason: String },

    /// A simulated arm's step failed: its state would become non-finite.
    #[error("{reason}")]
    Simulation { reason: String },

    /// An iterative solver stopped without meeting its tolerance.
    #[error("{what} did not converge after {iterations} iterations (residual {residual:e})")]
    NotConverged { what: String, iterations: usize, residual: f64 },
}

impl PhriError {
    pub(crate) fn shape(arg: &str, expected: impl Into<String>, got: impl Into<String>) -> Self {
        PhriError::Shape { arg: arg.into(), expected: expected.into(), got: got.into() }
    }

    pub(crate) fn invalid(arg: &str, reason: impl Into<String>) -> Self {
        PhriError::InvalidParameter { arg: arg.into(), reason: reason.into() }
    }
}

/// Largest magnitude of an entry of an array input [in its SI unit: rad, m, s, N·m, cost weight]:
/// no joint position, velocity, torque, weight or distance phri handles lies beyond it, and products
/// of a few such values stay far from overflow, so results stay finite. (The Python layer refuses
/// arrays beyond it, naming the argument.)
pub const MAX_MAGNITUDE: f64 = 1e9;

/// Checks that `values` has `len` entries, all finite.
pub fn check_vector(arg: &str, values: &[f64], len: usize) -> Result<()> {
    if values.len() != len {
        return Err(PhriError::shape(arg, format!("({len},)"), format!("({},)", values.len())));
    }
    check_finite(arg, values)
}

/// Checks that every entry of `values` is finite.
pub fn check_finite(arg: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(PhriError::NonFinite { arg: arg.into(), index, value: values[index] }),
        None => Ok(()),
    }
}
