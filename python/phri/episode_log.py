"""What an episode log records besides its time series: the robot and the scene it ran in, so that
the log alone is enough to replay it (:mod:`phri.view`).

Every episode log (simulated, :func:`phri.sim.episode.score_episode`, or on the FR3,
:mod:`phri.franka.episode`) holds these keys next to its time series:

- ``robot``: the shipped robot the task is posed for (``"jaco2"``, ``"fr3"``), ``task`` and
  ``strategy``; ``frame``: the frame the features read (the cup or the hand);
- ``sphere_frames`` (S,), ``sphere_centers`` (S, 3) [m, in their frame], ``sphere_radii`` (S,) [m]
  and ``sphere_bodies`` (S,) (rows of ``body_names``): the robot's collision spheres as the planner
  and the safety checks saw them (the carried cup's included);
- ``object_shapes``, ``object_kinds`` (n,), ``object_poses`` (n, 4, 4) [m] in the robot's base frame
  and ``object_dims`` (n, 3) [m] (a box's full extents; a cylinder's radius and length; a sphere's
  radius; zeros for a plane): the scene, in the order of ``object_names``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from phri._phri import Robot, Scene

__all__ = ["GEOMETRY_KEYS", "Geometry", "geometry_arrays", "nearest_rows"]

#: The keys :func:`geometry_arrays` writes.
GEOMETRY_KEYS = (
    "robot", "task", "strategy", "frame", "sphere_frames", "sphere_centers", "sphere_radii",
    "sphere_bodies", "object_shapes", "object_kinds", "object_poses", "object_dims",
)  # fmt: skip


def nearest_rows(t: np.ndarray, times: np.ndarray) -> np.ndarray:
    """For each of `times` [s], the row of the log times `t` (ascending) nearest to it (the earlier
    of two equally near; the last row for a time past the log's end)."""
    if len(t) <= 1:
        return np.zeros(len(times), dtype=int)
    i = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    return i - ((times - t[i - 1]) <= (t[i] - times)).astype(int)


def _dims(obj: Any) -> list[float]:
    """A scene object's extents as ``object_dims`` holds them [m]."""
    if obj.shape == "box":
        return [float(x) for x in obj.size]
    if obj.shape == "cylinder":
        return [float(obj.radius), float(obj.length), 0.0]
    if obj.shape == "sphere":
        return [float(obj.radius), 0.0, 0.0]
    return [0.0, 0.0, 0.0]


def geometry_arrays(
    model: Robot, scene: Scene, *, robot: str, task: str, strategy: str, frame: str
) -> dict[str, np.ndarray]:
    """The log's record of the robot `model` (posed for the shipped robot `robot`) and `scene`."""
    frames: list[str] = []
    centers: list[np.ndarray] = []
    radii: list[np.ndarray] = []
    bodies: list[int] = []
    for i, body in enumerate(model.collision_bodies):
        c, r, f = model.collision_spheres(body)
        frames += [f] * len(r)
        centers.append(np.asarray(c, dtype=float).reshape(-1, 3))
        radii.append(np.asarray(r, dtype=float))
        bodies += [i] * len(r)
    objects = scene.objects
    return {
        "robot": np.array(robot), "task": np.array(task), "strategy": np.array(strategy),
        "frame": np.array(frame),
        "sphere_frames": np.array(frames, dtype=str),
        "sphere_centers": np.concatenate(centers) if centers else np.zeros((0, 3)),
        "sphere_radii": np.concatenate(radii) if radii else np.zeros(0),
        "sphere_bodies": np.array(bodies, dtype=np.int64),
        "object_shapes": np.array([o.shape for o in objects], dtype=str),
        "object_kinds": np.array([o.kind for o in objects], dtype=str),
        "object_poses": np.array([o.pose for o in objects], dtype=float).reshape(-1, 4, 4),
        "object_dims": np.array([_dims(o) for o in objects], dtype=float).reshape(-1, 3),
    }  # fmt: skip


@dataclass(frozen=True)
class SceneItem:
    """One scene object as a log records it."""

    name: str
    shape: str
    kind: str
    pose: np.ndarray  # (4, 4) [m]
    dims: np.ndarray  # (3,) [m]


@dataclass(frozen=True)
class Geometry:
    """The robot and scene a log records (:func:`geometry_arrays`), read back."""

    robot: str
    task: str
    strategy: str
    frame: str
    sphere_frames: tuple[str, ...]
    sphere_centers: np.ndarray
    sphere_radii: np.ndarray
    sphere_bodies: np.ndarray
    objects: tuple[SceneItem, ...]

    @staticmethod
    def from_log(log: Mapping[str, Any]) -> Geometry:
        """The geometry in `log` (a mapping or an open .npz). A missing key is a KeyError naming it;
        arrays of the wrong shape are a ValueError saying which."""
        missing = [k for k in GEOMETRY_KEYS if k not in log]
        if missing:
            raise KeyError(", ".join(missing))
        centers = np.asarray(log["sphere_centers"], dtype=float)
        radii = np.asarray(log["sphere_radii"], dtype=float)
        frames = tuple(str(f) for f in np.asarray(log["sphere_frames"]).reshape(-1))
        bodies = np.asarray(log["sphere_bodies"]).astype(np.int64)
        s = len(frames)
        if centers.shape != (s, 3) or radii.shape != (s,) or bodies.shape != (s,):
            raise ValueError(
                f"sphere arrays disagree: {s} frames, centers {centers.shape}, radii {radii.shape}, "
                f"bodies {bodies.shape}"
            )
        names = [str(n) for n in np.asarray(log["object_names"]).reshape(-1)] if "object_names" in log else []
        shapes = [str(x) for x in np.asarray(log["object_shapes"]).reshape(-1)]
        kinds = [str(x) for x in np.asarray(log["object_kinds"]).reshape(-1)]
        poses = np.asarray(log["object_poses"], dtype=float)
        dims = np.asarray(log["object_dims"], dtype=float)
        n = len(shapes)
        if len(names) != n or len(kinds) != n or poses.shape != (n, 4, 4) or dims.shape != (n, 3):
            raise ValueError(
                f"scene arrays disagree: {len(names)} names, {n} shapes, {len(kinds)} kinds, poses "
                f"{poses.shape}, dims {dims.shape}"
            )
        for a, what in ((centers, "sphere_centers"), (radii, "sphere_radii"), (poses, "object_poses"),
                        (dims, "object_dims")):  # fmt: skip
            if not np.isfinite(a).all():
                raise ValueError(f"{what} holds NaN or infinity")
        return Geometry(
            robot=str(log["robot"]), task=str(log["task"]), strategy=str(log["strategy"]),
            frame=str(log["frame"]), sphere_frames=frames, sphere_centers=centers, sphere_radii=radii,
            sphere_bodies=bodies,
            objects=tuple(SceneItem(names[i], shapes[i], kinds[i], poses[i], dims[i]) for i in range(n)),
        )  # fmt: skip
