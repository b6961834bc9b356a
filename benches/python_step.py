"""Time the per-tick calls of a 1 kHz control loop written in Python: one impedance step (eq. 6 with
gravity compensation, and the implicit form the simulation uses), the learner's quiet tick (observe
between interactions) and its reference, the safety layer's two checks, each called from Python with
numpy arrays; and the control-thread part of a whole tick as phri.control.ControlLoop runs it
(check the state, observe without a replan, reference, implicit torque with the virtual wall, limit
the torque), whose budget is 50 µs at the 99.9th percentile (libfranka leaves about 300 µs per tick),
and the same tick while a person pushes, the learner's worker learning and replanning.

Each call is timed individually with perf_counter_ns over --calls calls on varied states (a new state
every call, the result written into a preallocated `out` where the API offers one); the median, the
99th and the 99.9th percentile are printed (the timer's own cost, about 0.1 µs, is included). The
garbage collector is frozen and disabled while timing, as the loop does.

Usage: python benches/python_step.py [--calls 100000]      (or `make bench-python`)
"""

from __future__ import annotations

import argparse
import gc
import time

import numpy as np

import phri
from phri.control import safety_limits

PLACE_LOWER = np.deg2rad([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
PICK_BASIC = np.deg2rad([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8])
#: A person's push [N·m], above the JACO2's detection thresholds on joints 1 and 3: it presses the
#: cup down (the table's weight rises; its negative lifts the cup).
PUSH = np.array([0.0, -12.0, 0.0, -6.0, 0.0, 0.0, 0.0])


def samples(call, states: list) -> np.ndarray:
    """The time of each call of `call(*state)` [ns]."""
    out = np.empty(len(states))
    for k, state in enumerate(states):
        began = time.perf_counter_ns()
        call(*state)
        out[k] = time.perf_counter_ns() - began
    return out


def timed(label: str, call, states: list) -> None:
    us = samples(call, states) / 1e3
    print(
        f"  {label:<44} median {np.median(us):6.2f} µs   p99 {np.percentile(us, 99):6.2f} µs"
        f"   p99.9 {np.percentile(us, 99.9):6.2f} µs"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=100_000)
    args = parser.parse_args()
    gc.collect()
    gc.freeze()
    gc.disable()
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
    # Every call at a new tick, 1 ms apart: a task long enough for all of them (a tick's work does not
    # depend on the task's length), and at least the study's 15 s.
    duration = max(15.0, args.calls * 1e-3 + 1.0)

    def make_learner(**kwargs) -> phri.Learner:
        return phri.Learner(
            features, phri.Deformation(), phri.WeightUpdate([0.0, 2.0], [1.0, 0.0], [1.0, 1.0]),
            phri.InteractionDetector(), phri.TrajectoryOptimizer(features, duration=duration), [1.0, 0.0],
            PICK_BASIC, PLACE_LOWER,
            duration=duration, sample_period=1e-3, **kwargs,
        )  # fmt: skip

    learner = make_learner()
    quiet = np.array([0.5, 1.0, 0.0, 0.3, 0.2, 0.1, 0.0])  # below every threshold
    ticks = [(k * 1e-3, quiet) for k in range(args.calls)]  # every tick a sample instant
    timed("Learner.observe, a quiet sampled tick", learner.observe, ticks)
    timed("Learner.reference", learner.reference, [(t,) for t, _ in ticks])

    # The safety layer of the table task (its tool box; the JACO2's joint limits).
    task = phri.load_task("table")
    limits = safety_limits(robot, "jaco2", task)
    safety = limits.layer(robot, period=1e-3, gravity_compensated=False)
    taus = [walled.torque_implicit(q[k], qd[k], PLACE_LOWER, np.zeros(7), 1e-3) for k in range(args.calls)]
    command = np.empty(7)
    # States the checks pass (a rare one of the random states puts the hand below the table).
    inside = []
    for k in range(args.calls):
        safety.reset()
        if safety.check_state(0.0, q[k], qd[k], quiet) is None:
            inside.append(k)
    clock = [(i * 1e-3, q[k], qd[k], quiet) for i, k in enumerate(inside)]
    safety.reset()
    timed("SafetyLayer.check_state", safety.check_state, clock)
    safety.reset()
    timed(
        "SafetyLayer.limit_torque",
        lambda q, tau: safety.limit_torque(q, tau, command),
        [(q[k], taus[k]) for k in inside],
    )

    # A whole control-thread tick, as ControlLoop._run makes it (the study's learner, sampling at
    # 1 kHz so every tick is a sample, nobody pushing: observe never replans).
    learner = make_learner()
    ref = (np.zeros(7), np.zeros(7), np.zeros(7))
    tau = np.zeros(7)
    safety.reset()
    observe, reference, torque = learner.observe, learner.reference, walled.torque_implicit
    check_state, limit_torque = safety.check_state, safety.limit_torque

    def tick(t: float, q: np.ndarray, qd: np.ndarray, tau_ext: np.ndarray) -> None:
        if check_state(t, q, qd, tau_ext) is not None:
            raise RuntimeError("the benchmark's states must pass the checks")
        observe(t, tau_ext)
        reference(t, out=ref)
        torque(q, qd, ref[0], ref[1], 1e-3, out=tau)
        if limit_torque(q, tau, command) is not None:
            raise RuntimeError("the benchmark's torques must be finite")

    timed("ControlLoop tick, control-thread part", tick, clock)

    # The same tick while a person pushes, with a learner as `phri run` makes it: the worker (wall
    # clock) learns from each push and replans while the ticks go on. A push on every 100th tick
    # (the study's 10 Hz samples of a push), pressing the cup down and lifting it in turn, so that
    # the table's weight moves at each push and each replan is a real one; the ticks run back to
    # back, so the worker is busy throughout.
    learner = make_learner(replan_latency=None)
    observe, reference = learner.observe, learner.reference
    safety.reset()
    pushed = [
        (t, q_k, qd_k, (PUSH if i % 200 == 0 else -PUSH) if i % 100 == 0 else quiet)
        for i, (t, q_k, qd_k, _) in enumerate(clock)
    ]
    us = samples(tick, pushed) / 1e3
    history = learner.history()
    # The pushed ticks that deformed the plan (not those too near the end of the task).
    push_us = us[::100][: len(history)][history.moved > 0]
    print(
        f"  {'the same, pushed every 100th tick':<44} median {np.median(us):6.2f} µs   p99 "
        f"{np.percentile(us, 99):6.2f} µs   p99.9 {np.percentile(us, 99.9):6.2f} µs"
    )
    print(
        f"  {'  the pushed ticks (the worker learns)':<44} median {np.median(push_us):6.2f} µs   p99 "
        f"{np.percentile(push_us, 99):6.2f} µs   ({len(push_us)} pushes deformed the plan, "
        f"{sum(u is not None for u in history.updates)} learned from, {len(history.plans) - 1} plans adopted)"
    )


if __name__ == "__main__":
    main()
