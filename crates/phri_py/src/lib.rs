//! The thin PyO3 layer over phri_core, importable as `phri._phri`. Each file mirrors one core
//! module; a method converts its arguments, calls the core, and maps the error.

use pyo3::prelude::*;

mod arrays;
mod errors;
mod robot;

#[pymodule]
fn _phri(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<robot::PyRobot>()?;
    Ok(())
}
