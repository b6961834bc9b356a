"""phri.Learner (Algorithm 1): typed errors, the sampling grid and the interaction thresholds, the
impedance baseline (learning=False), and one scripted push on the study's table task checked against
an independent numpy reconstruction — the deformation (eq. 7) with H from a dense solve, Φ summed in
numpy from Robot.frame_pose, the update (eq. 13, cost form) for the "all" and "confidence" rules —
then the reference across the replan (C¹ blend or instant switch) and the shapes of the history;
replans on the worker thread (a simulated latency of one tick reproduces inline replanning, newer
pushes supersede, a stalled or panicking worker never takes the tick down), reset(), the time and
integer checks, and reference() from another thread during observe()."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

import phri
from phri import exceptions as ex

PICK_BASIC = np.radians([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8])
PLACE_LOWER = np.radians([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
THRESHOLDS = np.array([8.0, 8.0, 8.0, 2.0, 1.0, 1.0, 1.0])  # N·m, the JACO2's (the authors' published code)
TOOL = "j2s7s300_end_effector"
CUP = "j2s7s300_link_7"  # the point of the position features
DURATION = 15.0  # s
WAYPOINTS = 31
DT = DURATION / (WAYPOINTS - 1)  # 0.5 s between waypoints
WINDOW, MU = 5, 0.01  # phri.Deformation() defaults
DOWN_25N = np.array([0.0, 0.0, -25.0, 0.0, 0.0, 0.0])  # wrench at the tool point: force [N], torque [N·m]
# Table task (Task 2), cost form: efficiency never learned, table learned with gain 2, clipped to [0, 1].
STEP, LOWER, UPPER, LEARNED = [0.0, 2.0], [1.0, 0.0], [1.0, 1.0], [False, True]
INITIAL = [1.0, 0.0]


@pytest.fixture(scope="module")
def robot() -> phri.Robot:
    return phri.Robot.jaco2()


@pytest.fixture(scope="module")
def features(robot: phri.Robot) -> phri.Features:
    return phri.Features(robot, ["efficiency", "table"])


@pytest.fixture(scope="module")
def optimizer(features: phri.Features) -> phri.TrajectoryOptimizer:
    return phri.TrajectoryOptimizer(features, WAYPOINTS, duration=DURATION)


@pytest.fixture
def make(features, optimizer):
    """`make(step=..., rule=..., detector=..., **learner_kwargs)`: a fresh table-task Learner."""

    def build(step=STEP, rule="all", detector=None, weights=INITIAL, **kwargs) -> phri.Learner:
        update = phri.WeightUpdate(step, LOWER, UPPER, learned=LEARNED, rule=rule)
        detector = detector or phri.InteractionDetector()
        return phri.Learner(
            features, phri.Deformation(), update, detector, optimizer, weights, PICK_BASIC, PLACE_LOWER,
            duration=DURATION, **kwargs,
        )  # fmt: skip

    return build


# --------------------------------------------------------------------------------------------------
# numpy references


def reference_shape(m: int) -> np.ndarray:
    """H = R⁻¹e₁, R = AᵀA with A the (m+2)×m zero-padded second-difference matrix, scaled to ‖H‖ = √m."""
    a = np.zeros((m + 2, m))
    for k in range(m):
        a[k : k + 3, k] = (1.0, -2.0, 1.0)
    x = np.linalg.solve(a.T @ a, np.eye(m)[0])
    return x * np.sqrt(m) / np.linalg.norm(x)


def reference_u_h(tau: np.ndarray) -> np.ndarray:
    """Thresholded torque: joints at or below their threshold zeroed."""
    return np.where(np.abs(tau) > THRESHOLDS, tau, 0.0)


def reference_deform(xi: np.ndarray, t: float, u_h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ξ_H, μ·H per waypoint and joint for a unit torque): waypoints index+1..index+5 moved."""
    index = int(np.floor(t / DT))
    assert index + WINDOW <= len(xi) - 2, "a full window must fit before the goal"
    shape = np.zeros_like(xi)
    shape[index + 1 : index + 1 + WINDOW] = MU * reference_shape(WINDOW)[:, None]
    return xi + shape * u_h, shape


def reference_phi(robot: phri.Robot, xi: np.ndarray) -> np.ndarray:
    """(efficiency, table) summed over waypoints 1..N-1: Σ‖q_i − q_{i−1}‖², Σ z of the link_7 origin."""
    efficiency = float(np.sum(np.diff(xi, axis=0) ** 2))
    table = sum(robot.frame_pose(CUP, q)[2, 3] for q in xi[1:])
    return np.array([efficiency, table])


def reference_relevance(delta_phi: np.ndarray, sensitivity: np.ndarray, u_h: np.ndarray) -> np.ndarray:
    """r_k = min(1, ΔΦ_k² / (‖S_k‖²·‖u_H‖²)), 0 when either norm vanishes."""
    s2 = np.sum(sensitivity**2, axis=1)
    push = float(u_h @ u_h)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where((s2 > 0) & (push > 0), delta_phi**2 / (s2 * push), 0.0)
    return np.minimum(1.0, r)


def reference_update(w, delta_phi, step, relevance=1.0) -> np.ndarray:
    target = np.asarray(w) - np.asarray(step) * relevance * delta_phi
    return np.where(LEARNED, np.clip(target, LOWER, UPPER), w)


def push_torque(robot: phri.Robot, learner: phri.Learner, t: float, wrench=DOWN_25N) -> np.ndarray:
    """u_H = Jᵀ·wrench at the tool point, at the learner's current reference."""
    q, _, _ = learner.reference(t)
    return robot.jacobian(TOOL, q).T @ wrench


def tracked(learner: phri.Learner) -> np.ndarray:
    """The trajectory the arm follows, at the waypoint times (the plan, or the blend into it)."""
    return np.array([learner.reference(i * DT)[0] for i in range(WAYPOINTS)])


# --------------------------------------------------------------------------------------------------
# errors


def nan_at(v, i: int) -> np.ndarray:
    v = np.array(v, dtype=float)
    v[i] = np.nan
    return v


CONSTRUCTION_ERRORS = [
    ({"weights": [1.0, 0.0, 0.0]}, ex.ShapeError, "weights must have shape (2,), got (3,)"),
    ({"weights": [[1.0, 0.0]]}, ex.ShapeError, "weights must have shape (2,), got (1, 2)"),
    ({"start": PICK_BASIC[:6]}, ex.ShapeError, "start must have shape (7,), got (6,)"),
    ({"goal": np.append(PLACE_LOWER, 0.0)}, ex.ShapeError, "goal must have shape (7,), got (8,)"),
    ({"weights": nan_at(INITIAL, 1)}, ex.NonFiniteError, "weights must be finite, got NaN at index 1"),
    ({"start": nan_at(PICK_BASIC, 2)}, ex.NonFiniteError, "start must be finite, got NaN at index 2"),
    ({"goal": nan_at(PLACE_LOWER, 6)}, ex.NonFiniteError, "goal must be finite, got NaN at index 6"),
    ({"sample_period": 0.0}, ex.InvalidParameterError, "sample_period must be a finite time > 0 s, got 0"),
    ({"sample_period": -0.1}, ex.InvalidParameterError, "sample_period must be a finite time > 0 s"),
    (
        {"sample_period": np.nan},
        ex.InvalidParameterError,
        "sample_period must be a finite time > 0 s, got NaN",
    ),
    ({"sample_period": np.inf}, ex.InvalidParameterError, "sample_period must be a finite time > 0 s"),
    ({"transition_speed": -0.1}, ex.InvalidParameterError, "transition_speed must be a finite fraction"),
    ({"transition_speed": np.nan}, ex.InvalidParameterError, "transition_speed must be a finite fraction"),
    ({"transition_speed": np.inf}, ex.InvalidParameterError, "transition_speed must be a finite fraction"),
    ({"interpolation": "spline"}, ex.InvalidParameterError, "interpolation must be 'cubic' or 'linear'"),
    ({"interpolation": "Cubic"}, ex.InvalidParameterError, "interpolation must be 'cubic' or 'linear'"),
    ({"duration": 0.0}, ex.InvalidParameterError, "duration must be in "),
    (
        {"update": phri.WeightUpdate([0.0, 2.0, 1.0], [1.0, 0.0, 0.0], [1.0, 1.0, 1.0])},
        ex.InvalidParameterError,
        "update must have one step per feature (2 features), got 3 steps",
    ),
    (
        {"detector": phri.InteractionDetector(np.ones(6))},
        ex.InvalidParameterError,
        "detector must have one threshold per joint (7 joints), got 6",
    ),
]


def error_id(case) -> str:
    (name, value), error = next(iter(case[0].items())), case[1]
    if isinstance(value, (str, float)):
        return f"{name}={value}"
    if isinstance(value, phri.WeightUpdate):
        return f"{name}-{len(value)}-steps"
    return f"{name}-{error.__name__}-{np.shape(getattr(value, 'thresholds', value))}"


@pytest.mark.parametrize(
    ("change", "error", "pattern"), CONSTRUCTION_ERRORS, ids=[error_id(c) for c in CONSTRUCTION_ERRORS]
)
def test_construction_errors_are_typed_and_name_the_argument(features, optimizer, change, error, pattern):
    args = {
        "update": phri.WeightUpdate(STEP, LOWER, UPPER, learned=LEARNED),
        "detector": phri.InteractionDetector(),
        "weights": INITIAL,
        "start": PICK_BASIC,
        "goal": PLACE_LOWER,
    }
    kwargs = {k: v for k, v in change.items() if k not in args}
    args.update({k: v for k, v in change.items() if k in args})
    with pytest.raises(error, match="^" + re.escape(pattern)):
        phri.Learner(
            features, phri.Deformation(), args["update"], args["detector"], optimizer,
            args["weights"], args["start"], args["goal"], **kwargs,
        )  # fmt: skip


@pytest.mark.parametrize(
    ("call", "error", "pattern"),
    [
        (
            lambda lr: lr.observe(0.0, np.zeros(6)),
            ex.ShapeError,
            "tau_measured must have shape (7,), got (6,)",
        ),
        (
            lambda lr: lr.observe(0.0, np.zeros((1, 7))),
            ex.ShapeError,
            "tau_measured must have shape (7,), got (1, 7)",
        ),
        (
            lambda lr: lr.observe(0.0, nan_at(np.zeros(7), 3)),
            ex.NonFiniteError,
            "tau_measured must be finite, got NaN at index 3",
        ),
        (lambda lr: lr.observe(np.nan, np.zeros(7)), ex.NonFiniteError, "t must be finite, got NaN"),
        (lambda lr: lr.observe(np.inf, np.zeros(7)), ex.NonFiniteError, "t must be finite, got inf"),
        (lambda lr: lr.reference(np.nan), ex.NonFiniteError, "t must be finite, got NaN"),
        (lambda lr: lr.reference(-np.inf), ex.NonFiniteError, "t must be finite, got -inf"),
    ],
    ids=["tau-short", "tau-2d", "tau-nan", "t-nan", "t-inf", "reference-nan", "reference-inf"],
)
def test_observe_and_reference_errors_are_typed_and_leave_the_learner_untouched(make, call, error, pattern):
    learner = make()
    with pytest.raises(error, match="^" + re.escape(pattern)):
        call(learner)
    # The failed call consumed no sample instant and recorded nothing.
    assert learner.observe(0.0, np.zeros(7)) == (True, False, False)
    history = learner.history()
    assert len(history) == 0 and history.t.shape == (0,) and history.plan_t.shape == (1,)


def test_a_finite_but_absurd_torque_is_an_error_naming_it(make):
    learner = make()
    weights, plan = learner.weights, learner.plan
    with pytest.raises(
        ex.InvalidParameterError, match="^tau_measured (is so large that the deformed|must be within ±1e9)"
    ):
        learner.observe(4.0, np.full(7, 1e300))
    np.testing.assert_array_equal(learner.weights, weights)
    np.testing.assert_array_equal(learner.plan, plan)


# --------------------------------------------------------------------------------------------------
# sampling and thresholds


def test_a_1khz_loop_is_sampled_every_100_ticks(make):
    learner = make(learning=False)
    sampled = []
    for k in range(1001):  # t = k·1 ms carries rounding: 0.001·k is not exactly k/1000
        obs = learner.observe(k * 0.001, np.zeros(7))
        if obs[0]:
            sampled.append(k)
            assert obs == (True, False, False)
        else:
            assert obs == (False, False, False), f"tick {k}"
    assert sampled == list(range(0, 1001, 100))


def test_a_late_tick_samples_once_and_missed_instants_are_not_replayed(make):
    learner = make(learning=False)
    push = 2.0 * THRESHOLDS
    assert learner.observe(0.0, np.zeros(7)) == (True, False, False)
    assert learner.observe(0.05, push) == (False, False, False), "between instants: not even looked at"
    assert learner.observe(0.35, push) == (True, True, False), "0.1, 0.2, 0.3 missed: one late sample"
    assert learner.observe(0.38, push) == (False, False, False)
    assert learner.observe(0.4, push) == (True, True, False)
    assert learner.history().t.tolist() == [0.35, 0.4]


def test_thresholds_are_the_jaco2s_and_strict(make):
    np.testing.assert_array_equal(phri.InteractionDetector().thresholds, THRESHOLDS)
    learner = make(learning=False)
    signs = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
    t = 0.0
    for tau in (0.999 * signs * THRESHOLDS, signs * THRESHOLDS):  # below and exactly at: no interaction
        assert learner.observe(t, tau) == (True, False, False)
        t += 0.1
    assert len(learner.history()) == 0
    for j in range(7):
        tau = 0.99 * signs * THRESHOLDS
        tau[j] = signs[j] * 1.01 * THRESHOLDS[j]
        assert learner.observe(t, tau) == (True, True, False), f"joint {j}"
        want = np.zeros(7)
        want[j] = tau[j]
        np.testing.assert_array_equal(learner.history().u_h[-1], want)
        t += 0.1
    assert learner.history().u_h.shape == (7, 7)


# --------------------------------------------------------------------------------------------------
# the impedance baseline


def test_without_learning_pushes_are_recorded_but_nothing_changes(robot, make):
    learner = make(learning=False)
    assert learner.learning is False
    plan0 = learner.plan
    reference0 = [learner.reference(t) for t in (3.9, 4.0, 6.0, 14.9)]
    t_push = [4.0, 4.1, 4.2, 4.3]
    for t in t_push:
        tau = push_torque(robot, learner, t)
        assert learner.observe(t, tau) == (True, True, False)
    history = learner.history()
    assert history.t.tolist() == t_push
    for i, t in enumerate(t_push):
        np.testing.assert_array_equal(history.u_h[i], reference_u_h(push_torque(robot, learner, t)))
        assert np.any(history.u_h[i] != 0)
        assert np.all(np.isnan(history.delta_phi[i])) and history.moved[i] == 0
        assert history.updates[i] is None and history.replans[i] is None
        np.testing.assert_array_equal(history.weights[i], INITIAL)
    np.testing.assert_array_equal(learner.weights, INITIAL)
    np.testing.assert_array_equal(learner.plan, plan0)
    history = learner.history()
    assert history.plan_t.tolist() == [0.0] and history.plans.shape == (1, *plan0.shape)
    np.testing.assert_array_equal(history.plans[0], plan0)
    for before, t in zip(reference0, (3.9, 4.0, 6.0, 14.9), strict=True):
        for a, b in zip(before, learner.reference(t), strict=True):
            np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------------------------------
# one scripted push, against numpy


def test_the_initial_plan_is_the_optimizers_for_the_clipped_weights(make, optimizer):
    learner = make(weights=[3.0, -2.0])  # clipped into [1, 1] × [0, 1]
    np.testing.assert_array_equal(learner.weights, [1.0, 0.0])
    assert learner.learning is True
    plan, info = optimizer.solve([1.0, 0.0], PICK_BASIC, PLACE_LOWER)
    assert info.converged
    np.testing.assert_allclose(learner.plan, plan, rtol=0, atol=1e-12)
    assert learner.plan.shape == (WAYPOINTS, 7)
    np.testing.assert_array_equal(learner.plan[0], PICK_BASIC)
    np.testing.assert_array_equal(learner.plan[-1], PLACE_LOWER)


@pytest.mark.parametrize("step", [STEP, [0.0, 0.5]], ids=["gain-2-clipped", "gain-0.5"])
def test_a_downward_push_matches_the_numpy_reconstruction(robot, make, step):
    learner = make(step=step)
    t = 4.0
    xi_r = learner.plan  # no blend on a fresh learner: the arm tracks the plan itself
    np.testing.assert_allclose(tracked(learner), xi_r, rtol=0, atol=1e-12)
    tau = push_torque(robot, learner, t)
    assert learner.observe(t, tau) == (True, True, True)

    u_h = reference_u_h(tau)
    xi_h, _ = reference_deform(xi_r, t, u_h)
    np.testing.assert_allclose(phri.Deformation().deform(xi_r, int(t / DT), u_h), xi_h, rtol=0, atol=1e-12)
    delta_phi = reference_phi(robot, xi_h) - reference_phi(robot, xi_r)
    assert delta_phi[1] < -0.1, "pushing down lowers the cup: the table feature (height) drops"

    history = learner.history()
    assert len(history) == 1
    i = 0
    assert history.t[i] == t and history.moved[i] == WINDOW
    np.testing.assert_array_equal(history.u_h[i], u_h)
    np.testing.assert_allclose(history.delta_phi[i], delta_phi, rtol=0, atol=1e-9)
    weights = reference_update(INITIAL, delta_phi, step)
    np.testing.assert_allclose(history.weights[i], weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(learner.weights, weights, rtol=0, atol=1e-12)
    assert learner.weights[1] > INITIAL[1], "the table weight grows"
    assert history.updates[i].clipped == (step == STEP)
    assert history.updates[i].chosen is None
    assert abs(history.updates[i].max_change - abs(weights[1] - INITIAL[1])) < 1e-12

    assert history.plan_t.tolist() == [0.0, t]
    np.testing.assert_array_equal(history.plans[1], learner.plan)
    assert np.abs(learner.plan - xi_r).max() > 1e-3, "the new weights give a new plan"
    assert history.replans[i].converged


def test_the_confidence_rule_scales_the_step_by_the_numpy_relevance(robot, features, make):
    step = [0.0, 0.5]  # small enough not to clip, so the relevance shows in the weight
    learner = make(step=step, rule="confidence")
    t = 4.0
    xi_r = learner.plan
    tau = push_torque(robot, learner, t)
    assert learner.observe(t, tau) == (True, True, True)

    u_h = reference_u_h(tau)
    xi_h, shape = reference_deform(xi_r, t, u_h)
    delta_phi = reference_phi(robot, xi_h) - reference_phi(robot, xi_r)
    _, jac = features.phi_gradient(xi_r)  # (K, N, n)
    assert jac.shape == (2, WAYPOINTS, 7)
    sensitivity = np.einsum("kij,ij->kj", jac, shape)  # S = ∂ΔΦ/∂u_H, (K, n)
    relevance = reference_relevance(delta_phi, sensitivity, u_h)
    assert relevance[0] == 1.0 and 0.5 < relevance[1] < 0.99, f"relevance {relevance}"

    history = learner.history()
    assert len(history) == 1
    i = 0
    np.testing.assert_allclose(history.delta_phi[i], delta_phi, rtol=0, atol=1e-9)
    weights = reference_update(INITIAL, delta_phi, step, relevance)
    np.testing.assert_allclose(history.weights[i], weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(learner.weights, weights, rtol=0, atol=1e-12)
    assert not history.updates[i].clipped
    # The same push under the "all" rule moves the weight further, by 1/relevance.
    full = reference_update(INITIAL, delta_phi, step)
    assert abs((weights[1] - INITIAL[1]) - relevance[1] * (full[1] - INITIAL[1])) < 1e-12


def test_a_push_during_the_blend_deforms_the_blended_reference(robot, make):
    learner = make(step=[0.0, 0.5])
    assert learner.observe(4.0, push_torque(robot, learner, 4.0))[2]
    xi_r = tracked(learner)  # the blend from the old plan is still running at 4.1 s
    assert np.abs(xi_r - learner.plan).max() > 1e-2, "the blend should still be visible"
    w = learner.weights
    t = 4.1
    tau = push_torque(robot, learner, t)
    assert learner.observe(t, tau) == (True, True, True)
    u_h = reference_u_h(tau)
    xi_h, _ = reference_deform(xi_r, t, u_h)
    delta_phi = reference_phi(robot, xi_h) - reference_phi(robot, xi_r)
    history = learner.history()
    i = -1
    np.testing.assert_allclose(history.delta_phi[i], delta_phi, rtol=0, atol=1e-9)
    np.testing.assert_allclose(history.weights[i], reference_update(w, delta_phi, [0.0, 0.5]), atol=1e-12)
    assert history.plan_t.tolist() == [0.0, 4.0, 4.1]


def test_a_push_too_close_to_the_goal_is_recorded_but_moves_nothing(robot, make):
    learner = make()
    t = 13.0  # waypoint 26: fewer than 5 waypoints left before the goal (skip rule)
    assert learner.observe(t, push_torque(robot, learner, t)) == (True, True, False)
    history = learner.history()
    assert len(history) == 1
    i = 0
    assert history.moved[i] == 0 and np.all(np.isnan(history.delta_phi[i]))
    assert history.updates[i] is None and history.replans[i] is None
    np.testing.assert_array_equal(learner.weights, INITIAL)
    assert history.plan_t.shape == (1,)


# --------------------------------------------------------------------------------------------------
# the reference across a replan


@pytest.mark.parametrize(("interpolation", "t"), [("cubic", 4.0), ("cubic", 4.2), ("linear", 4.2)])
def test_after_a_replan_the_reference_is_c1_and_blends_into_the_new_plan(robot, make, interpolation, t):
    learner = make(interpolation=interpolation)
    q_left, qd_left, _ = learner.reference(t - 1e-9)
    q_at, qd_at, _ = learner.reference(t)
    assert learner.observe(t, push_torque(robot, learner, t)) == (True, True, True)
    q_after, qd_after, _ = learner.reference(t)
    np.testing.assert_allclose(q_after, q_at, rtol=0, atol=1e-12)
    np.testing.assert_allclose(qd_after, qd_at, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q_after, q_left, rtol=0, atol=1e-8)
    np.testing.assert_allclose(qd_after, qd_left, rtol=0, atol=1e-8)

    plan = phri.TimedTrajectory(learner.plan, DURATION, interpolation)
    q_plan, _, _ = plan.sample(t)
    assert np.abs(q_plan - q_after).max() > 0.1, "the new plan lies far from the old reference"
    for got, want in zip(learner.reference(14.9), plan.sample(14.9), strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # Within the blend: joint speeds at most 0.8 × the velocity limits, or the new plan's own speed.
    times = np.linspace(t, DURATION, 2201)
    qd = np.array([learner.reference(s)[1] for s in times])
    _, qd_plan, _ = plan.sample_many(times)
    limit = np.maximum(0.8 * robot.velocity_limits, np.abs(qd_plan))
    assert np.all(np.abs(qd) <= limit * (1 + 1e-6)), f"worst {np.max(np.abs(qd) / limit)}"


def test_with_transition_speed_zero_the_reference_jumps_to_the_new_plan(robot, make):
    t = 4.0
    learner = make(transition_speed=0.0)
    q_before, _, _ = learner.reference(t)
    assert learner.observe(t, push_torque(robot, learner, t)) == (True, True, True)
    plan = phri.TimedTrajectory(learner.plan, DURATION)
    for s in (t, t + 0.05, 5.0, 8.0, 14.9):
        for got, want in zip(learner.reference(s), plan.sample(s), strict=True):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=f"t = {s}")
    assert np.abs(learner.reference(t)[0] - q_before).max() > 0.1, "an instant switch jumps"


# --------------------------------------------------------------------------------------------------
# the history


def test_history_shapes_and_dtypes(robot, make):
    learner = make()
    history = learner.history()
    assert len(history) == 0 and history.plan_t.tolist() == [0.0]
    assert history.plans.shape == (1, WAYPOINTS, 7) and history.plans.dtype == np.float64
    assert history.u_h.shape == (0, 7) and history.weights.shape == (0, 2)
    for t in (4.0, 4.1):
        learner.observe(t, push_torque(robot, learner, t))
    learner.observe(4.2, np.zeros(7))  # sampled, no interaction: not recorded
    history = learner.history()
    assert len(history) == 2 and repr(history) == "LearnerHistory(interactions=2, plans=3)"
    assert history.t.dtype == np.float64 and history.t.tolist() == [4.0, 4.1]
    assert history.u_h.shape == (2, 7)
    assert history.delta_phi.shape == (2, 2) and history.weights.shape == (2, 2)
    assert history.moved.tolist() == [WINDOW, WINDOW] and np.issubdtype(history.moved.dtype, np.integer)
    assert all(isinstance(u, phri.UpdateInfo) for u in history.updates)
    assert all(isinstance(r, phri.TrajoptInfo) for r in history.replans)
    np.testing.assert_array_equal(history.weights[-1], learner.weights)
    assert history.plan_t.tolist() == [0.0, 4.0, 4.1]
    assert history.plans.shape == (3, WAYPOINTS, 7)
    np.testing.assert_array_equal(history.plans[-1], learner.plan)
    # What the accessors return are copies.
    learner.plan[:] = 0.0
    learner.weights[:] = 7.0
    history.plans[0][:] = 0.0
    history.weights[0][:] = 7.0
    assert np.all(learner.plan[0] == PICK_BASIC) and np.all(learner.weights <= 1.0)
    np.testing.assert_array_equal(learner.history().plans[0][0], PICK_BASIC)
    assert np.all(learner.history().weights[0] <= 1.0)


def test_reference_writes_into_out_buffers(robot, make):
    learner = make()
    learner.observe(4.0, push_torque(robot, learner, 4.0))
    out = (np.empty(7), np.empty(7), np.empty(7))
    for t in (0.0, 4.05, 9.3):
        got = learner.reference(t, out=out)
        assert all(g is o for g, o in zip(got, out, strict=True))
        for a, b in zip(out, learner.reference(t), strict=True):
            np.testing.assert_array_equal(a, b)
    bad = [
        ((np.empty(6), np.empty(7), np.empty(7)), ex.ShapeError, "out[0]"),
        ((np.empty(7), np.empty(14)[::2], np.empty(7)), ex.ShapeError, "out[1]"),
        ((out[0], out[0], np.empty(7)), ex.InvalidParameterError, "out[1]"),
    ]
    readonly = np.empty(7)
    readonly.flags.writeable = False
    bad.append(((np.empty(7), np.empty(7), readonly), ex.InvalidParameterError, "out[2]"))
    for buffers, error, name in bad:
        with pytest.raises(error, match=re.escape(name)):
            learner.reference(1.0, out=buffers)
    not_buffers = [
        (
            (np.empty(7, dtype=np.float32), np.empty(7), np.empty(7)),
            "out[0] must be a one-dimensional float64",
        ),
        ((np.empty(7), np.empty((7, 1)), np.empty(7)), "out[1] must be a one-dimensional float64"),
        ((np.empty(7), np.empty(7)), "out must hold three arrays (q, qd, qdd), got 2"),
        ("qqq", "out must be a tuple of three float64 arrays"),
        (7, "out must be a tuple of three float64 arrays"),
    ]
    for buffers, message in not_buffers:
        with pytest.raises(ex.ShapeError, match=re.escape(message)):
            learner.reference(1.0, out=buffers)


def test_a_replan_budget_goes_on_over_the_next_ticks(make, robot, optimizer):
    capped, full = make(replan_iterations=2), make()
    assert not capped.replan_pending
    tau = push_torque(robot, capped, 4.0)
    capped.observe(4.0, tau)
    full.observe(4.0, tau)
    assert capped.replan_pending, "a push from weight 0 needs more than 2 iterations"
    assert capped.history().replans[0].iterations <= 2
    ticks = 0
    while capped.replan_pending:
        ticks += 1
        assert ticks < 300
        assert capped.observe(4.0 + 1e-3 * ticks, np.zeros(7)) == (False, False, True)
    # Both converge to the same optimum, to the solver's relative cost tolerance (1e-9), which
    # leaves the plans within ~1e-4 rad of each other (below the JACO2 encoders' resolution).
    np.testing.assert_array_equal(capped.weights, full.weights)
    capped_cost, full_cost = (optimizer.objective(x.plan, x.weights)[0] for x in (capped, full))
    assert abs(capped_cost - full_cost) <= 1e-8 * abs(full_cost)
    np.testing.assert_allclose(capped.plan, full.plan, rtol=0, atol=1e-4)
    # Every budgeted step's plan is adopted, except those not yet feasible (the arm keeps its last
    # feasible plan meanwhile); the converged plan is adopted.
    assert 1 <= len(capped.history().plan_t) - 1 <= ticks + 1
    assert len(capped.history().rejected_t) == 0
    np.testing.assert_array_equal(capped.history().plans[-1], capped.plan)


def test_seed_plans_shorten_the_replan_after_a_push(make, robot):
    seeded, plain = make(seeds=3), make()
    tau = push_torque(robot, plain, 4.0)
    seeded.observe(4.0, tau)
    plain.observe(4.0, tau)
    a, b = seeded.history().replans[0], plain.history().replans[0]
    assert a.converged and b.converged
    assert a.iterations < b.iterations and a.cost <= b.cost + 1e-9 * abs(b.cost)  # the solver's tolerance
    with pytest.raises(ex.InvalidParameterError, match="^seeds must be 0 .none. or at least 2"):
        make(seeds=1)


# --------------------------------------------------------------------------------------------------
# replans on the worker thread

TICK = 0.001  # s, a 1 kHz loop


def loop(learner: phri.Learner, robot, times, push_at=()):
    """observe then reference at every tick of `times`, pushing down at the ticks in `push_at`
    (computed on the learner's own reference); returns the observations and references."""
    observed, references = [], []
    for k, t in times:
        tau = push_torque(robot, learner, t) if k in push_at else np.zeros(7)
        observed.append(learner.observe(t, tau))
        references.append(np.concatenate(learner.reference(t)))
    return observed, np.array(references)


def test_a_one_tick_latency_reproduces_inline_replanning(robot, make):
    inline, worker = make(), make(replan_latency=TICK)
    assert inline.replan_latency == 0.0 and worker.replan_latency == TICK
    adopted = []
    inline_weights_last_tick = inline.weights
    for k in range(3000, 6001):
        t = k * TICK
        tau = push_torque(robot, inline, t) if 4000 <= k < 4500 and k % 100 == 0 else np.zeros(7)
        a, b = inline.observe(t, tau), worker.observe(t, tau)
        assert a[:2] == b[:2], f"tick {k}"
        # The worker learns before it replans: the weights arrive with the plan, a tick later.
        np.testing.assert_array_equal(inline_weights_last_tick, worker.weights, err_msg=f"tick {k}")
        inline_weights_last_tick = inline.weights
        if worker.adopted:
            adopted.append(k)
        ra, rb = inline.reference(t), worker.reference(t)
        if a[2]:
            # Inline switched at t, blending in from the reference the worker still tracks.
            np.testing.assert_allclose(ra[0], rb[0], rtol=0, atol=1e-12)
        else:
            for x, y in zip(ra, rb, strict=True):
                np.testing.assert_array_equal(x, y)
    assert adopted == [4001, 4101, 4201, 4301, 4401], "one tick after each push"
    h, g = inline.history(), worker.history()
    for key in ("t", "u_h", "delta_phi", "weights", "moved", "plan_t", "plans", "rejected_t"):
        np.testing.assert_array_equal(getattr(h, key), getattr(g, key), err_msg=key)
    assert [r.iterations for r in h.replans] == [r.iterations for r in g.replans]


def test_a_simulated_latency_adopts_only_the_newest_replan_at_its_time(robot, make):
    learner = make(replan_latency=0.25)
    plan0 = learner.plan
    running, replanned = {}, []
    for k in range(3900, 5001):
        t = k * TICK
        tau = push_torque(robot, learner, t) if k in (4000, 4100) else np.zeros(7)
        obs = learner.observe(t, tau)
        running[k] = learner.replan_running_since
        if obs[2]:
            replanned.append((k, learner.adopted))
        if k < 4350:
            np.testing.assert_array_equal(learner.plan, plan0)
    # The push at 4.1 s superseded the one at 4.0 s; its plan is due at 4.35 s.
    assert replanned == [(4350, True)]
    assert (running[3999], running[4050], running[4349], running[4350]) == (None, 4.0, 4.1, None)
    assert learner.superseded_replans == 1 and learner.last_replan_converged is True
    history = learner.history()
    assert history.plan_t.tolist() == [0.0, 4349 * TICK], "blended in from the tick before"
    assert history.replans[0] is None and history.replans[1] is not None


def test_with_the_wall_clock_a_stalled_worker_never_holds_up_observe(robot, make):
    learner = make(replan_latency=None)
    assert learner.replan_latency is None
    plan0 = learner.plan
    learner._debug_stall_worker(1.0)
    learner.observe(1.0, push_torque(robot, learner, 1.0))
    began = time.monotonic()
    k, longest = 0, 0.0
    while not learner.adopted:
        k += 1
        assert time.monotonic() - began < 60, "never adopted"
        time.sleep(TICK)
        call = time.monotonic()
        learner.observe(min(1.0 + k * TICK, 14.0), np.zeros(7))
        longest = max(longest, time.monotonic() - call)
        if not learner.adopted:
            assert learner.replan_running_since == 1.0
            np.testing.assert_array_equal(learner.plan, plan0)
    # Ticks went on during the 1 s stall, none of them waiting for it (on a loaded machine a
    # tick's sleep may take far longer than asked, so only the calls themselves are timed).
    assert time.monotonic() - began >= 1.0 and k > 3, "ticks went on during the stall"
    assert longest < 0.5, f"an observe waited {longest:.3f} s for the stalled worker"
    assert learner.replan_running_since is None and len(learner.history().plan_t) == 2


@pytest.mark.parametrize("latency", [0.01, None], ids=["simulated", "wall-clock"])
def test_a_worker_panic_is_a_typed_error_once(robot, make, latency):
    learner = make(replan_latency=latency)
    plan0 = learner.plan
    learner._debug_panic_worker()
    learner.observe(4.0, push_torque(robot, learner, 4.0))
    errors, k = [], 0
    while learner.replan_pending:
        k += 1
        assert k < 20_000
        time.sleep(1e-4)
        try:
            learner.observe(4.0 + k * TICK, np.zeros(7))
        except Exception as e:  # noqa: BLE001 - a PanicException is a BaseException and escapes
            errors.append(e)
    assert len(errors) == 1 and isinstance(errors[0], ex.ReplanWorkerError), errors
    assert "panicked" in str(errors[0])
    np.testing.assert_array_equal(learner.plan, plan0)
    assert len(learner.history().rejected) == 1


def test_a_replan_that_does_not_converge_is_adopted_and_said_so(robot, features):
    optimizer = phri.TrajectoryOptimizer(features, WAYPOINTS, duration=DURATION, max_iterations=2)
    update = phri.WeightUpdate(STEP, LOWER, UPPER, learned=LEARNED)
    learner = phri.Learner(
        features, phri.Deformation(), update, phri.InteractionDetector(), optimizer, INITIAL,
        PICK_BASIC, PLACE_LOWER, duration=DURATION, replan_latency=0.01,
    )  # fmt: skip
    assert learner.last_replan_converged is None
    learner.observe(4.0, push_torque(robot, learner, 4.0))
    for k in range(1, 11):
        learner.observe(4.0 + k * TICK, np.zeros(7))
    assert learner.last_replan_converged is False and len(learner.history().plan_t) == 2


def test_dropping_a_learner_with_a_stalled_worker_returns(robot, make):
    learner = make(replan_latency=None)
    learner._debug_stall_worker(60.0)
    learner.observe(1.0, push_torque(robot, learner, 1.0))
    time.sleep(0.05)
    began = time.monotonic()
    del learner
    assert time.monotonic() - began < 30


def test_fault_hooks_need_a_worker(make):
    learner = make()
    with pytest.raises(ex.InvalidParameterError, match="needs a replan worker"):
        learner._debug_stall_worker(1.0)
    with pytest.raises(ex.InvalidParameterError, match="^seconds must be in"):
        make(replan_latency=None)._debug_stall_worker(-1.0)


# --------------------------------------------------------------------------------------------------
# times, reset, threads, integer and speed arguments


@pytest.mark.parametrize("latency", [0.0, 0.05, None], ids=["inline", "simulated", "wall-clock"])
def test_times_outside_the_task_or_going_back_are_refused_and_change_nothing(robot, make, latency):
    learner = make(replan_latency=latency)
    learner.observe(2.0, np.zeros(7))
    tau = push_torque(robot, learner, 4.0)
    for t in (5000.0, DURATION + 0.02, -1e-9):
        with pytest.raises(
            ex.InvalidParameterError, match=r"^t must be a time within the task, in \[0, 15.01\] s"
        ):
            learner.observe(t, tau)
    with pytest.raises(
        ex.InvalidParameterError, match="^t must not go back in time: got 1.9 s after an observe at 2"
    ):
        learner.observe(1.9, tau)
    assert len(learner.history()) == 0 and learner.weights.tolist() == INITIAL
    assert learner.observe(4.0, tau)[:2] == (True, True), "a valid push still learns"
    assert phri.Learner.TIME_SLACK == 0.01
    learner.observe(DURATION + phri.Learner.TIME_SLACK, np.zeros(7))


@pytest.mark.parametrize("latency", [0.0, TICK], ids=["inline", "one-tick"])
def test_reset_starts_again_as_a_fresh_learner(robot, make, latency):
    def episode(learner):
        return loop(learner, robot, [(k, k * TICK) for k in range(3900, 4400)], push_at=(4000, 4100, 4200))

    fresh, reused = make(replan_latency=latency), make(replan_latency=latency)
    plan0 = reused.plan
    _, want = episode(fresh)
    episode(reused)
    reused.observe(4.5, push_torque(robot, reused, 4.5))
    reused.reset()
    assert reused.weights.tolist() == INITIAL and reused.replan_running_since is None
    np.testing.assert_array_equal(reused.plan, plan0)
    assert len(reused.history()) == 0 and reused.history().plan_t.tolist() == [0.0]
    _, got = episode(reused)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(reused.history().plans, fresh.history().plans)


def test_reference_from_another_thread_during_observe(robot, make):
    # Inline replans release the GIL for milliseconds: another thread's reference() waits for the
    # observe rather than failing.
    learner = make()
    stop, failures, samples = threading.Event(), [], [0]

    def read():
        out = (np.zeros(7), np.zeros(7), np.zeros(7))
        while not stop.is_set():
            try:
                learner.reference(4.0, out=out)
                _ = learner.weights, learner.replan_running_since
                samples[0] += 1
            except BaseException as e:  # noqa: BLE001 - a PanicException too
                failures.append(e)
                return

    reader = threading.Thread(target=read)
    reader.start()
    try:
        for k in range(10):
            t = 4.0 + 0.1 * k
            learner.observe(t, push_torque(robot, learner, t))
    finally:
        stop.set()
        reader.join()
    assert failures == [] and samples[0] > 0
    assert len(learner.history().plan_t) > 1


@pytest.mark.parametrize("name", ["replan_iterations", "seeds"])
@pytest.mark.parametrize("value", [-1, 2**64, 10**100])
def test_integer_arguments_out_of_range_name_the_argument(make, name, value):
    with pytest.raises(ex.InvalidParameterError, match=f"^{name} must be an integer in \\[0, "):
        make(**{name: value})


def test_integer_arguments_of_another_type_name_the_argument(make):
    with pytest.raises(TypeError, match="^argument 'seeds': must be an int, got float$"):
        make(seeds=2.0)


@pytest.mark.parametrize("speed", [5e-324, 1e-310, 1e-4, 1.5])
def test_absurd_transition_speeds_are_refused(make, speed):
    with pytest.raises(ex.InvalidParameterError, match="^transition_speed must be a finite fraction"):
        make(transition_speed=speed)


@pytest.mark.parametrize("latency", [-0.001, np.nan, np.inf, DURATION + 1])
def test_bad_replan_latencies_are_refused(make, latency):
    with pytest.raises(ex.InvalidParameterError, match="^replan_latency must be a time in \\[0, duration"):
        make(replan_latency=latency)


def test_a_budget_needs_inline_replans(make):
    with pytest.raises(ex.InvalidParameterError, match="^replan_iterations budgets inline replans only"):
        make(replan_latency=None, replan_iterations=3)


@pytest.mark.parametrize("spin", [-0.001, np.nan, -np.inf])
def test_bad_worker_spins_are_refused(make, spin):
    with pytest.raises(ex.InvalidParameterError, match="^worker_spin must be a time >= 0 s"):
        make(replan_latency=None, worker_spin=spin)


def test_worker_spin_needs_a_worker_and_learning(make):
    with pytest.raises(ex.InvalidParameterError, match="^worker_spin needs a replan worker"):
        make(worker_spin=1.0)
    with pytest.raises(
        ex.InvalidParameterError, match="^worker_spin must be 0 for a learner that does not learn"
    ):
        make(replan_latency=None, worker_spin=1.0, learning=False)


def test_a_spinning_worker_replans_and_stops_with_the_learner(robot, make):
    # The worker busy-waits for pushes from the start (a core of its own): the plan a push gives is
    # the sleeping worker's, and dropping the learner stops it.
    plans = []
    for spin in (0.0, np.inf):
        learner = make(replan_latency=None, seeds=3, worker_spin=spin)
        learner.observe(4.0, push_torque(robot, learner, 4.0))
        for k in range(1, 100_000):
            time.sleep(1e-4)
            learner.observe(4.0 + k * TICK, np.zeros(7))
            if len(learner.history().plan_t) == 2:
                break
        plans.append(learner.history().plans[-1])
        began = time.monotonic()
        del learner
        assert time.monotonic() - began < 1.0
    np.testing.assert_array_equal(plans[0], plans[1])
