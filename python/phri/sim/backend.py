"""The simulated study's JACO2 in PyBullet (:class:`phri.sim.world.World`) as a control-loop
:class:`~phri.control.backend.Backend`, with the simulated person on the world's side.

The person (:class:`phri.sim.participant.Participant`) pushes the hand in the simulator; the robot
only sees what its joint-torque sensor measures: Jᵀ·wrench at the hand plus Gaussian noise and a
constant bias, sampled at the study's sample rate and held in between (``RobotState.tau_ext``). The
noise is drawn only at sample instants, one draw per joint, from the generator given, so the
random streams are those of the study before the loop existed.
"""

from __future__ import annotations

import math

import numpy as np

from phri._phri import Robot
from phri.control.backend import RobotState
from phri.exceptions import InvalidParameterError
from phri.sim.participant import Participant
from phri.sim.world import HAND, World

__all__ = ["RATE_TOLERANCE", "PyBulletBackend", "steps_per_period"]

#: A rate's period may differ from a whole number of simulator steps by this fraction [-].
RATE_TOLERANCE = 1e-9


def steps_per_period(name: str, rate: float, dt: float) -> int:
    """The whole number of simulator steps of `dt` [s] in one period of `rate` [Hz], else an
    InvalidParameterError naming `name` and the nearby rates that are whole numbers of steps."""
    steps = 1.0 / (rate * dt)
    whole = round(steps)
    if whole >= 1 and abs(steps - whole) <= RATE_TOLERANCE * steps:
        return int(whole)
    nearby = sorted({max(1, math.floor(steps)), max(1, math.ceil(steps))})
    listed = ", ".join(f"{1.0 / (n * dt):g} Hz" for n in nearby)
    raise InvalidParameterError(
        f"{name} = {rate:g} Hz is not a whole number of simulator steps of {dt:g} s "
        f"(its period is {steps:.6g} steps, the simulator runs at {1.0 / dt:g} Hz); "
        f"nearby valid rates: {listed}"
    )


class PyBulletBackend:
    """`world`'s arm at the world's time step: a tick is one ``stepSimulation``.

    `participant` pushes the hand (None: nobody does). The sensor measures the person's joint
    torque Jᵀ·wrench [N·m] at `sample_rate` [Hz] (a whole number of simulator steps per sample)
    with Gaussian noise of `sensor_noise` [N·m] per joint drawn from `rng` and a constant
    `sensor_bias` [N·m] per joint (None: none), and holds the measurement between samples. The arm
    does not compensate gravity: the loop's torque includes g(q). The world's scene is the
    caller's (``world.set_scene``)."""

    gravity_compensated = False

    def __init__(
        self,
        world: World,
        *,
        participant: Participant | None = None,
        sample_rate: float = 10.0,
        sensor_noise: float = 0.1,
        sensor_bias: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.world = world
        #: phri's model of the simulated arm (the JACO2 with its cup).
        self.robot: Robot = world.model
        #: The control period [s]: the simulator's time step.
        self.period: float = world.params.timestep
        n = self.robot.nq
        if not (isinstance(sample_rate, int | float) and 0 < sample_rate <= 1.0 / self.period):
            raise InvalidParameterError(
                f"sample_rate must be in (0, {1.0 / self.period:g}] Hz, got {sample_rate!r}"
            )
        self.sample_every = steps_per_period("sample_rate", sample_rate, self.period)
        if not (isinstance(sensor_noise, int | float) and math.isfinite(sensor_noise) and sensor_noise >= 0):
            raise InvalidParameterError(f"sensor_noise must be a finite value >= 0 N·m, got {sensor_noise!r}")
        self.sensor_noise = float(sensor_noise)
        bias = np.zeros(n) if sensor_bias is None else np.asarray(sensor_bias, dtype=float)
        if bias.shape != (n,) or not np.isfinite(bias).all():
            raise InvalidParameterError(f"sensor_bias must be {n} finite values [N·m], got {sensor_bias!r}")
        self.bias = bias
        self.participant = participant
        self.rng = rng if rng is not None else np.random.default_rng(0)
        #: The person's wrench at the hand this tick (force [N], torque [N·m], world frame), or None.
        self.push: tuple[np.ndarray, np.ndarray] | None = None
        self._tick = 0
        self._measured = bias.copy()

    def start(self, q_start: np.ndarray) -> RobotState:
        """Places the arm at rest at `q_start` [rad] and returns the state at t = 0."""
        self.world.reset(q_start)
        self._tick = 0
        return self._state()

    def read(self) -> RobotState:
        """The state one time step after the previous one (the world stepped in :meth:`write`)."""
        self._tick += 1
        return self._state()

    def _state(self) -> RobotState:
        k = self._tick
        t = k * self.period
        q, qd = self.world.state()
        push = None if self.participant is None else self.participant.wrench(t, q)
        self.push = push
        if k % self.sample_every == 0:
            measured = (
                self.bias + self.rng.normal(0.0, self.sensor_noise, len(q))
                if self.sensor_noise
                else self.bias.copy()
            )
            if push is not None:
                measured += self.robot.jacobian(HAND, q).T @ np.concatenate(push)
            self._measured = measured
        return RobotState(t=t, q=q, qd=qd, tau_ext=self._measured)

    def write(self, tau: np.ndarray) -> None:
        """Applies `tau` [N·m] and the person's push for one time step and steps the physics."""
        push = self.push
        if push is None:
            self.world.step(tau)
        else:
            self.world.step(tau, push[0], push[1])

    def stop(self) -> None:
        """Ends the motion: the world is no longer stepped (nothing to release in a simulator)."""
        self.push = None
