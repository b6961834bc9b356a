"""What the person sees: each feature they care about, evaluated on the cup where it is, against the
desired behaviour they were shown, and the move of the cup that would put it right.

The paper's participants were shown the desired behaviour and asked to get the robot there with
minimal intervention (§4.1). So the person watches the task's *features* — the cup's tilt, its height
over the table, how far it is inside the laptop's or the person's circle — not the desired path at
the same clock time:

- They care about the features whose weight the robot has wrong: learned features whose true weight
  differs from the initial one, and the task's unmodelled features (``Task.unmodelled``), which the
  robot does not have at all. A higher true cost weight means they want that feature lower.
- The feature's value now, φ_k(q) (the task's own feature, one configuration), is compared with the
  desired behaviour's value at the same place along the way: the desired path's point nearest the
  cup in the horizontal plane, never going back (the person follows the demonstration's progress, not
  its clock). Where the desired behaviour itself has the feature (the goal inside the laptop's circle),
  nothing is wrong.
- The error becomes a move of the cup: the smallest change of the cup's pose δx = (δp [m], δθ [rad])
  that puts the feature back to the desired value to first order, δx = −(φ_k − φ_k*)·G_k / ‖G_k‖²,
  where G_k is the feature's gradient with respect to the cup's pose (world frame; from the feature's
  joint gradient through the Jacobian, G_k = (J Jᵀ)⁻¹ J ∇_q φ_k). A feature the cup's pose does not
  change (G_k = 0) is one a push cannot fix, and is ignored.

Everything comes from the task's features (phri.Features) and the robot model; nothing here needs a
simulator, so the same person corrects PyBullet's JACO2 and franky-sim's FR3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phri._phri import Robot, TimedTrajectory
from phri.config import Task
from phri.exceptions import InvalidParameterError

__all__ = ["Correction", "TaskView"]

#: The desired behaviour is sampled every this many seconds for the person's reference [s].
REFERENCE_SPACING = 0.05
#: The person compares with the demonstration's nearest point at most this far from the clock [s].
MATCH_WINDOW = 1.0
#: A feature whose pose gradient is below this norm cannot be changed by moving the cup.
_FLAT = 1e-9


@dataclass(frozen=True)
class Correction:
    """One watched feature as the person sees it."""

    feature: str
    #: The feature's value now and the desired behaviour's value here (the task's feature units).
    value: float
    desired: float
    #: The cup's move that would fix it: translation [m] and rotation [rad] (world frame); zero when
    #: nothing is wrong.
    move: np.ndarray
    #: Whether moving the cup changes this feature at all.
    fixable: bool

    @property
    def translation(self) -> float:
        """Length of the move's translation [m]."""
        m = self.move
        return math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])

    @property
    def rotation(self) -> float:
        """Angle of the move's rotation [rad]."""
        m = self.move
        return math.sqrt(m[3] * m[3] + m[4] * m[4] + m[5] * m[5])


class TaskView:
    """The person's view of `task` executed by `robot`, against the `desired` behaviour (the plan for
    the true weights, as waypoints over the task's duration or a TimedTrajectory)."""

    def __init__(
        self, task: Task, robot: Robot, desired: TimedTrajectory | np.ndarray, *, window: float = MATCH_WINDOW
    ) -> None:
        if not (math.isfinite(window) and window > 0):
            raise InvalidParameterError(f"window must be a time > 0 s, got {window!r}")
        #: How far from the clock the compared point of the demonstration may be [s].
        self.window = window
        task = task.seen_by_person()  # the features the robot does not model matter to them too
        self.features = task.feature_set(robot)
        self.robot, self.frame = robot, self.features.frame
        initial, true = task.vector("initial"), task.vector("true")
        #: (index, name, +1 to lower it / −1 to raise it) of each feature the person cares about.
        self.watched = [
            (k, f.name, 1.0 if true[k] > initial[k] else -1.0)
            for k, f in enumerate(task.features)
            if f.learned and true[k] != initial[k]
        ]
        if not isinstance(desired, TimedTrajectory):
            desired = TimedTrajectory(np.asarray(desired, dtype=float), task.duration)
        times = np.arange(0.0, desired.duration + REFERENCE_SPACING / 2, REFERENCE_SPACING)
        path = desired.sample_many(times)[0]
        # Each configuration's own feature values: the segment (q, q] of a repeated waypoint.
        values = self.features.per_segment(np.repeat(path, 2, axis=0))[0::2]
        #: The watched features' indices in the task's features.
        self.index = [k for k, _, _ in self.watched]
        self.reference = values[:, self.index]
        self.reference_xy = robot.frame_pose(self.frame, path)[:, :2, 3].copy()
        #: Index of the desired point the person compares with; it never goes back.
        self.progress = 0
        #: The cup's pose (4×4, world frame) at the last look.
        self.pose = np.eye(4)

    def reset(self) -> None:
        """Start comparing from the desired behaviour's first point again (:attr:`progress` only
        moves forward while the person looks)."""
        self.progress = 0

    def look(self, q: np.ndarray, t: float | None = None) -> list[Correction]:
        """Each watched feature at joint positions `q` [rad] and time `t` [s] since the task began
        (None: by place alone, anywhere ahead), in the order of the task's features."""
        q = np.asarray(q, dtype=float)
        self.pose = pose = self.robot.frame_pose(self.frame, q)
        if not self.watched:
            return []
        first, last = self.progress, len(self.reference_xy) - 1
        if t is not None:  # only points of the demonstration within `window` of the clock
            last = min(last, int((t + self.window) / REFERENCE_SPACING))
            first = min(max(first, math.ceil((t - self.window) / REFERENCE_SPACING)), last)
        gaps = self.reference_xy[first : last + 1] - pose[:2, 3]
        self.progress = first + int(np.argmin(np.einsum("ij,ij->i", gaps, gaps)))
        phi, jac = self.features.phi_gradient(np.stack([q, q]))
        jacobian = self.robot.jacobian(self.frame, q)
        index = self.index
        # ∇_q φ_k(q) of the single configuration: both waypoints of the segment are q.
        grad_q = jac[index, 0] + jac[index, 1]  # (K', n)
        # G_k: the pose gradient with J^T G_k = ∇_q φ_k, in the least-squares sense (exact when φ_k
        # depends on the cup's pose only): G_k = (J J^T)^-1 J ∇_q φ_k.
        grad_x = np.linalg.solve(jacobian @ jacobian.T, jacobian @ grad_q.T).T  # (K', 6)
        out = []
        reference = self.reference[self.progress]
        for j, (k, name, sign) in enumerate(self.watched):
            value, desired = float(phi[k]), float(reference[j])
            g = grad_x[j]
            norm2 = float(g @ g)
            fixable = math.sqrt(norm2) > _FLAT
            wrong = sign * (value - desired) > 0.0
            move = -(value - desired) * g / norm2 if (fixable and wrong) else np.zeros(6)
            out.append(Correction(name, value, desired, move, fixable))
        return out
