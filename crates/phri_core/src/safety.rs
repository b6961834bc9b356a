//! The safety layer of the control loop: per-tick checks of the arm's state against its limits, and
//! the limits applied to the torque before it is written.
//!
//! Made once from the limits ([`SafetyLimits`], read from the robot description and the task), then
//! called twice per tick, allocating nothing (the ruckig pattern: validate and precompute in the
//! constructor, write into caller storage, return a status):
//!
//! 1. [`SafetyLayer::check_state`] on the state just read: a non-finite value, a joint outside its
//!    position limits (less the margin) or faster than its velocity limit, the tool point outside its
//!    box, too many late ticks in a row, or a clock that did not advance is a [`Violation`], on which
//!    the loop stops the arm.
//! 2. [`SafetyLayer::limit_torque`] on the torque the impedance law computed: clipped to the torque
//!    limits and, as the command written, to the torque-rate limit (each clip counted per joint); a
//!    non-finite torque is a violation. For an arm that compensates gravity itself (libfranka), the
//!    command written is the torque less g(q).
//!
//! Lateness is measured on the robot's clock (the state's time stamp), never on the wall clock.

use std::sync::Arc;

use crate::data::RobotData;
use crate::error::{check_finite, check_vector, PhriError, Result};
use crate::model::{FrameId, RobotModel};

/// A box of the base frame [m]: `lower[i] <= p[i] <= upper[i]` on each axis x, y, z.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolBox {
    pub lower: [f64; 3],
    pub upper: [f64; 3],
}

/// The limits the safety layer holds the arm to. Every per-joint vector has one entry per joint.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyLimits {
    /// Lowest position each joint may reach while running [rad]: its URDF limit plus a margin
    /// (−∞ for a continuous joint).
    pub position_lower: Vec<f64>,
    /// Highest position each joint may reach while running [rad] (+∞ for a continuous joint).
    pub position_upper: Vec<f64>,
    /// Largest |q̇_j| before a stop [rad/s].
    pub velocity: Vec<f64>,
    /// Largest |τ_j| written; larger torques are clipped to it [N·m].
    pub torque: Vec<f64>,
    /// Largest change of the written command per second [N·m/s]; faster changes are clipped.
    pub torque_rate: Vec<f64>,
    /// Where the tool point must stay [m, base frame]; None: anywhere.
    pub tool_box: Option<ToolBox>,
}

/// How the layer watches the clock and what the arm expects as a command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyParams {
    /// The control period [s] (0.001 for 1 kHz).
    pub period: f64,
    /// A tick is late when it comes more than this many periods after the previous one (default 1.5:
    /// at least one tick of the robot was missed).
    pub late_after: f64,
    /// This many late ticks in a row are a violation (default 3).
    pub late_ticks: u32,
    /// The arm adds g(q) itself (libfranka): the command written is the torque less g(q).
    pub gravity_compensated: bool,
}

/// The documented defaults of [`SafetyParams`] (1 kHz, an arm without gravity compensation).
pub const DEFAULT_SAFETY_PARAMS: SafetyParams =
    SafetyParams { period: 1e-3, late_after: 1.5, late_ticks: 3, gravity_compensated: false };

impl Default for SafetyParams {
    fn default() -> Self {
        DEFAULT_SAFETY_PARAMS
    }
}

/// Which limit a violation crossed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Limit {
    /// A NaN or infinite value (which one: [`Violation::quantity`]).
    NonFinite,
    /// A joint outside its position limits less the margin.
    JointPosition,
    /// A joint faster than its velocity limit.
    JointVelocity,
    /// The tool point outside its box.
    ToolBox,
    /// Too many late ticks in a row.
    LateTicks,
    /// The robot's clock did not advance since the previous tick (a stalled or broken clock).
    Clock,
}

impl Limit {
    /// The names Python sees, in the order of the variants.
    pub const NAMES: [&'static str; 6] = ["non_finite", "joint_position", "joint_velocity", "tool_box", "late_ticks", "clock"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }
}

/// The value a violation is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// The robot's time stamp t [s].
    Time,
    /// A joint position q [rad].
    Position,
    /// A joint velocity q̇ [rad/s].
    Velocity,
    /// The measured external torque τ_ext [N·m].
    ExternalTorque,
    /// The torque to write τ [N·m].
    Torque,
    /// The tool point's position [m] (index: axis 0, 1, 2 = x, y, z).
    ToolPosition,
    /// The time between two ticks [s] (index: the number of late ticks in a row).
    TickGap,
}

impl Quantity {
    /// The names Python sees (the loop's and the log's), in the order of the variants.
    pub const NAMES: [&'static str; 7] = ["t", "q", "qd", "tau_ext", "tau", "tool_position", "tick_gap"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }
}

/// What crossed which limit: the stop's reason and the value that caused it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Violation {
    pub limit: Limit,
    pub quantity: Quantity,
    /// The joint (or the tool's axis; for late ticks, how many in a row).
    pub index: usize,
    /// The offending value, in the unit of `quantity`.
    pub value: f64,
    /// The bound it crossed (NaN for a non-finite value).
    pub bound: f64,
}

/// What one check did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SafetyStatus {
    /// The first limit crossed (None: none); the loop stops the arm on any.
    pub violation: Option<Violation>,
    /// Bit j set when joint j's torque was clipped to its torque limit.
    pub torque_saturated: u64,
    /// Bit j set when joint j's command was clipped to its torque-rate limit.
    pub rate_saturated: u64,
}

impl SafetyStatus {
    fn stop(violation: Violation) -> Self {
        SafetyStatus { violation: Some(violation), ..SafetyStatus::default() }
    }

    pub fn is_ok(&self) -> bool {
        self.violation.is_none()
    }
}

/// The per-tick safety checks for one robot. See the module documentation.
#[derive(Debug, Clone)]
pub struct SafetyLayer {
    model: Arc<RobotModel>,
    data: RobotData,
    tool: FrameId,
    limits: SafetyLimits,
    params: SafetyParams,
    /// The largest change of the command in one period, per joint [N·m].
    rate_step: Vec<f64>,
    /// The command written at the previous tick [N·m], if any.
    previous: Vec<f64>,
    has_previous: bool,
    gravity: Vec<f64>,
    /// The previous tick's time [s] (NaN before the first).
    previous_t: f64,
    late_in_a_row: u32,
    /// Per joint: how many ticks clipped its torque, and its command's rate.
    torque_clips: Vec<u64>,
    rate_clips: Vec<u64>,
}

impl SafetyLayer {
    /// The layer for `model` with `tool` the tool point the box is about. Every limit is checked:
    /// per-joint vectors of the model's joint count, position limits not NaN and lower <= upper,
    /// velocity, torque and torque-rate limits finite and > 0, the box finite with lower < upper,
    /// the period finite and > 0, late_after >= 1 and late_ticks >= 1.
    pub fn new(model: Arc<RobotModel>, tool: FrameId, limits: SafetyLimits, params: SafetyParams) -> Result<Self> {
        let n = model.nq();
        if tool.0 >= model.frames.len() {
            return Err(PhriError::invalid("tool", "is not a frame of the robot"));
        }
        for (arg, v) in [("position_lower", &limits.position_lower), ("position_upper", &limits.position_upper)] {
            if v.len() != n {
                return Err(PhriError::shape(arg, format!("({n},)"), format!("({},)", v.len())));
            }
            if let Some(j) = v.iter().position(|x| x.is_nan()) {
                return Err(PhriError::NonFinite { arg: arg.into(), index: j, value: v[j] });
            }
        }
        if let Some(j) = (0..n).find(|&j| !(limits.position_lower[j] <= limits.position_upper[j])) {
            return Err(PhriError::invalid(
                "position_lower",
                format!(
                    "[{j}] = {} rad must not exceed position_upper[{j}] = {} rad (is the margin wider than the joint's range?)",
                    limits.position_lower[j], limits.position_upper[j]
                ),
            ));
        }
        for (arg, v, unit) in [
            ("velocity", &limits.velocity, "rad/s"),
            ("torque", &limits.torque, "N·m"),
            ("torque_rate", &limits.torque_rate, "N·m/s"),
        ] {
            check_vector(arg, v, n)?;
            if let Some(j) = v.iter().position(|x| !(*x > 0.0)) {
                return Err(PhriError::invalid(arg, format!("[{j}] must be > 0 {unit}, got {}", v[j])));
            }
        }
        if let Some(b) = &limits.tool_box {
            check_finite("tool_box.lower", &b.lower)?;
            check_finite("tool_box.upper", &b.upper)?;
            if let Some(i) = (0..3).find(|&i| !(b.lower[i] < b.upper[i])) {
                return Err(PhriError::invalid(
                    "tool_box",
                    format!("lower[{i}] = {} m must be below upper[{i}] = {} m", b.lower[i], b.upper[i]),
                ));
            }
        }
        if !(params.period.is_finite() && params.period > 0.0) {
            return Err(PhriError::invalid("period", format!("must be a finite time > 0 s, got {}", params.period)));
        }
        if !(params.late_after.is_finite() && params.late_after >= 1.0) {
            return Err(PhriError::invalid(
                "late_after",
                format!("must be a finite number of periods >= 1, got {}", params.late_after),
            ));
        }
        if params.late_ticks == 0 {
            return Err(PhriError::invalid("late_ticks", "must be >= 1"));
        }
        let rate_step = limits.torque_rate.iter().map(|r| r * params.period).collect();
        Ok(SafetyLayer {
            data: model.data(),
            tool,
            limits,
            params,
            rate_step,
            previous: vec![0.0; n],
            has_previous: false,
            gravity: vec![0.0; n],
            previous_t: f64::NAN,
            late_in_a_row: 0,
            torque_clips: vec![0; n],
            rate_clips: vec![0; n],
            model,
        })
    }

    pub fn limits(&self) -> &SafetyLimits {
        &self.limits
    }

    pub fn params(&self) -> &SafetyParams {
        &self.params
    }

    pub fn model(&self) -> &Arc<RobotModel> {
        &self.model
    }

    pub fn tool(&self) -> FrameId {
        self.tool
    }

    /// Per joint, the ticks whose torque was clipped to the torque limit since [`reset`](Self::reset).
    pub fn torque_clips(&self) -> &[u64] {
        &self.torque_clips
    }

    /// Per joint, the ticks whose command was clipped to the torque-rate limit since the reset.
    pub fn rate_clips(&self) -> &[u64] {
        &self.rate_clips
    }

    /// Starts a motion: forgets the clock, the late ticks and the counts. `previous_command` [N·m]
    /// is the command the arm holds now, from which the first command's rate is limited (zero for
    /// an arm that compensates gravity and is at rest); None leaves the first command free (a
    /// simulator whose arm must hold its weight from its first step).
    pub fn reset(&mut self, previous_command: Option<&[f64]>) -> Result<()> {
        match previous_command {
            Some(c) => {
                check_vector("previous_command", c, self.model.nq())?;
                self.previous.copy_from_slice(c);
                self.has_previous = true;
            }
            None => self.has_previous = false,
        }
        self.previous_t = f64::NAN;
        self.late_in_a_row = 0;
        self.torque_clips.fill(0);
        self.rate_clips.fill(0);
        Ok(())
    }

    /// Checks the state read at robot time `t` [s]: q [rad], q̇ [rad/s], τ_ext [N·m], each of the
    /// model's joint count (else an error). Returns the first limit crossed, in this order: a
    /// non-finite value, a clock that did not advance, late ticks, joint positions, joint velocities, the tool box.
    pub fn check_state(&mut self, t: f64, q: &[f64], qd: &[f64], tau_ext: &[f64]) -> Result<SafetyStatus> {
        let n = self.model.nq();
        for (arg, v) in [("q", q), ("qd", qd), ("tau_ext", tau_ext)] {
            if v.len() != n {
                return Err(PhriError::shape(arg, format!("({n},)"), format!("({},)", v.len())));
            }
        }
        if !t.is_finite() {
            return Ok(SafetyStatus::stop(non_finite(Quantity::Time, 0, t)));
        }
        for (quantity, v) in [(Quantity::Position, q), (Quantity::Velocity, qd), (Quantity::ExternalTorque, tau_ext)] {
            if let Some(j) = v.iter().position(|x| !x.is_finite()) {
                return Ok(SafetyStatus::stop(non_finite(quantity, j, v[j])));
            }
        }
        let gap = t - self.previous_t; // NaN at the first tick: neither late nor stalled
        self.previous_t = t;
        if gap <= 0.0 {
            return Ok(SafetyStatus::stop(Violation {
                limit: Limit::Clock,
                quantity: Quantity::TickGap,
                index: 0,
                value: gap,
                bound: 0.0,
            }));
        }
        let late = self.params.late_after * self.params.period;
        if gap > late {
            self.late_in_a_row += 1;
            if self.late_in_a_row >= self.params.late_ticks {
                let index = self.late_in_a_row as usize;
                return Ok(SafetyStatus::stop(Violation {
                    limit: Limit::LateTicks,
                    quantity: Quantity::TickGap,
                    index,
                    value: gap,
                    bound: late,
                }));
            }
        } else {
            self.late_in_a_row = 0;
        }
        let l = &self.limits;
        for j in 0..n {
            let bound = if q[j] < l.position_lower[j] {
                l.position_lower[j]
            } else if q[j] > l.position_upper[j] {
                l.position_upper[j]
            } else {
                continue;
            };
            return Ok(SafetyStatus::stop(Violation {
                limit: Limit::JointPosition,
                quantity: Quantity::Position,
                index: j,
                value: q[j],
                bound,
            }));
        }
        for j in 0..n {
            if qd[j].abs() > l.velocity[j] {
                let bound = l.velocity[j].copysign(qd[j]);
                return Ok(SafetyStatus::stop(Violation {
                    limit: Limit::JointVelocity,
                    quantity: Quantity::Velocity,
                    index: j,
                    value: qd[j],
                    bound,
                }));
            }
        }
        if let Some(b) = l.tool_box {
            self.model.forward_kinematics_unchecked(q, &mut self.data);
            let p = self.model.frame_pose(self.tool, &self.data).translation.vector;
            for i in 0..3 {
                let bound = if p[i] < b.lower[i] {
                    b.lower[i]
                } else if p[i] > b.upper[i] {
                    b.upper[i]
                } else {
                    continue;
                };
                return Ok(SafetyStatus::stop(Violation {
                    limit: Limit::ToolBox,
                    quantity: Quantity::ToolPosition,
                    index: i,
                    value: p[i],
                    bound,
                }));
            }
        }
        Ok(SafetyStatus::default())
    }

    /// Limits the joint torque `tau` [N·m] (in: the law's, out: the torque the arm applies) at
    /// joint positions `q` [rad], and writes the command to send into `command` [N·m]: `tau` less
    /// g(q) for an arm that compensates gravity, else `tau`. Each |τ_j| is clipped to its torque
    /// limit and the command's change since the previous tick to its torque-rate limit × period
    /// (then the torque limit again, the harder one). A non-finite torque is a violation and leaves
    /// `command` at the previous command (zero without one).
    pub fn limit_torque(&mut self, q: &[f64], tau: &mut [f64], command: &mut [f64]) -> Result<SafetyStatus> {
        let n = self.model.nq();
        check_vector("q", q, n)?;
        for (arg, v) in [("tau", &*tau), ("command", &*command)] {
            if v.len() != n {
                return Err(PhriError::shape(arg, format!("({n},)"), format!("({},)", v.len())));
            }
        }
        if let Some(j) = tau.iter().position(|x| !x.is_finite()) {
            let value = tau[j];
            if self.has_previous {
                command.copy_from_slice(&self.previous);
            } else {
                command.fill(0.0);
            }
            return Ok(SafetyStatus::stop(non_finite(Quantity::Torque, j, value)));
        }
        if self.params.gravity_compensated {
            self.model.forward_kinematics_unchecked(q, &mut self.data);
            self.model.gravity_after_fk(&mut self.data, &mut self.gravity);
        }
        let mut status = SafetyStatus::default();
        for j in 0..n {
            let limit = self.limits.torque[j];
            let g = if self.params.gravity_compensated { self.gravity[j] } else { 0.0 };
            let mut total = tau[j];
            if total.abs() > limit {
                total = total.clamp(-limit, limit);
                status.torque_saturated |= 1 << j.min(63);
            }
            let mut c = if self.params.gravity_compensated { total - g } else { total };
            if self.has_previous {
                let (low, high) = (self.previous[j] - self.rate_step[j], self.previous[j] + self.rate_step[j]);
                if c < low || c > high {
                    c = c.clamp(low, high);
                    status.rate_saturated |= 1 << j.min(63);
                    // The torque limit is the harder one: a command held back by the rate limit
                    // must still keep the applied torque within it.
                    c = if self.params.gravity_compensated { (c + g).clamp(-limit, limit) - g } else { c.clamp(-limit, limit) };
                }
            }
            command[j] = c;
            tau[j] = if self.params.gravity_compensated { c + g } else { c };
            self.previous[j] = c;
            if status.torque_saturated & (1 << j.min(63)) != 0 {
                self.torque_clips[j] += 1;
            }
            if status.rate_saturated & (1 << j.min(63)) != 0 {
                self.rate_clips[j] += 1;
            }
        }
        self.has_previous = true;
        Ok(status)
    }
}

fn non_finite(quantity: Quantity, index: usize, value: f64) -> Violation {
    Violation { limit: Limit::NonFinite, quantity, index, value, bound: f64::NAN }
}
