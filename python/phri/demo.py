"""The main job: the study's four tasks, both strategies, one simulated participant.

Prints a table and writes into one output folder: force over time for both strategies (the paper's
Fig. 1), the hand's path against the desired path (Fig. 5, right), the learned weight over time,
rendered PNG frames of the scene, each episode's compressed log, and ``summary.csv``.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from phri.config import STUDY_TASKS, load_task
from phri.exceptions import InvalidParameterError
from phri.sim import STRATEGIES, EpisodeConfig, EpisodeResult, ParticipantParams, Planner, World, WorldParams

__all__ = ["fresh_folder", "frame_times", "run_demo"]

#: Frames rendered per episode, evenly spaced from the start to the end of the task.
FRAMES = 4


def frame_times(duration: float) -> tuple[float, ...]:
    """The times [s] of an episode's frames for a task lasting `duration` [s]."""
    return tuple(float(t) for t in np.linspace(0.0, duration, FRAMES))


def check_out(path: Path) -> None:
    """Raises InvalidParameterError naming --out unless `path` can be (or hold) the output folder."""
    for p in (path, *path.parents):
        if p.exists() and not p.is_dir():
            what = "is a file" if p == path else f"is inside {p}, a file"
            raise InvalidParameterError(f"--out {path} {what}; give a folder (a new one or an existing one)")


def fresh_folder(path: Path) -> Path:
    """`path` if it is new or empty, else the first free `path-2`, `path-3`, ...: never overwrite
    (a file of such a name is skipped too)."""
    candidate, k = path, 1
    while candidate.exists() and (not candidate.is_dir() or any(candidate.iterdir())):
        k += 1
        candidate = path.with_name(f"{path.name}-{k}")
    candidate.mkdir(parents=True, exist_ok=True)
    return candidate


@dataclass
class DemoResult:
    folder: Path
    results: list[EpisodeResult]
    seconds: float


def _plot(
    folder: Path, task: str, results: dict[str, EpisodeResult], true_weight: float, duration: float
) -> list[Path]:
    """The task's figures; `duration` [s] is the task's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"impedance": "tab:red", "learning": "tab:blue"}
    written = []
    # Fig. 1: the person's effort over time.
    fig, ax = plt.subplots(figsize=(6.4, 3.2))
    for strategy, r in results.items():
        with np.load(r.log) as log:
            ax.plot(log["t"], np.abs(log["u_h"]).sum(axis=1), color=colors[strategy], label=strategy, lw=1)
    ax.set(xlabel="time [s]", ylabel="measured |u_H|₁ [N·m]", title=f"{task}: human torque over time")
    ax.legend()
    fig.tight_layout()
    written.append(folder / f"force_{task}.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)
    # Fig. 5 right: the hand's path against the desired one.
    fig, (top, side) = plt.subplots(1, 2, figsize=(9, 3.6))
    desired = next(iter(results.values())).desired_path
    t = np.linspace(0, duration, len(desired))
    top.plot(desired[:, 0], desired[:, 1], "k--", label="desired")
    side.plot(t, desired[:, 2], "k--", label="desired")
    for strategy, r in results.items():
        top.plot(r.executed_path[:, 0], r.executed_path[:, 1], color=colors[strategy], label=strategy)
        side.plot(t, r.executed_path[:, 2], color=colors[strategy], label=strategy)
    top.set(xlabel="x [m]", ylabel="y [m]", title="cup path, top view", aspect="equal")
    side.set(xlabel="time [s]", ylabel="cup height z [m]", title="cup height")
    side.legend(fontsize=8)
    fig.suptitle(task)
    fig.tight_layout()
    written.append(folder / f"path_{task}.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)
    # The learned weight over time.
    r = results["learning"]
    with np.load(r.log) as log:
        wt = np.append(log["weights_t"], duration)
        w = np.vstack([log["weights"], log["weights"][-1:]])[:, -1]
    fig, ax = plt.subplots(figsize=(6.4, 3.0))
    ax.step(wt, w, where="post", color=colors["learning"], label="learned")
    ax.axhline(true_weight, color="k", ls="--", label="true")
    ax.set(xlabel="time [s]", ylabel=f"weight of '{task}'", title=f"{task}: weight over time")
    ax.legend()
    fig.tight_layout()
    written.append(folder / f"weights_{task}.png")
    fig.savefig(written[-1], dpi=110)
    plt.close(fig)
    return written


def run_demo(
    out: Path = Path("out/demo"), seed: int = 7, gui: bool = False, frames: bool = True
) -> DemoResult:
    """Runs the demo into a fresh folder next to (or at) `out` and returns what it did.

    Each episode's row is appended to ``summary.csv`` as soon as it finishes, so an interrupted demo
    keeps what it did."""
    began = time.perf_counter()
    check_out(Path(out))
    folder = fresh_folder(Path(out))
    (folder / "logs").mkdir()
    (folder / "frames").mkdir()
    participant = ParticipantParams.draw(np.random.default_rng(seed))
    results: list[EpisodeResult] = []
    header = (
        f"{'task':<8} {'strategy':<10} {'effort':>9} {'time':>6} {'cost':>8} {'desired':>8} {'weight':>7} "
        f"{'wall':>6}"
    )
    print(f"phri demo: one simulated participant ({participant}), output in {folder}")
    print(header)
    print("-" * len(header))
    summary: csv.DictWriter | None = None
    with World(params=WorldParams(gui=gui)) as world, open(folder / "summary.csv", "x", newline="") as f:
        for task_name in STUDY_TASKS:
            task = load_task(task_name)
            planner = Planner(task, world)
            per_task: dict[str, EpisodeResult] = {}
            for strategy in STRATEGIES:
                r = run_episode_for_demo(task, world, participant, strategy, planner, folder, seed, frames)
                per_task[strategy] = r
                results.append(r)
                if summary is None:
                    summary = csv.DictWriter(f, fieldnames=list(r.row()))
                    summary.writeheader()
                summary.writerow(r.row())
                f.flush()
                print(
                    f"{task_name:<8} {strategy:<10} {r.effort:>9.1f} {r.interaction_time:>6.1f} "
                    f"{r.cost:>8.3f} "
                    f"{r.desired_cost:>8.3f} {r.final_weights[task.task_index]:>7.3f} {r.wall_time:>6.2f}"
                )
            _plot(folder, task_name, per_task, float(task.vector("true")[task.task_index]), task.duration)
    seconds = time.perf_counter() - began
    print(
        f"\nwrote {folder}/summary.csv, figures force_*.png path_*.png weights_*.png, frames/, logs/ "
        f"in {seconds:.1f} s"
    )
    return DemoResult(folder, results, seconds)


def run_episode_for_demo(task, world, participant, strategy, planner, folder, seed, frames) -> EpisodeResult:
    from phri.sim import run_episode

    return run_episode(
        task, world, participant, EpisodeConfig(strategy=strategy), seed=seed, planner=planner,
        log_path=folder / "logs" / f"{task.name}_{strategy}.npz",
        frame_times=frame_times(task.duration) if frames else (),
        frame_prefix=folder / "frames" / f"{task.name}_{strategy}",
    )  # fmt: skip
