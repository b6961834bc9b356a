"""A simulated study participant: knows how the task should be done (the plan for the true weights),
knows nothing of the robot's learner, watches the cup, and pushes the hand when it strays.

Behaviour, every control tick:

- The task-relevant error is the cup's position error from the desired path at the same time (tasks
  table, laptop, human) or the excess tilt of the cup over the desired tilt (coffee).
- When the error has stayed above ``tolerance`` for ``delay`` seconds, the participant grabs the hand
  and applies a corrective wrench: force ``stiffness · error`` toward the desired position (or torque
  ``rotational_stiffness · tilt`` righting the cup) plus Gaussian noise of standard deviation ``noise``
  (per axis, in N; a tenth of it in N·m for torques), the sum saturated in norm at ``max_force`` /
  ``max_torque``.
- They let go when the error falls below ``release · tolerance`` (hysteresis).
- They re-judge at ``rate`` (100 Hz) and hold the push in between.

Per-participant parameters are drawn with :meth:`ParticipantParams.draw` from the documented uniform
distributions below, from a seeded generator; the same participant drives both strategies.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from phri._phri import Robot, TimedTrajectory
from phri.exceptions import InvalidParameterError

__all__ = ["DISTRIBUTIONS", "Participant", "ParticipantParams"]

#: Uniform ranges (low, high) each parameter is drawn from.
DISTRIBUTIONS: dict[str, tuple[float, float]] = {
    "stiffness": (250.0, 450.0),  # N/m
    "rotational_stiffness": (8.0, 15.0),  # N·m/rad
    "tolerance": (0.03, 0.05),  # m
    "tilt_tolerance": (0.15, 0.25),  # rad
    "delay": (0.2, 0.4),  # s
    "max_force": (25.0, 35.0),  # N
    "max_torque": (3.0, 5.0),  # N·m
    "noise": (0.5, 1.5),  # N (and N·m for torques, scaled by 0.1)
}


@dataclass(frozen=True)
class ParticipantParams:
    """How one simulated person corrects the robot."""

    stiffness: float = 350.0
    rotational_stiffness: float = 12.0
    tolerance: float = 0.04
    tilt_tolerance: float = 0.2
    delay: float = 0.3
    max_force: float = 30.0
    max_torque: float = 4.0
    noise: float = 1.0
    release: float = 0.4
    rate: float = 100.0  # Hz at which the person re-judges the error and updates their push

    def __post_init__(self) -> None:
        for name in ("stiffness", "rotational_stiffness", "tolerance", "tilt_tolerance", "delay", "max_force",
                     "max_torque", "noise"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InvalidParameterError(f"{name} must be a finite value >= 0, got {value}")
        if not 0 <= self.release <= 1:
            raise InvalidParameterError(
                f"release must be a fraction of the tolerance in [0, 1], got {self.release}"
            )
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise InvalidParameterError(f"rate must be a finite rate > 0 Hz, got {self.rate}")

    @classmethod
    def draw(cls, rng: np.random.Generator) -> ParticipantParams:
        """One participant from :data:`DISTRIBUTIONS` (the draw order is fixed, so seeds reproduce)."""
        return cls(**{k: float(rng.uniform(lo, hi)) for k, (lo, hi) in DISTRIBUTIONS.items()})

    def as_dict(self) -> dict[str, float]:
        """The parameters by name."""
        return asdict(self)


def cup_tilt(rotation: np.ndarray) -> float:
    """Angle between the cup axis (link_7's x axis) and vertical [rad]."""
    return math.acos(min(1.0, max(-1.0, float(rotation[2, 0]))))


class Participant:
    """Watches the robot and pushes; `wrench(t, q)` returns (force [N], torque [N·m]) at the hand.

    The desired cup pose is precomputed on the control grid `dt` [s] (one batched call), so a tick
    costs one forward kinematics of the robot's actual configuration.
    """

    def __init__(
        self,
        params: ParticipantParams,
        desired: TimedTrajectory,
        task_feature: str,
        robot: Robot,
        rng: np.random.Generator,
        dt: float = 1e-3,
        frame: str | None = None,
    ) -> None:
        """`frame` is the cup the person watches (default: the robot's feature frame)."""
        frame = frame or robot.feature_frame
        if frame is None:
            raise InvalidParameterError(f"frame: robot '{robot.name}' declares no feature frame; pass frame=")
        self.params, self.robot, self.rng, self.frame, self.dt = params, robot, rng, frame, dt
        self.rotational = task_feature in ("coffee", "coffee_dot")
        times = np.arange(0.0, desired.duration + dt / 2, dt)
        poses = robot.frame_pose(frame, desired.sample_many(times)[0])
        self.desired_position = poses[:, :3, 3].copy()
        self.desired_tilt = np.arccos(np.clip(poses[:, 2, 0], -1.0, 1.0))
        self.over_since: float | None = None
        self.pushing = False
        self.next_look = 0.0
        self.held: tuple[np.ndarray, np.ndarray] | None = None

    def error(self, t: float, q: np.ndarray) -> tuple[float, np.ndarray]:
        """(task-relevant error magnitude [m or rad], corrective direction), world frame."""
        k = min(max(int(round(t / self.dt)), 0), len(self.desired_tilt) - 1)
        pose = self.robot.frame_pose(self.frame, q)
        if self.rotational:
            # Righting the cup: rotate its axis x towards vertical, about x × ẑ = (x_y, −x_x, 0).
            excess = cup_tilt(pose) - float(self.desired_tilt[k])
            axis = np.array([pose[1, 0], -pose[0, 0], 0.0])
            norm = math.hypot(axis[0], axis[1])
            return max(excess, 0.0), (axis / norm if norm > 1e-9 else np.zeros(3))
        e = self.desired_position[k] - pose[:3, 3]
        size = math.sqrt(float(e @ e))
        return size, (e / size if size > 0 else e)

    def wrench(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The push at time `t` [s] for joint positions `q`, or None when not touching the robot.

        A person re-judges what they see at ``params.rate`` Hz and holds their push in between."""
        if t < self.next_look:
            return self.held
        self.next_look = t + 1.0 / self.params.rate - 1e-9
        self.held = self._judge(t, q)
        return self.held

    def _judge(self, t: float, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        p = self.params
        size, direction = self.error(t, q)
        tolerance = p.tilt_tolerance if self.rotational else p.tolerance
        if self.pushing:
            if size < p.release * tolerance:
                self.pushing, self.over_since = False, None
        elif size > tolerance:
            if self.over_since is None:
                self.over_since = t
            if t - self.over_since >= p.delay:
                self.pushing = True
        else:
            self.over_since = None
        if not self.pushing:
            return None
        # The noise is part of the push, so the push (noise included) is what saturates.
        if self.rotational:
            torque = direction * p.rotational_stiffness * size + self.rng.normal(0.0, 0.1 * p.noise, 3)
            return np.zeros(3), _saturate(torque, p.max_torque)
        force = direction * p.stiffness * size + self.rng.normal(0.0, p.noise, 3)
        return _saturate(force, p.max_force), np.zeros(3)


def _saturate(v: np.ndarray, limit: float) -> np.ndarray:
    """`v` scaled down, keeping its direction, to a norm of at most `limit`."""
    norm = math.sqrt(float(v @ v))
    return v * (limit / norm) if norm > limit else v
