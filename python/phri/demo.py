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

from phri import plots
from phri.config import STUDY_TASKS, Task, load_task
from phri.exceptions import InvalidParameterError
from phri.sim import STRATEGIES, EpisodeConfig, EpisodeResult, ParticipantParams, Planner, World, WorldParams

__all__ = ["episode_figures", "fresh_folder", "frame_times", "run_demo"]

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


def episode_figures(folder: Path, task: Task, results: dict[str, EpisodeResult]) -> list[Path]:
    """The figures of `task`'s episodes, one per strategy in `results` (one or both), drawn from
    their results in memory (their `log_arrays`): ``force_<task>.png``, ``path_<task>.png`` and
    ``weights_<task>.png`` (the learning episode's weight, else the only episode's) in `folder`.
    The demo and ``phri run`` draw these."""
    logs = {strategy: r.log_arrays for strategy, r in results.items()}
    # Fig. 1: the person's effort over time.
    force = plots.plot_effort(
        folder / f"force_{task.name}.png", task.name, {s: (a["t"], a["u_h"]) for s, a in logs.items()}
    )
    # Fig. 5 right: the hand's path against the desired one, at the plan's waypoint times.
    desired = next(iter(results.values())).desired_path
    t = np.linspace(0, task.duration, len(desired))
    executed = {s: (t, r.executed_path) for s, r in results.items()}
    path = plots.plot_paths(
        folder / f"path_{task.name}.png", (t, desired), executed, plots.DEMO_PATHS, title=task.name
    )
    # The learned weight of the task's feature over time.
    learned = logs["learning"] if "learning" in logs else next(iter(logs.values()))
    true = float(task.vector("true")[task.task_index])
    weights = plots.plot_weight(
        folder / f"weights_{task.name}.png", task.name, learned["weights_t"],
        learned["weights"][:, task.task_index], true, task.duration,
    )  # fmt: skip
    return [force, path, weights]


def run_demo(
    out: Path = Path("out/demo"), seed: int = 7, gui: bool = False, frames: bool = True
) -> DemoResult:
    """Runs the demo into a fresh folder next to (or at) `out` and returns what it did.

    Each episode's row is appended to ``summary.csv`` as soon as it finishes, so an interrupted demo
    keeps what it did."""
    began = time.perf_counter()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    check_out(Path(out))
    folder = fresh_folder(Path(out))
    (folder / "logs").mkdir()
    (folder / "frames").mkdir()
    participant = ParticipantParams.draw(np.random.default_rng(seed))
    results: list[EpisodeResult] = []
    header = (
        f"{'task':<8} {'strategy':<10} {'effort':>9} {'time':>6} {'cost':>8} {'desired':>8} {'weight':>7} "
        f"{'clear':>6} {'walled':>6} {'secs':>6}"
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
                    f"{r.cost:>8.3f} {r.desired_cost:>8.3f} {r.final_weights[task.task_index]:>7.3f} "
                    f"{r.min_clearance:>6.3f} {r.wall_contact_time:>6.2f} {r.wall_time:>6.2f}"
                )
            episode_figures(folder, task, per_task)
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
