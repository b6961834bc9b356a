//! phri_core: the numeric core of phri, learning robot objectives from physical human interaction
//! (Bajcsy, Losey, O'Malley and Dragan, CoRL 2017).
//!
//! Pure Rust, no Python and no I/O beyond reading a robot description. Units are SI throughout:
//! m, rad, s, kg, N, N·m.

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
pub mod reference;
pub mod trajopt;
pub mod update;

pub use data::RobotData;
pub use error::{PhriError, Result};
pub use model::{BodyInertia, Frame, FrameId, Joint, JointKind, RobotModel, Transform};
