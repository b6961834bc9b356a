"""Pushes the features explain, and pushes they do not: the paper's update rule ("all") against the
"beta" rule, which scales each step by how well the learned features explain the push (β̂,
docs/concepts.md). The measurements of docs/participant.md ("People who push for a reason no
feature names") come from here.

1. The paper's four tasks: the default study (10 people × 4 tasks × 2 strategies × 2 attempts)
   under each rule, the same people. Printed per task, for the learning episodes: the mean effort
   [N·m·s], interaction time [s] and final weight of the task's feature under each rule, and the
   ratio beta / all.
2. People who push for a reason no feature names: the table task with its height already right
   (true weight = initial = 0) and a keep-out around the laptop that the person cares about and the
   robot does not model (a task file's [unmodelled.laptop]). The default population's first
   --people people × --seeds episode seeds, learning, under each rule. Printed: the mean and largest
   move of the height's weight as a fraction of its range, the episodes in which it moved more
   than half and more than a tenth of its range, and the share of pushes with β̂ below
   phri.BETA_THRESHOLD; for comparison, the β̂ of the same people's pushes on the paper's four
   tasks, made for the task's own feature.

Usage: python benches/misspecified.py [--people 10] [--seeds 2] [--skip-study]
       (about 45 s on the project's 2-core machine)
"""

from __future__ import annotations

import argparse
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

import phri
from phri.sim import EpisodeConfig, World
from phri.sim.episode import Planner, simulate_episode
from phri.sim.participant import default_population
from phri.study import StudyConfig, run_study

RULES = ("all", "beta")

#: The laptop's keep-out, as the laptop task's feature: what the person of part 2 also wants.
UNMODELLED_LAPTOP = """
# The person also keeps the cup away from the laptop; the robot has no feature for it.
[unmodelled.laptop]
true = 10.0
keep_out = "laptop"
radius = 0.4
offset = [0.0, -0.1]
samples = 4
"""


def misspecified_task(folder: Path) -> phri.Task:
    """The table task with the height right and the unmodelled laptop keep-out (part 2)."""
    text = (resources.files("phri.tasks") / "table.toml").read_text(encoding="utf-8")
    text = text.replace('name = "table"', 'name = "table_unmodelled_laptop"')
    right = text.replace(
        "[features.table]\ninitial = 0.0\ntrue = 1.0", "[features.table]\ninitial = 0.0\ntrue = 0.0"
    )
    assert right != text, "the table task's [features.table] changed: update this bench"
    path = folder / "table_unmodelled_laptop.toml"
    path.write_text(right + UNMODELLED_LAPTOP, encoding="utf-8")
    return phri.load_task(path)


def paper_tasks(folder: Path) -> None:
    frames = {}
    for rule in RULES:
        run_study(folder / rule, StudyConfig(rule=rule), progress=False)
        d = pd.read_csv(folder / rule / "results.csv")
        frames[rule] = (
            d[(d.strategy == "learning") & (d.status == "ok")]
            .groupby("task")[["effort", "interaction_time", "final_weight"]]
            .mean()
        )
    print("1. the paper's four tasks, the default study's learning episodes (means)")
    print(f"  {'task':<8} {'measure':<17} {'all':>9} {'beta':>9} {'beta/all':>9}")
    for task in frames["all"].index:
        for measure in ("effort", "interaction_time", "final_weight"):
            a, b = frames["all"].loc[task, measure], frames["beta"].loc[task, measure]
            print(f"  {task:<8} {measure:<17} {a:9.3f} {b:9.3f} {b / a if a else float('nan'):9.3f}")


def learning_episodes(task, world, planner, rule: str, people: int, seeds: int):
    """(result, error) of the default population's first `people` people × `seeds` episode seeds,
    learning on `task` under `rule`."""
    for p in range(1, people + 1):
        person = default_population().draw(0, p)
        for seed in range(1, seeds + 1):
            yield simulate_episode(task, world, person, EpisodeConfig(rule=rule), seed=seed, planner=planner)


def push_betas(result) -> np.ndarray:
    """β̂ of an episode's pushes (those the learner scored)."""
    b = result.log_arrays["interaction_beta"]
    return b[~np.isnan(b)]


def unmodelled(folder: Path, people: int, seeds: int) -> None:
    task = misspecified_task(folder)
    planner = Planner(task, phri.Robot.jaco2())
    k = task.task_index
    span = task.vector("upper")[k] - task.vector("lower")[k]
    print()
    print(
        f"2. pushes for a reason no feature names: {task.name}, {people} people x {seeds} seeds, learning "
        f"(the height's weight starts right, at {task.vector('initial')[k]:g}, range {span:g})"
    )
    print(
        f"  {'rule':<6} {'episodes':>8} {'mean move':>10} {'largest':>8} {'> half':>7} {'> tenth':>8} "
        f"{'beta < threshold':>17}"
    )
    with World() as world:
        for rule in RULES:
            moves, betas, stopped = [], [], 0
            for result, error in learning_episodes(task, world, planner, rule, people, seeds):
                if error is not None:
                    stopped += 1
                    continue
                moves.append(abs(result.final_weights[k] - task.vector("initial")[k]) / span)
                betas.extend(push_betas(result))
            m, b = np.array(moves), np.array(betas)
            print(
                f"  {rule:<6} {len(m):>8} {m.mean():>10.3f} {m.max():>8.3f} {int((m > 0.5).sum()):>7} "
                f"{int((m > 0.1).sum()):>8} {(b < phri.BETA_THRESHOLD).mean():>10.0%} of {len(b)}"
                + (f" ({stopped} stopped)" if stopped else "")
            )


def explained(people: int, seeds: int) -> None:
    """The same people on the paper's four tasks, learning under "all": the β̂ of pushes made for
    the task's own feature."""
    print("  for comparison, the same people's pushes on the paper's tasks (all):")
    with World() as world:
        for name in ("table", "coffee", "laptop", "human"):
            task = phri.load_task(name)
            planner = Planner(task, phri.Robot.jaco2())
            episodes = learning_episodes(task, world, planner, "all", people, seeds)
            b = np.concatenate([push_betas(result) for result, error in episodes if error is None])
            below, full = (b < phri.BETA_THRESHOLD).mean(), (b >= phri.BETA_FULL).mean()
            print(
                f"    {name:<7} beta median {np.median(b):6.2f}, {below:4.0%} below the threshold, "
                f"{full:4.0%} at or above phri.BETA_FULL, of {len(b)}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--people", type=int, default=10)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--skip-study", action="store_true", help="part 2 only")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if not args.skip_study:
            paper_tasks(folder)
        unmodelled(folder, args.people, args.seeds)
        explained(args.people, args.seeds)


if __name__ == "__main__":
    main()
