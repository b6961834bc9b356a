//! NumPy in and out: shape checks that name the argument, and zero-copy results.

use std::borrow::Cow;

use numpy::{AllowTypeChange, PyArrayLikeDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;

use crate::errors::{error, Kind};

/// Any array-like of floats (lists, tuples, arrays of any numeric dtype). What numpy cannot read
/// as numbers (strings, ragged lists, arbitrary objects) is a TypeError, which PyO3 prefixes with
/// the argument's name ("argument 'q': expected numbers ...").
pub struct ArrayIn<'py>(PyArrayLikeDyn<'py, f64, AllowTypeChange>);

impl<'py> std::ops::Deref for ArrayIn<'py> {
    type Target = PyArrayLikeDyn<'py, f64, AllowTypeChange>;

    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl<'a, 'py> FromPyObject<'a, 'py> for ArrayIn<'py> {
    type Error = PyErr;

    fn extract(ob: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        PyArrayLikeDyn::extract(ob).map(ArrayIn).map_err(|e| {
            let kind = ob.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "object".into());
            PyTypeError::new_err(format!("expected numbers (an array, a list or a number), got {kind}: {e}"))
        })
    }
}

/// Row-major values of an input that is either one row `(n,)` or a batch `(N, n)`.
pub struct Rows<'a> {
    pub values: Cow<'a, [f64]>,
    /// `None` for a single `(n,)` input, `Some(N)` for a batch.
    pub batch: Option<usize>,
    pub n: usize,
}

impl Rows<'_> {
    pub fn count(&self) -> usize {
        self.batch.unwrap_or(1)
    }

    pub fn row(&self, i: usize) -> &[f64] {
        &self.values[i * self.n..(i + 1) * self.n]
    }
}

pub fn shape_str(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        many => format!("({})", many.iter().map(usize::to_string).collect::<Vec<_>>().join(", ")),
    }
}

fn values<'a>(a: &'a ArrayIn<'_>) -> Cow<'a, [f64]> {
    // `as_slice` also succeeds for Fortran-ordered arrays, whose memory is not row-major.
    match a.as_slice() {
        Ok(s) if a.is_c_contiguous() => Cow::Borrowed(s),
        _ => Cow::Owned(a.as_array().iter().copied().collect()),
    }
}

fn check_finite(arg: &str, values: &[f64], n: usize, batched: bool) -> PyResult<()> {
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        let at = if batched { format!("({}, {})", i / n, i % n) } else { i.to_string() };
        return Err(error(Kind::NonFinite, format!("{arg} must be finite, got {} at index {at}", values[i])));
    }
    Ok(())
}

/// `(n,)` or `(N, n)`, finite.
pub fn rows<'a>(arg: &str, a: &'a ArrayIn<'_>, n: usize) -> PyResult<Rows<'a>> {
    let shape = a.shape();
    let batch = match shape {
        [m] if *m == n => None,
        [b, m] if *m == n => Some(*b),
        _ => return Err(error(Kind::Shape, format!("{arg} must have shape ({n},) or (N, {n}), got {}", shape_str(shape)))),
    };
    let values = values(a);
    check_finite(arg, &values, n, batch.is_some())?;
    Ok(Rows { values, batch, n })
}

/// Exactly `(n,)`, finite.
pub fn vector<'a>(arg: &str, a: &'a ArrayIn<'_>, n: usize) -> PyResult<Cow<'a, [f64]>> {
    if a.shape() != [n] {
        return Err(error(Kind::Shape, format!("{arg} must have shape ({n},), got {}", shape_str(a.shape()))));
    }
    let v = values(a);
    check_finite(arg, &v, n, false)?;
    Ok(v)
}

/// Exactly `(rows, cols)`, finite, row-major; `rows = None` accepts any number of rows.
pub fn matrix<'a>(arg: &str, a: &'a ArrayIn<'_>, rows: Option<usize>, cols: usize) -> PyResult<(Cow<'a, [f64]>, usize)> {
    let shape = a.shape();
    let ok = shape.len() == 2 && shape[1] == cols && rows.is_none_or(|r| r == shape[0]);
    if !ok {
        let r = rows.map_or("N".to_string(), |r| r.to_string());
        return Err(error(Kind::Shape, format!("{arg} must have shape ({r}, {cols}), got {}", shape_str(shape))));
    }
    let v = values(a);
    check_finite(arg, &v, cols, true)?;
    Ok((v, shape[0]))
}

/// Checks that the batch sizes of several `Rows` agree.
pub fn same_batch(args: &[(&str, &Rows)]) -> PyResult<Option<usize>> {
    let first = args[0].1.batch;
    for (name, r) in &args[1..] {
        if r.batch != first {
            let want = first.map_or(format!("({},)", r.n), |b| format!("({b}, {})", r.n));
            let got = r.batch.map_or(format!("({},)", r.n), |b| format!("({b}, {})", r.n));
            return Err(error(Kind::Shape, format!("{name} must have shape {want} like {}, got {got}", args[0].0)));
        }
    }
    Ok(first)
}
