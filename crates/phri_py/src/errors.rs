//! The one mapping from core errors to the exception classes of `phri.exceptions`.

use phri_core::PhriError;
use pyo3::exceptions::{PyOverflowError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

/// The exception classes defined in Python (so they can inherit from both PhriError and ValueError).
#[derive(Clone, Copy)]
pub enum Kind {
    Shape,
    NonFinite,
    InvalidParameter,
    UnknownName,
    Urdf,
    NotConverged,
    Planning,
    ReplanWorker,
}

impl Kind {
    fn class_name(self) -> &'static str {
        match self {
            Kind::Shape => "ShapeError",
            Kind::NonFinite => "NonFiniteError",
            Kind::InvalidParameter => "InvalidParameterError",
            Kind::UnknownName => "UnknownNameError",
            Kind::Urdf => "UrdfError",
            Kind::NotConverged => "NotConvergedError",
            Kind::Planning => "PlanningError",
            Kind::ReplanWorker => "ReplanWorkerError",
        }
    }

    fn cell(self) -> &'static PyOnceLock<Py<PyType>> {
        static CELLS: [PyOnceLock<Py<PyType>>; 8] = [const { PyOnceLock::new() }; 8];
        &CELLS[self as usize]
    }
}

/// A Python exception of class `kind` with `message`.
pub fn error(kind: Kind, message: impl Into<String>) -> PyErr {
    let message = message.into();
    Python::attach(|py| match kind.cell().import(py, "phri.exceptions", kind.class_name()) {
        Ok(class) => PyErr::from_type(class.clone(), message),
        // Only if the package is broken: still a ValueError with the message.
        Err(_) => PyValueError::new_err(message),
    })
}

/// Converts a core error into its Python exception.
pub fn to_py(e: PhriError) -> PyErr {
    let kind = match &e {
        PhriError::Shape { .. } => Kind::Shape,
        PhriError::NonFinite { .. } => Kind::NonFinite,
        PhriError::InvalidParameter { .. } => Kind::InvalidParameter,
        PhriError::UnknownName { .. } => Kind::UnknownName,
        PhriError::Urdf { .. } => Kind::Urdf,
        PhriError::NotConverged { .. } => Kind::NotConverged,
        PhriError::Planning { .. } => Kind::Planning,
        PhriError::ReplanWorker { .. } => Kind::ReplanWorker,
    };
    error(kind, e.to_string())
}

/// `?`-friendly conversion of core results.
pub trait IntoPy<T> {
    fn py_err(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for phri_core::Result<T> {
    #[inline]
    fn py_err(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}

/// `value` as a count (an int in [0, `max`]) for argument `arg`: an InvalidParameterError naming it
/// when out of range (PyO3's own OverflowError names nothing), a TypeError when not an int (PyO3
/// prefixes it with "argument '<arg>': ").
pub fn count(arg: &str, value: &Bound<'_, PyAny>, max: usize) -> PyResult<usize> {
    let out_of_range = || error(Kind::InvalidParameter, format!("{arg} must be an integer in [0, {max}], got {value}"));
    match value.extract::<usize>() {
        Ok(v) if v <= max => Ok(v),
        Ok(_) => Err(out_of_range()),
        Err(e) if e.is_instance_of::<PyOverflowError>(value.py()) => Err(out_of_range()),
        Err(_) => Err(PyTypeError::new_err(format!("must be an int, got {}", value.get_type().qualname()?))),
    }
}
