"""Time the per-tick calls of a 1 kHz control loop written in Python: one impedance step (eq. 6 with
gravity compensation, and the implicit form the simulation uses), the learner's quiet tick (observe
between interactions) and its reference, each called from Python with numpy arrays.

Each call is timed individually with perf_counter_ns over --calls calls on varied states (a new state
every call, the result written into a preallocated `out` where the API offers one); the median and the
99th percentile are printed (the timer's own cost, about 0.1 µs, is included).

Usage: python benches/python_step.py [--calls 100000]      (or `make bench-python`)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import phri

PLACE_LOWER = np.deg2rad([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
PICK_BASIC = np.deg2rad([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8])


def timed(label: str, call, states: list) -> None:
    samples = np.empty(len(states))
    for k, state in enumerate(states):
        began = time.perf_counter_ns()
        call(*state)
        samples[k] = time.perf_counter_ns() - began
    us = samples / 1e3
    print(f"  {label:<44} median {np.median(us):6.2f} µs   p99 {np.percentile(us, 99):6.2f} µs")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=100_000)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    robot = phri.Robot.jaco2()
    controller = phri.ImpedanceController(robot)
    out = np.empty(7)
    q = PLACE_LOWER + rng.normal(scale=0.05, size=(args.calls, 7))
    qd = rng.normal(scale=0.2, size=(args.calls, 7))
    states = [(q[k], qd[k], PLACE_LOWER, np.zeros(7)) for k in range(args.calls)]
    print(f"per call from Python, {args.calls} calls each")
    timed("ImpedanceController.torque(out=)", lambda *s: controller.torque(*s, out=out), states)
    timed(
        "ImpedanceController.torque_implicit(out=)",
        lambda *s: controller.torque_implicit(*s, 1e-3, out=out),
        states,
    )
    walled = phri.ImpedanceController(robot, scene=phri.load_task("table").scene)
    timed(
        "the same with the virtual wall (table scene)",
        lambda *s: walled.torque_implicit(*s, 1e-3, out=out),
        states,
    )
    features = phri.Features(robot, ["efficiency", "table"])
    learner = phri.Learner(
        features, phri.Deformation(), phri.WeightUpdate([0.0, 2.0], [1.0, 0.0], [1.0, 1.0]),
        phri.InteractionDetector(), phri.TrajectoryOptimizer(features, duration=15.0), [1.0, 0.0],
        PICK_BASIC, PLACE_LOWER,
        sample_period=1e-3,
    )  # fmt: skip
    quiet = np.array([0.5, 1.0, 0.0, 0.3, 0.2, 0.1, 0.0])  # below every threshold
    ticks = [(k * 1e-3, quiet) for k in range(args.calls)]  # every tick a sample instant
    timed("Learner.observe, a quiet sampled tick", learner.observe, ticks)
    timed("Learner.reference", learner.reference, [(t,) for t, _ in ticks])


if __name__ == "__main__":
    main()
