"""The figures of an episode, drawn with matplotlib (Agg backend, files only): the person's effort
over time (the paper's Fig. 1), the cup's path against the desired one, seen from above and as its
height over time, with the scene drawn in both (Fig. 5, right), the taught feature over time, and the
learned weights over time. The demo and the study report both draw with these, in the paper's
colours (:data:`STUDY_COLORS`); each passes its own :class:`PathStyle`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phri._phri import Scene, SceneObject

__all__ = [
    "DEMO_PATHS",
    "FEATURE_LABELS",
    "REPORT_PATHS",
    "STUDY_COLORS",
    "Circle",
    "PathStyle",
    "label_image",
    "plot_effort",
    "plot_feature",
    "plot_paths",
    "plot_weights",
    "pyplot",
]

#: The paper's colours per strategy (and the desired behaviour's): impedance grey, learning orange,
#: desired blue. The demo's figures and the study report's use them alike.
STUDY_COLORS = {"impedance": "#8c8c8c", "learning": "#f28e2b", "desired": "#1f77b4"}
#: How the scene is drawn: furniture grey, a person pink, keep-out circles red.
_SCENE_COLORS = {"furniture": "0.45", "person": "#e377c2", "keep_out": "#d62728"}
#: What each built-in feature measures at the cup (its value at one point of the path), for axis
#: labels; a keep-out feature's is how far inside its circle the cup is.
FEATURE_LABELS = {
    "efficiency": "squared joint step [rad²]",
    "table": "cup height z [m]",
    "coffee": "cup tilt |x_x| + |x_y| (0: upright)",
    "coffee_dot": "cup tilt 1 − x·ẑ (0: upright)",
    "laptop": "depth in the laptop's keep-out [m]",
    "human": "depth in the person's keep-out [m]",
    "origin": "cup distance from base [m]",
}

#: A keep-out circle in the top view: centre (x, y) and radius [m].
Circle = tuple[tuple[float, float], float]


def pyplot():  # type: ignore[no-untyped-def]
    """matplotlib.pyplot on the Agg backend (files only, no window; works without a display)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: str | Path, dpi: int) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def label_image(path: str | Path, text: str) -> Path:
    """Writes `text` into the top left corner of the image `path` (PNG), on a light band."""
    from matplotlib.figure import Figure
    from matplotlib.image import imread

    image = imread(path)
    height, width = image.shape[:2]
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    fig.figimage(image, resize=False)
    fig.text(0.015, 0.975, text, ha="left", va="top", fontsize=11, family="monospace",
             bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})  # fmt: skip
    fig.savefig(path, dpi=100)
    return Path(path)


def plot_effort(path: str | Path, task: str, efforts: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Path:
    """Fig. 1: the measured human torque |u_H|₁ [N·m] over time [s], one line per strategy;
    `efforts` maps a strategy to its (t, u_h) log arrays (u_h per joint)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.2))
    for strategy, (t, u_h) in efforts.items():
        ax.plot(t, np.abs(u_h).sum(axis=1), color=STUDY_COLORS.get(strategy), label=strategy, lw=1)
    ax.set(xlabel="time [s]", ylabel="measured |u_H|₁ [N·m]", title=f"{task}: human torque over time")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return _save(fig, path, 110)


def plot_feature(
    path: str | Path,
    task: str,
    feature: str,
    series: Mapping[str, tuple[np.ndarray, np.ndarray]],
    duration: float,
) -> Path:
    """The taught feature over time: `series` maps a strategy (and "desired") to (t [s], the
    feature's value at the cup at those times); the axis says what `feature` measures
    (:data:`FEATURE_LABELS`). The task ends at `duration` [s]."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    for name, (t, value) in series.items():
        ax.plot(t, value, color=STUDY_COLORS.get(name), label=name, lw=2 if name == "desired" else 1.2,
                ls="--" if name == "desired" else "-")  # fmt: skip
    ax.set(xlabel="time [s]", ylabel=FEATURE_LABELS.get(feature, feature), xlim=(0, duration),
           title=f"{task}: the taught feature '{feature}' over time")  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path, 110)


def plot_weights(
    path: str | Path,
    task: str,
    names: Sequence[str],
    t: np.ndarray,
    weights: np.ndarray,
    true: np.ndarray,
    duration: float,
) -> Path:
    """The learned weights over time, one panel per feature in `names`: row i of `weights` (M, k)
    holds from `t[i]` [s] on (the last up to the end of the task, `duration` [s]); the dashed line
    is the feature's entry of `true`, the weight the person wants."""
    plt = pyplot()
    k = len(names)
    fig, axes = plt.subplots(k, 1, figsize=(6.4, 1.2 + 1.6 * k), sharex=True, squeeze=False)
    steps = np.append(t, duration)
    for i, (ax, name) in enumerate(zip(axes[:, 0], names, strict=True)):
        w = weights[:, i]
        ax.step(steps, np.append(w, w[-1:]), where="post", color=STUDY_COLORS["learning"], label="learned")
        ax.axhline(true[i], color=STUDY_COLORS["desired"], ls="--", label="true")
        ax.set(ylabel=f"w[{name}]", xlim=(0, duration))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(f"{task}: learned weights over time")
    fig.tight_layout()
    return _save(fig, path, 110)


@dataclass(frozen=True)
class PathStyle:
    """How :func:`plot_paths` draws: the demo's compact figure or the report's larger one."""

    #: Colour per strategy and for "desired".
    colors: Mapping[str, str]
    #: Figure size [in] and resolution [dots per inch].
    figsize: tuple[float, float]
    dpi: int
    #: Titles of the top view and of the height panel, and the height axis label.
    titles: tuple[str, str]
    height_label: str
    #: matplotlib line options of the desired path, and the executed paths' line width (None: the
    #: default).
    desired: Mapping[str, Any] = field(default_factory=dict)
    width: float | None = None
    legend_size: float = 8


#: The demo's path figure.
DEMO_PATHS = PathStyle(
    STUDY_COLORS, (11, 4.4), 110, ("cup path, top view", "cup height"), "cup height z [m]",
    desired={"ls": "--", "lw": 2},
)  # fmt: skip
#: The study report's path figure (Fig. 5, right).
REPORT_PATHS = PathStyle(
    STUDY_COLORS, (11, 4.6), 120, ("cup (link_7) path seen from above", "cup height over time"),
    "height z [m]", desired={"lw": 2.5}, width=1.8, legend_size=9,
)  # fmt: skip


def plot_paths(
    path: str | Path,
    desired: tuple[np.ndarray, np.ndarray],
    executed: Mapping[str, tuple[np.ndarray, np.ndarray]],
    style: PathStyle = REPORT_PATHS,
    *,
    scene: Scene | None = None,
    task: str = "",
    title: str = "",
    keep_out: Circle | None = None,
    keep_outs: Mapping[str, Circle] | None = None,
) -> Path:
    """Fig. 5 (right): the cup's path for each strategy against the desired path, seen from above
    (x, y) and its height over time. `desired` and each of `executed` (by strategy) are
    (t [s], positions (N, 3) [m]). Both panels show the scene: every object of `scene` (its outline
    from above, its top in the height panel), the keep-out circles `keep_outs` (by feature name;
    `keep_out` is the task's one circle, named after `task`) and the start and goal."""
    import matplotlib.patches as patches

    plt = pyplot()
    fig, (top, side) = plt.subplots(1, 2, figsize=style.figsize, layout="constrained")
    circles = dict(keep_outs or {})
    if keep_out is not None:
        circles.setdefault(task or "keep-out", keep_out)
    _draw_scene_top(top, scene, circles, patches)
    t, d = desired
    _draw_scene_height(side, scene, (t[0], t[-1]), (d[0, 2], d[-1, 2]))
    top.plot(d[:, 0], d[:, 1], color=style.colors["desired"], label="desired", **style.desired)
    side.plot(t, d[:, 2], color=style.colors["desired"], label="desired", **style.desired)
    for strategy, (te, e) in executed.items():
        top.plot(e[:, 0], e[:, 1], color=style.colors.get(strategy), lw=style.width, label=strategy)
        side.plot(te, e[:, 2], color=style.colors.get(strategy), lw=style.width, label=strategy)
    for point, marker, name in ((d[0, :2], "o", "start"), (d[-1, :2], "s", "goal")):
        top.plot(*point, marker, color="k", ms=6, zorder=5)
        top.annotate(name, point, textcoords="offset points", xytext=(6, 4), fontsize=9)
    top.set(xlabel="x [m]", ylabel="y [m]", title=style.titles[0])
    top.set_aspect("equal", adjustable="datalim")
    side.set(xlabel="time [s]", ylabel=style.height_label, title=style.titles[1])
    for ax in (top, side):
        ax.grid(alpha=0.3)
    top.legend(fontsize=style.legend_size, loc="best")
    side.legend(fontsize=style.legend_size, loc="best")
    if title:
        fig.suptitle(title, fontsize=12)
    return _save(fig, path, style.dpi)


def _outline(obj: SceneObject) -> np.ndarray | None:
    """The object's outline seen from above: the convex hull (M, 2) of its extreme points in the
    base frame's xy plane [m]; None for a plane (it has no outline)."""
    if obj.shape == "box" and obj.size is not None:
        half = np.asarray(obj.size) / 2
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    elif obj.shape in ("cylinder", "sphere") and obj.radius is not None:
        a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
        ring = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)]) * obj.radius
        ends = (0.0,) if obj.shape == "sphere" else (-(obj.length or 0.0) / 2, (obj.length or 0.0) / 2)
        local = np.vstack([ring + [0.0, 0.0, z] for z in ends])
    else:
        return None
    pose = np.asarray(obj.pose)
    return _hull((local @ pose[:3, :3].T + pose[:3, 3])[:, :2])


def _hull(points: np.ndarray) -> np.ndarray:
    """The convex hull of 2-D `points`, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted(map(tuple, np.round(points, 12)))

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while (
                len(out) >= 2
                and (
                    (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                    - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
                )
                <= 0
            ):
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _draw_scene_top(top: Any, scene: Scene | None, circles: Mapping[str, Circle], patches: Any) -> None:
    """The scene from above: each object's outline, named, and the keep-out circles."""
    for obj in scene.objects if scene is not None else ():
        outline = _outline(obj)
        if outline is None:
            continue
        color = _SCENE_COLORS["person" if obj.kind == "person" else "furniture"]
        top.add_patch(patches.Polygon(outline, closed=True, facecolor=color, alpha=0.18, edgecolor=color))
        # The name inside the outline's far edge, clear of the paths that cross its middle.
        top.annotate(obj.name, (outline[:, 0].mean(), outline[:, 1].max()), textcoords="offset points",
                     xytext=(0, -3), ha="center", va="top", fontsize=8, color="0.25")  # fmt: skip
    top.plot(0.0, 0.0, "P", color="0.15", ms=7, zorder=5)
    top.annotate("robot base", (0.0, 0.0), textcoords="offset points", xytext=(6, -10), fontsize=8)
    for name, ((cx, cy), radius) in circles.items():
        top.add_patch(patches.Circle((cx, cy), radius, fill=False, ls="--", lw=1.2,
                                     color=_SCENE_COLORS["keep_out"]))  # fmt: skip
        top.annotate(f"{name} keep-out ({radius:g} m)", (cx, cy - radius), ha="center", va="top",
                     fontsize=8, color=_SCENE_COLORS["keep_out"])  # fmt: skip
        top.update_datalim([(cx - radius, cy - radius), (cx + radius, cy + radius)])


def _draw_scene_height(
    side: Any, scene: Scene | None, times: tuple[float, float], z: tuple[float, float]
) -> None:
    """The scene in the height panel: the top of each piece of furniture (a person is taller than the
    plot) and the start's and goal's heights."""
    tops = sorted(
        (o.top, o.name)
        for o in (scene.objects if scene is not None else ())
        if o.kind != "person" and o.top is not None
    )
    for i, (height, name) in enumerate(tops):
        side.axhline(height, color=_SCENE_COLORS["furniture"], lw=1.2)
        # Names alternate between the left and the right end, so that close tops stay readable.
        x, ha = (0.01, "left") if i % 2 == 0 else (0.99, "right")
        side.annotate(f"{name} top", (x, height), xycoords=("axes fraction", "data"), ha=ha,
                      textcoords="offset points", xytext=(0, 3), fontsize=8, color="0.3")  # fmt: skip
    side.plot(times[0], z[0], "o", color="k", ms=6, zorder=5)
    side.plot(times[1], z[1], "s", color="k", ms=6, zorder=5)
    side.annotate("start", (times[0], z[0]), textcoords="offset points", xytext=(6, 4), fontsize=9)
    side.annotate("goal", (times[1], z[1]), textcoords="offset points", xytext=(-24, 6), fontsize=9)
