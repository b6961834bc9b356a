"""The main job: the study's four tasks (or your own task files), both strategies, one simulated
participant.

Writes into one output folder, per task: the person's torque over time for both strategies (the
paper's Fig. 1, ``force_TASK.png``), the cup's path against the desired path with the scene drawn
(Fig. 5, right, ``path_TASK.png``), the taught feature over time (``feature_TASK.png``), the learned
weights over time (``weights_TASK.png``), rendered frames of the scene labelled with task, strategy
and time (``frames/``), each episode's compressed log (``logs/``), and ``summary.csv``. The table of
results is returned (and printed by ``phri demo``); progress goes to the ``phri.demo`` logger.
"""

from __future__ import annotations

import csv
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from phri import plots
from phri._phri import Features, Robot, TimedTrajectory
from phri.config import STUDY_TASKS, Task, load_task
from phri.exceptions import InvalidParameterError
from phri.feature import Feature as PythonFeature
from phri.sim import (
    SIMULATORS,
    STRATEGIES,
    EpisodeConfig,
    EpisodeResult,
    ParticipantParams,
    Planner,
    World,
    WorldParams,
)
from phri.sim.participant import PARAMETERS

__all__ = [
    "FRAMES",
    "DemoResult",
    "check_out",
    "describe_participant",
    "episode_figures",
    "fresh_folder",
    "frame_times",
    "run_demo",
    "table_header",
    "table_row",
]

log = logging.getLogger(__name__)

#: Frames rendered per episode, evenly spaced from the start to the end of the task.
FRAMES = 4
#: The results table's columns: (heading, width, format of the value).
_COLUMNS = (
    ("task", -8, ""), ("strategy", -10, ""), ("effort", 9, ".1f"), ("time", 6, ".1f"),
    ("cost", 8, ".3f"), ("desired", 8, ".3f"), ("weight", 7, ".3f"), ("clear", 6, ".3f"),
    ("walled", 6, ".2f"), ("secs", 6, ".2f"),
)  # fmt: skip


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


def describe_participant(params: ParticipantParams) -> str:
    """The drawn parameters of a simulated participant, three significant digits each, with units."""

    def unit(name: str) -> str:
        return "" if PARAMETERS[name].unit == "-" else f" {PARAMETERS[name].unit}"

    return ", ".join(f"{name} {getattr(params, name):.3g}{unit(name)}" for name in PARAMETERS)


def table_header() -> str:
    """The heading of the results table, and a rule under it."""
    heading = " ".join(f"{name:<{-w}}" if w < 0 else f"{name:>{w}}" for name, w, _ in _COLUMNS)
    return f"{heading}\n{'-' * len(heading)}"


def table_row(result: EpisodeResult) -> str:
    """One episode's row of the results table: effort Σ|u_H| [N·m], interaction time [s], task cost
    of the executed path and of the desired one, the learned task weight, the smallest clearance [m],
    the time the virtual wall acted [s] and the episode's wall-clock time [s]."""
    values = (
        result.task, result.strategy, result.effort, result.interaction_time, result.cost,
        result.desired_cost, float(result.final_weights[result.task_index]), result.min_clearance,
        result.wall_contact_time, result.wall_time,
    )  # fmt: skip
    return " ".join(
        f"{v:<{-w}}" if w < 0 else f"{v:>{w}{fmt}}" for v, (_, w, fmt) in zip(values, _COLUMNS, strict=True)
    )


@dataclass
class DemoResult:
    """What :func:`run_demo` did: the folder it wrote, each episode's result (task by task, both
    strategies) and how long it took [s]."""

    folder: Path
    results: list[EpisodeResult]
    seconds: float

    def table(self) -> str:
        """The results table, as ``phri demo`` prints it."""
        return "\n".join([table_header(), *(table_row(r) for r in self.results)])


def _tasks(tasks: Sequence[str | Path]) -> list[Task]:
    """The tasks to run (names of shipped tasks or task files), loaded and checked up front."""
    if isinstance(tasks, str | Path) or not len(tasks):
        raise InvalidParameterError(f"--task: give one or more tasks (names or files), got {tasks!r}")
    loaded = [load_task(t) for t in tasks]
    names = [t.name for t in loaded]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InvalidParameterError(f"--task: each task once (figures are named by task), got {twice} twice")
    return loaded


def run_demo(
    out: Path = Path("out/demo"),
    seed: int = 7,
    gui: bool = False,
    frames: bool = True,
    tasks: Sequence[str | Path] | None = None,
    on_episode: Callable[[EpisodeResult], None] | None = None,
    simulator: str | None = None,
) -> DemoResult:
    """Runs the demo into a fresh folder next to (or at) `out` and returns what it did.

    `tasks` are shipped task names or task files (None: the study's four,
    :data:`~phri.config.STUDY_TASKS`); the simulated participant is the default population's median
    person (``ParticipantParams()``: the typical one, where a drawn person may be one of the few
    too weak to register a push) and `seed` seeds their tremor, aim and the sensor; `gui` shows
    PyBullet's window; `frames` renders PNG frames. `on_episode` is called with each episode's
    result as it finishes (``phri demo`` prints its row). Each episode's row is appended to
    ``summary.csv`` as soon as it finishes, so an interrupted demo keeps what it did. `simulator`
    (``EpisodeConfig.simulator``; None: "native", or "pybullet" with `gui`, whose window shows
    PyBullet's arm) simulates the episodes."""
    began = time.perf_counter()
    simulator = simulator or ("pybullet" if gui else "native")
    if simulator not in SIMULATORS:
        raise InvalidParameterError(f"simulator must be one of {SIMULATORS}, got {simulator!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    check_out(Path(out))
    loaded = _tasks(STUDY_TASKS if tasks is None else tasks)
    participant = ParticipantParams()
    with World(params=WorldParams(gui=gui)) as world:
        # Every task is planned before anything is written: one that cannot run here (another
        # robot's, or one that cannot be planned safely) leaves no folder behind.
        planners = [Planner(task, world) for task in loaded]
        folder = fresh_folder(Path(out))
        (folder / "logs").mkdir()
        (folder / "frames").mkdir()
        log.info("one simulated participant (%s); output in %s", describe_participant(participant), folder)
        results = _run(world, planners, participant, folder, seed, frames, on_episode, simulator)
    seconds = time.perf_counter() - began
    log.info(
        "wrote %s: summary.csv, force_*.png, path_*.png, feature_*.png, weights_*.png, frames/, logs/ "
        "in %.1f s", folder, seconds,
    )  # fmt: skip
    return DemoResult(folder, results, seconds)


def _run(
    world: World,
    planners: list[Planner],
    participant: ParticipantParams,
    folder: Path,
    seed: int,
    frames: bool,
    on_episode: Callable[[EpisodeResult], None] | None,
    simulator: str,
) -> list[EpisodeResult]:
    """Both strategies on each planner's task; each row into ``summary.csv`` as it finishes, then
    the task's figures."""
    results: list[EpisodeResult] = []
    summary: csv.DictWriter | None = None
    with open(folder / "summary.csv", "x", newline="") as f:
        for planner in planners:
            task, per_task = planner.task, {}
            for strategy in STRATEGIES:
                r = run_episode_for_demo(
                    task, world, participant, strategy, planner, folder, seed, frames, simulator
                )
                per_task[strategy] = r
                results.append(r)
                if summary is None:
                    summary = csv.DictWriter(f, fieldnames=list(r.row()))
                    summary.writeheader()
                summary.writerow(r.row())
                f.flush()
                _label_frames(r, task)
                if on_episode is not None:
                    on_episode(r)
            episode_figures(folder, task, planner, world.model, per_task)
    return results


def run_episode_for_demo(
    task: Task,
    world: World,
    participant: ParticipantParams,
    strategy: str,
    planner: Planner,
    folder: Path,
    seed: int,
    frames: bool,
    simulator: str = "native",
) -> EpisodeResult:
    """One episode of the demo on `simulator`: its log into ``folder/logs``, its frames into
    ``folder/frames``."""
    from phri.sim import run_episode

    config = EpisodeConfig(strategy=strategy, simulator=simulator)
    return run_episode(
        task, world, participant, config, seed=seed, planner=planner,
        log_path=folder / "logs" / f"{task.name}_{strategy}.npz",
        frame_times=frame_times(task.duration) if frames else (),
        frame_prefix=folder / "frames" / f"{task.name}_{strategy}",
    )  # fmt: skip


def _label_frames(result: EpisodeResult, task: Task) -> None:
    """Writes the task, the strategy and the time into each of the episode's frames."""
    for path, t in zip(result.frames, frame_times(task.duration) if result.frames else (), strict=True):
        plots.label_image(path, f"{task.name} · {result.strategy} · t = {t:.2f} s")


def _point_features(task: Task, planner: Planner, model: Robot) -> Features:
    """The task's feature measured at single points: a keep-out feature at one point per segment
    (its sum over a segment's sample points would count the same point several times on a dense
    log), so that segment i of a path gives the feature's value at waypoint i."""
    spec = task.features[task.task_index].feature(model, task.scene)
    if isinstance(spec, dict) and ("keep_out" in spec or spec.get("kind") == "distance"):
        spec = {**spec, "samples": 1}
    elif isinstance(spec, PythonFeature) and spec.samples > 1:
        spec.samples = 1  # a fresh instance, made for these figures
    return Features(model, [spec], scene=task.scene, frame=planner.features.frame)


def episode_figures(
    folder: Path, task: Task, planner: Planner, model: Robot, results: dict[str, EpisodeResult]
) -> list[Path]:
    """The figures of `task`'s episodes on `model` (planned by `planner`), one per strategy in
    `results` (one or both), drawn from their results in memory (their `log_arrays`):
    ``force_<task>.png``, ``path_<task>.png``, ``feature_<task>.png`` and ``weights_<task>.png``
    (the learning episode's weights, else the only episode's) in `folder`. The demo and ``phri run``
    draw these."""
    logs = {strategy: r.log_arrays for strategy, r in results.items()}
    # Fig. 1: the person's effort over time.
    force = plots.plot_effort(
        folder / f"force_{task.name}.png", task.name, {s: (a["t"], a["u_h"]) for s, a in logs.items()}
    )
    # Fig. 5 right: the cup's path against the desired one, at the plan's waypoint times, in the scene.
    desired = next(iter(results.values())).desired_path
    t = np.linspace(0, task.duration, len(desired))
    executed = {s: (t, r.executed_path) for s, r in results.items()}
    path = plots.plot_paths(
        folder / f"path_{task.name}.png", (t, desired), executed, plots.DEMO_PATHS, scene=task.scene,
        title=task.title, keep_outs=planner.features.keep_out_circles,
    )  # fmt: skip
    # The taught feature at the cup over time (the log rate), against the desired behaviour's.
    point = _point_features(task, planner, model)
    t_log = next(iter(logs.values()))["t"]
    desired_q = TimedTrajectory(planner.desired, task.duration).sample_many(t_log)[0]
    series = {s: (a["t"][1:], point.per_segment(a["q"])[:, 0]) for s, a in logs.items()}
    series["desired"] = (t_log[1:], point.per_segment(desired_q)[:, 0])
    feature = plots.plot_feature(
        folder / f"feature_{task.name}.png", task.name, task.task_feature, series, task.duration
    )
    # Every learned weight over time.
    learned = [i for i, f in enumerate(task.features) if f.learned]
    history = logs["learning"] if "learning" in logs else next(iter(logs.values()))
    weights = plots.plot_weights(
        folder / f"weights_{task.name}.png", task.name, [task.feature_names[i] for i in learned],
        history["weights_t"], history["weights"][:, learned], task.vector("true")[learned], task.duration,
    )  # fmt: skip
    return [force, path, feature, weights]
