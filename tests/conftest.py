"""Shared fixtures: the shipped JACO2 in phri and in PyBullet, a seeded generator, random configurations."""

from __future__ import annotations

import importlib.resources
import importlib.util
import os
import subprocess
import sys
import textwrap

# Ray instances the tests start listen on loopback only (the house rule; see
# phri.study.parallel.RAY_LOCAL_ONLY_ENV): Ray reads this when it is imported.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import NamedTuple

import numpy as np
import pybullet as p
import pytest

import phri

SEED = 20171113  # fixed: every run draws the same configurations
GRAVITY = (0.0, 0.0, -9.81)


def jaco2_urdf_path() -> Path:
    """The JACO2 description shipped inside the phri package."""
    resource = importlib.resources.files("phri").joinpath("robots/jaco2/j2s7s300.urdf")
    path = Path(str(resource))
    assert path.is_file(), f"shipped URDF not found at {path}"
    return path


def load_bench(name: str) -> ModuleType:
    """benches/<name>.py as a module (benches are scripts, not a package), for the tests that run
    a bench's own code on a small problem or share its definitions."""
    path = Path(__file__).resolve().parents[1] / "benches" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it loads
    spec.loader.exec_module(module)
    return module


def random_configurations(
    lower: np.ndarray, upper: np.ndarray, rng: np.random.Generator, n: int
) -> np.ndarray:
    """(n, nq) joint positions [rad] uniform within the limits; continuous joints uniform in [0, 2π)."""
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    limited = np.isfinite(lower) & np.isfinite(upper)
    lo = np.where(limited, lower, 0.0)
    hi = np.where(limited, upper, 2.0 * np.pi)
    return lo + (hi - lo) * rng.random((n, lower.size))


class PyBulletRobot(NamedTuple):
    """A robot loaded in its own PyBullet DIRECT client; unpacks as (client, body, links, joints)."""

    client: int
    body: int
    links: dict[str, int]  # URDF link name -> PyBullet link index (-1 for the base link)
    joints: list[int]  # indices of the movable joints, base to tip


@pytest.fixture
def robot() -> phri.Robot:
    return phri.Robot.jaco2()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


@pytest.fixture
def draw_q(robot: phri.Robot, rng: np.random.Generator) -> Callable[[int], np.ndarray]:
    """`draw_q(n)`: (n, 7) random JACO2 configurations within limits, from the seeded `rng`."""
    return lambda n: random_configurations(robot.lower_limits, robot.upper_limits, rng, n)


@pytest.fixture
def load_pybullet() -> Iterator[Callable[[str | Path], PyBulletRobot]]:
    """`load_pybullet(path)`: a URDF in a fresh DIRECT client (fixed base, inertia from the file,
    gravity 9.81 m/s² along −z). Every client opened is disconnected at teardown."""
    clients: list[int] = []

    def load(path: str | Path) -> PyBulletRobot:
        client = p.connect(p.DIRECT)
        clients.append(client)
        body = p.loadURDF(
            str(path), useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client
        )
        p.setGravity(*GRAVITY, physicsClientId=client)
        base_name = p.getBodyInfo(body, physicsClientId=client)[0].decode()
        links = {base_name: -1}
        joints = []
        for j in range(p.getNumJoints(body, physicsClientId=client)):
            info = p.getJointInfo(body, j, physicsClientId=client)
            links[info[12].decode()] = j
            if info[2] != p.JOINT_FIXED:
                joints.append(j)
        return PyBulletRobot(client, body, links, joints)

    yield load
    for client in clients:
        p.disconnect(physicsClientId=client)


@pytest.fixture(scope="module")
def world():
    """The simulated world (the JACO2 carrying the cup, in PyBullet), one per test module."""
    from phri.sim import World

    with World() as w:
        yield w


@pytest.fixture(scope="module")
def planners(world):
    """The planner of each of the paper's four tasks, by task name."""
    from phri.sim.episode import Planner

    return {name: Planner(phri.load_task(name), world) for name in ("human", "coffee", "table", "laptop")}


@pytest.fixture
def pybullet_jaco2(load_pybullet: Callable[[str | Path], PyBulletRobot]) -> PyBulletRobot:
    """The shipped JACO2 URDF in PyBullet: (client id, body id, {link name: link index}, movable joints)."""
    return load_pybullet(jaco2_urdf_path())


# -- a Python without some modules -----------------------------------------------------------------

BLOCKER = """
import importlib.abc, sys
BLOCKED = set(sys.argv[1].split(","))
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
        return None
sys.meta_path.insert(0, Refuse())
"""


def run_without(blocked: set[str], code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Runs `code` in a fresh interpreter in which the modules `blocked` cannot be imported."""
    script = BLOCKER + textwrap.dedent(code)
    return subprocess.run(
        [sys.executable, "-c", script, ",".join(sorted(blocked))],
        cwd=cwd, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
