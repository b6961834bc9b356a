"""The interface between phri's control loop and an arm: read the state, write a torque, the
robot's clock, stop. The loop (:mod:`phri.control.loop`) is the same for every arm; a backend is
all a lab writes to run phri on another one.

Two backends ship with phri: the PyBullet JACO2 of the simulated study
(:class:`phri.sim.backend.PyBulletBackend`) and libfranka (:class:`phri.franka.FrankaBackend`), which
drives a real FR3 or franky-sim's simulated one over the same network protocol.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from phri._phri import Robot

__all__ = ["Backend", "RobotState"]


@dataclass
class RobotState:
    """One tick's reading of the arm. Arrays have one entry per joint."""

    #: The robot's own clock [s] since the backend started: simulated time in simulation, the
    #: controller's time stamp on hardware. Lateness is measured on it, never on the wall clock.
    t: float
    #: Joint positions [rad].
    q: np.ndarray
    #: Joint velocities [rad/s].
    qd: np.ndarray
    #: The robot's estimate of the external joint torque, the person's push [N·m] (libfranka's
    #: ``tau_ext_hat_filtered``; in simulation the sensor model's measurement).
    tau_ext: np.ndarray
    #: The robot's own reflex or error state as a message naming it and the recovery to do; None
    #: while there is none. The loop stops the arm on any.
    fault: str | None = None


@runtime_checkable
class Backend(Protocol):
    """An arm the control loop drives at its control rate.

    The loop calls :meth:`start` once, then per tick :meth:`read` and :meth:`write`, and
    :meth:`stop` once at the end, also after an error. ``read`` blocks until the arm's next tick; a
    backend raises :class:`phri.exceptions.ConnectionLostError` when the arm stops answering and
    reports the arm's own faults in :attr:`RobotState.fault`.
    """

    #: phri's model of the arm (kinematics, dynamics, limits, collision model).
    robot: Robot
    #: The control period [s] (0.001 for 1 kHz).
    period: float
    #: True when the arm compensates gravity itself and :meth:`write` takes the torque without
    #: g(q) (libfranka); False when the commanded torque must include it (PyBullet).
    gravity_compensated: bool

    def start(self, q_start: np.ndarray) -> RobotState:
        """Prepares the arm for torque control and returns its first state. A simulator places the
        arm at `q_start` [rad]; a real arm stays where it is (the loop drives it there)."""
        ...

    def read(self) -> RobotState:
        """Blocks until the arm's next tick and returns its state."""
        ...

    def write(self, tau: np.ndarray) -> None:
        """Commands the joint torque `tau` [N·m] for the tick just read (without gravity if
        :attr:`gravity_compensated`)."""
        ...

    def stop(self) -> None:
        """Ends torque control and releases the arm; idempotent, never raises for an arm already
        gone."""
        ...
