//! `phri.rationality` and the belief's constants: how well the learned features explain a push
//! (the learner's belief itself is `Learner.belief()`).

use numpy::PyUntypedArrayMethods;
use phri_core::belief;
use pyo3::prelude::*;

use crate::arrays::{matrix, shape_str, vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};

/// How well the learned features explain a push u_H (n,) [N·m], given the linearised sensitivity
/// S = ∂ΔΦ/∂u_H (K, n) and which features are learned (K,). Returns (beta, explained, rank):
/// `explained` = ‖u*‖²/‖u_H‖² with u* the projection of u_H onto the span of the learned rows of S
/// (the best push they explain), `rank` r that span's dimension, and
/// β̂ = (explained / r) / ((1 − explained) / (n − r)) in [0, BETA_MAX]: about 1 for a push explained
/// no better than a random direction, large for one the features explain.
#[pyfunction]
pub fn rationality(sensitivity: ArrayIn<'_>, learned: Vec<bool>, u_h: ArrayIn<'_>) -> PyResult<(f64, f64, usize)> {
    let u_h = match u_h.shape() {
        [n] => vector("u_h", &u_h, *n)?,
        other => return Err(error(Kind::Shape, format!("u_h must have shape (n,), got {}", shape_str(other)))),
    };
    let (sensitivity, _) = matrix("sensitivity", &sensitivity, Some(learned.len()), u_h.len())?;
    let r = belief::rationality(&sensitivity, &learned, &u_h).py_err()?;
    Ok((r.beta, r.explained, r.rank))
}

/// The belief's constants, as module attributes.
pub fn add_constants(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("BETA_THRESHOLD", belief::BETA_THRESHOLD)?;
    m.add("BETA_FULL", belief::BETA_FULL)?;
    m.add("BETA_MAX", belief::BETA_MAX)?;
    m.add("DEFAULT_EFFORT", belief::DEFAULT_EFFORT)?;
    Ok(())
}
