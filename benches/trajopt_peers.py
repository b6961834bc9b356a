"""Time phri's trajectory optimiser against the peers a Python user would reach for, on the same
problem, in one run: the study's planner (python/phri/sim/episode.py `Planner`) for each task.

The problem (eq. 4 as phri solves it): N waypoints, start and goal fixed, joint limits as bounds,
cost = w_eff·efficiency + w_task·task feature (the kinks Huber-smoothed with δ = 0.05) + the
clearance penalty ρ·Σ max(0, z_min − z)² of the tool point and link_7 at every interior waypoint
(ρ = 10³) + the max_step penalty 10³·Σ max(0, |Δq| − L)², L = 0.5 × velocity limit × spacing
(two thirds of it on the first and last segments). Collision checks are off: the peers have none.

Solvers, all from the same straight line, with the joint limits as bounds:

* phri: `phri.TrajectoryOptimizer` (projected Newton).
* scipy L-BFGS-B on `ReferenceObjective`, an independent numpy implementation of the same cost and
  gradient whose kinematics (poses and Jacobians of the sample points) come either from phri's
  batched `Robot.frame_pose`/`Robot.jacobian` ("scipy+phri-kin") or from pinocchio, one call per
  sample point in a Python loop ("scipy+pinocchio", the usual approach: ~33 ms for 20
  waypoints). tests/test_trajopt.py checks that `ReferenceObjective` equals phri's
  `TrajectoryOptimizer.objective` to 1e-9, so every solver minimises the same function. L-BFGS-B
  runs to convergence (ftol 1e-13, gtol 1e-9, 20 correction pairs).
* Drake (`pip install drake`) with IPOPT and SNOPT, if installed and enabled: `MathematicalProgram`
  with the same cost (value and gradient from `ReferenceObjective` with phri kinematics, passed as
  an autodiff cost) and a bounding box; IPOPT with a limited-memory Hessian, tol 1e-8.

Each number is the median wall time of `--repeat` solves (the final cost is printed alongside so a
fast wrong answer would show); ratios are against phri's Newton solve.

Usage: python benches/trajopt_peers.py [--repeat 5] [--tasks human,coffee,table,laptop]
       [--waypoints 31] [--json PATH]       (or `make bench-trajopt-peers`)
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
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import phri

HAND = "j2s7s300_end_effector"
LINK_7 = "j2s7s300_link_7"
#: As phri.sim.episode: the tool point and the cup stay this far above the table top [m].
HAND_CLEARANCE = 0.1016
CUP_CLEARANCE = 0.06
VELOCITY_MARGIN = 0.5
CLEARANCE_WEIGHT = 1e3
STEP_WEIGHT = 1e3
SMOOTHING = 0.05
TASKS = ("human", "coffee", "table", "laptop")


@dataclass(frozen=True)
class Problem:
    """One planning problem exactly as the study's planner poses it."""

    name: str
    names: tuple[str, ...]
    weights: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    waypoints: int
    clearance: tuple[tuple[str, float], ...]
    max_step: np.ndarray
    laptop_center: tuple[float, float]
    human_center: tuple[float, float]
    laptop_radius: float
    human_radius: float
    samples: int
    lower: np.ndarray
    upper: np.ndarray
    smoothing: float = SMOOTHING


def study_features(names: list[str] | tuple[str, ...]) -> list:
    """Items of phri.Features for `names`, each feature as the shipped tasks define it (the keep-out
    features as the laptop and human tasks place them in STUDY_SCENE)."""
    specs = {f.name: f.feature() for t in ("laptop", "human") for f in phri.load_task(t).features}
    return [specs.get(n, n) for n in names]


#: The study's scene (the same in every shipped task).
STUDY_SCENE = phri.load_task("laptop").scene


def study_problem(name: str, waypoints: int | None = None, weights: np.ndarray | None = None) -> Problem:
    """The task's planning problem with its true weights (or `weights`), as phri.sim.Planner sets it up."""
    task = phri.load_task(name)
    robot = phri.Robot.jaco2()
    n = task.waypoints if waypoints is None else waypoints
    top = task.scene["table"].top
    (laptop_center, laptop_radius), (human_center, human_radius) = (
        phri.load_task(t).keep_out_circle(t) for t in ("laptop", "human")
    )
    spacing = task.duration / (n - 1)
    return Problem(
        name=name,
        names=tuple(task.feature_names),
        weights=task.vector("true") if weights is None else np.asarray(weights, dtype=float),
        start=task.start,
        goal=task.goal,
        waypoints=n,
        clearance=((HAND, top + HAND_CLEARANCE), (LINK_7, top + CUP_CLEARANCE)),
        max_step=VELOCITY_MARGIN * robot.velocity_limits * spacing,
        laptop_center=laptop_center,
        human_center=human_center,
        laptop_radius=laptop_radius,
        human_radius=human_radius,
        samples=study_features(["laptop"])[0]["samples"],
        lower=robot.lower_limits,
        upper=robot.upper_limits,
    )


def phri_optimizer(problem: Problem, **kwargs) -> phri.TrajectoryOptimizer:
    """phri's optimiser for the problem (keyword arguments override the defaults, e.g. coarsening)."""
    robot = phri.Robot.jaco2()
    features = phri.Features(robot, study_features(problem.names), scene=STUDY_SCENE)
    options = {
        "collisions": False,  # the peers' problem (ReferenceObjective) has no collision term
        "clearance_weight": CLEARANCE_WEIGHT,
        "step_weight": STEP_WEIGHT,
        "smoothing": problem.smoothing,
        **kwargs,
    }
    return phri.TrajectoryOptimizer(
        features, problem.waypoints, clearance=list(problem.clearance), max_step=problem.max_step, **options
    )


def straight_line(problem: Problem) -> np.ndarray:
    s = np.linspace(0.0, 1.0, problem.waypoints)[:, None]
    return problem.start + s * (problem.goal - problem.start)


# --------------------------------------------------------------------------------------------------
# kinematics backends: poses and Jacobians of a frame at many configurations


class PhriKinematics:
    """phri's batched calls: one (M, 7) call for the poses, one for the Jacobians."""

    name = "phri-kin"

    def __init__(self) -> None:
        self.robot = phri.Robot.jaco2()

    def __call__(self, frame: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pose = self.robot.frame_pose(frame, q)
        return pose[:, :3, 3], pose[:, :3, :3], self.robot.jacobian(frame, q)


class PinocchioKinematics:
    """pinocchio, one configuration per call (no batch API): computeFrameJacobian (world-aligned)
    then data.oMf. Continuous joints use pinocchio's (cos θ, sin θ) encoding."""

    name = "pinocchio"

    def __init__(self) -> None:
        import pinocchio as pin

        self.pin = pin
        path = Path(str(importlib.resources.files("phri").joinpath("robots/jaco2/j2s7s300.urdf")))
        self.model = pin.buildModelFromUrdf(str(path))
        self.data = self.model.createData()
        self.unbounded = [j.nq == 2 for j in self.model.joints[1:]]
        self.frames = {f: self.model.getFrameId(f) for f in (HAND, LINK_7)}

    def __call__(self, frame: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pin, fid = self.pin, self.frames[frame]
        m = q.shape[0]
        p, r, jac = np.empty((m, 3)), np.empty((m, 3, 3)), np.empty((m, 6, 7))
        for i in range(m):
            parts = [
                [np.cos(x), np.sin(x)] if ub else [x] for ub, x in zip(self.unbounded, q[i], strict=True)
            ]
            qp = np.concatenate(parts)
            jac[i] = pin.computeFrameJacobian(self.model, self.data, qp, fid, pin.LOCAL_WORLD_ALIGNED)
            pose = self.data.oMf[fid]
            p[i], r[i] = pose.translation, pose.rotation
        return p, r, jac


# --------------------------------------------------------------------------------------------------
# the cost in numpy


def huber(x: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """Huber smoothing of |x| (phri.features::huber): value and derivative."""
    a = np.abs(x)
    if delta == 0.0:
        return a, np.sign(x)
    lin = a >= delta
    return np.where(lin, a - 0.5 * delta, 0.5 * x * x / delta), np.where(lin, np.sign(x), x / delta)


def smooth_hinge(x: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """Huber-smoothed max(0, x) (phri.features::smooth_hinge): value and slope."""
    if delta == 0.0:
        return np.maximum(x, 0.0), (x > 0.0).astype(float)
    value = np.where(x <= 0.0, 0.0, np.where(x >= delta, x - 0.5 * delta, 0.5 * x * x / delta))
    slope = np.where(x <= 0.0, 0.0, np.where(x >= delta, 1.0, x / delta))
    return value, slope


class ReferenceObjective:
    """The cost phri's optimiser minimises, written out in numpy from poses and Jacobians only.

    Features are summed over segments (q_{i-1}, q_i], i = 1..N-1; the keep-out features sample
    `samples` points q_{i-1} + s·(q_i − q_{i-1}), s = k/samples (the last one is q_i itself)."""

    def __init__(self, problem: Problem, kinematics: Callable | None = None) -> None:
        self.p = problem
        self.kin = kinematics or PhriKinematics()
        self.evaluations = 0
        known = {"efficiency", "table", "coffee", "laptop", "human"}
        if not set(problem.names) <= known:
            raise NotImplementedError(f"reference features {sorted(known)}, got {problem.names}")

    def full(self, xi: np.ndarray) -> tuple[float, float, np.ndarray]:
        """(cost, penalty, gradient (N, 7)) at a full trajectory."""
        self.evaluations += 1
        p, d = self.p, self.p.smoothing
        xi = np.asarray(xi, dtype=float)
        n_wp = xi.shape[0]
        grad = np.zeros_like(xi)
        cost = 0.0
        seg = xi[1:] - xi[:-1]
        ends = None  # link_7 kinematics at waypoints 1..N-1
        for name, w in zip(p.names, p.weights, strict=True):
            if w == 0.0:
                continue
            if name == "efficiency":
                cost += w * float(np.sum(seg * seg))
                grad[1:] += 2.0 * w * seg
                grad[:-1] -= 2.0 * w * seg
                continue
            if name in ("table", "coffee"):
                if ends is None:
                    ends = self.kin(LINK_7, xi[1:])
                pos, rot, jac = ends
                if name == "table":
                    cost += w * float(np.sum(pos[:, 2]))
                    grad[1:] += w * jac[:, 2, :]
                else:
                    x = rot[:, :, 0]
                    (a, da), (b, db) = huber(x[:, 0], d), huber(x[:, 1], d)
                    cost += w * float(np.sum(a + b))
                    dx = np.cross(jac[:, 3:6, :], x[:, :, None], axis=1)  # ∂x/∂q_j = ω_j × x
                    grad[1:] += w * (da[:, None] * dx[:, 0, :] + db[:, None] * dx[:, 1, :])
                continue
            center = np.asarray(p.laptop_center if name == "laptop" else p.human_center)
            radius = p.laptop_radius if name == "laptop" else p.human_radius
            for k in range(1, p.samples + 1):
                s = k / p.samples
                q = xi[1:] if k == p.samples else xi[:-1] + s * seg
                pos, _, jac = self.kin(LINK_7, q)
                dvec = pos[:, :2] - center
                dist = np.linalg.norm(dvec, axis=1)
                inside = dist < radius
                value, slope = smooth_hinge(np.where(inside, radius - dist, 0.0), d)
                cost += w * float(np.sum(value))
                u = dvec / np.where(dist > 0.0, dist, 1.0)[:, None]
                g = -(u[:, 0, None] * jac[:, 0, :] + u[:, 1, None] * jac[:, 1, :]) * (w * slope)[:, None]
                grad[1:] += s * g
                grad[:-1] += (1.0 - s) * g
        penalty = 0.0
        interior = xi[1 : n_wp - 1]
        for frame, min_z in p.clearance:
            pos, _, jac = self.kin(frame, interior)
            gap = np.maximum(min_z - pos[:, 2], 0.0)
            penalty += CLEARANCE_WEIGHT * float(np.sum(gap * gap))
            grad[1 : n_wp - 1] -= 2.0 * CLEARANCE_WEIGHT * gap[:, None] * jac[:, 2, :]
        # Two thirds of max_step on the first and last segments, where the executed cubic starts
        # or ends at rest (phri_core::trajopt::cost::segment_step).
        limit = np.tile(p.max_step, (n_wp - 1, 1))
        limit[[0, -1]] *= 2.0 / 3.0
        excess = np.maximum(np.abs(seg) - limit, 0.0)
        penalty += STEP_WEIGHT * float(np.sum(excess * excess))
        g = 2.0 * STEP_WEIGHT * excess * np.sign(seg)
        grad[1:] += g
        grad[:-1] -= g
        return cost + penalty, penalty, grad

    def interior(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """Cost and gradient of the interior waypoints (flat), start and goal fixed: scipy's form."""
        xi = np.vstack([self.p.start, x.reshape(-1, 7), self.p.goal])
        cost, _, grad = self.full(xi)
        return cost, grad[1:-1].ravel()

    def bounds(self) -> list[tuple[float | None, float | None]]:
        one = [
            (float(lo) if np.isfinite(lo) else None, float(hi) if np.isfinite(hi) else None)
            for lo, hi in zip(self.p.lower, self.p.upper, strict=True)
        ]
        return one * (self.p.waypoints - 2)


# --------------------------------------------------------------------------------------------------
# solvers: each returns (plan (N, 7), final cost, evaluations)


def solve_phri(problem: Problem) -> Callable[[], tuple[np.ndarray, float, int]]:
    opt = phri_optimizer(problem)

    def run() -> tuple[np.ndarray, float, int]:
        plan, info = opt.solve(problem.weights, problem.start, problem.goal)
        return plan, info.cost, info.evaluations

    return run


def solve_scipy(
    problem: Problem, kinematics: Callable | None = None
) -> Callable[[], tuple[np.ndarray, float, int]]:
    from scipy.optimize import minimize

    objective = ReferenceObjective(problem, kinematics)
    x0 = straight_line(problem)[1:-1].ravel()
    bounds = objective.bounds()

    def run() -> tuple[np.ndarray, float, int]:
        res = minimize(
            objective.interior, x0, jac=True, method="L-BFGS-B", bounds=bounds,
            options={"maxiter": 100_000, "maxfun": 1_000_000, "ftol": 1e-13, "gtol": 1e-9, "maxcor": 20},
        )  # fmt: skip
        plan = np.vstack([problem.start, res.x.reshape(-1, 7), problem.goal])
        return plan, float(res.fun), int(res.nfev)

    return run


def drake_solvers() -> dict[str, object]:
    """Drake's IPOPT and SNOPT solvers that are available and enabled here (empty without Drake)."""
    try:
        from pydrake.solvers import IpoptSolver, SnoptSolver
    except ImportError:
        return {}
    found = {}
    for name, cls in (("ipopt", IpoptSolver), ("snopt", SnoptSolver)):
        solver = cls()
        if solver.available() and solver.enabled():
            found[name] = solver
    return found


def solve_drake(problem: Problem, solver_name: str, solver) -> Callable[[], tuple[np.ndarray, float, int]]:
    from pydrake.autodiffutils import AutoDiffXd, ExtractGradient, ExtractValue
    from pydrake.solvers import MathematicalProgram, SolverOptions

    objective = ReferenceObjective(problem)
    x0 = straight_line(problem)[1:-1].ravel()
    lo = np.tile(np.where(np.isfinite(problem.lower), problem.lower, -np.inf), problem.waypoints - 2)
    hi = np.tile(np.where(np.isfinite(problem.upper), problem.upper, np.inf), problem.waypoints - 2)

    def cost(z):
        if z.dtype == float:
            return objective.interior(z)[0]
        value = ExtractValue(z).ravel()
        f, g = objective.interior(value)
        return AutoDiffXd(f, g @ ExtractGradient(z))

    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(x0.size, "x")
    prog.AddBoundingBoxConstraint(lo, hi, x)
    prog.AddCost(cost, vars=x)
    options = SolverOptions()
    if solver_name == "ipopt":
        options.SetOption(solver.solver_id(), "hessian_approximation", "limited-memory")
        options.SetOption(solver.solver_id(), "tol", 1e-8)
        options.SetOption(solver.solver_id(), "max_iter", 5000)
        options.SetOption(solver.solver_id(), "print_level", 0)
    else:
        options.SetOption(solver.solver_id(), "Major optimality tolerance", 1e-8)
        options.SetOption(solver.solver_id(), "Major iterations limit", 5000)

    def run() -> tuple[np.ndarray, float, int]:
        before = objective.evaluations
        result = solver.Solve(prog, x0, options)
        xs = result.GetSolution(x)
        plan = np.vstack([problem.start, xs.reshape(-1, 7), problem.goal])
        return plan, float(objective.full(plan)[0]), objective.evaluations - before - 1

    return run


# --------------------------------------------------------------------------------------------------


def time_solver(run: Callable[[], tuple[np.ndarray, float, int]], repeat: int) -> dict[str, float]:
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - t0)
    assert result is not None
    _, cost, evaluations = result
    return {"median_ms": 1e3 * statistics.median(times), "min_ms": 1e3 * min(times), "cost": cost,
            "evaluations": evaluations}  # fmt: skip


def versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "machine": platform.machine(), "cpus": str(os.cpu_count())}
    for dist in ("phri", "numpy", "scipy", "pin", "drake"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="solves per solver and task (median reported)")
    ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    ap.add_argument("--waypoints", type=int, default=31, help="waypoints N")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args(argv)

    info = versions()
    print("trajectory optimisation peers: " + ", ".join(f"{k} {v}" for k, v in info.items()))
    try:
        import pinocchio  # noqa: F401

        have_pin = True
    except ImportError:
        have_pin = False
        print("pinocchio not installed: skipping scipy+pinocchio (pip install 'pin>=3')")
    solvers = drake_solvers()
    if not solvers:
        try:
            import pydrake  # noqa: F401

            print("drake installed, but neither IPOPT nor SNOPT is available and enabled: skipping Drake")
        except ImportError:
            print("drake not installed: skipping Drake (pip install drake)")
    elif "snopt" not in solvers:
        print("drake: SNOPT not available or not enabled in this build; IPOPT only")

    rows: list[dict[str, object]] = []
    header = f"{'task':<7} {'solver':<18} {'median ms':>10} {'× phri':>8} {'final cost':>14} {'evals':>7}"
    print(f"\nN = {args.waypoints} waypoints, {args.repeat} solves each, from the straight line\n")
    print(header)
    print("-" * len(header))
    for name in args.tasks.split(","):
        problem = study_problem(name, args.waypoints)
        runs: list[tuple[str, Callable]] = [
            ("phri newton", solve_phri(problem)),
            ("scipy+phri-kin", solve_scipy(problem)),
        ]
        if have_pin:
            runs.append(("scipy+pinocchio", solve_scipy(problem, PinocchioKinematics())))
        for solver_name, solver in solvers.items():
            runs.append((f"drake {solver_name}", solve_drake(problem, solver_name, solver)))
        base = None
        for label, run in runs:
            # Peers that take seconds per solve get at most 3 repeats.
            repeat = args.repeat if label.startswith("phri") else min(args.repeat, 3)
            r = time_solver(run, repeat)
            base = base or r["median_ms"]
            ratio = r["median_ms"] / base
            ms, cost, evals = r["median_ms"], r["cost"], r["evaluations"]
            print(f"{name:<7} {label:<18} {ms:>10.2f} {ratio:>8.1f} {cost:>14.8f} {evals:>7}")
            rows.append({"task": name, "solver": label, "waypoints": args.waypoints, "repeat": repeat, **r,
                         "ratio_to_phri": ratio})  # fmt: skip
        print()
    if args.json:
        args.json.write_text(json.dumps({"versions": info, "results": rows}, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
