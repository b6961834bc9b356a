"""``phri run``: one episode on a real arm (or franky-sim's) at an address, written as the simulated
episodes are.

``phri run --robot fr3 --host ADDR --task table --strategy learning`` connects to whatever answers
at ADDR (a real FR3, or ``phri sim-server``), moves the arm to the task's start pose in a motion of
its own, runs the episode with the learner on the control loop (:class:`phri.franka.episode.FrankaEpisode`)
and writes into a fresh output folder (``out/run``, else ``out/run-2``, ...; never overwritten):

- ``logs/<task>_<strategy>.npz``: the episode's log, with the keys of a simulated episode's log, plus
  the move's (``move_*``), the tick counts (``ticks``, ``late_ticks``, ``max_tick_gap``) and the
  replans' convergence (``replan_converged``); written also when the arm was stopped;
- ``force_<task>.png``, ``path_<task>.png``, ``weights_<task>.png``: the demo's figures;
- ``summary.csv`` (the demo's columns) and ``summary.json``: effort, interaction time, the stop
  record if any, the ticks and late ticks measured on the robot's clock.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from phri.atomic import write_atomic
from phri.config import Task
from phri.exceptions import InvalidParameterError
from phri.franka.episode import (
    CONNECT_TIMEOUT,
    REPLAN_LATENCY,
    FrankaEpisode,
    FrankaOutcome,
    check_task_robot,
)
from phri.franka.move import MAX_MOVE, MOVE_SPEED
from phri.sim.episode import STRATEGIES, WALL_CLOCK_SEEDS, EpisodeConfig, replan_settings, write_log

__all__ = ["RunOutput", "add_arguments", "load_run_task", "run", "run_episode_at", "write_run"]

#: The robots ``phri run`` drives (over libfranka).
ROBOTS = ("fr3",)


@dataclass
class RunOutput:
    """What :func:`run_episode_at` wrote: the folder, the log, the figures and the summary."""

    folder: Path
    log: Path
    figures: list[Path]
    summary: dict[str, Any]
    outcome: FrankaOutcome


def load_run_task(name_or_path: str, robot: str, duration: float | None = None) -> Task:
    """The task `name_or_path` for `robot`: a shipped one by its name with or without the robot's
    prefix (``table`` is ``fr3_table``), or a task file; posed for another robot it is a
    ConfigError. `duration` [s] overrides the task's."""
    from phri.franka.sim_server import check_duration, fr3_task

    if robot not in ROBOTS:
        raise InvalidParameterError(f"robot must be one of {ROBOTS}, got {robot!r}")
    task = fr3_task(name_or_path)
    check_task_robot(task, robot)
    if duration is not None:
        task = dataclasses.replace(task, duration=check_duration(duration))
    return task


def summary_of(outcome: FrankaOutcome, task: Task, config: EpisodeConfig, host: str) -> dict[str, Any]:
    """The episode's summary: the study's measures (the demo's row), the stop record (None without
    a stop), the move to the start, the ticks on the robot's clock and the learner's replan
    settings (seed plans per learned weight, the worker's spin [s], null for ever)."""
    result, stop = outcome.result, outcome.stop
    summary: dict[str, Any] = {"host": host, "task": task.name, "strategy": config.strategy}
    summary["seeds"], summary["worker_spin"] = replan_settings(task, config, REPLAN_LATENCY)
    summary.update(result.row() if result is not None else {})
    summary["wall_peak_force"] = None if result is None else result.wall_peak_force
    summary["completed"] = outcome.error is None
    error = outcome.error
    summary["error"] = None if error is None else (str(error) or type(error).__name__)
    summary["stop"] = None if stop is None else _stop_record(stop)
    summary["move_duration"] = None if outcome.move is None else outcome.move.total
    summary["ticks"] = outcome.ticks
    summary["late_ticks"] = outcome.late_ticks
    summary["max_tick_gap"] = outcome.max_tick_gap
    summary["motion_seconds"] = outcome.motion_seconds
    # Ticks per second of wall time: 1000 on an FR3; franky-sim slowed by --realtime serves fewer.
    summary["loop_rate"] = outcome.ticks / outcome.motion_seconds if outcome.motion_seconds > 0 else None
    return {k: _json_value(v) for k, v in summary.items()}


def _json_value(v: Any) -> Any:
    """JSON has no NaN or infinity: a value that does not apply (or is unbounded) is null."""
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _stop_record(stop: Any) -> dict[str, Any]:
    record = {
        "reason": stop.reason, "message": stop.message, "tick": stop.tick, "t": stop.t,
        "quantity": stop.quantity, "index": stop.index, "value": stop.value, "bound": stop.bound,
        "q": stop.q.tolist(), "qd": stop.qd.tolist(), "tau": stop.tau.tolist(),
        "tau_ext": stop.tau_ext.tolist(),
    }  # fmt: skip
    return {k: _json_value(v) for k, v in record.items()}


def write_run(folder: Path, episode: FrankaEpisode, outcome: FrankaOutcome) -> RunOutput:
    """Writes the log, figures and summary of `episode`'s `outcome` into `folder` (made by the
    caller, empty)."""
    from phri.demo import episode_figures

    task, strategy, host = episode.task, episode.config.strategy, episode.backend.host
    (folder / "logs").mkdir(exist_ok=True)
    log = write_log(folder / "logs" / f"{task.name}_{strategy}.npz", outcome.log_arrays)
    figures: list[Path] = []
    result = outcome.result
    if result is not None:
        result.log = log
        figures = episode_figures(folder, task, episode.controls.planner, episode.model, {strategy: result})
    summary = summary_of(outcome, task, episode.config, host)
    if result is not None:
        row = result.row()
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(row), lineterminator="\n")
        writer.writeheader()
        writer.writerow(row)
        write_atomic(folder / "summary.csv", text.getvalue().encode(), overwrite=False)
    write_atomic(folder / "summary.json", (json.dumps(summary, indent=2) + "\n").encode(), overwrite=False)
    return RunOutput(folder, log, figures, summary, outcome)


def run_episode_at(
    host: str,
    task: Task,
    strategy: str,
    out: Path,
    *,
    config: EpisodeConfig | None = None,
    connect_timeout: float = CONNECT_TIMEOUT,
    move_speed: float = MOVE_SPEED,
    max_move: float = MAX_MOVE,
) -> RunOutput:
    """One episode of `task` with `strategy` on the arm at `host`, written into a fresh folder at
    (or next to) `out`. Errors before the arm moved (nothing answers, a move refused) are raised
    and write nothing; a stop or a failure after is in the summary, with the log so far."""
    from phri.demo import check_out, fresh_folder

    if strategy not in STRATEGIES:
        raise InvalidParameterError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")
    config = dataclasses.replace(config or EpisodeConfig(), strategy=strategy)
    check_out(out)  # before the arm moves: a bad --out must not cost an episode
    episode = FrankaEpisode(
        host, task, config, connect_timeout=connect_timeout, move_speed=move_speed, max_move=max_move
    )
    outcome = episode.run()
    return write_run(fresh_folder(out), episode, outcome)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``phri run``'s options."""
    add = parser.add_argument
    add("--robot", required=True, choices=ROBOTS, help="the arm at --host (fr3)")
    add("--host", required=True, help="the robot's address (a real FR3's, or `phri sim-server`'s)")
    add("--task", required=True, help="task name (table, laptop, human, coffee, fr3_*) or task file")
    add("--strategy", required=True, choices=STRATEGIES, help="learning or impedance")
    add("--out", default="out/run", help="output folder (a fresh one if it exists; default out/run)")
    add("--duration", type=float, default=None, help="override the task's duration [s] (robot time)")
    add("--sample-rate", type=float, default=None, help="torque sampling rate [Hz] (default 10)")
    add(
        "--connect-timeout", type=float, default=CONNECT_TIMEOUT,
        help=f"seconds to wait for an answer at --host (default {CONNECT_TIMEOUT:g})",
    )  # fmt: skip
    add(
        "--seeds", type=int, default=None,
        help=f"seed plans per learned weight for the replans (default {WALL_CLOCK_SEEDS}; 0: none)",
    )  # fmt: skip
    add(
        "--worker-spin", type=float, default=0.0,
        help="seconds the replan worker busy-waits for the next push before it sleeps (default 0; "
        "inf: never sleeps; keeps a CPU core busy, for a machine with one to spare)",
    )  # fmt: skip
    add(
        "--move-speed", type=float, default=MOVE_SPEED,
        help="the move to the start pose: its fastest joint peaks at this fraction of its rated "
        f"speed (default {MOVE_SPEED:g})",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """``phri run`` as `args` say; prints the summary. 0: the episode ran to its end; 1: it was
    stopped or failed (its log and summary are written)."""
    task = load_run_task(args.task, args.robot, args.duration)
    rate = {} if args.sample_rate is None else {"sample_rate": args.sample_rate}
    config = EpisodeConfig(**rate, seeds=args.seeds, worker_spin=args.worker_spin)
    output = run_episode_at(
        args.host, task, args.strategy, Path(args.out), config=config,
        connect_timeout=args.connect_timeout, move_speed=args.move_speed,
    )  # fmt: skip
    s = output.summary
    print(f"phri run: {task.name}, {args.strategy}, on {args.robot} at {args.host} -> {output.folder}")
    if s["move_duration"] is not None:
        print(f"  moved to the start pose in {s['move_duration']:.1f} s")
    if "effort" in s:
        print(
            f"  effort {s['effort']:.1f} N·m, interaction time {s['interaction_time']:.2f} s, cost "
            f"{s['cost']:.3f} (desired {s['desired_cost']:.3f}), final weight {s['final_weight']:.3f}"
        )
        print(
            f"  {s['ticks']} ticks at {s['loop_rate']:.0f} per second of wall time, {s['late_ticks']} "
            f"late (robot's clock), largest gap {1e3 * s['max_tick_gap']:.0f} ms; wrote {output.log.name}, "
            f"{', '.join(p.name for p in output.figures)}, summary.csv, summary.json"
        )
    if s["error"] is not None:
        print(f"  stopped: {s['error']}")
        return 1
    return 0
