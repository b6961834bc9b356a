"""Times simulated 15 s study episodes at 1 kHz (one core) on both simulators in one run and prints,
per task and strategy, the median wall time on each, the native loop's speed-up over real time and
its ratio to the PyBullet-stepped loop: the study's tasks, the JACO2's (the FR3's run on
franky-sim). ``make bench-episode``."""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

import phri
from phri.config import STUDY_TASKS
from phri.sim import SIMULATORS, STRATEGIES, EpisodeConfig, ParticipantParams, Planner, World


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args()
    person = ParticipantParams.draw(np.random.default_rng(7))
    rows = []
    header = f"{'native [s]':>10} {'pybullet [s]':>12} {'x real time':>12} {'ratio':>7}"
    print(f"{'task':<8} {'strategy':<10} {header}")
    with World() as world:
        for name in STUDY_TASKS:
            task = phri.load_task(name)
            planner = Planner(task, world)
            for strategy in STRATEGIES:
                median = {}
                for simulator in SIMULATORS:
                    config = EpisodeConfig(strategy=strategy, simulator=simulator)
                    times = [
                        phri.sim.run_episode(task, world, person, config, seed=k, planner=planner).wall_time
                        for k in range(args.repeats)
                    ]
                    median[simulator] = statistics.median(times)
                native, pybullet = median["native"], median["pybullet"]
                rows.append(
                    {
                        "task": name,
                        "strategy": strategy,
                        "median_s": native,
                        "pybullet_median_s": pybullet,
                        "speedup": task.duration / native,
                        "ratio": pybullet / native,
                    }
                )
                print(
                    f"{name:<8} {strategy:<10} {native:>10.3f} {pybullet:>12.3f} "
                    f"{task.duration / native:>12.1f} {pybullet / native:>7.2f}"
                )
    overall = statistics.median(r["speedup"] for r in rows)
    ratio = statistics.median(r["ratio"] for r in rows)
    print(f"median speed-up of the native loop over the PyBullet-stepped loop: {ratio:.2f}x")
    print(f"median speed-up over real time: {overall:.1f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"episodes": rows, "median_speedup": overall, "median_ratio": ratio}, f, indent=2)


if __name__ == "__main__":
    main()
