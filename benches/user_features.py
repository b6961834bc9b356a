"""Time cold plans with a lab's own feature in place of a built-in: the same feature three ways (the
built-in, declared in a task file with Rust's analytic derivatives, and written in numpy as a
phri.Feature), each replacing the task's own feature in the study's planner (phri.sim.episode.Planner's
settings: the collision model on, the task's knots, N = 31), solved from scratch for the task's true
weights.

  table:  built-in `table`       | declared `height` (offset = the table feature's height) | numpy
  coffee: built-in `coffee_dot`  | declared `alignment` (x against +z)                      | numpy
  laptop: built-in `laptop`      | declared `distance` (the laptop's keep-out circle)       | numpy

Rounds interleave the variants (each round solves every variant once), so a noisy machine slows
them alike. Printed per variant: the median cold plan [ms], its ratio to the built-in's median (the
targets: declared at most 1.5x, Python at most 5x), the plan's cost against the built-in's, and
for Python the calls per plan.

Usage: python benches/user_features.py [--rounds 15]   (or `make bench-features`)
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

import phri
from phri.config import Task, load_task
from phri.sim.episode import VELOCITY_MARGIN


class NumpyHeight(phri.Feature):
    """The table feature in numpy: the feature frame's height above `height` [m]."""

    def __init__(self, robot: phri.Robot, name: str, height: float) -> None:
        self.robot, self.frame, self.name, self.height = robot, robot.feature_frame, name, height
        self.calls = 0

    def value(self, q: np.ndarray) -> np.ndarray:
        self.calls += 1
        return self.robot.frame_pose(self.frame, q)[:, 2, 3] - self.height

    def gradient(self, q: np.ndarray) -> np.ndarray:  # type: ignore[override]
        self.calls += 1
        return self.robot.jacobian(self.frame, q)[:, 2, :]


class NumpyUpright(phri.Feature):
    """coffee_dot in numpy: 1 − x·ẑ, x the feature frame's x axis (the cup's)."""

    def __init__(self, robot: phri.Robot, name: str) -> None:
        self.robot, self.frame, self.name = robot, robot.feature_frame, name
        self.calls = 0

    def value(self, q: np.ndarray) -> np.ndarray:
        self.calls += 1
        return 1.0 - self.robot.frame_pose(self.frame, q)[:, 2, 0]

    def gradient(self, q: np.ndarray) -> np.ndarray:  # type: ignore[override]
        self.calls += 1
        x = self.robot.frame_pose(self.frame, q)[:, :3, 0]  # (M, 3)
        omega = self.robot.jacobian(self.frame, q)[:, 3:, :]  # (M, 3, n)
        # d x / d q_j = ω_j × x; its z component is ω_x x_y − ω_y x_x.
        return -(omega[:, 0, :] * x[:, 1, None] - omega[:, 1, :] * x[:, 0, None])


class NumpyKeepout(phri.Feature):
    """The laptop feature in numpy: h(radius − d), d the feature frame's horizontal distance from
    `centre` [m], at `samples` points per segment, h the hinge max(0, x) Huber-smoothed over
    `smoothing` [m] as the optimiser smooths the built-in's (its default 0.05 m; a kinked feature
    stalls a Newton solve)."""

    def __init__(self, robot: phri.Robot, name: str, centre: Any, radius: float, samples: int) -> None:
        self.robot, self.frame, self.name = robot, robot.feature_frame, name
        self.centre, self.radius, self.samples = np.asarray(centre, float), radius, samples
        self.smoothing = 0.05
        self.calls = 0

    def _depth(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.robot.frame_pose(self.frame, q)[:, :2, 3] - self.centre
        norm = np.linalg.norm(d, axis=1)
        return self.radius - norm, d / np.maximum(norm, 1e-12)[:, None]

    def value(self, q: np.ndarray) -> np.ndarray:
        self.calls += 1
        x, delta = self._depth(q)[0], self.smoothing
        return np.where(x <= 0, 0.0, np.where(x >= delta, x - delta / 2, x * x / (2 * delta)))

    def gradient(self, q: np.ndarray) -> np.ndarray:  # type: ignore[override]
        self.calls += 1
        x, unit = self._depth(q)
        slope = np.clip(x / self.smoothing, 0.0, 1.0)
        jac = self.robot.jacobian(self.frame, q)[:, :2, :]
        return -slope[:, None] * np.einsum("mc,mcj->mj", unit, jac)


def variants(task: Task, robot: phri.Robot) -> dict[str, Any]:
    """The task feature as the built-in, declared and numpy (name -> item of phri.Features)."""
    spec = task.features[task.task_index]
    name, params = spec.name, dict(spec.params)
    if name == "table":
        height = params.get("height", 0.0)
        return {
            "built-in": "table",
            "declared": {"name": name, "kind": "height", "offset": height},
            "Python": NumpyHeight(robot, name, height),
        }
    if name == "coffee":
        return {
            "built-in": "coffee_dot",
            "declared": {"name": name, "kind": "alignment", "axis": "x", "direction": (0.0, 0.0, 1.0)},
            "Python": NumpyUpright(robot, name),
        }
    (centre, radius) = task.keep_out_circle(name)  # type: ignore[misc]
    samples = params.get("samples", 4)
    offset = (*params.get("offset", (0.0, 0.0)), 0.0)
    return {
        "built-in": spec.feature(robot, task.scene),
        "declared": {
            "name": name, "kind": "distance", "object": params["keep_out"], "radius": radius,
            "offset": offset, "samples": samples,
        },
        "Python": NumpyKeepout(robot, name, centre, radius, samples),
    }  # fmt: skip


def optimizer(task: Task, robot: phri.Robot, item: Any) -> phri.TrajectoryOptimizer:
    items: list[Any] = [f.feature(robot, task.scene) for f in task.features]
    items[task.task_index] = item
    features = phri.Features(robot, items, scene=task.scene, frame=task.feature_frame)
    return phri.TrajectoryOptimizer(
        features, task.waypoints, duration=task.duration, speed_fraction=VELOCITY_MARGIN, knots=task.knots
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=15, help="cold plans per variant (default 15)")
    rounds = parser.parse_args().rounds
    robot = phri.Robot.jaco2()
    print(f"cold plans, N = 31, collision model on, {rounds} rounds; median [ms] and ratio to the built-in")
    for task_name in ("table", "coffee", "laptop"):
        task = load_task(task_name)
        weights, start, goal = task.vector("true"), task.start, task.goal
        items = variants(task, robot)
        optimizers = {label: optimizer(task, robot, item) for label, item in items.items()}
        times: dict[str, list[float]] = {label: [] for label in items}
        costs: dict[str, float] = {}
        for _ in range(rounds):
            for label, opt in optimizers.items():
                calls = getattr(items[label], "calls", 0)
                t0 = time.perf_counter()
                _, info = opt.solve(weights, start, goal)
                times[label].append(time.perf_counter() - t0)
                if not (info.converged and info.feasible):
                    raise SystemExit(f"{task_name} {label}: plan not converged or infeasible: {info}")
                costs[label] = info.cost
                if label == "Python":
                    items[label].per_plan = items[label].calls - calls
        base = statistics.median(times["built-in"])
        for label in items:
            median = statistics.median(times[label])
            extra = f", {items[label].per_plan} calls" if label == "Python" else ""
            print(
                f"{task_name:6s} {label:9s} {1e3 * median:7.2f} ms  {median / base:5.2f}x"
                f"  cost {costs[label]:.6g} ({costs[label] / costs['built-in'] - 1:+.1e}){extra}"
            )


if __name__ == "__main__":
    main()
