//! NumPy in and out: shape checks that name the argument, and zero-copy results.

use std::borrow::Cow;

use numpy::{AllowTypeChange, PyArrayDescrMethods, PyArrayLikeDyn, PyUntypedArray, PyUntypedArrayMethods};
use phri_core::MAX_MAGNITUDE;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

use crate::errors::{error, Kind};

/// Any array-like of real numbers (lists, tuples, arrays of an integer or floating dtype). What is
/// not a real number is a TypeError, which PyO3 prefixes with the argument's name ("argument 'q':
/// expected real numbers ..."): strings (also numeric ones), bools, complex numbers (their
/// imaginary part would be lost), datetimes, structured and object arrays, ragged lists, and
/// masked arrays (their mask would be lost).
pub struct ArrayIn<'py>(PyArrayLikeDyn<'py, f64, AllowTypeChange>);

impl<'py> std::ops::Deref for ArrayIn<'py> {
    type Target = PyArrayLikeDyn<'py, f64, AllowTypeChange>;

    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

/// numpy's dtype kinds of real numbers: signed and unsigned integers, floating point.
const REAL_KINDS: &[u8] = b"iuf";

fn refused(what: impl std::fmt::Display) -> PyErr {
    PyTypeError::new_err(format!("expected real numbers (an array, a list or a number), got {what}"))
}

impl<'a, 'py> FromPyObject<'a, 'py> for ArrayIn<'py> {
    type Error = PyErr;

    fn extract(ob: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        static ASARRAY: PyOnceLock<Py<PyAny>> = PyOnceLock::new();
        static MASKED: PyOnceLock<Py<PyType>> = PyOnceLock::new();
        let py = ob.py();
        let kind = || {
            let name = ob.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "object".into());
            let article = if name.starts_with(['a', 'e', 'i', 'o', 'u']) { "an" } else { "a" };
            format!("{article} {name}")
        };
        // An array keeps its dtype; anything else is read by numpy first, so that its dtype can be
        // checked before it is taken as floats (numpy would read "1.5" and True as numbers).
        let array = match ob.cast::<PyUntypedArray>() {
            Ok(a) => {
                if !a.is_exact_instance_of::<PyUntypedArray>()
                    && a.is_instance(MASKED.import(py, "numpy.ma", "MaskedArray")?)?
                {
                    return Err(refused("a masked array (pass a.filled(value) or a.compressed())"));
                }
                a.to_owned().into_any()
            }
            Err(_) => ASARRAY.import(py, "numpy", "asarray")?.call1((ob,)).map_err(|e| refused(format!("{}: {e}", kind())))?,
        };
        let dtype = array.cast::<PyUntypedArray>()?.dtype();
        if !REAL_KINDS.contains(&dtype.kind()) {
            let what = if ob.is_instance_of::<PyUntypedArray>() { "an array".to_string() } else { kind() };
            return Err(refused(format!("{what} of dtype {dtype}")));
        }
        PyArrayLikeDyn::extract(array.as_borrowed()).map(ArrayIn).map_err(|e| refused(format!("{}: {e}", kind())))
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

/// Finite, and within ±MAX_MAGNITUDE (phri_core::MAX_MAGNITUDE says why).
pub fn check_finite(arg: &str, values: &[f64], n: usize, batched: bool) -> PyResult<()> {
    let at = |i: usize| if batched { format!("({}, {})", i / n, i % n) } else { i.to_string() };
    if let Some(i) = values.iter().position(|v| !v.is_finite() || v.abs() > MAX_MAGNITUDE) {
        let (v, at) = (values[i], at(i));
        return Err(if v.is_finite() {
            error(Kind::InvalidParameter, format!("{arg} must be within ±{MAX_MAGNITUDE:e}, got {v:e} at index {at}"))
        } else {
            error(Kind::NonFinite, format!("{arg} must be finite, got {v} at index {at}"))
        });
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

/// A zeroed output of `len` values for input `arg`, or an InvalidParameterError saying how large
/// it would be when the memory cannot be had (`vec!` would abort the interpreter instead).
pub fn zeros(arg: &str, len: usize) -> PyResult<Vec<f64>> {
    let too_large = || {
        let gigabytes = len as f64 * std::mem::size_of::<f64>() as f64 / 1e9;
        error(
            Kind::InvalidParameter,
            format!("{arg} is too large: its result would take {gigabytes:.1} GB, which cannot be allocated"),
        )
    };
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| too_large())?;
    v.resize(len, 0.0);
    Ok(v)
}
