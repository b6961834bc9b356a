//! Integer arguments in: counts and indices are read as any Python integer (a numpy integer too)
//! with `#[pyo3(from_py_with = int)]`, so that -1 or 2**70 reach the method, which refuses what
//! is out of range with an InvalidParameterError naming the argument and the range. (PyO3's own
//! conversion into `usize` raises a bare OverflowError that names neither.)

use std::ops::RangeInclusive;

use pyo3::exceptions::{PyOverflowError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::PyBool;

use crate::errors::{error, Kind};

/// `from_py_with` of an integer argument: its value, saturated to i128's range (beyond it only
/// the sign matters for the message). A bool is refused, and so is anything that is not an
/// integer (a float, a string): TypeErrors, which PyO3 prefixes with the argument's name.
pub fn int(ob: &Bound<'_, PyAny>) -> PyResult<i128> {
    if ob.is_instance_of::<PyBool>() || ob.get_type().name().is_ok_and(|n| n == "bool" || n == "bool_") {
        return Err(PyTypeError::new_err("expected an integer, got a bool"));
    }
    match ob.extract::<i128>() {
        Ok(v) => Ok(v),
        Err(e) if e.is_instance_of::<PyOverflowError>(ob.py()) => Ok(if ob.lt(0)? { i128::MIN } else { i128::MAX }),
        Err(e) => Err(e),
    }
}

/// `from_py_with` of an optional integer argument: None, or [`int`] of it.
pub fn optional_int(ob: &Bound<'_, PyAny>) -> PyResult<Option<i128>> {
    if ob.is_none() {
        Ok(None)
    } else {
        int(ob).map(Some)
    }
}

/// `value` as shown in a message (a saturated value by its bound).
fn shown(value: i128) -> String {
    match value {
        i128::MAX => "an integer of 2**127 or more".into(),
        i128::MIN => "an integer of -2**127 or less".into(),
        v => v.to_string(),
    }
}

/// `value` of argument `arg` if it lies in `range`, else an InvalidParameterError naming both;
/// `what` says what the number counts (e.g. "waypoints") and, where there is one, why the range
/// ends where it does.
pub fn bounded(arg: &str, value: i128, range: RangeInclusive<usize>, what: &str) -> PyResult<usize> {
    let (lo, hi) = (*range.start(), *range.end());
    match usize::try_from(value) {
        Ok(v) if range.contains(&v) => Ok(v),
        _ => {
            let what = if what.is_empty() { String::new() } else { format!(" {what}") };
            let range = match (hi == usize::MAX, value > hi as i128) {
                (false, _) => format!("in {lo}..={hi}"),
                (true, false) => format!("an integer >= {lo}"),
                (true, true) => format!("at most {hi}"),
            };
            Err(error(Kind::InvalidParameter, format!("{arg} must be {range}{what}, got {}", shown(value))))
        }
    }
}

/// `value` as a count (an int in [0, `max`]) for argument `arg` (a constructor's keyword read with
/// `from_py_with`): an InvalidParameterError naming it when out of range, a TypeError when it is
/// not an int (a bool, a float), which PyO3 prefixes with "argument '<arg>': ".
pub fn count(arg: &str, value: &Bound<'_, PyAny>, max: usize) -> PyResult<usize> {
    let Ok(v) = int(value) else {
        return Err(PyTypeError::new_err(format!("must be an int, got {}", value.get_type().qualname()?)));
    };
    match usize::try_from(v) {
        Ok(v) if v <= max => Ok(v),
        _ => Err(error(Kind::InvalidParameter, format!("{arg} must be an integer in [0, {max}], got {}", shown(v)))),
    }
}
