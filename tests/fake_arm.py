"""An in-memory arm for the control loop's tests: a :class:`phri.control.Backend` that needs neither a
simulator nor a network, whose state the tests script."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

import phri
from phri.config import load_task
from phri.control import RobotState


class FakeArm:
    """An in-memory `robot` (default the JACO2) that holds still at `q` (default the table task's
    start pose) — a perfect position servo, as far as the loop can tell — unless `script(k, state)`
    changes the tick-k state; `fail(k)` may raise instead of returning it, `fail_write(k)` instead
    of taking the command. It records every command written and every stop."""

    def __init__(
        self,
        robot: phri.Robot | None = None,
        q: np.ndarray | None = None,
        *,
        period: float = 1e-3,
        gravity_compensated: bool = False,
        script: Callable[[int, RobotState], None] | None = None,
        fail: Callable[[int], None] | None = None,
        fail_write: Callable[[int], None] | None = None,
    ) -> None:
        self.robot = robot if robot is not None else phri.Robot.jaco2()
        self.q = np.array(q if q is not None else load_task("table").start, dtype=float)
        self.period = period
        self.gravity_compensated = gravity_compensated
        self.script, self.fail, self.fail_write = script, fail, fail_write
        self.commands: list[np.ndarray] = []
        self.stops = 0
        self.k = 0

    def _state(self) -> RobotState:
        n = self.robot.nq
        state = RobotState(t=self.k * self.period, q=self.q.copy(), qd=np.zeros(n), tau_ext=np.zeros(n))
        if self.fail is not None:
            self.fail(self.k)
        if self.script is not None:
            self.script(self.k, state)
        return state

    def start(self, q_start: np.ndarray) -> RobotState:
        self.k = 0
        return self._state()

    def read(self) -> RobotState:
        self.k += 1
        return self._state()

    def write(self, tau: np.ndarray) -> None:
        if self.fail_write is not None:
            self.fail_write(self.k)
        self.commands.append(tau.copy())

    def stop(self) -> None:
        self.stops += 1
