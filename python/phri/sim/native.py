"""The simulated episode's control loop in Rust: :class:`phri.SimulatedLoop` on
:class:`phri.SimulatedArm`, the default simulator of :func:`phri.sim.run_episode`
(``EpisodeConfig.simulator = "native"``).

Each tick is the one :class:`phri.control.ControlLoop` runs over the PyBullet backend
(:class:`phri.sim.backend.PyBulletBackend`): the safety layer's checks, the learner's observation
and reference, the implicit impedance law with its wall, the torque limits, one integration step and
a log row at the log rate; a stop holds the position as the loop does. Python is called only at the
person's own rate (:class:`~phri.sim.participant.Participant` re-judges at ``params.rate``, 50 Hz,
and holds their push in between), at rendered frames and at the end, for the log in bulk. The
sensor's noise is drawn from the same generator in the same order as the PyBullet backend draws it
(one draw per joint at each sample instant), so both simulators see the same person and the same
noise.

The arm integrates the same rigid-body dynamics as PyBullet, by the same semi-implicit Euler step,
but has no contacts and no joint limits: the safety layer, the virtual wall and the plan's clearance
keep the arm off the furniture in both. docs/simulation.md gives the tolerance between the two.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from phri._phri import ImpedanceController, Learner, SimulatedArm, SimulatedLoop
from phri.control import LoopResult, SafetyLimits, StopEvent
from phri.control.loop import HOLD_TIME
from phri.exceptions import SafetyStopError
from phri.sim.participant import Participant
from phri.sim.world import HAND, World

logger = logging.getLogger(__name__)

__all__ = ["NativeRun", "run_native"]

#: Called at a rendered frame's tick with (tick index, joint positions [rad]).
FrameHook = Callable[[int, np.ndarray], None]


@dataclass
class NativeRun:
    """What a native run did: the loop's result (as :class:`phri.control.ControlLoop`'s), the
    person's wrench at each log row (force [N], torque [N·m]; zero while nobody touches the hand)
    and whether anybody did, and the error that ended the run early (None: none, or a safety stop,
    which is in ``loop.stop``)."""

    loop: LoopResult
    push: np.ndarray
    touched: np.ndarray
    error: BaseException | None


def _next_look(person: Participant | None, k: int, dt: float, end: int) -> int:
    """The first tick after `k` at which `person` looks again (their push is held until then), as
    the backend's clock t = tick × dt meets their ``next_look``; `end` without a person."""
    if person is None:
        return end
    due = person.next_look
    tick = max(k + 1, math.ceil(due / dt))
    while tick - 1 > k and (tick - 1) * dt >= due:
        tick -= 1
    while tick * dt < due:
        tick += 1
    return tick


def run_native(
    world: World,
    q_start: np.ndarray,
    duration: float,
    learner: Learner,
    controller: ImpedanceController,
    limits: SafetyLimits,
    person: Participant | None,
    *,
    sample_every: int,
    sensor_noise: float,
    bias: np.ndarray,
    rng: np.random.Generator,
    log_rate: float,
    frame_ticks: Sequence[int] = (),
    on_frame: FrameHook | None = None,
) -> NativeRun:
    """One motion of `world`'s arm (its model, time step, gravity and joint damping; not its
    physics) from `q_start` [rad] for `duration` [s] under `learner`, `controller` and the safety
    layer of `limits`, with `person` pushing the hand (None: nobody). The sensor measures Jᵀ·wrench
    every `sample_every` ticks with Gaussian noise of `sensor_noise` [N·m] from `rng` plus `bias`
    [N·m], and holds it in between. `on_frame` is called at each of `frame_ticks` with the state
    of that tick (before its command)."""
    dt = world.params.timestep
    model = world.model
    n = model.nq
    safety = limits.layer(model, period=dt, gravity_compensated=False)
    arm = SimulatedArm(model, dt=dt, gravity=world.params.gravity, damping=world.params.joint_damping)
    loop = SimulatedLoop(
        arm, q_start, safety, duration=duration, hand=HAND, hold_time=HOLD_TIME,
        log_period=1.0 / log_rate, sample_every=sample_every,
    )  # fmt: skip
    # The last tick there can be: the motion's, then the hold's.
    end = int(math.ceil((duration + HOLD_TIME) / dt)) + 2
    frames = sorted(set(frame_ticks))
    error: BaseException | None = None
    try:
        while not loop.done:
            k = loop.tick
            q = loop.q
            push = None if person is None else person.wrench(k * dt, q)
            while frames and frames[0] < k:
                frames.pop(0)  # a tick the motion skipped (it cannot: ticks are consecutive)
            if frames and frames[0] == k:
                frames.pop(0)
                if on_frame is not None:
                    on_frame(k, q)
            until = min(_next_look(person, k, dt, end), frames[0] if frames else end)
            samples = loop.samples_before(until)
            if sensor_noise:
                offsets = bias + rng.normal(0.0, sensor_noise, (samples, n))
            else:
                offsets = np.tile(bias, (samples, 1))
            wrench = None if push is None else np.concatenate(push)
            loop.advance(until, wrench, offsets, learner, controller, safety)
    except BaseException as e:  # noqa: BLE001 - kept with the log so far; the caller re-raises it
        error = e
    log = loop.log()
    return NativeRun(_result(loop, log, safety), log["push"], log["touched"], error)


def _result(loop: SimulatedLoop, log: dict[str, np.ndarray], safety: object) -> LoopResult:
    """The run as a :class:`phri.control.LoopResult` (`log`: the loop's), its stop logged as the
    loop logs one."""
    result = LoopResult(
        ticks=loop.ticks,
        log={key: log[key] for key in ("t", "q", "qd", "q_ref", "tau", "tau_ext", "wall_force")},
        held=loop.held,
        torque_clips=safety.torque_clips,  # type: ignore[attr-defined]
        rate_clips=safety.rate_clips,  # type: ignore[attr-defined]
        replan_failures=loop.replan_failures,
        wall_ticks=loop.wall_ticks,
        wall_peak_force=loop.wall_peak_force,
    )
    if loop.replan_failures:
        logger.error(
            "%d replans failed on the learner's worker (%s); the arm kept its plan",
            loop.replan_failures, loop.replan_error,
        )  # fmt: skip
    stop = loop.stop
    if stop is not None:
        v, tick, t, q, qd, tau, tau_ext, hold = stop
        event = StopEvent(
            reason=v.limit, message=v.message, tick=tick, t=t, q=q, qd=qd, tau=tau, tau_ext=tau_ext,
            quantity=v.quantity, index=v.index, value=v.value, bound=v.bound,
        )  # fmt: skip
        result.stop = event
        result.error = SafetyStopError(str(event), event)
        logger.warning("%s; %s", event, "holding the position" if hold else "ending the motion")
    return result
