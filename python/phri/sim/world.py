"""The simulated study scene in PyBullet: the JACO2 on its mount holding a cup, the table, the
laptop and a stand-in for the person, stepped at 1 kHz in torque control.

Positions are those of original_system.md (robot base frame, z up, metres). PyBullet runs in DIRECT
mode unless ``gui=True``. Pictures come from PyBullet's software renderer (no display needed).
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from phri._phri import Robot
from phri.config import Scene
from phri.exceptions import SimulationError

__all__ = ["CUP_INERTIA", "CUP_MASS", "World", "WorldParams"]

CUP_MASS = 0.3  # kg, the shipped cup.urdf
CUP_INERTIA = np.diag([0.00037, 0.00037, 0.00024])  # kg·m² about its centre, cup frame axes
HAND = "j2s7s300_end_effector"
CUP_FRAME = "j2s7s300_cup_frame"
LINK_7 = "j2s7s300_link_7"


@dataclass(frozen=True)
class WorldParams:
    """Physics settings. The defaults are the study's: 1 kHz, gravity 9.81 m/s²."""

    timestep: float = 1e-3  # s
    gravity: float = 9.81  # m/s²
    gui: bool = False
    joint_damping: float = 0.0  # N·m·s/rad of viscous friction in every joint (0 = ideal arm)


def _flush_all() -> None:
    """Flushes Python's and the C library's buffered standard output and error."""
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            try:
                stream.flush()
            except (OSError, ValueError):  # a closed or broken stream: nothing to keep in order
                pass
    try:
        ctypes.CDLL(None).fflush(None)  # every C stdio stream
    except (OSError, AttributeError, TypeError):  # no C library to reach (e.g. Windows)
        pass


@contextmanager
def _quiet_c_output() -> Iterator[None]:
    """Sends what C code writes to file descriptors 1 and 2 to the null device meanwhile.

    Both Python's and C's buffers are flushed before the switch (so earlier output keeps its place)
    and again before switching back (so what was written meanwhile is dropped, not delayed)."""
    _flush_all()
    saved: list[tuple[int, int]] = []
    try:
        with open(os.devnull, "w") as devnull:
            for fd in (1, 2):
                try:
                    saved.append((fd, os.dup(fd)))
                except OSError:  # a closed descriptor: nothing to protect
                    continue
                os.dup2(devnull.fileno(), fd)
            try:
                yield
            finally:
                _flush_all()
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def _pybullet():
    """pybullet, imported without the "pybullet build time" line its C code prints."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with _quiet_c_output():
        import pybullet
    return pybullet


def _asset(*parts: str) -> str:
    return str(resources.files("phri").joinpath("robots", *parts))


def arm_with_cup_urdf() -> str:
    """The shipped arm with the shipped cup fixed at its cup frame, as one URDF document."""
    arm = ET.parse(_asset("jaco2", "j2s7s300.urdf")).getroot()
    cup = ET.parse(_asset("jaco2", "cup.urdf")).getroot()
    for material in cup.findall("material"):
        arm.insert(0, material)
    arm.extend(cup.findall("link"))
    joint = ET.SubElement(arm, "joint", name="cup_grasp", type="fixed")
    ET.SubElement(joint, "parent", link=CUP_FRAME)
    ET.SubElement(joint, "child", link="cup")
    ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    return ET.tostring(arm, encoding="unicode")


class World:
    """One PyBullet client with the scene; reuse it across episodes with :meth:`reset`."""

    def __init__(self, scene: Scene | None = None, params: WorldParams | None = None) -> None:
        p = _pybullet()
        self.p = p
        self.scene = scene or Scene()
        self.params = params or WorldParams()
        self.client = p.connect(p.GUI if self.params.gui else p.DIRECT)
        c = self.client
        p.setTimeStep(self.params.timestep, physicsClientId=c)
        p.setGravity(0.0, 0.0, -self.params.gravity, physicsClientId=c)
        # The arm and its cup as one multibody (a rigid grasp): no constraint for the solver to chase.
        # Self-collision stays off: adjacent primitives overlap at the joints by design.
        with tempfile.TemporaryDirectory() as folder:
            urdf = Path(folder) / "j2s7s300_with_cup.urdf"
            urdf.write_text(arm_with_cup_urdf(), encoding="utf-8")
            self.robot_id = p.loadURDF(
                str(urdf), useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=c
            )
        self.links = {p.getBodyInfo(self.robot_id, physicsClientId=c)[0].decode(): -1}
        self.joints: list[int] = []
        for j in range(p.getNumJoints(self.robot_id, physicsClientId=c)):
            info = p.getJointInfo(self.robot_id, j, physicsClientId=c)
            self.links[info[12].decode()] = j
            if info[2] != p.JOINT_FIXED:
                self.joints.append(j)
        # Torque control: switch off the default velocity motors first.
        p.setJointMotorControlArray(
            self.robot_id, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * len(self.joints), physicsClientId=c
        )
        for j in self.joints:
            p.changeDynamics(
                self.robot_id, j, linearDamping=0.0, angularDamping=0.0,
                jointDamping=self.params.joint_damping, physicsClientId=c,
            )  # fmt: skip
        self._build_scene()
        # phri's model of what the robot carries: the arm plus the cup, for gravity compensation.
        self.model = Robot.jaco2().with_payload(CUP_FRAME, CUP_MASS, inertia=CUP_INERTIA)

    def _build_scene(self) -> None:
        p, c, s = self.p, self.client, self.scene

        def box(half, pos, rgba, collide=True):
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c) if collide else -1
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=c)
            return p.createMultiBody(0, col, vis, basePosition=pos, physicsClientId=c)

        top = s.table_height
        # Mount under the robot base, table top at `table_height`, spanning x in [-0.81, 0].
        self.mount_id = box(
            [0.08, 0.08, (0.0 - (top - 0.7)) / 2], [0.0, 0.0, (top - 0.7) / 2], [0.3, 0.3, 0.3, 1], False
        )
        self.table_id = box([0.405, 0.81, 0.02], [-0.405, 0.0, top - 0.02], [0.6, 0.45, 0.3, 1])
        lx, ly = s.laptop_center
        self.laptop_id = box([0.115, 0.15, 0.0125], [lx, ly + 0.1, top + 0.0125], [0.15, 0.15, 0.18, 1])
        # The person: a visual-only column at the human feature centre (it must not block the arm).
        hx, hy = s.human_center
        vis = self.p.createVisualShape(
            p.GEOM_CYLINDER, radius=0.15, length=1.7, rgbaColor=[0.85, 0.6, 0.45, 0.35], physicsClientId=c
        )
        self.human_id = p.createMultiBody(0, -1, vis, basePosition=[hx, hy, top + 0.85], physicsClientId=c)

    def set_scene(self, scene: Scene) -> None:
        """Moves the table, laptop and person to `scene` (a task's [scene]); no-op if already there."""
        if scene == self.scene:
            return
        for body in (self.mount_id, self.table_id, self.laptop_id, self.human_id):
            self.p.removeBody(body, physicsClientId=self.client)
        self.scene = scene
        self._build_scene()

    def reset(self, q: np.ndarray) -> None:
        """Puts the arm at rest at `q` [rad] and the cup in the hand."""
        p, c = self.p, self.client
        for j, v in zip(self.joints, np.asarray(q, dtype=float), strict=True):
            p.resetJointState(self.robot_id, j, float(v), 0.0, physicsClientId=c)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions [rad] and velocities [rad/s]."""
        states = self.p.getJointStates(self.robot_id, self.joints, physicsClientId=self.client)
        q = [s[0] for s in states]
        qd = [s[1] for s in states]
        if not math.isfinite(sum(q) + sum(qd)):
            raise SimulationError(f"the simulator returned a non-finite joint state q={q}, qd={qd}")
        return np.array(q), np.array(qd)

    def hand_position(self) -> np.ndarray:
        """World position of the tool point (where the person pushes) [m]."""
        s = self.p.getLinkState(
            self.robot_id, self.links[HAND], computeForwardKinematics=True, physicsClientId=self.client
        )
        return np.array(s[4])

    def step(
        self, tau: np.ndarray, force: np.ndarray | None = None, torque: np.ndarray | None = None
    ) -> None:
        """Applies joint torques `tau` [N·m] and, if given, a push at the hand (world-frame force [N]
        at the tool point, torque [N·m]) for one time step, then steps the physics."""
        p, c = self.p, self.client
        p.setJointMotorControlArray(
            self.robot_id, self.joints, p.TORQUE_CONTROL, forces=tau, physicsClientId=c
        )
        hand = self.links[HAND]
        if force is not None:
            pos = self.hand_position()
            p.applyExternalForce(
                self.robot_id, hand, force.tolist(), pos.tolist(), p.WORLD_FRAME, physicsClientId=c
            )
        if torque is not None:
            p.applyExternalTorque(self.robot_id, hand, torque.tolist(), p.WORLD_FRAME, physicsClientId=c)
        p.stepSimulation(physicsClientId=c)

    def render(self, path: str | Path, width: int = 480, height: int = 360) -> Path:
        """Writes a PNG of the scene from PyBullet's software renderer."""
        p, c = self.p, self.client
        view = p.computeViewMatrix([0.9, -1.2, 0.8], [-0.3, 0.0, 0.05], [0, 0, 1], physicsClientId=c)
        proj = p.computeProjectionMatrixFOV(50, width / height, 0.05, 5.0, physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=c
        )
        image = np.reshape(np.asarray(rgba, dtype=np.uint8), (height, width, 4))[:, :, :3]
        import matplotlib.image

        path = Path(path)
        matplotlib.image.imsave(path, image)
        return path

    def close(self) -> None:
        if self.client is not None and self.p.isConnected(self.client):
            self.p.disconnect(self.client)
        self.client = None  # type: ignore[assignment]

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
