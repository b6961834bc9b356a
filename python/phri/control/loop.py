"""The one control loop of phri, for simulation and hardware alike.

:class:`ControlLoop` drives any :class:`~phri.control.backend.Backend` (the PyBullet JACO2 of the
simulated study, a Franka over libfranka) at the backend's control rate. One tick:

1. read the arm's state (blocks until the arm's tick);
2. the safety layer checks it (:meth:`phri.control.SafetyLayer.check_state`: non-finite values,
   the clock, late ticks, joint positions and velocities, the tool's box);
3. ``learner.observe(t, tau_ext)``: the learner samples the person's torque on its own grid and
   returns at once between samples (replans never hold the tick up); a last tick that comes late,
   past the motion's end, is observed at the end; a failed replan worker
   (:class:`~phri.exceptions.ReplanWorkerError`) leaves the arm on its plan and the motion goes on
   (``LoopResult.replan_failures``);
4. ``learner.reference(t)``: the reference q_R, q̇_R to track;
5. the impedance torque (:meth:`phri.ImpedanceController.torque_implicit`, or
   :meth:`~phri.ImpedanceController.torque` for a real arm: ``implicit=False``; with the task's
   scene so the run-time clearance wall acts), including g(q);
6. the safety layer limits it (:meth:`phri.control.SafetyLayer.limit_torque`: torque and
   torque-rate limits, clips counted; the first command's rate from what the arm applies at rest
   where it starts: zero, or g(q) for an arm that does not compensate gravity) and makes the
   command: the torque less g(q) for an arm that compensates gravity itself
   (``backend.gravity_compensated``);
7. write the command.

The watchdog stops the arm on a violation (a non-finite value, a limit crossed, late ticks, a clock
that does not advance), a lost connection (:class:`~phri.exceptions.ConnectionLostError` from the
backend) or the robot's own fault (``RobotState.fault``, or
:class:`~phri.exceptions.RobotFaultError` from the backend). Stopping holds the position: the
reference becomes the position at the stop with zero velocity, which the impedance law holds for
``hold_time`` seconds of robot time; then the loop ends the motion and calls ``backend.stop()``.
When the state cannot be trusted (non-finite q or q̇, a stalled clock) or the arm no longer takes
commands (lost connection, robot fault) there is nothing to hold with, and the motion ends at once.
Every stop is a :class:`StopEvent` (the reason and the state that caused it) in the loop's result
(and a warning on the ``phri.control.loop`` logger);
``run(check=True)`` then raises :class:`~phri.exceptions.SafetyStopError` with it, after the log is
complete. Any other error ends the motion (``backend.stop()``) and is raised, the log so far kept in
:attr:`ControlLoop.result`.

While it runs the loop keeps Python's garbage collector out of the tick (``gc.freeze()`` and
``gc.disable()``, restored afterwards, also on an error), and per tick it allocates no arrays of its
own: the reference, torque and command live in buffers made once; the Rust calls allocate nothing.
"""

from __future__ import annotations

import gc
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phri._phri import (
    GRID_TOLERANCE,
    MAX_LOG_ROWS,
    SAFETY_LIMITS,
    ImpedanceController,
    Learner,
    SafetyViolation,
)
from phri.control.backend import Backend, RobotState
from phri.control.safety import LATE_AFTER, LATE_TICKS, SafetyLimits
from phri.exceptions import (
    ConnectionLostError,
    InvalidParameterError,
    ReplanWorkerError,
    RobotFaultError,
    SafetyStopError,
)

logger = logging.getLogger(__name__)

__all__ = [
    "HOLD_TIME",
    "LOG_RATE",
    "STOP_REASONS",
    "ControlLoop",
    "LoopResult",
    "StopEvent",
]

#: How long a stop holds the position before the motion ends [s of robot time].
HOLD_TIME = 0.5
#: The loop's log rate [Hz].
LOG_RATE = 100.0
#: Why the watchdog may stop the arm: the safety layer's limits (:data:`phri.control.SAFETY_LIMITS`),
#: a lost connection, or the robot's own fault.
STOP_REASONS = (*SAFETY_LIMITS, "connection_lost", "robot_fault")
# MAX_LOG_ROWS: most rows of a run's log (made at the start, about 300 bytes a row for 7 joints:
# 300 MB; 2.8 hours at the default log rate): a longer run is refused before it starts, not a
# MemoryError. GRID_TOLERANCE: a tick on the log's time grid within this fraction of a log period
# counts as on it (tick times carry rounding), as the learner's sample grid does. Both are the
# core's, which its simulated loop (phri.SimulatedLoop) and learner use.

#: Called every tick with (tick index, state, log row written at this tick or -1), after the
#: command is made and before it is written (a simulation logs what only it knows, renders frames).
TickHook = Callable[[int, RobotState, int], None]


@dataclass(frozen=True, eq=False)
class StopEvent:
    """A stop of the arm: why, and the state that caused it.

    `reason` is one of :data:`STOP_REASONS`; `message` says it in words. `tick` is the tick's index
    and `t` its robot time [s]; `q` [rad], `qd` [rad/s] and `tau_ext` [N·m] the state read, `tau`
    [N·m] the joint torque last computed (the offending one for a non-finite torque). For a limit,
    `quantity` names the value ("q", "qd", "tau_ext", "tau", "t", "tool_position", "tick_gap"),
    `index` its joint (the axis for the tool, the late ticks in a row for late ticks), `value` the
    offending value and `bound` the limit it crossed (NaN where none applies; `index` -1)."""

    reason: str
    message: str
    tick: int
    t: float
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    tau_ext: np.ndarray
    quantity: str = ""
    index: int = -1
    value: float = math.nan
    bound: float = math.nan

    #: The log keys of a stop (:meth:`arrays`); every key starts with ``stop_``.
    KEYS = (
        "stop_reason", "stop_message", "stop_tick", "stop_t", "stop_q", "stop_qd", "stop_tau",
        "stop_tau_ext", "stop_quantity", "stop_index", "stop_value", "stop_bound",
    )  # fmt: skip

    def arrays(self) -> dict[str, np.ndarray]:
        """The event as log arrays, one row each (:meth:`empty_arrays` has the same keys, no row)."""
        return {
            "stop_reason": np.array([self.reason]),
            "stop_message": np.array([self.message]),
            "stop_tick": np.array([self.tick]),
            "stop_t": np.array([self.t]),
            "stop_q": self.q[None, :],
            "stop_qd": self.qd[None, :],
            "stop_tau": self.tau[None, :],
            "stop_tau_ext": self.tau_ext[None, :],
            "stop_quantity": np.array([self.quantity]),
            "stop_index": np.array([self.index]),
            "stop_value": np.array([self.value]),
            "stop_bound": np.array([self.bound]),
        }

    @staticmethod
    def empty_arrays(nq: int) -> dict[str, np.ndarray]:
        """The log arrays of an episode without a stop: every key of :meth:`arrays`, no row."""
        joints = np.zeros((0, nq))
        return {
            "stop_reason": np.array([], dtype=str),
            "stop_message": np.array([], dtype=str),
            "stop_tick": np.zeros(0, dtype=int),
            "stop_t": np.zeros(0),
            "stop_q": joints,
            "stop_qd": joints.copy(),
            "stop_tau": joints.copy(),
            "stop_tau_ext": joints.copy(),
            "stop_quantity": np.array([], dtype=str),
            "stop_index": np.zeros(0, dtype=int),
            "stop_value": np.zeros(0),
            "stop_bound": np.zeros(0),
        }

    @classmethod
    def from_arrays(cls, log: Any) -> StopEvent | None:
        """The stop recorded in a log (a mapping or an open .npz), or None if it records none."""
        if len(log["stop_reason"]) == 0:
            return None
        return cls(
            reason=str(log["stop_reason"][0]),
            message=str(log["stop_message"][0]),
            tick=int(log["stop_tick"][0]),
            t=float(log["stop_t"][0]),
            q=np.array(log["stop_q"][0]),
            qd=np.array(log["stop_qd"][0]),
            tau=np.array(log["stop_tau"][0]),
            tau_ext=np.array(log["stop_tau_ext"][0]),
            quantity=str(log["stop_quantity"][0]),
            index=int(log["stop_index"][0]),
            value=float(log["stop_value"][0]),
            bound=float(log["stop_bound"][0]),
        )

    def __str__(self) -> str:
        return f"safety stop at t = {self.t:.3f} s ({self.reason}): {self.message}"


@dataclass
class LoopResult:
    """What a run of the loop did, filled as it runs (so an error keeps what came before)."""

    #: Ticks run (including those holding after a stop).
    ticks: int = 0
    #: The log at the loop's log rate: ``t`` [s] (robot time), ``q`` [rad], ``qd`` [rad/s],
    #: ``q_ref`` [rad] (the reference tracked; the held position after a stop), ``tau`` [N·m] (the
    #: joint torque applied, g(q) included), ``tau_ext`` [N·m] (the measured external torque) and
    #: ``wall_force`` [N] (the virtual wall's largest total force since the previous row).
    log: dict[str, np.ndarray] = field(default_factory=dict)
    #: The stop, or None if the motion ran to its end.
    stop: StopEvent | None = None
    #: How long the arm held its position after the stop [s of robot time] (0 without a hold).
    held: float = 0.0
    #: Per joint, the ticks whose torque the safety layer clipped to its limit, and those whose
    #: command it clipped to its rate limit.
    torque_clips: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint64))
    rate_clips: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint64))
    #: Replans the learner's worker failed (:class:`~phri.exceptions.ReplanWorkerError`, a bug in
    #: phri, logged as an error): the arm kept the plan it tracked and the motion went on.
    replan_failures: int = 0
    #: Ticks at which the virtual wall acted, and its largest total force [N].
    wall_ticks: int = 0
    wall_peak_force: float = 0.0
    #: The stop as the error :meth:`raise_for_stop` raises (None without a stop).
    error: SafetyStopError | None = None

    def raise_for_stop(self) -> None:
        """Raises :class:`~phri.exceptions.SafetyStopError` (its ``event`` the :class:`StopEvent`)
        if the arm was stopped."""
        if self.error is not None:
            raise self.error


class _Log:
    """The loop's log rows at the log rate, in arrays made once."""

    def __init__(self, rows: int, nq: int) -> None:
        self.rows = 0
        self.t = np.zeros(rows)
        self.q, self.qd, self.q_ref, self.tau, self.tau_ext = (np.zeros((rows, nq)) for _ in range(5))
        self.wall_force = np.zeros(rows)

    def arrays(self) -> dict[str, np.ndarray]:
        n = self.rows
        return {
            "t": self.t[:n].copy(),
            "q": self.q[:n].copy(),
            "qd": self.qd[:n].copy(),
            "q_ref": self.q_ref[:n].copy(),
            "tau": self.tau[:n].copy(),
            "tau_ext": self.tau_ext[:n].copy(),
            "wall_force": self.wall_force[:n].copy(),
        }


class _Stop(Exception):
    """Internal: the tick found a reason to stop; `hold` says whether the arm can hold."""

    def __init__(self, event: StopEvent, hold: bool) -> None:
        super().__init__(event.message)
        self.event, self.hold = event, hold


class ControlLoop:
    """The control loop over `backend` (see the module documentation for a tick).

    `learner` supplies ``observe(t, tau_ext)`` and ``reference(t, out=(q, qd, qdd))`` (a
    :class:`phri.Learner`); `controller` is the impedance law, made with
    ``gravity_compensation=True`` (the loop removes g(q) itself for an arm that compensates
    gravity). `limits` are the safety layer's (:func:`phri.control.safety_limits`).

    `hold_time` [s]: how long a stop holds the position (robot time, >= 0). `late_ticks`: this many
    late ticks in a row stop the arm; a tick is late when it comes more than `late_after` periods
    after the previous one, on the robot's clock. `log_rate` [Hz]: the rate of the loop's log.
    `on_tick`: called every tick with (tick, state, log row or -1) before the command is written.

    `implicit`: the impedance law discretised implicitly (:meth:`phri.ImpedanceController.torque_implicit`,
    the default), for a simulator that integrates explicitly an arm without rotor inertia (PyBullet's
    JACO2), where the explicit law goes unstable at 1 kHz. False: the explicit law
    (:meth:`~phri.ImpedanceController.torque`), for a real arm, whose rotors' inertia keeps it stable
    (libfranka's own joint-impedance examples). The implicit law divides by phri's model's inertia,
    which has no rotors: on an FR3's wrist (link inertia about 0.002 kg·m², rotor 0.07) its static
    stiffness would be about a tenth of the gains.
    """

    def __init__(
        self,
        backend: Backend,
        learner: Learner,
        controller: ImpedanceController,
        limits: SafetyLimits,
        *,
        hold_time: float = HOLD_TIME,
        late_ticks: int = LATE_TICKS,
        late_after: float = LATE_AFTER,
        log_rate: float = LOG_RATE,
        on_tick: TickHook | None = None,
        implicit: bool = True,
    ) -> None:
        if not isinstance(backend, Backend):
            raise InvalidParameterError(
                f"backend must implement phri.control.Backend (robot, period, gravity_compensated, "
                f"start, read, write, stop), got {type(backend).__name__}"
            )
        period = float(backend.period)
        if not (math.isfinite(period) and period > 0):
            raise InvalidParameterError(f"backend.period must be a finite time > 0 s, got {backend.period!r}")
        if not controller.gravity_compensation:
            raise InvalidParameterError(
                "controller must be made with gravity_compensation=True: the loop needs the law's g(q), "
                "and removes it itself for an arm that compensates gravity (backend.gravity_compensated)"
            )
        if (
            isinstance(hold_time, bool)
            or not isinstance(hold_time, int | float)
            or not (math.isfinite(hold_time) and hold_time >= 0)
        ):
            raise InvalidParameterError(f"hold_time must be a finite time >= 0 s, got {hold_time!r}")
        if isinstance(late_ticks, bool) or not isinstance(late_ticks, int) or late_ticks < 1:
            raise InvalidParameterError(f"late_ticks must be an integer >= 1, got {late_ticks!r}")
        if not (isinstance(log_rate, int | float) and 0 < log_rate <= 1.0 / period * (1 + GRID_TOLERANCE)):
            raise InvalidParameterError(
                f"log_rate must be in (0, {1.0 / period:g}] Hz (the control rate), got {log_rate!r}"
            )
        if not isinstance(implicit, bool):
            raise InvalidParameterError(f"implicit must be True or False, got {implicit!r}")
        self.backend, self.learner, self.controller, self.limits = backend, learner, controller, limits
        self.implicit = implicit
        self.period = period
        self.hold_time = float(hold_time)
        self.log_period = 1.0 / float(log_rate)
        self.on_tick = on_tick
        #: The per-tick safety checks (phri.control.SafetyLayer).
        self.safety = limits.layer(
            backend.robot,
            period=period,
            gravity_compensated=bool(backend.gravity_compensated),
            late_after=late_after,
            late_ticks=late_ticks,
        )
        n = backend.robot.nq
        #: The reference of the current tick: q_R [rad], q̇_R [rad/s], q̈_R [rad/s²].
        self.q_ref, self.qd_ref, self.qdd_ref = np.zeros(n), np.zeros(n), np.zeros(n)
        #: The joint torque of the current tick [N·m] (g(q) included) and the command written.
        self.tau, self.command = np.zeros(n), np.zeros(n)
        #: The result of the current (or last) run, filled as it runs.
        self.result = LoopResult()

    # -- running -----------------------------------------------------------------------------------

    def run(self, q_start: np.ndarray, duration: float, *, check: bool = True) -> LoopResult:
        """Runs one motion of `duration` seconds of robot time from `q_start` [rad] (where a
        simulator places the arm; a real arm must already be there) and returns its result.

        A safety stop holds the arm, ends the motion and, with `check`, raises
        :class:`~phri.exceptions.SafetyStopError` (the result stays in :attr:`result`); without
        it, the result carries the stop (``result.stop``, ``result.error``). Any other error ends
        the motion and is raised as it is, the log so far in :attr:`result`."""
        if (
            isinstance(duration, bool)
            or not isinstance(duration, int | float)
            or not (math.isfinite(duration) and duration > 0)
        ):
            raise InvalidParameterError(f"duration must be a finite time > 0 s, got {duration!r}")
        n = self.backend.robot.nq
        try:
            given = np.asarray(q_start)
        except ValueError:  # a ragged sequence
            given = np.asarray(None)
        if isinstance(q_start, np.ma.MaskedArray) or given.dtype.kind not in "iuf":
            # Not cast: a complex value would lose its imaginary part, a masked one its mask.
            raise TypeError(
                f"q_start must be an array of real numbers, got {type(q_start).__name__} of {given.dtype}"
            )
        q_start = given.astype(float)
        if q_start.shape != (n,):
            raise InvalidParameterError(f"q_start must have shape ({n},), got {q_start.shape}")
        if float(duration) + self.hold_time > (MAX_LOG_ROWS - 3) * self.log_period:
            raise InvalidParameterError(
                f"duration + hold_time ({duration:g} s + {self.hold_time:g} s) at log_rate "
                f"{1.0 / self.log_period:g} Hz would log more than {MAX_LOG_ROWS} rows: run shorter "
                "motions or lower log_rate"
            )
        rows = int(math.floor((duration + self.hold_time) / self.log_period + GRID_TOLERANCE)) + 3
        log = _Log(rows, n)
        result = self.result = LoopResult()
        # Garbage frozen now is collected after the run (unfreeze returns it to the oldest generation).
        enabled, froze = gc.isenabled(), gc.get_freeze_count() == 0
        gc.freeze()
        gc.disable()
        try:
            state = self.backend.start(q_start)
            self.safety.reset(self._at_rest(state))
            self._run(state, float(duration), result, log)
        finally:
            try:
                self.backend.stop()  # idempotent; ends the motion whatever happened
            finally:
                result.log = log.arrays()
                result.torque_clips = self.safety.torque_clips
                result.rate_clips = self.safety.rate_clips
                if froze:
                    gc.unfreeze()
                if enabled:
                    gc.enable()
        if check:
            result.raise_for_stop()
        return result

    def _run(self, state: RobotState, duration: float, result: LoopResult, log: _Log) -> None:
        """The ticks of one motion, then the hold after a stop."""
        backend, learner, controller, safety = self.backend, self.learner, self.controller, self.safety
        observe, reference, torque = learner.observe, learner.reference, self._law()
        check_state, limit_torque = safety.check_state, safety.limit_torque
        read, write, on_tick = backend.read, backend.write, self.on_tick
        q_ref, qd_ref, tau, command = self.q_ref, self.qd_ref, self.tau, self.command
        out = (self.q_ref, self.qd_ref, self.qdd_ref)
        period, log_period = self.period, self.log_period
        end = duration - 0.5 * period
        next_row = 0.0  # the log grid's next row, in log periods
        wall_row = 0.0  # the wall's largest force since the previous row [N]
        k = 0
        try:
            while True:
                t = state.t
                if state.fault is not None:
                    raise _Stop(self._event("robot_fault", state.fault, k, state), hold=False)
                violation = check_state(t, state.q, state.qd, state.tau_ext)
                if violation is not None:
                    raise self._violation(violation, k, state)
                try:
                    # A late last tick may come past the motion's end (the robot's clock jumped):
                    # the learner, which refuses times past its task's end, sees the end.
                    observe(t if t <= duration else duration, state.tau_ext)
                except ReplanWorkerError as e:
                    # The learner's worker failed (a bug in phri): as the learner promises, the arm
                    # keeps the plan it tracks, so the motion goes on; the failure is counted.
                    result.replan_failures += 1
                    logger.error("t = %.3f s: %s; the arm keeps its plan", t, e)
                reference(t, out=out)
                torque(state.q, state.qd, q_ref, qd_ref, period, out=tau)
                wall = controller.wall_force
                if wall > 0.0:
                    result.wall_ticks += 1
                    if wall > result.wall_peak_force:
                        result.wall_peak_force = wall
                    if wall > wall_row:
                        wall_row = wall
                violation = limit_torque(state.q, tau, command)
                if violation is not None:
                    raise self._violation(violation, k, state)
                row = -1
                position = t / log_period + GRID_TOLERANCE
                if position >= next_row:
                    next_row = math.floor(position) + 1.0
                    row = self._log_row(log, state, wall_row)
                    wall_row = 0.0
                if on_tick is not None:
                    on_tick(k, state, row)
                write(command)
                result.ticks = k + 1
                if t >= end:
                    return
                k += 1
                state = read()
        except _Stop as s:
            stop = s
        # Only the backend raises these (its read or write): `state` is the last state read.
        except ConnectionLostError as e:
            stop = _Stop(self._event("connection_lost", str(e), k, state), hold=False)
        except RobotFaultError as e:
            stop = _Stop(self._event("robot_fault", str(e), k, state), hold=False)
        result.stop = stop.event
        result.error = SafetyStopError(str(stop.event), stop.event)
        logger.warning("%s; %s", stop.event, "holding the position" if stop.hold else "ending the motion")
        if stop.hold:
            self._hold(state, k, result, log, next_row, wall_row)

    def _hold(
        self, state: RobotState, k: int, result: LoopResult, log: _Log, next_row: float, wall_row: float
    ) -> None:
        """Holds the position of `state` (the stop's) with the impedance law for the hold time;
        ends early when the state cannot be trusted or the arm stops answering."""
        controller, safety, on_tick, law = self.controller, self.safety, self.on_tick, self._law()
        q_ref, qd_ref, tau, command = self.q_ref, self.qd_ref, self.tau, self.command
        q_ref[:] = state.q
        qd_ref[:] = 0.0
        self.qdd_ref[:] = 0.0
        t_stop = state.t
        until = t_stop + self.hold_time - 0.5 * self.period
        period, log_period = self.period, self.log_period
        try:
            while True:
                law(state.q, state.qd, q_ref, qd_ref, period, out=tau)
                if safety.limit_torque(state.q, tau, command) is not None:
                    return  # a non-finite torque: nothing to hold with
                wall = controller.wall_force
                if wall > 0.0:
                    result.wall_ticks += 1
                    result.wall_peak_force = max(result.wall_peak_force, wall)
                    wall_row = max(wall_row, wall)
                row = -1
                position = state.t / log_period + GRID_TOLERANCE
                if position >= next_row:
                    next_row = math.floor(position) + 1.0
                    row = self._log_row(log, state, wall_row)
                    wall_row = 0.0
                if on_tick is not None:
                    on_tick(k, state, row)
                self.backend.write(command)
                result.ticks = k + 1
                result.held = state.t - t_stop
                if state.t >= until:
                    return
                state = self.backend.read()
                k += 1
                if state.fault is not None:
                    return
                violation = safety.check_state(state.t, state.q, state.qd, state.tau_ext)
                # Holding is the response to a limit crossed; only a state that cannot be trusted
                # (or a stalled clock, on which the hold would never end) ends it early.
                if violation is not None and _untrusted(violation):
                    return
        except (ConnectionLostError, RobotFaultError):
            return

    # -- helpers -----------------------------------------------------------------------------------

    def _law(self) -> Callable[..., np.ndarray]:
        """The impedance law as ``law(q, qd, q_ref, qd_ref, dt, out=tau)``: implicit or explicit."""
        if self.implicit:
            return self.controller.torque_implicit
        explicit = self.controller.torque

        def law(q: Any, qd: Any, q_ref: Any, qd_ref: Any, dt: float, out: np.ndarray) -> np.ndarray:
            return explicit(q, qd, q_ref, qd_ref, out=out)

        return law

    def _at_rest(self, state: RobotState) -> np.ndarray | None:
        """What the arm applies at rest where it starts, from which the first command's rate is
        limited: nothing for an arm that compensates gravity, g(q) for one that does not (PyBullet,
        or a lab's own arm). None for a state that cannot be trusted: the first tick stops then,
        before any command."""
        n = self.backend.robot.nq
        if self.backend.gravity_compensated:
            return np.zeros(n)
        q = np.asarray(state.q, dtype=float)
        if q.shape != (n,) or not np.isfinite(q).all():
            return None
        return self.backend.robot.gravity(q)

    def _log_row(self, log: _Log, state: RobotState, wall_force: float) -> int:
        row = log.rows
        if row >= len(log.t):  # cannot happen on a clock that advances; never overwrite a row
            return -1
        log.t[row] = state.t
        log.q[row] = state.q
        log.qd[row] = state.qd
        log.q_ref[row] = self.q_ref
        log.tau[row] = self.tau
        log.tau_ext[row] = state.tau_ext
        log.wall_force[row] = wall_force
        log.rows = row + 1
        return row

    def _event(self, reason: str, message: str, k: int, state: RobotState, **limit: Any) -> StopEvent:
        return StopEvent(
            reason=reason,
            message=message,
            tick=k,
            t=float(state.t),
            q=np.array(state.q, dtype=float),
            qd=np.array(state.qd, dtype=float),
            tau=self.tau.copy(),
            tau_ext=np.array(state.tau_ext, dtype=float),
            **limit,
        )

    def _violation(self, v: SafetyViolation, k: int, state: RobotState) -> _Stop:
        """The stop for a violation; the arm holds unless the state itself cannot be trusted."""
        event = self._event(
            v.limit, v.message, k, state, quantity=v.quantity, index=v.index, value=v.value, bound=v.bound
        )
        return _Stop(event, hold=not _untrusted(v))


def _untrusted(v: SafetyViolation) -> bool:
    """Whether the state behind `v` cannot be held from: a non-finite time, position or velocity,
    or a clock that does not advance (a hold measured on it would never end)."""
    return (v.limit == "non_finite" and v.quantity in ("t", "q", "qd")) or v.limit == "clock"
