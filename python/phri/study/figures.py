"""The study's figures as PNG and PDF (matplotlib, Agg backend): the paper's Fig. 4 and Fig. 5. The
path figure is :func:`phri.plots.plot_paths`, fed from the episode logs.

Each function takes the PNG's path and writes the PDF beside it (same name, ``.pdf``); it returns the
PNG's path.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phri._extras import require
from phri._phri import Scene
from phri.atomic import write_atomic
from phri.exceptions import InvalidParameterError
from phri.plots import REPORT_PATHS, STUDY_COLORS, pyplot
from phri.plots import plot_paths as plot_path_figure

if TYPE_CHECKING:
    import pandas as pd
else:
    pd = require("pandas", __name__)

__all__ = ["COLORS", "FORMATS", "log_rate", "plot_cost", "plot_effort_time", "plot_paths", "read_paths"]

#: The paper's colours: impedance grey, learning orange, desired blue.
COLORS = STUDY_COLORS
#: p below this gets an asterisk (the paper's convention: p < 0.0001).
STAR = 1e-4
#: The formats every figure is written in: PNG for the report, PDF (vector) for a paper.
FORMATS = ("png", "pdf")
#: Resolution of the PNGs [dots per inch].
DPI = 120


def _paths(path: str | Path) -> list[Path]:
    """The files of the figure whose PNG is `path`, one per format."""
    return [Path(path).with_suffix(f".{fmt}") for fmt in FORMATS]


def _save(fig: Any, path: str | Path) -> Path:
    """Writes `fig` in every format (each file atomically) and closes it; returns the PNG's path."""
    for target in _paths(path):
        buffer = io.BytesIO()
        fig.savefig(buffer, format=target.suffix[1:], dpi=DPI)
        write_atomic(target, buffer.getvalue())
    pyplot().close(fig)
    return Path(path).with_suffix(".png")


def _task_label(task: str, familiarization: str | None, tasks: Sequence[str]) -> str:
    if task == familiarization:
        return f"{task}\n(familiarization)"
    experimental = [t for t in tasks if t != familiarization]
    return f"{task}\n(task {experimental.index(task) + 1})"


def _star_p(tests: pd.DataFrame | None, task: str, measure: str) -> float:
    if tests is None or not len(tests):
        return float("nan")
    hit = tests[(tests["task"] == task) & (tests["measure"] == measure) & (tests["effect"] == "strategy")]
    if not len(hit) or ("estimable" in hit and not bool(hit["estimable"].iloc[0])):
        return float("nan")  # a test that is not estimable never gets an asterisk
    return float(hit["p"].iloc[0])


def _bars(
    ax, desc: pd.DataFrame, measure: str, tasks: list[str], strategies: list[str], tests, labels
) -> None:  # type: ignore[no-untyped-def]
    width = 0.8 / len(strategies)
    x = np.arange(len(tasks))
    top = 0.0
    for i, s in enumerate(strategies):
        sub = desc[desc["strategy"] == s].set_index("task").reindex(tasks)
        mean, sd = sub[f"{measure}_mean"].to_numpy(float), np.nan_to_num(sub[f"{measure}_sd"].to_numpy(float))
        ax.bar(x + (i - (len(strategies) - 1) / 2) * width, mean, width, yerr=sd, capsize=3,
               color=COLORS.get(s), label=s, edgecolor="black", linewidth=0.5)  # fmt: skip
        top = max(top, float(np.nanmax(mean + sd)) if np.isfinite(mean).any() else 0.0)
    for j, task in enumerate(tasks):
        if _star_p(tests, task, measure) < STAR:
            ax.text(x[j], top * 1.04, "*", ha="center", va="bottom", fontsize=16, fontweight="bold")
    ax.set_xticks(x, labels)
    ax.set_ylim(0, top * 1.15 if top > 0 else 1.0)
    ax.grid(axis="y", alpha=0.3)


def plot_effort_time(
    desc: pd.DataFrame,
    path: str | Path,
    *,
    tests: pd.DataFrame | None = None,
    familiarization: str | None = None,
) -> Path:
    """Fig. 4: mean (± SD) effort and interaction time per task and strategy."""
    plt = pyplot()
    tasks = list(dict.fromkeys(desc["task"]))
    strategies = list(dict.fromkeys(desc["strategy"]))
    labels = [_task_label(t, familiarization, tasks) for t in tasks]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
    for ax, measure, title in (
        (axes[0], "effort", "Effort: Σ‖u_H‖₁ over interaction samples [N·m]"),
        (axes[1], "interaction_time", "Interaction time [s]"),
    ):
        _bars(ax, desc, measure, tasks, strategies, tests, labels)
        ax.set_title(title, fontsize=11)
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncols=len(names), title="strategy")
    fig.suptitle("Effort and interaction time by task and strategy (mean ± SD; * p < 0.0001)", fontsize=12)
    return _save(fig, path)


def plot_cost(
    desc: pd.DataFrame,
    path: str | Path,
    *,
    tests: pd.DataFrame | None = None,
    familiarization: str | None = None,
) -> Path:
    """Fig. 5 (left): mean (± SD) task cost per strategy against the desired behaviour's cost, one
    panel per task (the tasks' features have different units)."""
    plt = pyplot()
    tasks = list(dict.fromkeys(desc["task"]))
    strategies = list(dict.fromkeys(desc["strategy"]))
    fig, axes = plt.subplots(
        1, len(tasks), figsize=(3.0 * len(tasks) + 1, 4.0), layout="constrained", squeeze=False
    )
    for ax, task in zip(axes[0], tasks, strict=True):
        sub = desc[desc["task"] == task].set_index("strategy").reindex(strategies)
        mean, sd = sub["cost_mean"].to_numpy(float), np.nan_to_num(sub["cost_sd"].to_numpy(float))
        desired = float(sub["desired_cost_mean"].mean())
        x = np.arange(len(strategies) + 1)
        ax.bar(x[:-1], mean, 0.7, yerr=sd, capsize=3, color=[COLORS.get(s) for s in strategies],
               edgecolor="black", linewidth=0.5)  # fmt: skip
        ax.bar(x[-1], desired, 0.7, color=COLORS["desired"], edgecolor="black", linewidth=0.5)
        ax.set_xticks(x, [*strategies, "desired"])
        top = float(np.nanmax(np.append(mean + sd, desired)))
        if _star_p(tests, task, "cost_error") < STAR:
            ax.text(0.5, top * 1.04, "*", ha="center", va="bottom", fontsize=16, fontweight="bold")
        ax.set_ylim(0, top * 1.15 if top > 0 else 1.0)
        ax.set_title(_task_label(task, familiarization, tasks).replace("\n", " "), fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("task-feature cost of the executed path")
    fig.suptitle(
        "Task cost against the desired behaviour's cost (mean ± SD; * p < 0.0001 on |cost − desired|)",
        fontsize=11,
    )
    return _save(fig, path)


def read_log(log: str | Path, *keys: str) -> list[np.ndarray]:
    """The arrays `keys` of the episode log `log` (.npz). The file is opened here, so a damaged one
    (which np.load would leave open) is closed whatever it raises."""
    with open(log, "rb") as f, np.load(f) as data:
        return [np.asarray(data[k]) for k in keys]


def log_rate(log: str | Path) -> float:
    """The rate at which an episode log holds its samples [Hz], from its times `t` (NaN with fewer
    than two samples)."""
    (t,) = read_log(log, "t")
    t = t.astype(float)
    return float(1.0 / np.median(np.diff(t))) if t.size > 1 else float("nan")


def read_paths(log: str | Path, frame: str | None = None, robot: str = "jaco2") -> dict[str, np.ndarray]:
    """From an episode log of `robot` (a shipped robot's name or a description file, the task's
    ``robot``): time `t` [s], the executed path of `frame` (the task's feature frame; None: the
    robot's) at the log rate, and the desired plan's path sampled at the same times (cubic
    interpolation of its waypoints), each (N, 3) [m]."""
    from phri._phri import Robot, TimedTrajectory

    t, q, desired = read_log(log, "t", "q", "desired")
    model = Robot.from_description(robot)
    cup = frame or model.feature_frame
    if cup is None:
        raise InvalidParameterError("frame: the robot's description names no feature frame; pass one")
    duration = float(t[-1]) if len(t) > 1 else 1.0
    plan = TimedTrajectory(desired, duration)
    q_desired = plan.sample_many(t)[0]
    return {
        "t": t,
        "executed": model.frame_pose(cup, q)[:, :3, 3],
        "desired": model.frame_pose(cup, q_desired)[:, :3, 3],
    }


def plot_paths(
    logs: Mapping[str, str | Path],
    path: str | Path,
    *,
    scene: Scene | None = None,
    task: str = "",
    title: str = "",
    keep_out: tuple[tuple[float, float], float] | None = None,
    frame: str | None = None,
    robot: str = "jaco2",
) -> Path:
    """Fig. 5 (right): the path of the cup (the task's feature frame `frame`, see
    :func:`read_paths`) for each strategy against the desired path, seen from above (x, y) and its
    height over time. `logs` maps a strategy to its episode log; the desired path is that of the first
    log; `scene`'s laptop and table top and the task's `keep_out` circle (centre, radius [m]) are
    drawn if given. `robot`: the robot the logs are of (the task's ``robot``)."""
    paths = {strategy: read_paths(log, frame, robot) for strategy, log in logs.items()}
    first = next(iter(paths.values()))
    for target in _paths(path):  # phri.plots writes one file a call, its format from the suffix
        plot_path_figure(
            target, (first["t"], first["desired"]), {s: (p["t"], p["executed"]) for s, p in paths.items()},
            REPORT_PATHS, scene=scene, task=task, keep_out=keep_out, title=title,
        )  # fmt: skip
    return Path(path).with_suffix(".png")
