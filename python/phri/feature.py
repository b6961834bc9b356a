"""Features written in Python: pass one wherever a built-in feature's name is accepted.

A feature maps joint configurations to a number per configuration. phri evaluates it for all
points of a trajectory in one call (the waypoints q_1 … q_{N-1}, or ``samples`` points along each
segment), so write ``value`` (and ``gradient``) over a batch ``q`` of shape (M, n) with numpy::

    class CupOverTray(phri.Feature):
        name = "tray"

        def __init__(self, robot, tray_xy):
            self.robot, self.tray = robot, np.asarray(tray_xy)

        def value(self, q):  # (M, n) [rad] -> (M,)
            p = self.robot.frame_pose(self.robot.cup_frame, q)[:, :2, 3]
            return np.sum((p - self.tray) ** 2, axis=1)

        def gradient(self, q):  # (M, n) -> (M, n), d value / d q
            p = self.robot.frame_pose(self.robot.cup_frame, q)[:, :2, 3]
            jac = self.robot.jacobian(self.robot.cup_frame, q)[:, :2, :]
            return 2.0 * np.einsum("mc,mcj->mj", p - self.tray, jac)

    features = phri.Features(robot, ["efficiency", CupOverTray(robot, (0.4, 0.2))], scene=task.scene)

``Robot.frame_pose(frame, q)`` and ``Robot.jacobian(frame, q)`` take the whole (M, n) batch.
Without ``gradient``, phri takes central finite differences of ``value`` (one more call, 2·M·n
rows); without ``hessian`` (M, n, n), the optimiser's curvature comes from finite differences of
the gradient, made positive semidefinite until the solve settles (see docs/features.md).

A feature that raises, returns the wrong shape or a non-finite value, or takes longer than its
``timeout`` [s] for one call, is a :class:`phri.exceptions.FeatureError` naming it; a replan on
the learner's worker thread that meets one is rejected (the arm keeps its plan) and recorded in
the history. The learner's worker calls the feature from its own thread, holding the GIL only
during the call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

__all__ = ["Feature", "feature"]

Array = NDArray[np.float64]


class Feature:
    """Base class of a feature written in Python. Set ``name`` and define ``value``; ``gradient``
    and ``hessian`` are optional (see the module's documentation).

    Class attributes: ``name`` (unique in a feature set), ``samples`` (points per segment: 1 sums
    over the waypoints as the table and cup features do; more samples each segment at s = k/samples
    as the keep-outs do), ``timeout`` (the most one call may take [s]).
    """

    name: ClassVar[str] | str = ""
    samples: int = 1
    timeout: float = 1.0
    gradient: Callable[[Array], Any] | None = None
    hessian: Callable[[Array], Any] | None = None

    def value(self, q: Array) -> Any:
        """The feature at each configuration: q (M, n) [rad] → (M,)."""
        raise NotImplementedError(f"{type(self).__name__} must define value(q)")

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


class _FunctionFeature(Feature):
    def __init__(
        self,
        name: str,
        value: Callable[[Array], Any],
        gradient: Callable[[Array], Any] | None,
        hessian: Callable[[Array], Any] | None,
        samples: int,
        timeout: float,
    ) -> None:
        self.name = name
        self._value = value
        self.gradient = gradient
        self.hessian = hessian
        self.samples = samples
        self.timeout = timeout

    def value(self, q: Array) -> Any:
        return self._value(q)


def feature(
    name: str,
    value: Callable[[Array], Any],
    gradient: Callable[[Array], Any] | None = None,
    *,
    hessian: Callable[[Array], Any] | None = None,
    samples: int = 1,
    timeout: float = 1.0,
) -> Feature:
    """A feature from functions: ``value(q)`` (M, n) → (M,), optionally ``gradient(q)`` (M, n) →
    (M, n) and ``hessian(q)`` (M, n) → (M, n, n); see :class:`Feature`."""
    if not isinstance(name, str) or not name:
        raise TypeError("name must be a non-empty string")
    if not callable(value):
        raise TypeError("value must be callable: value(q) with q of shape (M, n)")
    for arg, f in (("gradient", gradient), ("hessian", hessian)):
        if f is not None and not callable(f):
            raise TypeError(f"{arg} must be callable or None")
    return _FunctionFeature(name, value, gradient, hessian, samples, timeout)
