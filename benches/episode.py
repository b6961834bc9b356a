"""Times simulated 15 s study episodes at 1 kHz (PyBullet DIRECT, one core) and prints the median
wall time and the speed-up over real time per task and strategy: the study's tasks, the JACO2's
(the FR3's run on franky-sim). ``make bench-episode``."""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

import phri
from phri.config import STUDY_TASKS
from phri.sim import STRATEGIES, EpisodeConfig, ParticipantParams, Planner, World


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()
    person = ParticipantParams.draw(np.random.default_rng(7))
    rows = []
    print(f"{'task':<8} {'strategy':<10} {'median [s]':>10} {'x real time':>12}")
    with World() as world:
        for name in STUDY_TASKS:
            task = phri.load_task(name)
            planner = Planner(task, world)
            for strategy in STRATEGIES:
                times = [
                    phri.sim.run_episode(
                        task, world, person, EpisodeConfig(strategy=strategy), seed=k, planner=planner
                    ).wall_time
                    for k in range(args.repeats)
                ]
                median = statistics.median(times)
                rows.append(
                    {
                        "task": name,
                        "strategy": strategy,
                        "median_s": median,
                        "speedup": task.duration / median,
                    }
                )
                print(f"{name:<8} {strategy:<10} {median:>10.3f} {task.duration / median:>12.1f}")
    overall = statistics.median(r["speedup"] for r in rows)
    print(f"median speed-up over real time: {overall:.1f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"episodes": rows, "median_speedup": overall}, f, indent=2)


if __name__ == "__main__":
    main()
