"""Moving a real arm to a pose before an episode: a slow, smooth joint motion under the control loop.

A simulator places its arm at an episode's start; a real arm has to be driven there, in a
torque-control motion of its own before the episode's (on franky-sim's scene server each motion is
one episode for the simulated person, who stays back during a motion that does not begin at the
task's start pose). :func:`plan_move` checks the motion before anything moves: both ends within
the safety layer's joint limits, no joint farther than ``max_move``, and the straight joint-space
path clear of the scene and inside the tool's box; the motion is a minimum-jerk profile whose
fastest joint peaks at ``speed`` × its rated velocity. :func:`move_to` runs it on
:class:`phri.control.ControlLoop` (the safety layer and the watchdog act every tick, the impedance
law's clearance wall too) and checks that the arm arrived within :data:`START_TOLERANCE`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from phri._phri import ImpedanceController, Learner, Robot, Scene
from phri.control import Backend, ControlLoop, LoopResult, RobotState, SafetyLimits
from phri.control.loop import TickHook
from phri.exceptions import InvalidParameterError, PlanningError

__all__ = [
    "MAX_MOVE",
    "MOVE_SPEED",
    "START_TOLERANCE",
    "JointMove",
    "check_move_options",
    "move_to",
    "plan_move",
]

#: The arm is at a pose when every joint is within this of it [rad] (0.02 rad moves the FR3's hand
#: by at most about 2 cm, half the simulated person's smallest tolerance).
START_TOLERANCE = 0.02
#: The move's default speed: its fastest joint peaks at this fraction of its rated velocity (the
#: FR3's joints 1-4: 0.26 rad/s, which moves the hand at most about 0.25 m/s).
MOVE_SPEED = 0.1
#: The fastest move allowed, as a fraction of the rated velocities.
MAX_MOVE_SPEED = 0.5
#: The farthest a move takes a joint [rad]; an arm farther from the start is brought closer by
#: hand (Desk's guiding mode) first.
MAX_MOVE = 1.5
#: The shortest move [s], and how long a move holds its goal after reaching it [s] (the arm
#: settles on the impedance law).
MIN_MOVE_TIME = 1.0
SETTLE_TIME = 0.5
#: Points of the straight path at which the scene and the tool box are checked per radian of the
#: largest joint distance (at least 10).
PATH_CHECKS_PER_RAD = 50
#: Slack on the scene's clearances [m]: measurement rounding, not a margin.
CLEARANCE_SLACK = 1e-4


@dataclass(frozen=True, eq=False)
class JointMove:
    """A minimum-jerk joint motion from `q_from` to `q_to` [rad] in `duration` [s], then holding
    `q_to` for `settle` [s]: the reference the control loop tracks (``observe`` and ``reference``
    as a :class:`phri.Learner` has them; it learns nothing)."""

    q_from: np.ndarray
    q_to: np.ndarray
    duration: float
    settle: float = SETTLE_TIME

    def __post_init__(self) -> None:
        for name, value, low in (("duration", self.duration, 0.0), ("settle", self.settle, None)):
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or (value <= 0 if low is not None else value < 0):
                bound = "> 0" if low is not None else ">= 0"
                raise InvalidParameterError(f"{name} must be a finite time {bound} s, got {value!r}")

    @property
    def total(self) -> float:
        """The motion and the settling [s]."""
        return self.duration + self.settle

    def observe(self, t: float, tau_measured: np.ndarray) -> tuple[bool, bool, bool]:
        """Nothing to learn during the move: (interacting, updated, replanned) all False."""
        return False, False, False

    def reference(self, t: float, *, out: Sequence[np.ndarray]) -> Sequence[np.ndarray]:
        """q_R [rad], q̇_R [rad/s], q̈_R [rad/s²] at `t` [s], written into `out`."""
        T = self.duration
        s = min(max(t / T, 0.0), 1.0)
        p = s * s * s * (10.0 + s * (-15.0 + 6.0 * s))
        dp = s * s * (30.0 + s * (-60.0 + 30.0 * s)) / T
        ddp = s * (60.0 + s * (-180.0 + 120.0 * s)) / (T * T)
        q, qd, qdd = out
        np.subtract(self.q_to, self.q_from, out=qdd)  # Δq, before it becomes the acceleration
        np.multiply(qdd, dp, out=qd)
        np.multiply(qdd, p, out=q)
        np.add(q, self.q_from, out=q)
        np.multiply(qdd, ddp, out=qdd)
        return out


def check_move_options(speed: object, max_move: object) -> None:
    """InvalidParameterError unless `speed` is a fraction of the rated joint velocities in
    (0, MAX_MOVE_SPEED] and `max_move` a joint distance in (0, π] rad."""
    if isinstance(speed, bool) or not (
        isinstance(speed, int | float) and math.isfinite(speed) and 0 < speed <= MAX_MOVE_SPEED
    ):
        raise InvalidParameterError(
            f"speed must be a fraction of the rated joint velocities in (0, {MAX_MOVE_SPEED:g}], "
            f"got {speed!r}"
        )
    if isinstance(max_move, bool) or not (isinstance(max_move, int | float) and 0 < max_move <= math.pi):
        raise InvalidParameterError(f"max_move must be a joint distance in (0, pi] rad, got {max_move!r}")


def plan_move(
    robot: Robot,
    limits: SafetyLimits,
    q_from: np.ndarray,
    q_to: np.ndarray,
    *,
    scene: Scene | None = None,
    speed: float = MOVE_SPEED,
    max_move: float = MAX_MOVE,
    what: str = "the start pose",
) -> JointMove:
    """The move from `q_from` (where the arm is) to `q_to` [rad], checked: both within the safety
    layer's joint limits (`limits`), no joint farther than `max_move` [rad], the straight joint
    path keeping every collision body at least each object of `scene` its margin away (or no
    nearer than at either end: the base on the table it stands on) and the tool inside the
    limits' box. Its duration makes the fastest joint peak at `speed` × its rated velocity (at
    least MIN_MOVE_TIME). A move that fails a check is a PlanningError saying what to do; `what`
    names `q_to` in messages."""
    n = robot.nq
    q_from, q_to = (np.asarray(q, dtype=float) for q in (q_from, q_to))
    for name, q in (("q_from", q_from), ("q_to", q_to)):
        if q.shape != (n,) or not np.isfinite(q).all():
            raise InvalidParameterError(f"{name} must be {n} finite joint positions [rad], got {q!r}")
    check_move_options(speed, max_move)
    for name, q in (("the arm", q_from), (what, q_to)):
        outside = (q < limits.position_lower) | (q > limits.position_upper)
        if outside.any():
            j = int(np.argmax(outside))
            raise PlanningError(
                f"{name} is outside the safety layer's joint limits ({limits.source}): joint {j + 1} at "
                f"{q[j]:.3f} rad, allowed [{limits.position_lower[j]:.3f}, {limits.position_upper[j]:.3f}] "
                "rad; bring the arm within them by hand (Desk's guiding mode)"
                if q is q_from
                else f"{name} is outside the safety layer's joint limits ({limits.source}): joint {j + 1} "
                f"at {q[j]:.3f} rad, allowed [{limits.position_lower[j]:.3f}, "
                f"{limits.position_upper[j]:.3f}] rad; fix the task's start"
            )
    delta = q_to - q_from
    far = np.abs(delta)
    if far.max() > max_move:
        j = int(np.argmax(far))
        raise PlanningError(
            f"the arm is too far from {what} to move there on its own: joint {j + 1} is {far[j]:.2f} rad "
            f"away (at most {max_move:g} rad); bring the arm closer by hand (Desk's guiding mode) and "
            "start again"
        )
    checks = max(10, math.ceil(PATH_CHECKS_PER_RAD * far.max()))
    path = q_from + np.linspace(0.0, 1.0, checks + 1)[:, None] * delta
    if scene is not None and len(scene):
        _check_clearance(robot, scene, path, what)
    if limits.tool_box is not None:
        tool = robot.frame_pose(limits.tool, path)[:, :3, 3]
        lower, upper = limits.tool_box
        out = (tool < lower) | (tool > upper)
        if out.any():
            i, axis = np.unravel_index(int(np.argmax(out)), out.shape)
            raise PlanningError(
                f"the straight move to {what} takes the tool out of its box ({limits.source}): "
                f"{'xyz'[axis]} = {tool[i, axis]:.3f} m at {100 * i / checks:.0f} % of the way, allowed "
                f"[{lower[axis]:.3f}, {upper[axis]:.3f}] m; bring the arm closer to {what} by hand first"
            )
    duration = 15.0 / 8.0 * float(np.max(far / (speed * robot.velocity_limits)))
    return JointMove(q_from, q_to, max(MIN_MOVE_TIME, duration))


def _check_clearance(robot: Robot, scene: Scene, path: np.ndarray, what: str) -> None:
    """PlanningError unless `path` keeps every body at least each object's margin away, or no
    nearer than at either end of the path."""
    distances = robot.scene_distances(path, scene)  # (points, bodies, objects) [m]
    if distances.size == 0:
        return
    margins = np.array([o.margin for o in scene.objects])
    allowed = np.minimum(margins[None, :], np.minimum(distances[0], distances[-1])) - CLEARANCE_SLACK
    short = distances < allowed[None]
    if short.any():
        i, b, o = np.unravel_index(int(np.argmax(short)), short.shape)
        raise PlanningError(
            f"the straight move to {what} brings '{robot.collision_bodies[b]}' within "
            f"{distances[i, b, o]:.3f} m of '{scene.objects[o].name}' (margin {margins[o]:.3f} m); bring "
            f"the arm closer to {what} by hand first"
        )


def move_to(
    backend: Backend,
    move: JointMove,
    controller: ImpedanceController,
    limits: SafetyLimits,
    *,
    on_tick: TickHook | None = None,
) -> tuple[LoopResult, Exception | None]:
    """Runs `move` on the control loop over `backend` (the arm must be at ``move.q_from``; its
    safety layer has `limits`, `controller` is the impedance law with the task's scene) and checks
    that the arm came to rest within START_TOLERANCE of ``move.q_to``.

    Returns the loop's result (its log, its stop) and what went wrong, None if the arm arrived:
    the safety stop (:class:`~phri.exceptions.SafetyStopError`), or a PlanningError naming the
    joint that did not arrive. Errors of the backend before the motion (no answer, a refused
    start) are raised."""
    last: dict[str, RobotState] = {}

    def hook(k: int, state: RobotState, row: int) -> None:
        last["state"] = state
        if on_tick is not None:
            on_tick(k, state, row)

    # The explicit law, as on every real arm (see ControlLoop's `implicit`): the implicit one, with
    # phri's model that has no rotor inertia, left the FR3's wrist a 0.045 rad dead band against
    # franky-sim's joint friction.
    loop = ControlLoop(
        backend, cast(Learner, cast(Any, move)), controller, limits, on_tick=hook, implicit=False
    )
    result = loop.run(move.q_from, move.total, check=False)
    if result.error is not None:
        return result, result.error
    off = np.abs(last["state"].q - move.q_to)
    if off.max() > START_TOLERANCE:
        j = int(np.argmax(off))
        return result, PlanningError(
            f"the arm did not reach the start pose: joint {j + 1} is {off[j]:.3f} rad from it after the "
            f"move (at most {START_TOLERANCE:g} rad); check for an obstacle or a payload the robot does "
            "not know about, then start again"
        )
    return result, None
