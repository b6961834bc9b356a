"""The figures of an episode, drawn with matplotlib (Agg backend, PNG): the person's effort over time
(the paper's Fig. 1), the cup's path against the desired one, seen from above and as its height over
time (Fig. 5, right), and the learned weight over time. The demo and the study report both draw
with these; each passes its own :class:`PathStyle` and colours.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phri._phri import Scene
from phri.config import TABLE

__all__ = [
    "DEMO_COLORS",
    "DEMO_PATHS",
    "REPORT_PATHS",
    "STUDY_COLORS",
    "PathStyle",
    "plot_effort",
    "plot_paths",
    "plot_weight",
    "pyplot",
]

#: The demo's colours per strategy (and the desired path's).
DEMO_COLORS = {"impedance": "tab:red", "learning": "tab:blue", "desired": "k"}
#: The paper's colours, used by the study report: impedance grey, learning orange, desired blue.
STUDY_COLORS = {"impedance": "#8c8c8c", "learning": "#f28e2b", "desired": "#1f77b4"}


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


def plot_effort(path: str | Path, task: str, efforts: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Path:
    """Fig. 1: the measured human torque |u_H|₁ [N·m] over time [s], one line per strategy;
    `efforts` maps a strategy to its (t, u_h) log arrays (u_h per joint)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.2))
    for strategy, (t, u_h) in efforts.items():
        ax.plot(t, np.abs(u_h).sum(axis=1), color=DEMO_COLORS[strategy], label=strategy, lw=1)
    ax.set(xlabel="time [s]", ylabel="measured |u_H|₁ [N·m]", title=f"{task}: human torque over time")
    ax.legend()
    fig.tight_layout()
    return _save(fig, path, 110)


def plot_weight(
    path: str | Path, task: str, t: np.ndarray, weight: np.ndarray, true_weight: float, duration: float
) -> Path:
    """The learned weight of the task's feature over time: `weight[i]` holds from `t[i]` [s] on (the
    last up to the end of the task, `duration` [s]), against the true weight."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    ax.step(np.append(t, duration), np.append(weight, weight[-1:]), where="post",
            color=DEMO_COLORS["learning"], label="learned")  # fmt: skip
    ax.axhline(true_weight, color="k", ls="--", label="true")
    ax.set(xlabel="time [s]", ylabel=f"weight of '{task}'", title=f"{task}: weight over time")
    ax.legend()
    fig.tight_layout()
    return _save(fig, path, 110)


@dataclass(frozen=True)
class PathStyle:
    """How :func:`plot_paths` draws: the demo's compact figure or the report's detailed one."""

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
    #: Start and goal marked, a grid and a legend in both panels, the top view's limits fitted to
    #: the data (else a legend in the height panel only).
    detailed: bool = False


DEMO_PATHS = PathStyle(
    DEMO_COLORS, (9, 3.6), 110, ("cup path, top view", "cup height"), "cup height z [m]",
    desired={"ls": "--"},
)  # fmt: skip
REPORT_PATHS = PathStyle(
    STUDY_COLORS, (11, 4.6), 120, ("cup (link_7) path seen from above", "cup height over time"),
    "height z [m]", desired={"lw": 2.5}, width=1.8, legend_size=9, detailed=True,
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
    keep_out: tuple[tuple[float, float], float] | None = None,
) -> Path:
    """Fig. 5 (right): the cup's (link_7) path for each strategy against the desired path, seen from
    above (x, y) and its height over time. `desired` and each of `executed` (by strategy) are
    (t [s], positions (N, 3) [m]); the task's `keep_out` circle (centre, radius [m]) and, with
    `scene`, the laptop (task "laptop") and the table top are drawn."""
    plt = pyplot()
    layout = "constrained" if style.detailed else None
    fig, (top, side) = plt.subplots(1, 2, figsize=style.figsize, layout=layout)
    t, d = desired
    top.plot(d[:, 0], d[:, 1], color=style.colors["desired"], label="desired", **style.desired)
    side.plot(t, d[:, 2], color=style.colors["desired"], label="desired", **style.desired)
    if style.detailed:
        for point, marker, name in ((d[0, :2], "ko", "start"), (d[-1, :2], "ks", "goal")):
            top.plot(*point, marker, ms=5)
            top.annotate(name, point, textcoords="offset points", xytext=(5, 5), fontsize=9)
    for strategy, (t, e) in executed.items():
        top.plot(e[:, 0], e[:, 1], color=style.colors.get(strategy), lw=style.width, label=strategy)
        side.plot(t, e[:, 2], color=style.colors.get(strategy), lw=style.width, label=strategy)
    _draw_scene(top, side, task, scene, keep_out)
    top.set(xlabel="x [m]", ylabel="y [m]", title=style.titles[0])
    top.set_aspect("equal", adjustable="datalim" if style.detailed else "box")
    side.set(xlabel="time [s]", ylabel=style.height_label, title=style.titles[1])
    for ax in (top, side) if style.detailed else (side,):
        if style.detailed:
            ax.grid(alpha=0.3)
        ax.legend(fontsize=style.legend_size)
    if title:
        fig.suptitle(title, fontsize=12)
    if not style.detailed:
        fig.tight_layout()
    return _save(fig, path, style.dpi)


def _draw_scene(
    top: Any, side: Any, task: str, scene: Scene | None, keep_out: tuple[tuple[float, float], float] | None
) -> None:
    """The scene in the path figure: the task's keep-out circle, the laptop (task "laptop") and the
    table top in the height panel. The only reader of scene values here."""
    import matplotlib.patches as patches

    if keep_out is not None:
        (cx, cy), radius = keep_out
        top.add_patch(patches.Circle((cx, cy), radius, fill=False, ls="--", color="red", lw=1))
        top.annotate(f"{task} keep-out ({radius} m)", (cx, cy - radius), ha="center",
                     va="top", fontsize=9, color="red")  # fmt: skip
    if scene is None:
        return
    laptop, table = scene.get("laptop"), scene.get(TABLE)
    if task == "laptop" and laptop is not None and laptop.size is not None:
        (lx, ly, _), (sx, sy, _) = laptop.position, laptop.size
        top.add_patch(patches.Rectangle((lx - sx / 2, ly - sy / 2), sx, sy, color="0.2", alpha=0.6))
    if table is not None:
        side.axhline(table.top, color="saddlebrown", lw=1.5)
        side.annotate("table top", (0, table.top), textcoords="offset points", xytext=(3, 3), fontsize=9,
                      color="saddlebrown")  # fmt: skip
