"""The Franka backend over the real libfranka protocol, against franky-sim's simulated FR3 started
here on loopback addresses (and always stopped): connect, torque control, the external torque, the
robot's faults, a lost connection, and an address where nothing answers."""

from __future__ import annotations

import time
from collections.abc import Iterator
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from phri import Robot
from phri.control import Backend, RobotState
from phri.exceptions import ConnectionLostError, InvalidParameterError, MissingExtraError
from phri.franka import CollisionThresholds, FrankaBackend, fault_message
from phri.franka.sim_server import SimServer

#: franky-sim's own FR3 description (the parameters its libfranka model is computed from).
FR3_URDF = Path(str(resources.files("franky_sim").joinpath("assets", "fr3.urdf")))


def fr3() -> Robot:
    return Robot.from_urdf(FR3_URDF, "base", "fr3_link8")


@pytest.fixture(scope="module")
def server() -> Iterator[SimServer]:
    with SimServer("127.0.0.41", realtime=1.0) as s:
        yield s


def test_torque_control_over_the_protocol(server: SimServer) -> None:
    backend = FrankaBackend(server.host, fr3(), realtime=False)
    assert isinstance(backend, Backend) and backend.gravity_compensated
    try:
        first = backend.start(np.zeros(7))
        assert isinstance(first, RobotState) and first.fault is None
        assert first.q.shape == (7,) and np.all(np.isfinite(first.q))
        times, states = [], []
        for _ in range(300):
            state = backend.read()
            backend.write(np.zeros(7))  # the robot compensates gravity: zero torque holds the arm
            times.append(state.t)
            states.append(state)
        # Each state owns its arrays: a state kept (a log row) is not overwritten by the next read.
        assert not np.shares_memory(states[0].q, states[1].q)
        assert not np.shares_memory(states[-1].q, states[-1].tau_ext)
        # The robot's clock advances a millisecond per tick (lateness is measured on it).
        steps = np.diff(times)
        assert np.all(steps > 0) and np.median(steps) == pytest.approx(1e-3, abs=1e-6)
        assert np.all(np.isfinite(state.tau_ext)) and state.fault is None
        assert np.max(np.abs(state.q - first.q)) < 0.05
    finally:
        backend.stop()
        backend.stop()  # idempotent


def test_a_killed_server_is_a_lost_connection() -> None:
    with SimServer("127.0.0.42") as server:
        backend = FrankaBackend(server.host, fr3(), realtime=False)
        backend.start(np.zeros(7))
        for _ in range(20):
            backend.read()
            backend.write(np.zeros(7))
        server.stop()
        with pytest.raises(ConnectionLostError, match="127.0.0.42"):
            for _ in range(2000):  # libfranka notices within its own timeout
                backend.read()
                backend.write(np.zeros(7))
        backend.stop()


def test_nothing_at_the_address_is_a_clear_error_within_the_timeout() -> None:
    backend = FrankaBackend("127.0.0.43", fr3(), connect_timeout=1.0, realtime=False)
    began = time.monotonic()
    with pytest.raises(
        ConnectionLostError, match=r"host '127.0.0.43': no robot answers on port 1337 within 1 s"
    ):
        backend.start(np.zeros(7))
    assert time.monotonic() - began < 5


def test_the_robots_own_faults_name_the_recovery() -> None:
    class Errors:
        joint_reflex = True
        cartesian_reflex = False

    class Mode:
        name = "Reflex"

    class State:
        robot_mode = Mode()
        current_errors = Errors()

    message = fault_message(State())
    assert message is not None
    assert "robot mode Reflex" in message and "joint_reflex" in message and "cartesian_reflex" not in message
    assert "automatic_error_recovery" in message
    Mode.name, Errors.joint_reflex = "Move", False
    assert fault_message(State()) is None


def test_bad_arguments_are_named() -> None:
    with pytest.raises(InvalidParameterError, match="host must be"):
        FrankaBackend("", fr3())
    with pytest.raises(InvalidParameterError, match="robot must be a 7-joint Franka model"):
        FrankaBackend("127.0.0.44", Robot.from_urdf(FR3_URDF, "base", "fr3_link5"))
    with pytest.raises(InvalidParameterError, match="connect_timeout"):
        FrankaBackend("127.0.0.44", fr3(), connect_timeout=0)
    with pytest.raises(InvalidParameterError, match="joint_upper must be 7 finite thresholds"):
        CollisionThresholds(joint_upper=(1.0,))
    with pytest.raises(InvalidParameterError, match="loopback"):
        SimServer("10.0.0.1")


def test_without_the_extra_the_error_names_the_install(monkeypatch: pytest.MonkeyPatch) -> None:
    import phri._extras

    monkeypatch.setattr(phri._extras, "available", lambda module: False)
    real = phri._extras.importlib.import_module

    def missing(name: str, *args: object) -> object:
        if name.startswith("pylibfranka"):
            raise ModuleNotFoundError(name)
        return real(name, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(phri._extras.importlib, "import_module", missing)
    with pytest.raises(MissingExtraError, match=r"phri\[franka\]"):
        FrankaBackend("127.0.0.44", fr3())
