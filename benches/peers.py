"""Time phri against pinocchio and PyBullet on the same URDF (the shipped JACO2), in one run.

For each operation — pose + Jacobian of link_7, gravity torques, mass matrix, inverse dynamics — two
modes are timed from Python:

* per call: one configuration per call (what a control loop written in Python pays);
* batch of 1000: phri's batched (1000, 7) call vs a Python loop for the peers (neither pinocchio nor
  PyBullet has a batch API for these).

Before timing, the three are checked to agree numerically on a few configurations (so this never
times wrong answers). Inputs are converted to each library's native form *outside* the timed region
(pinocchio's (cos θ, sin θ) encoding of continuous joints, Python lists for PyBullet). Each number is
the median over `--repeat` timeit repeats of the mean time per call (per batch for the batch mode); the
repeats of the three libraries are interleaved so that a busy spell of a shared machine hits all alike.

What each library does per "pose + Jacobian": phri `frame_pose` + `jacobian` (two calls, each runs
forward kinematics); pinocchio `computeFrameJacobian` (LOCAL_WORLD_ALIGNED, runs forward kinematics
and updates `data.oMf`) + `oMf[frame].homogeneous`; PyBullet `resetJointStatesMultiDof` (its link
state is stateful) + `getLinkState(computeForwardKinematics=True)` + `calculateJacobian`.

Usage: python benches/peers.py [--repeat 7] [--json PATH]   (or `make bench-peers`)
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.resources
import json
import os
import platform
import statistics
import sys
import timeit
from collections.abc import Callable
from pathlib import Path

import numpy as np

import phri

FRAME = "j2s7s300_link_7"
BATCH = 1000
CHECK_CONFIGS = 8
ATOL = 1e-9  # double vs double on the same URDF (observed ~1e-14)
SEED = 20171113


def urdf_path() -> Path:
    return Path(str(importlib.resources.files("phri").joinpath("robots/jaco2/j2s7s300.urdf")))


def random_configurations(robot: phri.Robot, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 7) configurations within the limits; continuous joints uniform in [0, 2π)."""
    lo, hi = robot.lower_limits, robot.upper_limits
    limited = np.isfinite(lo)
    lo = np.where(limited, lo, 0.0)
    hi = np.where(limited, hi, 2 * np.pi)
    return lo + (hi - lo) * rng.random((n, robot.nq))


def quat_to_matrix(quat) -> np.ndarray:
    x, y, z, w = quat
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------------------------------
# the three libraries behind one interface: each returns callables on pre-converted inputs


class Phri:
    name = "phri"

    def __init__(self) -> None:
        self.robot = phri.Robot.jaco2()

    def convert(self, q: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(q, dtype=np.float64)

    def pose_jacobian(self, q):
        return self.robot.frame_pose(FRAME, q), self.robot.jacobian(FRAME, q)

    def gravity(self, q):
        return self.robot.gravity(q)

    def mass_matrix(self, q):
        return self.robot.mass_matrix(q)

    def inverse_dynamics(self, q, qd, qdd):
        return self.robot.inverse_dynamics(q, qd, qdd)


class Pinocchio:
    """Fixed base (no root joint): continuous joints are RUBZ joints with nq = 2 (cos θ, sin θ)."""

    name = "pinocchio"

    def __init__(self) -> None:
        import pinocchio as pin

        self.pin = pin
        self.model = pin.buildModelFromUrdf(str(urdf_path()))
        self.data = self.model.createData()
        assert self.model.nv == 7, self.model
        self.frame = self.model.getFrameId(FRAME)
        self.unbounded = [j.nq == 2 for j in self.model.joints[1:]]  # joints[0] is the universe

    def convert(self, q: np.ndarray) -> np.ndarray:
        parts = [[np.cos(x), np.sin(x)] if ub else [x] for ub, x in zip(self.unbounded, q, strict=True)]
        return np.concatenate(parts)

    def pose_jacobian(self, q):
        # computeFrameJacobian runs forward kinematics and updates data.oMf[frame] on the way.
        jac = self.pin.computeFrameJacobian(
            self.model, self.data, q, self.frame, self.pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        return self.data.oMf[self.frame].homogeneous, jac

    def gravity(self, q):
        return self.pin.computeGeneralizedGravity(self.model, self.data, q)

    def mass_matrix(self, q):
        return self.pin.crba(self.model, self.data, q)

    def inverse_dynamics(self, q, qd, qdd):
        return self.pin.rnea(self.model, self.data, q, qd, qdd)


class PyBullet:
    """DIRECT client, fixed base, inertia from the file, gravity −9.81 z. Poses need the joint state set
    (one resetJointStatesMultiDof call); Jacobian and dynamics take q directly."""

    name = "pybullet"

    def __init__(self) -> None:
        import pybullet as p

        self.p = p
        self.client = p.connect(p.DIRECT)
        self.body = p.loadURDF(
            str(urdf_path()),
            useFixedBase=True,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=self.client,
        )
        p.setGravity(0, 0, -9.81, physicsClientId=self.client)
        self.joints, self.link = [], None
        for j in range(p.getNumJoints(self.body, physicsClientId=self.client)):
            info = p.getJointInfo(self.body, j, physicsClientId=self.client)
            if info[2] != p.JOINT_FIXED:
                self.joints.append(j)
            if info[12].decode() == FRAME:
                self.link = j
        assert len(self.joints) == 7 and self.link is not None
        # calculateJacobian's localPosition: the point relative to the URDF link origin in the inertial
        # frame's axes (bullet3 issue #4668), so the link origin itself is (0, 0, 0).
        self.origin = [0.0, 0.0, 0.0]
        self.zeros = [0.0] * 7

    def close(self) -> None:
        self.p.disconnect(physicsClientId=self.client)

    def convert(self, q: np.ndarray) -> list[float]:
        return [float(x) for x in q]

    def pose_jacobian(self, q):
        p, c, b = self.p, self.client, self.body
        p.resetJointStatesMultiDof(b, self.joints, [[x] for x in q], physicsClientId=c)
        state = p.getLinkState(b, self.link, computeForwardKinematics=True, physicsClientId=c)
        jac = p.calculateJacobian(b, self.link, self.origin, q, self.zeros, self.zeros, physicsClientId=c)
        return state, jac

    def gravity(self, q):
        return self.p.calculateInverseDynamics(
            self.body, q, self.zeros, self.zeros, physicsClientId=self.client
        )

    def mass_matrix(self, q):
        return self.p.calculateMassMatrix(self.body, q, physicsClientId=self.client)

    def inverse_dynamics(self, q, qd, qdd):
        return self.p.calculateInverseDynamics(self.body, q, qd, qdd, physicsClientId=self.client)

    @staticmethod
    def pose_from_state(state) -> np.ndarray:
        """URDF link frame from the double-precision COM frame (fields 0, 1) and the local inertial frame
        (2, 3); fields 4, 5 hold the same pose rounded to float32."""
        r_com, r_in = quat_to_matrix(state[1]), quat_to_matrix(state[3])
        r = r_com @ r_in.T
        t = np.eye(4)
        t[:3, :3] = r
        t[:3, 3] = np.array(state[0]) - r @ np.array(state[2])
        return t


# --------------------------------------------------------------------------------------------------


def check_agreement(ph: Phri, pn: Pinocchio, pb: PyBullet, qs, qds, qdds) -> float:
    """Raises SystemExit naming the quantity and configuration if any two libraries disagree."""
    worst = 0.0

    def same(what: str, q: np.ndarray, a, b, c) -> None:
        nonlocal worst
        a, b, c = (np.asarray(x, dtype=float) for x in (a, b, c))
        err = max(np.abs(a - b).max(), np.abs(a - c).max())
        worst = max(worst, err)
        if not err <= ATOL:
            sys.exit(f"peers disagree on {what} at q={q.tolist()}: max |error| {err:.3e} > {ATOL:.0e}")

    for q, qd, qdd in zip(qs, qds, qdds, strict=True):
        x, y, z = ph.convert(q), pn.convert(q), pb.convert(q)
        (pose_a, jac_a), (pose_b, jac_b), (state, jac_c) = (
            ph.pose_jacobian(x),
            pn.pose_jacobian(y),
            pb.pose_jacobian(z),
        )
        same("link_7 pose", q, pose_a, pose_b, PyBullet.pose_from_state(state))
        same("link_7 Jacobian", q, jac_a, jac_b, np.vstack([np.array(jac_c[0]), np.array(jac_c[1])]))
        same("gravity torques", q, ph.gravity(x), pn.gravity(y), pb.gravity(z))
        same("mass matrix", q, ph.mass_matrix(x), pn.mass_matrix(y), pb.mass_matrix(z))
        same(
            "inverse dynamics",
            q,
            ph.inverse_dynamics(x, qd, qdd),
            pn.inverse_dynamics(y, qd, qdd),
            pb.inverse_dynamics(z, qd.tolist(), qdd.tolist()),
        )
    # phri's batched calls equal its single calls (what the batch timings rely on)
    for name, call in [("gravity", ph.gravity), ("mass_matrix", ph.mass_matrix)]:
        if not np.array_equal(call(qs), np.stack([call(q) for q in qs])):
            sys.exit(f"phri batched {name} differs from stacked single calls")
    return worst


def median_times(
    fns: dict[str, Callable[[], object]], repeat: int, min_seconds: float = 0.1
) -> dict[str, float]:
    """Median over `repeat` repeats of the mean seconds per call of each function. The repeats of the
    libraries are interleaved, so a slow spell of a shared machine hits them alike."""
    timers, numbers = {}, {}
    for name, fn in fns.items():
        timer, number = timeit.Timer(fn), 1
        while timer.timeit(number) < min_seconds:  # like Timer.autorange, to `min_seconds` per repeat
            number *= 2 if number < 8 else 4
        timers[name], numbers[name] = timer, number
    samples: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeat):
        for name, timer in timers.items():
            samples[name].append(timer.timeit(numbers[name]) / numbers[name])
    return {name: statistics.median(times) for name, times in samples.items()}


def time_operation(op: str, mode: str, fns: dict[str, Callable[[], object]], repeat: int) -> dict:
    """One table row: median µs per call of every library's function."""
    times = median_times(fns, repeat)
    return {"operation": op, "mode": mode, "unit": "us", **{name: t * 1e6 for name, t in times.items()}}


COLUMNS = [  # (title, key, format)
    ("operation", "operation", "<26"),
    ("mode", "mode", "<14"),
    ("phri", "phri", ">11.2f"),
    ("pinocchio", "pinocchio", ">11.2f"),
    ("pybullet", "pybullet", ">11.2f"),
    ("pin/phri", "pinocchio/phri", ">9.2f"),
    ("pb/phri", "pybullet/phri", ">9.2f"),
]


def print_table(rows: list[dict], repeat: int) -> None:
    print(f"\nmedian of {repeat} repeats, µs per call (per call) or per whole batch (batch of {BATCH})")
    header = " ".join(f"{title:{fmt[0]}{fmt[1:].split('.')[0]}}" for title, _, fmt in COLUMNS)
    print(header)
    print("-" * len(header))
    for row in rows:
        print(" ".join(f"{row[key]:{fmt}}" for _, key, fmt in COLUMNS))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="timeit repeats; the median is reported")
    parser.add_argument("--json", type=Path, help="also write the results as JSON to this path")
    args = parser.parse_args(argv)

    ph, pn, pb = Phri(), Pinocchio(), PyBullet()
    rng = np.random.default_rng(SEED)
    qs = random_configurations(ph.robot, rng, BATCH)
    qds = rng.uniform(-1.0, 1.0, qs.shape)
    qdds = rng.uniform(-5.0, 5.0, qs.shape)
    worst = check_agreement(ph, pn, pb, qs[:CHECK_CONFIGS], qds[:CHECK_CONFIGS], qdds[:CHECK_CONFIGS])
    print(f"agreement on {CHECK_CONFIGS} configurations: worst |difference| {worst:.1e} (limit {ATOL:.0e})")

    libs = [ph, pn, pb]
    # pre-converted inputs: qs_native[lib][k]; velocities and accelerations are plain 7-vectors
    native = {lib.name: [lib.convert(q) for q in qs] for lib in libs}
    native_rates = {
        lib.name: (
            [qd.tolist() for qd in qds] if lib is pb else list(qds),
            [qdd.tolist() for qdd in qdds] if lib is pb else list(qdds),
        )
        for lib in libs
    }

    operations: list[tuple[str, Callable]] = [
        ("pose + Jacobian (link_7)", lambda lib, k: lib.pose_jacobian(native[lib.name][k])),
        ("gravity torques", lambda lib, k: lib.gravity(native[lib.name][k])),
        ("mass matrix", lambda lib, k: lib.mass_matrix(native[lib.name][k])),
        (
            "inverse dynamics",
            lambda lib, k: lib.inverse_dynamics(
                native[lib.name][k], native_rates[lib.name][0][k], native_rates[lib.name][1][k]
            ),
        ),
    ]
    phri_batch = {
        "pose + Jacobian (link_7)": lambda: ph.pose_jacobian(qs),
        "gravity torques": lambda: ph.gravity(qs),
        "mass matrix": lambda: ph.mass_matrix(qs),
        "inverse dynamics": lambda: ph.inverse_dynamics(qs, qds, qdds),
    }

    rows = []
    for op, call in operations:
        single = {lib.name: (lambda lib=lib, call=call: call(lib, 0)) for lib in libs}
        rows.append(time_operation(op, "per call", single, args.repeat))
        loops = {lib.name: (lambda lib=lib, call=call: [call(lib, k) for k in range(BATCH)]) for lib in libs}
        loops["phri"] = phri_batch[op]  # one (1000, 7) call, not a loop
        rows.append(time_operation(op, f"batch of {BATCH}", loops, args.repeat))
    pb.close()
    for row in rows:
        row["pinocchio/phri"] = row["pinocchio"] / row["phri"]
        row["pybullet/phri"] = row["pybullet"] / row["phri"]
    print_table(rows, args.repeat)

    if args.json:
        meta = {
            "python": sys.version.split()[0],
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "versions": {
                name: importlib.metadata.version(dist)
                for name, dist in [
                    ("phri", "phri"),
                    ("pinocchio", "pin"),
                    ("pybullet", "pybullet"),
                    ("numpy", "numpy"),
                ]
            },
            "repeat": args.repeat,
            "batch": BATCH,
            "statistic": "median over repeats of mean time per call (us)",
            "agreement_worst_abs_difference": worst,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
