"""Time a push's replan on a real arm: from the push's sample to the control tick that adopts the new
plan, on the FR3's four tasks (fr3_human, fr3_coffee, fr3_table, fr3_laptop), with the learner that
`phri run` makes (phri.sim.episode.robot_controls: replans on the worker thread, adopted at the first
tick after they are ready; WALL_CLOCK_SEEDS seed plans per learned weight), and for comparison
without seed plans and with the worker spinning (``worker_spin=inf``).

Each sequence pushes once a second, at t = 2, 3, ..., 11 s, the way the task wants: a joint torque
of PUSH N·m in norm (above every FR3 detection threshold) against the gradient of the task's feature
at the plan's waypoint nearest t (`Features.phi_gradient`), so that each push raises the task's weight,
as a person's corrections do, until it reaches its bound. After a push that updated the weights,
`observe` is called every --poll-us microseconds of wall time (a 1 kHz loop looks every millisecond;
polling faster measures the replan rather than the loop's period) at the next ticks' times until a
plan is adopted. The learner is
reset between sequences. Printed per task: the pushes that replanned, the median, p99 and maximum
of push-to-adoption (wall clock, from before the push's `observe` to the return of the one that
adopted), and the median and p99 of the worker's solve alone (the replan's ``seconds``).

Usage: python benches/push_adoption.py [--sequences 10] [--poll-us 50]   (or `make bench-push`)
"""

from __future__ import annotations

import argparse
import gc
import math
import time

import numpy as np

import phri
from phri.config import load_task
from phri.sim.episode import EpisodeConfig, robot_controls

TASKS = ("fr3_human", "fr3_coffee", "fr3_table", "fr3_laptop")
#: Push times of one sequence [s].
PUSH_TIMES = tuple(float(t) for t in range(2, 12))
#: The push's joint torque, in norm [N·m].
PUSH = 20.0
#: Ticks of the loop [s].
TICK = 1e-3


def corrective_push(features: phri.Features, task_index: int, plan: np.ndarray, duration: float, t: float):
    """The push at `t` [s]: PUSH N·m against the gradient of the task feature Φ_task with respect to
    the plan's waypoint nearest t (None where the gradient vanishes)."""
    i = min(max(round(t / duration * (len(plan) - 1)), 1), len(plan) - 2)
    gradient = features.phi_gradient(plan)[1][task_index, i]
    norm = float(np.linalg.norm(gradient))
    return None if norm < 1e-9 else -PUSH * gradient / norm


def run_task(
    name: str, config: EpisodeConfig, sequences: int, poll: float
) -> tuple[list[float], list[float]]:
    """Push-to-adoption times and solve times [s] of `sequences` sequences of pushes on task `name`."""
    task = load_task(name)
    model = phri.Robot.from_description(task.robot)
    controls = robot_controls(task, model, config, replan_latency=None)
    learner, features = controls.learner, controls.planner.features
    latencies: list[float] = []
    solves: list[float] = []
    for _ in range(sequences):
        learner.reset()
        for t in PUSH_TIMES:
            tau = corrective_push(features, task.task_index, learner.history().plans[-1], task.duration, t)
            if tau is None:
                continue
            began = time.perf_counter()
            learner.observe(t, tau)
            if not learner.replan_pending:
                continue  # the push moved nothing (too near the goal, or below the thresholds)
            k = 1
            quiet = np.zeros(model.nq)
            while True:
                time.sleep(poll)
                learner.observe(min(t + k * TICK, t + 0.9), quiet)
                if learner.adopted:
                    latencies.append(time.perf_counter() - began)
                    break
                if not learner.replan_pending:
                    break  # rejected: not adopted, nothing to time
                k += 1
            replan = learner.history().replans[-1]
            if replan is not None:
                solves.append(replan.seconds)
    return latencies, solves


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", type=int, default=10, help="push sequences per task (default 10)")
    parser.add_argument("--poll-us", type=float, default=50.0, help="polling period [µs] (default 50)")
    args = parser.parse_args()
    poll = args.poll_us * 1e-6
    variants = [
        ("phri run's learner (seeds by default, worker asleep)", EpisodeConfig()),
        ("without seed plans", EpisodeConfig(seeds=0)),
        ("with the worker spinning", EpisodeConfig(worker_spin=math.inf)),
    ]
    ms = 1e3
    print(f"push to adopted plan on the FR3's tasks, {args.sequences} sequences of {len(PUSH_TIMES)} pushes, "
          f"polled every {args.poll_us:g} µs [ms]")  # fmt: skip
    gc.freeze()
    gc.disable()
    try:
        for label, config in variants:
            print(f"{label}:")
            print(f"  {'task':<12} {'pushes':>6} {'median':>8} {'p99':>8} {'max':>8}   solve median / p99")
            for name in TASKS:
                latencies, solves = run_task(name, config, args.sequences, poll)
                if not latencies:
                    print(f"  {name:<12} no push replanned")
                    continue
                lat, sol = np.array(latencies) * ms, np.array(solves) * ms
                print(
                    f"  {name:<12} {len(lat):>6} {np.median(lat):8.3f} {np.percentile(lat, 99):8.3f} "
                    f"{lat.max():8.3f}   {np.median(sol):6.3f} / {np.percentile(sol, 99):6.3f}"
                )
    finally:
        gc.enable()
        gc.unfreeze()


if __name__ == "__main__":
    main()
