"""phri.ImpedanceController: eq. 6 against a numpy reference with gravity from Robot.gravity, eq. 5
through the arm's own dynamics (Robot.mass_matrix / nonlinear_effects), saturation status, the `out`
argument, input forms, and typed errors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import phri
from phri import exceptions as ex

K_DEFAULT = np.array([20.0, 30.0, 15.0, 15.0, 10.0, 10.0, 6.0])  # N·m/rad
B_DEFAULT = np.array([40.0, 60.0, 30.0, 30.0, 15.0, 15.0, 10.0])  # N·m·s/rad
PLACE_LOWER = np.radians([210.8, 101.6, 192.0, 114.7, 222.2, 246.1, 322.0])
TOL = 1e-9


@pytest.fixture(scope="module")
def jaco2() -> phri.Robot:
    return phri.Robot.jaco2()


@pytest.fixture
def gen() -> np.random.Generator:
    return np.random.default_rng(6)


def random_q(robot: phri.Robot, rng: np.random.Generator) -> np.ndarray:
    lo = np.where(np.isfinite(robot.lower_limits), robot.lower_limits, 0.0)
    hi = np.where(np.isfinite(robot.upper_limits), robot.upper_limits, 2.0 * np.pi)
    return lo + (hi - lo) * (0.05 + 0.9 * rng.random(7))


def random_spd(rng: np.random.Generator, scale: float) -> np.ndarray:
    a = rng.normal(size=(7, 7))
    return scale * (a @ a.T / 7 + np.eye(7))


def draw_gains(gen, kind: str, k_max: float):
    """(K, B, ImpedanceController kwargs): the defaults, random diagonal gains (stiffness in [10, k_max],
    damping a tenth of that range), or random full symmetric positive definite matrices."""
    if kind == "default":
        return K_DEFAULT, B_DEFAULT, {}
    if kind == "diagonal":
        k, b = gen.uniform(10, k_max, 7), gen.uniform(1, k_max / 10, 7)
    else:
        k, b = random_spd(gen, 60.0), random_spd(gen, 6.0)
    return k, b, {"stiffness": k, "damping": b}


def as_matrix(gain: np.ndarray) -> np.ndarray:
    return np.diag(gain) if gain.ndim == 1 else gain


def reference_eq6(robot, q, qd, q_ref, qd_ref, k, b, gravity=True):
    """(τ saturated, saturated bitmask) of eq. 6 in numpy."""
    tau = as_matrix(k) @ (q_ref - q) + as_matrix(b) @ (qd_ref - qd)
    if gravity:
        tau = tau + robot.gravity(q)
    limits = robot.effort_limits
    over = np.abs(tau) > limits
    return np.clip(tau, -limits, limits), int(sum(1 << j for j in np.flatnonzero(over)))


@pytest.mark.parametrize("gains", ["default", "diagonal", "full"])
@pytest.mark.parametrize("gravity", [True, False])
def test_eq6_matches_numpy_reference(jaco2, gen, gains, gravity):
    k, b, kwargs = draw_gains(gen, gains, k_max=200.0)
    c = phri.ImpedanceController(jaco2, gravity_compensation=gravity, **kwargs)
    saturated_seen = 0
    for _ in range(200):
        q = random_q(jaco2, gen)
        qd = gen.normal(scale=0.5, size=7)
        q_ref = q + gen.normal(scale=0.25, size=7)
        qd_ref = gen.normal(scale=0.5, size=7)
        tau = c.torque(q, qd, q_ref, qd_ref)
        want, bits = reference_eq6(jaco2, q, qd, q_ref, qd_ref, k, b, gravity)
        np.testing.assert_allclose(tau, want, rtol=0, atol=TOL, err_msg=f"q={q.tolist()}")
        assert c.saturated == bits
        saturated_seen += bits != 0
    assert saturated_seen > 0, "the sweep should reach the effort limits at least once"


def test_on_the_reference_the_law_is_gravity_compensation(jaco2):
    c = phri.ImpedanceController(jaco2)
    z = np.zeros(7)
    np.testing.assert_array_equal(c.torque(PLACE_LOWER, z, PLACE_LOWER, z), jaco2.gravity(PLACE_LOWER))
    assert c.saturated == 0
    np.testing.assert_array_equal(
        phri.ImpedanceController(jaco2, gravity_compensation=False).torque(PLACE_LOWER, z, PLACE_LOWER, z), z
    )


def test_saturation_clips_to_the_effort_limits_and_reports_the_joints(jaco2):
    c = phri.ImpedanceController(jaco2)
    z = np.zeros(7)
    q_ref = PLACE_LOWER.copy()
    q_ref[4] += 3.0  # 10 N·m/rad · 3 rad = 30 N·m > 20 N·m
    q_ref[1] -= 4.0  # 30 N·m/rad · 4 rad = 120 N·m > 80 N·m (with g(q) too)
    tau = c.torque(PLACE_LOWER, z, q_ref, z)
    assert c.saturated == (1 << 4) | (1 << 1)
    assert tau[4] == jaco2.effort_limits[4] and tau[1] == -jaco2.effort_limits[1]
    c.torque(PLACE_LOWER, z, PLACE_LOWER, z)
    assert c.saturated == 0, "the status describes the last step"


@pytest.mark.parametrize("inertia", ["diagonal", "full"])
def test_eq5_renders_the_desired_impedance_through_the_arms_dynamics(jaco2, gen, inertia):
    m_r = np.array([0.5, 0.5, 0.3, 0.3, 0.1, 0.1, 0.1]) if inertia == "diagonal" else random_spd(gen, 0.2)
    c = phri.ImpedanceController(jaco2, inertia=m_r)
    checked = 0
    for _ in range(100):
        q = random_q(jaco2, gen)
        qd = gen.uniform(-0.3, 0.3, 7)
        q_ref = q + gen.uniform(-0.05, 0.05, 7)
        qd_ref = gen.uniform(-0.1, 0.1, 7)
        qdd_ref = gen.uniform(-0.2, 0.2, 7)
        u_h = gen.uniform(-1.0, 1.0, 7)
        tau = c.torque_full(q, qd, q_ref, qd_ref, qdd_ref, u_h)
        if c.saturated:
            continue
        # The arm's forward dynamics: q̈ = M⁻¹(τ + u_H − h).
        qdd = np.linalg.solve(jaco2.mass_matrix(q), tau + u_h - jaco2.nonlinear_effects(q, qd))
        lhs = as_matrix(m_r) @ (qdd - qdd_ref) + B_DEFAULT * (qd - qd_ref) + K_DEFAULT * (q - q_ref)
        np.testing.assert_allclose(lhs, u_h, rtol=0, atol=1e-8, err_msg=f"q={q.tolist()}")
        checked += 1
    assert checked > 50


def saturate(robot, tau):
    """(τ clipped to the effort limits, bitmask of the clipped joints)."""
    limits = robot.effort_limits
    over = np.abs(tau) > limits
    return np.clip(tau, -limits, limits), int(sum(1 << j for j in np.flatnonzero(over)))


def reference_eq5(robot, q, qd, q_ref, qd_ref, qdd_ref, u_h, k, b, m_r):
    """Eq. 5 in numpy: τ = M(q)·(q̈_R + M_R⁻¹(u_H + K(q_R − q) + B(q̇_R − q̇))) + C(q, q̇)q̇ + g(q) − u_H."""
    spring_damper = as_matrix(k) @ (q_ref - q) + as_matrix(b) @ (qd_ref - qd)
    qdd = qdd_ref + np.linalg.solve(as_matrix(m_r), u_h + spring_damper)
    h = robot.inverse_dynamics(q, qd, np.zeros(7))  # C(q, q̇)q̇ + g(q)
    return saturate(robot, robot.mass_matrix(q) @ qdd + h - u_h)


def reference_implicit(robot, q, qd, q_ref, qd_ref, dt, k, b, gravity=True):
    """Stable PD in numpy: (M + BΔt) q̈ = K(q_R − q − q̇Δt) + B(q̇_R − q̇) − C(q, q̇)q̇ [− g without
    compensation], then τ = [g +] K(q_R − q − q̇Δt) + B(q̇_R − q̇ − q̈Δt)."""
    k, b = as_matrix(k), as_matrix(b)
    g = robot.gravity(q)
    compensation = g if gravity else np.zeros(7)
    h = robot.nonlinear_effects(q, qd)  # C(q, q̇)q̇ + g
    e_pred = q_ref - q - qd * dt
    qdd = np.linalg.solve(robot.mass_matrix(q) + b * dt, k @ e_pred + b @ (qd_ref - qd) - h + compensation)
    return saturate(robot, compensation + k @ e_pred + b @ (qd_ref - qd - qdd * dt))


@pytest.mark.parametrize("inertia", ["diagonal", "full"])
@pytest.mark.parametrize("gains", ["default", "full"])
def test_eq5_matches_numpy_reference(jaco2, gen, inertia, gains):
    m_r = gen.uniform(0.05, 1.0, 7) if inertia == "diagonal" else random_spd(gen, 0.3)
    k, b, kwargs = draw_gains(gen, gains, k_max=200.0)
    c = phri.ImpedanceController(jaco2, inertia=m_r, **kwargs)
    saturated, free = 0, 0
    for _ in range(200):
        q = random_q(jaco2, gen)
        qd = gen.normal(scale=0.5, size=7)
        spread = 10 ** gen.uniform(-3.0, 0.5)  # from well inside the limits to far beyond them
        q_ref = q + gen.normal(scale=spread, size=7)
        qd_ref = qd + gen.normal(scale=spread, size=7)
        qdd_ref = gen.normal(scale=10 * spread, size=7)
        u_h = gen.normal(scale=2.0, size=7)
        tau = c.torque_full(q, qd, q_ref, qd_ref, qdd_ref, u_h)
        want, bits = reference_eq5(jaco2, q, qd, q_ref, qd_ref, qdd_ref, u_h, k, b, m_r)
        np.testing.assert_allclose(tau, want, rtol=0, atol=TOL, err_msg=f"q={q.tolist()}")
        assert c.saturated == bits, f"q={q.tolist()}"
        saturated += bits != 0
        free += bits == 0
    assert saturated > 5 and free > 5, f"{saturated} saturated, {free} not: the sweep should see both"


@pytest.mark.parametrize("gravity", [True, False])
@pytest.mark.parametrize("gains", ["default", "diagonal", "full"])
@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_torque_implicit_matches_numpy_reference(jaco2, gen, gains, dt, gravity):
    k, b, kwargs = draw_gains(gen, gains, k_max=300.0)
    c = phri.ImpedanceController(jaco2, gravity_compensation=gravity, **kwargs)
    saturated, free = 0, 0
    # The default gains are soft (the study's arm): larger errors and rates reach the effort limits.
    spread = 3.0 if gains == "default" else 1.0
    for _ in range(200):
        q = random_q(jaco2, gen)
        qd = gen.normal(scale=0.5 * spread, size=7)
        q_ref = q + gen.normal(scale=0.15 * spread, size=7)
        qd_ref = gen.normal(scale=0.5 * spread, size=7)
        tau = c.torque_implicit(q, qd, q_ref, qd_ref, dt)
        want, bits = reference_implicit(jaco2, q, qd, q_ref, qd_ref, dt, k, b, gravity)
        np.testing.assert_allclose(tau, want, rtol=0, atol=TOL, err_msg=f"q={q.tolist()}")
        assert c.saturated == bits, f"q={q.tolist()}"
        saturated += bits != 0
        free += bits == 0
    assert saturated > 5 and free > 5, f"{saturated} saturated, {free} not: the sweep should see both"


def test_out_is_written_and_returned(jaco2, gen):
    c = phri.ImpedanceController(jaco2)
    q, qd = random_q(jaco2, gen), gen.normal(size=7)
    q_ref, qd_ref = q + 0.01, np.zeros(7)
    expected = c.torque(q, qd, q_ref, qd_ref)
    out = np.full(7, np.nan)
    assert c.torque(q, qd, q_ref, qd_ref, out=out) is out
    np.testing.assert_array_equal(out, expected)
    full = phri.ImpedanceController(jaco2, inertia=np.ones(7))
    args = (q, qd, q_ref, qd_ref, np.zeros(7), np.ones(7))
    out2 = np.empty(7)
    assert full.torque_full(*args, out=out2) is out2
    np.testing.assert_array_equal(out2, full.torque_full(*args))


@pytest.mark.parametrize(
    ("out", "error", "pattern"),
    [
        (
            np.zeros(7, dtype=np.float32),
            ex.InvalidParameterError,
            "out must be a writable, contiguous float64",
        ),
        (np.zeros(6), ex.ShapeError, "out must have shape (7,), got (6,)"),
        (np.zeros((1, 7)), ex.ShapeError, "out must have shape (7,), got (1, 7)"),
        (np.zeros(14)[::2], ex.InvalidParameterError, "out must be a writable, contiguous float64"),
        (
            [0.0] * 7,
            ex.InvalidParameterError,
            "out must be a writable, contiguous float64 ndarray of shape (7,), got list",
        ),
    ],
)
def test_bad_out_is_a_typed_error(jaco2, out, error, pattern):
    c = phri.ImpedanceController(jaco2)
    z = np.zeros(7)
    with pytest.raises(error, match="^" + re.escape(pattern)):
        c.torque(PLACE_LOWER, z, PLACE_LOWER, z, out=out)


def test_out_must_be_writable_and_not_an_input(jaco2):
    c = phri.ImpedanceController(jaco2)
    z = np.zeros(7)
    frozen = np.zeros(7)
    frozen.flags.writeable = False
    with pytest.raises(ex.InvalidParameterError, match="^out must be writable"):
        c.torque(PLACE_LOWER, z, PLACE_LOWER, z, out=frozen)
    q = PLACE_LOWER.copy()
    with pytest.raises(
        ex.InvalidParameterError, match="^out must be writable and must not be one of the inputs"
    ):
        c.torque(q, z, PLACE_LOWER, z, out=q)
    np.testing.assert_array_equal(q, PLACE_LOWER)


def test_every_input_form_gives_the_same_torque(jaco2, gen):
    c = phri.ImpedanceController(jaco2)
    q, qd = random_q(jaco2, gen), gen.normal(size=7)
    q_ref, qd_ref = q + gen.normal(scale=0.05, size=7), gen.normal(size=7)
    expected = c.torque(q, qd, q_ref, qd_ref)
    strided = np.zeros(14)
    strided[::2] = q
    forms = [
        (q.tolist(), qd, q_ref, qd_ref),
        (tuple(q), qd.tolist(), q_ref, qd_ref),
        (strided[::2], qd, q_ref, qd_ref),  # float64 but not contiguous
        (q[::-1][::-1], qd, q_ref, qd_ref),
    ]
    for args in forms:
        np.testing.assert_array_equal(c.torque(*args), expected)
    as_f32 = c.torque(q.astype(np.float32), qd, q_ref, qd_ref)
    np.testing.assert_allclose(as_f32, c.torque(q.astype(np.float32).astype(np.float64), qd, q_ref, qd_ref))
    np.testing.assert_array_equal(
        c.torque(np.zeros(7, dtype=int), qd, q_ref, qd_ref), c.torque(np.zeros(7), qd, q_ref, qd_ref)
    )


def test_properties(jaco2, gen):
    c = phri.ImpedanceController(jaco2)
    np.testing.assert_array_equal(c.stiffness, K_DEFAULT)
    np.testing.assert_array_equal(c.damping, B_DEFAULT)
    np.testing.assert_array_equal(c.effort_limits, jaco2.effort_limits)
    assert c.inertia is None and c.gravity_compensation is True and c.saturated == 0
    a = gen.normal(size=(7, 7))
    k = a @ a.T  # full gains are symmetric positive semidefinite
    full = phri.ImpedanceController(jaco2, stiffness=k, inertia=np.full(7, 0.2), gravity_compensation=False)
    np.testing.assert_array_equal(full.stiffness, k)  # row-major round trip
    np.testing.assert_array_equal(full.inertia, np.full(7, 0.2))
    assert full.gravity_compensation is False


# --------------------------------------------------------------------------------------------------
# errors


@pytest.mark.parametrize("method", ["torque", "torque_full"])
@pytest.mark.parametrize("form", ["array", "list"])
def test_bad_joint_vectors_are_typed_errors(jaco2, method, form):
    c = phri.ImpedanceController(jaco2, inertia=np.ones(7))
    good = [PLACE_LOWER, np.zeros(7), PLACE_LOWER, np.zeros(7), np.zeros(7), np.zeros(7)]
    names = ["q", "qd", "q_ref", "qd_ref", "qdd_ref", "u_h"][: 4 if method == "torque" else 6]
    convert = (lambda a: a) if form == "array" else (lambda a: a.tolist())
    for i, name in enumerate(names):
        args = [convert(a) for a in good[: len(names)]]
        args[i] = convert(np.zeros(6))
        with pytest.raises(ex.ShapeError, match="^" + re.escape(f"{name} must have shape (7,), got (6,)")):
            getattr(c, method)(*args)
        bad = np.zeros(7)
        bad[3] = np.nan
        args[i] = convert(bad)
        with pytest.raises(
            ex.NonFiniteError, match="^" + re.escape(f"{name} must be finite, got NaN at index 3")
        ):
            getattr(c, method)(*args)
    args = [convert(a) for a in good[: len(names)]]
    args[0] = np.zeros((1, 7))
    with pytest.raises(ex.ShapeError, match=re.escape("q must have shape (7,), got (1, 7)")):
        getattr(c, method)(*args)


def test_the_full_law_needs_an_inertia(jaco2):
    z = np.zeros(7)
    with pytest.raises(ex.InvalidParameterError, match="^inertia must be set"):
        phri.ImpedanceController(jaco2).torque_full(PLACE_LOWER, z, PLACE_LOWER, z, z, z)


@pytest.mark.parametrize(
    ("kwargs", "error", "pattern"),
    [
        ({"stiffness": np.ones(6)}, ex.ShapeError, "stiffness must have shape (7,) or (7, 7), got (6,)"),
        ({"damping": np.ones((7, 6))}, ex.ShapeError, "damping must have shape (7,) or (7, 7), got (7, 6)"),
        (
            {"inertia": np.ones((2, 7, 7))},
            ex.ShapeError,
            "inertia must have shape (7,) or (7, 7), got (2, 7, 7)",
        ),
        ({"stiffness": -np.ones(7)}, ex.InvalidParameterError, "stiffness [0] must be >= 0, got -1"),
        ({"damping": np.full(7, np.nan)}, ex.NonFiniteError, "damping must be finite"),
        ({"stiffness": np.full((7, 7), np.inf)}, ex.NonFiniteError, "stiffness must be finite"),
        ({"inertia": np.zeros(7)}, ex.InvalidParameterError, "inertia [0] must be > 0 kg·m²"),
        (
            {"inertia": -np.eye(7)},
            ex.InvalidParameterError,
            "inertia must be positive semidefinite, got an eigenvalue",
        ),
        (
            {"inertia": np.diag([0.0, 1, 1, 1, 1, 1, 1])},
            ex.InvalidParameterError,
            "inertia must be symmetric positive definite",
        ),
        (
            {"inertia": np.full(7, 1e-320)},
            ex.InvalidParameterError,
            "inertia [0] must be > 0 kg·m² (and not so small that its inverse overflows)",
        ),
        (
            {"inertia": np.eye(7) + 5 * np.eye(7, k=1)},
            ex.InvalidParameterError,
            "inertia must be a symmetric matrix",
        ),
        ({"damping": -np.eye(7)}, ex.InvalidParameterError, "damping must be positive semidefinite"),
        (
            {"stiffness": np.eye(7) - 3 * np.eye(7, k=1) - 3 * np.eye(7, k=-1)},
            ex.InvalidParameterError,
            "stiffness must be positive semidefinite",
        ),
    ],
)
def test_bad_gains_are_typed_errors(jaco2, kwargs, error, pattern):
    with pytest.raises(error, match="^" + re.escape(pattern)):
        phri.ImpedanceController(jaco2, **kwargs)


def test_default_gains_need_a_seven_joint_robot():
    urdf = Path(phri.__file__).parent / "robots" / "jaco2" / "j2s7s300.urdf"
    arm5 = phri.Robot.from_urdf(urdf, base="root", tip="j2s7s300_link_5")
    assert arm5.nq == 5
    with pytest.raises(ex.InvalidParameterError, match="^stiffness must be given for a robot with 5 joints"):
        phri.ImpedanceController(arm5)
    c = phri.ImpedanceController(arm5, stiffness=np.ones(5), damping=np.ones(5))
    assert c.torque(np.ones(5), np.zeros(5), np.ones(5), np.zeros(5)).shape == (5,)


@pytest.mark.parametrize("method", ["torque", "torque_implicit", "torque_full"])
def test_finite_inputs_whose_torque_would_overflow_are_refused_naming_them(jaco2, method):
    """Gains and states are bounded (±1e9, phri_core::MAX_MAGNITUDE), so the torque cannot overflow:
    a gain of 1e308 and a reference 1e300 away are refused by name instead."""
    with pytest.raises(ex.InvalidParameterError, match=r"^stiffness must be within ±1e9, got 1e308"):
        phri.ImpedanceController(jaco2, stiffness=np.full(7, 1e308), inertia=np.ones(7))
    c = phri.ImpedanceController(jaco2, stiffness=np.full(7, 1e9), inertia=np.ones(7))
    q = np.full(7, np.pi)
    calls = {
        "torque": lambda r: c.torque(q, np.zeros(7), r, np.zeros(7)),
        "torque_implicit": lambda r: c.torque_implicit(q, np.zeros(7), r, np.zeros(7), 1e-3),
        "torque_full": lambda r: c.torque_full(q, np.zeros(7), r, np.zeros(7), np.zeros(7), np.zeros(7)),
    }
    with pytest.raises(ex.InvalidParameterError, match=r"^q_ref must be within ±1e9, got 1e300"):
        calls[method](q + 1e300)
    assert np.isfinite(calls[method](np.full(7, 1e9))).all()
    # The same controller is still fine on sane inputs.
    assert np.all(np.isfinite(c.torque(q, np.zeros(7), q, np.zeros(7))))
