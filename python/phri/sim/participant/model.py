"""The simulated participant: perception, decision and arm put together, judged at the person's own
rate and called every control tick.

``Participant(params, task, robot, desired, rng).wrench(t, q)`` is all a control loop needs: the
person's push at the robot's hand frame (force [N], torque [N·m], world frame) for joint positions
`q` [rad] at time `t` [s], or None while nobody touches the arm. It needs only the robot model, `q`
and `t` (no simulator), so the same person drives PyBullet's JACO2 and franky-sim's FR3.

The person acts on what they saw ``delay`` seconds ago (visuomotor delay): they grab, let go and aim
their hand by that view. Their hand goes where they expect the cup to be now plus the move that would
have fixed what they saw. They expect it where they saw it, carried on at the velocity they saw it
move with (people tracking a predictable motion compensate for their delay, Miall & Wolpert's forward
models; a hand does not trail a steadily moving cup by the delay): so a hand on a robot that moves on
steadily does not drag on it, but one on a robot that changes course (a new plan, a spring-back)
does, for about the delay, and every push starts late. Their arm also resists the cup moving
otherwise than they expect, at once (the arm's own give, not a decision): a damping of stiffness ×
delay on the difference between the velocity they saw and the one their hand feels now (between
their last two looks), which keeps their delayed corrections from rocking a compliant arm.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from phri._phri import Robot, TimedTrajectory
from phri.config import Task
from phri.exceptions import InvalidParameterError
from phri.sim.participant.arm import HumanArm
from phri.sim.participant.params import ParticipantParams
from phri.sim.participant.perception import Correction, TaskView
from phri.sim.participant.persistence import Persistence, State

__all__ = ["Participant", "Sight"]


@dataclass(frozen=True)
class Sight:
    """What the person saw at one look: when [s], the cup's pose (4×4), each watched feature."""

    t: float
    pose: np.ndarray
    corrections: list[Correction]


def _rotation_between(seen: np.ndarray, now: np.ndarray) -> np.ndarray:
    """The rotation vector [rad] (world frame) that turns orientation `now` into `seen` (3×3 each)."""
    a = seen @ now.T
    vee = 0.5 * np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]])
    s = float(np.linalg.norm(vee))
    c = (float(np.trace(a)) - 1.0) / 2.0
    angle = math.atan2(s, c)
    return vee * (angle / s) if s > 1e-12 else vee


def _velocity(before: Sight, after: Sight) -> np.ndarray:
    """The cup's velocity between two looks: linear [m/s] and angular [rad/s] (world frame)."""
    dt = after.t - before.t
    turn = _rotation_between(after.pose[:3, :3], before.pose[:3, :3])
    return np.concatenate([(after.pose[:3, 3] - before.pose[:3, 3]) / dt, turn / dt])


def _rotation(vector: np.ndarray) -> np.ndarray:
    """The rotation matrix of rotation vector `vector` [rad] (Rodrigues' formula)."""
    angle = float(np.linalg.norm(vector))
    if angle < 1e-12:
        return np.eye(3)
    x, y, z = vector / angle
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


class Participant:
    """One person correcting `robot` executing `task`, having been shown the `desired` behaviour (the
    plan for the true weights: waypoints over the task's duration, or a TimedTrajectory).

    `rng` is the person's own random stream (tremor, how they aim). `dt` [s] is the control period the
    loop calls :meth:`wrench` at; the person re-judges at ``params.rate`` and holds their push in
    between. For a second or later attempt pass ``params.for_attempt(attempt)``.

    With several watched features the person corrects every one still wrong in the same push (their
    moves add up); with `one_at_a_time` they correct the most visible error first (the largest in
    units of their tolerance), only it until it looks fixed, and then the next, as the participants
    of Bajcsy et al., "Learning from Physical Human Corrections, One Feature at a Time" (HRI 2018)
    were asked to."""

    def __init__(
        self,
        params: ParticipantParams,
        task: Task,
        robot: Robot,
        desired: TimedTrajectory | np.ndarray,
        rng: np.random.Generator,
        dt: float = 1e-3,
        hand: str | None = None,
        *,
        one_at_a_time: bool = False,
    ) -> None:
        hand = hand or robot.hand_frame
        if hand is None:
            raise InvalidParameterError(f"hand: robot '{robot.name}' declares no hand frame; pass hand=")
        if not (math.isfinite(dt) and dt > 0):
            raise InvalidParameterError(f"dt must be a control period > 0 s, got {dt!r}")
        if not isinstance(one_at_a_time, bool):
            raise InvalidParameterError(f"one_at_a_time must be True or False, got {one_at_a_time!r}")
        self.params, self.robot, self.hand, self.dt = params, robot, hand, dt
        self.one_at_a_time = one_at_a_time
        #: With `one_at_a_time`: the index (in the watched features) of the one being corrected.
        self.focus: int | None = None
        self.period = 1.0 / params.rate
        self.view = TaskView(task, robot, desired)
        self.arm = HumanArm(params, rng, self.period)
        self.persistence = Persistence(params, self.period)
        self.next_look = 0.0
        self.held: tuple[np.ndarray, np.ndarray] | None = None
        #: What the person saw at their recent looks, newest last (as far back as their delay).
        self.sights: deque[Sight] = deque()

    @property
    def state(self) -> State:
        """What the person is doing now (:class:`~phri.sim.participant.persistence.State`): watching,
        pushing, pausing after a bout, or given up for the rest of this attempt."""
        return self.persistence.state

    @property
    def seen(self) -> Sight | None:
        """The view the person acts on now: their look ``delay`` seconds ago (or their first)."""
        return self.sights[0] if self.sights else None

    def errors(self, corrections: list[Correction]) -> list[float]:
        """Each watched feature's error in units of the person's tolerance (1: just visible)."""
        p = self.params
        return [max(c.translation / p.tolerance, c.rotation / p.tilt_tolerance) for c in corrections]

    def wrench(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The push at time `t` [s] for joint positions `q` [rad], or None when not touching the arm."""
        if t < self.next_look:
            return self.held
        self.next_look = t + self.period - 1e-9
        self.held = self._judge(t, q)
        return self.held

    def _judge(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        corrections = self.view.look(q, t)
        now = self.view.pose.copy()
        self.sights.append(Sight(t, now, corrections))
        # Keep the newest look at least `delay` old, and everything after it.
        while len(self.sights) > 1 and self.sights[1].t <= t - self.params.delay + 1e-9:
            self.sights.popleft()
        seen = self.sights[0]
        errors = self.errors(seen.corrections)
        release = self.params.release
        if self.one_at_a_time:
            errors = self._focus_on(errors, seen.corrections)
        visible = any(e > 1.0 and c.fixable for e, c in zip(errors, seen.corrections, strict=True))
        fixed = all(e < release for e in errors)
        if not self.persistence.update(t, visible, fixed):
            return self.arm.push(None)
        # Several features at once: the moves of every feature still wrong add up.
        move = np.zeros(6)
        for e, c in zip(errors, seen.corrections, strict=True):
            if e >= release and c.fixable:
                move += c.move
        expected = self.expected(t)
        lag = np.concatenate([expected[:3, 3] - now[:3, 3], _rotation_between(expected[:3, :3], now[:3, :3])])
        if len(self.sights) >= 2:
            # The arm's damping, in the spring's units: stiffness × delay × velocity difference.
            felt = _velocity(self.sights[-2], self.sights[-1])
            lag += self.params.delay * (_velocity(self.sights[0], self.sights[1]) - felt)
        return self.arm.push(move, lag)

    def _focus_on(self, errors: list[float], corrections: list[Correction]) -> list[float]:
        """`errors` with every feature but the one in focus seen as right: the focus stays until it
        looks fixed (below ``release``) or cannot be fixed by a push, then moves to the most visible
        error left (above 1), if any."""
        k = self.focus
        if k is not None and (errors[k] < self.params.release or not corrections[k].fixable):
            k = None
        if k is None:
            wrong = [
                i for i, (e, c) in enumerate(zip(errors, corrections, strict=True)) if e > 1.0 and c.fixable
            ]
            k = max(wrong, key=lambda i: errors[i]) if wrong else None
        self.focus = k
        return [e if i == k else 0.0 for i, e in enumerate(errors)]

    def expected(self, t: float) -> np.ndarray:
        """Where the person expects the cup to be at `t` [s] (4×4, world frame): where they saw it
        ``delay`` ago, carried on at the velocity they saw then (between that look and the next) for
        the time since; where they saw it if they have looked once only."""
        seen = self.sights[0]
        if len(self.sights) < 2:
            return seen.pose
        after = self.sights[1]
        ahead = (t - seen.t) / (after.t - seen.t)
        expected = seen.pose.copy()
        expected[:3, 3] += ahead * (after.pose[:3, 3] - seen.pose[:3, 3])
        turn = ahead * _rotation_between(after.pose[:3, :3], seen.pose[:3, :3])
        expected[:3, :3] = _rotation(turn) @ seen.pose[:3, :3]
        return expected
