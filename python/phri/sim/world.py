"""The simulated study scene in PyBullet: the JACO2 on its mount holding a cup and the objects of
a task's scene (the study's: the table, the laptop and a stand-in for the person), stepped at 1 kHz
in torque control.

Positions are the scene's (robot base frame, z up, metres). The person is visual only: the arm may
pass through their stand-in, as it is the person who moves it. PyBullet runs in DIRECT mode unless
``gui=True``. Pictures come from PyBullet's software renderer (no display needed).
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

from phri import robots
from phri._phri import Robot, Scene, SceneObject
from phri._validate import must_be
from phri.config import TABLE
from phri.exceptions import InvalidParameterError, SimulationError

__all__ = ["CUP_INERTIA", "CUP_MASS", "World", "WorldParams"]

#: The shipped cup's mass [kg] (cup.urdf).
CUP_MASS = 0.3
#: The shipped cup's inertia about its centre, in the cup frame's axes [kg·m²].
CUP_INERTIA = np.diag([0.00037, 0.00037, 0.00024])
#: The simulated arm's description (its URDF and frame names).
JACO2 = robots.load("jaco2")
HAND: str = JACO2.hand_frame  # type: ignore[assignment]
CUP_FRAME: str = JACO2.cup_frame  # type: ignore[assignment]
#: Colours (RGBA) of the study's objects by name; others are grey, the person skin-coloured.
COLORS = {"table": [0.6, 0.45, 0.3, 1], "laptop": [0.15, 0.15, 0.18, 1]}
PERSON_COLOR = [0.85, 0.6, 0.45, 0.35]
OTHER_COLOR = [0.5, 0.5, 0.5, 1]
#: The robot's mount stands this far below the table top, on the floor [m].
MOUNT_DEPTH = 0.7


@dataclass(frozen=True)
class WorldParams:
    """Physics settings. The defaults are the study's: 1 kHz, gravity 9.81 m/s². Each is refused
    outside the range in which the simulated arm means something (an InvalidParameterError naming
    it): timestep in [1e-5, 0.01] s, gravity in [0, 100] m/s², joint_damping in [0, 1000] N·m·s/rad."""

    timestep: float = 1e-3  # s
    gravity: float = 9.81  # m/s²
    gui: bool = False
    joint_damping: float = 0.0  # N·m·s/rad of viscous friction in every joint (0 = ideal arm)

    def __post_init__(self) -> None:
        for key, (low, high, unit) in WORLD_RANGES.items():
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
                raise must_be(
                    key, f"a number in [{low:g}, {high:g}] {unit}", value, error=InvalidParameterError
                )
        if not isinstance(self.gui, bool):
            raise must_be("gui", "True or False", self.gui, error=InvalidParameterError)


#: The accepted range of each WorldParams number (low, high, unit).
WORLD_RANGES = {
    "timestep": (1e-5, 1e-2, "s"),
    "gravity": (0.0, 100.0, "m/s²"),
    "joint_damping": (0.0, 1000.0, "N·m·s/rad"),
}


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
    arm = ET.parse(JACO2.urdf).getroot()
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
        self.scene = Scene() if scene is None else scene
        #: PyBullet body of each scene object, by name; the robot's stand is `mount_id`.
        self.bodies: dict[str, int] = {}
        self.mount_id: int | None = None
        self.params = params or WorldParams()
        self.client = p.connect(p.GUI if self.params.gui else p.DIRECT)
        c = self.client
        p.setTimeStep(self.params.timestep, physicsClientId=c)
        p.setGravity(0.0, 0.0, -self.params.gravity, physicsClientId=c)
        # The arm and its cup as one multibody (a rigid grasp): no constraint for the solver to chase.
        # Self-collision stays off: adjacent primitives overlap at the joints by design.
        with tempfile.TemporaryDirectory() as folder:
            urdf = Path(folder) / "arm_with_cup.urdf"
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
        p, c = self.p, self.client
        table = self.scene.get(TABLE)
        top = None if table is None else table.top
        if top is not None:
            # The robot's stand (not a scene object): from the floor under the table to the base.
            half = [0.08, 0.08, (0.0 - (top - MOUNT_DEPTH)) / 2]
            vis = p.createVisualShape(
                p.GEOM_BOX, halfExtents=half, rgbaColor=[0.3, 0.3, 0.3, 1], physicsClientId=c
            )
            self.mount_id = p.createMultiBody(
                0, -1, vis, basePosition=[0.0, 0.0, (top - MOUNT_DEPTH) / 2], physicsClientId=c
            )
        for obj in self.scene.objects:
            self.bodies[obj.name] = self._body(obj)

    def _body(self, obj: SceneObject) -> int:
        """A static PyBullet body for `obj`; the person's is visual only (it must not block the arm)."""
        p, c = self.p, self.client
        person = obj.kind == "person"
        rgba = PERSON_COLOR if person else COLORS.get(obj.name, OTHER_COLOR)
        # PyBullet spells a cylinder's length "height" for collision shapes, "length" for visual ones.
        if obj.shape == "box" and obj.size is not None:
            collision = visual = {"shapeType": p.GEOM_BOX, "halfExtents": [float(h) / 2 for h in obj.size]}
        elif obj.shape == "cylinder":
            collision = {"shapeType": p.GEOM_CYLINDER, "radius": obj.radius, "height": obj.length}
            visual = {"shapeType": p.GEOM_CYLINDER, "radius": obj.radius, "length": obj.length}
        elif obj.shape == "sphere":
            collision = visual = {"shapeType": p.GEOM_SPHERE, "radius": obj.radius}
        else:
            collision = visual = {"shapeType": p.GEOM_PLANE, "planeNormal": [0, 0, 1]}
        col = -1 if person else p.createCollisionShape(**collision, physicsClientId=c)
        vis = p.createVisualShape(**visual, rgbaColor=rgba, physicsClientId=c)
        position = [float(x) for x in obj.position]
        orientation = p.getQuaternionFromEuler([float(a) for a in obj.rpy])
        return p.createMultiBody(
            0, col, vis, basePosition=position, baseOrientation=orientation, physicsClientId=c
        )

    def set_scene(self, scene: Scene) -> None:
        """Moves the world to `scene` (a task's [scene]); no-op if already there."""
        if scene == self.scene:
            return
        for body in [self.mount_id, *self.bodies.values()]:
            if body is not None:
                self.p.removeBody(body, physicsClientId=self.client)
        self.bodies, self.mount_id = {}, None
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
        """World position of the tool point (where the person pushes) [m]: phri's model's hand frame
        at the arm's joint positions. (PyBullet's own link frame lies about 3e-8 m from it, its
        rounding of the URDF's chain, which would change a push's joint torques by about 1e-6 of
        themselves and set PyBullet apart from the native simulator, phri.sim.native.)"""
        # Also refreshes PyBullet's link poses, which stepSimulation leaves one step stale and from
        # which applyExternalForce takes the push's lever arm.
        self.p.getLinkState(
            self.robot_id, self.links[HAND], computeForwardKinematics=True, physicsClientId=self.client
        )
        q, _ = self.state()
        return self.model.frame_pose(HAND, q)[:3, 3]

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
        # From the front right, far and high enough that the arm stretched up or out stays in view.
        view = p.computeViewMatrix([1.7, -1.9, 1.5], [-0.15, 0.25, 0.25], [0, 0, 1], physicsClientId=c)
        proj = p.computeProjectionMatrixFOV(45, width / height, 0.05, 6.0, physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=c
        )
        image = np.reshape(np.asarray(rgba, dtype=np.uint8), (height, width, 4))[:, :, :3]
        import matplotlib.image

        path = Path(path)
        matplotlib.image.imsave(path, image)
        return path

    def close(self) -> None:
        """Disconnects from PyBullet; closing twice does nothing."""
        if self.client is not None and self.p.isConnected(self.client):
            self.p.disconnect(self.client)
        self.client = None  # type: ignore[assignment]

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
