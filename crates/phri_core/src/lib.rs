//! phri_core: the numeric core of phri, learning robot objectives from physical human interaction
//! (Bajcsy, Losey, O'Malley and Dragan, CoRL 2017).
//!
//! Pure Rust, no Python and no I/O beyond reading a robot description. Units are SI throughout:
//! m, rad, s, kg, N, N·m.

// `!(x > 0.0)` is deliberate throughout: it is true for NaN, so invalid input fails the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Kernels index several parallel per-joint slices in one loop; iterator zips would obscure them.
#![allow(clippy::needless_range_loop)]

pub mod belief;
pub mod collision;
pub mod data;
pub mod deform;
pub mod dynamics;
pub mod error;
pub mod features;
pub mod impedance;
pub mod interaction;
pub mod kinematics;
pub mod learner;
pub mod model;
mod pose;
pub mod reference;
pub mod safety;
pub mod scene;
pub mod sim;
pub mod trajopt;
pub mod update;
pub mod wall;

pub use data::RobotData;
pub use error::{PhriError, Result, MAX_MAGNITUDE};
pub use model::{AxisPermutation, BodyInertia, Frame, FrameId, Joint, JointKind, RobotModel, Transform};
