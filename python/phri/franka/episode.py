"""One attempt at a task on a Franka over libfranka: a real FR3, or franky-sim's behind phri's scene
server with the simulated person. The robot's side and the scoring are the simulated episode's
(:func:`phri.sim.episode.robot_controls`, :func:`~phri.sim.episode.run_on_loop`,
:func:`~phri.sim.episode.score_episode`); what differs is the arm: it is driven to the task's start
pose in a motion of its own first (:mod:`phri.franka.move`), the person's push is what the robot
measures (``tau_ext_hat_filtered``; the logged wrench is its ``O_F_ext_hat_K``), and the learner
replans on its worker thread with the plan adopted at the first tick after it is ready (the wall
clock decides, as on any real arm).

:class:`FrankaEpisode` connects (a clear error within the timeout if nothing answers), reads where
the arm is, moves it to the start (refused if it is far or the way is not clear), runs the episode
and scores it. The log has the keys of a simulated episode's log plus the move's (``move_*``), the
loop's tick counts (``ticks``, ``late_ticks``, ``max_tick_gap``: lateness on the robot's clock) and
whether each replan converged (``replan_converged``).
"""

from __future__ import annotations

import ipaddress
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from phri import robots
from phri._phri import Robot
from phri.config import Task
from phri.control import LATE_AFTER, LoopResult, RobotState, StopEvent
from phri.control.loop import TickHook
from phri.exceptions import ConfigError
from phri.franka.backend import FrankaBackend
from phri.franka.move import (
    MAX_MOVE,
    MOVE_SPEED,
    START_TOLERANCE,
    JointMove,
    check_move_options,
    move_to,
    plan_move,
)
from phri.sim.episode import (
    EpisodeConfig,
    EpisodeResult,
    Planner,
    RobotControls,
    robot_controls,
    run_on_loop,
    score_episode,
)

if TYPE_CHECKING:
    from phri._phri import Learner

__all__ = [
    "CONNECT_TIMEOUT",
    "REPLAN_LATENCY",
    "FrankaEpisode",
    "FrankaOutcome",
    "check_task_robot",
    "is_simulator",
]

#: How long an address may take to answer [s] before it is a ConnectionLostError.
CONNECT_TIMEOUT = 5.0
#: The learner's replan latency on a Franka: None, the worker thread's, adopted at the first tick
#: after the replan is ready (see :class:`phri.Learner`). The one line to change.
REPLAN_LATENCY: float | None = None
#: The robots phri drives over libfranka (their descriptions' names).
FRANKA_ROBOTS = ("fr3",)


def is_simulator(host: str) -> bool:
    """Whether `host` is a loopback address: franky-sim's scene server, never a real arm (which is
    on the Control's network), so libfranka's real-time kernel check is left out."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_task_robot(task: Task, robot: str) -> None:
    """ConfigError unless `task` is posed for `robot`."""
    if task.robot != robot:
        raise ConfigError(
            f"task: {task.source} is posed for robot '{task.robot}', not '{robot}'; use an {robot.upper()} "
            f'task (fr3_table, fr3_laptop, fr3_human, fr3_coffee) or a task file with robot = "{robot}"'
        )


@dataclass
class FrankaOutcome:
    """What :meth:`FrankaEpisode.run` did."""

    #: The episode's measures and log (``log_arrays``); None if it never started (the move to the
    #: start failed, or the robot refused control before the first tick).
    result: EpisodeResult | None
    #: What ended the episode early or kept it from starting: a safety stop
    #: (:class:`~phri.exceptions.SafetyStopError`, with the stop in ``result.stop``), the move's
    #: failure (its stop, or a PlanningError), or another error; None when it ran to its end.
    error: BaseException | None
    #: The move to the start pose (None: the arm was already there).
    move: JointMove | None = None
    move_result: LoopResult | None = None
    #: The episode motion's ticks, the late ones (more than LATE_AFTER periods after the one
    #: before, on the robot's clock) and the largest gap between two ticks [s].
    ticks: int = 0
    late_ticks: int = 0
    max_tick_gap: float = 0.0
    #: The episode motion's wall time [s] (with its ticks, the loop's rate in wall time).
    motion_seconds: float = 0.0
    #: The log's arrays (the episode's and the move's), also when the episode never started.
    log_arrays: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def stop(self) -> StopEvent | None:
        """The safety stop of the episode, else of the move (None: neither stopped)."""
        if self.result is not None and self.result.stop is not None:
            return self.result.stop
        return self.move_result.stop if self.move_result is not None else None


class FrankaEpisode:
    """One attempt at `task` (posed for the FR3) with `config`'s strategy on the Franka at `host`.

    `planner`: the task's planner (made here if None; reuse one across episodes of a task).
    `connect_timeout` [s]: an address where nothing answers is a ConnectionLostError within it.
    `realtime`: require libfranka's real-time kernel (None: unless `host` is loopback, which is
    franky-sim). `move_speed`, `max_move`: the move to the start pose (:func:`phri.franka.move.plan_move`).

    The learner (:attr:`learner`) is made here; replace it before :meth:`run` to run another."""

    def __init__(
        self,
        host: str,
        task: Task,
        config: EpisodeConfig | None = None,
        *,
        planner: Planner | None = None,
        connect_timeout: float = CONNECT_TIMEOUT,
        realtime: bool | None = None,
        move_speed: float = MOVE_SPEED,
        max_move: float = MAX_MOVE,
    ) -> None:
        check_task_robot(task, "fr3")
        check_move_options(move_speed, max_move)  # before anything connects
        self.task = task
        self.config = config or EpisodeConfig()
        self.description = robots.load(task.robot)
        self.model = Robot.from_description(task.robot)
        self.move_speed, self.max_move = move_speed, max_move
        self.backend = FrankaBackend(
            host, self.model, connect_timeout=connect_timeout,
            realtime=not is_simulator(host) if realtime is None else realtime,
        )  # fmt: skip
        self.controls: RobotControls = robot_controls(
            task, self.model, self.config, planner, replan_latency=REPLAN_LATENCY
        )

    @property
    def learner(self) -> Learner:
        """The episode's learner (Algorithm 1, or compliance only for the impedance strategy)."""
        return self.controls.learner

    @learner.setter
    def learner(self, learner: Learner) -> None:
        self.controls.learner = learner

    # -- running -----------------------------------------------------------------------------------

    def run(self, on_tick: TickHook | None = None) -> FrankaOutcome:
        """Connects, reads where the arm is, moves it to the task's start (unless it is within
        START_TOLERANCE of it), runs the episode and scores it. `on_tick` is called at every tick
        of the episode motion (not the move). Errors before anything moved (no answer, a move
        refused by :func:`~phri.franka.move.plan_move`, a fault the robot cannot recover) are
        raised; what happened after is in the outcome (its `error`), with the log so far."""
        began = time.perf_counter()
        task, model, controls = self.task, self.model, self.controls
        now = self.backend.read_once()
        move: JointMove | None = None
        move_result: LoopResult | None = None
        if now.fault is None and np.abs(now.q - task.start).max() <= START_TOLERANCE:
            pass  # already at the start (the connection is kept for the episode's motion)
        else:
            try:
                move = plan_move(
                    model, controls.limits, now.q, task.start, scene=task.scene, speed=self.move_speed,
                    max_move=self.max_move, what=f"{task.name}'s start pose",
                )  # fmt: skip
            except BaseException:
                self.backend.stop()  # the connection read_once made: nothing will move
                raise
            # The move's own impedance law: the episode's starts fresh (its clearance wall's state).
            controller = robots.impedance_controller(model, self.description, task.scene)
            move_result, problem = move_to(self.backend, move, controller, controls.limits)
            if problem is not None:
                arrays = _move_arrays(move_result, model.nq)
                return FrankaOutcome(None, problem, move, move_result, log_arrays=arrays)
        ticks = _Ticks(self.backend.period, on_tick)
        initial_weights = controls.learner.weights
        motion_began = time.perf_counter()
        trace = run_on_loop(
            task, self.backend, controls.learner, controls.controller, controls.limits, self._push_of,
            log_rate=self.config.log_rate, hand=self.backend.robot.hand_frame or "", on_tick=ticks,
            implicit=False,  # a real arm (or franky-sim's, rotors modelled): libfranka's explicit law
        )  # fmt: skip
        motion_seconds = time.perf_counter() - motion_began
        if trace.rows == 0:  # nothing ran: the robot refused control, or never answered
            arrays = _move_arrays(move_result, model.nq)
            return FrankaOutcome(None, trace.error, move, move_result, log_arrays=arrays)
        result = score_episode(
            task, model, controls.planner, controls.learner, trace, self.config, initial_weights,
            period=self.backend.period,
        )  # fmt: skip
        result.wall_time = time.perf_counter() - began
        result.log_arrays.update(_move_arrays(move_result, model.nq))
        result.log_arrays.update(
            ticks=np.array(ticks.count), late_ticks=np.array(ticks.late),
            max_tick_gap=np.array(ticks.max_gap), replan_converged=_replan_converged(controls.learner),
        )  # fmt: skip
        return FrankaOutcome(
            result, trace.error, move, move_result, ticks.count, ticks.late, ticks.max_gap, motion_seconds,
            log_arrays=result.log_arrays,
        )  # fmt: skip

    def _push_of(self, state: RobotState) -> np.ndarray | None:
        """The person's wrench on the hand as the robot estimates it (−``O_F_ext_hat_K``: force [N],
        torque [N·m], base frame) while the measured torque crosses a detection threshold on some
        joint; None while it does not (nobody touches the hand)."""
        raw = self.backend.raw
        if raw is None or not (np.abs(state.tau_ext) > self.controls.thresholds).any():
            return None
        return -np.asarray(raw.O_F_ext_hat_K, dtype=float)


class _Ticks:
    """Counts the episode motion's ticks and its late ones on the robot's clock (a tick hook)."""

    def __init__(self, period: float, then: TickHook | None) -> None:
        self.period, self.then = period, then
        self.count = self.late = 0
        self.max_gap = 0.0
        self.previous = math.nan

    def __call__(self, k: int, state: RobotState, row: int) -> None:
        gap = state.t - self.previous
        if gap > LATE_AFTER * self.period:
            self.late += 1
        if gap > self.max_gap:
            self.max_gap = gap
        self.previous = state.t
        self.count += 1
        if self.then is not None:
            self.then(k, state, row)


def _move_arrays(result: LoopResult | None, nq: int) -> dict[str, np.ndarray]:
    """The move's log as ``move_*`` arrays (its time series and its stop); empty without a move."""
    if result is None:
        joints = np.zeros((0, nq))
        log = {"t": np.zeros(0), "q": joints, "qd": joints, "q_ref": joints, "tau": joints, "tau_ext": joints}
        log["wall_force"] = np.zeros(0)
        stop = StopEvent.empty_arrays(nq)
    else:
        log = dict(result.log)
        stop = StopEvent.empty_arrays(nq) if result.stop is None else result.stop.arrays()
    return {f"move_{key}": np.asarray(value) for key, value in {**log, **stop}.items()}


def _replan_converged(learner: Learner) -> np.ndarray:
    """Per interaction sample: 1 if its replan converged, 0 if it did not, -1 if it made none (no
    replan, or superseded by a newer push)."""
    return np.array(
        [-1 if info is None else int(info.converged) for info in learner.history().replans], dtype=np.int8
    )
