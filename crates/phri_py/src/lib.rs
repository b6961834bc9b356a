//! The thin PyO3 layer over phri_core, importable as `phri._phri`. Each file mirrors one core
//! module; a method converts its arguments, calls the core, and maps the error.

use pyo3::prelude::*;

mod arrays;
mod deform;
mod errors;
mod features;
mod impedance;
mod interaction;
mod learner;
mod reference;
mod robot;
mod safety;
mod scene;
mod trajopt;
mod update;

#[pymodule]
fn _phri(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<robot::PyRobot>()?;
    m.add_class::<features::PyFeatures>()?;
    m.add("FEATURE_NAMES", pyo3::types::PyTuple::new(m.py(), phri_core::features::BUILTIN_FEATURES)?)?;
    m.add("FEATURE_PARAMETERS", features::parameters(m.py())?)?;
    m.add_class::<scene::PySceneObject>()?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<update::PyWeightUpdate>()?;
    m.add_class::<update::PyUpdateInfo>()?;
    m.add_function(wrap_pyfunction!(update::relevance, m)?)?;
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
    m.add("UPDATE_RULES", pyo3::types::PyTuple::new(m.py(), phri_core::update::UpdateRule::NAMES)?)?;
    Ok(())
}
