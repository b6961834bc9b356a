"""A Franka (FR3 / Panda) over libfranka's official Python bindings (``pylibfranka``, the
``phri[franka]`` extra), as a :class:`phri.control.backend.Backend`: 1 kHz torque control, the
robot compensating gravity itself, and the robot's own estimate of the external torque as the
person's push. The same code drives a real arm or franky-sim's simulated one (``phri[franka-sim]``),
which speaks the same protocol on a loopback address.
"""

from __future__ import annotations

import math
import socket
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from phri._extras import require
from phri._phri import Robot
from phri.control.backend import RobotState
from phri.exceptions import ConnectionLostError, InvalidParameterError, RobotFaultError
from phri.franka.faults import ERROR_NAMES

__all__ = ["COMMAND_PORT", "CollisionThresholds", "FrankaBackend", "fault_message"]

#: The TCP port of the robot's command interface (libfranka's, and franky-sim's).
COMMAND_PORT = 1337
#: The Franka's joint count.
JOINTS = 7
#: What each of the robot's own modes means for an operator, and the recovery to do.
MODE_RECOVERY = {
    "Reflex": "the robot stopped itself (a collision or limit reflex); clear the cause, then call "
    "automatic_error_recovery() (phri does so on the next connect)",
    "UserStopped": "the user stop is pressed; release it, then restart the episode",
    "AutomaticErrorRecovery": "the robot is recovering from an error; wait until it is idle",
}


@dataclass(frozen=True)
class CollisionThresholds:
    """The robot's collision reflex thresholds (libfranka's ``set_collision_behavior``): a joint
    torque [N·m] or a Cartesian force/torque [N, N·m] beyond the upper threshold stops the robot.

    Twice the thresholds of libfranka's examples (20, 20, 18, 18, 16, 14, 12 N·m; 20 N and 25 N·m)
    so that a person's firm push, which phri learns from, is not a reflex; phri's own limits and
    virtual wall act first."""

    joint_lower: tuple[float, ...] = (40.0, 40.0, 36.0, 36.0, 32.0, 28.0, 24.0)
    joint_upper: tuple[float, ...] = (40.0, 40.0, 36.0, 36.0, 32.0, 28.0, 24.0)
    force_lower: tuple[float, ...] = (40.0, 40.0, 40.0, 50.0, 50.0, 50.0)
    force_upper: tuple[float, ...] = (40.0, 40.0, 40.0, 50.0, 50.0, 50.0)

    def __post_init__(self) -> None:
        for key, size in (("joint_lower", 7), ("joint_upper", 7), ("force_lower", 6), ("force_upper", 6)):
            value = tuple(float(v) for v in getattr(self, key))
            if len(value) != size or not all(math.isfinite(v) and v > 0 for v in value):
                raise InvalidParameterError(f"{key} must be {size} finite thresholds > 0, got {value}")
            object.__setattr__(self, key, value)
        for lower, upper in (("joint_lower", "joint_upper"), ("force_lower", "force_upper")):
            if any(a > b for a, b in zip(getattr(self, lower), getattr(self, upper), strict=True)):
                raise InvalidParameterError(f"{lower} must not exceed {upper}")


def fault_message(state: Any) -> str | None:
    """The robot's own reflex or error state in `state` (a pylibfranka RobotState) as a message
    naming the mode, the active errors (libfranka's ``Errors`` names, :data:`ERROR_NAMES`) and the
    recovery to do; None while there is none."""
    mode = getattr(state.robot_mode, "name", str(state.robot_mode))
    errors = state.current_errors
    active = [name for name in ERROR_NAMES if getattr(errors, name, False) is True] if errors else []
    if not active and mode not in MODE_RECOVERY:
        return None
    parts = [f"robot mode {mode}"]
    if active:
        parts.append("errors: " + ", ".join(active))
    recovery = MODE_RECOVERY.get(mode, MODE_RECOVERY["Reflex"])
    return f"the robot reports {'; '.join(parts)}: {recovery}"


def _nonfinite_message(block: np.ndarray) -> str:
    """Names the non-finite entries of a (3, 7) block of q, dq, tau_ext."""
    bad = [
        f"{field}[{j}]={block[i, j]}"
        for i, field in enumerate(("q", "dq", "tau_ext"))
        for j in range(JOINTS)
        if not math.isfinite(block[i, j])
    ]
    return (
        "the robot's state has non-finite values (" + ", ".join(bad) + "); a sensor or the link "
        "failed: stop, check the arm and its network before running again"
    )


class FrankaBackend:
    """A Franka over libfranka: :meth:`start` connects and starts torque control, :meth:`read` and
    :meth:`write` are one 1 kHz tick, :meth:`stop` ends control.

    `host`: the robot's address (franky-sim prints its loopback one). `robot`: phri's model of the
    arm (its joint count must be 7). `connect_timeout` [s]: an address where nothing answers is a
    ConnectionLostError after at most this long, never a hang. `realtime`: require a real-time
    kernel as on hardware (libfranka refuses to run without one otherwise); False for franky-sim on
    a desktop. `thresholds`: the robot's collision reflexes. `load`: the mass [kg], centre of mass
    in the flange frame [m] and inertia (3×3, [kg·m²]) of what the hand holds (hand and cup), or
    None to keep the robot's configured load."""

    period = 1e-3
    gravity_compensated = True

    def __init__(
        self,
        host: str,
        robot: Robot,
        *,
        connect_timeout: float = 5.0,
        realtime: bool = True,
        thresholds: CollisionThresholds | None = None,
        load: tuple[float, Sequence[float], Sequence[Sequence[float]]] | None = None,
    ) -> None:
        if not isinstance(host, str) or not host:
            raise InvalidParameterError(f"host must be the robot's address, got {host!r}")
        if robot.nq != JOINTS:
            raise InvalidParameterError(f"robot must be a {JOINTS}-joint Franka model, got {robot.nq} joints")
        if not (isinstance(connect_timeout, int | float) and 0 < connect_timeout <= 600):
            raise InvalidParameterError(f"connect_timeout must be in (0, 600] s, got {connect_timeout!r}")
        self.host, self.robot, self.connect_timeout, self.realtime = (
            host,
            robot,
            float(connect_timeout),
            realtime,
        )
        self.thresholds = thresholds or CollisionThresholds()
        self.load = load
        self._franka = require("pylibfranka", "the Franka backend")
        self._robot: Any = None
        self._control: Any = None
        self._t0: float | None = None
        self._torques = [0.0] * JOINTS
        #: The robot modes that are faults (pylibfranka's RobotMode members; compared per tick).
        self._fault_modes = frozenset(getattr(self._franka.RobotMode, m) for m in MODE_RECOVERY)
        #: The fault that ended control (every later read repeats it).
        self._fault: RobotState | None = None
        #: The last pylibfranka RobotState read, for fields phri does not use (None before start).
        self.raw: Any = None

    # -- connection ------------------------------------------------------------------------------

    def _connect(self) -> Any:
        """libfranka's Robot at `host`, or ConnectionLostError within the timeout. The port is probed
        first (a closed one fails at once), then libfranka connects in a thread joined with the
        timeout: it blocks, holding the interpreter, while it waits for an answer."""
        try:
            socket.create_connection((self.host, COMMAND_PORT), timeout=self.connect_timeout).close()
        except OSError as e:
            raise ConnectionLostError(
                f"host {self.host!r}: no robot answers on port {COMMAND_PORT} within "
                f"{self.connect_timeout:g} s ({e})"
            ) from None
        franka = self._franka
        config = franka.RealtimeConfig.kEnforce if self.realtime else franka.RealtimeConfig.kIgnore
        out: dict[str, Any] = {}

        def connect() -> None:
            try:
                out["robot"] = franka.Robot(self.host, config)
            except Exception as e:  # noqa: BLE001 - handed to the caller below
                out["error"] = e

        thread = threading.Thread(target=connect, name="phri-franka-connect", daemon=True)
        thread.start()
        thread.join(self.connect_timeout)
        if thread.is_alive():
            raise ConnectionLostError(
                f"host {self.host!r}: the robot did not finish connecting within {self.connect_timeout:g} s"
            )
        if "error" in out:
            error = out["error"]
            if isinstance(error, franka.RealtimeException):
                raise InvalidParameterError(
                    f"host {self.host!r}: {error}; run on a real-time kernel (see the docs), or pass "
                    "realtime=False for a simulator"
                ) from None
            raise ConnectionLostError(f"host {self.host!r}: {error}") from None
        return out["robot"]

    def read_once(self) -> RobotState:
        """Connects (unless connected) and reads the robot's state once, without starting control:
        where the arm is before a motion is planned. The connection is kept for :meth:`start`.
        The state's time is 0; its `fault` names a pending reflex (which :meth:`start` recovers)."""
        if self._robot is None:
            self._robot, self._t0 = self._connect(), None
        try:
            state = self._robot.read_once()
        except self._franka.NetworkException as e:
            self.stop()
            raise ConnectionLostError(f"host {self.host!r}: the robot stopped answering: {e}") from None
        self._t0 = None
        return self._state(state)

    def start(self, q_start: np.ndarray) -> RobotState:
        """Connects (or takes the connection :meth:`read_once` made), clears a pending reflex, sets
        the collision thresholds and the load, and starts torque control. The arm stays where it is
        (`q_start` is for the loop to drive it to)."""
        robot = self._robot if self._robot is not None else self._connect()
        self._robot, self._t0, self._fault = robot, None, None
        try:
            state = robot.read_once()
            pending = fault_message(state)
            if pending is not None:
                try:
                    robot.automatic_error_recovery()
                except self._franka.CommandException as e:
                    self.stop()
                    raise RobotFaultError(
                        f"host {self.host!r}: {pending}; phri's automatic error recovery was refused: {e}"
                    ) from None
            th = self.thresholds
            robot.set_collision_behavior(th.joint_lower, th.joint_upper, th.force_lower, th.force_upper)
            if self.load is not None:
                mass, com, inertia = self.load
                robot.set_load(
                    float(mass), [float(c) for c in com], [float(v) for v in np.asarray(inertia).T.ravel()]
                )
            self._control = robot.start_torque_control()
        except self._franka.NetworkException as e:
            self.stop()
            raise ConnectionLostError(f"host {self.host!r}: {e}") from None
        except (self._franka.ControlException, self._franka.CommandException) as e:
            self.stop()
            raise RobotFaultError(f"host {self.host!r}: the robot refused torque control: {e}") from None
        return self.read()

    # -- one tick ----------------------------------------------------------------------------------

    def read(self) -> RobotState:
        """Blocks until the arm's next 1 kHz tick and returns its state (libfranka's ``readOnce``);
        a lost connection is a ConnectionLostError. ``tau_ext`` is the person's push on the arm
        [N·m] (phri's sign, as in simulation): the negative of libfranka's ``tau_ext_hat_filtered``,
        which libfranka gives as the torque the robot exerts on its surroundings."""
        if self._fault is not None:
            return self._fault
        if self._control is None:
            raise ConnectionLostError(f"host {self.host!r}: not connected (call start first)")
        try:
            state, _ = self._control.readOnce()
        except self._franka.NetworkException as e:
            raise ConnectionLostError(f"host {self.host!r}: the robot stopped answering: {e}") from None
        except self._franka.ControlException as e:
            # libfranka's message says why (a reflex and its errors, or the user stop).
            mode = "UserStopped" if "User Stop" in str(e) else "Reflex"
            # With the last state the robot sent (its time and pose), NaN if there was none.
            self._fault = self._state(
                self.raw, fault=f"the robot aborted control: {e}; {MODE_RECOVERY[mode]}"
            )
            return self._fault
        return self._state(state)

    def _state(self, state: Any, fault: str | None = None) -> RobotState:
        if state is None:
            nan = np.full(JOINTS, np.nan)
            return RobotState(t=math.nan, q=nan, qd=nan.copy(), tau_ext=nan.copy(), fault=fault)
        self.raw = state
        t = state.time.to_sec()
        if self._t0 is None:
            self._t0 = t
        # One array per tick (rows q, dq, tau_ext), fresh: a caller may keep the state it was given.
        block = np.array((state.q, state.dq, state.tau_ext_hat_filtered))
        np.negative(block[2], out=block[2])
        if state.current_errors or state.robot_mode in self._fault_modes:
            fault = fault or fault_message(state)
        if not np.isfinite(block).all():
            fault = fault or _nonfinite_message(block)
        return RobotState(t=t - self._t0, q=block[0], qd=block[1], tau_ext=block[2], fault=fault)

    def write(self, tau: np.ndarray) -> None:
        """Commands the joint torque `tau` [N·m] for the tick just read, gravity excluded (the robot
        compensates it); libfranka's ``writeOnce``."""
        if self._control is None:
            raise ConnectionLostError(f"host {self.host!r}: not connected (call start first)")
        torques = self._torques
        for j in range(JOINTS):
            torques[j] = float(tau[j])
        try:
            self._control.writeOnce(self._franka.Torques(torques))
        except self._franka.NetworkException as e:
            raise ConnectionLostError(f"host {self.host!r}: the robot stopped answering: {e}") from None
        except self._franka.ControlException as e:
            raise RobotFaultError(f"host {self.host!r}: the robot aborted control: {e}") from None

    def stop(self) -> None:
        """Ends torque control and releases the arm; idempotent, never raises for an arm already
        gone."""
        robot, self._robot, self._control, self._fault = self._robot, None, None, None
        if robot is not None:
            try:
                robot.stop()
            except Exception:  # noqa: BLE001, S110 - an arm already gone has nothing to stop
                pass
