//! `phri.SafetyLayer`: the control loop's per-tick safety checks (phri_core::safety).
//!
//! Like the impedance step, a check is a microsecond: joint vectors take the borrowed fast path,
//! the GIL is kept, and a check returns None (nothing to report) or a `SafetyViolation`.

use numpy::{PyArray1, PyArrayMethods, PyReadwriteArray1, PyUntypedArrayMethods};
use phri_core::safety::{
    Limit, SafetyLayer, SafetyLimits, SafetyParams, SafetyStatus, ToolBox, Violation, DEFAULT_SAFETY_PARAMS,
};
use phri_core::{PhriError, MAX_MAGNITUDE};
use pyo3::prelude::*;

use crate::arrays::{vector, ArrayIn};
use crate::errors::{error, IntoPy, Kind};
use crate::impedance::Joints;
use crate::ints::count;
use crate::robot::PyRobot;

// The signature spells the core's defaults out (so that Python's help shows numbers).
const _: () = assert!(
    DEFAULT_SAFETY_PARAMS.period == 1e-3 && DEFAULT_SAFETY_PARAMS.late_after == 1.5 && DEFAULT_SAFETY_PARAMS.late_ticks == 3
);

/// A limit the safety layer found crossed: `limit` (one of SAFETY_LIMITS), the `quantity` it is
/// about ("t" [s], "q" [rad], "qd" [rad/s], "tau_ext" or "tau" [N·m], "tool_position" [m],
/// "tick_gap" [s]), `index` (the joint; the axis 0, 1, 2 = x, y, z for the tool; the late ticks in
/// a row for late ticks), the offending `value` and the `bound` it crossed (NaN for a non-finite
/// value), in the quantity's unit.
#[pyclass(name = "SafetyViolation", module = "phri._phri", frozen, eq)]
#[derive(PartialEq)]
pub struct PySafetyViolation {
    /// The limit crossed, one of SAFETY_LIMITS.
    #[pyo3(get)]
    limit: &'static str,
    /// What crossed it: "t" [s], "q" [rad], "qd" [rad/s], "tau_ext" or "tau" [N·m],
    /// "tool_position" [m] or "tick_gap" [s].
    #[pyo3(get)]
    quantity: &'static str,
    /// The joint; the axis (0, 1, 2 = x, y, z) for the tool; the late ticks in a row for late ticks.
    #[pyo3(get)]
    index: usize,
    /// The offending value, in the quantity's unit.
    #[pyo3(get)]
    value: f64,
    /// The bound it crossed, in the quantity's unit (NaN for a non-finite value).
    #[pyo3(get)]
    bound: f64,
}

impl From<Violation> for PySafetyViolation {
    fn from(v: Violation) -> Self {
        PySafetyViolation { limit: v.limit.name(), quantity: v.quantity.name(), index: v.index, value: v.value, bound: v.bound }
    }
}

#[pymethods]
impl PySafetyViolation {
    /// The violation in words, e.g. "joint 2 velocity qd = 0.95 rad/s beyond its limit 0.84 rad/s".
    #[getter]
    fn message(&self) -> String {
        let (v, b, i) = (self.value, self.bound, self.index);
        match self.limit {
            "non_finite" if v.is_finite() => {
                format!("{}[{i}] = {v:e} beyond ±{MAX_MAGNITUDE:e}: not a reading to trust", self.quantity)
            }
            "non_finite" => format!("non-finite {}[{i}] = {v}", self.quantity),
            "joint_position" => {
                format!("joint {i} position q = {v:.6} rad beyond its limit {b:.6} rad (the URDF's less the margin)")
            }
            "joint_velocity" => format!("joint {i} velocity qd = {v:.6} rad/s beyond its limit {b:.6} rad/s"),
            "tool_box" => format!("the tool's {} = {v:.6} m outside its box (bound {b:.6} m)", ["x", "y", "z"][i.min(2)]),
            "late_ticks" => format!("{i} late ticks in a row (the last {:.6} s after the previous, more than {:.6} s)", v, b),
            "clock" => format!("the robot's clock did not advance ({v:.6} s since the previous tick)"),
            other => format!("{other}: {} = {v}", self.quantity),
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "SafetyViolation(limit={:?}, quantity={:?}, index={}, value={:?}, bound={:?})",
            self.limit, self.quantity, self.index, self.value, self.bound
        )
    }
}

/// The per-tick safety checks of the control loop for `robot` (phri.control.loop builds one from
/// the robot description's and the task's [safety] tables; see phri.control.safety).
///
/// Limits, one value per joint: `position_lower`, `position_upper` [rad] (the URDF's limits less a
/// margin; ±inf for a continuous joint), `velocity` [rad/s], `torque` [N·m], `torque_rate` [N·m/s];
/// `tool_box` a (lower, upper) pair of (3,) corners [m, base frame] the point `tool` (a frame name)
/// must stay within, or None. `period` [s] is the control period; a tick more than `late_after`
/// periods after the previous one (on the robot's clock) is late, `late_ticks` late ticks in a row
/// are a violation. `gravity_compensated`: the arm adds g(q) itself, so the command written is the
/// torque less g(q).
///
/// Per tick: `check_state` on the state read (None, or the first limit crossed: a non-finite
/// value, the clock, late ticks, a joint position, a joint velocity, the tool box), then
/// `limit_torque` on the law's torque (clipped to `torque`, the command's rate to `torque_rate`,
/// both counted per joint; a non-finite torque is a violation). Neither allocates.
#[pyclass(name = "SafetyLayer", module = "phri._phri")]
pub struct PySafetyLayer {
    pub(crate) layer: SafetyLayer,
    status: SafetyStatus,
    tool: String,
}

fn limit_vector(arg: &str, a: &ArrayIn<'_>, n: usize, allow_infinite: bool) -> PyResult<Vec<f64>> {
    if allow_infinite {
        if a.shape() != [n] {
            return Err(error(Kind::Shape, format!("{arg} must have shape ({n},), got {:?}", a.shape())));
        }
        return Ok(a.as_array().iter().copied().collect());
    }
    Ok(vector(arg, a, n)?.into_owned())
}

fn corner(arg: &str, a: &ArrayIn<'_>) -> PyResult<[f64; 3]> {
    let v = vector(arg, a, 3)?;
    Ok([v[0], v[1], v[2]])
}

fn writable<'py>(arg: &str, a: &Bound<'py, PyArray1<f64>>, n: usize) -> PyResult<PyReadwriteArray1<'py, f64>> {
    if a.len() != n || !a.is_c_contiguous() {
        return Err(error(Kind::Shape, format!("{arg} must be a C-contiguous float64 array of shape ({n},)")));
    }
    a.try_readwrite()
        .map_err(|e| error(Kind::InvalidParameter, format!("{arg} must be a writable array distinct from the others ({e})")))
}

fn late_ticks_arg(value: &Bound<'_, PyAny>) -> PyResult<u32> {
    // u32::MAX fits a usize on every platform PyO3 supports.
    Ok(count("late_ticks", value, u32::MAX as usize)? as u32)
}

fn report(status: &SafetyStatus) -> Option<PySafetyViolation> {
    status.violation.map(PySafetyViolation::from)
}

#[pymethods]
impl PySafetyLayer {
    /// A tick more than this many control periods after the previous one is late (the default of
    /// `late_after`) [-].
    #[classattr]
    const LATE_AFTER: f64 = DEFAULT_SAFETY_PARAMS.late_after;

    /// This many late ticks in a row are a violation (the default of `late_ticks`).
    #[classattr]
    const LATE_TICKS: u32 = DEFAULT_SAFETY_PARAMS.late_ticks;

    #[new]
    #[pyo3(signature = (
        robot, *, tool, position_lower, position_upper, velocity, torque, torque_rate, tool_box = None,
        period = 1e-3, late_after = 1.5, late_ticks = 3, gravity_compensated = false
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        robot: PyRef<'_, PyRobot>,
        tool: String,
        position_lower: ArrayIn<'_>,
        position_upper: ArrayIn<'_>,
        velocity: ArrayIn<'_>,
        torque: ArrayIn<'_>,
        torque_rate: ArrayIn<'_>,
        tool_box: Option<(ArrayIn<'_>, ArrayIn<'_>)>,
        period: f64,
        late_after: f64,
        #[pyo3(from_py_with = late_ticks_arg)] late_ticks: u32,
        gravity_compensated: bool,
    ) -> PyResult<Self> {
        let model = robot.model.clone();
        let n = model.nq();
        let frame = model
            .frame_id(&tool)
            .map_err(|e| match e {
                PhriError::UnknownName { kind, name, known, .. } => {
                    PhriError::UnknownName { arg: "tool".into(), kind, name, known }
                }
                e => e,
            })
            .py_err()?;
        let tool_box = match &tool_box {
            Some((lower, upper)) => Some(ToolBox { lower: corner("tool_box[0]", lower)?, upper: corner("tool_box[1]", upper)? }),
            None => None,
        };
        let limits = SafetyLimits {
            position_lower: limit_vector("position_lower", &position_lower, n, true)?,
            position_upper: limit_vector("position_upper", &position_upper, n, true)?,
            velocity: limit_vector("velocity", &velocity, n, false)?,
            torque: limit_vector("torque", &torque, n, false)?,
            torque_rate: limit_vector("torque_rate", &torque_rate, n, false)?,
            tool_box,
        };
        let params = SafetyParams { period, late_after, late_ticks, gravity_compensated };
        let layer = SafetyLayer::new(model, frame, limits, params).py_err()?;
        Ok(PySafetyLayer { layer, status: SafetyStatus::default(), tool })
    }

    /// Starts a motion: forgets the clock, the late ticks and the clip counts. The first command's
    /// rate is limited from `previous_command` [N·m] (the command the arm holds now, e.g. zeros for
    /// an arm that compensates gravity), or not at all if None.
    #[pyo3(signature = (previous_command = None))]
    fn reset(&mut self, previous_command: Option<ArrayIn<'_>>) -> PyResult<()> {
        let n = self.layer.model().nq();
        let previous = previous_command.as_ref().map(|c| vector("previous_command", c, n)).transpose()?;
        self.status = SafetyStatus::default();
        self.layer.reset(previous.as_deref()).py_err()
    }

    /// Checks the state read at robot time `t` [s]: q [rad], qd [rad/s], tau_ext [N·m], each (n,).
    /// Returns None, or the first limit crossed as a SafetyViolation.
    fn check_state(&mut self, t: f64, q: Joints<'_>, qd: Joints<'_>, tau_ext: Joints<'_>) -> PyResult<Option<PySafetyViolation>> {
        let n = self.layer.model().nq();
        // Unchecked: a non-finite reading is the core's to report as a violation (the loop then stops
        // the arm); refusing it with an error would skip the hold.
        let (q, qd, tau_ext) = (q.unchecked("q", n)?, qd.unchecked("qd", n)?, tau_ext.unchecked("tau_ext", n)?);
        self.status = self.layer.check_state(t, &q, &qd, &tau_ext).py_err()?;
        Ok(report(&self.status))
    }

    /// Limits the law's joint torque at q [rad]: `tau` [N·m] (a writable float64 (n,) array) is
    /// clipped in place to the torque the arm applies, and `command` (another) receives what to
    /// write: tau, less g(q) if gravity_compensated. Returns None, or a SafetyViolation for a
    /// non-finite torque (the command then repeats the previous one, zero without one).
    fn limit_torque(
        &mut self,
        q: Joints<'_>,
        tau: &Bound<'_, PyArray1<f64>>,
        command: &Bound<'_, PyArray1<f64>>,
    ) -> PyResult<Option<PySafetyViolation>> {
        let n = self.layer.model().nq();
        let q = q.values("q", n)?;
        let mut tau = writable("tau", tau, n)?;
        let mut command = writable("command", command, n)?;
        let (Ok(tau), Ok(command)) = (tau.as_slice_mut(), command.as_slice_mut()) else {
            return Err(error(Kind::Shape, "tau and command must be C-contiguous"));
        };
        self.status = self.layer.limit_torque(&q, tau, command).py_err()?;
        Ok(report(&self.status))
    }

    /// Bit j set when the last limit_torque clipped joint j's torque to its limit.
    #[getter]
    fn torque_saturated(&self) -> u64 {
        self.status.torque_saturated
    }

    /// Bit j set when the last limit_torque clipped joint j's command to its rate limit.
    #[getter]
    fn rate_saturated(&self) -> u64 {
        self.status.rate_saturated
    }

    /// Per joint, the ticks whose torque was clipped to its limit since the last reset.
    #[getter]
    fn torque_clips<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        PyArray1::from_slice(py, self.layer.torque_clips())
    }

    /// Per joint, the ticks whose command was clipped to its rate limit since the last reset.
    #[getter]
    fn rate_clips<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        PyArray1::from_slice(py, self.layer.rate_clips())
    }

    /// Lowest joint positions allowed [rad].
    #[getter]
    fn position_lower<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.layer.limits().position_lower)
    }

    /// Highest joint positions allowed [rad].
    #[getter]
    fn position_upper<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.layer.limits().position_upper)
    }

    /// Velocity limits [rad/s].
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.layer.limits().velocity)
    }

    /// Torque limits [N·m].
    #[getter]
    fn torque<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.layer.limits().torque)
    }

    /// Torque-rate limits of the command [N·m/s].
    #[getter]
    fn torque_rate<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.layer.limits().torque_rate)
    }

    /// The tool's box as (lower, upper) corners [m, base frame], or None.
    #[getter]
    #[allow(clippy::type_complexity)]
    fn tool_box<'py>(&self, py: Python<'py>) -> Option<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        self.layer.limits().tool_box.map(|b| (PyArray1::from_slice(py, &b.lower), PyArray1::from_slice(py, &b.upper)))
    }

    /// The frame whose origin must stay in the tool box.
    #[getter]
    fn tool(&self) -> &str {
        &self.tool
    }

    /// The control period [s].
    #[getter]
    fn period(&self) -> f64 {
        self.layer.params().period
    }

    /// A tick is late after this many periods [-].
    #[getter]
    fn late_after(&self) -> f64 {
        self.layer.params().late_after
    }

    /// Late ticks in a row that are a violation.
    #[getter]
    fn late_ticks(&self) -> u32 {
        self.layer.params().late_ticks
    }

    /// Whether the command excludes g(q) (the arm compensates gravity itself).
    #[getter]
    fn gravity_compensated(&self) -> bool {
        self.layer.params().gravity_compensated
    }

    fn __repr__(&self) -> String {
        format!(
            "SafetyLayer(nq={}, tool={:?}, tool_box={}, period={}, late_ticks={}, gravity_compensated={})",
            self.layer.model().nq(),
            self.tool,
            if self.layer.limits().tool_box.is_some() { "set" } else { "None" },
            self.layer.params().period,
            self.layer.params().late_ticks,
            if self.layer.params().gravity_compensated { "True" } else { "False" }
        )
    }
}

/// The names of the limits a SafetyViolation can name (phri_core::safety::Limit).
pub fn limit_names() -> [&'static str; 6] {
    Limit::NAMES
}
