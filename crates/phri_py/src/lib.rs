//! The thin PyO3 layer over phri_core, importable as `phri._phri`. Each file mirrors one core
//! module; a method converts its arguments, calls the core, and maps the error.
//!
//! Accepted ranges shared by every method: array inputs hold real numbers (integer or floating
//! dtypes; not bool, complex, strings, datetimes, structured, object or masked arrays), finite and
//! within ±1e9 in their SI unit (`phri_core::MAX_MAGNITUDE`); integer arguments are Python or
//! numpy integers, not bools, and out of range they are an InvalidParameterError naming the
//! argument and its range. Each scalar's own range is in its class's documentation.

use pyo3::prelude::*;

mod arrays;
mod belief;
mod deform;
mod errors;
mod features;
mod impedance;
mod interaction;
mod ints;
mod learner;
mod python_feature;
mod reference;
mod robot;
mod safety;
mod scene;
mod sim;
mod trajopt;
mod update;

#[pymodule]
fn _phri(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<robot::PyRobot>()?;
    m.add_class::<features::PyFeatures>()?;
    m.add("FEATURE_NAMES", pyo3::types::PyTuple::new(m.py(), phri_core::features::BUILTIN_FEATURES)?)?;
    m.add("FEATURE_PARAMETERS", features::parameters(m.py())?)?;
    m.add("DECLARED_KINDS", pyo3::types::PyTuple::new(m.py(), phri_core::features::DECLARED_KINDS)?)?;
    m.add("DECLARED_PARAMETERS", features::declared(m.py())?)?;
    m.add_class::<scene::PySceneObject>()?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<update::PyWeightUpdate>()?;
    m.add_class::<update::PyUpdateInfo>()?;
    m.add_function(wrap_pyfunction!(update::relevance, m)?)?;
    m.add_function(wrap_pyfunction!(belief::rationality, m)?)?;
    belief::add_constants(m)?;
    m.add_class::<interaction::PyInteractionDetector>()?;
    m.add_class::<reference::PyTimedTrajectory>()?;
    m.add_class::<impedance::PyImpedanceController>()?;
    m.add_class::<deform::PyDeformation>()?;
    m.add_class::<trajopt::PyTrajectoryOptimizer>()?;
    m.add_class::<trajopt::PyTrajoptInfo>()?;
    m.add_class::<trajopt::PyPlanLevels>()?;
    m.add_class::<safety::PySafetyLayer>()?;
    m.add_class::<safety::PySafetyViolation>()?;
    m.add("SAFETY_LIMITS", pyo3::types::PyTuple::new(m.py(), safety::limit_names())?)?;
    m.add_class::<learner::PyLearner>()?;
    m.add_class::<learner::PyLearnerHistory>()?;
    m.add_class::<sim::PySimulatedArm>()?;
    m.add_class::<sim::PySimulatedLoop>()?;
    m.add("GRID_TOLERANCE", phri_core::sim::GRID_TOLERANCE)?;
    m.add("MAX_LOG_ROWS", phri_core::sim::MAX_LOG_ROWS)?;
    m.add("UPDATE_RULES", pyo3::types::PyTuple::new(m.py(), phri_core::update::UpdateRule::NAMES)?)?;
    Ok(())
}
