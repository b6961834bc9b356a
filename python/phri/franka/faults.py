"""Faults the scene server injects into the FR3 it simulates, so that a client's handling of a real
robot's failures can be tested over the real protocol: a reflex or error (the robot stops itself and
aborts the motion, as an FR3 does), a NaN in the state, late ticks, a stalled link, a dropped
connection.

A fault is written ``KIND[:ARGUMENT][@T]``:

``reflex[:ERROR[,ERROR...]]``
    The robot's reflex: it enters ``Reflex`` mode with the named libfranka errors (default
    ``joint_reflex``; e.g. ``reflex:joint_velocity_violation``) set in ``current_errors`` and
    ``last_motion_errors``, aborts a running motion (the Move command answers ``ReflexAborted``, so
    libfranka raises a ``ControlException`` naming the errors) and holds its position until
    ``automatic_error_recovery()``; a motion started before that is refused.
``user_stop[:S]``
    The user stop pressed for S seconds of robot time (default 1): ``UserStopped`` mode, a running
    motion aborted (``EmergencyAborted``), error recovery and new motions refused; released, the
    robot is idle again.
``nan[:FIELD]``
    One tick's state with NaN in ``q`` (default), ``dq`` or ``tau_ext`` (``tau_ext_hat_filtered``).
``late:N``
    N ticks (N ≥ 2) pass on the robot while the client hears nothing: the physics steps N times
    under the last command, then one state is sent; the robot's clock jumps N ms, which is how a
    client that missed ticks sees it on an FR3.
``stall:S``
    The link stalls for S seconds of wall time: nothing is stepped or sent. Beyond libfranka's own
    receive timeout the client loses the connection.
``drop``
    The server closes the client's connection (TCP and UDP) and keeps serving: the next command
    of the client fails as on a pulled cable.

``@T`` is the robot's time [s] since the client's torque-control motion started (faults with a time
wait for one); without it the fault happens at once (the control channel) or when torque control
starts (a schedule given at start). Each fault happens once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from phri.exceptions import InvalidParameterError

__all__ = ["ERROR_NAMES", "FAULT_KINDS", "NAN_FIELDS", "Fault"]

#: libfranka's error flags in the order of the robot's wire format (research interface ``Error``),
#: as ``franka::Errors`` names them (pylibfranka's ``Errors`` attributes). Checked name by name
#: against pylibfranka 0.21.3 in tests/test_franka_scene.py.
ERROR_NAMES: tuple[str, ...] = (
    "joint_position_limits_violation",
    "cartesian_position_limits_violation",
    "self_collision_avoidance_violation",
    "joint_velocity_violation",
    "cartesian_velocity_violation",
    "force_control_safety_violation",
    "joint_reflex",
    "cartesian_reflex",
    "max_goal_pose_deviation_violation",
    "max_path_pose_deviation_violation",
    "cartesian_velocity_profile_safety_violation",
    "joint_position_motion_generator_start_pose_invalid",
    "joint_motion_generator_position_limits_violation",
    "joint_motion_generator_velocity_limits_violation",
    "joint_motion_generator_velocity_discontinuity",
    "joint_motion_generator_acceleration_discontinuity",
    "cartesian_position_motion_generator_start_pose_invalid",
    "cartesian_motion_generator_elbow_limit_violation",
    "cartesian_motion_generator_velocity_limits_violation",
    "cartesian_motion_generator_velocity_discontinuity",
    "cartesian_motion_generator_acceleration_discontinuity",
    "cartesian_motion_generator_elbow_sign_inconsistent",
    "cartesian_motion_generator_start_elbow_invalid",
    "force_controller_desired_force_tolerance_violation",
    "start_elbow_sign_inconsistent",
    "communication_constraints_violation",
    "power_limit_violation",
    "cartesian_motion_generator_joint_position_limits_violation",
    "cartesian_motion_generator_joint_velocity_limits_violation",
    "cartesian_motion_generator_joint_velocity_discontinuity",
    "cartesian_motion_generator_joint_acceleration_discontinuity",
    "cartesian_position_motion_generator_invalid_frame",
    "controller_torque_discontinuity",
    "joint_p2p_insufficient_torque_for_planning",
    "tau_j_range_violation",
    "instability_detected",
    "joint_move_in_wrong_direction",
    "cartesian_spline_motion_generator_violation",
    "joint_via_motion_generator_planning_joint_limit_violation",
    "base_acceleration_initialization_timeout",
    "base_acceleration_invalid_reading",
)
#: The faults the scene server can inject (``KIND[:ARG][@T]``; see the module docstring).
FAULT_KINDS = ("reflex", "user_stop", "nan", "late", "stall", "drop")
#: State fields a ``nan`` fault can spoil (phri's names; tau_ext is libfranka's tau_ext_hat_filtered).
NAN_FIELDS = ("q", "dq", "tau_ext")
#: The longest stall [s] (a longer one only makes a test slower: libfranka gives up well before).
MAX_STALL = 60.0
#: The most ticks a ``late`` fault may skip.
MAX_LATE = 100_000


@dataclass(frozen=True)
class Fault:
    """One injected fault (see the module's documentation for the kinds and what each does)."""

    kind: str
    #: Robot time [s] since the torque-control motion started; None: at once / at its start.
    at: float | None = None
    #: reflex: the libfranka error names set.
    errors: tuple[str, ...] = ()
    #: nan: the state field spoilt.
    field: str = "q"
    #: late: the ticks that pass unheard.
    ticks: int = 0
    #: stall: the wall time [s] nothing is sent; user_stop: the robot time [s] it is pressed.
    seconds: float = 0.0

    @classmethod
    def parse(cls, spec: str) -> Fault:
        """The fault written `spec` (``KIND[:ARGUMENT][@T]``); a bad one is an InvalidParameterError
        naming what is wrong."""
        text = spec.strip()
        at: float | None = None
        if "@" in text:
            text, _, when = text.partition("@")
            at = _number(spec, "@T (robot time [s])", when)
            if at < 0:
                raise InvalidParameterError(f"fault {spec!r}: @T must be a robot time >= 0 s, got {at:g}")
        kind, _, argument = text.partition(":")
        kind = kind.strip()
        if kind == "reflex":
            names = tuple(n.strip() for n in argument.split(",") if n.strip()) or ("joint_reflex",)
            unknown = [n for n in names if n not in ERROR_NAMES]
            if unknown:
                raise InvalidParameterError(
                    f"fault {spec!r}: unknown libfranka error {', '.join(unknown)}; known: "
                    + ", ".join(ERROR_NAMES)
                )
            return cls("reflex", at, errors=names)
        if kind == "nan":
            field = argument.strip() or "q"
            if field not in NAN_FIELDS:
                raise InvalidParameterError(f"fault {spec!r}: nan takes one of {', '.join(NAN_FIELDS)}")
            return cls("nan", at, field=field)
        if kind == "late":
            ticks = _number(spec, "late:N (ticks)", argument)
            if ticks != int(ticks) or not 2 <= ticks <= MAX_LATE:
                raise InvalidParameterError(
                    f"fault {spec!r}: late:N takes a whole number of ticks in [2, {MAX_LATE}]"
                )
            return cls("late", at, ticks=int(ticks))
        if kind == "stall":
            seconds = _number(spec, "stall:S (seconds)", argument)
            if not 0 < seconds <= MAX_STALL:
                raise InvalidParameterError(f"fault {spec!r}: stall:S takes seconds in (0, {MAX_STALL:g}]")
            return cls("stall", at, seconds=seconds)
        if kind == "user_stop":
            seconds = _number(spec, "user_stop:S (seconds)", argument) if argument.strip() else 1.0
            if not 0 < seconds <= MAX_STALL:
                raise InvalidParameterError(
                    f"fault {spec!r}: user_stop:S takes seconds in (0, {MAX_STALL:g}]"
                )
            return cls("user_stop", at, seconds=seconds)
        if kind == "drop" and not argument:
            return cls("drop", at)
        raise InvalidParameterError(
            f"fault {spec!r}: expected KIND[:ARGUMENT][@T] with KIND one of {', '.join(FAULT_KINDS)} "
            "(drop takes no argument)"
        )

    def spec(self) -> str:
        """The fault written as :meth:`parse` reads it."""
        argument = {
            "reflex": ",".join(self.errors),
            "nan": self.field,
            "late": str(self.ticks),
            "stall": _text(self.seconds),
            "user_stop": _text(self.seconds),
        }.get(self.kind, "")
        return (
            self.kind
            + (f":{argument}" if argument else "")
            + (f"@{_text(self.at)}" if self.at is not None else "")
        )


def _text(value: float) -> str:
    """`value` as :meth:`Fault.parse` reads it back exactly: the shortest repr, without a trailing
    ``.0`` (``2``, ``0.5``, ``1234.5678``)."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def _number(spec: str, what: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InvalidParameterError(
            f"fault {spec!r}: {what} must be a number, got {text.strip()!r}"
        ) from None
    if not math.isfinite(value):
        raise InvalidParameterError(f"fault {spec!r}: {what} must be finite, got {text.strip()!r}")
    return value
