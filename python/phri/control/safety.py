"""The limits of the control loop's safety layer, from the robot description and the task.

A robot description's ``[safety]`` table (``python/phri/robots/<robot>/robot.toml``) gives the
robot's joint limits for the loop: a position margin inside the URDF's limits, velocity and torque
limits (default: the URDF's) and a torque-rate limit. A task's ``[safety]`` table gives the box the
tool point must stay in and may tighten the robot's limits, never loosen them.
:func:`safety_limits` combines the two into :class:`SafetyLimits`, and
:meth:`SafetyLimits.layer` makes the per-tick checks (:class:`phri.SafetyLayer`, in the Rust core).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phri._phri import Robot, SafetyLayer
from phri.config import Task
from phri.exceptions import ConfigError
from phri.robots import RobotDescription, SafetySpec
from phri.robots import load as load_description

__all__ = ["LATE_AFTER", "LATE_TICKS", "SafetyLimits", "safety_limits"]

#: A tick more than this many control periods after the previous one (on the robot's clock) is
#: late: the robot ticked at least once without a command from phri (the core's default, 1.5).
LATE_AFTER: float = SafetyLayer.LATE_AFTER
#: This many late ticks in a row stop the arm (libfranka itself aborts after a few lost commands;
#: the core's default, 3).
LATE_TICKS: int = SafetyLayer.LATE_TICKS


@dataclass(frozen=True, eq=False)
class SafetyLimits:
    """The limits the safety layer holds the arm to; one entry per joint in each array.

    The loop stops the arm when a joint leaves the interval from `position_lower` to
    `position_upper` [rad] (the URDF's limits less the margin; ±inf for a continuous joint), moves
    faster than `velocity` [rad/s], or
    the origin of frame `tool` leaves `tool_box` (lower, upper corners [m] in the base frame; None:
    anywhere); it clips the torque to `torque` [N·m] and the command's rate of change to
    `torque_rate` [N·m/s]. `source` says where the limits came from (for messages)."""

    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    torque_rate: np.ndarray
    tool: str
    tool_box: tuple[np.ndarray, np.ndarray] | None = None
    source: str = "<memory>"

    def layer(
        self,
        robot: Robot,
        *,
        period: float,
        gravity_compensated: bool,
        late_after: float = LATE_AFTER,
        late_ticks: int = LATE_TICKS,
    ) -> SafetyLayer:
        """The per-tick checks of these limits for `robot` at control `period` [s]; see
        :class:`phri.SafetyLayer` (which checks every value and names a bad one)."""
        return SafetyLayer(
            robot,
            tool=self.tool,
            position_lower=self.position_lower,
            position_upper=self.position_upper,
            velocity=self.velocity,
            torque=self.torque,
            torque_rate=self.torque_rate,
            tool_box=self.tool_box,
            period=period,
            late_after=late_after,
            late_ticks=late_ticks,
            gravity_compensated=gravity_compensated,
        )


def _per_joint(spec: SafetySpec, key: str, n: int, where: str) -> np.ndarray | None:
    """`spec`'s `key` as n values (one number is every joint's), None if not given."""
    value = getattr(spec, key)
    if value is None:
        return None
    if isinstance(value, float):
        return np.full(n, value)
    if len(value) != n:
        raise ConfigError(
            f"{spec.source}: key '{where}{key}' must be one number or {n} (one per joint), got {len(value)}"
        )
    return np.array(value, dtype=float)


def safety_limits(
    robot: Robot, description: str | RobotDescription, task: Task | None = None
) -> SafetyLimits:
    """The safety layer's limits for `robot`, read from its `description` (a shipped robot's name,
    a ``robot.toml`` path, or a loaded :class:`phri.robots.RobotDescription`) and `task`'s
    ``[safety]`` table.

    Per joint: position bounds = the URDF's limits less ``position_margin`` (default 0 rad); velocity
    and torque limits = the description's, else the URDF's; the torque-rate limit = the
    description's (required: the URDF has none). A task's values must be at least as tight (its
    margin at least as wide); the tool is the description's hand frame, its box the task's. Errors
    (ConfigError) name the file and the key."""
    d = description if isinstance(description, RobotDescription) else load_description(description)
    n = robot.nq
    own = d.safety
    margin = _per_joint(own, "position_margin", n, "safety.")
    velocity = _per_joint(own, "velocity_limits", n, "safety.")
    torque = _per_joint(own, "torque_limits", n, "safety.")
    rate = _per_joint(own, "torque_rate_limit", n, "safety.")
    if rate is None:
        raise ConfigError(
            f"{d.source}: key 'safety.torque_rate_limit' is missing: the control loop needs the robot's "
            "torque-rate limit [N·m/s] (one number, or one per joint)"
        )
    efforts = robot.effort_limits
    if torque is not None and (torque > efforts).any():
        j = int(np.argmax(torque > efforts))
        raise ConfigError(
            f"{d.source}: key 'safety.torque_limits' must not exceed the URDF's efforts: joint {j} "
            f"{torque[j]:g} N·m > {efforts[j]:g} N·m"
        )
    limits = {
        "position_margin": np.zeros(n) if margin is None else margin,
        "velocity_limits": robot.velocity_limits if velocity is None else velocity,
        "torque_limits": efforts if torque is None else torque,
        "torque_rate_limit": rate,
    }
    sources = [d.source]
    tool_box = None
    if task is not None:
        sources.append(task.source)
        for key, robot_value in limits.items():
            value = _per_joint(task.safety.limits, key, n, "safety.")
            if value is None:
                continue
            # The margin tightens as it grows, the other limits as they shrink.
            looser = value < robot_value if key == "position_margin" else value > robot_value
            if looser.any():
                j = int(np.argmax(looser))
                relation = "below" if key == "position_margin" else "above"
                raise ConfigError(
                    f"{task.source}: key 'safety.{key}' may only tighten the robot's ({d.source}): "
                    f"joint {j} {value[j]:g} is {relation} the robot's {robot_value[j]:g}"
                )
            limits[key] = value
        if task.safety.tool_box is not None:
            box_lower, box_upper = task.safety.tool_box
            tool_box = (np.array(box_lower, dtype=float), np.array(box_upper, dtype=float))
    margin = limits["position_margin"]
    lower, upper = robot.lower_limits + margin, robot.upper_limits - margin
    for j in range(n):
        if math.isfinite(lower[j]) and not lower[j] <= upper[j]:
            raise ConfigError(
                f"{' and '.join(sources)}: position_margin {margin[j]:g} rad is wider than half of "
                f"joint {j}'s range [{robot.lower_limits[j]:g}, {robot.upper_limits[j]:g}] rad"
            )
    if d.hand_frame is None:
        raise ConfigError(f"{d.source}: key 'hand_frame' is missing: the tool box is about the hand frame")
    return SafetyLimits(
        position_lower=lower,
        position_upper=upper,
        velocity=limits["velocity_limits"],
        torque=limits["torque_limits"],
        torque_rate=limits["torque_rate_limit"],
        tool=d.hand_frame,
        tool_box=tool_box,
        source=" and ".join(sources),
    )
