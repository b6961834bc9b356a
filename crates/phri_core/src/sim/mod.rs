//! A simulated arm and the control loop that drives it at the control rate, both native: the
//! fast path of phri's simulated episodes (PyBullet stays for rendering and as the reference).
//!
//! [`SimulatedArm`] integrates the arm's rigid-body dynamics as PyBullet's step does
//! (semi-implicit Euler on M(q)q̈ + C(q, q̇)q̇ + g(q) = τ + τ_ext − d·q̇). [`SimulatedLoop`] runs
//! the ticks of phri's control loop on it (the Python `phri.control.ControlLoop`'s, one for one):
//! the safety layer's checks, the learner's observation and reference, the implicit impedance law
//! with its wall, the torque limits, the step and the log at the log rate, and the hold after a
//! stop. The person's push is given per chunk of ticks (the person re-judges at their own rate and
//! holds their push in between), as is the sensor's offset at each sample instant.

mod arm;
mod control_loop;

pub use arm::SimulatedArm;
pub use control_loop::{LoopLog, LoopSettings, SimulatedLoop, Stop, GRID_TOLERANCE, MAX_LOG_ROWS};
