"""An episode log turned into what the replay page draws: the robot's collision spheres and the cup
at each frame, the scene's objects, the plans as paths of the feature frame, the push, and the time
series of the plots. Everything is computed here with phri's own kinematics, so the page only
places things; positions are in the robot's base frame [m], z up.
"""

from __future__ import annotations

import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from phri._phri import Robot
from phri.episode_log import Geometry, nearest_rows
from phri.exceptions import LogError, PhriError

__all__ = ["FRAME_RATE", "PLOT_RATE", "read_log", "replay_data"]

#: Frames of the 3D replay per second of the episode [Hz].
FRAME_RATE = 25.0
#: Samples per second of the plots [Hz].
PLOT_RATE = 50.0
#: The series every episode log has, with their shapes (T rows, n joints).
_SERIES = ("t", "q", "tau", "u_h", "push", "wall_force")
_REQUIRED = (
    *_SERIES, "weights_t", "weights", "plan_t", "plans", "desired", "feature_names", "distances",
    "body_names", "object_names", "interaction_t",
)  # fmt: skip


def read_log(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of the episode log `path` (.npz). A file that is missing, not a .npz, damaged or
    not an episode log phri wrote is a :class:`~phri.exceptions.LogError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such log file")
    if not zipfile.is_zipfile(path):  # np.load would read any other file as a pickle
        raise LogError(f"{path}: not an episode log (a .npz file): it is not a zip archive")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as e:
        raise LogError(f"{path}: not a readable .npz episode log ({type(e).__name__}: {e})") from None
    missing = [k for k in _REQUIRED if k not in arrays]
    if missing:
        raise LogError(
            f"{path}: not a phri episode log (it has no {', '.join(repr(k) for k in missing[:5])}"
            f"{' ...' if len(missing) > 5 else ''})"
        )
    try:
        Geometry.from_log(arrays)
    except KeyError as e:
        raise LogError(
            f"{path}: the log does not record its robot and scene (no {e.args[0]}): an earlier phri "
            "wrote it; run the episode again to replay it"
        ) from None
    except ValueError as e:
        raise LogError(f"{path}: damaged scene record: {e}") from None
    t, q = arrays["t"], arrays["q"]
    if t.ndim != 1 or len(t) < 1 or q.ndim != 2 or len(q) != len(t):
        raise LogError(f"{path}: 't' {t.shape} and 'q' {q.shape} must have one row per tick")
    for k in _SERIES[2:]:
        if len(arrays[k]) != len(t):
            raise LogError(f"{path}: '{k}' has {len(arrays[k])} rows, 't' has {len(t)}")
    for k in ("t", "q"):
        if not np.isfinite(arrays[k]).all():
            raise LogError(f"{path}: '{k}' holds NaN or infinity")
    if np.any(np.diff(t) < 0):
        raise LogError(f"{path}: 't' is not in time order")
    return arrays


def _rows(t: np.ndarray, rate: float) -> np.ndarray:
    """Rows of the log times `t` nearest a grid of `rate` [Hz] from its first to its last time."""
    return np.unique(nearest_rows(t, np.arange(t[0], t[-1] + 0.5 / rate, 1.0 / rate)))


def _round(a: Any, digits: int = 4) -> Any:
    """`a` as nested lists, rounded (the page's JSON stays small); NaN and infinity become None."""
    a = np.round(np.asarray(a, dtype=float), digits)
    if np.isfinite(a).all():
        return a.tolist()
    out: list[Any] = np.where(np.isfinite(a), a, None).tolist()  # type: ignore[attr-defined]
    return out


def _positions(robot: Robot, frame: str, q: np.ndarray) -> np.ndarray:
    """Poses (M, 4, 4) of `frame` at the rows of `q` (M, n)."""
    if len(q) == 0:
        return np.zeros((0, 4, 4))
    return np.asarray(robot.frame_pose(frame, q)).reshape(len(q), 4, 4)


def replay_data(log: Mapping[str, np.ndarray], *, title: str = "") -> dict[str, Any]:
    """What the replay page of the episode log `log` (the arrays :func:`read_log` returns) draws, as
    JSON-ready values. A robot or frame the installed phri does not know is a LogError."""
    g = Geometry.from_log(log)
    try:
        robot = Robot.from_description(g.robot)
    except PhriError as e:
        raise LogError(f"the log's robot '{g.robot}' is not one this phri ships ({e})") from None
    unknown = sorted({f for f in (*g.sphere_frames, g.frame) if f not in robot.frame_names})
    if unknown:
        raise LogError(f"the log names frames its robot '{g.robot}' does not have: {', '.join(unknown)}")
    t, q = np.asarray(log["t"], float), np.asarray(log["q"], float)
    if q.shape[1] != robot.nq:
        raise LogError(f"the log's 'q' has {q.shape[1]} joints, robot '{g.robot}' has {robot.nq}")
    rows = _rows(t, FRAME_RATE)
    qf = q[rows]
    # Collision spheres: their centres at each frame, frame by frame of the robot.
    centers = np.zeros((len(rows), len(g.sphere_frames), 3))
    for f in sorted(set(g.sphere_frames)):
        pose = _positions(robot, f, qf)
        idx = [i for i, name in enumerate(g.sphere_frames) if name == f]
        local = g.sphere_centers[idx]  # (k, 3)
        centers[:, idx] = np.einsum("mij,kj->mki", pose[:, :3, :3], local) + pose[:, None, :3, 3]
    hand = _positions(robot, g.frame, qf)[:, :3, 3]
    bodies = [str(b) for b in np.asarray(log["body_names"]).reshape(-1)]
    cup = [i for i, b in enumerate(bodies) if b == "cup"]
    push = np.asarray(log["push"], float)[rows, :3]
    plans = np.asarray(log["plans"], float)
    plan_paths = [_positions(robot, g.frame, p)[:, :3, 3] for p in plans.reshape(len(plans), -1, robot.nq)]
    desired = _positions(robot, g.frame, np.asarray(log["desired"], float).reshape(-1, robot.nq))[:, :3, 3]
    prow = _rows(t, PLOT_RATE)
    feature_names = [str(f) for f in np.asarray(log["feature_names"]).reshape(-1)]
    object_names = [str(n) for n in np.asarray(log["object_names"]).reshape(-1)]
    plots: list[dict[str, Any]] = [
        {"title": "joint torque τ [N·m]", "t": _round(t[prow], 3),
         "series": [{"name": f"joint {j + 1}", "y": _round(np.asarray(log["tau"])[prow, j], 3)}
                    for j in range(robot.nq)]},
        {"title": "person's force at the cup [N]", "t": _round(t[prow], 3),
         "series": [{"name": "|F|",
                     "y": _round(np.linalg.norm(np.asarray(log["push"])[prow, :3], axis=1), 3)}]},
    ]  # fmt: skip
    weights_t, weights = np.asarray(log["weights_t"], float), np.asarray(log["weights"], float)
    if len(weights_t):
        wt = np.append(weights_t, t[-1])  # held from the last update to the end
        plots.append({
            "title": "weights θ", "t": _round(wt, 3), "step": True,
            "series": [{"name": name, "y": _round(np.append(weights[:, k], weights[-1, k]), 4)}
                       for k, name in enumerate(feature_names)],
        })  # fmt: skip
    if "segment_phi" in log and "desired_segment_phi" in log:
        seg, want = np.asarray(log["segment_phi"], float), np.asarray(log["desired_segment_phi"], float)
        if seg.ndim == 2 and seg.shape == want.shape and seg.shape[1] == len(feature_names) and len(seg):
            ts = np.linspace(t[0], t[-1], len(seg) + 1)
            mid = (ts[:-1] + ts[1:]) / 2
            for k, name in enumerate(feature_names):
                plots.append({
                    "title": f"feature {name} per segment", "t": _round(mid, 3),
                    "series": [{"name": "executed", "y": _round(seg[:, k], 5)},
                               {"name": "desired", "y": _round(want[:, k], 5), "dashed": True}],
                })  # fmt: skip
    distances = np.asarray(log["distances"], float)
    if distances.ndim == 3 and distances.shape[0] == len(t) and distances.shape[2] == len(object_names):
        clearance = distances.min(axis=1)[prow]
        plots.append({
            "title": "clearance to the scene [m]", "t": _round(t[prow], 3),
            "series": [{"name": n, "y": _round(clearance[:, i], 4)} for i, n in enumerate(object_names)],
        })  # fmt: skip
    wall = np.asarray(log["wall_force"], float)
    plots.append({
        "title": "safety wall's force [N]", "t": _round(t[prow], 3),
        "series": [{"name": "wall", "y": _round(wall[prow], 3)}],
    })  # fmt: skip
    stop = None
    if "stop_t" in log and len(log["stop_t"]):
        stop = {"t": float(np.asarray(log["stop_t"]).reshape(-1)[0]),
                "reason": _first_str(log["stop_reason"]),
                "message": _first_str(log["stop_message"])}  # fmt: skip
    return {
        "title": title or f"{g.task} · {g.strategy}",
        "robot": g.robot, "task": g.task, "strategy": g.strategy, "frame": g.frame,
        "duration": float(t[-1] - t[0]), "t0": float(t[0]),
        "frames": {"t": _round(t[rows], 3), "spheres": _round(centers, 3), "hand": _round(hand, 4),
                   "push": _round(push, 2), "wall": _round(wall[rows], 2)},
        "spheres": {"radius": _round(g.sphere_radii, 4),
                    "cup": [bool(b in cup) for b in g.sphere_bodies.tolist()]},
        "objects": [{"name": o.name, "shape": o.shape, "kind": o.kind, "pose": _round(o.pose, 5),
                     "dims": _round(o.dims, 5)} for o in g.objects],
        "desired": _round(desired, 4),
        "plans": {"t": _round(np.asarray(log["plan_t"], float), 3),
                  "paths": [_round(p, 4) for p in plan_paths]},
        "interactions": _round(np.asarray(log["interaction_t"], float), 3),
        "plots": plots,
        "stop": stop,
    }  # fmt: skip


def _first_str(values: Any) -> str:
    """The first of a logged string array, or "" when it is empty."""
    flat = np.asarray(values).reshape(-1)
    return str(flat[0]) if len(flat) else ""
