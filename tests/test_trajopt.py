"""phri.TrajectoryOptimizer on the study's four tasks: plans that do the task and keep the constraints,
no worse than scipy's L-BFGS-B on the same objective, determinism, warm starts, typed errors, and the
GIL released while it runs.

The objective. `benches/trajopt_peers.py` defines `ReferenceObjective`, an independent numpy
implementation of the cost phri minimises — w·Φ(ξ) with the kinks Huber-smoothed (δ = 0.05), plus the
clearance penalty of the tool point and link_7 and the max_step penalty — built only from
phri.Robot.frame_pose/jacobian. The first tests check that it equals `TrajectoryOptimizer.objective`
(cost and gradient) and, with δ = 0 and no penalties, `Features.weighted_cost`. The comparison with
scipy then runs L-BFGS-B to convergence on that numpy objective from the same straight line, with the
joint limits as bounds, and compares the final costs of the same function.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from conftest import load_bench

import phri
from phri import exceptions as ex

TASKS = ("human", "coffee", "table", "laptop")
#: Violation of the clearance allowed by the quadratic penalty (phri_core::trajopt docs) [m].
CLEARANCE_TOL = 1e-3


peers = load_bench("trajopt_peers")


@pytest.fixture(scope="module")
def robot() -> phri.Robot:
    return phri.Robot.jaco2()


@pytest.fixture(scope="module")
def solved():
    """Per task: (problem, optimiser, plan for the true weights, its info, plan for task weight 0)."""
    out = {}
    for name in TASKS:
        problem = peers.study_problem(name)
        opt = peers.phri_optimizer(problem)
        plan, info = opt.solve(problem.weights, problem.start, problem.goal)
        zero = problem.weights.copy()
        zero[1:] = 0.0
        plan0, info0 = opt.solve(zero, problem.start, problem.goal)
        out[name] = (problem, opt, plan, info, plan0, info0)
    return out


def _trajectory(problem, rng: np.random.Generator, scale: float = 0.05) -> np.ndarray:
    xi = peers.straight_line(problem) + scale * rng.standard_normal((problem.waypoints, 7))
    xi[0], xi[-1] = problem.start, problem.goal
    return xi


@pytest.mark.parametrize("name", TASKS)
def test_the_reference_objective_is_the_one_phri_minimises(name, solved) -> None:
    problem, opt, plan, *_ = solved[name]
    ref = peers.ReferenceObjective(problem)
    rng = np.random.default_rng(4)
    for xi in (peers.straight_line(problem), plan, _trajectory(problem, rng), _trajectory(problem, rng, 0.3)):
        cost, penalty, grad = opt.objective(xi, problem.weights)
        r_cost, r_penalty, r_grad = ref.full(xi)
        assert abs(cost - r_cost) <= 1e-9 * max(1.0, abs(cost))
        assert abs(penalty - r_penalty) <= 1e-9 * max(1.0, abs(penalty))
        np.testing.assert_allclose(grad, r_grad, rtol=1e-9, atol=1e-9)


def test_without_smoothing_and_penalties_the_objective_is_features_weighted_cost(robot) -> None:
    names = ["efficiency", "table", "coffee", "laptop", "human"]
    features = phri.Features(robot, peers.study_features(names), scene=peers.STUDY_SCENE)
    opt = phri.TrajectoryOptimizer(features, 31, smoothing=0.0, speed_limits=False, collisions=False)
    problem = peers.study_problem("laptop")
    rng = np.random.default_rng(9)
    w = np.array([1.0, 0.5, 2.0, 10.0, 10.0])
    for _ in range(3):
        xi = _trajectory(problem, rng, 0.2)
        cost, penalty, grad = opt.objective(xi, w)
        f_cost, f_grad = features.weighted_cost(xi, w)
        assert penalty == 0.0
        assert abs(cost - f_cost) <= 1e-12 * max(1.0, abs(cost))
        np.testing.assert_allclose(grad, f_grad, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", TASKS)
def test_plans_do_the_task_and_keep_start_goal_limits_and_clearance(name, solved, robot) -> None:
    problem, opt, plan, info, plan0, info0 = solved[name]
    k = problem.names.index(name)
    phi = opt_features(problem).phi(plan)
    phi0 = opt_features(problem).phi(plan0)
    assert info.converged and info0.converged, (info, info0)
    assert phi[k] < phi0[k] - 1e-3, f"{name}: the task feature did not drop: {phi[k]} vs {phi0[k]}"
    np.testing.assert_array_equal(plan[0], problem.start)
    np.testing.assert_array_equal(plan[-1], problem.goal)
    lo, hi = robot.lower_limits, robot.upper_limits
    assert np.all(plan >= lo) and np.all(plan <= hi)
    for frame, min_z in problem.clearance:
        z = robot.frame_pose(frame, plan)[:, 2, 3]
        assert z.min() >= min_z - CLEARANCE_TOL, (
            f"{name}: {frame} {min_z - z.min():.2e} m below its clearance"
        )
    assert info.max_violation < CLEARANCE_TOL
    assert np.all(np.abs(np.diff(plan, axis=0)) <= problem.max_step + 1e-2)


def opt_features(problem) -> phri.Features:
    return phri.Features(phri.Robot.jaco2(), peers.study_features(problem.names), scene=peers.STUDY_SCENE)


@pytest.mark.slow
@pytest.mark.parametrize("name", TASKS)
def test_phri_ends_no_higher_than_scipy_lbfgsb_on_the_same_objective(name, solved) -> None:
    scipy_optimize = pytest.importorskip("scipy.optimize")
    problem, opt, plan, info, *_ = solved[name]
    ref = peers.ReferenceObjective(problem)
    x0 = peers.straight_line(problem)[1:-1].ravel()
    res = scipy_optimize.minimize(
        ref.interior, x0, jac=True, method="L-BFGS-B", bounds=ref.bounds(),
        options={"maxiter": 100_000, "maxfun": 1_000_000, "ftol": 1e-13, "gtol": 1e-9, "maxcor": 20},
    )  # fmt: skip
    scipy_plan = np.vstack([problem.start, res.x.reshape(-1, 7), problem.goal])
    scipy_cost = ref.full(scipy_plan)[0]
    phri_cost = ref.full(plan)[0]  # the same function evaluates both plans
    assert abs(phri_cost - info.cost) <= 1e-9 * max(1.0, info.cost)
    assert phri_cost <= scipy_cost + 1e-7 * max(1.0, abs(scipy_cost)), (
        f"{name}: phri {phri_cost:.10f} > scipy {scipy_cost:.10f} ({res.message}, {res.nfev} evaluations)"
    )


def test_solves_are_deterministic(solved) -> None:
    problem, opt, plan, info, *_ = solved["laptop"]
    again, info2 = opt.solve(problem.weights, problem.start, problem.goal)
    np.testing.assert_array_equal(plan, again)
    assert (info.iterations, info.evaluations, info.cost) == (info2.iterations, info2.evaluations, info2.cost)
    fresh = peers.phri_optimizer(problem)
    np.testing.assert_array_equal(plan, fresh.solve(problem.weights, problem.start, problem.goal)[0])


@pytest.mark.parametrize("name", TASKS)
def test_warm_starts(name, solved) -> None:
    problem, opt, plan, info, plan0, _ = solved[name]
    # From its own solution: nothing left to do.
    same, again = opt.solve(problem.weights, problem.start, problem.goal, init=plan)
    assert again.converged and again.iterations <= 2, again
    assert again.cost <= info.cost + 1e-12
    # After one update step of the task weight (0 → 0.3 × true): converges to a local optimum (the
    # problem is not convex: on the laptop task the cold start from the straight line ends in
    # another one, of cost 0.2253 against 0.2479), so solving again from it gains nothing.
    w = problem.weights.copy()
    w[1:] *= 0.3
    warm, winfo = opt.solve(w, problem.start, problem.goal, init=plan0)
    assert winfo.converged and winfo.coarse_iterations == 0, winfo
    _, pinfo = opt.solve(w, problem.start, problem.goal, init=warm)
    assert pinfo.cost >= winfo.cost - 1e-8 * abs(winfo.cost), (winfo, pinfo)
    np.testing.assert_array_equal(warm[0], problem.start)


def test_bad_input_is_a_typed_error(robot) -> None:
    problem = peers.study_problem("table")
    opt = peers.phri_optimizer(problem)
    w, a, b = problem.weights, problem.start, problem.goal
    with pytest.raises(ex.ShapeError, match="weights"):
        opt.solve([1.0], a, b)
    with pytest.raises(ex.ShapeError, match="start"):
        opt.solve(w, a[:6], b)
    with pytest.raises(ex.ShapeError, match="init"):
        opt.solve(w, a, b, init=np.zeros((30, 7)))
    with pytest.raises(ex.NonFiniteError):
        opt.solve([1.0, np.nan], a, b)
    with pytest.raises(ex.NonFiniteError):
        opt.solve(w, a, b, init=np.full((31, 7), np.nan))
    with pytest.raises(ex.InvalidParameterError, match="outside the limits"):
        opt.solve(w, np.zeros(7), b)
    with pytest.raises(ex.ShapeError, match="xi"):
        opt.objective(np.zeros((5, 7)), w)
    features = phri.Features(robot, ["efficiency", "table"])
    with pytest.raises(ex.InvalidParameterError, match="waypoints"):
        phri.TrajectoryOptimizer(features, 2, duration=15.0)
    with pytest.raises(ex.InvalidParameterError, match="max_step"):
        phri.TrajectoryOptimizer(features, 31, max_step=-np.ones(7))
    with pytest.raises(ex.UnknownNameError):
        phri.TrajectoryOptimizer(features, 31, duration=15.0, clearance=[("no_such_frame", 0.0)])


def test_solve_releases_the_gil() -> None:
    """A pure-Python thread keeps counting while a long solve runs (it could not if the GIL were held)."""
    problem = peers.study_problem("laptop", waypoints=400)
    opt = peers.phri_optimizer(
        problem, max_iterations=100_000, gradient_tolerance=0.0, relative_tolerance=0.0, max_time=0.6,
        coarsening=0,
    )  # fmt: skip
    count = [0]
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            count[0] += 1

    thread = threading.Thread(target=spin)
    thread.start()
    try:
        time.sleep(0.05)
        c0, t0 = count[0], time.perf_counter()
        time.sleep(0.2)  # the thread's rate with the main thread idle
        rate = (count[0] - c0) / (time.perf_counter() - t0)
        c0, t0 = count[0], time.perf_counter()
        opt.solve(problem.weights, problem.start, problem.goal)
        elapsed = time.perf_counter() - t0
        during = count[0] - c0
    finally:
        stop.set()
        thread.join()
    assert elapsed > 0.3, f"the solve was too short to tell ({elapsed:.3f} s)"
    # Held, the thread would get at most a few switch intervals (5 ms each) of the solve.
    assert during > 0.2 * rate * elapsed, f"{during} counts in {elapsed:.2f} s at {rate:.0f}/s alone"


def test_coarse_levels_are_configurable_and_reach_the_single_level_optimum() -> None:
    problem = peers.study_problem("human")
    multi = peers.phri_optimizer(problem)
    assert multi.levels == [31, 11]
    single = peers.phri_optimizer(problem, coarsening=0)
    assert single.levels == [31]
    assert peers.phri_optimizer(peers.study_problem("human", waypoints=100)).levels == [100, 34, 12]
    plan, info = multi.solve(problem.weights, problem.start, problem.goal)
    plan1, info1 = single.solve(problem.weights, problem.start, problem.goal)
    assert info.coarse_iterations > 0 and info1.coarse_iterations == 0
    assert info.iterations < info1.iterations, (info, info1)
    assert abs(info.cost - info1.cost) <= 1e-8 * info1.cost, (info, info1)
    np.testing.assert_allclose(plan, plan1, rtol=0, atol=1e-3)
    with pytest.raises(ex.InvalidParameterError, match="coarsest"):
        peers.phri_optimizer(problem, coarsest=2)


@pytest.mark.parametrize("name", TASKS)
def test_every_kinematic_curvature_mode_reaches_the_optimum(name, solved) -> None:
    problem, _, _, info, *_ = solved[name]
    for mode in ("gauss-newton", "exact"):
        _, other = peers.phri_optimizer(problem, kinematic_curvature=mode).solve(
            problem.weights, problem.start, problem.goal
        )
        assert other.converged, (mode, other)
        if name != "laptop":  # two optima close together: a mode may end in either
            assert abs(other.cost - info.cost) <= 1e-7 * abs(info.cost), (mode, other, info)
    with pytest.raises(ex.InvalidParameterError, match="kinematic_curvature"):
        peers.phri_optimizer(problem, kinematic_curvature="yes")


def test_warm_starts_through_the_coarse_levels() -> None:
    problem = peers.study_problem("human")
    opt = peers.phri_optimizer(problem)
    base, info0 = opt.solve_levels(problem.weights * [1.0, 0.0], problem.start, problem.goal)
    assert isinstance(base, phri.PlanLevels) and len(base) == 2
    assert base.plan.shape == (31, 7) and base.level(1).shape == (11, 7)
    np.testing.assert_array_equal(base.level(0), base.plan)
    plain, _ = opt.solve(problem.weights * [1.0, 0.0], problem.start, problem.goal)
    np.testing.assert_array_equal(base.plan, plain)  # a cold solve is the same either way
    # The first push's jump 0 → true weight: the coarse level does most of the work.
    levels, info = opt.solve_levels(problem.weights, problem.start, problem.goal, init=base)
    _, direct = opt.solve(problem.weights, problem.start, problem.goal, init=base.plan)
    assert info.converged and direct.converged
    assert info.iterations < direct.iterations and info.coarse_iterations > 0, (info, direct)
    assert abs(info.cost - direct.cost) <= 1e-8 * direct.cost
    # The same weights again: nothing left to do.
    _, again = opt.solve_levels(problem.weights, problem.start, problem.goal, init=levels)
    assert again.converged and again.iterations <= 2, again
    with pytest.raises(ex.ShapeError, match="init"):
        peers.phri_optimizer(problem, coarsening=0).solve_levels(
            problem.weights, problem.start, problem.goal, init=levels
        )
    with pytest.raises(ex.InvalidParameterError, match="k must be in 0..=1"):
        levels.level(2)


def test_rescale_weights_keeps_the_trade_off_on_another_grid(robot) -> None:
    features = phri.Features(
        robot, peers.study_features(["efficiency", "table", "laptop"]), scene=peers.STUDY_SCENE
    )
    w = np.array([1.0, 2.0, 10.0])
    # Efficiency (a sum of squared steps, e = −1) keeps its weight; per-waypoint features (e = 1)
    # scale with the square of the segment-length ratio.
    np.testing.assert_allclose(
        features.rescale_weights(w, 31, 100), w * [1.0, (30 / 99) ** 2, (30 / 99) ** 2]
    )
    np.testing.assert_allclose(
        features.rescale_weights(w, 100, 31), w * [1.0, (99 / 30) ** 2, (99 / 30) ** 2]
    )
    np.testing.assert_array_equal(features.rescale_weights(w, 31, 31), w)
    with pytest.raises(ex.ShapeError, match="weights"):
        features.rescale_weights(w[:2], 31, 100)
    for bad in (1, 0, -3):
        with pytest.raises(ex.InvalidParameterError, match="from_waypoints"):
            features.rescale_weights(w, bad, 100)
        with pytest.raises(ex.InvalidParameterError, match="to_waypoints"):
            features.rescale_weights(w, 31, bad)


def _at(plan: np.ndarray, times: np.ndarray) -> np.ndarray:
    """The piecewise-linear path through `plan`'s waypoints at normalised times in [0, 1]."""
    grid = np.linspace(0.0, 1.0, len(plan))
    return np.stack([np.interp(times, grid, plan[:, j]) for j in range(plan.shape[1])], axis=1)


@pytest.mark.parametrize("name", TASKS)
def test_rescaled_weights_plan_the_same_path_on_100_waypoints(name, solved, robot) -> None:
    problem, _, plan31, *_ = solved[name]
    fine = peers.study_problem(name, waypoints=100)
    features = phri.Features(robot, peers.study_features(problem.names), scene=peers.STUDY_SCENE)
    weights = features.rescale_weights(problem.weights, problem.waypoints, fine.waypoints)
    # The clearance penalty, a sum over waypoints too, scaled as the per-waypoint features.
    r2 = ((problem.waypoints - 1) / (fine.waypoints - 1)) ** 2
    opt = peers.phri_optimizer(fine, clearance_weight=peers.CLEARANCE_WEIGHT * r2)
    plan100, info = opt.solve(weights, fine.start, fine.goal)
    assert info.converged, info
    times = np.linspace(0.0, 1.0, 601)
    gap = np.abs(_at(plan100, times) - _at(plan31, times)).max()
    # Within 0.06 rad (the unscaled weights give another path, 0.36 rad away): the first and last
    # segments step at 2/3 of max_step (the executed cubic starts and ends at rest), and a segment
    # lasts 0.5 s on 31 waypoints but 0.15 s on 100, so the plans differ near the ends.
    assert gap <= 0.06, f"{name}: the 100-waypoint plan strays {gap:.3f} rad from the 31-waypoint one"
    if name == "table":
        # Unscaled, the same weights pose another trade-off: a visibly different plan.
        other, _ = peers.phri_optimizer(fine).solve(problem.weights, fine.start, fine.goal)
        assert np.abs(_at(other, times) - _at(plan31, times)).max() > 0.1


def test_speed_limits_come_from_the_duration_unless_given_or_turned_off(robot) -> None:
    task = phri.load_task("table")
    features = task.feature_set(robot)
    spacing = task.duration / (task.waypoints - 1)
    opt = phri.TrajectoryOptimizer(features, task.waypoints, duration=task.duration)
    np.testing.assert_allclose(opt.max_step, 0.5 * robot.velocity_limits * spacing, rtol=1e-15)
    slow = phri.TrajectoryOptimizer(features, 11, duration=30.0, speed_fraction=0.25)
    np.testing.assert_allclose(slow.max_step, 0.25 * robot.velocity_limits * 3.0, rtol=1e-15)
    given = phri.TrajectoryOptimizer(features, max_step=np.full(7, 0.1))
    np.testing.assert_array_equal(given.max_step, np.full(7, 0.1))
    free = phri.TrajectoryOptimizer(features, speed_limits=False)
    assert free.max_step is None
    # Without speed limits the plan for the true weights moves faster than the arm may.
    plan, info = free.solve(task.vector("true"), task.start, task.goal)
    _, limited = opt.solve(task.vector("true"), task.start, task.goal)
    assert info.max_step_excess == 0.0 and limited.feasible
    fastest = np.abs(np.diff(plan, axis=0)).max(axis=0) / spacing / robot.velocity_limits
    assert fastest.max() > 0.5 * (1 + free.STEP_TOLERANCE), fastest
    assert "feasible=True" in repr(limited)
    cases = [
        ({}, r"^duration: .*pass duration=.*or max_step=.*or speed_limits=False"),
        ({"duration": 0.0}, r"duration must be in \[3e-3, 1e6\] s"),
        ({"duration": np.inf}, r"duration must be in \[3e-3, 1e6\] s"),
        ({"duration": 15.0, "max_step": np.ones(7)}, "duration and max_step: give one"),
        ({"speed_limits": False, "max_step": np.ones(7)}, "with speed_limits=False leave it out"),
        ({"duration": 15.0, "speed_fraction": 0.0}, r"speed_fraction must be in \(0, 0.66+\d*\]"),
        ({"duration": 15.0, "speed_fraction": 0.9}, r"speed_fraction must be in \(0, 0.66+\d*\]"),
        ({"duration": 15.0, "collision_weight": 0.0}, "collision_weight must be > 0"),
        ({"duration": 15.0, "collision_buffer": -1e-3}, "collision_buffer"),
        ({"duration": 15.0, "collision_samples": 0}, "collision_samples must be in 1..=64"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ex.InvalidParameterError, match=message):
            phri.TrajectoryOptimizer(features, **kwargs)


def test_the_collision_penalty_is_in_the_objective_with_its_exact_gradient(robot) -> None:
    """A trajectory through the table costs more with collision checks, by a penalty whose gradient
    is the central difference of the objective."""
    task = phri.load_task("table")
    features = task.feature_set(robot)
    on = phri.TrajectoryOptimizer(features, task.waypoints, duration=task.duration)
    off = phri.TrajectoryOptimizer(features, task.waypoints, duration=task.duration, collisions=False)
    xi = np.linspace(task.start, task.goal, task.waypoints)
    xi[:, 1] -= 0.5 * np.sin(np.linspace(0.0, np.pi, task.waypoints))  # the shoulder dips: into the table
    w = task.vector("true")
    cost, penalty, grad = on.objective(xi, w)
    cost0, penalty0, _ = off.objective(xi, w)
    assert penalty - penalty0 > 1.0 and cost - cost0 == pytest.approx(penalty - penalty0, rel=1e-12)
    h = 1e-6
    rng = np.random.default_rng(3)
    for _ in range(12):
        i, j = rng.integers(1, task.waypoints - 1), rng.integers(0, 7)
        up, down = xi.copy(), xi.copy()
        up[i, j] += h
        down[i, j] -= h
        fd = (on.objective(up, w)[0] - on.objective(down, w)[0]) / (2 * h)
        assert fd == pytest.approx(grad[i, j], rel=1e-5, abs=1e-4), (i, j)


@pytest.mark.parametrize("name", TASKS)
def test_plans_by_knots_are_four_waypoints_planned_and_upsampled_as_the_original_did(name, robot) -> None:
    # The original system planned 4 waypoints 5 s apart with trajopt and upsampled the plan
    # linearly to 31; knots=4 does that in one solve. Independently: a 4-waypoint optimiser (step
    # limit of 5 s, collision samples as dense as 31 waypoints' along each chord), its plan upsampled
    # with numpy.
    task = phri.load_task(name)
    features = task.feature_set(robot)
    by_knots = phri.TrajectoryOptimizer(features, 31, duration=task.duration, knots=4)
    four = phri.TrajectoryOptimizer(features, 4, duration=task.duration, collision_samples=40)
    assert by_knots.levels == [31, 4]
    np.testing.assert_array_equal(by_knots.max_step, four.max_step / 10)
    for which in ("initial", "true"):
        w = task.vector(which)
        plan, info = by_knots.solve(w, task.start, task.goal)
        knots, info4 = four.solve(w, task.start, task.goal)
        assert info.converged and info.feasible, (name, which, info)
        assert (info.iterations, info.coarse_iterations) == (info4.iterations, info4.coarse_iterations)
        assert (info.cost, info.penalty) == (info4.cost, info4.penalty)
        times = np.linspace(0, 3, 31)
        upsampled = np.stack([np.interp(times, np.arange(4), knots[:, j]) for j in range(7)], axis=1)
        np.testing.assert_allclose(plan, upsampled, rtol=0, atol=1e-12)
        # What it minimises is the knot problem's cost at the plan's knots.
        cost, penalty, grad = by_knots.objective(plan, w)
        assert (cost, penalty) == (info.cost, info.penalty)
        assert not grad[np.arange(31) % 10 != 0].any()
        # A warm start from the plan stays there.
        again, warm = by_knots.solve(w, task.start, task.goal, init=plan)
        assert warm.converged
        np.testing.assert_allclose(again, plan, rtol=0, atol=1e-6)


def test_knots_outside_their_range_are_typed_errors(robot) -> None:
    features = phri.Features(robot, ["efficiency", "table"])
    for knots in (1, 2, 5, 30, 31, 40, -1):  # 5 and 30 would put knots between waypoints
        with pytest.raises(ex.InvalidParameterError, match="knots"):
            phri.TrajectoryOptimizer(features, 31, duration=15.0, knots=knots)
    for off in (0, None):
        assert phri.TrajectoryOptimizer(features, 31, duration=15.0, knots=off).levels == [31, 11]
    with pytest.raises(TypeError, match="knots"):
        phri.TrajectoryOptimizer(features, 31, duration=15.0, knots=4.0)  # type: ignore[arg-type]
