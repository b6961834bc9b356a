//! The one mapping from core errors to the exception classes of `phri.exceptions`.

use phri_core::PhriError;
use pyo3::exceptions::PyValueError;
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
    Feature,
    Simulation,
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
            Kind::Feature => "FeatureError",
            Kind::Simulation => "SimulationError",
        }
    }

    fn cell(self) -> &'static PyOnceLock<Py<PyType>> {
        static CELLS: [PyOnceLock<Py<PyType>>; 10] = [const { PyOnceLock::new() }; 10];
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
        PhriError::Feature { .. } => Kind::Feature,
        PhriError::Simulation { .. } => Kind::Simulation,
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
